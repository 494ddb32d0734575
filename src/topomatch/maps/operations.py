"""Operations on point-to-point maps: composition, transfer, inversion, coverage, folding.

Direction suffixes follow the project convention: ``p2p_21`` has one entry per vertex
of shape 2 holding a vertex of shape 1, ``-1`` where unmatched.
"""

from __future__ import annotations

import numpy as np

from topomatch.maps.knn import nearest_neighbors
from topomatch.mesh.geometry import face_normals
from topomatch.typing import FloatArray, IndexArray

__all__ = ["compose_p2p", "coverage", "folded_fraction", "invert_p2p", "transfer_function"]


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


def folded_fraction(
    p2p_21: IndexArray,
    vertices_1: FloatArray,
    normals_1: FloatArray,
    faces_2: IndexArray,
    face_areas_2: FloatArray | None = None,
) -> float:
    """Fraction of shape 2's area that the map turns over on shape 1.

    Each face of shape 2 whose three vertices map to three distinct vertices of shape 1
    has an image triangle there; the face is *turned over* when that triangle's normal
    (in the face's vertex order) points against shape 1's vertex normals at its corners
    (their sum). A map that follows the surfaces turns over only scattered faces; a
    region mapped with the wrong handedness or onto a folded place is turned over
    wholesale (attempt #135 in ``docs/flagship.md``). Faces with an unmatched vertex or a
    degenerate image are left out of both the count and the total.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
        A vertex of shape 1 for each vertex of shape 2 (``-1``: unmatched).
    vertices_1 : ndarray, shape (n1, 3)
    normals_1 : ndarray, shape (n1, 3)
        Shape 1's outward vertex normals.
    faces_2 : ndarray, shape (f2, 3)
        Shape 2's faces, consistently oriented.
    face_areas_2 : ndarray, shape (f2,), optional
        Weights of the faces (their areas); default: every face counts once.

    Returns
    -------
    float in [0, 1]
        ``0.0`` when no face has a proper image.
    """
    p = _as_map(p2p_21, "p2p_21")
    V = np.asarray(vertices_1, dtype=np.float64)
    N = np.asarray(normals_1, dtype=np.float64)
    F = np.asarray(faces_2, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or N.shape != V.shape:
        raise ValueError(f"vertices_1 and normals_1 must both have shape (n1, 3), got {V.shape} and {N.shape}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"faces_2 must have shape (f2, 3), got {F.shape}")
    if F.size and (F.min() < 0 or F.max() >= len(p)):
        raise ValueError(f"faces_2 index vertices outside the map's {len(p)} entries")
    if p.size and p.max() >= len(V):
        raise ValueError(f"p2p_21 points to vertex {p.max()} but shape 1 has {len(V)} vertices")
    w = np.ones(len(F)) if face_areas_2 is None else np.asarray(face_areas_2, dtype=np.float64)
    if w.shape != (len(F),):
        raise ValueError(f"face_areas_2 must have shape ({len(F)},), got {w.shape}")
    # a repeated image vertex gives an exactly zero normal, like any other degenerate image
    idx = np.flatnonzero((p[F] >= 0).all(axis=1))
    img = p[F[idx]]
    n_img = face_normals(V, img)
    proper = n_img.any(axis=1)
    idx, n_img, img = idx[proper], n_img[proper], img[proper]
    total = float(w[idx].sum())
    if total <= 0:
        return 0.0
    turned = np.einsum("ij,ij->i", n_img, N[img].sum(axis=1)) < 0
    return float(w[idx][turned].sum() / total)
