"""Operations on point-to-point maps: composition, transfer, inversion, coverage.

Direction suffixes follow the project convention: ``p2p_21`` has one entry per vertex
of shape 2 holding a vertex of shape 1, ``-1`` where unmatched.
"""

from __future__ import annotations

import numpy as np

from topomatch.maps.knn import nearest_neighbors
from topomatch.typing import FloatArray, IndexArray

__all__ = ["compose_p2p", "coverage", "invert_p2p", "transfer_function"]


def _as_map(p2p: object, name: str) -> IndexArray:
    p = np.asarray(p2p)
    if p.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {p.shape}")
    if p.size and not np.issubdtype(p.dtype, np.integer):
        raise TypeError(f"{name} must hold integer vertex indices, got dtype {p.dtype}")
    return p.astype(np.int64)


def compose_p2p(p2p_21: IndexArray, p2p_32: IndexArray) -> IndexArray:
    """Compose two maps into ``p2p_31``: shape 3 -> shape 2 -> shape 1.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
    p2p_32 : ndarray, shape (n3,)

    Returns
    -------
    ndarray, shape (n3,)
        ``-1`` where either map is unmatched.
    """
    a = _as_map(p2p_21, "p2p_21")
    b = _as_map(p2p_32, "p2p_32")
    if b.size and b.max() >= len(a):
        raise ValueError(f"p2p_32 points to vertex {b.max()} but shape 2 has {len(a)} vertices")
    out = np.full(len(b), -1, dtype=np.int64)
    ok = b >= 0
    out[ok] = a[b[ok]]
    return out


def transfer_function(p2p_21: IndexArray, f_1: FloatArray, fill: float = np.nan) -> FloatArray:
    """Pull a function on shape 1 back to shape 2 through ``p2p_21``.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
    f_1 : ndarray, shape (n1,) or (n1, d)
    fill : float
        Value at unmatched vertices.

    Returns
    -------
    ndarray, shape (n2,) or (n2, d)
    """
    p = _as_map(p2p_21, "p2p_21")
    f = np.asarray(f_1)
    if p.size and p.max() >= len(f):
        raise ValueError(f"p2p_21 points to vertex {p.max()} but f_1 has {len(f)} rows")
    out = np.full((len(p), *f.shape[1:]), fill, dtype=np.result_type(f.dtype, np.float64))
    ok = p >= 0
    out[ok] = f[p[ok]]
    return out


def invert_p2p(p2p_21: IndexArray, n_1: int, embedding_1: FloatArray) -> IndexArray:
    """Invert ``p2p_21`` into a map ``p2p_12`` where it can.

    Each vertex of shape 1 hit by ``p2p_21`` gets one of its preimages (the first);
    every other vertex of shape 1 gets the preimage of the nearest hit vertex, nearest
    in the embedding ``embedding_1`` of shape 1.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
    n_1 : int
        Number of vertices of shape 1.
    embedding_1 : ndarray, shape (n1, d)
        Coordinates of shape 1's vertices in any space (3-D positions, a spectral
        embedding); distances in it decide the fill-in.

    Returns
    -------
    ndarray, shape (n1,)
    """
    p = _as_map(p2p_21, "p2p_21")
    emb = np.asarray(embedding_1, dtype=np.float64)
    if emb.ndim != 2 or emb.shape[0] != n_1:
        raise ValueError(f"embedding_1 must have shape ({n_1}, d), got {emb.shape}")
    ok = np.flatnonzero(p >= 0)
    if ok.size == 0:
        raise ValueError("p2p_21 matches no vertex; nothing to invert")
    order = ok[np.argsort(p[ok], kind="stable")]
    hit, first = np.unique(p[order], return_index=True)
    out = np.full(n_1, -1, dtype=np.int64)
    out[hit] = order[first]
    miss = np.flatnonzero(out < 0)
    if miss.size:
        nn = nearest_neighbors(emb[hit], emb[miss])
        out[miss] = out[hit[nn]]
    return out


def coverage(p2p_21: IndexArray, n_1: int, weights_1: FloatArray | None = None) -> float:
    """Fraction of shape 1 (by vertex count, or by ``weights_1``) hit by the map.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
    n_1 : int
    weights_1 : ndarray, shape (n1,), optional
        E.g. vertex areas.

    Returns
    -------
    float in [0, 1]
    """
    p = _as_map(p2p_21, "p2p_21")
    hit = np.zeros(n_1, dtype=bool)
    hit[p[p >= 0]] = True
    if weights_1 is None:
        return float(hit.mean()) if n_1 else 0.0
    w = np.asarray(weights_1, dtype=np.float64)
    if w.shape != (n_1,):
        raise ValueError(f"weights_1 must have shape ({n_1},), got {w.shape}")
    return float(w[hit].sum() / w.sum()) if w.sum() > 0 else 0.0
