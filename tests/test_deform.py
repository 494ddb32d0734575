"""Deformation graphs, graph registration and the deform matcher."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from topomatch.datasets.toy import icosphere
from topomatch.deform.graph import build_deformation_graph
from topomatch.deform.register import DataPairs, RegistrationSchedule, fit_residual, register
from topomatch.matching import MATCHERS, make_matcher
from topomatch.matching.deform import (
    _PREPARED_KEPT,
    _prepared,
    local_wks_features,
    map_from_deformed,
    swap_regions,
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



@pytest.mark.parametrize("stop", [0, 4, 7])
def test_registration_stopped_and_resumed_equals_one_call(pair, stop):
    # the verification's race (DeformMatcher.race_iterations): every hypothesis stops after a
    # few closest-point iterations, the best go on from there, bit for bit as one call
    src, tgt, _ = pair
    g = build_deformation_graph(src.vertices, src.faces, 80)
    smp = (farthest_point_sampling(300, points=src.vertices), farthest_point_sampling(300, points=tgt.vertices))
    pts = np.arange(0, src.n_vertices, 30)
    pairs = DataPairs(pts, tgt.vertices[pts], tgt.vertex_normals[pts], np.ones(len(pts)))
    sched = RegistrationSchedule(n_nodes=80, fit_iterations=3, icp_iterations=8)
    whole = register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, sched, graph=g, samples=smp)
    part = register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, sched, graph=g, samples=smp, stop_after=stop)
    assert whole.resume_at is None and part.resume_at == stop
    # the partial result is the state after `stop` iterations: as a shorter schedule would not be
    # (its stiffness and scales follow the whole schedule), but scored the same way
    assert part.residual >= 0 and not np.array_equal(part.deformed, whole.deformed)
    done = register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, graph=g, samples=smp, resume=part)
    assert done.resume_at is None
    assert np.array_equal(done.deformed, whole.deformed)
    assert done.residual == whole.residual and done.distortion == whole.distortion
    with pytest.raises(ValueError, match="resume must be the result of a call with stop_after"):
        register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, graph=g, samples=smp, resume=whole)
    with pytest.raises(ValueError, match="stop_after must be an integer"):
        register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, sched, graph=g, samples=smp, stop_after=9)
    with pytest.raises(ValueError, match="already been resumed"):
        register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, graph=g, samples=smp, resume=part)


def test_turned_normals_follow_the_nodes_rotations(pair):
    from topomatch.deform.register import GraphDeformation

    src, _, _ = pair
    g = build_deformation_graph(src.vertices, src.faces, 80)
    D = GraphDeformation(src.vertices, src.faces, g)
    some = np.arange(0, src.n_vertices, 7)
    n0 = src.vertex_normals
    np.testing.assert_allclose(D.turned_normals(n0, some), n0[some], atol=1e-14)
    # one rotation for every node: every normal turned by it (the translations play no part)
    R = axis_rotation(np.array([0.3, -1.0, 0.5]), 0.8)
    D.rotations[:] = R
    D.positions += 5.0
    np.testing.assert_allclose(D.turned_normals(n0, some), n0[some] @ R.T, atol=1e-12)
    # two nodes' rotations blend: a vertex between them gets the normalised blend
    assert np.allclose(np.linalg.norm(D.turned_normals(n0, some), axis=1), 1.0)


def test_registration_on_a_surface_subset(pair):
    # register's surface: the closest-point iterations deform and search a subset of the
    # source's vertices (with turned rest normals); close to the registration on every vertex
    src, tgt, perm = pair
    g = build_deformation_graph(src.vertices, src.faces, 80)
    smp = (farthest_point_sampling(300, points=src.vertices, first=0), farthest_point_sampling(300, points=tgt.vertices))
    surface = np.union1d(farthest_point_sampling(900, points=src.vertices, first=0), smp[0])
    assert len(surface) == 900  # the farthest points from the same start hold the samples
    pts = np.arange(0, src.n_vertices, 30)
    exact = np.empty_like(src.vertices)
    exact[perm] = tgt.vertices
    pairs = DataPairs(pts, exact[pts], tgt.vertex_normals[np.argsort(perm)][pts], np.ones(len(pts)))
    sched = RegistrationSchedule(n_nodes=80, fit_iterations=3, icp_iterations=8)
    every = register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, sched, graph=g, samples=smp)
    some = register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, sched, graph=g, samples=smp, surface=surface)
    assert not np.array_equal(some.deformed, every.deformed)
    assert some.residual < 1.2 * every.residual + 1e-3
    assert np.linalg.norm(some.deformed - exact, axis=1).mean() < 0.05 * np.sqrt(src.area)
    # stopped and resumed on the subset: bit for bit as one call
    part = register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, sched, graph=g, samples=smp, surface=surface, stop_after=4)
    done = register(src.vertices, src.faces, tgt.vertices, tgt.faces, None, sched, graph=g, samples=smp, surface=surface, resume=part)
    assert np.array_equal(done.deformed, some.deformed) and done.residual == some.residual
    # bad subsets are named
    for bad, match in ((surface[::-1], "sorted"), (surface[1:], "every source sample"), (np.r_[surface, src.n_vertices], r"\[0, "),
                       (surface.astype(float), "vertex indices"), (np.array([], dtype=int), "non-empty")):
        with pytest.raises(ValueError, match=match):
            register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, sched, graph=g, samples=smp, surface=bad)
    with pytest.raises(ValueError, match="needs the source samples"):
        register(src.vertices, src.faces, tgt.vertices, tgt.faces, pairs, sched, graph=g, surface=surface)


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


@pytest.mark.parametrize("n_threads", [1, 2])
def test_deform_race_changes_nothing_when_every_hypothesis_goes_on(pair, n_threads):
    src, tgt, _ = pair
    kw = {"hypotheses": (("hks", 30, False),), "n_samples": 600, "coarse_nodes": 60, "fine_nodes": 150, "coarse_icp_iterations": 8,
          "fine_icp_iterations": 6, "limb_rounds": 1, "n_threads": n_threads, "n_starts": 2, "follow_top": 2}
    base = make_matcher("deform", **kw).match(src, tgt)
    every = make_matcher("deform", race_iterations=3, race_keep=100, **kw).match(src, tgt)
    np.testing.assert_array_equal(every.p2p_21, base.p2p_21)
    assert every.info["residuals"] == base.info["residuals"]
    # a real race: the three best after 3 iterations go on, bit for bit as uninterrupted
    # verifications; the others keep their state after 3
    raced = make_matcher("deform", race_iterations=3, race_keep=3, **kw)
    hyps, results = raced.verify_hypotheses(src, tgt)
    hyps0, results0 = make_matcher("deform", **kw).verify_hypotheses(src, tgt)
    assert [h.label for h in hyps] == [h.label for h in hyps0] and len(hyps) > 3
    whole = [r.resume_at is None for r in results]
    assert sum(whole) == 3 and all(r.resume_at == 3 for r, w in zip(results, whole) if not w)
    for r, r0, w in zip(results, results0, whole):
        if w:
            np.testing.assert_array_equal(r.deformed, r0.deformed)
            assert r.residual == r0.residual
    # the three that went on are the three best at the stop
    samples, graph, surface, basis = raced._setup(src, tgt)
    _, stops, go_on = raced._verify(src, tgt, raced._check(), samples, graph, surface, basis)
    assert go_on is not None and all(r.resume_at == 3 for r in stops)
    assert [i for i, w in enumerate(whole) if w] == sorted(np.argsort([r.residual for r in stops], kind="stable")[:3])
    assert [r.residual for r, w in zip(results, whole) if not w] == [r.residual for r, w in zip(stops, whole) if not w]
    c = raced.match(src, tgt)
    assert c.p2p_21.shape == (tgt.n_vertices,)
    assert set(c.info["continued"]) <= {h.label for h, w in zip(hyps, whole) if w} or c.info["run"] != 0


def test_deform_surface_vertices(pair):
    # the coarse registrations on the samples and farthest points: a valid map, and the
    # whole surface (as many vertices as the source has) is not the default's path
    src, tgt, perm = pair
    kw = {"hypotheses": (("hks", 30, False),), "n_samples": 400, "coarse_nodes": 60, "fine_nodes": 150, "coarse_icp_iterations": 8,
          "fine_icp_iterations": 6, "limb_rounds": 1, "n_threads": 1}
    base = make_matcher("deform", **kw).match(src, tgt)
    some = make_matcher("deform", surface_vertices=1200, **kw).match(src, tgt)
    err0, err = (np.linalg.norm(src.vertices[c.p2p_21] - src.vertices[perm], axis=1).mean() / np.sqrt(src.area) for c in (base, some))
    assert err < max(1.5 * err0, 0.05)
    m = make_matcher("deform", surface_vertices=1200, **kw)
    s1 = m._samples(src, 0)
    first = m._surface(src, s1)
    assert np.all(np.isin(s1, first)) and len(first) == 1200 and np.all(np.diff(first) > 0)
    assert np.array_equal(m._setup(src, tgt)[2], first)  # made once per run, beside the samples
    assert make_matcher("deform", **kw)._surface(src, s1) is None
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="surface_vertices"):
            make_matcher("deform", surface_vertices=bad, **kw).match(src, tgt)


def test_deform_keeps_samples_and_graphs_across_pairs(pair):
    # the samples and graphs are pure functions of the mesh: made once, then the same
    # objects for another mesh object with the same arrays (the next pair's template)
    src, tgt, _ = pair
    m = make_matcher("deform", n_samples=300, coarse_nodes=40, fine_nodes=90, n_starts=2, n_threads=1)
    again = TriangleMesh(src.vertices.copy(), src.faces.copy())
    s0 = m._samples(src, 0)
    assert m._samples(again, 0) is s0 and not s0.flags.writeable
    assert m._samples(src, 1) is not s0 and not np.array_equal(m._samples(src, 1), s0)
    np.testing.assert_array_equal(s0, farthest_point_sampling(300, points=src.vertices, first=0))
    g = m._graph(again, 40, 0)
    assert m._setup(src, tgt)[1] is g and m._fine_graph(src, 0) is m._graph(again, 90, 0) is not g
    moved = TriangleMesh(src.vertices * 1.01, src.faces)
    assert m._graph(moved, 40, 0) is not g  # by content: other vertices, another graph
    # at most _PREPARED_KEPT kept, the latest used
    made = [_prepared(("test", k), lambda k=k: np.arange(k + 1)) for k in range(_PREPARED_KEPT + 3)]
    assert _prepared(("test", _PREPARED_KEPT + 2), lambda: None) is made[-1]
    assert _prepared(("test", 0), lambda: np.arange(1)) is not made[0]


def test_deform_feature_gate(pair):
    # a gate no fine-stage lead passes changes nothing; one every lead passes is the
    # feature stage after the choice (no challengers here)
    src, tgt, _ = pair
    kw = {"hypotheses": (("hks", 30, False),), "n_samples": 400, "coarse_nodes": 60, "fine_nodes": 150, "coarse_icp_iterations": 8,
          "fine_icp_iterations": 6, "feature_icp_iterations": 6, "limb_rounds": 0, "n_threads": 2, "n_starts": 2, "refine_runs": 2}
    base = make_matcher("deform", **kw).match(src, tgt)
    closed = make_matcher("deform", feature_gate=1e9, **kw).match(src, tgt)
    np.testing.assert_array_equal(closed.p2p_21, base.p2p_21)
    assert closed.info["feature_gate"]["passed"] is False and "feature_gate" not in base.info
    assert [r["score"] for r in closed.info["runs"]] == [r["score"] for r in base.info["runs"]]
    open_ = make_matcher("deform", feature_gate=1e-12, **kw).match(src, tgt)
    after = make_matcher("deform", features_after_choice=True, **kw).match(src, tgt)
    np.testing.assert_array_equal(open_.p2p_21, after.p2p_21)
    gate = open_.info["feature_gate"]
    assert gate["passed"] is True and gate["margin"] > 0
    # only the kept run had the feature stage: the other keeps its fine-stage score
    assert sum("fine_score" in r for r in open_.info["runs"]) == 1
    for bad, match in (({"feature_gate": -0.1}, "feature_gate"), ({"feature_gate": True}, "feature_gate"),
                       ({"feature_gate": 0.05, "features_after_choice": True}, "cannot be combined")):
        with pytest.raises(ValueError, match=match):
            make_matcher("deform", **{**kw, **bad}).match(src, tgt)


def test_deform_race_rejects_bad_settings(pair):
    src, tgt, _ = pair
    for bad, match in (({"race_iterations": 25}, "race_iterations"), ({"race_iterations": -1}, "race_iterations"),
                       ({"race_iterations": 5, "race_keep": 2}, "race_keep"),
                       ({"race_iterations": 5, "accept_residual": 0.01}, "accept_residual")):
        with pytest.raises(ValueError, match=match):
            make_matcher("deform", **bad).match(src, tgt)


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
