"""The registration's compiled steps against the numpy and SciPy formulas they replaced.

On x86-64 with numpy 2.4 the compiled steps give the same bits (they add in the same
order; the training split's maps were equal bit for bit, docs/flagship.md #156); the
tests allow 1e-13, since the order in which numpy's ``einsum`` and SciPy's sparse
products add is the platform's, not part of either's contract.
"""

from __future__ import annotations

import numpy as np
import pytest

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
    S = np.asarray(D._Ia @ outer).reshape(m, 3, 3)
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
