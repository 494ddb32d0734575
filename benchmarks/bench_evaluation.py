"""Cost of scoring (matching excluded): the 90-pair shrec16 evaluation at low res and one
high-res pair, wall time and peak memory, against potpourri3d's heat solver on one group.

    python benchmarks/bench_evaluation.py [--data DIR] [--jobs 2] [--high-pair kid01-kid02]

The maps scored are random maps (their queries are as spread as a bad method's, the
worst case for the geodesic work; a good method's cost is the same since every
ground-truth vertex is a distance-field source either way).
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

import numpy as np

from topomatch._memory import PeakMemory
from topomatch.datasets.topkids import load_topkids
from topomatch.evaluation.protocols import PairSpec, get_protocol
from topomatch.evaluation.scoring import _score_group, score_maps, summarize
from topomatch.mesh.geodesics import GeodesicSolver


class Pp3dHeat(GeodesicSolver):
    """potpourri3d's heat method, one source at a time (the baseline)."""

    kind = "heat"

    def __init__(self, vertices, faces):
        import potpourri3d as pp3d

        self.n_vertices = len(vertices)
        self._s = pp3d.MeshHeatMethodDistanceSolver(vertices, faces)

    def distances_from(self, sources):
        return np.stack([self._s.compute_distance(int(i)) for i in sources])


def random_maps(coll, pairs, seed=0):
    rng = np.random.default_rng(seed)
    return {("random", p.id): rng.integers(0, coll[p.source].n_vertices, coll[p.target].n_vertices) for p in pairs}


def children_peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA") or str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--high-pair", default="kid01-kid02")
    ap.add_argument("--skip-high", action="store_true")
    args = ap.parse_args()

    low = load_topkids(args.data, "low")
    p = get_protocol("shrec16")
    pairs = p.pairs(low)
    maps = random_maps(low, pairs)
    with PeakMemory() as mem:
        t0 = time.perf_counter()
        scores = score_maps(low, p, maps, n_jobs=args.jobs)
        wall = time.perf_counter() - t0
    s = summarize(scores, p)
    print(f"shrec16 low res, {len(pairs)} pairs, symmetric credit, heat geodesics, {args.jobs} jobs: "
          f"{wall:.1f} s, peak RSS main {mem.peak_mb:.0f} MB, workers {children_peak_mb():.0f} MB (AUC of random maps {s['auc_mean']:.4f})")

    # baseline on one source group: our batched heat vs potpourri3d, same queries
    src = pairs[0].source
    group = [pr for pr in pairs if pr.source == src]
    shape = low[src]
    jobs = [("random", pr, low[pr.target], maps[("random", pr.id)]) for pr in group]
    t0 = time.perf_counter()
    ours = _score_group(shape, jobs, p, "heat", None)
    t_ours = time.perf_counter() - t0
    shape.mesh.__dict__["_geo_heat"] = Pp3dHeat(shape.mesh.vertices, shape.mesh.faces)
    t0 = time.perf_counter()
    base = _score_group(shape, jobs, p, "heat", None)
    t_base = time.perf_counter() - t0
    shape.mesh.drop_caches()
    d_auc = max(abs(a.auc - b.auc) for a, b in zip(ours, base))
    print(f"one source group ({src}, {len(group)} pairs, 1 process): ours {t_ours:.1f} s, potpourri3d {t_base:.1f} s, "
          f"ratio {t_base / t_ours:.1f}x; max AUC difference {d_auc:.4f}")

    if args.skip_high:
        return
    high = load_topkids(args.data, "high")
    pr = PairSpec.from_id(args.high_pair)
    m = random_maps(high, [pr])
    with PeakMemory() as mem:
        t0 = time.perf_counter()
        sc = score_maps(high, p, m, n_jobs=1)
        wall = time.perf_counter() - t0
    print(f"shrec16 high res, one pair {pr.id} ({high[pr.target].n_vertices} -> {high[pr.source].n_vertices} vertices): "
          f"{wall:.1f} s, peak RSS {mem.peak_mb:.0f} MB, {sc[0].n_scored} scored, {sc[0].n_excluded} excluded")


if __name__ == "__main__":
    main()
