"""The registration's compiled steps against the numpy and SciPy formulas they replaced.

The formulas live in :mod:`topomatch.deform._reference`. On x86-64 with numpy 2.4 the
compiled steps give the same bits (they add in the same order; the training split's
maps were equal bit for bit, docs/flagship.md #156); the tests allow 1e-12, since the
order in which numpy's ``einsum`` and SciPy's sparse products add is the platform's,
not part of either's contract.
"""

from __future__ import annotations

import numpy as np
import pytest

from topomatch._kernels import _horn_rotation, banded_blocks, dense_blocks, position_terms
from topomatch.datasets.toy import icosphere
from topomatch.deform import _reference as ref
from topomatch.deform import register
from topomatch.deform.graph import build_deformation_graph
from topomatch.deform.register import DataPairs, GraphDeformation, _weighted_pairs


@pytest.fixture(scope="module")
def deformation() -> GraphDeformation:
    mesh = icosphere(4)
    graph = build_deformation_graph(mesh.vertices, mesh.faces, 60)
    return GraphDeformation(mesh.vertices, mesh.faces, graph)


def _moved(D: GraphDeformation, rng: np.random.Generator) -> None:
    """A state away from rest: moved nodes, turned rotations, uneven link scales."""
    m = D.graph.n_nodes
    D.positions = D.graph.rest + 0.3 * rng.standard_normal((m, 3))
    D.rotations = np.linalg.qr(rng.standard_normal((m, 3, 3)))[0]
    D.link_scale = rng.uniform(0.1, 1.0, len(D.graph.links))


def _rest(D: GraphDeformation) -> None:
    m = D.graph.n_nodes
    D.positions = D.graph.rest.copy()
    D.rotations = np.tile(np.eye(3), (m, 1, 1))
    D.link_scale = np.ones(len(D.graph.links))


def _pairs(D: GraphDeformation, rng: np.random.Generator, factor: int) -> DataPairs:
    """Pairs that repeat vertices, in no order, some with zero weight, with unit normals."""
    n = len(D.vertices)
    src = rng.integers(0, n, factor * n)
    normals = rng.standard_normal((len(src), 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    weights = rng.uniform(0, 1, len(src)) * (rng.uniform(size=len(src)) > 0.1)
    return DataPairs(src, D.vertices[src] * 1.7 + rng.standard_normal((len(src), 3)), normals, weights)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotation_step_equals_the_numpy_formula(deformation, seed):
    rng = np.random.default_rng(seed)
    D = deformation
    m = D.graph.n_nodes
    _moved(D, rng)
    pairs = _pairs(D, rng, 3)
    for p, dw in ((pairs, 1.0), (pairs, 0.37), (None, 1.0), (pairs, 0.0)):
        want = ref.rotations(D, p, dw)
        before = D.rotations.copy()
        D.update_rotations(p, dw)
        np.testing.assert_allclose(D.rotations, want, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.einsum("mij,mkj->mik", D.rotations, D.rotations), np.tile(np.eye(3), (m, 1, 1)), atol=1e-12)
        assert np.all(np.linalg.det(D.rotations) > 0)
        D.rotations = before
    _rest(D)


def test_rotation_step_keeps_the_rotation_of_a_node_without_any_term(deformation):
    D = deformation
    m = D.graph.n_nodes
    D.positions = D.graph.rest.copy()
    D.rotations = np.linalg.qr(np.random.default_rng(5).standard_normal((m, 3, 3)))[0]
    D.link_scale = np.zeros(len(D.graph.links))  # no link term, and no pairs: every S is zero
    before = D.rotations.copy()
    D.update_rotations(None)
    np.testing.assert_array_equal(D.rotations, before)
    _rest(D)


@pytest.mark.parametrize("seed", [0, 1])
def test_skinned_vertices_equal_the_numpy_formula(deformation, seed):
    rng = np.random.default_rng(seed)
    D = deformation
    _moved(D, rng)
    subset = rng.integers(0, len(D.vertices), 2 * len(D.vertices))
    np.testing.assert_allclose(D._affine_part(subset), ref.affine_part(D, subset), rtol=0, atol=1e-12)
    np.testing.assert_allclose(D._affine_part(), ref.affine_part(D), rtol=0, atol=1e-12)
    np.testing.assert_allclose(D.deformed(), ref.deformed(D), rtol=0, atol=1e-12)
    # a Fortran-ordered state (the dense solve returns one) gives the same result
    D.positions = np.asfortranarray(D.positions)
    np.testing.assert_allclose(D.deformed(), ref.deformed(D), rtol=0, atol=1e-12)
    _rest(D)
    np.testing.assert_allclose(D.deformed(), D.vertices, atol=1e-12)  # at rest: the source itself


@pytest.mark.parametrize("mu_plane", [0.0, 0.7])
def test_position_step_equals_the_numpy_formula(deformation, mu_plane):
    rng = np.random.default_rng(11)
    D = deformation
    m = D.graph.n_nodes
    _moved(D, rng)
    pairs = _pairs(D, rng, 2)
    src = pairs.source
    reg, want_r, want_w = ref.position_terms(D, pairs, 0.5, 0.1, mu_plane)
    r = np.empty((m, 3))
    w = np.empty((len(src), want_w.shape[1]))
    S = D._skin
    resid = pairs.points - D._affine_part(src)
    position_terms(D.rotations, D._dir_a, D._dir_b, D._dir_rest, D._link_weights(), S.indptr, S.indices, S.data, src,
                   pairs.weights, resid, pairs.normals, reg, 0.1, mu_plane, r, w)
    np.testing.assert_allclose(r, want_r, rtol=0, atol=1e-12)
    np.testing.assert_allclose(w, want_w, rtol=0, atol=1e-13)
    np.testing.assert_allclose(D._pattern.grams(src, w), ref.grams(D, src, w), rtol=0, atol=1e-12)
    # the whole step, then a second one from its result with the rotations unchanged:
    # the nodes are at the solution of the step's system, so they stay put
    want = ref.position_step(D, pairs, alpha=0.5, mu_point=0.1, mu_plane=mu_plane)
    D.update_positions(pairs, alpha=0.5, mu_point=0.1, mu_plane=mu_plane)
    np.testing.assert_allclose(D.positions, want, rtol=0, atol=1e-9)
    before = D.positions.copy()
    D.update_positions(pairs, alpha=0.5, mu_point=0.1, mu_plane=mu_plane)
    np.testing.assert_allclose(D.positions, before, atol=1e-6)
    _rest(D)


def test_rotation_step_rejects_non_finite_sums(deformation):
    # LAPACK is called directly (no longer through numba's np.linalg.svd, which checked this)
    D = deformation
    _rest(D)
    D.positions = D.graph.rest.copy()
    D.positions[3] = np.nan
    with pytest.raises(np.linalg.LinAlgError, match="infs or NaNs"):
        D.update_rotations(None)
    _rest(D)


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("seed", [0, 1])
def test_weighted_pairs_equal_the_numpy_formula(seed):
    # the closest-point pairs' weights and the pairs kept: incompatible normals, an infinite
    # and a zero distance, repeated vertices, both directions and each direction alone
    rng = np.random.default_rng(seed)
    n1, n2 = 400, 300
    Ns, Vt, Nt = _unit(rng, n1), rng.standard_normal((n2, 3)), _unit(rng, n2)
    src = rng.choice(n1, 250, replace=False)
    j = rng.integers(0, n2, len(src))
    d = rng.uniform(0, 0.2, len(src))
    d[3], d[7] = np.inf, 0.0
    tgt = rng.integers(0, n2, 200)
    i = rng.integers(0, n1, len(tgt))
    d2 = rng.uniform(0, 0.2, len(tgt))
    empty_i, empty_d = np.zeros(0, dtype=np.int64), np.zeros(0)
    for args in ((src, j, d, tgt, i, d2), (src, j, d, empty_i, empty_i, empty_d), (empty_i, empty_i, empty_d, tgt, i, d2)):
        got = _weighted_pairs(*args, Ns, Vt, Nt, 0.05, 0.3)
        want = ref.weighted_pairs(*args, Ns, Vt, Nt, 0.05, 0.3)
        assert 0 < len(want.source) < len(args[0]) + len(args[3])  # some pairs dropped, some kept
        np.testing.assert_array_equal(got.source, want.source)
        np.testing.assert_array_equal(got.points, want.points)
        np.testing.assert_array_equal(got.normals, want.normals)
        np.testing.assert_allclose(got.weights, want.weights, rtol=0, atol=1e-15)
    assert len(_weighted_pairs(empty_i, empty_i, empty_d, empty_i, empty_i, empty_d, Ns, Vt, Nt, 0.05, 0.3).source) == 0


@pytest.mark.parametrize("blocks_of", ["point", "plane"])
def test_dense_system_equals_the_fancy_indexed_one(deformation, blocks_of):
    rng = np.random.default_rng(5)
    P = deformation._pattern
    m = len(P.diagonal)
    keys = [(0, 0)] if blocks_of == "point" else [(i, j) for i in range(3) for j in range(i, 3)]
    blocks = {ij: rng.standard_normal(P.n_entries) for ij in keys}
    want = ref.dense_system(blocks, P.rows, P.cols, m, 1e-3)
    H = np.zeros(want.shape, order="F")
    dense_blocks(P.rows, P.cols, np.array([i for i, _ in keys]), np.array([j for _, j in keys]), np.array(list(blocks.values())), m, 1e-3, H)
    np.testing.assert_array_equal(H, want)
    assert np.count_nonzero(np.tril(H, -1)) == 0  # the upper triangle only, as LAPACK reads it


@pytest.fixture
def banded(monkeypatch) -> list[tuple[int, int]]:
    """The banded solve switched on for any band (this small graph's is half its size); the shapes it was called with."""
    monkeypatch.setattr(register, "BANDED_SOLVE", True)
    monkeypatch.setattr(register, "_BAND_MAX", 1.0)
    called: list[tuple[int, int]] = []
    solve = register.banded_cholesky_solve
    monkeypatch.setattr(register, "banded_cholesky_solve", lambda ab, b: called.append(ab.shape) or solve(ab, b))
    return called


def test_banded_system_is_the_dense_one_reordered(deformation):
    rng = np.random.default_rng(6)
    P = deformation._pattern
    m = len(P.diagonal)
    keys = [(i, j) for i in range(3) for j in range(i, 3)]
    blocks = {ij: rng.standard_normal(P.n_entries) for ij in keys}
    bi, bj, values = np.array([i for i, _ in keys]), np.array([j for _, j in keys]), np.array(list(blocks.values()))
    H = np.zeros((3 * m, 3 * m), order="F")
    dense_blocks(P.rows, P.cols, bi, bj, values, m, 1e-3, H)
    full = np.triu(H) + np.triu(H, 1).T
    position, old_of_new, kd = P.band(3)
    assert kd < 3 * m - 1  # a band narrower than the matrix
    AB = np.zeros((kd + 1, 3 * m), order="F")
    banded_blocks(P.rows, P.cols, bi, bj, values, 3, 1e-3, position, AB)
    reordered = full[np.ix_(old_of_new, old_of_new)]
    i, j = np.triu_indices(3 * m)
    inside = j - i <= kd
    np.testing.assert_array_equal(AB[kd + i[inside] - j[inside], j[inside]], reordered[i[inside], j[inside]])
    assert np.count_nonzero(reordered[i[~inside], j[~inside]]) == 0  # nothing outside the band


def test_banded_solve_equals_the_dense_one(deformation, banded):
    rng = np.random.default_rng(7)
    P = deformation._pattern
    m = len(P.diagonal)
    keys = [(i, j) for i in range(3) for j in range(i, 3)]
    # a positive definite system on the pattern: the Gram blocks of random pairs plus a Laplacian
    D = deformation
    pairs = _pairs(D, rng, 2)
    w = rng.uniform(0.1, 1.0, (len(pairs.source), 6))
    w[:, [0, 3, 5]] += 2.0
    G = P.grams(pairs.source, w)
    Lg = P.laplacian(rng.uniform(0.5, 1.0, 2 * len(D.graph.links)))
    blocks = {ij: G[:, k] + (Lg if ij[0] == ij[1] else 0.0) for k, ij in enumerate(keys)}
    rhs, x0 = rng.standard_normal(3 * m), rng.standard_normal(3 * m)
    got = P.solve(blocks, rhs, x0)
    assert banded  # the band path was taken
    eps = 1e-8 * float(np.concatenate([blocks[i, i][P.diagonal] for i in range(3)]).mean())
    H = ref.dense_system(blocks, P.rows, P.cols, m, eps)
    want = np.linalg.solve(np.triu(H) + np.triu(H, 1).T, rhs + eps * x0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-10 * np.abs(want).max())


def test_horn_rotation_is_the_svd_rotation():
    rng = np.random.default_rng(8)
    N, V, got = np.empty((4, 4)), np.empty((4, 4)), np.empty((3, 3))
    for _ in range(200):
        S = rng.standard_normal((3, 3)) * 10.0 ** rng.uniform(-4, 3)
        U, _, Vt = np.linalg.svd(S)
        if np.linalg.det(Vt.T @ U.T) < 0:
            Vt[2] *= -1
        want = Vt.T @ U.T  # the rotation maximising tr(R S)
        _horn_rotation(S.ravel(order="F").copy(), N, V, got)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
        np.testing.assert_allclose(got @ got.T, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_quaternion_rotation_step_equals_the_svd_one(deformation, seed, monkeypatch):
    rng = np.random.default_rng(seed)
    D = deformation
    _moved(D, rng)
    pairs = _pairs(D, rng, 2)
    start = D.rotations.copy()
    monkeypatch.setattr(register, "QUATERNION_ROTATIONS", False)  # LAPACK's SVDs
    D.update_rotations(pairs, data_weight=0.8)
    want = D.rotations.copy()
    monkeypatch.setattr(register, "QUATERNION_ROTATIONS", True)
    D.rotations = start
    D.update_rotations(pairs, data_weight=0.8)
    np.testing.assert_allclose(D.rotations, want, rtol=0, atol=1e-9)
    _rest(D)


def test_banded_position_step_equals_the_dense_one(deformation, request, monkeypatch):
    rng = np.random.default_rng(12)
    D = deformation
    _moved(D, rng)
    pairs = _pairs(D, rng, 2)
    start = D.positions.copy()
    monkeypatch.setattr(register, "BANDED_SOLVE", False)  # the dense factorisation
    D.update_positions(pairs, alpha=0.5, mu_point=0.1, mu_plane=0.7)
    want = D.positions.copy()
    banded = request.getfixturevalue("banded")  # from here on, the band path
    D.positions = start
    D.update_positions(pairs, alpha=0.5, mu_point=0.1, mu_plane=0.7)
    assert banded  # the band path was taken
    np.testing.assert_allclose(D.positions, want, rtol=0, atol=1e-9)
    _rest(D)
