import numpy as np
import pytest

from topomatch.datasets.toy import grid, icosphere, torus
from topomatch.mesh import TriangleMesh
from topomatch.mesh import geometry as g
from topomatch.mesh.sampling import farthest_point_sampling


def test_single_triangle_geometry():
    m = TriangleMesh([[0, 0, 0], [2, 0, 0], [0, 3, 0]], [[0, 1, 2]])
    assert m.area == pytest.approx(3.0)
    np.testing.assert_allclose(m.vertex_areas, [1, 1, 1])
    np.testing.assert_allclose(m.face_normals, [[0, 0, 1]])
    assert len(m.boundary_loops) == 1 and sorted(m.boundary_loops[0]) == [0, 1, 2]
    assert m.euler_characteristic == 1 and m.genus == 0


@pytest.mark.parametrize(("mesh", "genus", "loops", "chi"), [(icosphere(2), 0, 0, 2), (torus(20, 10), 1, 0, 0), (grid(6), 0, 1, 1)])
def test_topology(mesh, genus, loops, chi):
    assert mesh.genus == genus
    assert len(mesh.boundary_loops) == loops
    assert mesh.euler_characteristic == chi
    assert mesh.n_components == 1
    assert mesh.is_manifold


def test_sphere_area_and_normals():
    m = icosphere(4)
    assert m.area == pytest.approx(4 * np.pi, rel=2e-3)
    np.testing.assert_allclose(np.einsum("ij,ij->i", m.vertex_normals, m.vertices), 1.0, atol=1e-3)


def test_arrays_are_read_only_and_copied():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    m = TriangleMesh(v, [[0, 1, 2]])
    v[0, 0] = 5.0
    assert m.vertices[0, 0] == 0.0
    with pytest.raises(ValueError):
        m.vertices[0, 0] = 1.0


@pytest.mark.parametrize(
    ("v", "f", "match"),
    [
        ([[0, 0], [1, 1]], [[0, 1, 1]], r"shape \(n_vertices, 3\)"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], "index out of range"),
        ([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 1, 2]], "non-finite"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1]], r"shape \(n_faces, 3\)"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.zeros((0, 3), int), "at least one face"),
    ],
)
def test_bad_input(v, f, match):
    with pytest.raises(ValueError, match=match):
        TriangleMesh(v, f)


def test_non_manifold_duplicate_and_components():
    s = icosphere(1)
    # a fin: the same triangle twice with opposite orientations, plus a second component
    f0 = s.faces[0]
    extra_v = s.vertices[:3] + 5.0
    v = np.vstack([s.vertices, extra_v, [[9.0, 9.0, 9.0]]])
    n = len(s.vertices)
    f = np.vstack([s.faces, f0[::-1], [[n, n + 1, n + 2]]])
    m = TriangleMesh(v, f)
    assert len(m.duplicate_faces) == 1
    assert len(m.non_manifold_edges) == 3
    assert m.n_components == 2
    assert list(m.unreferenced_vertices) == [n + 3]
    np.testing.assert_array_equal(np.unique(m.component_labels), [-1, 0, 1])
    info = m.summary()
    assert info["duplicate_faces"] == 1 and info["unreferenced_vertices"] == 1


@pytest.mark.parametrize("dtype", [np.int64, np.int32])
def test_edges_with_counts_equals_the_row_unique_formula(dtype):
    """The 1-D keyed unique gives what ``np.unique(..., axis=0)`` gives, on a boundary, a
    non-manifold fin and a degenerate face, for 32-bit faces too."""
    s = grid(6, 5)
    f = np.vstack([s.faces, s.faces[:1][:, ::-1], [[3, 3, 7]]]).astype(dtype)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    want, want_counts = np.unique(e, axis=0, return_counts=True)
    edges, counts = g.edges_with_counts(f)
    np.testing.assert_array_equal(edges, want)
    np.testing.assert_array_equal(counts, want_counts)
    assert edges.dtype == np.int64 and counts.dtype == np.int64
    assert set(np.unique(counts)) == {1, 2, 3}  # boundary, interior, the fin
    empty, none = g.edges_with_counts(np.zeros((0, 3), dtype=dtype))
    assert empty.shape == (0, 2) and none.shape == (0,)


def test_boundary_loops_of_annulus():
    m = grid(7)
    v, f = np.array(m.vertices), np.array(m.faces)
    centre = np.linalg.norm(v[f].mean(axis=1) - [0.5, 0.5, 0], axis=1) < 0.2
    a = TriangleMesh(v, f[~centre])
    loops = a.boundary_loops
    assert len(loops) == 2
    assert a.genus == 0 and a.euler_characteristic == 0
    # each boundary edge appears in exactly one loop
    be = g.boundary_edges(a.faces)
    assert sum(len(lp) for lp in loops) == len(be)


def test_mesh_pickles_after_building_a_geodesic_solver(sphere):
    import pickle

    mesh = type(sphere)(sphere.vertices, sphere.faces, name="s")
    d0 = mesh.geodesic_solver("heat").distances_from([0])
    clone = pickle.loads(pickle.dumps(mesh))
    assert clone.name == "s" and np.array_equal(clone.faces, mesh.faces)
    assert np.allclose(clone.geodesic_solver("heat").distances_from([0]), d0)


def test_vertex_normals_kernel_has_the_numpy_formula_s_bits():
    rng = np.random.default_rng(0)
    for mesh in (icosphere(3), torus(), grid(7, 5)):
        V = mesh.vertices + 0.05 * rng.standard_normal(mesh.vertices.shape)
        np.testing.assert_array_equal(g.vertex_normals(V, mesh.faces), g._vertex_normals_numpy(V, mesh.faces))
    # an isolated vertex and a degenerate face get zero normals
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [2, 0, 0]])
    F = np.array([[0, 1, 2], [0, 1, 4]])
    n = g.vertex_normals(V, F)
    np.testing.assert_array_equal(n, g._vertex_normals_numpy(V, F))
    np.testing.assert_array_equal(n[3], 0.0)
    with pytest.raises(ValueError, match="face indices"):
        g.vertex_normals(V, np.array([[0, 1, 5]]))
    with pytest.raises(ValueError, match="face indices"):
        g.vertex_normals(V, np.array([[0, -1, 2]]))
    with pytest.raises(ValueError, match="must be"):
        g.vertex_normals(V[:, :2], F)


def _fps_reference(n_samples: int, points: np.ndarray, first: int) -> np.ndarray:
    """Farthest-point sampling in plain numpy (the formula the compiled kernel must equal bit for bit)."""
    dmin = np.full(len(points), np.inf)
    out, cur = [], first
    for _ in range(n_samples):
        out.append(cur)
        dmin = np.minimum(dmin, np.sqrt(np.sum((points - points[cur]) ** 2, axis=1)))
        dmin[out] = -1.0
        cur = int(np.argmax(dmin))
    return np.array(out)


@pytest.mark.parametrize("dim", [3, 2, 7])
def test_farthest_point_sampling_equals_the_numpy_formula(dim):
    rng = np.random.default_rng(dim)
    X = rng.standard_normal((700, dim))
    lattice = rng.integers(0, 3, (300, dim)).astype(float)  # duplicates and distance ties: first index wins
    for pts, first in ((X, 0), (X, 411), (lattice, 5)):
        np.testing.assert_array_equal(farthest_point_sampling(250, points=pts, first=first), _fps_reference(250, pts, first))
    with pytest.raises(ValueError, match="first"):
        farthest_point_sampling(5, points=X, first=700)
    with pytest.raises(ValueError, match="finite"):
        farthest_point_sampling(5, points=np.r_[X, [[np.nan] * dim]], first=0)
