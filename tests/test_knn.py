"""Exact nearest neighbours in feature space (maps.knn)."""

from __future__ import annotations

import numpy as np
import pytest

from topomatch.maps import knn
from topomatch.maps.knn import nearest_neighbors


def _brute(ref: np.ndarray, qry: np.ndarray) -> np.ndarray:
    return np.linalg.norm(qry[:, None, :] - ref[None, :, :], axis=-1)


@pytest.mark.parametrize("d", [1, 3, 30, 110])
def test_nearest_neighbors_match_float64_brute_force(d, monkeypatch):
    rng = np.random.default_rng(d)
    ref, qry = rng.standard_normal((700, d)), rng.standard_normal((450, d))
    D = _brute(ref, qry)
    monkeypatch.setattr(knn, "_BLOCK_ELEMENTS", 700 * 64)  # several blocks, a short last one
    idx, dist = nearest_neighbors(ref, qry, return_distances=True)
    assert idx.shape == dist.shape == (450,)
    rows = np.arange(450)
    # float32 scores: the neighbour is the float64 one but for near ties, never farther than rounding
    tol = 1e-5 * (1.0 + np.abs(ref).max() ** 2 * d)
    assert np.mean(idx == np.argmin(D, axis=1)) > 0.99
    assert np.all(D[rows, idx] ** 2 - D.min(axis=1) ** 2 <= tol)
    np.testing.assert_allclose(dist, D[rows, idx], rtol=1e-12)  # distances in float64
    idx5, dist5 = nearest_neighbors(ref, qry, k=5, return_distances=True)
    assert idx5.shape == dist5.shape == (450, 5)
    assert np.all(np.diff(dist5, axis=1) >= 0) and np.all([len(set(r)) == 5 for r in idx5])
    assert np.all(dist5**2 - np.sort(D, axis=1)[:, :5] ** 2 <= tol)
    np.testing.assert_allclose(dist5, D[rows[:, None], idx5], rtol=1e-12)


def test_nearest_neighbors_of_the_points_themselves():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((2000, 50)) * 1e-3  # small scales, as spectral embeddings
    np.testing.assert_array_equal(nearest_neighbors(x, x), np.arange(2000))


def test_nearest_neighbors_rejects_bad_input():
    a = np.zeros((5, 3))
    with pytest.raises(ValueError, match="equal d"):
        nearest_neighbors(a, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="equal d"):
        nearest_neighbors(np.zeros(5), a)
    for k in (0, 6, 1.5):
        with pytest.raises(ValueError, match="k must be"):
            nearest_neighbors(a, a, k=k)
    with pytest.raises(ValueError, match="k must be"):
        nearest_neighbors(np.zeros((0, 3)), a)
