"""Exact nearest neighbours in feature or spectral space (faiss when available)."""

from __future__ import annotations

import numpy as np

from topomatch.typing import FloatArray

__all__ = ["nearest_neighbors"]


def nearest_neighbors(reference: FloatArray, queries: FloatArray, *, k: int = 1, return_distances: bool = False):
    """Exact Euclidean k-nearest neighbours of ``queries`` among ``reference``.

    Uses faiss's brute-force inner-product index (float32) when installed, which was
    4-25x faster than scikit-learn or cKDTree at 10-60K points in d >= 30, and falls
    back to scikit-learn.

    Parameters
    ----------
    reference : ndarray, shape (n_ref, d)
    queries : ndarray, shape (n_queries, d)
    k : int

    Returns
    -------
    indices : ndarray, shape (n_queries,) if k == 1 else (n_queries, k)
    distances : ndarray, same shape (only if ``return_distances``)
    """
    ref = np.ascontiguousarray(reference, dtype=np.float32)
    qry = np.ascontiguousarray(queries, dtype=np.float32)
    if ref.ndim != 2 or qry.ndim != 2 or ref.shape[1] != qry.shape[1]:
        raise ValueError(f"reference and queries must be (n, d) with equal d, got {ref.shape} and {qry.shape}")
    try:
        import faiss

        index = faiss.IndexFlatL2(ref.shape[1])
        index.add(ref)
        d2, idx = index.search(qry, k)
        dist = np.sqrt(np.maximum(d2, 0.0))
    except ImportError:  # pragma: no cover
        from sklearn.neighbors import NearestNeighbors

        nn = NearestNeighbors(n_neighbors=k, algorithm="brute").fit(ref)
        dist, idx = nn.kneighbors(qry)
    idx = idx.astype(np.int64)
    if k == 1:
        idx, dist = idx[:, 0], dist[:, 0]
    return (idx, dist.astype(np.float64)) if return_distances else idx
