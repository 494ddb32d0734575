import numpy as np
import pytest

from topomatch.datasets.base import ground_truth_21
from topomatch.evaluation.metrics import SHREC16_THRESHOLDS
from topomatch.evaluation.protocols import PairSpec, get_protocol
from topomatch.evaluation.scoring import score_maps, summarize


def gt_map(collection, pair, mirrored=False):
    g = ground_truth_21(collection[pair.target], collection[pair.source], mirrored=mirrored)
    p2p = np.full(g.shape[0], -1, dtype=np.int64)
    has = np.diff(g.indptr) > 0
    p2p[has] = g.indices[g.indptr[:-1][has]]
    return p2p


def test_pair_enumeration(builtin):
    sh = get_protocol("shrec16")
    pairs = sh.pairs(builtin)
    assert len(pairs) == 4 * 3 and all(p.target != p.source for p in pairs)
    tk = get_protocol("topkids25")
    pairs = tk.pairs(builtin)
    assert len(pairs) == 10 and {p.source for p in pairs} == {"syn00"}
    assert PairSpec.from_id("kid16-kid17") == PairSpec("kid16", "kid17")
    with pytest.raises(ValueError, match="not of the form"):
        PairSpec.from_id("kid16kid17")
    with pytest.raises(ValueError, match="unknown protocol"):
        get_protocol("faust")


@pytest.mark.parametrize("protocol", ["shrec16", "topkids25"])
def test_oracle_scores_perfectly(builtin, protocol):
    p = get_protocol(protocol)
    maps = {("oracle", pr.id): gt_map(builtin, pr) for pr in p.pairs(builtin)}
    for kind in p.geodesics:
        scores = score_maps(builtin, p, maps, geodesic=kind)
        s = summarize(scores, p)
        assert s["mean_error"] == 0.0
        assert s["auc_mean"] == 1.0 and s["auc_worst"] == 1.0
        assert all(x.n_scored > 0 for x in scores)


def test_mirror_needs_symmetric_credit(builtin):
    p = get_protocol("shrec16")
    maps = {("mirror", pr.id): gt_map(builtin, pr, mirrored=True) for pr in p.pairs(builtin)[::3]}  # four pairs: each test shape once a target
    with_sym = summarize(score_maps(builtin, p, maps), p)
    assert with_sym["auc_mean"] == 1.0 and with_sym["symmetric_fraction"] == 1.0
    no_sym = summarize(score_maps(builtin, p.with_options(symmetric=False), maps), p)
    assert no_sym["auc_mean"] < 0.8 and no_sym["symmetric_fraction"] == 0.0


def test_random_map_matches_its_expectation(builtin):
    """E[curve(t)] = mean over scored x of P_y(d(y*, y) <= t) for y uniform over vertices."""
    p = get_protocol("shrec16").with_options(symmetric=False)
    pairs = p.pairs(builtin)[:1]
    rng = np.random.default_rng(0)
    maps = {("random", pr.id): rng.integers(0, builtin[pr.source].n_vertices, builtin[pr.target].n_vertices) for pr in pairs}
    scores = score_maps(builtin, p, maps)
    for pr, sc in zip(pairs, scores):
        src = builtin[pr.source]
        g = ground_truth_21(builtin[pr.target], src)
        has = np.diff(g.indptr) > 0
        ystar = g.indices[g.indptr[:-1][has]]  # builtin ground truth is one-to-one
        d = src.mesh.geodesic_solver("heat").distances_from(np.unique(ystar)) / np.sqrt(src.mesh.area)
        lookup = {s: i for i, s in enumerate(np.unique(ystar))}
        rows = d[[lookup[s] for s in ystar]]
        expected = np.array([(rows <= t).mean() for t in SHREC16_THRESHOLDS])
        exp_auc = np.trapezoid(expected, SHREC16_THRESHOLDS) / 0.25
        assert abs(sc.auc - exp_auc) < 0.01, (pr.id, sc.auc, exp_auc)


def test_unmatched_and_excluded_are_counted(builtin):
    p = get_protocol("shrec16")
    pr = p.pairs(builtin)[0]
    m = gt_map(builtin, pr)
    reliable = np.flatnonzero((m >= 0) & ~builtin[pr.target].unreliable)[:100]  # vertices that would be scored
    m[reliable] = -1
    sc = score_maps(builtin, p, {("half", pr.id): m})[0]
    assert sc.n_unmatched + sc.n_excluded + sc.n_scored == sc.n_target
    assert sc.n_unmatched >= 100 and sc.auc == 1.0  # sparse maps are scored on matched points


def test_bad_maps_are_rejected(builtin):
    p = get_protocol("shrec16")
    pr = p.pairs(builtin)[0]
    with pytest.raises(ValueError, match="entries"):
        score_maps(builtin, p, {("x", pr.id): np.zeros(5, dtype=np.int64)})
    bad = np.full(builtin[pr.target].n_vertices, builtin[pr.source].n_vertices)
    with pytest.raises(ValueError, match="outside"):
        score_maps(builtin, p, {("x", pr.id): bad})


@pytest.mark.data
def test_real_topkids_oracle_and_mirror(topkids_low):
    p = get_protocol("shrec16")
    pairs = p.pairs(topkids_low)
    assert len(pairs) == 90
    some = pairs[:1]
    maps = {("oracle", pr.id): gt_map(topkids_low, pr) for pr in some}
    maps.update({("mirror", pr.id): gt_map(topkids_low, pr, mirrored=True) for pr in some})
    scores = score_maps(topkids_low, p, maps)
    assert all(s.auc == 1.0 and s.mean_error == 0.0 for s in scores)
    assert all(s.symmetric_used for s in scores if s.method == "mirror")
    # composing through kid00 leaves some vertices without an exact partner: excluded, counted
    assert all(0 < s.n_excluded < 0.3 * s.n_target for s in scores)
    tk = get_protocol("topkids25")
    assert len(tk.pairs(topkids_low)) == 25
    assert len(tk.pairs(topkids_low, "test")) == 10


@pytest.mark.data
def test_high_res_ground_truth_is_many_to_many(topkids_high):
    t, s = topkids_high["kid01"], topkids_high["kid02"]
    g = ground_truth_21(t, s)
    counts = np.diff(g.indptr)
    assert counts.max() > 1
    assert np.all(counts[t.unreliable] == 0)  # flagged vertices are excluded
    pairs = get_protocol("shrec16").pairs(topkids_high, "train")
    assert len(pairs) == 13 * 12  # kid04 and kid05 meshes are absent from the copy
