"""Repairing left-right exchanges in a point-to-point map onto a symmetric shape.

A registration of a symmetric template onto a shape whose two hands (or feet) touch can
leave a patch of one hand mapped onto the template's *other* hand: the deformed
template's wrong hand lies nearer there than its right one. Such a patch is
continuous in itself but jumps at its rim, while its mirror image (each vertex sent to
the template vertex's mirror) joins the surrounding map. :func:`flip_mirror_patches`
finds these patches and mirrors them; it needs only the map, the shape's edges and the
template's symmetry map, no ground truth. Attempt #109 in ``docs/flagship.md``.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from topomatch.typing import FloatArray, IndexArray

__all__ = ["flip_mirror_patches"]


def _edges(faces: IndexArray, n_vertices: int) -> tuple[IndexArray, IndexArray]:
    E = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    E = np.unique(np.sort(E, axis=1), axis=0)
    E = E[E[:, 0] != E[:, 1]]
    return E[:, 0], E[:, 1]


def flip_mirror_patches(
    p2p_21: IndexArray,
    faces_2: IndexArray,
    vertices_1: FloatArray,
    faces_1: IndexArray,
    sym_1: IndexArray,
    *,
    jump: float = 0.1,
    max_fraction: float = 0.05,
    ratio: float = 0.5,
    sweeps: int = 3,
) -> tuple[IndexArray, int]:
    """Mirror the small patches of a map whose mirror image joins their surroundings better.

    The shape's edges whose two ends map more than ``jump`` apart on shape 1 are cut;
    the connected pieces left are the map's continuous patches. A patch of at most
    ``max_fraction`` of the shape's vertices is sent to its mirror image
    (``p2p[v] -> sym_1[p2p[v]]``) when, summed over its cut rim edges (each capped at
    one), the distances from its vertices' mirror images to where the neighbours map
    are below ``ratio`` times the distances from its vertices' images. Repeated up to
    ``sweeps`` times while a patch flips. Distances are on shape 1, in units of the
    square root of its area.

    Parameters
    ----------
    p2p_21 : ndarray of int, shape (n2,)
        Map from shape 2's vertices to shape 1's (``-1``: unmatched, left alone).
    faces_2 : ndarray of int, shape (f2, 3)
        Shape 2's triangles.
    vertices_1 : ndarray, shape (n1, 3)
        Shape 1's vertex positions.
    faces_1 : ndarray of int, shape (f1, 3)
        Shape 1's triangles (for its area, the unit of distance).
    sym_1 : ndarray of int, shape (n1,)
        Shape 1's left-right symmetry map (``-1`` where a vertex has no mirror; a patch
        touching such a vertex is never flipped).
    jump, max_fraction, ratio : float
        Chosen on the TOPKIDS training pairs (attempt #109: ``jump`` 0.05-0.2,
        ``max_fraction`` 0.02-0.1 and ``ratio`` 0.3-0.8 gave the same training figure
        within 0.002).
    sweeps : int

    Returns
    -------
    p2p_21 : ndarray of int, shape (n2,)
        The repaired map (a copy).
    n_flipped : int
        Vertices whose image was mirrored (counted once per flip).
    """
    p2p = np.asarray(p2p_21)
    faces = np.asarray(faces_2)
    V = np.asarray(vertices_1, dtype=np.float64)
    sym = np.asarray(sym_1)
    if p2p.ndim != 1 or not np.issubdtype(p2p.dtype, np.integer):
        raise ValueError(f"flip_mirror_patches: p2p_21 must be a 1-D integer array, got {p2p.dtype} of shape {p2p.shape}")
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"flip_mirror_patches: vertices_1 must have shape (n1, 3), got {V.shape}")
    n1, n2 = len(V), len(p2p)
    if sym.shape != (n1,) or not np.issubdtype(sym.dtype, np.integer) or (n1 and (sym.min() < -1 or sym.max() >= n1)):
        raise ValueError(f"flip_mirror_patches: sym_1 must hold one index in [-1, {n1 - 1}] per vertex of shape 1 ({n1})")
    if n2 and (p2p.min() < -1 or p2p.max() >= n1):
        raise ValueError(f"flip_mirror_patches: p2p_21 has indices outside [-1, {n1 - 1}]")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer) or (faces.size and (faces.min() < 0 or faces.max() >= n2)):
        raise ValueError(f"flip_mirror_patches: faces_2 must be (f2, 3) indices into the map's {n2} vertices")
    if not (jump > 0 and 0 <= max_fraction <= 1 and ratio > 0) or isinstance(sweeps, bool) or int(sweeps) != sweeps or sweeps < 0:
        raise ValueError(f"flip_mirror_patches: need jump > 0, 0 <= max_fraction <= 1, ratio > 0 and an integer sweeps >= 0; got {jump}, {max_fraction}, {ratio}, {sweeps}")
    F1 = np.asarray(faces_1)
    if F1.ndim != 2 or F1.shape[1] != 3 or not np.issubdtype(F1.dtype, np.integer) or (F1.size and (F1.min() < 0 or F1.max() >= n1)):
        raise ValueError(f"flip_mirror_patches: faces_1 must be (f1, 3) indices into shape 1's {n1} vertices")
    out = p2p.astype(np.int64, copy=True)
    if n2 == 0 or len(faces) == 0 or n1 == 0:
        return out, 0
    scale = np.sqrt(0.5 * np.linalg.norm(np.cross(V[F1[:, 1]] - V[F1[:, 0]], V[F1[:, 2]] - V[F1[:, 0]]), axis=1).sum())
    if not scale > 0:
        raise ValueError("flip_mirror_patches: shape 1 has zero area")
    V = V / scale
    a, b = _edges(faces, n2)
    n_flipped = 0
    for _ in range(int(sweeps)):
        live = (out[a] >= 0) & (out[b] >= 0)
        d = np.full(len(a), np.inf)
        d[live] = np.linalg.norm(V[out[a[live]]] - V[out[b[live]]], axis=1)
        keep = d <= jump
        G = sparse.coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(n2, n2))
        k, label = connected_components(G, directed=False)
        sizes = np.bincount(label, minlength=k)
        # the rim: cut edges between two patches, once from each side
        rim = ~keep & live & (label[a] != label[b])
        inner = np.r_[a[rim], b[rim]]
        outer = np.r_[b[rim], a[rim]]
        patch = label[inner]
        mirror = sym[out[inner]]
        has = mirror >= 0
        now = np.minimum(np.linalg.norm(V[out[inner]] - V[out[outer]], axis=1), 1.0)
        flipped = np.ones(len(inner))
        flipped[has] = np.minimum(np.linalg.norm(V[mirror[has]] - V[out[outer[has]]], axis=1), 1.0)
        cost_now = np.bincount(patch, now, minlength=k)
        cost_flip = np.bincount(patch, flipped, minlength=k)
        # every mapped vertex of a flipped patch needs a mirror
        mapped = out >= 0
        no_mirror = np.bincount(label[mapped], sym[out[mapped]] < 0, minlength=k) > 0
        flip = (sizes <= max_fraction * n2) & (cost_now > 0) & (cost_flip < ratio * cost_now) & ~no_mirror
        if not flip.any():
            break
        members = flip[label] & mapped
        out[members] = sym[out[members]]
        n_flipped += int(members.sum())
    return out, n_flipped
