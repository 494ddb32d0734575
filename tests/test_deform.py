"""Deformation graphs, graph registration and the deform matcher."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from scipy.spatial import cKDTree

from topomatch.datasets.toy import icosphere
from topomatch.deform.graph import build_deformation_graph
from topomatch.deform.register import DataPairs, RegistrationSchedule, fit_residual, register
from topomatch.maps import folded_fraction
from topomatch.matching import MATCHERS, make_matcher
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
    swap_regions,
    turn_limb,
)
from topomatch.mesh import TriangleMesh
from topomatch.mesh.geometry import axis_rotation
from topomatch.mesh.mesh import EigenbasisJob
from topomatch.mesh.sampling import farthest_point_sampling

from ._fmap_shapes import bumpy, shuffled
from ._truth import euclidean_errors


def bent(mesh: TriangleMesh, angle: float = 0.6) -> TriangleMesh:
    """A smooth non-rigid deformation: a twist about the y axis growing with x."""
    v = np.array(mesh.vertices)
    a = angle * v[:, 0]
    c, s = np.cos(a), np.sin(a)
    w = np.c_[v[:, 0], c * v[:, 1] - s * v[:, 2], s * v[:, 1] + c * v[:, 2]]
    return TriangleMesh(w, mesh.faces, name="bent")


@pytest.fixture(scope="module")
def pair():
    src = bumpy(4, mirror_symmetric=False)
    tgt, perm = shuffled(bent(src), seed=3)
    return src, tgt, perm


def test_graph_structure(pair):
    src, _, _ = pair
    g = build_deformation_graph(src.vertices, src.faces, 80)
    assert g.n_nodes == 80
    assert np.all(g.links[:, 0] < g.links[:, 1])
    np.testing.assert_allclose(np.asarray(g.skin.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    assert g.labels.shape == (src.n_vertices,) and set(np.unique(g.labels)) == set(range(80))
    # the first node: vertex 0 by default, or the given vertex (the next one a face uses)
    assert g.nodes[0] == 0
    assert build_deformation_graph(src.vertices, src.faces, 80, first=1234).nodes[0] == 1234
    V = np.vstack([src.vertices, src.vertices[:1]])  # vertex n is used by no face
    F = src.faces.copy()
    assert build_deformation_graph(V, F, 80, first=src.n_vertices - 1).nodes[0] == src.n_vertices - 1
    assert build_deformation_graph(V, F, 80, first=src.n_vertices).nodes[0] == src.n_vertices - 1
    for bad in (-1, src.n_vertices + 1, 2.5):
        with pytest.raises(ValueError, match="first"):
            build_deformation_graph(V, F, 80, first=bad)


def test_registration_leaves_a_shared_graph_untouched(pair):
    # DeformMatcher runs several registrations on one graph in threads: nothing may mutate it
    src, tgt, _ = pair
    g = build_deformation_graph(src.vertices, src.faces, 60)
    assert g.skin.has_sorted_indices
    before = (g.skin.indptr.copy(), g.skin.indices.copy(), g.skin.data.copy(), g.rest.copy())
    pts = np.arange(0, src.n_vertices, 40)
    pairs = DataPairs(pts, tgt.vertices[pts], tgt.vertex_normals[pts], np.ones(len(pts)))
    register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, RegistrationSchedule(n_nodes=60, fit_iterations=2, icp_iterations=2), graph=g)
    after = (g.skin.indptr, g.skin.indices, g.skin.data, g.rest)
    assert all(np.array_equal(a, b) for a, b in zip(before, after))


def test_registration_from_sparse_correct_pairs_recovers_the_map(pair):
    src, tgt, perm = pair
    inv = np.argsort(perm)  # source vertex -> target vertex
    pts = np.arange(0, src.n_vertices, 25)
    pairs = DataPairs(pts, tgt.vertices[inv[pts]], tgt.vertex_normals[inv[pts]], np.ones(len(pts)))
    rigid = np.linalg.norm(src.vertices[perm] - tgt.vertices, axis=1).mean()
    # fitting the pairs alone moves every vertex close to its true image
    fit = register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, RegistrationSchedule(n_nodes=120, fit_iterations=8, icp_iterations=0))
    assert np.linalg.norm(fit.deformed[perm] - tgt.vertices, axis=1).mean() < 0.25 * rigid
    # closest-point iterations keep the surfaces together (they may slide tangentially)
    icp = register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, RegistrationSchedule(n_nodes=120, fit_iterations=8, icp_iterations=8))
    assert icp.residual < 0.01
    assert np.linalg.norm(icp.deformed[perm] - tgt.vertices, axis=1).mean() < 0.6 * rigid


def test_registration_needs_pairs_or_a_start(pair):
    src, tgt, _ = pair
    with pytest.raises(ValueError, match="init_pairs or a start"):
        register(src.vertices, src.faces, tgt.vertices, tgt.faces, None)
    with pytest.raises(ValueError, match="start positions have shape"):
        register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, start=src.vertices[:10])


def test_registration_from_start_positions(pair):
    # a start given as positions (e.g. assembled by swap_regions) seeds the registration
    src, tgt, perm = pair
    sched = RegistrationSchedule(n_nodes=120, fit_iterations=0, icp_iterations=6)
    exact = np.empty_like(src.vertices)
    exact[perm] = tgt.vertices  # source vertex -> its true position on the target
    r = register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, start=exact)
    off = register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, start=exact + 0.5 * np.sqrt(src.area))
    assert r.residual < 0.01 < off.residual
    assert np.linalg.norm(r.deformed - exact, axis=1).mean() < 0.04 * np.sqrt(src.area)  # tangential sliding ~0.02
    # the two search directions side by side give the same registration
    both = register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, start=off.deformed, n_threads=2)
    one = register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, start=off.deformed)
    assert np.array_equal(both.deformed, one.deformed) and both.residual == one.residual



def test_position_step_reuses_the_last_factor_as_preconditioner(pair, monkeypatch):
    # a graph large enough for the sparse path: the warm-started conjugate gradients give
    # the registration the direct solves give (every step factorised afresh)
    from topomatch.deform import register as reg

    src, tgt, _ = pair
    sched = RegistrationSchedule(n_nodes=250, fit_iterations=0, icp_iterations=8, alpha_icp=(0.2, 0.01))
    assert 3 * sched.n_nodes > reg._DENSE_SOLVE_MAX
    graph = build_deformation_graph(src.vertices, src.faces, sched.n_nodes)
    start = src.vertices + 0.02 * np.sqrt(src.area) * np.sin(3 * src.vertices[:, [1, 2, 0]])
    real, solved = reg._pcg, []

    def counting(*args, **kwargs):
        x, steps = real(*args, **kwargs)
        solved.append(x is not None)
        return x, steps

    monkeypatch.setattr(reg, "_pcg", counting)
    warm = register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, graph=graph, start=start)
    assert sum(solved) >= 4  # most position steps were solved by conjugate gradients
    monkeypatch.setattr(reg, "_pcg", lambda *a, **k: (None, 0))
    direct = register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, graph=graph, start=start)
    assert np.abs(warm.deformed - direct.deformed).max() < 1e-7 * np.sqrt(src.area)


def test_pcg_solves_and_reports_failure():
    from scipy import sparse

    from topomatch.deform.register import _pcg

    rng = np.random.default_rng(0)
    B = sparse.random(300, 300, density=0.02, random_state=rng)
    A = (B @ B.T + sparse.eye(300)).tocsc()
    A2 = (A + 0.1 * sparse.diags(rng.random(300))).toarray()  # a nearby matrix's inverse as preconditioner
    P = np.linalg.inv(A2)
    b = rng.standard_normal((300, 2))
    x, steps = _pcg(A, b, np.zeros_like(b), lambda r: P @ r, rtol=1e-12, max_steps=50)
    assert x is not None and 0 < steps < 50
    assert np.allclose(x, np.linalg.solve(A.toarray(), b), rtol=0, atol=1e-9)
    x1, steps1 = _pcg(A, b[:, 0], np.zeros(300), lambda r: r, rtol=1e-12, max_steps=2)  # no preconditioner, 2 steps
    assert x1 is None and steps1 == 2


def _blob(center: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.exp(-np.sum((x - center) ** 2, axis=1) / 0.05)[:, None]


def test_swap_regions_takes_the_region_another_registration_got_right(pair):
    from scipy.spatial import cKDTree

    src, tgt, perm = pair
    exact = np.empty_like(src.vertices)
    exact[perm] = tgt.vertices
    scale = np.sqrt(src.area)
    X = src.vertices
    far = int(np.argmax(np.linalg.norm(X - X[0], axis=1)))
    # two registrations, each right except for a blob pushed off the surface, on opposite sides
    a = exact + 0.3 * scale * _blob(X[0], X) * np.array([0.0, 0.0, 1.0])
    b = exact + 0.3 * scale * _blob(X[far], X) * np.array([0.0, 1.0, 0.0])
    tree = cKDTree(tgt.vertices)
    res = [fit_residual(v, src.faces, tgt.vertices, tgt.vertex_normals, tree, scale=scale) for v in (a, b)]
    out, r, swaps = swap_regions(src, tgt, [a, b], threshold=0.05)
    # the blob of A comes from B, B's own blob is not taken: the exact registration
    wrong_a = np.linalg.norm(a - exact, axis=1) > 0.05 * scale
    assert swaps == [(1, int(wrong_a.sum()))]
    assert r < min(res)
    np.testing.assert_allclose(out[wrong_a], exact[wrong_a])
    np.testing.assert_allclose(np.linalg.norm(out - exact, axis=1).max(), 0.05 * scale, rtol=0.2)  # only seams remain
    # nothing to gain: the best registration is kept as is
    out2, _, swaps2 = swap_regions(src, tgt, [exact, b], threshold=0.05)
    assert swaps2 == [] and np.array_equal(out2, exact)
    # regions below min_vertices are ignored
    _, _, swaps3 = swap_regions(src, tgt, [a, b], threshold=0.05, min_vertices=len(X))
    assert swaps3 == []


def test_deform_matcher_on_a_bent_shuffled_copy(pair, monkeypatch):
    import topomatch.mesh.mesh as mesh_module
    from topomatch import _cache

    src, tgt, perm = pair
    m = make_matcher(
        "deform", hypotheses=(("hks", 30, False), ("hks", 30, True)), n_samples=800, coarse_nodes=80, fine_nodes=200, n_threads=2
    )
    # the target's eigenbasis in a forked process (only for larger meshes by default; not
    # when the disk cache holds it, as it may after other tests ran the command line)
    monkeypatch.setattr(mesh_module, "BACKGROUND_MIN_VERTICES", 0)
    monkeypatch.setattr(_cache, "_CACHE_DIR", None)
    monkeypatch.delenv("TOPOMATCH_CACHE_DIR", raising=False)
    jobs = []

    def spy(mesh, k, **kw):
        jobs.append(EigenbasisJob(mesh, k, kw.get("kind", "robust")))
        jobs.append(jobs[-1]._process is not None)
        return jobs[-2]

    monkeypatch.setattr(TriangleMesh, "eigenbasis_in_background", spy)
    tgt = TriangleMesh(tgt.vertices, tgt.faces)  # no eigenbasis yet
    c = m.match(src, tgt)
    monkeypatch.undo()
    assert len(jobs) == 2 and jobs[1] and jobs[0]._process is None  # forked, and waited for
    assert c.p2p_21.shape == (tgt.n_vertices,) and c.p2p_21.min() >= 0
    # Euclidean error on the (undeformed) source, relative to its size
    err = np.linalg.norm(src.vertices[c.p2p_21] - src.vertices[perm], axis=1) / np.sqrt(src.area)
    assert np.mean(err) < 0.05  # tangential sliding on this smooth shape costs ~0.04
    assert c.info["hypothesis"] in c.info["residuals"]
    # the default rigid hypotheses were verified too (as given + four principal-axis frames)
    assert {"rigid as-given", "rigid axes +++", "rigid axes +--", "rigid axes -+-", "rigid axes --+"} <= set(c.info["residuals"])
    # deterministic, the same without the forked eigenbasis, and the same with the
    # verification on one thread (not pipelined): same hypotheses in the same order,
    # same residuals, same map
    fresh = TriangleMesh(tgt.vertices, tgt.faces)
    np.testing.assert_array_equal(m.match(src, fresh).p2p_21, c.p2p_21)
    c1 = m.set_params(n_threads=1).match(src, tgt)
    np.testing.assert_array_equal(c1.p2p_21, c.p2p_21)
    assert list(c1.info["residuals"].items()) == list(c.info["residuals"].items())


def test_deform_registers_large_meshes_through_decimated_copies(pair):
    src, tgt, perm = pair  # 2,562 vertices each
    kw = {"hypotheses": (("hks", 30, False), ("hks", 30, True)), "n_samples": 800, "coarse_nodes": 80, "fine_nodes": 200}
    small = make_matcher("deform", working_vertices=1000, working_sizes=(1000,), **kw)
    c = small.match(src, tgt)
    n1, n2 = c.info["working_vertices"]
    assert abs(n1 - 1000) < 50 and abs(n2 - 1000) < 50 and c.info["seconds"]["decimation"] >= 0
    assert [r["working_size"] for r in c.info["runs"]] == [1000] and c.info["run"] == 0
    assert c.p2p_21.shape == (tgt.n_vertices,) and c.p2p_21.min() >= 0
    err = np.linalg.norm(src.vertices[c.p2p_21] - src.vertices[perm], axis=1) / np.sqrt(src.area)
    assert np.mean(err) < 0.06
    deformed, _ = small.register(src, tgt)  # carried to every source vertex, onto the target
    assert deformed.shape == src.vertices.shape
    assert np.median(cKDTree(tgt.vertices).query(deformed)[0]) < 0.01 * np.sqrt(src.area)
    # meshes within the working size are registered as they are
    assert "working_vertices" not in make_matcher("deform", **kw).match(src, tgt).info
    for wv in (999, 2.5e4, True):
        with pytest.raises(ValueError, match="working_vertices"):
            make_matcher("deform", working_vertices=wv).match(src, tgt)
    for ws in ((), (999,), 1000, (1000, 2.5e3), (True,)):
        with pytest.raises(ValueError, match="working_sizes"):
            make_matcher("deform", working_vertices=1000, working_sizes=ws).match(src, tgt)


def test_deform_keeps_the_working_size_with_the_best_full_resolution_score(pair):
    src, tgt, _ = pair  # 2,562 vertices each
    kw = {"hypotheses": (("hks", 30, False),), "n_samples": 800, "coarse_nodes": 80, "fine_nodes": 200, "working_vertices": 1000}
    # 3,000 and 4,000 both leave the meshes as they are: one registration for the two
    c = make_matcher("deform", working_sizes=(1000, 1500, 3000, 4000), **kw).match(src, tgt)
    runs = c.info["runs"]
    assert [r["working_size"] for r in runs] == [1000, 1500, 3000]
    assert runs[2]["vertices"] == (src.n_vertices, tgt.n_vertices)
    best = int(np.argmin([r["score"] for r in runs]))
    assert c.info["run"] == best and c.info["working_vertices"] == runs[best]["vertices"]
    # the score is the full-resolution residual plus the weighted distortion of the kept registration
    assert runs[best]["score"] == pytest.approx(runs[best]["full_residual"] + 0.025 * c.info["distortion"])
    # the kept map is that size's own registration (deterministic)
    alone = make_matcher("deform", working_sizes=(runs[best]["working_size"],), **kw).match(src, tgt)
    np.testing.assert_array_equal(alone.p2p_21, c.p2p_21)


def test_deform_keeps_the_sampling_start_with_the_best_score(pair, monkeypatch):
    src, tgt, _ = pair
    kw = {"hypotheses": (("hks", 30, False),), "n_samples": 800, "coarse_nodes": 80, "fine_nodes": 200}
    one = make_matcher("deform", **kw).match(src, tgt)
    assert "runs" not in one.info  # one start: registered as before
    import topomatch.matching.deform as deform_module

    deform_module._SPECTRAL.clear()  # the shapes' spectral data are kept across registrations
    spectral_calls = []
    real = deform_module._spectral_data
    monkeypatch.setattr(deform_module, "_spectral_data", lambda mesh, *a: spectral_calls.append(mesh.content_hash) or real(mesh, *a))
    solves = []
    real_solve = deform_module.solve_fmap
    monkeypatch.setattr(deform_module, "solve_fmap", lambda *a, **k: solves.append(a[0].shape) or real_solve(*a, **k))
    c = make_matcher("deform", n_starts=3, **kw).match(src, tgt)
    # the shapes' spectral data (basis, descriptors, operators) and the initial functional
    # map of each setting (one here) are computed once, not per start
    assert sorted(spectral_calls) == sorted([src.content_hash, tgt.content_hash])
    assert len(solves) == 1
    runs = c.info["runs"]
    assert [r["start"] for r in runs] == [0, 1, 2] and all(r["working_size"] is None for r in runs)
    scores = [r["score"] for r in runs]
    assert c.info["run"] == int(np.argmin(scores))
    # start 0 is the single registration; the others sample elsewhere and differ
    first = make_matcher("deform", n_starts=3, **kw)._register(src, tgt, make_matcher("deform", **kw)._check(), 0)[0]
    np.testing.assert_array_equal(first, make_matcher("deform", **kw).register(src, tgt)[0])
    if c.info["run"] == 0:
        np.testing.assert_array_equal(c.p2p_21, one.p2p_21)
    assert len({round(s, 12) for s in scores}) > 1
    with pytest.raises(ValueError, match="n_starts"):
        make_matcher("deform", n_starts=0, **kw).match(src, tgt)


def test_deform_matcher_rejects_bad_parameters(pair):
    src, tgt, _ = pair
    assert MATCHERS["deform"].name == "deform"
    with pytest.raises(ValueError, match="hypothesis"):
        make_matcher("deform", hypotheses=(("sift", 10, False),)).match(src, tgt)
    with pytest.raises(ValueError, match="empty"):
        make_matcher("deform", hypotheses=()).match(src, tgt)
    with pytest.raises(ValueError, match="n_samples"):
        make_matcher("deform", n_samples=0).match(src, tgt)
    with pytest.raises(ValueError, match="ground truth or needs training"):
        make_matcher("deform", matcher_hypotheses=("oracle",)).match(src, tgt)
    with pytest.raises(ValueError, match="ground truth or needs training"):
        make_matcher("deform", matcher_hypotheses=("rf",)).match(src, tgt)
    with pytest.raises(ValueError, match="unknown or invalid"):
        make_matcher("deform", matcher_hypotheses=("nosuch",)).match(src, tgt)
    with pytest.raises(ValueError, match="n_threads"):
        make_matcher("deform", n_threads=0).match(src, tgt)
    with pytest.raises(ValueError, match="rigid_frames"):
        make_matcher("deform", rigid_frames=("upright",)).match(src, tgt)
    with pytest.raises(ValueError, match="rigid_frames_with_poses"):
        make_matcher("deform", rigid_frames_with_poses=("upright",)).match(src, tgt)
    with pytest.raises(ValueError, match="rigid_frames_with_poses"):
        make_matcher("deform", rigid_frames_with_poses="as-given").match(src, tgt)
    with pytest.raises(ValueError, match="pose_samples"):
        make_matcher("deform", pose_samples=2).match(src, tgt)
    with pytest.raises(ValueError, match="swap_threshold"):
        make_matcher("deform", swap_threshold=-0.1).match(src, tgt)
    with pytest.raises(ValueError, match="swap_min_vertices"):
        make_matcher("deform", swap_min_vertices=0).match(src, tgt)
    with pytest.raises(ValueError, match="has 42 vertices"):
        make_matcher("deform").match(icosphere(1), icosphere(1))
    with pytest.raises(ValueError, match="continue_icp_iterations"):
        make_matcher("deform", continue_icp_iterations=-1).match(src, tgt)
    with pytest.raises(ValueError, match="distortion_weight"):
        make_matcher("deform", distortion_weight=-0.01).match(src, tgt)
    with pytest.raises(ValueError, match="n_continue"):
        make_matcher("deform", n_continue=0).match(src, tgt)
    with pytest.raises(ValueError, match="articulated"):
        make_matcher("deform", articulated=-1).match(src, tgt)
    for angles in ((), (0.0,), (200.0,), 90.0, ("90",)):
        with pytest.raises(ValueError, match="bend_angles"):
            make_matcher("deform", bend_angles=angles).match(src, tgt)
    with pytest.raises(ValueError, match="limb_rounds"):
        make_matcher("deform", limb_rounds=-1).match(src, tgt)
    for gain in (-0.1, 1.0, "0.01"):
        with pytest.raises(ValueError, match="limb_min_gain"):
            make_matcher("deform", limb_min_gain=gain).match(src, tgt)
    for n in (0, 1.5):
        with pytest.raises(ValueError, match="limb_candidates"):
            make_matcher("deform", limb_candidates=n).match(src, tgt)
    for judge in ("Fine", "", None):
        with pytest.raises(ValueError, match="limb_judge"):
            make_matcher("deform", limb_judge=judge).match(src, tgt)
    for n in (0, 2.5, "25"):
        with pytest.raises(ValueError, match="limb_judge_iterations"):
            make_matcher("deform", limb_judge="fine", limb_judge_iterations=n).match(src, tgt)


def test_deform_chooses_by_fit_and_distortion_after_continuing(pair):
    src, tgt, _ = pair
    kw = {"hypotheses": (("hks", 30, False), ("hks", 10, False)), "n_samples": 800, "coarse_nodes": 80, "fine_nodes": 200}
    for w in (0.0, 0.025, 10.0):
        c = make_matcher("deform", distortion_weight=w, n_continue=3, **kw).match(src, tgt)
        cont = c.info["continued"]
        assert len(cont) == 3 and c.info["hypothesis"] in cont
        labels = list(cont)
        best = labels[int(np.argmin([r + w * d for r, d in cont.values()]))]
        assert c.info["hypothesis"] == best


def test_deform_does_not_turn_the_figure_around(builtin):
    """syn05 from syn00: the figure is nearly symmetric front to back.

    A registration of the figure turned front to back fits the target almost as well
    as the upright one; the distortion it needs to fit (feet, knees and face bent out
    of shape) is what the choice's score charges for. Which spectral hypothesis lands
    turned around depends on the eigenvectors (so on the machine's floating point), so
    the premise is checked on two rigid starts, the same everywhere, and the matcher
    by its result.
    """
    target, source = builtin["syn05"], builtin["syn00"]
    c = make_matcher("deform").match(source.mesh, target.mesh)
    assert np.median(euclidean_errors(target, source, c.p2p_21)) < 0.05

    V, W = source.mesh.vertices, target.mesh.vertices
    s1 = farthest_point_sampling(1500, points=V, first=0)
    s2 = farthest_point_sampling(1500, points=W, first=0)
    graph = build_deformation_graph(V, source.mesh.faces, 150)
    verify = RegistrationSchedule(n_nodes=150, fit_iterations=0, icp_iterations=25, alpha_icp=(1.0, 0.1))
    cont = RegistrationSchedule(n_nodes=150, fit_iterations=0, icp_iterations=25, alpha_icp=(0.3, 0.1))
    up = np.eye(3)[np.argmax(np.ptp(V, axis=0))]
    scale = np.sqrt(target.mesh.area / source.mesh.area)
    weight = MATCHERS["deform"]().distortion_weight
    runs = {}
    for angle in (0.0, np.pi):  # upright, turned front to back about the vertical
        start = (V - V.mean(0)) @ axis_rotation(up, angle).T * scale + W.mean(0)
        r = register(V, source.mesh.faces, W, target.mesh.faces, None, verify, graph=graph, start=start, samples=(s1, s2))
        r = register(V, source.mesh.faces, W, target.mesh.faces, None, cont, graph=graph, start=r.deformed, samples=(s1, s2))
        p2p = map_from_deformed(target.mesh, r.deformed, source.mesh.faces)
        runs[angle] = (r, np.median(euclidean_errors(target, source, p2p)))
    (upright, e_up), (turned, e_turned) = runs[0.0], runs[np.pi]
    assert e_up < 0.05 < 0.15 < e_turned  # the two starts end upright and turned around
    assert turned.residual < 1.25 * upright.residual  # the fit alone hardly tells them apart
    assert turned.distortion > 1.5 * upright.distortion  # the distortion does
    assert upright.residual + weight * upright.distortion < turned.residual + weight * turned.distortion


def test_deform_matcher_hypotheses_from_other_matchers(pair):
    src, tgt, _ = pair
    m = make_matcher("deform", hypotheses=(("hks", 10, True),), matcher_hypotheses=("em",), rigid_frames=(), articulated=0,
                     n_samples=800, coarse_nodes=80, fine_nodes=200)
    c = m.match(src, tgt)
    assert set(c.info["residuals"]) == {"hks k=10 reversing", "em"}


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



def test_deform_background_eigenbasis_must_be_a_bool(pair):
    src, tgt, _ = pair
    with pytest.raises(ValueError, match="background_eigenbasis"):
        make_matcher("deform", background_eigenbasis="false").match(src, tgt)


def test_feature_pairs_without_features_are_nearest_positions():
    from topomatch.deform.register import feature_pairs

    rng = np.random.default_rng(1)
    X, Y = rng.normal(size=(200, 3)), rng.normal(size=(150, 3))
    NX, NY = np.tile([0.0, 0.0, 1.0], (200, 1)), np.tile([0.0, 0.0, 1.0], (150, 1))
    NY[:10] *= -1  # incompatible normals: those pairs are dropped
    pts = np.c_[Y, np.zeros((150, 2))]
    p = feature_pairs(X, NX, Y, NY, np.zeros((200, 2)), pts, cKDTree(pts), sigma=0.5)
    j = cKDTree(Y).query(X)[1]
    i = cKDTree(X).query(Y)[1]
    fwd = np.flatnonzero(j >= 10)  # forward pairs whose target normal agrees
    np.testing.assert_array_equal(p.source, np.r_[fwd, i[10:]])
    np.testing.assert_array_equal(p.points, np.r_[Y[j[fwd]], Y[10:]])
    d = np.linalg.norm(X[fwd] - Y[j[fwd]], axis=1)
    np.testing.assert_allclose(p.weights[: len(fwd)], 1 / (1 + (d / 0.5) ** 2))


def test_features_stop_a_registration_sliding():
    # a sphere onto itself turned about z: positions alone cannot tell the turn (the
    # surfaces already coincide), a feature that follows the points can
    src = icosphere(3)
    V, F = src.vertices, src.faces
    a = 0.3
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    W = V @ R.T  # target vertex i is source vertex i turned
    f = np.c_[V[:, 0], V[:, 1]]  # a feature of each point: where it was before the turn
    graph = build_deformation_graph(V, F, 60)
    plain = RegistrationSchedule(n_nodes=60, fit_iterations=0, icp_iterations=15, alpha_icp=(0.5, 0.1), sigma_icp=(0.1, 0.05))
    joint = RegistrationSchedule(**{**plain.__dict__, "feature_weight": (0.5, 0.5)})
    error = {}
    for name, sched, feats in (("plain", plain, None), ("features", joint, (f, f))):
        r = register(V, F, W, F, None, sched, graph=graph, start=V, features=feats)
        p = cKDTree(r.deformed).query(W)[1]  # target vertex -> source vertex
        error[name] = float(np.mean(np.linalg.norm(V[p] - V, axis=1)))
    assert error["plain"] > 0.2  # stays turned (0.3 rad: about 0.23 on average): the map is off by the turn
    assert error["features"] < 0.3 * error["plain"], error
    with pytest.raises(ValueError, match="needs features"):
        register(V, F, W, F, None, joint, graph=graph, start=V)
    with pytest.raises(ValueError, match=r"shapes \(642, d\) and \(642, d\)"):
        register(V, F, W, F, None, joint, graph=graph, start=V, features=(f, f[:, :1]))
    with pytest.raises(ValueError, match="feature_weight"):
        register(V, F, W, F, None, RegistrationSchedule(**{**plain.__dict__, "feature_weight": (0.5, -1.0)}), graph=graph, start=V)
    with pytest.raises(ValueError, match="two finite numbers"):  # a single number: start and end needed
        register(V, F, W, F, None, RegistrationSchedule(**{**plain.__dict__, "feature_weight": 0.5}), graph=graph, start=V, features=(f, f))


def test_local_wks_features(pair):
    src, tgt, perm = pair
    fs, ft = local_wks_features(src, tgt, k=40, n_energies=20, first=10, n_components=4)
    assert fs.shape == (src.n_vertices, 4) and ft.shape == (tgt.n_vertices, 4)
    np.testing.assert_allclose(fs.mean(axis=0), 0, atol=1e-12)
    np.testing.assert_allclose(np.mean(np.sum(fs**2, axis=1)), 1.0)
    same_s, same_t = local_wks_features(src, src, k=40, n_energies=20, first=10, n_components=4)
    np.testing.assert_array_equal(same_s, same_t)  # one shape twice: the same features
    # a near-isometric copy: corresponding points have near features (against random pairs)
    near = np.mean(np.linalg.norm(ft - fs[perm], axis=1))
    rand = np.mean(np.linalg.norm(ft - fs[np.random.default_rng(0).permutation(perm)], axis=1))
    assert near < 0.5 * rand
    with pytest.raises(ValueError, match="first < n_energies"):
        local_wks_features(src, tgt, n_energies=20, first=20)


def test_deform_feature_stage_parameters(pair):
    src, tgt, _ = pair
    with pytest.raises(ValueError, match="feature_icp_iterations"):
        make_matcher("deform", feature_icp_iterations=-1).match(src, tgt)
    with pytest.raises(ValueError, match="feature_weight"):
        make_matcher("deform", feature_weight=float("nan")).match(src, tgt)


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


def test_deform_matcher_fills_the_small_islands_of_its_map(pair, monkeypatch):
    import topomatch.matching.deform as deform_module
    from topomatch.maps.patches import fill_small_patches

    src, tgt, perm = pair
    # the registration is stubbed and the read-off map damaged: a small disc of the target sent to one far vertex
    far = int(np.argmax(np.linalg.norm(src.vertices - src.vertices[perm[0]], axis=1)))
    disc = np.flatnonzero(np.linalg.norm(tgt.vertices - tgt.vertices[0], axis=1) < 0.1 * np.sqrt(tgt.area))
    damaged = perm.copy()
    damaged[disc] = far
    monkeypatch.setattr(deform_module.DeformMatcher, "register", lambda self, s, t: (s.vertices, {"seconds": {"refinement": 0.0}}))
    monkeypatch.setattr(deform_module, "map_from_deformed", lambda t, d, f: damaged.copy())
    c = make_matcher("deform").match(src, tgt)
    expected, n = fill_small_patches(damaged, tgt.vertices, tgt.faces, src.vertices, src.faces)
    assert 3 < n == len(disc) == c.info["filled"]
    np.testing.assert_array_equal(c.p2p_21, expected)
    err = np.linalg.norm(src.vertices[c.p2p_21[disc]] - src.vertices[perm[disc]], axis=1)
    assert np.all(err < 0.15 * np.sqrt(src.area))  # near the disc's truth, no longer at the far vertex
    off = make_matcher("deform", fill_patches=False).match(src, tgt)
    np.testing.assert_array_equal(off.p2p_21, damaged)
    assert "filled" not in off.info
    monkeypatch.undo()
    with pytest.raises(ValueError, match="fill_patches"):
        make_matcher("deform", fill_patches="yes").match(src, tgt)
