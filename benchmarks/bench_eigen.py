"""Laplacian eigenbasis on TOPKIDS kid00: time and memory of our shift-invert solve
(CHOLMOD through cholespy) against scipy's default shift-invert (SuperLU) in the same run.

    python benchmarks/bench_eigen.py [--data DIR] [--k 100 200 300] [--resolution low high]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from scipy.sparse import linalg as sla

from topomatch._memory import PeakMemory
from topomatch.datasets.topkids import load_topkids
from topomatch.mesh.spectral import laplacian_eigenbasis


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA") or str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ap.add_argument("--k", type=int, nargs="+", default=[100, 200, 300])
    ap.add_argument("--resolution", nargs="+", default=["low", "high"])
    ap.add_argument("--no-baseline", action="store_true")
    args = ap.parse_args()
    for res in args.resolution:
        mesh = load_topkids(args.data, res)["kid00"].mesh
        t0 = time.perf_counter()
        L, M = mesh.laplacian("robust")
        t_lap = time.perf_counter() - t0
        print(f"\nkid00 {res} res ({mesh.n_vertices} vertices): robust Laplacian {t_lap:.2f} s")
        for k in args.k:
            with PeakMemory() as mem:
                t0 = time.perf_counter()
                b = laplacian_eigenbasis(L, M, k)
                t_ours = time.perf_counter() - t0
            resid = np.linalg.norm(L @ b.evecs - (M @ b.evecs) * b.evals, axis=0).max()
            line = f"  k={k:3d}: ours {t_ours:6.1f} s (peak RSS {mem.peak_mb:.0f} MB, max residual {resid:.1e})"
            if not args.no_baseline:
                t0 = time.perf_counter()
                w, _ = sla.eigsh(L, k=k, M=M, sigma=-1e-8 * float(np.mean(L.diagonal() / M.diagonal())), which="LM")
                t_base = time.perf_counter() - t0
                line += f"; scipy SuperLU {t_base:6.1f} s; ratio {t_base / t_ours:.2f}x; max |dlambda|/lambda_k {np.max(np.abs(np.sort(w) - b.evals)) / b.evals[-1]:.1e}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
