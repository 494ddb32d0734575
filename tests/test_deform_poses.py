"""The deform matcher's hypotheses (rigid, articulated, known poses), limb turns and posed sources."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from scipy.spatial import cKDTree

from topomatch.deform.graph import build_deformation_graph
from topomatch.deform.register import fit_residual
from topomatch.maps import folded_fraction
from topomatch.matching import make_matcher
from topomatch.matching.deform import (
    _rank_poses,
    _sphere_directions,
    articulated_hypotheses,
    bend_in_two,
    local_wks_features,
    map_from_deformed,
    pose_hypotheses,
    rigid_hypotheses,
    source_limbs,
    spectral_hypotheses,
    turn_limb,
)
from topomatch.mesh import TriangleMesh
from topomatch.mesh.geometry import axis_rotation
from topomatch.mesh.sampling import farthest_point_sampling

from ._fmap_shapes import bumpy, shuffled


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_rigid_hypotheses_recover_a_rotated_scaled_moved_copy():
    src = bumpy(4, mirror_symmetric=False)
    tgt0, perm = shuffled(src, seed=5)  # tgt0 vertex i is source vertex perm[i]
    R = _rotation(np.array([1.0, 2.0, 0.5]), 2.0)
    tgt = TriangleMesh(1.7 * tgt0.vertices @ R.T + np.array([3.0, -1.0, 2.0]), tgt0.faces)
    s1 = np.arange(0, src.n_vertices, 3)
    s2 = np.arange(0, tgt.n_vertices, 3)
    scale = np.sqrt(src.area)
    errors = {}
    for h in rigid_hypotheses(src, tgt, s1, s2):
        assert h.p2p.shape == s2.shape and h.target is None
        errors[h.label] = np.mean(np.linalg.norm(src.vertices[h.p2p] - src.vertices[perm[s2]], axis=1)) / scale
    assert len(errors) == 5 and "rigid as-given" in errors
    # one of the four principal-axis frames is the true rotation: exact up to the nearest vertex
    assert min(v for k, v in errors.items() if k.startswith("rigid axes")) < 0.01
    # the identity is wrong for this rotation (the ICP cannot undo 115 degrees)
    assert errors["rigid as-given"] > 0.1
    # unrotated data: "as given" alone is right
    moved = TriangleMesh(1.7 * tgt0.vertices + 2.0, tgt0.faces)
    (h,) = rigid_hypotheses(src, moved, s1, s2, ("as-given",))
    assert np.mean(np.linalg.norm(src.vertices[h.p2p] - src.vertices[perm[s2]], axis=1)) / scale < 0.01
    with pytest.raises(ValueError, match="rigid frames"):
        list(rigid_hypotheses(src, moved, s1, s2, ("sideways",)))


def test_bend_in_two_turns_one_half_about_the_hinge(builtin):
    mesh = builtin["syn00"].mesh
    basis = mesh.eigenbasis(2)
    f, mass = basis.evecs[:, 1], basis.mass
    bends = bend_in_two(mesh.vertices, mesh.faces, f, mass, (90.0,))
    assert [label for label, _ in bends] == ["half a +90", "half a -90", "half b +90", "half b -90"]
    V = mesh.vertices
    f_mid = np.sort(f)[np.searchsorted(np.cumsum(mass[np.argsort(f)]), 0.5 * mass.sum())]
    half_a = f > f_mid
    assert 0.45 < mass[half_a].sum() / mass.sum() < 0.55
    moved = [np.linalg.norm(Vb - V, axis=1) > 1e-9 for _, Vb in bends]
    assert np.array_equal(moved[0], moved[1]) and np.array_equal(moved[2], moved[3])
    assert np.array_equal(moved[0], ~moved[2])  # the two halves, each turned as a whole
    assert (moved[0] >= half_a).all() and (moved[0] <= (f >= f_mid)).all()  # the vertices at the median join one side
    for label, Vb in bends:
        turned = moved[0] if label.startswith("half a") else moved[2]
        # rigid per half: distances within the turned half are kept
        i, j = np.flatnonzero(turned)[[0, -1]]
        assert np.isclose(np.linalg.norm(Vb[i] - Vb[j]), np.linalg.norm(V[i] - V[j]))
    # the split direction (between the halves' centroids) turns by the bending angle
    d0 = V[half_a].mean(0) - V[~half_a].mean(0)
    Vb = bends[0][1]
    d1 = Vb[half_a].mean(0) - Vb[~half_a].mean(0)
    hinge_dist = np.linalg.norm(V[half_a].mean(0) - Vb[half_a].mean(0))
    assert hinge_dist > 0.1 * np.linalg.norm(d0) and np.degrees(np.arccos(d0 @ d1 / np.linalg.norm(d0) / np.linalg.norm(d1))) > 20
    # the set of bent shapes does not depend on the eigenvector's sign
    flipped = bend_in_two(V, mesh.faces, -f, mass, (90.0,))
    for _, Vb in bends:
        assert min(np.abs(Vb - Wb).max() for _, Wb in flipped) < 1e-9 * np.abs(V).max()


def test_articulated_hypotheses_recover_a_figure_bent_in_two(builtin):
    src = builtin["syn00"].mesh
    basis = src.eigenbasis(2)
    label, Vb = bend_in_two(src.vertices, src.faces, basis.evecs[:, 1], basis.mass, (90.0,))[2]
    tgt0, perm = shuffled(TriangleMesh(Vb, src.faces), seed=4)  # tgt0 vertex i is source vertex perm[i]
    tgt = TriangleMesh(1.3 * tgt0.vertices + np.array([0.5, -2.0, 1.0]), tgt0.faces)
    s1 = np.arange(0, src.n_vertices, 4)
    s2 = np.arange(0, tgt.n_vertices, 4)
    scale = np.sqrt(src.area)

    def error(p2p: np.ndarray) -> float:
        return float(np.mean(np.linalg.norm(src.vertices[p2p] - src.vertices[perm[s2]], axis=1)) / scale)

    hyps = list(articulated_hypotheses(src, tgt, s1, s2, n_keep=4, angles=(90.0,)))
    assert len(hyps) == 4 and all(h.p2p.shape == s2.shape for h in hyps)
    assert hyps[0].label == f"bent {label}"  # the best-fitting bent copy comes first
    assert error(hyps[0].p2p) < 0.01
    assert min(error(h.p2p) for h in hyps[1:]) > 0.05
    (rigid,) = rigid_hypotheses(src, tgt, s1, s2, ("as-given",))
    assert error(rigid.p2p) > 0.05  # unbent, the rigid hypothesis cannot reach the pose
    # with the default angles (60, 90, 120) the right one still fits best
    (best,) = articulated_hypotheses(src, tgt, s1, s2, n_keep=1)
    assert best.label == f"bent {label}"


def _bent_syn00(builtin, seed: int) -> tuple[TriangleMesh, list, TriangleMesh, np.ndarray]:
    """syn00, its copies bent in two at 90 degrees, and the third bent copy shuffled (vertex ``i`` is syn00's ``perm[i]``)."""
    src = builtin["syn00"].mesh
    basis = src.eigenbasis(2)
    bends = bend_in_two(src.vertices, src.faces, basis.evecs[:, 1], basis.mass, (90.0,))
    tgt, perm = shuffled(TriangleMesh(bends[2][1], src.faces), seed=seed)
    return src, bends, tgt, perm


# a fast registration for the small pose tests (no limb rounds, no feature stage, no bent hypotheses)
_FAST_POSED = {"n_samples": 600, "coarse_nodes": 80, "fine_nodes": 150, "limb_rounds": 0, "feature_icp_iterations": 0, "articulated": 0}


def test_pose_hypotheses_find_the_known_pose(builtin):
    src, bends, tgt0, perm = _bent_syn00(builtin, seed=6)  # tgt0 vertex i is source vertex perm[i]
    R = _rotation(np.array([0.3, 1.0, 0.2]), 2.5)  # beyond the reach of an ICP from the frame as given
    tgt = TriangleMesh(1.2 * tgt0.vertices @ R.T + np.array([1.0, 2.0, -0.5]), tgt0.faces)
    s1 = np.arange(0, src.n_vertices, 4)
    s2 = np.arange(0, tgt.n_vertices, 4)
    scale = np.sqrt(src.area)

    def error(p2p: np.ndarray) -> float:
        return float(np.mean(np.linalg.norm(src.vertices[p2p] - src.vertices[perm[s2]], axis=1)) / scale)

    poses = [("a", bends[0][1]), ("b", bends[2][1]), ("rest", src.vertices)]
    hyps = list(pose_hypotheses(src, tgt, s1, s2, poses, n_keep=2))
    assert len(hyps) == 2 and all(h.p2p.shape == s2.shape and h.target is None for h in hyps)
    # the known pose, from one of the principal-axes starts, fits best and is right
    assert hyps[0].label.startswith("pose b axes ") and error(hyps[0].p2p) < 0.01
    # as given (no rotation), the ICP cannot undo the turn
    (given,) = pose_hypotheses(src, tgt, s1, s2, poses[1:2], n_keep=1, frames=("as-given",))
    assert given.label == "pose b" and error(given.p2p) > 0.05
    with pytest.raises(ValueError, match="pose 'bad'"):
        list(pose_hypotheses(src, tgt, s1, s2, [("bad", src.vertices[:-1])]))
    with pytest.raises(ValueError, match="frames"):
        list(pose_hypotheses(src, tgt, s1, s2, poses, frames=("sideways",)))


def test_deform_verifies_the_pose_hypotheses(builtin, monkeypatch):
    src, bends, tgt, perm = _bent_syn00(builtin, seed=7)
    fast = _FAST_POSED
    m = make_matcher("deform", **fast)
    poses = [("b", bends[2][1]), ("a", bends[0][1])]
    hyps, results = m.verify_hypotheses(src, tgt, poses=poses)
    labels = [h.label for h in hyps]
    assert sum(label.startswith("pose ") for label in labels) == 3 == m.pose_keep
    assert labels[int(np.argmin([r.residual for r in results]))].startswith("pose b")
    deformed, info = m.register(src, tgt, poses=poses)
    assert info["hypothesis"].startswith("pose b")
    p2p = map_from_deformed(tgt, deformed, src.faces)
    assert np.median(np.linalg.norm(src.vertices[p2p] - src.vertices[perm], axis=1)) / np.sqrt(src.area) < 0.01
    # the rigid hypotheses from every frame, unless rigid_frames_with_poses narrows them where the poses are
    assert sum(label.startswith("rigid axes ") for label in labels) == 4 and "rigid as-given" in labels
    narrow = make_matcher("deform", **fast, rigid_frames_with_poses=("as-given",))
    narrow_labels = [h.label for h in narrow.verify_hypotheses(src, tgt, poses=poses)[0]]
    assert [x for x in labels if not x.startswith("rigid axes ")] == narrow_labels
    # the poses' own alignments still start from every frame; without poses every rigid frame is verified
    assert any(" axes " in x for x in narrow_labels if x.startswith("pose "))
    assert sum(h.label.startswith("rigid axes ") for h in narrow.verify_hypotheses(src, tgt)[0]) == 4
    # the poses ranked on a prefix of the samples (a farthest-point sample itself): the known pose still wins
    import topomatch.matching.deform as deform_module

    sizes = []
    ranked = deform_module._rank_poses
    monkeypatch.setattr(deform_module, "_rank_poses", lambda source, target, s1, s2, *a, **k: sizes.append((len(s1), len(s2))) or ranked(source, target, s1, s2, *a, **k))
    few = make_matcher("deform", **fast, pose_samples=100)
    few_hyps, few_results = few.verify_hypotheses(src, tgt, poses=poses)
    assert sizes == [(100, 100)]
    monkeypatch.setattr(deform_module, "_rank_poses", ranked)
    assert few_hyps[int(np.argmin([r.residual for r in few_results]))].label.startswith("pose b")
    # pose_keep=0 and no poses: no pose hypotheses
    assert not any(h.label.startswith("pose ") for h in make_matcher("deform", **fast, pose_keep=0).verify_hypotheses(src, tgt, poses=poses)[0])
    assert not any(h.label.startswith("pose ") for h in m.verify_hypotheses(src, tgt)[0])
    with pytest.raises(ValueError, match="pose_keep"):
        make_matcher("deform", pose_keep=-1).register(src, tgt)
    # several sampling starts align the poses once (on start 0's samples) and read each start's map off them
    calls = []
    real = deform_module._rank_poses
    monkeypatch.setattr(deform_module, "_rank_poses", lambda *a, **k: calls.append(1) or real(*a, **k))
    _, info2 = make_matcher("deform", **fast, n_starts=2).register(src, tgt, poses=poses)
    assert len(calls) == 1 and len(info2["runs"]) == 2
    assert all(run["hypothesis"].startswith("pose b") for run in info2["runs"])
    # "extra": the poses in one more registration (from start 0) beside the n_starts without them
    _, info3 = make_matcher("deform", **fast, pose_runs="extra").register(src, tgt, poses=poses)
    assert [(run["start"], run["poses"]) for run in info3["runs"]] == [(0, False), (0, True)]
    assert info3["runs"][1]["hypothesis"].startswith("pose b") and not info3["runs"][0]["hypothesis"].startswith("pose")
    assert info3["run"] == int(np.argmin([run["score"] for run in info3["runs"]]))  # the best full-mesh score kept
    with pytest.raises(ValueError, match="pose_runs"):
        make_matcher("deform", pose_runs="some").register(src, tgt)
    with pytest.raises(ValueError, match="pose 'x'"):
        m.register(src, tgt, poses=[("x", np.zeros((3, 3)))])
    with pytest.raises(ValueError, match="pairs"):
        m.register(src, tgt, poses=[np.zeros((3, 3))])


def _part_root(graph, faces_mesh: TriangleMesh, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    limb = np.isin(graph.labels, nodes)
    E = faces_mesh.edges
    leaving = limb[E[:, 0]] != limb[E[:, 1]]
    ring = np.unique(np.where(limb[E[leaving, 0]], E[leaving, 0], E[leaving, 1]))
    return limb, faces_mesh.vertices[ring].mean(axis=0)


def test_source_limbs_are_the_figure_s_head_arms_and_legs(builtin):
    src = builtin["syn00"].mesh
    graph = build_deformation_graph(src.vertices, src.faces, 150)
    parts = source_limbs(graph)
    limbs = parts[:5]
    # five limbs (head, two arms, two legs), disjoint, then outer halves nested in them
    assert 5 <= len(parts) <= 10
    assert len(np.unique(np.concatenate(limbs))) == sum(len(p) for p in limbs)
    for outer in parts[5:]:
        assert any(set(outer) < set(limb) for limb in limbs)
    # the limbs' ends are the figure's extremities: together they hold its five farthest-apart tips
    V = src.vertices
    centre = V.mean(axis=0)
    tips = [int(np.argmax(np.where(np.isin(graph.labels, limb), np.linalg.norm(V - centre, axis=1), -1))) for limb in limbs]
    assert len(set(tips)) == 5
    assert source_limbs(build_deformation_graph(src.vertices, src.faces, 4)) == []


def test_turn_limb_puts_a_turned_limb_back(builtin):
    """The target is the figure with one limb turned; the untouched figure as the
    "registration" leaves that limb in the wrong place, and the search turns it back."""
    src = builtin["syn00"].mesh
    graph = build_deformation_graph(src.vertices, src.faces, 150)
    parts = source_limbs(graph)
    samples = (np.arange(0, src.n_vertices, 3), np.arange(1, src.n_vertices, 3))
    scale = np.sqrt(src.area)
    on_grid = axis_rotation(_sphere_directions(26)[7], np.deg2rad(120.0))  # one of the turns searched
    off_grid = axis_rotation(np.array([0.3, -0.2, 1.0]), np.deg2rad(100.0))
    for k, R, most in ((1, on_grid, 0.1), (3, on_grid, 0.1), (3, off_grid, 0.75)):
        limb, root = _part_root(graph, src, parts[k])
        Vt = src.vertices.copy()
        Vt[limb] = (Vt[limb] - root) @ R.T + root
        tgt = TriangleMesh(Vt, src.faces)
        # how far the limb lies from the target's limb (a turn about its own axis is free)
        tree = cKDTree(Vt[limb])
        before = float(tree.query(src.vertices[limb])[0].mean() / scale)
        found = turn_limb(src, tgt, src.vertices, graph, parts, samples, n_best=3)
        assert 1 <= len(found) <= 3
        moved, move = found[0]
        assert move[0] == k and 0 < move[1] < 1 - 0.005
        after = float(tree.query(moved[limb])[0].mean() / scale)
        assert before > 0.02 and after < most * before, (k, before, after)
        assert np.array_equal(moved[~limb], src.vertices[~limb])  # nothing else moved
        # the other candidates: other parts, each turned alone, ranked by coverage
        ratios = [m[1] for _, m in found]
        assert ratios == sorted(ratios) and len({m[0] for _, m in found}) == len(found)
        for other, (i, _) in found[1:]:
            part = np.isin(graph.labels, parts[i])
            assert np.array_equal(other[~part], src.vertices[~part])
        # n_best=1 is the first of them
        (one, m1), = turn_limb(src, tgt, src.vertices, graph, parts, samples)
        assert m1 == move and np.array_equal(one, moved)
    # a registration already in place: no turn counts
    assert turn_limb(src, src, src.vertices, graph, parts, samples, n_best=3) == []
    with pytest.raises(ValueError, match="n_best"):
        turn_limb(src, src, src.vertices, graph, parts, samples, n_best=0)


def test_deform_reports_the_limb_rounds(builtin):
    target, source = builtin["syn05"], builtin["syn00"]
    kw = {"n_samples": 800, "coarse_nodes": 100, "fine_nodes": 200}
    c = make_matcher("deform", **kw).match(source.mesh, target.mesh)
    rounds = c.info["limbs"]
    assert len(rounds) <= 3
    for r in rounds:
        assert 0 < r["coverage_ratio"] < 1 - 0.005
        assert r["kept"] == (r["score_after"] < r["score"])
        assert r["part"] in r["tried"] and 1 <= len(r["tried"]) <= 2
    kept = [r for r in rounds if r["kept"]]
    assert all(a["score_after"] == b["score"] for a, b in pairwise(kept))  # each round starts where the last ended
    assert make_matcher("deform", limb_rounds=0, **kw).match(source.mesh, target.mesh).info["limbs"] == []


def test_limb_turns_judged_at_the_fine_level(builtin):
    target, source = builtin["syn05"], builtin["syn00"]
    kw = {"n_samples": 800, "coarse_nodes": 100, "fine_nodes": 200}
    coarse = make_matcher("deform", **kw).match(source.mesh, target.mesh).info["limbs"]
    fine = make_matcher("deform", limb_judge="fine", **kw).match(source.mesh, target.mesh).info["limbs"]
    assert coarse and fine  # this pair has limb candidates
    # same search, another judge: the first round tries the same turns
    assert fine[0]["tried"] == coarse[0]["tried"] and fine[0]["coverage_ratio"] == coarse[0]["coverage_ratio"]
    assert all("fine_score" not in r for r in coarse)
    for r in fine:
        assert r["kept"] == (r["fine_score_after"] < r["fine_score"])
    kept = [r for r in fine if r["kept"]]
    assert all(a["fine_score_after"] == b["fine_score"] for a, b in pairwise(kept))
    # the judge's iterations: the final registration's number gives the same map (its
    # registration reused); another number judges with other registrations
    ref = make_matcher("deform", limb_judge="fine", **kw).match(source.mesh, target.mesh)
    same = make_matcher("deform", limb_judge="fine", limb_judge_iterations=40, **kw).match(source.mesh, target.mesh)
    def untimed(rounds: list[dict]) -> list[dict]:
        return [{k: v for k, v in r.items() if k != "seconds"} for r in rounds]

    assert np.array_equal(same.p2p_21, ref.p2p_21) and untimed(same.info["limbs"]) == untimed(ref.info["limbs"])
    short = make_matcher("deform", limb_judge="fine", limb_judge_iterations=3, **kw).match(source.mesh, target.mesh).info["limbs"]
    assert short[0]["tried"] == fine[0]["tried"] and short[0]["fine_score"] != fine[0]["fine_score"]
    assert all(r["kept"] == (r["fine_score_after"] < r["fine_score"]) for r in short)



def test_every_run_s_extrinsic_hypotheses_are_made_before_the_spectral_ones(builtin, monkeypatch):
    """On threads the main thread makes every run's rigid hypotheses before any spectral ones, and a follower's spectral ones before its leader is collected; the results as on one thread."""
    import topomatch.matching.deform as deform_module

    src, bends, tgt, _ = _bent_syn00(builtin, seed=7)
    poses = [("a", bends[0][1]), ("b", bends[2][1])]
    s1_start1 = deform_module.farthest_point_sampling(600, points=src.vertices, first=deform_module._start_vertex(src.n_vertices, 1, 2))
    made: list[tuple[str, str]] = []  # (what, which run) in the order the main thread makes them

    def run_of(source, s1) -> str:
        if not np.array_equal(source.vertices, src.vertices):
            return "posed"
        return "start 1" if np.array_equal(s1, s1_start1) else "start 0"

    def logged(family, make):
        def spy(source, target, s1, *args, **kw):
            for h in make(source, target, s1, *args, **kw):
                made.append((family, run_of(source, s1)))
                yield h
        return spy

    collected = deform_module._collected

    def collect_spy(v):
        made.append(("collected", run_of(v.source, v.samples[0])))
        return collected(v)

    monkeypatch.setattr(deform_module, "rigid_hypotheses", logged("rigid", deform_module.rigid_hypotheses))
    monkeypatch.setattr(deform_module, "spectral_hypotheses", logged("spectral", deform_module.spectral_hypotheses))
    monkeypatch.setattr(deform_module, "_collected", collect_spy)
    fast = {**_FAST_POSED, "n_starts": 2, "pose_sources": 1, "follow_top": 2, "follow_spectral": True}
    two, info_two = make_matcher("deform", **fast, n_threads=2).register(src, tgt, poses=poses)
    made_two = list(made)
    made.clear()
    one, info_one = make_matcher("deform", **fast, n_threads=1).register(src, tgt, poses=poses)
    assert [r["source_pose"] for r in info_two["runs"]] == [None, None, "b"] and "followed" in info_two["runs"][1]
    # start 0 and the posed source are made together (start 1 follows start 0's results):
    # both runs' rigid hypotheses before the first spectral one
    first_spectral = made_two.index(next(x for x in made_two if x[0] == "spectral"))
    assert {run for family, run in made_two[:first_spectral] if family == "rigid"} == {"start 0", "posed"}
    # start 1's spectral hypotheses (every setting) are made before start 0, its leader, is
    # collected (read back from the cache when start 1 is verified)
    before = made_two[: made_two.index(("collected", "start 0"))]
    assert before.count(("spectral", "start 1")) == len(make_matcher("deform")._check())
    # one thread makes each run's hypotheses in turn
    assert made.index(("spectral", "start 0")) < made.index(("rigid", "posed"))
    # the same registrations either way: hypotheses in the same order, same scores, same result
    np.testing.assert_array_equal(two, one)
    assert [(r["hypothesis"], r["verified_score"], r["score"]) for r in info_two["runs"]] == [
        (r["hypothesis"], r["verified_score"], r["score"]) for r in info_one["runs"]
    ]


def test_spectral_hypotheses_are_kept_per_samples(builtin, monkeypatch):
    """With a cache, a second call on the same samples reads the hypotheses back (no ZoomOut); other samples compute their own."""
    import topomatch.matching.deform as deform_module

    src, _, tgt, _ = _bent_syn00(builtin, seed=7)
    settings = [("hks", 10, False), ("hks", 20, False)]
    s1 = farthest_point_sampling(300, points=src.vertices, first=0)
    s2 = farthest_point_sampling(300, points=tgt.vertices, first=0)
    s1b = farthest_point_sampling(300, points=src.vertices, first=5)
    calls = []
    real = deform_module.nearest_neighbors
    monkeypatch.setattr(deform_module, "nearest_neighbors", lambda *a, **kw: calls.append(1) or real(*a, **kw))
    cache: dict = {}
    first = list(spectral_hypotheses(src, tgt, s1, s2, settings, k_zoomout=30, cache=cache))
    n_first = len(calls)
    again = list(spectral_hypotheses(src, tgt, s1, s2, settings, k_zoomout=30, cache=cache))
    assert len(calls) == n_first > 0
    assert [h.label for h in again] == [h.label for h in first]
    assert all(np.array_equal(a.p2p, b.p2p) and not a.p2p.flags.writeable for a, b in zip(again, first))
    other = list(spectral_hypotheses(src, tgt, s1b, s2, settings, k_zoomout=30, cache=cache))
    assert len(calls) == 2 * n_first
    fresh = list(spectral_hypotheses(src, tgt, s1b, s2, settings, k_zoomout=30))
    assert all(np.array_equal(a.p2p, b.p2p) for a, b in zip(other, fresh))


def test_deform_posed_source_uses_the_source_own_intrinsic_data(builtin, monkeypatch):
    """The posed copy is the source's surface in another pose: its spectral hypotheses and feature stage read the source's own data."""
    src, bends, tgt, _ = _bent_syn00(builtin, seed=7)
    fast = {**_FAST_POSED, "feature_icp_iterations": 2}
    poses = [("a", bends[0][1]), ("b", bends[2][1])]
    seen: list[np.ndarray] = []
    spectral: list[np.ndarray] = []

    def spy(source, target, **kw):
        seen.append(np.array(source.vertices))
        return local_wks_features(source, target, **kw)

    def spy_spectral(source, target, *args, **kw):
        spectral.append(np.array(source.vertices))
        return spectral_hypotheses(source, target, *args, **kw)

    monkeypatch.setattr("topomatch.matching.deform.local_wks_features", spy)
    monkeypatch.setattr("topomatch.matching.deform.spectral_hypotheses", spy_spectral)
    _, info = make_matcher("deform", **fast, pose_sources=1, n_threads=1).register(src, tgt, poses=poses)
    assert [r["source_pose"] for r in info["runs"]] == [None, "b"] and all(r["refined"] for r in info["runs"])
    # both registrations (the plain source and the source posed as "b") read the source's
    # eigenbasis for their spectral hypotheses and its features in the feature stage
    assert len(spectral) == 2 and all(np.array_equal(v, src.vertices) for v in spectral)
    assert len(seen) == 2 and all(np.array_equal(v, src.vertices) for v in seen)
    # the posed run itself deforms the posed copy (its rest shape is the pose, not the source)
    assert not np.allclose(bends[2][1], src.vertices)


def test_deform_registers_the_source_in_its_best_fitting_known_pose(builtin):
    src, bends, tgt, perm = _bent_syn00(builtin, seed=7)
    fast = _FAST_POSED
    poses = [("a", bends[0][1]), ("b", bends[2][1])]
    scale = np.sqrt(src.area)
    base_deformed, base = make_matcher("deform", **fast).register(src, tgt, poses=poses)
    deformed, info = make_matcher("deform", **fast, pose_sources=1).register(src, tgt, poses=poses)
    runs = info["runs"]
    assert [(r["start"], r["poses"], r["source_pose"]) for r in runs] == [(0, True, None), (0, False, "b")]
    # the first run is the registration without pose_sources (the ranking leaves its pose hypotheses alone)
    samples = tuple(farthest_point_sampling(min(600, m.n_vertices), points=m.vertices, first=0) for m in (src, tgt))
    base_score = fit_residual(base_deformed, src.faces, tgt.vertices, tgt.vertex_normals, cKDTree(tgt.vertices), scale=scale, samples=samples)
    assert runs[0]["hypothesis"] == base["hypothesis"]
    assert runs[0]["score"] == pytest.approx(base_score + 0.025 * base["distortion"])
    # the posed source is the target's own shape: it fits without distortion, is kept, and maps right
    assert runs[1]["score"] < runs[0]["score"] and info["run"] == 1 and info["hypothesis"].startswith("posed b: ")
    p2p = map_from_deformed(tgt, deformed, src.faces)
    assert np.median(np.linalg.norm(src.vertices[p2p] - src.vertices[perm], axis=1)) / scale < 0.01
    # through a working copy the posed run's displacements are carried back onto the pose at full resolution
    copied, info_c = make_matcher("deform", **fast, pose_sources=1, working_vertices=1000, working_sizes=(1000,)).register(src, tgt, poses=poses)
    assert [r["source_pose"] for r in info_c["runs"]] == [None, "b"] and info_c["run"] == 1
    assert copied.shape == src.vertices.shape
    assert np.median(cKDTree(tgt.vertices).query(copied)[0]) < 0.01 * scale
    # start_sizes: the source as it is at the listed sizes only, the posed source at every size
    sized = make_matcher("deform", **fast, pose_sources=1, working_vertices=1000, working_sizes=(1000, 1200), start_sizes=(1000,))
    _, info_s = sized.register(src, tgt, poses=poses)
    assert [(r["working_size"], r["source_pose"]) for r in info_s["runs"]] == [(1000, None), (1000, "b"), (1200, "b")]
    for bad in ((), (1500,), 1000):
        with pytest.raises(ValueError, match="start_sizes"):
            make_matcher("deform", working_sizes=(1000, 1200), start_sizes=bad).register(src, tgt)
    # orientation_weight: the same refined runs, the final choice by fit residual + weight x folded fraction
    oriented, info_o = make_matcher("deform", **fast, pose_sources=1, orientation_weight=0.1).register(src, tgt, poses=poses)
    runs_o = info_o["runs"]
    assert [r["score"] for r in runs_o] == [r["score"] for r in runs]
    assert all(0 <= r["folded"] <= 1 for r in runs_o)
    keys = [r["full_residual"] + 0.1 * r["folded"] for r in runs_o]
    assert info_o["run"] == int(np.argmin(keys))
    p2p_o = map_from_deformed(tgt, oriented, src.faces)
    assert runs_o[info_o["run"]]["folded"] == folded_fraction(p2p_o, src.vertices, src.vertex_normals, tgt.faces, tgt.face_areas)
    # the target's own shape as the posed source: the map follows the surface, nothing turned over
    assert runs_o[1]["folded"] < 0.01 and info_o["run"] == 1
    for bad in (-0.1, True, "0.1"):
        with pytest.raises(ValueError, match="orientation_weight"):
            make_matcher("deform", orientation_weight=bad).register(src, tgt)
    # pose_challengers: the next-ranked pose registered as the source only to challenge the choice
    # (challenge_above=0: whatever the choice's folded share)
    kept, info_k = make_matcher("deform", **fast, pose_challengers=1, challenge_margin=1.0, challenge_above=0.0).register(src, tgt, poses=poses)
    runs_k = info_k["runs"]
    assert [(r["source_pose"], r["challenger"], r["refined"]) for r in runs_k] == [(None, False, True), ("b", True, True)]
    # the same registrations as with pose_sources=1; a margin of the whole area never replaces the choice
    assert [r["score"] for r in runs_k] == [r["score"] for r in runs]
    assert info_k["run"] == 0 and "replaced" not in info_k["challenge"] and np.array_equal(kept, base_deformed)
    assert all(0 <= r["folded"] <= 1 for r in runs_k)
    assert info_k["challenge"]["registered"] and info_k["challenge"]["folded"] == runs_k[0]["folded"]
    # with no margin, the challenger replaces the choice exactly when its map turns over less of the target
    _, info_0 = make_matcher("deform", **fast, pose_challengers=1, challenge_margin=0.0, challenge_above=0.0).register(src, tgt, poses=poses)
    f0, f1 = (r["folded"] for r in info_0["runs"])
    assert info_0["run"] == (1 if f1 < f0 else 0) and ("replaced" in info_0["challenge"]) == (f1 < f0)
    # challenge_above: the challenger is registered only when the choice's map turns over at least
    # that share of the target; below it, the default's registration and choice
    gate = f0 + 1e-9
    below, info_b = make_matcher("deform", **fast, pose_challengers=1, challenge_margin=0.0, challenge_above=gate).register(src, tgt, poses=poses)
    assert [(r["source_pose"], r["challenger"]) for r in info_b["runs"]] == [(None, False)]
    assert info_b["challenge"] == {"folded": f0, "above": gate, "registered": False} and np.array_equal(below, base_deformed)
    _, info_a = make_matcher("deform", **fast, pose_challengers=1, challenge_margin=0.0, challenge_above=f0).register(src, tgt, poses=poses)
    assert info_a["challenge"]["registered"] and info_a["run"] == info_0["run"]
    assert [r["folded"] for r in info_a["runs"]] == [f0, f1]
    # refine_runs counts the contenders only: the challenger is always refined
    _, info_r = make_matcher("deform", **fast, n_starts=2, pose_challengers=1, refine_runs=1, challenge_above=0.0).register(src, tgt, poses=poses)
    flags = [(r["challenger"], r["refined"]) for r in info_r["runs"]]
    assert flags[2] == (True, True) and sorted(f[1] for f in flags[:2]) == [False, True]
    # challenge_judge="score": once the challenger is registered, the lowest score of the refined runs is kept
    # (the same registrations as with the folded share's margin); a closed gate leaves the choice alone
    judged, info_j = make_matcher("deform", **fast, pose_challengers=1, challenge_judge="score", challenge_above=0.0).register(src, tgt, poses=poses)
    scores = [r["score"] for r in info_j["runs"]]
    assert scores == [r["score"] for r in info_0["runs"]] and info_j["run"] == int(np.argmin(scores))
    assert ("replaced" in info_j["challenge"]) == (info_j["run"] != 0)
    assert np.array_equal(judged, base_deformed) == (info_j["run"] == 0)
    shut, info_s2 = make_matcher("deform", **fast, pose_challengers=1, challenge_judge="score", challenge_above=gate).register(src, tgt, poses=poses)
    assert info_s2["challenge"] == {"folded": f0, "above": gate, "registered": False} and np.array_equal(shut, base_deformed)
    for name, bad in (("pose_challengers", -1), ("pose_challengers", True), ("challenge_margin", -0.1), ("challenge_margin", 2.0),
                      ("challenge_margin", True), ("challenge_above", -0.01), ("challenge_above", 1.5), ("challenge_above", "0.05"),
                      ("challenge_judge", "fit"), ("challenge_judge", None)):
        with pytest.raises(ValueError, match=name):
            make_matcher("deform", **{name: bad}).register(src, tgt)
    # without poses there is nothing to register in a pose: one plain registration
    assert "runs" not in make_matcher("deform", **fast, pose_sources=1).register(src, tgt)[1]
    # refine_runs: every run verified, the best by verified score refined (each as when all are)
    info_all = info_s
    assert all(r["refined"] for r in info_all["runs"])
    assert info_all["run"] == int(np.argmin([r["score"] for r in info_all["runs"]]))
    for n in (1, 2):
        part, info_n = make_matcher("deform", **fast, pose_sources=1, working_vertices=1000, working_sizes=(1000, 1200),
                                    start_sizes=(1000,), refine_runs=n).register(src, tgt, poses=poses)
        runs_n = info_n["runs"]
        assert [r["verified_score"] for r in runs_n] == [r["verified_score"] for r in info_all["runs"]]
        lead = sorted(np.argsort([r["verified_score"] for r in runs_n], kind="stable")[:n].tolist())
        assert [i for i, r in enumerate(runs_n) if r["refined"]] == lead
        assert all(r["score"] is None and r["full_residual"] is None for r in runs_n if not r["refined"])
        for i in lead:  # a refinement does not depend on which others are refined
            assert runs_n[i]["score"] == info_all["runs"][i]["score"]
        assert info_n["run"] in lead and runs_n[info_n["run"]]["score"] == min(runs_n[i]["score"] for i in lead)
        assert part.shape == src.vertices.shape
    # the refinements run side by side and the poses are ranked on threads: the same on one thread
    one, info_one = make_matcher("deform", **fast, pose_sources=1, working_vertices=1000, working_sizes=(1000, 1200),
                                 start_sizes=(1000,), refine_runs=2, n_threads=1).register(src, tgt, poses=poses)
    np.testing.assert_array_equal(one, part)
    assert [r["score"] for r in info_one["runs"]] == [r["score"] for r in runs_n]
    ranked = [_rank_poses(src, tgt, *samples, poses, None, ("as-given", "principal-axes"), n_threads=n) for n in (1, 2)]
    assert [r[0] for r in ranked[0]] == [r[0] for r in ranked[1]] and all(np.array_equal(a[1], b[1]) for a, b in zip(*ranked))
    for bad in (0, -1, True, 1.5):
        with pytest.raises(ValueError, match="refine_runs"):
            make_matcher("deform", refine_runs=bad).register(src, tgt)
    for bad in (-1, True, 1.5):
        with pytest.raises(ValueError, match="pose_sources"):
            make_matcher("deform", pose_sources=bad).register(src, tgt)
    # features_after_choice: the refined runs compared after the fine registration (as without
    # a feature stage: `runs`), only the kept one given the feature stage
    full = {**fast, "pose_sources": 1, "feature_icp_iterations": 10}
    every, info_e = make_matcher("deform", **full).register(src, tgt, poses=poses)
    after, info_a = make_matcher("deform", **full, features_after_choice=True).register(src, tgt, poses=poses)
    runs_e, runs_a = info_e["runs"], info_a["runs"]
    k = info_a["run"]
    assert len(runs_a) == 2 and all(r["refined"] for r in runs_a) and k == info["run"]
    for i, (ra, r) in enumerate(zip(runs_a, runs)):
        assert ra.get("fine_score", ra["score"]) == r["score"]
        assert ("fine_score" in ra) == (i == k)
    # the kept run, given the feature stage, is what it is when every run gets it (the posed
    # source, the target's own shape, is kept either way), and the stage moved it
    assert info_e["run"] == k == 1 and info_a["features_after_choice"]
    assert runs_a[k]["score"] == runs_e[k]["score"] != runs_a[k]["fine_score"]
    np.testing.assert_array_equal(after, every)
    assert info_a["residual"] == info_e["residual"] and info_a["distortion"] == info_e["distortion"]
    for bad in (1, "yes", None):
        with pytest.raises(ValueError, match="features_after_choice"):
            make_matcher("deform", features_after_choice=bad).register(src, tgt)


def _spy_rankings(monkeypatch) -> list[tuple[int, list[str], list[float]]]:
    """Spy on ``deform._collected``: each verified registration's (start, labels, residuals) is appended to the list returned."""
    import topomatch.matching.deform as deform_module

    seen: list[tuple[int, list[str], list[float]]] = []
    real = deform_module._collected

    def spy(v):
        out = real(v)
        seen.append((out.start, [h.label for h in out.hyps], [float(r.residual) for r in out.results]))
        return out

    monkeypatch.setattr(deform_module, "_collected", spy)
    return seen


def _by_start(seen: list[tuple[int, list[str], list[float]]]) -> dict[int, tuple[list[str], list[float]]]:
    """The last record of each start: its labels and residuals."""
    return {start: (labels, res) for start, labels, res in seen}


def _two_starts_with_poses(builtin):
    """A bent syn00 target, two of its bends as poses, and fast settings with two sampling starts."""
    src, bends, tgt, _ = _bent_syn00(builtin, seed=7)
    return src, tgt, [("b", bends[2][1]), ("a", bends[0][1])], {**_FAST_POSED, "n_starts": 2}


def test_follow_top_verifies_only_start_0_s_best_hypotheses(builtin, monkeypatch):
    import topomatch.matching.deform as deform_module

    src, tgt, poses, fast = _two_starts_with_poses(builtin)
    seen = _spy_rankings(monkeypatch)
    every, info_every = make_matcher("deform", **fast).register(src, tgt, poses=poses)
    runs_every = _by_start(seen)
    seen.clear()
    asked: list[list[str]] = []  # the spectral settings each call computes, by label
    spectral = deform_module.spectral_hypotheses

    def spectral_spy(source, target, s1, s2, settings, **kw):
        asked.append([deform_module._spectral_label(*x) for x in settings])
        return spectral(source, target, s1, s2, settings, **kw)

    monkeypatch.setattr(deform_module, "spectral_hypotheses", spectral_spy)
    followed, info = make_matcher("deform", **fast, follow_top=2).register(src, tgt, poses=poses)
    runs = _by_start(seen)  # the last record of each start
    # start 0 verifies every hypothesis, as before
    assert runs[0] == runs_every[0]
    best = [runs[0][0][i] for i in np.argsort(runs[0][1], kind="stable")[:2]]
    # start 1 verifies only those two, each as start 1 did when it verified them all
    assert sorted(runs[1][0]) == sorted(best) == info["runs"][1]["followed"]
    labels_1, res_1 = runs_every[1]
    assert all(r == res_1[labels_1.index(label)] for label, r in zip(*runs[1]))
    assert "followed" not in info["runs"][0] and len(runs_every[1][0]) > 2
    # the spectral hypotheses it does not verify are not computed: start 0 asks for every
    # setting, start 1 (if any of its labels is spectral) for those among the best only
    assert len(asked[0]) == len(make_matcher("deform")._check())
    spectral_best = [label for label in asked[0] if label in best]
    assert asked[1:] == ([spectral_best] if spectral_best else [])
    # the same on one thread (the follower waits for its leader either way)
    one, info_one = make_matcher("deform", **fast, follow_top=2, n_threads=1).register(src, tgt, poses=poses)
    np.testing.assert_array_equal(one, followed)
    assert [r["score"] for r in info_one["runs"]] == [r["score"] for r in info["runs"]]
    assert every.shape == followed.shape and info_every["runs"][0]["verified_score"] == info["runs"][0]["verified_score"]
    for bad in (-1, True, 1.5):
        with pytest.raises(ValueError, match="follow_top"):
            make_matcher("deform", follow_top=bad).register(src, tgt)


def test_follow_spectral_adds_every_spectral_setting_to_the_followed(builtin, monkeypatch):
    import topomatch.matching.deform as deform_module

    src, tgt, poses, fast = _two_starts_with_poses(builtin)
    seen = _spy_rankings(monkeypatch)
    make_matcher("deform", **fast).register(src, tgt, poses=poses)
    runs_every = _by_start(seen)
    seen.clear()
    _, info = make_matcher("deform", **fast, follow_top=2, follow_spectral=True).register(src, tgt, poses=poses)
    runs = _by_start(seen)
    spectral = [deform_module._spectral_label(*x) for x in make_matcher("deform")._check()]
    best = [runs[0][0][i] for i in np.argsort(runs[0][1], kind="stable")[:2]]
    # start 1 verifies start 0's two best and every spectral setting, each as it did when it verified them all
    assert sorted(runs[1][0]) == sorted(set(best) | set(spectral)) == info["runs"][1]["followed"]
    assert len(runs[1][0]) < len(runs_every[1][0])
    labels_1, res_1 = runs_every[1]
    assert all(r == res_1[labels_1.index(label)] for label, r in zip(*runs[1]))
    # without follow_top it changes nothing: every start verifies every hypothesis
    seen.clear()
    make_matcher("deform", **fast, follow_spectral=True).register(src, tgt, poses=poses)
    assert _by_start(seen) == runs_every
    for bad in (1, "yes", None):
        with pytest.raises(ValueError, match="follow_spectral"):
            make_matcher("deform", follow_spectral=bad).register(src, tgt)


def test_follow_bent_adds_the_follower_s_own_bent_copies_when_start_0_s_best_hold_one(builtin, monkeypatch):
    src, tgt, poses, fast = _two_starts_with_poses(builtin)
    fast = {**fast, "articulated": 2, "bend_angles": (30.0,)}  # bent too little: a pose leads start 0's ranking
    seen = _spy_rankings(monkeypatch)
    make_matcher("deform", **fast).register(src, tgt, poses=poses)
    runs_every = _by_start(seen)
    ranked_0 = [runs_every[0][0][i] for i in np.argsort(runs_every[0][1], kind="stable")]
    first_bent = next(i for i, label in enumerate(ranked_0) if label.startswith("bent "))
    own_bent = {label for label in runs_every[1][0] if label.startswith("bent ")}
    # both branches below are taken, and the flag adds a bent copy outside start 0's best
    assert first_bent >= 1 and len(own_bent) == 2 and own_bent - set(ranked_0[: first_bent + 1])
    labels_1, res_1 = runs_every[1]
    # start 0's best hold a bent copy: start 1 verifies them and both of its own bent copies,
    # each as it did when it verified them all
    seen.clear()
    _, info = make_matcher("deform", **fast, follow_top=first_bent + 1, follow_bent=True).register(src, tgt, poses=poses)
    runs = _by_start(seen)
    assert runs[0] == runs_every[0]
    assert sorted(runs[1][0]) == sorted((set(ranked_0[: first_bent + 1]) & set(labels_1)) | own_bent)
    assert "bent *" in info["runs"][1]["followed"]
    assert all(r == res_1[labels_1.index(label)] for label, r in zip(*runs[1]))
    # they hold none: as follow_top alone
    seen.clear()
    make_matcher("deform", **fast, follow_top=first_bent, follow_bent=True).register(src, tgt, poses=poses)
    with_flag = _by_start(seen)
    seen.clear()
    make_matcher("deform", **fast, follow_top=first_bent).register(src, tgt, poses=poses)
    assert with_flag == _by_start(seen) and sorted(with_flag[1][0]) == sorted(set(ranked_0[:first_bent]) & set(labels_1))
    for bad in (1, "yes", None):
        with pytest.raises(ValueError, match="follow_bent"):
            make_matcher("deform", follow_bent=bad).register(src, tgt)
