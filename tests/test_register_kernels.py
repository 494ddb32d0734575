"""The registration's compiled steps against the numpy and SciPy formulas they replaced.

On x86-64 with numpy 2.4 the compiled steps give the same bits (they add in the same
order; the training split's maps were equal bit for bit, docs/flagship.md #156); the
tests allow 1e-13, since the order in which numpy's ``einsum`` and SciPy's sparse
products add is the platform's, not part of either's contract.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from topomatch.datasets.toy import icosphere
from topomatch.deform.graph import build_deformation_graph
from topomatch.deform.register import DataPairs, GraphDeformation


def _procrustes(S: np.ndarray) -> np.ndarray:
    """The rotation step's SVD part before session 49 (numpy's stacked SVD)."""
    U, _, Vt = np.linalg.svd(S)
    R = np.einsum("mji,mkj->mik", Vt, U)  # V U^T
    flip = np.linalg.det(R) < 0
    if np.any(flip):
        Vt2 = Vt[flip].copy()
        Vt2[:, 2, :] *= -1
        R[flip] = np.einsum("mji,mkj->mik", Vt2, U[flip])
    return R


def _reference_rotations(D: GraphDeformation, pairs: DataPairs | None, data_weight: float = 1.0) -> np.ndarray:
    """``GraphDeformation.update_rotations`` as it was before session 49 (sparse products, numpy's SVD)."""
    m = D.graph.n_nodes
    wl = D._link_weights()
    cur = D.positions[D._dir_b] - D.positions[D._dir_a]
    outer = (wl[:, None, None] * D._dir_rest[:, :, None] * cur[:, None, :]).reshape(-1, 9)
    nd = len(D._dir_a)
    Ia = sparse.csr_matrix((np.ones(nd), (D._dir_a, np.arange(nd))), shape=(m, nd))
    S = np.asarray(Ia @ outer).reshape(m, 3, 3)
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


@pytest.fixture(scope="module")
def deformation() -> GraphDeformation:
    mesh = icosphere(4)
    graph = build_deformation_graph(mesh.vertices, mesh.faces, 60)
    return GraphDeformation(mesh.vertices, mesh.faces, graph)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotation_step_equals_the_numpy_formula(deformation, seed):
    rng = np.random.default_rng(seed)
    D = deformation
    m, n = D.graph.n_nodes, len(D.vertices)
    # a state away from rest: moved nodes, turned rotations, uneven link scales
    D.positions = D.graph.rest + 0.3 * rng.standard_normal((m, 3))
    D.rotations = np.linalg.qr(rng.standard_normal((m, 3, 3)))[0]
    D.link_scale = rng.uniform(0.1, 1.0, len(D.graph.links))
    # pairs that repeat vertices, in no order, some with zero weight
    src = rng.integers(0, n, 3 * n)
    pairs = DataPairs(src, D.vertices[src] * 1.7 + rng.standard_normal((len(src), 3)), np.zeros((len(src), 3)), rng.uniform(0, 1, len(src)) * (rng.uniform(size=len(src)) > 0.1))
    for p, dw in ((pairs, 1.0), (pairs, 0.37), (None, 1.0), (pairs, 0.0)):
        want = _reference_rotations(D, p, dw)
        before = D.rotations.copy()
        D.update_rotations(p, dw)
        np.testing.assert_allclose(D.rotations, want, rtol=0, atol=1e-13)
        np.testing.assert_allclose(np.einsum("mij,mkj->mik", D.rotations, D.rotations), np.tile(np.eye(3), (m, 1, 1)), atol=1e-12)
        assert np.all(np.linalg.det(D.rotations) > 0)
        D.rotations = before


def test_rotation_step_keeps_the_rotation_of_a_node_without_any_term(deformation):
    D = deformation
    m = D.graph.n_nodes
    D.positions = D.graph.rest.copy()
    D.rotations = np.linalg.qr(np.random.default_rng(5).standard_normal((m, 3, 3)))[0]
    D.link_scale = np.zeros(len(D.graph.links))  # no link term, and no pairs: every S is zero
    before = D.rotations.copy()
    D.update_rotations(None)
    np.testing.assert_array_equal(D.rotations, before)
    D.link_scale = np.ones(len(D.graph.links))


def _reference_affine(D: GraphDeformation, subset: np.ndarray | None) -> np.ndarray:
    """``GraphDeformation._affine_part`` before session 49 (sparse products and einsum)."""
    m = D.graph.n_nodes
    S, v = (D._skin, D.vertices) if subset is None else (D._skin[subset], D.vertices[subset])
    Rg0 = np.einsum("mab,mb->ma", D.rotations, D.graph.rest)
    blend = np.asarray(S @ np.c_[D.rotations.reshape(m, 9), Rg0])
    return np.einsum("nab,nb->na", blend[:, :9].reshape(-1, 3, 3), v) - blend[:, 9:]


@pytest.mark.parametrize("seed", [0, 1])
def test_skinned_vertices_equal_the_numpy_formula(deformation, seed):
    rng = np.random.default_rng(seed)
    D = deformation
    m, n = D.graph.n_nodes, len(D.vertices)
    D.positions = D.graph.rest + 0.3 * rng.standard_normal((m, 3))
    D.rotations = np.linalg.qr(rng.standard_normal((m, 3, 3)))[0]
    subset = rng.integers(0, n, 2 * n)
    np.testing.assert_allclose(D._affine_part(subset), _reference_affine(D, subset), rtol=0, atol=1e-13)
    np.testing.assert_allclose(D._affine_part(), _reference_affine(D, None), rtol=0, atol=1e-13)
    np.testing.assert_allclose(D.deformed(), _reference_affine(D, None) + D._skin @ D.positions, rtol=0, atol=1e-13)
    # a Fortran-ordered state (the dense solve returns one) gives the same result
    D.positions = np.asfortranarray(D.positions)
    np.testing.assert_allclose(D.deformed(), _reference_affine(D, None) + D._skin @ D.positions, rtol=0, atol=1e-13)
    D.rotations = np.tile(np.eye(3), (m, 1, 1))
    D.positions = D.graph.rest.copy()
    np.testing.assert_allclose(D.deformed(), D.vertices, atol=1e-12)  # at rest: the source itself


def _reference_position_terms(D, pairs, alpha, mu_point, mu_plane):
    """The right-hand side and Gram weights of ``update_positions`` before session 49."""
    m = D.graph.n_nodes
    nd = len(D._dir_a)
    Ia = sparse.csr_matrix((np.ones(nd), (D._dir_a, np.arange(nd))), shape=(m, nd))
    Ib = sparse.csr_matrix((np.ones(nd), (D._dir_b, np.arange(nd))), shape=(m, nd))
    wl = D._link_weights()
    d = np.einsum("kab,kb->ka", D.rotations[D._dir_a], D._dir_rest)
    rhs = (Ib - Ia).tocsr() @ (wl[:, None] * d)
    PT = D._skin[pairs.source].T
    resid = pairs.points - _reference_affine(D, pairs.source)
    c = pairs.weights
    reg = alpha * float(c.sum()) / max(float(wl.sum()), 1e-300)
    r = reg * rhs + PT @ (mu_point * c[:, None] * resid)
    if mu_plane > 0:
        nrm = pairs.normals
        r = r + PT @ ((mu_plane * c * np.einsum("pc,pc->p", nrm, resid))[:, None] * nrm)
        ij = [(i, j) for i in range(3) for j in range(i, 3)]
        w = np.stack([mu_plane * c * nrm[:, i] * nrm[:, j] + (mu_point * c if i == j else 0.0) for i, j in ij], axis=1)
    else:
        w = (mu_point * c)[:, None]
    return reg, r, w


@pytest.mark.parametrize("mu_plane", [0.0, 0.7])
def test_position_terms_equal_the_numpy_formula(deformation, mu_plane):
    from topomatch._kernels import position_terms

    rng = np.random.default_rng(11)
    D = deformation
    m, n = D.graph.n_nodes, len(D.vertices)
    D.positions = D.graph.rest + 0.3 * rng.standard_normal((m, 3))
    D.rotations = np.linalg.qr(rng.standard_normal((m, 3, 3)))[0]
    D.link_scale = rng.uniform(0.1, 1.0, len(D.graph.links))
    src = rng.integers(0, n, 2 * n)
    normals = rng.standard_normal((len(src), 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    pairs = DataPairs(src, D.vertices[src] + 0.2 * rng.standard_normal((len(src), 3)), normals, rng.uniform(0, 1, len(src)))
    reg, want_r, want_w = _reference_position_terms(D, pairs, 0.5, 0.1, mu_plane)
    r = np.empty((m, 3))
    w = np.empty((len(src), want_w.shape[1]))
    S = D._skin
    resid = pairs.points - D._affine_part(src)
    position_terms(D.rotations, D._dir_a, D._dir_b, D._dir_rest, D._link_weights(), S.indptr, S.indices, S.data, src, pairs.weights, resid, pairs.normals, reg, 0.1, mu_plane, r, w)
    np.testing.assert_allclose(r, want_r, rtol=0, atol=1e-12)
    np.testing.assert_allclose(w, want_w, rtol=0, atol=1e-13)
    # and the step itself moves the nodes to the solution of its system: a second step
    # from there, with the rotations unchanged, stays put
    D.update_positions(pairs, alpha=0.5, mu_point=0.1, mu_plane=mu_plane)
    before = D.positions.copy()
    D.update_positions(pairs, alpha=0.5, mu_point=0.1, mu_plane=mu_plane)
    np.testing.assert_allclose(D.positions, before, atol=1e-6)
    D.link_scale = np.ones(len(D.graph.links))
