"""The registration steps as numpy and SciPy formulas: the reference of the compiled steps.

Until session 49 :class:`~topomatch.deform.register.GraphDeformation` computed its steps
with these formulas (sparse products, ``einsum``, numpy's stacked SVD). The compiled
kernels of :mod:`topomatch._kernels` that replaced them add in the same order, so on
x86-64 with numpy 2.4 they give the same bits (the 15 training maps were equal bit for
bit); they also run without the GIL, which lets the verifications on two threads run
side by side. The tests (``tests/test_register_kernels.py``) check the kernels against
these formulas and ``benchmarks/bench_register_steps.py`` times them against each other.
Not used by the library's registration.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from topomatch.deform.register import DataPairs, GraphDeformation
from topomatch.typing import FloatArray, IndexArray

__all__ = ["affine_part", "deformed", "dense_system", "grams", "position_step", "position_terms", "robust_weights", "rotations", "weighted_pairs"]


def _incidence(D: GraphDeformation) -> tuple[sparse.csr_matrix, sparse.csr_matrix]:
    """The directed links' start and end incidence matrices, shape (m, 2 n_links) each."""
    m, nd = D.graph.n_nodes, len(D._dir_a)
    Ia = sparse.csr_matrix((np.ones(nd), (D._dir_a, np.arange(nd))), shape=(m, nd))
    Ib = sparse.csr_matrix((np.ones(nd), (D._dir_b, np.arange(nd))), shape=(m, nd))
    return Ia, Ib


def _procrustes(S: FloatArray) -> FloatArray:
    """Rotations ``R`` maximising ``tr(R S)`` for a stack ``S`` of shape (m, 3, 3) (numpy's stacked SVD)."""
    U, _, Vt = np.linalg.svd(S)
    R = np.einsum("mji,mkj->mik", Vt, U)  # V U^T
    flip = np.linalg.det(R) < 0
    if np.any(flip):
        Vt2 = Vt[flip].copy()
        Vt2[:, 2, :] *= -1
        R[flip] = np.einsum("mji,mkj->mik", Vt2, U[flip])
    return R


def rotations(D: GraphDeformation, pairs: DataPairs | None, data_weight: float = 1.0) -> FloatArray:
    """The rotation step's result, shape (m, 3, 3): ``GraphDeformation.update_rotations`` before session 49."""
    m = D.graph.n_nodes
    wl = D._link_weights()
    cur = D.positions[D._dir_b] - D.positions[D._dir_a]
    outer = (wl[:, None, None] * D._dir_rest[:, :, None] * cur[:, None, :]).reshape(-1, 9)
    S = np.asarray(_incidence(D)[0] @ outer).reshape(m, 3, 3)
    if pairs is not None and len(pairs.source) and data_weight > 0:
        Pt = D._skin[pairs.source].T
        c = data_weight * pairs.weights
        v = D.vertices[pairs.source]
        y = pairs.points
        cv = c[:, None] * v
        vy = (cv[:, :, None] * y[:, None, :]).reshape(-1, 9)
        sums = np.asarray(Pt @ np.c_[vy, cv, c[:, None] * y, c])
        S_vy = sums[:, :9].reshape(m, 3, 3)
        sv, sy, sc = sums[:, 9:12], sums[:, 12:15], sums[:, 15]
        g0, g = D.graph.rest, D.positions
        S += S_vy - sv[:, :, None] * g[:, None, :] - g0[:, :, None] * sy[:, None, :] + sc[:, None, None] * g0[:, :, None] * g[:, None, :]
    tiny = np.einsum("mii->m", np.abs(S)) < 1e-300
    R = _procrustes(S + 1e-12 * np.eye(3))
    R[tiny] = D.rotations[tiny]
    return R


def affine_part(D: GraphDeformation, subset: IndexArray | None = None) -> FloatArray:
    """``sum_q w_iq R_q (v_i - g0_q)`` for all vertices or a subset, shape (n or len(subset), 3)."""
    m = D.graph.n_nodes
    S, v = (D._skin, D.vertices) if subset is None else (D._skin[subset], D.vertices[subset])
    Rg0 = np.einsum("mab,mb->ma", D.rotations, D.graph.rest)
    blend = np.asarray(S @ np.c_[D.rotations.reshape(m, 9), Rg0])
    return np.einsum("nab,nb->na", blend[:, :9].reshape(-1, 3, 3), v) - blend[:, 9:]


def deformed(D: GraphDeformation) -> FloatArray:
    """The deformed source vertices, shape (n, 3)."""
    return affine_part(D) + D._skin @ D.positions


def grams(D: GraphDeformation, source: IndexArray, weights: FloatArray) -> FloatArray:
    """Upper triangles of ``skin[source]^T diag(w_k) skin[source]``, shape (n_entries, k)."""
    vp = D._pattern.vertex_products
    n = vp.shape[0]
    per_vertex = np.stack([np.bincount(source, weights=weights[:, j], minlength=n) for j in range(weights.shape[1])], axis=1)
    active = np.flatnonzero(np.any(per_vertex != 0, axis=1))
    return np.asarray(vp[active].T @ per_vertex[active])


def position_terms(
    D: GraphDeformation, pairs: DataPairs, alpha: float, mu_point: float, mu_plane: float
) -> tuple[float, FloatArray, FloatArray]:
    """The position step's regulariser weight, right-hand side (m, 3) and the pairs' Gram weights (p, 6 or 1)."""
    Ia, Ib = _incidence(D)
    wl = D._link_weights()
    d = np.einsum("kab,kb->ka", D.rotations[D._dir_a], D._dir_rest)
    rhs = (Ib - Ia).tocsr() @ (wl[:, None] * d)
    PT = D._skin[pairs.source].T
    resid = pairs.points - affine_part(D, pairs.source)
    c = pairs.weights
    data_scale = float(c.sum()) / max(float(wl.sum()), 1e-300)
    reg = alpha * data_scale
    r = reg * rhs + PT @ (mu_point * c[:, None] * resid)
    if mu_plane > 0:
        nrm = pairs.normals
        r = r + PT @ ((mu_plane * c * np.einsum("pc,pc->p", nrm, resid))[:, None] * nrm)
        ij = [(i, j) for i in range(3) for j in range(i, 3)]
        w = np.stack([mu_plane * c * nrm[:, i] * nrm[:, j] + (mu_point * c if i == j else 0.0) for i, j in ij], axis=1)
    else:
        w = (mu_point * c)[:, None]
    return reg, np.asarray(r), w


def position_step(D: GraphDeformation, pairs: DataPairs, *, alpha: float, mu_point: float = 1.0, mu_plane: float = 0.0) -> FloatArray:
    """The position step's new node positions, shape (m, 3) (the same linear solve as the library's)."""
    reg, r, w = position_terms(D, pairs, alpha, mu_point, mu_plane)
    return D._solved_positions(r, grams(D, pairs.source, w), reg, D._regulariser(D._link_weights()))


def robust_weights(normals: FloatArray, other_normals: FloatArray, d: FloatArray, sigma: float, min_cos: float) -> FloatArray:
    """``1 / (1 + (d / sigma)^2)`` where the two normals agree (cosine >= ``min_cos``), else 0; shape (p,)."""
    cos = np.einsum("pc,pc->p", normals, other_normals)
    return np.where(cos >= min_cos, 1.0 / (1.0 + (d / sigma) ** 2), 0.0)


def weighted_pairs(
    src: IndexArray, j: IndexArray, d: FloatArray, tgt: IndexArray, i: IndexArray, d2: FloatArray,
    source_normals: FloatArray, target_vertices: FloatArray, target_normals: FloatArray, sigma: float, min_cos: float,
) -> DataPairs:
    """The closest-point pairs of both directions with a positive weight (``closest_pairs``' and ``feature_pairs``' formula before session 58)."""
    return DataPairs.concat(
        DataPairs(src, target_vertices[j], target_normals[j], robust_weights(source_normals[src], target_normals[j], d, sigma, min_cos)),
        DataPairs(i, target_vertices[tgt], target_normals[tgt], robust_weights(target_normals[tgt], source_normals[i], d2, sigma, min_cos)),
    ).weighted()


def dense_system(blocks: dict[tuple[int, int], FloatArray], rows: IndexArray, cols: IndexArray, m: int, eps: float) -> FloatArray:
    """The dense matrix ``_GramPattern.solve`` factorises (its upper triangle; before session 58, by fancy indexing), shape (d m, d m)."""
    size = (max(max(ij) for ij in blocks) + 1) * m
    H = np.zeros((size, size), order="F")
    for (i, j), v in blocks.items():
        H[i * m + rows, j * m + cols] = v
        if i != j:
            H[i * m + cols, j * m + rows] = v
    H[np.diag_indices(size)] += eps
    return H
