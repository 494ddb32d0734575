"""Farthest-point sampling."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from topomatch._kernels import farthest_points
from topomatch._validation import check_random_state
from topomatch.typing import FloatArray, IndexArray, RandomState

__all__ = ["farthest_point_sampling"]


def farthest_point_sampling(
    n_samples: int,
    *,
    points: FloatArray | None = None,
    distance_fn: Callable[[int], FloatArray] | None = None,
    n_points: int | None = None,
    first: int | None = None,
    random_state: RandomState = None,
) -> IndexArray:
    """Greedy farthest-point sampling in Euclidean space or under any metric.

    Parameters
    ----------
    n_samples : int
        Number of samples.
    points : ndarray, shape (n_points, d), optional
        Points in a Euclidean space (3D positions, a spectral embedding...).
    distance_fn : callable, optional
        ``distance_fn(i)`` returns the distances from point ``i`` to all points, shape
        (n_points,), e.g. a geodesic solver row. Give ``n_points`` with it.
    first : int, optional
        First sample; drawn with ``random_state`` when omitted.
    random_state : int, Generator or None

    Returns
    -------
    ndarray, shape (n_samples,)
        Sample indices in selection order.
    """
    if (points is None) == (distance_fn is None):
        raise ValueError("give exactly one of points or distance_fn")
    if points is not None:
        cols = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)
        n = cols.shape[1]
        if not np.isfinite(cols).all():
            raise ValueError("farthest_point_sampling: points must be finite")
    elif n_points is None:
        raise ValueError("n_points is required with distance_fn")
    else:
        n = n_points
    if not 1 <= n_samples <= n:
        raise ValueError(f"n_samples must lie in [1, {n}], got {n_samples}")
    rng = check_random_state(random_state)
    cur = int(rng.integers(n)) if first is None else int(first)
    out = np.empty(n_samples, dtype=np.int64)
    if points is not None:
        if not 0 <= cur < n:
            raise ValueError(f"first must lie in [0, {n}), got {first}")
        farthest_points(cols, cur, out)  # compiled, one pass per sample, no temporaries
        return out
    dmin = np.full(n, np.inf)
    for k in range(n_samples):
        out[k] = cur
        dmin = np.minimum(dmin, distance_fn(cur))
        dmin[out[: k + 1]] = -1.0
        cur = int(np.argmax(dmin))
    return out
