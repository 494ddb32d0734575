"""Geodesic solvers on TOPKIDS kid00: accuracy against exact MMP geodesics, and speed.

Prints, for low and high resolution, the heat method's and Dijkstra's error against
exact distances from random sources (mean and max relative error over targets farther
than 1% of the geodesic diameter, mean absolute error / diameter), and milliseconds per
source for each solver (median of repeats), with ratios to potpourri3d's heat solver
measured in the same run.

    python benchmarks/bench_geodesics.py [--data DIR] [--sources 20] [--resolution low high]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from topomatch.datasets.topkids import load_topkids
from topomatch.mesh import make_geodesic_solver


def timed(fn, repeats=3):
    ts = []
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return out, float(np.median(ts))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA") or str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ap.add_argument("--sources", type=int, default=20)
    ap.add_argument("--resolution", nargs="+", default=["low", "high"])
    ap.add_argument("--t-scale", type=float, nargs="+", default=[1.0])
    args = ap.parse_args()
    for res in args.resolution:
        shape = load_topkids(args.data, res)["kid00"]
        V, F = shape.mesh.vertices, shape.mesh.faces
        rng = np.random.default_rng(0)
        src = rng.choice(len(V), args.sources, replace=False)
        print(f"\n== kid00 {res} res: {len(V)} vertices, {args.sources} random sources ==")
        t0 = time.perf_counter()
        exact = make_geodesic_solver(V, F, "exact")
        ex = exact.distances_from(src)
        t_exact = (time.perf_counter() - t0) / len(src)
        print(f"exact (MMP, pygeodesic): {1e3 * t_exact:.0f} ms per source; cleaning: {exact.cleaning or 'none'}")
        diam = float(ex[np.isfinite(ex)].max())
        far = ex > 0.01 * diam

        def report(name, d, per_source_ms, ex=ex, far=far, diam=diam):
            rel = np.abs(d[far] - ex[far]) / ex[far]
            bias = float(np.mean((d[far] - ex[far]) / ex[far]))
            print(
                f"{name:24s} rel. error mean {100 * rel.mean():5.2f}%  median {100 * np.median(rel):5.2f}%  p95 {100 * np.quantile(rel, 0.95):5.2f}%  "
                f"max {100 * rel.max():6.2f}%  signed mean {100 * bias:+5.2f}%  |err|/diam mean {100 * np.mean(np.abs(d - ex)) / diam:.3f}% max {100 * np.max(np.abs(d - ex)) / diam:.3f}%  "
                f"{per_source_ms:7.2f} ms/source"
            )
            return per_source_ms

        for ts in args.t_scale:
            from topomatch.mesh.geodesics import HeatGeodesicSolver

            t0 = time.perf_counter()
            heat = HeatGeodesicSolver(V, F, t_scale=ts)
            setup = time.perf_counter() - t0
            d = heat.distances_from(src)
            block = np.arange(min(len(V), 20 * heat.batch_size()))
            _, t = timed(lambda heat=heat, block=block: [heat.distances_from(b) for b in np.array_split(block, max(1, len(block) // heat.batch_size()))], 3)
            ms_heat = report(f"heat (ours, t={ts:g}h^2)", d, 1e3 * t / len(block))
            print(f"{'':24s} setup {setup:.2f} s, batch {heat.batch_size()} sources, {heat.n_flips} intrinsic flips")
        dj = make_geodesic_solver(V, F, "dijkstra")
        d = dj.distances_from(src)
        _, t = timed(lambda dj=dj: dj.distances_from(np.arange(200)), 3)
        report("dijkstra (edge graph)", d, 1e3 * t / 200)
        try:
            import potpourri3d as pp3d

            s = pp3d.MeshHeatMethodDistanceSolver(V, F)
            d = np.stack([s.compute_distance(int(i)) for i in src])
            _, t = timed(lambda s=s: [s.compute_distance(int(i)) for i in range(50)], 3)
            ms_pp = report("potpourri3d heat", d, 1e3 * t / 50)
            print(f"ratio: our heat is {ms_pp / ms_heat:.1f}x faster per source than potpourri3d's")
        except ImportError:
            pass


if __name__ == "__main__":
    main()
