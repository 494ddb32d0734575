"""The built-in synthetic benchmark: a procedural figure in touching poses, made noisy.

Made from code alone (no data files), so that ``topomatch bench`` runs on a fresh
machine. The articulated figure of :mod:`topomatch.datasets.figure` is posed by
skinning in ten poses where parts touch or interpenetrate (hands on hips, arms
crossed, knees together, ...); each pose goes through the same topological-noise
generator as user data (:mod:`topomatch.datasets.noise`): touching parts fuse, interior
parts vanish, the single outer surface is remeshed to about 5,000 vertices. One pose
also gets two synthetic shortcuts. Ground truth to the null shape comes from the
skinning (exact up to the remeshing), with unreliable vertices flagged along fused
seams; the figure is mirror-symmetric, so every shape has a left-right map.

Shapes: ``syn00`` (null shape, rest pose), ``syn01``-``syn06`` (train),
``syn07``-``syn10`` (test). Vertex orders are shuffled per shape (``random_state``).

Generation takes about 15-30 s on two cores; the result is cached on disk when a cache
directory is configured (the command line does), keyed by the arguments and a hash of
the generator's source files, and memoised in the process.
"""

from __future__ import annotations

import logging
import os
import time

import numpy as np
from scipy import sparse

from topomatch import _cache
from topomatch.datasets.base import Shape, ShapeCollection, ref_matrix
from topomatch.mesh import TriangleMesh

__all__ = ["BUILTIN_POSES", "builtin_benchmark"]

logger = logging.getLogger(__name__)

GENERATOR_VERSION = "builtin-3"
REFERENCE = "syn00"

BUILTIN_POSES: dict[str, str] = {
    "syn01": "hands_on_hips",
    "syn02": "arms_crossed",
    "syn03": "knees_together",
    "syn04": "hand_on_shoulder",
    "syn05": "hands_behind_head",
    "syn06": "free",  # no contact: two synthetic shortcuts instead
    "syn07": "hand_on_head",
    "syn08": "legs_crossed",
    "syn09": "hands_clasped",
    "syn10": "thinker",
}
"""Shape name -> pose of :data:`topomatch.datasets.figure.POSES`."""

_SHORTCUT_SHAPES = {"syn06": 2}
_TRAIN = [f"syn{i:02d}" for i in range(1, 7)]
_TEST = [f"syn{i:02d}" for i in range(7, 11)]

_MEMO: dict[tuple, ShapeCollection] = {}


def builtin_benchmark(n_vertices: int = 5000, *, random_state: int = 0, n_jobs: int | None = None) -> ShapeCollection:
    """Build (or load from the cache) the built-in benchmark; deterministic for given arguments.

    Parameters
    ----------
    n_vertices : int
        Resolution: vertices of the null shape (noisy shapes scale with their area).
    random_state : int
        Seeds the shortcuts and the vertex shuffles.
    n_jobs : int, optional
        Worker processes for a generation (not for a cache hit); default: two when the
        machine has two cores or more. The result does not depend on it.

    Returns
    -------
    ShapeCollection
        Reference ``syn00``; splits ``train`` (syn01-06), ``test`` (syn07-10) and
        ``all``. Every shape has ``ref`` (exact-as-possible ground truth to syn00, one
        entry per vertex), ``sym`` and ``unreliable``.
    """
    if isinstance(n_vertices, bool) or not isinstance(n_vertices, int | np.integer) or n_vertices < 500:
        raise ValueError(f"n_vertices must be an integer >= 500, got {n_vertices!r}")
    if isinstance(random_state, bool) or not isinstance(random_state, int | np.integer):
        raise TypeError(f"random_state must be an int, got {type(random_state).__name__}")
    memo_key = (int(n_vertices), int(random_state))
    if memo_key in _MEMO:
        return _MEMO[memo_key]
    key = _cache.array_hash(np.array([n_vertices, random_state]), extra=GENERATOR_VERSION + _source_digest())
    stored = _cache.load("builtin", key)
    if stored is not None:
        try:
            shapes = _unpack(stored)
        except (KeyError, ValueError) as err:
            logger.warning("ignoring a broken cached built-in benchmark (%s)", err)
            shapes = None
    else:
        shapes = None
    if shapes is None:
        t0 = time.perf_counter()
        if n_jobs is None:
            n_jobs = min(2, os.cpu_count() or 1)
        shapes = _generate(int(n_vertices), int(random_state), int(n_jobs))
        logger.info("built-in benchmark generated in %.1f s", time.perf_counter() - t0)
        _cache.save("builtin", key, _pack(shapes))
    coll = ShapeCollection(
        name="builtin",
        reference=REFERENCE,
        loaders={k: (lambda s=s: s) for k, s in shapes.items()},
        splits={"train": list(_TRAIN), "test": list(_TEST), "all": [*_TRAIN, *_TEST]},
        missing=[],
        root=None,
    )
    _MEMO[memo_key] = coll
    return coll


def _source_digest() -> str:
    """Hash of the generator's source files: any change to them invalidates cached data."""
    import hashlib
    from pathlib import Path

    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in ("builtin.py", "figure.py", "noise.py", "_surface.py", "_isosurface.py", "_noise_kernels.py"):
        try:
            h.update((here / name).read_bytes())
        except OSError:  # e.g. a zipped install: fall back to the version string alone
            h.update(name.encode())
    return h.hexdigest()[:16]


def _generate(n_vertices: int, random_state: int, n_jobs: int = 1) -> dict[str, Shape]:
    from topomatch.datasets.figure import build_figure
    from topomatch.datasets.noise import NoiseParams, noisy_collection

    rng = np.random.default_rng(random_state)
    fig = build_figure(2 * n_vertices)
    poses = {name: fig.pose(pose) for name, pose in BUILTIN_POSES.items()}
    params = NoiseParams(n_vertices=n_vertices)
    pose_params = {name: NoiseParams(n_vertices=n_vertices, shortcuts=k) for name, k in _SHORTCUT_SHAPES.items()}
    coll = noisy_collection(
        fig.mesh.vertices, fig.mesh.faces, poses, params, pose_params=pose_params, template_sym=fig.sym,
        null_vertices=n_vertices, reference=REFERENCE, name="builtin", random_state=rng, n_jobs=n_jobs,
    )
    shapes = {name: coll[name] for name in [REFERENCE, *BUILTIN_POSES]}
    return _shuffle(shapes, rng)


def _shuffle(shapes: dict[str, Shape], rng: np.random.Generator) -> dict[str, Shape]:
    """Permute every shape's vertices (the null shape's too, with the references)."""
    perms = {name: rng.permutation(s.n_vertices) for name, s in shapes.items()}  # new i <- old perm[i]
    inv = {name: np.argsort(p) for name, p in perms.items()}
    ref_inv = inv[REFERENCE]
    n_ref = shapes[REFERENCE].n_vertices
    out = {}
    for name, s in shapes.items():
        p, q = perms[name], inv[name]
        mesh = TriangleMesh(s.mesh.vertices[p], q[s.mesh.faces], name=name)
        ref_old = s.ref_p2p[p]
        ref = ref_matrix(np.c_[np.arange(len(p)), ref_inv[ref_old]], len(p), n_ref)
        sym = None if s.sym is None else np.where(s.sym[p] >= 0, q[np.maximum(s.sym[p], 0)], -1)
        unrel = None if s.unreliable is None else s.unreliable[p]
        out[name] = Shape(name, mesh, ref=ref, sym=sym, unreliable=unrel)
    return out


def _pack(shapes: dict[str, Shape]) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {"names": np.array(list(shapes))}
    for name, s in shapes.items():
        arrays[f"{name}.vertices"] = s.mesh.vertices
        arrays[f"{name}.faces"] = s.mesh.faces
        arrays[f"{name}.ref"] = s.ref_p2p
        arrays[f"{name}.sym"] = np.full(s.n_vertices, -1) if s.sym is None else s.sym
        arrays[f"{name}.unreliable"] = np.zeros(s.n_vertices, bool) if s.unreliable is None else s.unreliable
    return arrays


def _unpack(arrays: dict[str, np.ndarray]) -> dict[str, Shape]:
    names = [str(n) for n in arrays["names"]]
    if REFERENCE not in names:
        raise ValueError("no reference shape")
    n_ref = len(arrays[f"{REFERENCE}.vertices"])
    out = {}
    for name in names:
        mesh = TriangleMesh(arrays[f"{name}.vertices"], arrays[f"{name}.faces"], name=name)
        n = mesh.n_vertices
        if name == REFERENCE:
            ref = sparse.identity(n, dtype=np.int8, format="csr")
            unrel = None
        else:
            ref = ref_matrix(np.c_[np.arange(n), arrays[f"{name}.ref"]], n, n_ref)
            unrel = arrays[f"{name}.unreliable"].astype(bool)
        out[name] = Shape(name, mesh, ref=ref, sym=arrays[f"{name}.sym"].astype(np.int64), unreliable=unrel)
    return out
