"""All-pairs comparison on kid00 low res: heat method and Dijkstra against exact geodesics.

Uses the exact all-pairs matrix (computed once and cached by
``topomatch.evaluation.scoring.exact_distance_matrix``; about 2.4 h on one busy core) and
compares every pair farther apart than 1% of the diameter.

    TOPOMATCH_CACHE_DIR=~/.cache/topomatch python benchmarks/geodesic_allpairs_kid00.py [--data DIR]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from topomatch.datasets.topkids import load_topkids
from topomatch.evaluation.scoring import exact_distance_matrix


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA") or str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    args = ap.parse_args()
    shape = load_topkids(args.data, "low")["kid00"]
    t0 = time.perf_counter()
    ex = exact_distance_matrix(shape)
    print(f"exact matrix {ex.shape} loaded/computed in {time.perf_counter() - t0:.1f} s")
    diam = float(ex.max())
    for kind in ("heat", "dijkstra"):
        solver = shape.mesh.geodesic_solver(kind)
        t0 = time.perf_counter()
        rel_sum = 0.0
        signed_sum = 0.0
        abs_sum = 0.0
        count = 0
        rel_max = 0.0
        abs_max = 0.0
        hist = np.zeros(6)
        edges = np.array([0.005, 0.01, 0.02, 0.05, 0.1])
        for rows, d in solver.iter_rows(np.arange(shape.n_vertices)):
            e = ex[rows].astype(np.float64)
            far = e > 0.01 * diam
            r = np.abs(d[far] - e[far]) / e[far]
            rel_sum += r.sum()
            signed_sum += ((d[far] - e[far]) / e[far]).sum()
            count += far.sum()
            rel_max = max(rel_max, float(r.max(initial=0)))
            a = np.abs(d - e)
            abs_sum += a.sum()
            abs_max = max(abs_max, float(a.max()))
            hist += np.bincount(np.searchsorted(edges, r), minlength=6)
        n_all = shape.n_vertices**2
        wall = time.perf_counter() - t0
        frac = np.cumsum(hist)[:-1] / hist.sum()
        print(
            f"{kind:9s} all pairs ({wall:.0f} s): relative error mean {100 * rel_sum / count:.2f}% (signed {100 * signed_sum / count:+.2f}%), "
            f"max {100 * rel_max:.1f}%; |error|/diameter mean {100 * abs_sum / n_all / diam:.3f}% max {100 * abs_max / diam:.2f}%; "
            + ", ".join(f"<= {100 * t:g}%: {100 * f:.1f}% of pairs" for t, f in zip(edges, frac))
        )


if __name__ == "__main__":
    main()
