"""Chance level of the shrec16 protocol, derived and measured.

For a map sending each vertex x of M to a uniformly random vertex y of N, the expected
curve is ``E[curve(t)] = mean_x P_y(min_{y*} d_N(y*, y) / sqrt(area N) <= t)``, computed
here from the geodesic distance rows of the ground-truth vertices; the expected AUC is
its trapezoid area over t = 0..0.25 divided by 0.25. The small-radius estimate is
``P ~ pi t^2``, giving ``pi 0.25^2 / 3 = 0.0654``. The script prints both beside the AUC
measured on random maps (without and with symmetric credit).

    python benchmarks/random_expectation.py [--data DIR] [--pairs 90]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from topomatch.datasets.base import ground_truth_21
from topomatch.datasets.topkids import load_topkids
from topomatch.evaluation.metrics import SHREC16_THRESHOLDS
from topomatch.evaluation.protocols import get_protocol
from topomatch.evaluation.scoring import score_maps, summarize


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA") or str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ap.add_argument("--pairs", type=int, default=90)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    coll = load_topkids(args.data, "low")
    p = get_protocol("shrec16")
    pairs = p.pairs(coll)[: args.pairs]
    t = SHREC16_THRESHOLDS
    expected = []
    by_source: dict[str, list] = {}
    for pr in pairs:
        by_source.setdefault(pr.source, []).append(pr)
    for src, prs in by_source.items():
        shape = coll[src]
        solver = shape.mesh.geodesic_solver("heat")
        norm = np.sqrt(shape.mesh.area)
        for pr in prs:
            g = ground_truth_21(coll[pr.target], shape).tocsr()
            rows = np.flatnonzero(np.diff(g.indptr) > 0)
            need = np.unique(g.indices)
            dmin = {}
            for batch, d in solver.iter_rows(need):
                for s, row in zip(batch, d):
                    dmin[int(s)] = row / norm
            frac = np.zeros(len(t))
            for x in rows:
                ys = g.indices[g.indptr[x] : g.indptr[x + 1]]
                dx = np.min(np.stack([dmin[int(y)] for y in ys]), axis=0)
                frac += np.searchsorted(np.sort(dx), t, side="right") / len(dx)
            curve = frac / len(rows)
            expected.append(np.trapezoid(curve, t) / (t[-1] - t[0]))
        shape.mesh.drop_caches()
    rng = np.random.default_rng(0)
    maps = {("random", pr.id): rng.integers(0, coll[pr.source].n_vertices, coll[pr.target].n_vertices) for pr in pairs}
    nosym = summarize(score_maps(coll, p.with_options(symmetric=False), maps, n_jobs=args.jobs), p)
    sym = summarize(score_maps(coll, p, maps, n_jobs=args.jobs), p)
    print(f"{len(pairs)} shrec16 low-res test pairs, heat geodesics")
    print(f"small-radius estimate pi*0.25^2/3        : {np.pi * 0.25**2 / 3:.4f}")
    print(f"derived expectation (distance rows), mean : {np.mean(expected):.4f} (pairs {np.min(expected):.4f}..{np.max(expected):.4f})")
    print(f"measured, random maps, no symmetric credit: {nosym['auc_mean']:.4f} (worst {nosym['auc_worst']:.4f}, best {nosym['auc_best']:.4f})")
    print(f"measured, random maps, symmetric credit   : {sym['auc_mean']:.4f}")


if __name__ == "__main__":
    main()
