"""The registration's k-d trees (deform.kdtree) against brute force and scipy's cKDTree."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from topomatch.datasets.toy import icosphere
from topomatch.deform.kdtree import JointTree, PointTree, _query_order
from topomatch.deform.register import nearest_compatible


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _brute(P, Q, NQ, RN, k, min_cos):
    D = np.linalg.norm(Q[:, None] - P[None], axis=-1)
    order = np.argsort(D, axis=1, kind="stable")[:, :k]
    out = order[:, 0].copy()
    for q in range(len(Q)):
        ok = [j for j in order[q] if NQ[q] @ RN[j] >= min_cos]
        if ok:
            out[q] = ok[0]
    return out, D[np.arange(len(Q)), out]


@pytest.mark.parametrize("n", [1, 5, 13, 400, 3000])
def test_nearest_compatible_equals_brute_force(n):
    rng = np.random.default_rng(n)
    P = rng.standard_normal((n, 3)) * [1.0, 0.3, 2.0]  # uneven extents: splits along every axis
    RN = _unit(rng.standard_normal((n, 3)))
    Q = np.r_[rng.standard_normal((300, 3)), 10 * rng.standard_normal((20, 3))]  # near and far queries
    NQ = _unit(rng.standard_normal((len(Q), 3)))
    tree = PointTree(P)
    for k, min_cos in ((1, 0.0), (8, 0.3), (8, 0.9), (3, -2.0)):
        i, d = tree.nearest_compatible(Q, NQ, RN, k=k, min_cos=min_cos)
        bi, bd = _brute(P, Q, NQ, RN, min(k, n), min_cos)
        np.testing.assert_array_equal(i, bi)
        np.testing.assert_allclose(d, bd, rtol=1e-12, atol=1e-12)
        # the same answer through the registration's function, with either tree
        ci, cd = nearest_compatible(Q, NQ, cKDTree(P), RN, k=min(k, n), min_cos=min_cos)
        np.testing.assert_array_equal(ci, i)
        np.testing.assert_allclose(cd, d, rtol=1e-12, atol=1e-12)
    dist, idx = tree.query(Q)
    np.testing.assert_array_equal(idx, _brute(P, Q, NQ, RN, 1, 0.0)[0])
    np.testing.assert_allclose(dist, np.linalg.norm(Q - P[idx], axis=1), rtol=1e-12)


def test_query_order_is_a_permutation_and_keeps_answers():
    rng = np.random.default_rng(3)
    Q = rng.standard_normal((700, 3))
    order = _query_order(Q)  # scattered queries: searched cell by cell
    assert sorted(order) == list(range(len(Q))) and not np.array_equal(order, np.arange(len(Q)))
    path = np.cumsum(0.01 * rng.standard_normal((700, 3)), axis=0)  # successive queries close together
    np.testing.assert_array_equal(_query_order(path), np.arange(len(path)))
    for degenerate in (np.zeros((5, 3)), Q[:1], np.zeros((0, 3))):  # one point, one place, none
        np.testing.assert_array_equal(_query_order(degenerate), np.arange(len(degenerate)))
    # the answers are the queries' own, whatever order they come in
    P, RN = rng.standard_normal((2000, 3)), _unit(rng.standard_normal((2000, 3)))
    NQ = _unit(rng.standard_normal(Q.shape))
    tree = PointTree(P)
    i, d = tree.nearest_compatible(Q, NQ, RN, k=8, min_cos=0.3)
    shuffle = rng.permutation(len(Q))
    i2, d2 = tree.nearest_compatible(Q[shuffle], NQ[shuffle], RN, k=8, min_cos=0.3)
    np.testing.assert_array_equal(i2, i[shuffle])
    np.testing.assert_array_equal(d2, d[shuffle])
    np.testing.assert_array_equal(i, _brute(P, Q, NQ, RN, 8, 0.3)[0])


def test_refit_stays_exact_for_moved_points():
    mesh = icosphere(3)
    rng = np.random.default_rng(0)
    tree = PointTree(mesh.vertices)
    Q = rng.standard_normal((500, 3))
    for step in range(4):  # growing deformations of the points the tree was built on
        moved = mesh.vertices * [1.0 + step, 1.0, 1.0 / (1 + step)] + 0.2 * step * rng.standard_normal(mesh.vertices.shape)
        dist, idx = tree.refit(moved).query(Q)
        ref_d, ref_i = cKDTree(moved).query(Q)
        np.testing.assert_array_equal(idx, ref_i)
        np.testing.assert_allclose(dist, ref_d, rtol=1e-12)
        np.testing.assert_array_equal(tree.data, moved)


def test_duplicate_points_and_ties():
    P = np.zeros((50, 3))
    P[25:] = 1.0
    tree = PointTree(P)
    i, d = tree.nearest_compatible(np.array([[0.1, 0.0, 0.0], [0.9, 1.0, 1.0]]), np.zeros((2, 3)), np.zeros((50, 3)), k=8)
    assert i[0] < 25 <= i[1]
    np.testing.assert_allclose(d, [0.1, 0.1])


def test_point_tree_rejects_bad_input():
    with pytest.raises(ValueError, match="shape"):
        PointTree(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="no points"):
        PointTree(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="finite"):
        PointTree(np.array([[0.0, np.nan, 0.0]]))
    tree = PointTree(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="expected 4 points"):
        tree.refit(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="normals"):
        tree.nearest_compatible(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="reference normals"):
        tree.nearest_compatible(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((3, 3)))


@pytest.mark.parametrize("n, dim", [(1, 1), (7, 2), (400, 3), (3000, 8), (2000, 13)])
def test_joint_tree_equals_brute_force(n, dim):
    rng = np.random.default_rng(n + dim)
    P = rng.standard_normal((n, dim)) * np.linspace(2.0, 0.1, dim)  # uneven extents: splits along several axes
    Q = np.r_[rng.standard_normal((300, dim)), 10 * rng.standard_normal((20, dim))]
    dist, idx = JointTree(P).query(Q)
    D = np.linalg.norm(Q[:, None] - P[None], axis=-1)
    np.testing.assert_array_equal(idx, np.argmin(D, axis=1))
    np.testing.assert_allclose(dist, D.min(axis=1), rtol=1e-12, atol=1e-12)


def test_joint_tree_refit_stays_exact():
    """The feature stage's use: positions deform and the feature columns shrink towards 0."""
    mesh = icosphere(3)
    rng = np.random.default_rng(1)
    feats = rng.standard_normal((mesh.n_vertices, 5))
    tree = JointTree(np.c_[mesh.vertices, 0.5 * feats])
    Q = np.c_[rng.standard_normal((500, 3)), 0.3 * rng.standard_normal((500, 5))]
    for step, w in enumerate((0.5, 0.3, 0.1, 0.0)):
        moved = mesh.vertices * [1.0 + step, 1.0, 1.0 / (1 + step)] + 0.1 * step * rng.standard_normal(mesh.vertices.shape)
        P = np.c_[moved, w * feats]
        dist, idx = tree.refit(P).query(Q)
        ref_d, ref_i = cKDTree(P).query(Q)
        np.testing.assert_allclose(dist, ref_d, rtol=1e-12)
        np.testing.assert_array_equal(idx, ref_i)


def test_joint_tree_rejects_bad_input():
    with pytest.raises(ValueError, match="no points"):
        JointTree(np.zeros((0, 4)))
    with pytest.raises(ValueError, match="finite"):
        JointTree(np.array([[0.0, np.inf]]))
    with pytest.raises(ValueError, match="shape"):
        JointTree(np.zeros(4))
    tree = JointTree(np.zeros((4, 6)))
    with pytest.raises(ValueError, match=r"shape \(n, 6\)"):
        tree.query(np.zeros((2, 5)))
    with pytest.raises(ValueError, match="expected 4 points"):
        tree.refit(np.zeros((5, 6)))
