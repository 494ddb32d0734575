"""Small helpers shared by the benchmark scripts (run as ``python benchmarks/<script>.py``)."""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

from topomatch.datasets.base import ShapeCollection
from topomatch.datasets.topkids import load_topkids
from topomatch.evaluation.protocols import Protocol, get_protocol
from topomatch.mesh import TriangleMesh


def median_seconds(fn, repeat: int, *args):
    """Call ``fn(*args)`` ``repeat`` times; the median wall time in seconds and the last result."""
    times, res = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = fn(*args)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), res


def emit_row(row: dict, path: str | None) -> None:
    """Print ``row`` as one JSON line and, when ``path`` is given, append it there."""
    line = json.dumps(row)
    print(line, flush=True)
    if path:
        with open(path, "a") as fh:
            fh.write(line + "\n")


def topkids_targets_parser(description: str, json_help: str) -> argparse.ArgumentParser:
    """Arguments of the scripts that match kid00 onto given TOPKIDS targets.

    ``targets``, ``--data`` (default ``$TOPOMATCH_DATA``), ``--geodesic`` and ``--json``;
    a script adds its own.
    """
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("targets", nargs="+", help="target shapes, e.g. kid01 kid02")
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--geodesic", default="dijkstra", choices=["dijkstra", "heat", "exact"])
    ap.add_argument("--json", default=None, help=json_help)
    return ap


def fit_shapes(coll: ShapeCollection) -> list[str]:
    """The shapes ``topomatch bench`` fits a trained matcher on: the reference and the training split present."""
    return coll.present([coll.reference, *coll.splits.get("train", [])])


def load_topkids25(ap: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[ShapeCollection, Protocol, str, TriangleMesh]:
    """The low-res TOPKIDS collection, the ``topkids25`` protocol, the reference's name and mesh."""
    if not args.data:
        ap.error("give --data or set TOPOMATCH_DATA")
    coll = load_topkids(args.data, "low")
    return coll, get_protocol("topkids25"), coll.reference, coll[coll.reference].mesh
