"""The topological-noise generator, the procedural figure and the built-in benchmark."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from topomatch.datasets._isosurface import marching_tetrahedra, winding_numbers
from topomatch.datasets._surface import HoleCaps, SurfaceLocator, decimate
from topomatch.datasets.figure import POSES, build_figure
from topomatch.datasets.noise import (
    NoiseParams,
    Shortcut,
    find_shortcuts,
    noise_files,
    noisy_collection,
    outer_surface,
    topological_noise,
    write_topkids,
)
from topomatch.datasets.toy import grid, icosphere
from topomatch.mesh import TriangleMesh

from .conftest import data_path


def _grid_field(fn, lo=-1.5, hi=1.5, h=0.05):
    g = np.arange(lo, hi + h / 2, h)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    return fn(x, y, z), np.array([lo, lo, lo]), h


def _signed_volume(mesh: TriangleMesh) -> float:
    t = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)


@pytest.fixture(scope="module")
def small_figure():
    return build_figure(3000, voxel_size=0.009)


@pytest.fixture(scope="module")
def small_collection(small_figure):
    fig = small_figure
    poses = {"a": fig.pose("hands_on_hips"), "b": fig.pose("arms_crossed"), "c": fig.pose("free")}
    params = NoiseParams(n_vertices=1500)
    return noisy_collection(
        fig.mesh.vertices, fig.mesh.faces, poses, params, pose_params={"c": NoiseParams(n_vertices=1500, shortcuts=1)},
        template_sym=fig.sym, null_vertices=1500, reference="ref", splits={"train": ["a"], "test": ["b", "c"], "all": ["a", "b", "c"]},
        random_state=3,
    )


# ---- marching tetrahedra --------------------------------------------------------------------
def test_marching_tetrahedra_sphere_is_closed_manifold_and_outward():
    f, origin, h = _grid_field(lambda x, y, z: np.sqrt(x**2 + y**2 + z**2) - 1.0)
    v, faces = marching_tetrahedra(f, origin, h)
    m = TriangleMesh(v, faces)
    assert m.is_manifold and len(m.boundary_loops) == 0 and m.n_components == 1 and m.genus == 0
    assert np.abs(np.linalg.norm(v, axis=1) - 1).max() < 0.1 * h + 1e-3
    assert _signed_volume(m) == pytest.approx(4 / 3 * np.pi, rel=0.02)


def test_marching_tetrahedra_torus_genus_one():
    f, origin, h = _grid_field(lambda x, y, z: np.sqrt((np.sqrt(x**2 + y**2) - 0.9) ** 2 + z**2) - 0.3)
    m = TriangleMesh(*marching_tetrahedra(f, origin, h))
    assert m.genus == 1 and m.is_manifold and len(m.boundary_loops) == 0


def test_marching_tetrahedra_rejects_bad_field():
    with pytest.raises(ValueError, match="3D grid"):
        marching_tetrahedra(np.zeros((4, 4)), np.zeros(3), 1.0)


# ---- winding numbers ---------------------------------------------------------------------------
def test_winding_numbers_count_overlapping_layers():
    s = icosphere(3)
    v = s.vertices[None] + np.array([[[-0.5, 0, 0]], [[0.5, 0, 0]]])
    v = v.reshape(-1, 3)
    faces = np.concatenate([s.faces, s.faces + s.n_vertices])
    h = 0.1
    origin = np.array([-1.72, -1.23, -1.17])
    shape = (36, 26, 26)
    w = winding_numbers(v, faces, origin, h, shape)
    gx, gy, gz = np.meshgrid(*[origin[i] + h * np.arange(shape[i]) for i in range(3)], indexing="ij")
    p = np.stack([gx, gy, gz], -1)
    r1 = np.linalg.norm(p - [-0.5, 0, 0], axis=-1)
    r2 = np.linalg.norm(p - [0.5, 0, 0], axis=-1)
    clear = (np.abs(r1 - 1) > 0.05) & (np.abs(r2 - 1) > 0.05)  # off the (faceted) surfaces
    expected = (r1 < 1).astype(int) + (r2 < 1).astype(int)
    assert np.array_equal(w[clear], expected[clear])
    assert (w == 2).any()


# ---- closest points, caps, decimation ---------------------------------------------------------------
def test_surface_locator_matches_brute_force(rng):
    s = icosphere(2)
    pts = rng.normal(size=(200, 3)) * 0.8
    face, bary, dist = SurfaceLocator(s.vertices, s.faces).query(pts)
    proj = np.einsum("ij,ijk->ik", bary, s.vertices[s.faces[face]])
    assert np.allclose(np.linalg.norm(pts - proj, axis=1), dist)
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(1), 1)
    # brute force over a dense sample of every face: nothing is closer
    w = rng.dirichlet(np.ones(3), size=60)
    dense = np.einsum("sk,fkd->fsd", w, s.vertices[s.faces]).reshape(-1, 3)
    brute, _ = cKDTree(np.concatenate([dense, s.vertices])).query(pts)
    assert np.all(dist <= brute + 1e-12)


def test_hole_caps_close_a_disc():
    g = grid(9)
    caps = HoleCaps.build(g.faces, g.n_vertices)
    assert caps.n_caps == 1
    closed = TriangleMesh(caps.extend(g.vertices), np.concatenate([g.faces, caps.faces]))
    assert len(closed.boundary_loops) == 0 and closed.is_manifold and closed.genus == 0


def test_decimate_keeps_topology_and_hits_target():
    f, origin, h = _grid_field(lambda x, y, z: np.sqrt((np.sqrt(x**2 + y**2) - 0.9) ** 2 + z**2) - 0.3)
    v, faces = marching_tetrahedra(f, origin, h)
    v2, f2 = decimate(v, faces, 400)
    m = TriangleMesh(v2, f2)
    assert m.n_vertices == 400
    assert m.genus == 1 and m.is_manifold and len(m.boundary_loops) == 0 and m.n_components == 1
    assert len(m.duplicate_faces) == 0 and m.face_areas.min() > 0
    # still on the torus
    r = np.sqrt((np.linalg.norm(v2[:, :2], axis=1) - 0.9) ** 2 + v2[:, 2] ** 2)
    assert np.abs(r - 0.3).max() < 0.05


def test_decimate_keeps_boundary_loops():
    g = grid(31)
    v = np.array(g.vertices)
    v[:, 2] = 0.1 * np.sin(3 * v[:, 0])
    v2, f2 = decimate(v, g.faces, 200)
    m = TriangleMesh(v2, f2)
    assert m.n_vertices == 200 and len(m.boundary_loops) == 1 and m.genus == 0 and m.is_manifold


# ---- the outer surface ----------------------------------------------------------------------------
def test_outer_surface_removes_interior_and_fuses():
    s = icosphere(3)
    v = (s.vertices[None] + np.array([[[-0.6, 0, 0]], [[0.6, 0, 0]]])).reshape(-1, 3)
    faces = np.concatenate([s.faces, s.faces + s.n_vertices])
    ov, of = outer_surface(v, faces, voxel_size=0.05)
    m = TriangleMesh(ov, of)
    assert m.n_components == 1 and m.genus == 0 and m.is_manifold and len(m.boundary_loops) == 0
    # nothing of either sphere's inside survives: every vertex is outside the other sphere
    r1 = np.linalg.norm(ov - [-0.6, 0, 0], axis=1)
    r2 = np.linalg.norm(ov - [0.6, 0, 0], axis=1)
    assert np.all(np.maximum(r1, r2) > 0.97)


def _c_shape(gap: float) -> TriangleMesh:
    """A closed genus-0 'C': a torus with a wedge cut out, ends ``gap`` apart."""
    half = np.arcsin(gap / 2 / 1.0) + np.arcsin(0.3 / 1.0)  # the tube (r 0.3) ends just leave the gap

    def fn(x, y, z):
        torus = np.sqrt((np.sqrt(x**2 + y**2) - 1.0) ** 2 + z**2) - 0.3
        ang = np.abs(np.arctan2(y, x))
        tube_end = np.where(ang < half, np.inf, torus)
        # round caps at the two ends
        caps = []
        for s in (1, -1):
            c = np.array([np.cos(half), s * np.sin(half), 0.0])
            caps.append(np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + z**2) - 0.3)
        return np.minimum(tube_end, np.minimum(*caps))

    f, origin, h = _grid_field(fn, -1.6, 1.6, 0.04)
    return TriangleMesh(*marching_tetrahedra(f, origin, h))


def test_merge_distance_decides_fusion():
    c = _c_shape(0.2)
    assert c.genus == 0
    kept = TriangleMesh(*outer_surface(c.vertices, c.faces, voxel_size=0.04, merge_distance=0.08))
    fused = TriangleMesh(*outer_surface(c.vertices, c.faces, voxel_size=0.04, merge_distance=0.5))
    assert kept.genus == 0 and fused.genus == 1


def test_shortcut_adds_a_handle():
    s = icosphere(3)
    a = s.vertices[np.argmax(s.vertices[:, 0])] * 0.9
    b = s.vertices[np.argmax(s.vertices[:, 1])] * 0.9
    plain = TriangleMesh(*outer_surface(s.vertices, s.faces, voxel_size=0.05))
    # a capsule outside the sphere, both ends sunk in it: a handle
    mid = 0.5 * (a + b)
    out = mid / np.linalg.norm(mid) * 1.6
    cut = [Shortcut(a, out, 0.12), Shortcut(out, b, 0.12)]
    bridged = TriangleMesh(*outer_surface(s.vertices, s.faces, voxel_size=0.05, shortcuts=cut))
    assert plain.genus == 0 and bridged.genus == 1


# ---- one pose, a collection -------------------------------------------------------------------------
def test_topological_noise_invariants(small_figure):
    fig = small_figure
    posed = fig.pose("hands_on_hips")
    res = topological_noise(posed, fig.mesh.faces, NoiseParams(n_vertices=1500), rest_vertices=fig.mesh.vertices, name="hips")
    m = res.mesh
    assert m.n_components == 1 and m.is_manifold and len(m.duplicate_faces) == 0 and len(m.unreferenced_vertices) == 0
    assert len(m.boundary_loops) == 0  # the figure has no holes
    assert 0.7 * 1500 < m.n_vertices < 1.1 * 1500  # area-scaled resolution: the hands sank in
    assert res.face.min() >= 0 and res.face.max() < fig.mesh.n_faces
    assert np.allclose(res.bary.sum(1), 1) and res.bary.min() >= -1e-9
    # reliable vertices lie on the clean posed surface; the hands fused, so some are not reliable
    tol = res.info["unreliable_distance"]
    assert np.all(res.distance[~res.unreliable] <= tol)
    assert 0.002 < res.unreliable.mean() < 0.2
    # the fused seam is where the hands meet the hips: unreliable vertices are near the wrists' targets
    bad = m.vertices[res.unreliable]
    assert np.median(np.abs(bad[:, 2] - 0.56)) < 0.08


def test_topological_noise_is_deterministic(small_figure):
    fig = small_figure
    posed = fig.pose("free")
    p = NoiseParams(n_vertices=1200, shortcuts=1)
    r1 = topological_noise(posed, fig.mesh.faces, p, rest_vertices=fig.mesh.vertices, random_state=5)
    r2 = topological_noise(posed, fig.mesh.faces, p, rest_vertices=fig.mesh.vertices, random_state=5)
    assert np.array_equal(r1.mesh.vertices, r2.mesh.vertices) and np.array_equal(r1.mesh.faces, r2.mesh.faces)
    assert np.array_equal(r1.unreliable, r2.unreliable)
    assert len(r1.shortcuts) == 1


def test_find_shortcuts_picks_close_but_far_apart_patches(small_figure):
    fig = small_figure
    posed = fig.pose("free")
    cuts = find_shortcuts(posed, fig.mesh.faces, 3, radius=0.02, max_gap=0.15, min_ratio=3.0, rest_vertices=fig.mesh.vertices, random_state=0)
    assert len(cuts) >= 1
    from scipy.sparse.csgraph import dijkstra

    from topomatch.mesh.geometry import edge_graph

    g = edge_graph(fig.mesh.vertices, fig.mesh.faces)
    for c in cuts:
        eu = np.linalg.norm(posed[c.vertex_a] - posed[c.vertex_b])
        geo = dijkstra(g, indices=[c.vertex_a])[0, c.vertex_b]
        assert eu <= 0.15 and geo >= 3.0 * eu


def test_noise_params_validation():
    with pytest.raises(ValueError, match="n_vertices"):
        NoiseParams(n_vertices=10).validate()
    with pytest.raises(ValueError, match="voxel_size"):
        NoiseParams(voxel_size=-1.0).validate()
    with pytest.raises(ValueError, match="shortcuts"):
        NoiseParams(shortcuts=-1).validate()


def test_collection_ground_truth_is_consistent(small_collection, small_figure):
    coll = small_collection
    null = coll["ref"]
    n_ref = null.n_vertices
    assert null.sym is not None and (null.sym >= 0).all()
    # the null shape's mirror map sends each vertex next to its reflection across x = 0
    refl = null.mesh.vertices * [-1, 1, 1]
    edge = np.median(np.linalg.norm(null.mesh.vertices[null.mesh.edges[:, 0]] - null.mesh.vertices[null.mesh.edges[:, 1]], axis=1))
    assert np.percentile(np.linalg.norm(null.mesh.vertices[null.sym] - refl, axis=1), 95) < edge
    for name in ("a", "b", "c"):
        s = coll[name]
        assert s.ref.shape == (s.n_vertices, n_ref)
        assert np.all(np.diff(s.ref.indptr) == 1)  # exactly one null vertex per vertex
        assert s.sym.shape == (s.n_vertices,) and s.sym.min() >= -1 and s.sym.max() < s.n_vertices
        # no symmetric partner for unreliable vertices, nor pointing to one
        assert np.all(s.sym[s.unreliable] == -1)
        ok = s.sym >= 0
        assert not s.unreliable[s.sym[ok]].any()
        # left-right: a vertex and its partner lie on opposite sides of the null shape's mirror plane
        x_ref = null.mesh.vertices[s.ref_p2p, 0]
        assert np.mean(np.sign(x_ref[ok]) != np.sign(x_ref[s.sym[ok]])) > 0.9
    # shortcut shape got a handle the plain template does not have
    assert coll["c"].mesh.genus >= 1


def test_collection_ground_truth_is_accurate(small_collection, small_figure):
    """Reliable vertices: the posed position of their null vertex is within about half an edge."""
    fig = small_figure
    coll = small_collection
    null = coll["ref"]
    face, bary, _ = SurfaceLocator(fig.mesh.vertices, fig.mesh.faces).query(null.mesh.vertices)
    for name, pose in (("a", "hands_on_hips"), ("b", "arms_crossed")):
        s = coll[name]
        posed = fig.pose(pose)
        gt_pos = np.einsum("ij,ijk->ik", bary, posed[fig.mesh.faces[face]])[s.ref_p2p]
        edge = np.median(np.linalg.norm(null.mesh.vertices[null.mesh.edges[:, 0]] - null.mesh.vertices[null.mesh.edges[:, 1]], axis=1))
        err = np.linalg.norm(gt_pos - s.mesh.vertices, axis=1) / edge
        rel = ~s.unreliable
        # nearest-vertex rounding alone gives errors up to ~0.6 edge
        assert np.median(err[rel]) < 0.5 and np.percentile(err[rel], 95) < 0.9
        assert err[rel].max() < 2.5


def test_write_topkids_round_trip(small_collection, tmp_path):
    from topomatch.datasets.topkids import load_topkids

    folder = write_topkids(small_collection, tmp_path)
    assert folder == tmp_path / "low_res"
    for stem in ("kid00.off", "kid00_sym.txt", "kid01.off", "kid01_ref.txt", "kid01_sym.txt", "kid01_indmap.txt", "kid01_info.txt", "kid03_indmap.txt"):
        assert (folder / stem).is_file()
    back = load_topkids(tmp_path, "low")
    assert back.names == ["kid00", "kid01", "kid02", "kid03"]
    for src, dst in (("ref", "kid00"), ("a", "kid01"), ("b", "kid02"), ("c", "kid03")):
        s, t = small_collection[src], back[dst]
        assert np.allclose(s.mesh.vertices, t.mesh.vertices, atol=1e-5)
        assert np.array_equal(s.mesh.faces, t.mesh.faces)
        assert np.array_equal(s.ref_p2p, t.ref_p2p)
        assert np.array_equal(s.sym, t.sym)
        if src != "ref":
            assert np.array_equal(s.unreliable, t.unreliable)


def test_protocols_read_the_synthetic_set(small_collection, tmp_path):
    from topomatch.datasets.base import ground_truth_21
    from topomatch.datasets.topkids import load_topkids
    from topomatch.evaluation.protocols import get_protocol

    write_topkids(small_collection, tmp_path)
    back = load_topkids(tmp_path, "low")
    assert len(get_protocol("topkids25").pairs(back, "all")) == 3
    assert len(get_protocol("shrec16").pairs(back, "train")) == 6
    g = ground_truth_21(back["kid02"], back["kid01"])
    assert g.shape == (back["kid02"].n_vertices, back["kid01"].n_vertices)
    assert 0.3 < np.mean(np.diff(g.indptr) > 0) < 1.0  # composed through kid00, unreliable excluded


# ---- files in, files out -----------------------------------------------------------------------------
def test_noise_files_and_cli(small_figure, tmp_path):
    from topomatch.cli.main import main
    from topomatch.io import write_off

    fig = small_figure
    null = tmp_path / "null.off"
    write_off(null, fig.mesh.vertices, fig.mesh.faces)
    poses = []
    for i, name in enumerate(["knees_together", "hand_on_head"]):
        p = tmp_path / f"pose{i}.off"
        write_off(p, fig.pose(name), fig.mesh.faces)
        poses.append(str(p))
    out = tmp_path / "out"
    assert main(["noise", str(null), *poses, "--out", str(out), "--vertices", "900", "--seed", "1"]) == 0
    from topomatch.datasets.topkids import load_topkids

    coll = load_topkids(out, "low")
    assert coll.names == ["kid00", "kid01", "kid02"]
    assert coll["kid00"].sym is not None and coll["kid01"].unreliable is not None
    # bad input: a pose with other connectivity and no vertex map
    other = tmp_path / "other.off"
    s = icosphere(2)
    write_off(other, s.vertices, s.faces)
    with pytest.raises(ValueError, match="connectivity"):
        noise_files(null, [other], tmp_path / "x")
    assert main(["noise", str(null), "--out", str(tmp_path / "y")]) == 2


def test_vertex_map_input(small_figure, tmp_path, rng):
    """A pose given in its own vertex order, with a map from the null shape."""
    from topomatch.io import write_off, write_p2p

    fig = small_figure
    null = tmp_path / "null.off"
    write_off(null, fig.mesh.vertices, fig.mesh.faces)
    perm = rng.permutation(fig.mesh.n_vertices)  # pose vertex i is template vertex perm[i]
    inv = np.argsort(perm)
    posed = fig.pose("hands_clasped")
    pose = tmp_path / "pose.off"
    write_off(pose, posed[perm], inv[fig.mesh.faces])
    vmap = tmp_path / "map.txt"
    write_p2p(vmap, inv)  # null vertex j -> pose vertex inv[j]
    p = NoiseParams(n_vertices=800)
    a = noise_files(null, [pose], tmp_path / "a", p, vertex_maps=[vmap])
    pose2 = tmp_path / "pose2.off"
    write_off(pose2, posed, fig.mesh.faces)
    b = noise_files(null, [pose2], tmp_path / "b", p)
    assert np.array_equal(a["kid01"].mesh.faces, b["kid01"].mesh.faces)
    assert np.array_equal(a["kid01"].ref_p2p, b["kid01"].ref_p2p)


# ---- the figure and the built-in benchmark ---------------------------------------------------------------
def test_figure_is_symmetric_and_poses_keep_connectivity(small_figure):
    fig = small_figure
    m = fig.mesh
    assert m.genus == 0 and m.is_manifold and len(m.boundary_loops) == 0
    assert np.allclose(fig.weights.sum(1), 1)
    assert (fig.sym >= 0).mean() > 0.99
    refl = m.vertices[fig.sym] * [-1, 1, 1]
    edge = np.median(np.linalg.norm(m.vertices[m.faces[:, 0]] - m.vertices[m.faces[:, 1]], axis=1))
    assert np.median(np.linalg.norm(refl - m.vertices, axis=1)) < edge
    for name in POSES:
        v = fig.pose(name)
        assert v.shape == m.vertices.shape and np.all(np.isfinite(v))
    # skinning keeps the limbs' lengths: edge lengths change little
    e = m.edges
    rest = np.linalg.norm(m.vertices[e[:, 0]] - m.vertices[e[:, 1]], axis=1)
    posed = fig.pose("arms_crossed")
    new = np.linalg.norm(posed[e[:, 0]] - posed[e[:, 1]], axis=1)
    assert np.median(np.abs(new / rest - 1)) < 0.05
    with pytest.raises(ValueError, match="unknown pose"):
        fig.pose("cartwheel")


def test_builtin_benchmark(builtin):
    coll = builtin
    assert coll.reference == "syn00"
    assert coll.splits["train"] == [f"syn{i:02d}" for i in range(1, 7)]
    assert coll.splits["test"] == [f"syn{i:02d}" for i in range(7, 11)]
    n_ref = coll["syn00"].n_vertices
    assert 4500 <= n_ref <= 5000
    genus = []
    for name in coll.splits["all"]:
        s = coll[name]
        m = s.mesh
        assert m.n_components == 1 and m.is_manifold and len(m.boundary_loops) == 0
        assert 3500 < m.n_vertices < 5500
        assert s.ref.shape[1] == n_ref and np.all(np.diff(s.ref.indptr) == 1)
        frac = float((m.vertex_areas * s.unreliable).sum() / m.area)
        assert frac < 0.15
        genus.append(m.genus)
    assert max(genus) >= 2  # fused touching parts make handles
    assert sum(g > 0 for g in genus) >= 5


def test_builtin_benchmark_is_cached(small_collection, tmp_path, monkeypatch):
    """With a cache entry present, nothing is generated and the shapes come back intact."""
    from topomatch import _cache
    from topomatch.datasets import builtin as b

    shapes = {"syn00": small_collection["ref"], "syn01": small_collection["a"], "syn02": small_collection["b"]}
    monkeypatch.setattr(_cache, "_CACHE_DIR", tmp_path)
    monkeypatch.setattr(b, "_MEMO", {})
    key = _cache.array_hash(np.array([600, 1]), extra=b.GENERATOR_VERSION + b._source_digest())
    _cache.save("builtin", key, b._pack(shapes))

    def boom(n, r, j=1):
        raise AssertionError("generated although cached")

    monkeypatch.setattr(b, "_generate", boom)
    coll = b.builtin_benchmark(600, random_state=1)
    for name, s in shapes.items():
        t = coll[name]
        assert np.array_equal(s.mesh.faces, t.mesh.faces) and np.array_equal(s.ref_p2p, t.ref_p2p)
        assert np.array_equal(s.sym, t.sym)
    assert coll is b.builtin_benchmark(600, random_state=1)  # memoised


def test_builtin_benchmark_bad_arguments():
    from topomatch.datasets.builtin import builtin_benchmark

    with pytest.raises(ValueError, match="n_vertices"):
        builtin_benchmark(10)
    with pytest.raises(TypeError, match="random_state"):
        builtin_benchmark(random_state="a")


def test_collection_does_not_depend_on_n_jobs(small_figure):
    fig = small_figure
    poses = {"p": fig.pose("knees_together"), "q": fig.pose("free")}
    params = NoiseParams(n_vertices=700, shortcuts=1)
    a = noisy_collection(fig.mesh.vertices, fig.mesh.faces, poses, params, null_vertices=700, random_state=11, n_jobs=1)
    b = noisy_collection(fig.mesh.vertices, fig.mesh.faces, poses, params, null_vertices=700, random_state=11, n_jobs=2)
    for name in ("p", "q"):
        assert np.array_equal(a[name].mesh.vertices, b[name].mesh.vertices)
        assert np.array_equal(a[name].ref_p2p, b[name].ref_p2p)


def test_cli_writes_the_builtin_benchmark(builtin, tmp_path, monkeypatch):
    from topomatch import _cache
    from topomatch.cli.main import main
    from topomatch.datasets.topkids import load_topkids

    monkeypatch.setattr(_cache, "_CACHE_DIR", tmp_path / "cache")  # keep the user's cache out of it
    assert main(["noise", "--builtin", "--out", str(tmp_path / "b")]) == 0
    coll = load_topkids(tmp_path / "b", "low")
    assert coll.names == [f"kid{i:02d}" for i in range(11)]
    assert np.array_equal(coll["kid07"].mesh.faces, builtin["syn07"].mesh.faces)
    assert np.array_equal(coll["kid07"].unreliable, builtin["syn07"].unreliable)


@pytest.mark.data
def test_kids_pose_ground_truth_matches_known_correspondence(tmp_path):
    """A clean KIDS pose (same connectivity as the null shape): transferred ground truth vs the truth."""
    null_path = data_path("kids", "0001.null.0.off")
    pose_path = data_path("kids", "0001.isometry.15.off")
    coll = noise_files(null_path, [pose_path], tmp_path, NoiseParams(n_vertices=3000))
    null = TriangleMesh.from_file(null_path)
    pose = TriangleMesh.from_file(pose_path)
    kid00, s = coll["kid00"], coll["kid01"]
    assert len(kid00.mesh.boundary_loops) == 3 and kid00.sym is not None
    assert s.mesh.n_components == 1 and s.mesh.is_manifold and s.mesh.genus > 0
    frac = float((s.mesh.vertex_areas * s.unreliable).sum() / s.mesh.area)
    assert 0.005 < frac < 0.15  # hands on the face, crossed legs: fused seams
    face, bary, _ = SurfaceLocator(null.vertices, null.faces).query(kid00.mesh.vertices)
    carried = np.einsum("ij,ijk->ik", bary, pose.vertices[null.faces[face]])
    err = np.linalg.norm(carried[s.ref_p2p] - s.mesh.vertices, axis=1)
    edge = np.median(np.linalg.norm(kid00.mesh.vertices[kid00.mesh.edges[:, 0]] - kid00.mesh.vertices[kid00.mesh.edges[:, 1]], axis=1))
    rel = ~s.unreliable
    assert np.median(err[rel]) < 0.5 * edge and np.percentile(err[rel], 95) < 0.9 * edge
