"""Matching through a clean template (the ``template`` matcher)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy import sparse

from topomatch.datasets.base import Shape
from topomatch.maps.patches import fill_small_patches
from topomatch.maps.symmetry import flip_mirror_patches
from topomatch.matching import MATCHERS, NotFittedError, make_matcher
from topomatch.matching.deform import ACCURATE, WORKING_SIZES, map_from_deformed
from topomatch.matching.template import (
    CHALLENGE_ABOVE,
    CHALLENGE_JUDGE,
    FEATURE_ITERATIONS,
    FOLLOW_BENT,
    FOLLOW_SPECTRAL,
    FOLLOW_TOP,
    POSE_CHALLENGERS,
    POSE_SOURCES,
    POSED_STARTS,
    QUICK,
    REFINED_RUNS,
    RIGID_FRAMES_WITH_POSES,
    compose_through_template,
    mirrored_pose,
    pose_from_ground_truth,
)
from topomatch.mesh import TriangleMesh

from ._fmap_shapes import shuffled
from ._truth import euclidean_errors

# a cheaper registration than the default, enough for the built-in figure (two starts
# instead of ACCURATE's five: the starts are still judged against each other)
FAST = {"n_samples": 800, "coarse_nodes": 100, "fine_nodes": 250, "limb_rounds": 1, "n_starts": 2}


def test_compose_through_template():
    t2m = np.array([2, 0, 1, 2])
    m2s = np.array([5, 6, 7])
    np.testing.assert_array_equal(compose_through_template(t2m, m2s), [7, 5, 6, 7])
    with pytest.raises(ValueError, match="outside"):
        compose_through_template(np.array([3]), m2s)
    with pytest.raises(ValueError, match="1-D"):
        compose_through_template(np.zeros((2, 2), int), m2s)


def test_template_needs_a_template(tmp_path, builtin):
    assert MATCHERS["template"].requires_fit
    with pytest.raises(NotFittedError):
        make_matcher("template").match(builtin["syn01"].mesh, builtin["syn02"].mesh)
    # shapes without a null shape among them, and no model file
    with pytest.raises(ValueError, match="no template"):
        make_matcher("template").fit([builtin["syn01"], builtin["syn02"]])
    with pytest.raises(FileNotFoundError, match="not found"):
        make_matcher("template", model=str(tmp_path / "none.off")).fit([])
    with pytest.raises(ValueError, match="bad deform"):
        make_matcher("template", deform={"bogus": 1}).fit([builtin["syn00"]])
    with pytest.raises(ValueError, match="limb_rounds"):
        make_matcher("template", deform={"limb_rounds": -1}).fit([builtin["syn00"]])
    with pytest.raises(ValueError, match="deform must be a mapping"):
        make_matcher("template", deform='{"n_starts": 1, "refine_runs": nul}').fit([builtin["syn00"]])
    with pytest.raises(ValueError, match="copy_starts"):
        make_matcher("template", copy_starts=0).fit([builtin["syn00"]])


def test_template_registers_through_working_copies_with_copy_starts(builtin):
    # a registration through working copies runs every start at every copy size, so
    # the template uses copy_starts (1) there instead of ACCURATE's five starts
    small = builtin["syn07"].mesh
    m = make_matcher("template").fit([builtin["syn00"]])
    deformer = m._deformer()
    assert m._deformer_for(small, deformer) is deformer and deformer.n_starts == 5
    above = make_matcher("template", deform={"working_vertices": small.n_vertices - 1}).fit([builtin["syn00"]])
    d = above._deformer()
    assert above._deformer_for(small, d).n_starts == 1
    assert above._deformer_for(small, d).get_params() == {**d.get_params(), "n_starts": 1}
    # None: the deformer's own n_starts at every size
    assert make_matcher("template", deform={"working_vertices": small.n_vertices - 1}, copy_starts=None).fit(
        [builtin["syn00"]]
    )._deformer_for(small, d).n_starts == 5
    assert above._deformer_for(small, d) is not d and d.n_starts == 5


@pytest.fixture(scope="module")
def fitted(builtin):
    # as the benchmark fits it: the null shape and the training split
    m = make_matcher("template", deform=FAST)
    m.fit([builtin[n] for n in ["syn00", *builtin.splits["train"]]])
    return m


def _poses_for(matcher, mesh: TriangleMesh) -> list:
    """The poses the template matcher gives a registration onto ``mesh``: all but the mesh's own."""
    return [(name, P) for name, h, P in matcher.poses_ if h != mesh.content_hash]


def test_template_is_deform_when_the_source_is_the_template(fitted, builtin):
    assert fitted.template_name_ == "syn00"
    src, tgt = builtin["syn00"].mesh, builtin["syn07"].mesh
    c = fitted.match(src, tgt)
    assert c.info["registrations"] == {"target": "computed", "source": "is the template"}
    assert [name for name, _, _ in fitted.poses_] == fitted.training_shapes_[1:] == builtin.splits["train"]
    params = {**ACCURATE, "feature_icp_iterations": FEATURE_ITERATIONS, **FAST, "pose_sources": POSE_SOURCES, "refine_runs": REFINED_RUNS,
              "pose_challengers": POSE_CHALLENGERS, "challenge_judge": CHALLENGE_JUDGE, "challenge_above": CHALLENGE_ABOVE,
              "follow_top": FOLLOW_TOP, "follow_spectral": FOLLOW_SPECTRAL, "follow_bent": FOLLOW_BENT,
              "rigid_frames_with_poses": RIGID_FRAMES_WITH_POSES}
    deformed, _ = make_matcher("deform", **params).register(src, tgt, poses=_poses_for(fitted, tgt))
    plain = map_from_deformed(tgt, deformed, src.faces)
    # the map to the template with its mirrored patches repaired (the template's symmetry map from the null shape)
    fixed, n_flipped = flip_mirror_patches(plain, tgt.faces, src.vertices, src.faces, builtin["syn00"].sym)
    # then the small islands filled from the large pieces
    filled, n_filled = fill_small_patches(fixed, tgt.vertices, tgt.faces, src.vertices, src.faces)
    np.testing.assert_array_equal(c.p2p_21, filled)
    assert c.info["repaired"] == {"target": {"mirrored": n_flipped, "filled": n_filled}}
    off = copy.copy(fitted).set_params(mirror_patches=False, fill_patches=False).match(src, tgt)
    np.testing.assert_array_equal(off.p2p_21, plain)
    assert off.info["repaired"] == {"target": {}}
    # two sampling starts and the template in the best-fitting training pose, the best kept
    assert [len(info["runs"]) for _, info in fitted.registrations_.values()] == [3]
    runs = c.info["runs"]["target"]["runs"]
    assert [r["source_pose"] is None for r in runs] == [True, True, False] and "source" not in c.info["runs"]
    assert runs[2]["source_pose"] in builtin.splits["train"]
    # only the two that lead after verification are refined; the kept one is among them
    assert sum(r["refined"] for r in runs) == REFINED_RUNS == 2 and runs[c.info["runs"]["target"]["kept"]]["refined"]
    lead = sorted(np.argsort([r["verified_score"] for r in runs], kind="stable")[:REFINED_RUNS].tolist())
    assert [i for i, r in enumerate(runs) if r["refined"]] == lead
    # POSE_CHALLENGERS challengers, which this shape's kept map (folding less than 5 %) does not call for: the gate recorded
    kept = c.info["runs"]["target"]["kept"]
    assert c.info["runs"]["target"]["challenge"] == {"folded": runs[kept]["folded"], "above": 0.05, "registered": False}
    gated = copy.copy(fitted).set_params(deform={**FAST, "pose_challengers": 1, "challenge_above": 1.0}).match(src, tgt)
    np.testing.assert_array_equal(gated.p2p_21, c.p2p_21)
    record = gated.info["runs"]["target"]
    assert record["challenge"]["registered"] is False and record["challenge"]["above"] == 1.0
    assert [r["challenger"] for r in record["runs"]] == [False] * 3
    # the gate open: the challengers registered and refined, the lowest score of the refined runs kept
    opened = copy.copy(fitted).set_params(deform={**FAST, "challenge_above": 0.0}).match(src, tgt).info["runs"]["target"]
    assert [r["challenger"] for r in opened["runs"]] == [False] * 3 + [True] * POSE_CHALLENGERS and opened["challenge"]["registered"]
    refined = {i: r["score"] for i, r in enumerate(opened["runs"]) if r["refined"]}
    assert len(refined) == REFINED_RUNS + POSE_CHALLENGERS and opened["kept"] == min(refined, key=refined.get)
    # session 42's default: no challengers, no record
    plain_record = copy.copy(fitted).set_params(deform={**FAST, "pose_challengers": 0}).match(src, tgt).info["runs"]["target"]
    assert "challenge" not in plain_record and len(plain_record["runs"]) == 3
    # through working copies the template as it is runs at the smallest copy size only (the posed one at every size)
    assert fitted._deformer().start_sizes == (min(WORKING_SIZES),)
    other = copy.copy(fitted).set_params(deform={**FAST, "working_sizes": (12000, 9000)})
    assert other._deformer().start_sizes == (9000,)
    assert copy.copy(fitted).set_params(deform={**FAST, "start_sizes": None})._deformer().start_sizes is None
    assert copy.copy(fitted).set_params(deform={**FAST, "pose_sources": 0})._deformer().start_sizes is None  # session 29's setting
    assert make_matcher("template").fit([builtin["syn00"]])._deformer().start_sizes is None  # no poses, no posed source
    # refine_runs likewise: two with the posed source, unless told otherwise
    assert fitted._deformer().refine_runs == REFINED_RUNS
    assert copy.copy(fitted).set_params(deform={**FAST, "refine_runs": None})._deformer().refine_runs is None
    assert copy.copy(fitted).set_params(deform={**FAST, "pose_sources": 0})._deformer().refine_runs is None
    assert make_matcher("template").fit([builtin["syn00"]])._deformer().refine_runs is None
    # follow_top: with training poses the second start verifies the first start's four best (#164), else every hypothesis
    assert fitted._deformer().follow_top == FOLLOW_TOP == 4
    assert copy.copy(fitted).set_params(deform={**FAST, "follow_top": 0})._deformer().follow_top == 0
    assert make_matcher("template").fit([builtin["syn00"]])._deformer().follow_top == 0
    # follow_spectral: the follower also verifies every spectral setting (#165)
    assert fitted._deformer().follow_spectral is FOLLOW_SPECTRAL is True
    assert copy.copy(fitted).set_params(deform={**FAST, "follow_spectral": False})._deformer().follow_spectral is False
    assert make_matcher("template").fit([builtin["syn00"]])._deformer().follow_spectral is False
    # follow_bent: and its own bent copies when the first start's best hold one (#167)
    assert fitted._deformer().follow_bent is FOLLOW_BENT is True
    assert copy.copy(fitted).set_params(deform={**FAST, "follow_bent": False})._deformer().follow_bent is False
    assert make_matcher("template").fit([builtin["syn00"]])._deformer().follow_bent is False
    # the template's registrations use the accurate settings unless told otherwise
    assert make_matcher("template")._deformer().get_params()["n_starts"] == ACCURATE["n_starts"] == 5
    assert make_matcher("template", deform={"n_starts": 1})._deformer().get_params()["n_starts"] == 1


def test_template_composes_the_two_registrations(fitted, builtin):
    s, t = builtin["syn08"], builtin["syn07"]
    c = fitted.match(s.mesh, t.mesh)
    # syn07 was registered by the previous test (same matcher object): reused
    assert c.info["registrations"] == {"target": "reused", "source": "computed"}
    # the composition, recomputed from the two registrations
    deform = make_matcher("deform", **{**ACCURATE, "feature_icp_iterations": FEATURE_ITERATIONS, **FAST})
    template = builtin["syn00"].mesh
    d_t, _ = deform.register(template, t.mesh, poses=_poses_for(fitted, t.mesh))
    d_s, _ = deform.register(template, s.mesh, poses=_poses_for(fitted, s.mesh))
    t2m = flip_mirror_patches(map_from_deformed(t.mesh, d_t, template.faces), t.mesh.faces, template.vertices, template.faces, fitted.template_sym_)[0]
    t2m = fill_small_patches(t2m, t.mesh.vertices, t.mesh.faces, template.vertices, template.faces)[0]
    m2s = map_from_deformed(TriangleMesh(d_s, template.faces), s.mesh.vertices, s.mesh.faces)
    np.testing.assert_array_equal(c.p2p_21, m2s[t2m])
    # and it is a good map: most target vertices land near their true source vertex
    assert np.median(euclidean_errors(t, s, c.p2p_21)) < 0.05
    # the reverse pair reuses both registrations
    back = fitted.match(t.mesh, s.mesh)
    assert back.info["registrations"] == {"target": "reused", "source": "reused"}


def test_template_model_file_round_trip(tmp_path, fitted, builtin):
    path = fitted.save_model(tmp_path / "tmpl")
    assert path.suffix == ".off" and path.is_file()
    m = make_matcher("template", model=str(path), deform=FAST).fit([])
    np.testing.assert_allclose(m.template_.vertices, builtin["syn00"].mesh.vertices, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(m.template_.faces, builtin["syn00"].mesh.faces)
    # the symmetry map goes beside the mesh and comes back with it
    assert (tmp_path / "tmpl_sym.txt").is_file()
    np.testing.assert_array_equal(m.template_sym_, builtin["syn00"].sym)
    # without it the mirror-patch repair is skipped unless a file is given
    (tmp_path / "tmpl_sym.txt").rename(tmp_path / "other_sym.txt")
    assert make_matcher("template", model=str(path), deform=FAST).fit([]).template_sym_ is None
    m = make_matcher("template", model=str(path), symmetry=str(tmp_path / "other_sym.txt"), deform=FAST).fit([])
    np.testing.assert_array_equal(m.template_sym_, builtin["syn00"].sym)
    with pytest.raises(FileNotFoundError, match="symmetry map not found"):
        make_matcher("template", model=str(path), symmetry=str(tmp_path / "none.txt")).fit([])
    with pytest.raises(ValueError, match="mirror_patches"):
        make_matcher("template", model=str(path), mirror_patches="yes").fit([])
    with pytest.raises(ValueError, match="fill_patches"):
        make_matcher("template", model=str(path), fill_patches=1).fit([])


def test_template_model_file_brings_the_training_poses(tmp_path, fitted, builtin):
    # topomatch fit template --out MODEL.off, then topomatch match --template MODEL.off: the same matcher
    path = fitted.save_model(tmp_path / "model.off")
    assert (tmp_path / "model_poses.npz").is_file()
    m = make_matcher("template", model=str(path), deform=FAST).fit([])
    assert m.training_shapes_ == ["model", *builtin.splits["train"]]
    assert [(n, h) for n, h, _ in m.poses_] == [(n, h) for n, h, _ in fitted.poses_]
    for (_, _, P), (_, _, Q) in zip(m.poses_, fitted.poses_):
        np.testing.assert_array_equal(P, Q)
    # so the registration is set up as the benchmark's: two starts, the posed source, the challengers
    assert m._deformer().get_params() == fitted._deformer().get_params()
    assert m._deformer().pose_sources == POSE_SOURCES and m._deformer().challenge_above == CHALLENGE_ABOVE
    # a shape's own pose is still left out by content
    own = builtin[builtin.splits["train"][0]]
    assert len(_poses_for(m, own.mesh)) == len(m.poses_) - 1
    # poses=False ignores them; mirror_poses mirrors them with the model's symmetry map
    assert make_matcher("template", model=str(path), poses=False).fit([]).poses_ == []
    mirrored = make_matcher("template", model=str(path), mirror_poses=True).fit([])
    assert len(mirrored.poses_) == 2 * len(fitted.poses_) and mirrored.training_shapes_ == m.training_shapes_
    np.testing.assert_array_equal(mirrored.poses_[1][2], mirrored_pose(fitted.poses_[0][2], builtin["syn00"].sym))
    # a model saved again writes only the unmirrored poses
    mirrored.save_model(tmp_path / "again.off")
    assert len(np.load(tmp_path / "again_poses.npz")["names"]) == len(fitted.poses_)
    # a model without poses removes a stale poses file, whose poses would not be its own
    make_matcher("template", poses=False).fit([builtin["syn00"]]).save_model(tmp_path / "again.off")
    assert not (tmp_path / "again_poses.npz").exists()
    # bad poses files: the file named, what is wrong said
    np.savez(tmp_path / "model_poses.npz", names=np.array(["a"]), hashes=np.array(["h"]), poses=np.zeros((1, 5, 3)))
    with pytest.raises(ValueError, match=r"model_poses\.npz.*do not fit a template of"):
        make_matcher("template", model=str(path)).fit([])
    np.savez(tmp_path / "model_poses.npz", names=np.array(["a"]), poses=np.zeros((1, 5, 3)))
    with pytest.raises(ValueError, match=r"model_poses\.npz: not a template's poses file"):
        make_matcher("template", model=str(path)).fit([])
    (tmp_path / "model_poses.npz").write_text("not npz")
    with pytest.raises(ValueError, match=r"model_poses\.npz: not a template's poses file"):
        make_matcher("template", model=str(path)).fit([])
    n = fitted.template_.n_vertices
    np.savez(tmp_path / "model_poses.npz", names=np.array(["a"]), hashes=np.array(["h"]), poses=np.full((1, n, 3), np.nan))
    with pytest.raises(ValueError, match="finite"):
        make_matcher("template", model=str(path)).fit([])


def test_pose_from_ground_truth_moves_the_template_into_the_shape_s_pose(builtin):
    template = builtin["syn00"].mesh
    n = template.n_vertices
    # the template itself, moved and renumbered: shape vertex i is template vertex perm[i]
    moved0, perm = shuffled(template, seed=2)
    shift = np.array([3.0, -1.0, 0.5])
    moved = TriangleMesh(moved0.vertices + shift, moved0.faces)
    truth = sparse.csr_matrix((np.ones(n), (np.arange(n), perm)), shape=(n, n))
    np.testing.assert_allclose(pose_from_ground_truth(template, Shape("moved", moved, truth)), template.vertices + shift, atol=1e-9)
    # a third of the ground truth flagged unreliable: those template vertices are
    # interpolated (a translation is harmonic, so exactly up to the solver)
    unreliable = np.arange(n) % 3 == 0
    P = pose_from_ground_truth(template, Shape("moved", moved, truth, unreliable=unreliable))
    np.testing.assert_allclose(P, template.vertices + shift, atol=1e-6 * np.abs(template.vertices).max())
    # a rotation: reached vertices exact, the others near (harmonic, not rigid)
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    turned = TriangleMesh(moved0.vertices @ R.T, moved0.faces)
    P = pose_from_ground_truth(template, Shape("turned", turned, truth, unreliable=unreliable))
    reached = np.zeros(n, bool)
    reached[perm[~unreliable]] = True
    np.testing.assert_allclose(P[reached], (template.vertices @ R.T)[reached], atol=1e-9)
    err = np.linalg.norm(P[~reached] - (template.vertices @ R.T)[~reached], axis=1) / np.sqrt(template.area)
    assert err.max() < 0.02
    # a template vertex reached by several shape vertices: their mean
    two = sparse.csr_matrix((np.ones(2), ([0, 1], [5, 5])), shape=(2, n))
    pts = TriangleMesh(np.array([[0.0, 0, 0], [2.0, 0, 0], [0, 1.0, 0]]), np.array([[0, 1, 2]]))
    tiny = Shape("tiny", pts, sparse.vstack([two, sparse.csr_matrix((1, n))]).tocsr())
    np.testing.assert_allclose(pose_from_ground_truth(template, tiny)[5], [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="no ground truth"):
        pose_from_ground_truth(template, Shape("bare", moved))
    with pytest.raises(ValueError, match="columns"):
        pose_from_ground_truth(template, Shape("wrong", moved, truth[:, : n - 1]))
    with pytest.raises(ValueError, match="reaches no template vertex"):
        pose_from_ground_truth(template, Shape("moved", moved, truth, unreliable=np.ones(n, bool)))


def test_template_poses_leave_the_shape_s_own_pose_out(builtin):
    train = builtin.splits["train"]
    m = make_matcher("template", deform={**FAST, "n_starts": 1}).fit([builtin[n] for n in ["syn00", *train]])
    assert [name for name, _, _ in m.poses_] == train
    own = builtin[train[0]]
    m.match(builtin["syn00"].mesh, own.mesh)
    ((_, info),) = m.registrations_.values()
    labels = [label for label in info["residuals"] if label.startswith("pose ")]
    assert len(labels) == 3  # pose_keep: the three best alignments
    assert not any(label.split()[1] == own.name for label in labels)
    # without poses: none
    off = make_matcher("template", deform={**FAST, "n_starts": 1}, poses=False).fit([builtin[n] for n in ["syn00", *train]])
    assert off.poses_ == [] and off.training_shapes_ == ["syn00"]
    # with training poses the registration has POSED_STARTS starts and POSE_SOURCES posed
    # sources, without them ACCURATE's five starts and none
    posed = make_matcher("template").fit([builtin[n] for n in ["syn00", *train]])._deformer()
    assert posed.n_starts == POSED_STARTS == 2 and posed.pose_sources == POSE_SOURCES == 1
    assert posed.feature_icp_iterations == FEATURE_ITERATIONS == 60
    # quick: session 46's cheaper registration (one start, one refined, shorter stages, the rigid hypotheses
    # as given beside the poses); deform still on top; without poses it changes nothing
    quick = make_matcher("template", quick=True).fit([builtin[n] for n in ["syn00", *train]])._deformer()
    assert {k: quick.get_params()[k] for k in QUICK} == dict(QUICK)
    assert (quick.n_starts, quick.refine_runs, quick.coarse_icp_iterations, quick.fine_icp_iterations, quick.feature_icp_iterations,
            quick.rigid_frames_with_poses, quick.pose_sources) == (1, 1, 10, 25, 30, ("as-given",), POSE_SOURCES)
    assert posed.rigid_frames_with_poses == RIGID_FRAMES_WITH_POSES == ("as-given",) and posed.refine_runs == REFINED_RUNS == 2
    assert make_matcher("template", quick=True, deform={"n_starts": 3}).fit([builtin[n] for n in ["syn00", *train]])._deformer().n_starts == 3
    assert make_matcher("template", quick=True, poses=False).fit([builtin[n] for n in ["syn00", *train]])._deformer().get_params() == (
        make_matcher("template", poses=False).fit([builtin[n] for n in ["syn00", *train]])._deformer().get_params())
    with pytest.raises(ValueError, match="quick"):
        make_matcher("template", quick="yes").fit([builtin[n] for n in ["syn00", *train]])
    assert (posed.pose_challengers, posed.challenge_judge, posed.challenge_above) == (POSE_CHALLENGERS, CHALLENGE_JUDGE, CHALLENGE_ABOVE) == (3, "score", 0.05)
    assert make_matcher("deform").challenge_above == 0.06  # deform's own gate stays the training split's
    assert make_matcher("template", poses=False).fit([builtin[n] for n in ["syn00", *train]])._deformer().feature_icp_iterations == make_matcher("deform").feature_icp_iterations == 80
    assert make_matcher("template", poses=False).fit([builtin[n] for n in ["syn00", *train]])._deformer().pose_sources == 0
    assert make_matcher("template", deform={"n_starts": 1}).fit([builtin[n] for n in ["syn00", *train]])._deformer().n_starts == 1
    assert make_matcher("template", poses=False).fit([builtin[n] for n in ["syn00", *train]])._deformer().n_starts == ACCURATE["n_starts"]
    assert make_matcher("template").fit([builtin["syn00"]])._deformer().n_starts == ACCURATE["n_starts"]  # no training shapes
    with pytest.raises(ValueError, match="poses"):
        make_matcher("template", poses="yes").fit([builtin["syn00"]])


def test_mirrored_pose_exchanges_left_and_right(builtin):
    ref = builtin["syn00"]
    V, sym = ref.mesh.vertices, ref.sym
    # the rest pose is its own mirror image (syn00 is symmetric about x = 0, to its vertex placement)
    M = mirrored_pose(V, sym)
    assert np.abs(M - V).max() < 0.02 * np.abs(V).max()
    # a pose with one side moved: the mirror image moves the other side
    P = V + np.where(V[:, :1] > 0.2, [0.0, 0.0, 0.3], 0.0)
    Q = mirrored_pose(P, sym)
    moved = np.linalg.norm(Q - M, axis=1) > 0.1
    assert moved.any() and (V[moved, 0] < -0.15).all()
    # outward normals stay outward: the signed volume keeps its sign
    F = ref.mesh.faces
    def volume(X):
        return np.einsum("ij,ij->i", X[F[:, 0]], np.cross(X[F[:, 1]], X[F[:, 2]])).sum() / 6

    assert np.sign(volume(Q)) == np.sign(volume(V)) != 0
    with pytest.raises(ValueError, match="symmetry map"):
        mirrored_pose(V, sym[:-1])
    # the template gives both, and leaves both out for the shape itself
    train = builtin.splits["train"]
    m = make_matcher("template", mirror_poses=True).fit([builtin[n] for n in ["syn00", *train]])
    assert [name for name, _, _ in m.poses_] == [x for n in train for x in (n, n + " mirrored")]
    assert m.training_shapes_ == ["syn00", *train]
