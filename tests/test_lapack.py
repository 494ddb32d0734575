"""The GIL-free Cholesky solve (topomatch._lapack) against SciPy's, bit for bit."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import scipy.linalg
from scipy.linalg import cho_factor, cho_solve

from topomatch._lapack import cholesky_solve


def _spd(n: int, seed: int) -> np.ndarray:
    A = np.random.default_rng(seed).standard_normal((n, n))
    return A @ A.T + n * np.eye(n)


@pytest.mark.parametrize("n", [1, 7, 120, 451])
def test_cholesky_solve_equals_scipy_bit_for_bit(n):
    H = _spd(n, n)
    rng = np.random.default_rng(n + 1)
    for b in (rng.standard_normal(n), rng.standard_normal((n, 3))):
        want = cho_solve(cho_factor(H.copy(), lower=False, check_finite=False), b, check_finite=False)
        for a in (H.copy(), np.array(H, order="F")):  # C order (copied) and LAPACK's order (in place)
            got = cholesky_solve(a, b)
            assert got.shape == b.shape
            np.testing.assert_array_equal(got, want)
        if n > 1:  # (scipy.linalg.solve divides for a 1 x 1 system)
            np.testing.assert_array_equal(cholesky_solve(np.array(H, order="F"), b), scipy.linalg.solve(H, b, assume_a="pos"))


def test_cholesky_solve_reads_the_upper_triangle_only():
    H = _spd(30, 3)
    b = np.arange(30.0)
    junk = np.triu(H) + np.tril(np.full_like(H, 1e6), -1)  # garbage below the diagonal
    np.testing.assert_array_equal(cholesky_solve(junk, b), cholesky_solve(H.copy(), b))


def test_cholesky_solve_on_threads_gives_the_same_answers():
    mats = [_spd(200, s) for s in range(6)]
    b = np.ones(200)
    alone = [cholesky_solve(np.asfortranarray(H), b) for H in mats]
    with ThreadPoolExecutor(2) as ex:
        threaded = list(ex.map(lambda H: cholesky_solve(np.asfortranarray(H), b), mats))
    for x, y in zip(alone, threaded):
        np.testing.assert_array_equal(x, y)


def test_cholesky_solve_rejects_bad_input():
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        cholesky_solve(-np.eye(4), np.ones(4))
    with pytest.raises(ValueError, match="must be"):
        cholesky_solve(np.eye(4), np.ones(5))
    with pytest.raises(ValueError, match="must be"):
        cholesky_solve(np.ones((4, 3)), np.ones(4))


def test_cholesky_solve_falls_back_to_scipy_with_the_same_answers(monkeypatch):
    import topomatch._lapack as lapack

    H = _spd(40, 9)
    b = np.random.default_rng(9).standard_normal((40, 2))
    compiled = cholesky_solve(H.copy(), b)
    monkeypatch.setattr(lapack, "_compiled", lambda: None)  # as where SciPy's LAPACK table is not reachable
    np.testing.assert_array_equal(lapack.cholesky_solve(H.copy(), b), compiled)


def test_banded_cholesky_solve_equals_scipy_and_falls_back_to_it(monkeypatch):
    import topomatch._lapack as lapack

    n, kd = 60, 7
    H = _spd(n, 11)
    H[np.abs(np.subtract.outer(np.arange(n), np.arange(n))) > kd] = 0.0  # a band matrix ...
    H += n * np.eye(n)  # ... still positive definite
    ab = np.zeros((kd + 1, n), order="F")
    for j in range(n):
        for i in range(max(0, j - kd), j + 1):
            ab[kd + i - j, j] = H[i, j]
    b = np.random.default_rng(12).standard_normal(n)
    want = scipy.linalg.cho_solve_banded((scipy.linalg.cholesky_banded(ab.copy(), lower=False), False), b)
    np.testing.assert_array_equal(lapack.banded_cholesky_solve(ab.copy(order="F"), b), want)
    np.testing.assert_allclose(want, np.linalg.solve(H, b), rtol=1e-12)
    monkeypatch.setattr(lapack, "_compiled", lambda name="": None)  # as where SciPy's LAPACK table is not reachable
    np.testing.assert_array_equal(lapack.banded_cholesky_solve(ab.copy(order="F"), b), want)
