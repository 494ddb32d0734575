"""Score correspondence files produced by any method (``topomatch evaluate``)."""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from topomatch.evaluation.benchmark import (
    BenchmarkConfig,
    build_summary,
    load_collection,
    resolve_protocols,
    score_stored_maps,
)
from topomatch.evaluation.rundir import RunDir, write_json
from topomatch.io import read_p2p, read_shrec16_map
from topomatch.typing import IndexArray, PathType

__all__ = ["evaluate_submission", "find_map_file", "read_map_file"]

logger = logging.getLogger(__name__)

_SUFFIXES = (".txt", ".map", ".corr", ".vts", ".npy", ".npz", "")


def find_map_file(folder: Path, target: str, source: str) -> Path | None:
    """The file holding the map of ``target``'s vertices onto ``source``.

    Accepted names: ``<target>-<source>``, ``<target>_<source>``, ``<target>_to_<source>``
    with suffix ``.txt``, ``.map``, ``.corr``, ``.vts``, ``.npy``, ``.npz`` or none.
    """
    for stem in (f"{target}-{source}", f"{target}_{source}", f"{target}_to_{source}"):
        for suf in _SUFFIXES:
            p = folder / f"{stem}{suf}"
            if p.is_file():
                return p
    return None


def read_map_file(path: PathType, n_target: int, n_source: int, source_faces: IndexArray) -> IndexArray:
    """Read a map file of any supported kind into ``p2p_21`` (zero-based, ``-1`` = unmatched).

    ``.npy`` holds zero-based indices; ``.npz`` is a map file of a run directory
    (``RUN/maps/<method>/<pair>.npz``, its ``p2p_21`` array), so a run's maps can be
    re-scored, e.g. without symmetric credit. Text files with four columns are SHREC'16
    submissions (``triangle w1 w2 w3``); with one column, one-based vertex indices.
    """
    path = Path(path)
    if path.suffix in (".npy", ".npz"):
        try:
            if path.suffix == ".npz":
                with np.load(path, allow_pickle=False) as z:
                    if "p2p_21" not in z.files:
                        raise ValueError(f"{path}: a .npz map needs a 'p2p_21' array (found {', '.join(z.files) or 'none'})")
                    p = z["p2p_21"]
            else:
                p = np.load(path, allow_pickle=False)
        except (OSError, EOFError) as err:
            raise ValueError(f"{path}: cannot read ({err})") from None
        if p.shape != (n_target,) or not np.issubdtype(p.dtype, np.integer):
            raise ValueError(f"{path}: expected {n_target} integer zero-based indices, found shape {p.shape} dtype {p.dtype}")
        if p.size and (p.min() < -1 or p.max() >= n_source):
            raise ValueError(f"{path}: indices outside [-1, {n_source - 1}]")
        return p.astype(np.int64)
    with open(path, encoding="ascii", errors="replace") as fh:
        first = ""
        for line in fh:
            if line.strip() and not line.lstrip().startswith("#"):
                first = line
                break
    ncol = len(first.split())
    if ncol == 4:
        return read_shrec16_map(path, source_faces, n_target)  # type: ignore[return-value]
    if ncol == 1 or (ncol > 4 and "\n" not in first.strip()):
        return read_p2p(path, n_target, n_source)
    raise ValueError(f"{path}: cannot tell the format (first line has {ncol} columns; expected 1 or 4)")


def evaluate_submission(
    folder: PathType,
    *,
    protocol: str,
    data_dir: PathType | None = None,
    resolution: str = "low",
    split: str | None = None,
    name: str = "submission",
    out: PathType,
    symmetric: bool | None = None,
    geodesics: list[str] | None = None,
    jobs: int = 1,
    on_event: Callable[[str], None] | None = None,
) -> dict:
    """Score a folder of map files under ``protocol`` into a run directory.

    Missing files are recorded as failed pairs (and reported); unreadable files raise.

    Returns
    -------
    dict
        The run summary.
    """
    say = on_event or (lambda s: logger.info("%s", s))
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such submission folder")
    if not re.fullmatch(r"[A-Za-z0-9_.+]+", name):
        raise ValueError(f"method name {name!r} may only use letters, digits, '_', '.', '+'")
    config = BenchmarkConfig(
        dataset="topkids",
        data_dir=str(Path(data_dir).resolve()) if data_dir else os.environ.get("TOPOMATCH_DATA"),
        resolution=resolution,
        protocols=[protocol],
        split=split,
        methods=[name],
        symmetric=symmetric,
        geodesics=geodesics,
        jobs=jobs,
        external=True,
    )
    config.validate()
    collection = load_collection(config)
    protocols = resolve_protocols(config)
    pair_sets = {p.name: p.pairs(collection, split) for p in protocols}
    run = RunDir(out)
    run.path.mkdir(parents=True, exist_ok=True)
    n_found = 0
    for pr in pair_sets[protocol]:
        f = find_map_file(folder, pr.target, pr.source)
        if f is None:
            run.save_failure(name, pr.id, f"no file for pair {pr.id} in {folder}", "", 0.0)
            continue
        tgt, src = collection[pr.target], collection[pr.source]
        p2p = read_map_file(f, tgt.n_vertices, src.n_vertices, src.mesh.faces)
        run.save_map(name, pr.id, p2p, seconds=float("nan"), peak_rss_mb=float("nan"), info={"file": str(f)})
        n_found += 1
    say(f"{n_found} of {len(pair_sets[protocol])} pair files found in {folder}")
    write_json(run.path / "manifest.json", {"config": {**config.__dict__}, "submission": str(folder.resolve()), "dataset": {"name": collection.name, "root": str(collection.root), "missing": collection.missing}})
    score_stored_maps(run, config, collection, protocols, pair_sets, say)
    return build_summary(run, config, protocols, pair_sets)
