"""EM (Sahillioglu & Yemez 2012 as entered in SHREC'16): pieces and end-to-end on known answers."""

from __future__ import annotations

import numpy as np
import pytest

from topomatch.matching import MATCHERS, make_matcher
from topomatch.matching._spectral import classical_mds
from topomatch.matching.em import IsometricEmbeddingEMMatcher, greedy_refine, isometric_distortion
from topomatch.mesh.biharmonic import biharmonic_distances, biharmonic_embedding, unit_area_basis

from ._shrec16_toys import bent, planar_errors, sheet, shuffled


@pytest.fixture(scope="module")
def flat():
    return sheet()


def test_registered():
    assert MATCHERS["em"] is IsometricEmbeddingEMMatcher
    assert make_matcher("em", n_samples=50).n_samples == 50


def test_biharmonic_distance_matches_formula(small_sphere):
    basis = unit_area_basis(small_sphere.eigenbasis(30), small_sphere.area)
    emb = biharmonic_embedding(basis)
    assert emb.shape == (small_sphere.n_vertices, 29)  # the constant eigenpair is dropped
    i, j = 3, 17
    ref = np.sqrt(np.sum((basis.evecs[i, 1:] - basis.evecs[j, 1:]) ** 2 / basis.evals[1:] ** 2))
    assert biharmonic_distances(emb, [i], [j])[0, 0] == pytest.approx(ref, rel=1e-10)
    D = biharmonic_distances(emb, np.arange(10))
    assert D.shape == (10, small_sphere.n_vertices)
    assert np.allclose(np.diag(D[:, :10]), 0.0, atol=1e-6)


def test_unit_area_basis_is_scale_invariant(small_sphere):
    from topomatch.mesh import TriangleMesh

    big = TriangleMesh(small_sphere.vertices * 3.0, small_sphere.faces)
    e1 = biharmonic_embedding(unit_area_basis(small_sphere.eigenbasis(10), small_sphere.area))
    e2 = biharmonic_embedding(unit_area_basis(big.eigenbasis(10), big.area))
    d1 = biharmonic_distances(e1, np.arange(5), np.arange(5))
    d2 = biharmonic_distances(e2, np.arange(5), np.arange(5))
    assert np.allclose(d1, d2, rtol=1e-5, atol=1e-8)
    with pytest.raises(ValueError, match="area"):
        unit_area_basis(small_sphere.eigenbasis(10), -1.0)


def test_classical_mds_recovers_euclidean_points(rng):
    X = rng.standard_normal((40, 3)) * [3.0, 2.0, 1.0]
    D = np.linalg.norm(X[:, None] - X[None], axis=2)
    Y = classical_mds(D, 3)
    assert np.allclose(np.linalg.norm(Y[:, None] - Y[None], axis=2), D, atol=1e-8)
    with pytest.raises(ValueError, match="square"):
        classical_mds(D[:5], 2)


def test_greedy_refine_lowers_distortion_to_the_truth(rng):
    X = rng.standard_normal((30, 2))
    D = np.linalg.norm(X[:, None] - X[None], axis=2)
    perm = rng.permutation(30)
    D2 = D[np.ix_(perm, perm)]  # target sample j is source sample perm[j]
    start = perm.copy()
    start[[0, 1, 2, 3]] = start[[3, 2, 1, 0]]  # spoil four entries
    before = isometric_distortion(D, D2, start)
    m, n_swaps = greedy_refine(D, D2, start)
    assert n_swaps >= 1
    assert isometric_distortion(D, D2, m) < before
    assert np.array_equal(m, perm)
    assert sorted(m) == list(range(30))  # still one-to-one


def test_isometric_copy_is_matched_exactly(flat):
    target, orig = shuffled(flat, seed=3)
    corr = IsometricEmbeddingEMMatcher(n_samples=80, k=40).match(flat, target)
    matched = corr.p2p_21 >= 0
    assert matched.sum() == 80
    assert np.array_equal(corr.p2p_21[matched], orig[matched])
    assert corr.info["distortion"] == pytest.approx(0.0, abs=1e-9)


def test_bent_sheet_sparse_map(flat):
    """An exact isometry (rolling) with shuffled vertices: the known answer is recovered."""
    target, orig = shuffled(bent(flat, 0.3), seed=1)
    corr = IsometricEmbeddingEMMatcher(n_samples=80, k=40).match(flat, target)
    err = planar_errors(flat, corr.p2p_21, orig)
    assert len(err) == 80
    assert np.mean(err < 0.05) >= 0.9
    assert np.median(err) < 0.02


def test_deterministic(flat):
    target, _ = shuffled(bent(flat, 0.4), seed=2)
    a = IsometricEmbeddingEMMatcher(n_samples=60, k=30, random_state=1).match(flat, target)
    b = IsometricEmbeddingEMMatcher(n_samples=60, k=30, random_state=1).match(flat, target)
    assert np.array_equal(a.p2p_21, b.p2p_21)


@pytest.mark.parametrize(
    ("params", "message"),
    [({"n_samples": 2}, "n_samples"), ({"mds_dim": 9}, "mds_dim"), ({"max_iter": 0}, "max_iter"), ({"k": "x"}, "k")],
)
def test_bad_hyperparameters(flat, params, message):
    with pytest.raises(ValueError, match=message):
        IsometricEmbeddingEMMatcher(**params).match(flat, flat)


@pytest.mark.data
def test_topkids_smoke(topkids_low):
    src, tgt = topkids_low["kid11"], topkids_low["kid10"]
    corr = IsometricEmbeddingEMMatcher().match(src.mesh, tgt.mesh)
    p = corr.p2p_21
    assert p.shape == (tgt.n_vertices,)
    assert (p >= 0).sum() == 250
    assert len(np.unique(p[p >= 0])) == 250  # one-to-one
