"""Correspondence metrics as pure functions on arrays (no I/O, no plotting).

Conventions: the map ``p2p_21`` gives each vertex of shape 2 (the *mapped* shape) a
vertex of shape 1, or ``-1``; errors are geodesic distances on shape 1 divided by
``sqrt(area(shape 1))``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import sparse

from topomatch.typing import BoolArray, FloatArray, IndexArray

__all__ = [
    "SHREC16_THRESHOLDS",
    "area_matched",
    "auc",
    "cumulative_curve",
    "error_queries",
    "pointwise_errors",
    "reduce_min",
]

SHREC16_THRESHOLDS = np.round(np.arange(26) * 0.01, 10)
"""The track's thresholds: 0, 0.01, ..., 0.25 (as in the SHREC'16 comparison script)."""


def error_queries(p2p_21: IndexArray, gt_21: sparse.csr_matrix) -> tuple[IndexArray, IndexArray, IndexArray]:
    """Distance queries needed to score a map.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
        Vertex of shape 1 for each vertex of shape 2, ``-1`` = unmatched.
    gt_21 : scipy.sparse.csr_matrix, shape (n2, n1)
        Acceptable vertices of shape 1 for each vertex of shape 2 (empty row = excluded).

    Returns
    -------
    rows : ndarray, shape (n_queries,)
        Vertex of shape 2 each query belongs to.
    gt : ndarray, shape (n_queries,)
        A ground-truth vertex of shape 1 (the distance field's source).
    pred : ndarray, shape (n_queries,)
        The predicted vertex of shape 1.
    """
    gt_21 = sparse.csr_matrix(gt_21)
    p2p_21 = np.asarray(p2p_21, dtype=np.int64)
    if gt_21.shape[0] != len(p2p_21):
        raise ValueError(f"p2p_21 has {len(p2p_21)} entries but the ground truth has {gt_21.shape[0]} rows")
    counts = np.diff(gt_21.indptr)
    rows = np.repeat(np.arange(len(p2p_21)), counts)
    gt = gt_21.indices.astype(np.int64)
    pred = p2p_21[rows]
    keep = pred >= 0
    return rows[keep], gt[keep], pred[keep]


def reduce_min(n2: int, rows: IndexArray, dist: FloatArray) -> FloatArray:
    """Minimum distance per vertex of shape 2; ``nan`` where there is no query.

    Returns
    -------
    ndarray, shape (n2,)
    """
    out = np.full(n2, np.inf)
    np.minimum.at(out, rows, dist)
    out[np.isinf(out) & ~np.isin(np.arange(n2), rows)] = np.nan
    return out


def pointwise_errors(
    p2p_21: IndexArray,
    gt_21: sparse.csr_matrix,
    pair_distances: Callable[[IndexArray, IndexArray], FloatArray],
    normalization: float,
) -> FloatArray:
    """Normalised geodesic error of every vertex of shape 2.

    ``err(x) = min_{y* in gt(x)} d_1(y*, p2p_21[x]) / normalization``.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
    gt_21 : scipy.sparse.csr_matrix, shape (n2, n1)
    pair_distances : callable
        ``pair_distances(a, b)`` returns ``d_1(a[i], b[i])``, e.g.
        ``GeodesicSolver.pair_distances``.
    normalization : float
        Usually ``sqrt(area(shape 1))``.

    Returns
    -------
    ndarray, shape (n2,)
        ``nan`` for excluded (no ground truth) and unmatched vertices.
    """
    rows, gt, pred = error_queries(p2p_21, gt_21)
    d = pair_distances(gt, pred)
    return reduce_min(len(p2p_21), rows, d) / normalization


def cumulative_curve(errors: FloatArray, thresholds: FloatArray = SHREC16_THRESHOLDS) -> FloatArray:
    """Fraction of scored vertices with error ``<= t`` for each threshold.

    Parameters
    ----------
    errors : ndarray, shape (n,)
        ``nan`` entries (excluded / unmatched) are ignored.
    thresholds : ndarray, shape (n_thresholds,)

    Returns
    -------
    ndarray, shape (n_thresholds,)
        In [0, 1]; ``nan`` if nothing was scored.
    """
    e = np.asarray(errors, dtype=np.float64)
    e = e[~np.isnan(e)]
    if e.size == 0:
        return np.full(len(thresholds), np.nan)
    e = np.sort(e)
    return np.searchsorted(e, np.asarray(thresholds), side="right") / e.size


def auc(curve: FloatArray, thresholds: FloatArray = SHREC16_THRESHOLDS) -> float:
    """Area under a cumulative curve, normalised to [0, 1] over the threshold range (trapezoid rule)."""
    t = np.asarray(thresholds, dtype=np.float64)
    return float(np.trapezoid(np.asarray(curve, dtype=np.float64), t) / (t[-1] - t[0]))


def area_matched(p2p_21: IndexArray, vertex_areas_1: FloatArray, mask_2: BoolArray | None = None) -> float:
    """Fraction of shape 1's area covered by the image of the map.

    The lumped areas of the distinct vertices of shape 1 hit by ``p2p_21`` (restricted
    to the vertices of shape 2 in ``mask_2`` when given), over the total area.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
    vertex_areas_1 : ndarray, shape (n1,)
    mask_2 : ndarray of bool, shape (n2,), optional
    """
    p = np.asarray(p2p_21)
    if mask_2 is not None:
        p = p[mask_2]
    hit = np.unique(p[p >= 0])
    return float(vertex_areas_1[hit].sum() / vertex_areas_1.sum())
