"""The registration's Cholesky solves: SciPy's wrappers against ``topomatch._lapack.cholesky_solve``.

Both run the same LAPACK routines (``dpotrf`` + ``dpotrs``) of SciPy's own LAPACK; SciPy's
wrappers hold the GIL while they run, ``cholesky_solve`` calls them from numba without
it. Printed per system size (the registration's dense position solve, 450 unknowns; the
functional map's at k = 50, 2,500 unknowns): milliseconds per solve on one thread, then
the throughput of two threads each solving as many systems (x2.0 = the two threads ran
side by side; x1.0 = one waited for the other), and whether the answers are equal bit
for bit. One BLAS thread throughout (as in the registrations' threads).

    python benchmarks/bench_lapack.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import threading
from collections.abc import Callable

import numpy as np
import scipy.linalg
from _common import median_seconds
from threadpoolctl import threadpool_limits

from topomatch._lapack import cholesky_solve


def _scipy_solve(H: np.ndarray, b: np.ndarray) -> np.ndarray:
    if len(H) > 1000:  # solve_fmap's call before session 35
        return scipy.linalg.solve(H, b, assume_a="pos")
    # the registration's call before session 35 (a C-ordered matrix)
    return scipy.linalg.cho_solve(scipy.linalg.cho_factor(H.copy(), lower=False, overwrite_a=True, check_finite=False), b, check_finite=False)


def _ours(H: np.ndarray, b: np.ndarray) -> np.ndarray:
    return cholesky_solve(np.array(H, order="F"), b)


def _one_and_two(fn: Callable[[np.ndarray, np.ndarray], np.ndarray], H: np.ndarray, b: np.ndarray, count: int, repeat: int) -> tuple[float, float]:
    """Milliseconds per solve on one thread, and the speed-up of two threads each doing the same work."""

    def work() -> None:
        for _ in range(count):
            fn(H, b)

    def both() -> None:
        threads = [threading.Thread(target=work) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()

    work()  # compile / warm up
    one = median_seconds(work, repeat)[0]
    two = median_seconds(both, repeat)[0]
    return 1e3 * one / count, 2 * one / two


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    print(f"{os.cpu_count()} CPUs; medians of {args.repeat}; one BLAS thread")
    print(f"{'unknowns':>8s}  {'ms per solve scipy / ours (ratio)':36s}  {'two threads: speed-up scipy / ours':36s}  equal")
    with threadpool_limits(1):
        for n, count in ((450, 200), (2500, 4)):
            A = rng.standard_normal((n, n))
            H = A @ A.T + n * np.eye(n)
            b = rng.standard_normal((n, 3)) if n < 1000 else rng.standard_normal(n)
            equal = bool(np.array_equal(_scipy_solve(H, b), _ours(H, b)))
            row = [_one_and_two(fn, H, b, count, args.repeat) for fn in (_scipy_solve, _ours)]
            (ms_s, sp_s), (ms_o, sp_o) = row
            print(f"{n:8d}  {ms_s:8.2f} / {ms_o:6.2f} (x{ms_o / ms_s:.2f}){'':13s}  x{sp_s:.2f} / x{sp_o:.2f}{'':23s}  {equal}")


if __name__ == "__main__":
    main()
