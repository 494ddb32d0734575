"""The SHREC'16 topological-noise dataset (TOPKIDS).

Two layouts are recognised under the data directory (``--data DIR`` or
``TOPOMATCH_DATA``):

release layout (as published by TUM; ``DIR``, ``DIR/topkids`` or ``DIR/TOPKIDS``)
    ``low_res/`` and ``high_res/``, each with ``kidNN.off``, ``kidNN_ref.txt``,
    ``kidNN_sym.txt``, ``kidNN_indmap.txt`` (high res) and ``kid00_sym.txt``.
learning-code layout (ULRSSM and successors; low res only)
    ``off/kidNN.off`` and ``corres/kidNN_ref.vts`` (line ``k``: the kid00 vertex of
    vertex ``k``); no symmetry maps.

Shapes are ``kid00`` (the null shape, the reference) to ``kid25``. Splits:
train = kid01..kid15, test = kid16..kid25 (the SHREC'16 contest split).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy import sparse

from topomatch.datasets.base import Shape, ShapeCollection, ref_matrix
from topomatch.io import read_indmap, read_ref, read_sym, read_vts
from topomatch.mesh import TriangleMesh
from topomatch.typing import PathType

__all__ = [
    "ALL_SHAPES",
    "REFERENCE",
    "TEST_SHAPES",
    "TRAIN_SHAPES",
    "TopkidsLocation",
    "load_topkids",
    "locate_topkids",
    "resolve_data_dir",
]

logger = logging.getLogger(__name__)

Resolution = Literal["low", "high"]
REFERENCE = "kid00"
TRAIN_SHAPES = [f"kid{i:02d}" for i in range(1, 16)]
TEST_SHAPES = [f"kid{i:02d}" for i in range(16, 26)]
ALL_SHAPES = [REFERENCE, *TRAIN_SHAPES, *TEST_SHAPES]
DATA_ENV = "TOPOMATCH_DATA"


def resolve_data_dir(data: PathType | None) -> Path | None:
    """The data directory from ``data`` or ``TOPOMATCH_DATA``; ``None`` when neither is set."""
    if data is not None:
        p = Path(data).expanduser()
        if not p.is_dir():
            raise FileNotFoundError(f"data directory {p} does not exist")
        return p
    env = os.environ.get(DATA_ENV)
    if env:
        p = Path(env).expanduser()
        if not p.is_dir():
            raise FileNotFoundError(f"{DATA_ENV}={env} is not a directory")
        return p
    return None


@dataclass(frozen=True)
class TopkidsLocation:
    """Where a TOPKIDS resolution was found and in which layout."""

    path: Path
    layout: Literal["release", "learning"]
    resolution: Resolution


def locate_topkids(root: PathType, resolution: Resolution = "low") -> TopkidsLocation | None:
    """Find the TOPKIDS files of one resolution under ``root`` (``None`` if absent)."""
    root = Path(root)
    sub = "low_res" if resolution == "low" else "high_res"
    for base in (root, root / "topkids", root / "TOPKIDS", root / "TopKids"):
        if (base / sub).is_dir():
            return TopkidsLocation(base / sub, "release", resolution)
        if base.name == sub and (base / "kid00.off").is_file():
            return TopkidsLocation(base, "release", resolution)
        if resolution == "low" and (base / "off").is_dir() and (base / "corres").is_dir():
            return TopkidsLocation(base, "learning", resolution)
    return None


def load_topkids(root: PathType | None = None, resolution: Resolution = "low") -> ShapeCollection:
    """Load TOPKIDS lazily: shapes are read when first accessed.

    Parameters
    ----------
    root : str or PathLike, optional
        Data directory; defaults to ``TOPOMATCH_DATA``.
    resolution : {"low", "high"}

    Returns
    -------
    ShapeCollection
        Only shapes whose mesh (and, except for kid00, ground truth) exist are listed;
        ``missing`` says precisely which files are absent.

    Raises
    ------
    FileNotFoundError
        If no data directory is given or no TOPKIDS files of that resolution are found.
    """
    base = resolve_data_dir(root)
    if base is None:
        raise FileNotFoundError(f"no data directory: pass --data DIR or set {DATA_ENV}")
    loc = locate_topkids(base, resolution)
    if loc is None:
        raise FileNotFoundError(
            f"no TOPKIDS {resolution}-res data under {base} (looked for low_res/ or high_res/, "
            "topkids/<res>/, or off/ + corres/)"
        )
    if loc.layout == "release":
        return _load_release(loc)
    return _load_learning(loc)


def _read_n_vertices(path: Path) -> int:
    with open(path, encoding="ascii", errors="replace") as fh:
        for line in fh:
            s = line.split("#", 1)[0].split()
            if not s:
                continue
            if s[0].upper().endswith("OFF"):
                if len(s) > 1:
                    return int(s[1])
                continue
            return int(s[0])
    raise ValueError(f"{path}: cannot read the vertex count")


def _load_release(loc: TopkidsLocation) -> ShapeCollection:
    d = loc.path
    high = loc.resolution == "high"
    missing: list[str] = []
    loaders = {}
    ref_mesh = d / f"{REFERENCE}.off"
    if not ref_mesh.is_file():
        raise FileNotFoundError(f"{ref_mesh}: the null shape is missing; nothing can be evaluated without it")
    n_ref = _read_n_vertices(ref_mesh)

    def make_reference() -> Shape:
        mesh = TriangleMesh.from_file(ref_mesh, name=REFERENCE)
        symf = d / f"{REFERENCE}_sym.txt"
        sym = read_sym(symf, mesh.n_vertices) if symf.is_file() else None
        eye = sparse.identity(mesh.n_vertices, dtype=np.int8, format="csr")
        return Shape(REFERENCE, mesh, ref=eye, sym=sym, unreliable=None)

    loaders[REFERENCE] = make_reference
    if not (d / f"{REFERENCE}_sym.txt").is_file():
        missing.append(f"{REFERENCE}_sym.txt (symmetric solutions of pairs with kid00 cannot be scored)")
    for name in ALL_SHAPES[1:]:
        off = d / f"{name}.off"
        reff = d / f"{name}_ref.txt"
        symf = d / f"{name}_sym.txt"
        indf = d / f"{name}_indmap.txt"
        absent = [p.name for p in (off, reff) if not p.is_file()]
        if absent:
            missing.append(f"{name}: {', '.join(absent)} missing; shape skipped")
            continue
        if not symf.is_file():
            missing.append(f"{name}_sym.txt (no symmetric credit for pairs onto {name})")
        if high and not indf.is_file():
            missing.append(f"{name}_indmap.txt (all vertices with a _ref row treated as reliable)")

        def make(name: str = name, off: Path = off, reff: Path = reff, symf: Path = symf, indf: Path = indf) -> Shape:
            mesh = TriangleMesh.from_file(off, name=name)
            pairs = read_ref(reff, mesh.n_vertices, n_ref)
            ref = ref_matrix(pairs, mesh.n_vertices, n_ref)
            sym = read_sym(symf, mesh.n_vertices) if symf.is_file() else None
            unreliable = read_indmap(indf, mesh.n_vertices) if indf.is_file() else None
            if unreliable is None and high:
                unreliable = np.diff(ref.indptr) == 0
            return Shape(name, mesh, ref=ref, sym=sym, unreliable=unreliable)

        loaders[name] = make
    return ShapeCollection(
        name=f"topkids/{loc.resolution}_res",
        reference=REFERENCE,
        loaders=loaders,
        splits={"train": list(TRAIN_SHAPES), "test": list(TEST_SHAPES), "all": ALL_SHAPES[1:]},
        missing=missing,
        root=d,
    )


def _load_learning(loc: TopkidsLocation) -> ShapeCollection:
    d = loc.path
    missing: list[str] = ["symmetry maps (the learning-code layout has none): no symmetric credit"]
    ref_mesh = d / "off" / f"{REFERENCE}.off"
    if not ref_mesh.is_file():
        raise FileNotFoundError(f"{ref_mesh}: the null shape is missing")
    n_ref = _read_n_vertices(ref_mesh)
    loaders = {}

    def make_reference() -> Shape:
        mesh = TriangleMesh.from_file(ref_mesh, name=REFERENCE)
        return Shape(REFERENCE, mesh, ref=sparse.identity(mesh.n_vertices, dtype=np.int8, format="csr"))

    loaders[REFERENCE] = make_reference
    for name in ALL_SHAPES[1:]:
        off = d / "off" / f"{name}.off"
        vts = next((p for p in (d / "corres" / f"{name}_ref.vts", d / "corres" / f"{name}.vts") if p.is_file()), None)
        if not off.is_file() or vts is None:
            what = [s for s, ok in ((f"off/{name}.off", off.is_file()), (f"corres/{name}_ref.vts", vts is not None)) if not ok]
            missing.append(f"{name}: {', '.join(what)} missing; shape skipped")
            continue

        def make(name: str = name, off: Path = off, vts: Path = vts) -> Shape:
            mesh = TriangleMesh.from_file(off, name=name)
            idx = read_vts(vts, n_ref)
            if len(idx) != mesh.n_vertices:
                raise ValueError(f"{vts}: {len(idx)} rows but {name} has {mesh.n_vertices} vertices")
            pairs = np.c_[np.arange(mesh.n_vertices), idx]
            return Shape(name, mesh, ref=ref_matrix(pairs, mesh.n_vertices, n_ref))

        loaders[name] = make
    return ShapeCollection(
        name="topkids/low_res",
        reference=REFERENCE,
        loaders=loaders,
        splits={"train": list(TRAIN_SHAPES), "test": list(TEST_SHAPES), "all": ALL_SHAPES[1:]},
        missing=missing,
        root=d,
    )
