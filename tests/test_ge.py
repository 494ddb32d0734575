"""GE (Green's function embedding alignment, SHREC'16 §4.2): pieces and end-to-end."""

from __future__ import annotations

import numpy as np
import pytest

from topomatch.matching import MATCHERS, NotFittedError
from topomatch.matching.ge import (
    GreenEmbeddingGT4Matcher,
    GreenEmbeddingMatcher,
    align_green_embeddings,
    solve_linear_map,
)

from ._shrec16_toys import as_shape, bent, planar_errors, reference_shape, sheet, shuffled


@pytest.fixture(scope="module")
def flat():
    return sheet()


@pytest.fixture(scope="module")
def rolled(flat):
    return shuffled(bent(flat, 0.3, name="rolled"), seed=1)


def test_registered():
    assert MATCHERS["ge"] is GreenEmbeddingMatcher
    assert MATCHERS["ge-gt4"] is GreenEmbeddingGT4Matcher
    assert GreenEmbeddingGT4Matcher.uses_ground_truth
    assert GreenEmbeddingGT4Matcher.ground_truth_note == "uses 4 ground-truth landmarks"
    assert not GreenEmbeddingMatcher.uses_ground_truth


def test_solve_linear_map_recovers_a_known_map(rng):
    E1 = rng.standard_normal((200, 6))
    G_true = rng.standard_normal((5, 6))
    E2 = E1 @ G_true.T
    idx = np.arange(200)
    G = solve_linear_map(E1, E2, [(idx[:4], idx[:4]), (idx, idx)], eps=1e-10)
    assert np.allclose(G, G_true, atol=1e-6)
    # equal weight per set: a set of 4 pairs counts as much as one of 200
    bad = rng.standard_normal((4, 5))
    E2b = E2.copy()
    E2b[:4] = bad
    Gw = solve_linear_map(E1, E2b, [(idx[:4], idx[:4]), (idx[4:], idx[4:])], eps=1e-10)
    Gu = solve_linear_map(E1, E2b, [(idx, idx)], eps=1e-10)
    assert np.linalg.norm(Gw - G_true) > np.linalg.norm(Gu - G_true)
    with pytest.raises(ValueError, match="source and"):
        solve_linear_map(E1, E2, [(idx[:3], idx[:4])])


def test_align_identical_embeddings(rng):
    E = rng.standard_normal((300, 8))
    lm = np.array([0, 50, 100, 150])
    samples = np.arange(0, 300, 3)
    p2p, G, c1, c2 = align_green_embeddings(E, E, lm, lm, samples, samples, n_iter=5, n_dense=1)
    assert np.array_equal(p2p, np.arange(300))
    assert np.allclose(G, np.eye(8), atol=1e-4)
    assert len(c1) == len(c2) == 600


def test_gt4_on_bent_sheet(flat, rolled):
    target, orig = rolled
    m = GreenEmbeddingGT4Matcher(k=30, n_samples=300)
    m.fit([reference_shape(flat), as_shape(target, orig, flat.n_vertices, "rolled")])
    corr = m.match(flat, target)
    err = planar_errors(flat, corr.p2p_21, orig)
    assert len(err) == target.n_vertices  # dense
    assert np.mean(err < 0.05) > 0.9
    assert err.mean() < 0.03
    # the landmarks are ground-truth pairs
    ls, lt = np.array(corr.info["landmarks_source"]), np.array(corr.info["landmarks_target"])
    assert np.array_equal(orig[lt], ls)


def test_automatic_landmarks_on_bent_sheet(flat, rolled):
    target, orig = rolled
    corr = GreenEmbeddingMatcher(k=30, n_samples=300).match(flat, target)
    err = planar_errors(flat, corr.p2p_21, orig)
    assert np.mean(err < 0.05) > 0.85
    assert err.mean() < 0.05


def test_deterministic(flat, rolled):
    target, _ = rolled
    a = GreenEmbeddingMatcher(k=20, n_samples=200, n_iter=10, random_state=4).match(flat, target)
    b = GreenEmbeddingMatcher(k=20, n_samples=200, n_iter=10, random_state=4).match(flat, target)
    assert np.array_equal(a.p2p_21, b.p2p_21)


def test_sparse_output_without_dense_iterations(flat, rolled):
    target, _ = rolled
    corr = GreenEmbeddingMatcher(k=20, n_samples=100, n_iter=5, n_dense=0).match(flat, target)
    assert (corr.p2p_21 >= 0).sum() == 100


def test_gt4_needs_fit_and_known_shapes(flat, rolled):
    target, orig = rolled
    with pytest.raises(NotFittedError):
        GreenEmbeddingGT4Matcher().match(flat, target)
    with pytest.raises(ValueError, match="reference"):
        GreenEmbeddingGT4Matcher().fit([as_shape(target, orig, flat.n_vertices, "rolled")])
    m = GreenEmbeddingGT4Matcher(k=10, n_samples=50).fit([reference_shape(flat)])
    with pytest.raises(ValueError, match="no ground truth"):
        m.match(flat, target)


@pytest.mark.parametrize(("params", "message"), [({"k": 2}, "k"), ({"n_dense": 50}, "n_dense"), ({"eps": -1.0}, "eps"), ({"n_extremities": 3}, "n_extremities")])
def test_bad_hyperparameters(flat, params, message):
    with pytest.raises(ValueError, match=message):
        GreenEmbeddingMatcher(**params).match(flat, flat)


@pytest.mark.data
@pytest.mark.slow
def test_topkids_smoke(topkids_low):
    names = ["kid00", "kid10", "kid11"]
    m = GreenEmbeddingGT4Matcher().fit([topkids_low[n] for n in names])
    src, tgt = topkids_low["kid11"], topkids_low["kid10"]
    corr = m.match(src.mesh, tgt.mesh)
    assert corr.p2p_21.shape == (tgt.n_vertices,)
    assert corr.p2p_21.min() >= 0
    auto = GreenEmbeddingMatcher().match(src.mesh, tgt.mesh)
    assert auto.p2p_21.min() >= 0
