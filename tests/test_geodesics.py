import numpy as np
import pytest

from topomatch.datasets.toy import grid, icosphere
from topomatch.mesh import TriangleMesh, make_geodesic_solver
from topomatch.mesh.geodesics import clean_for_exact
from topomatch.mesh.intrinsic import intrinsic_delaunay, intrinsic_gradient_operator

from .conftest import data_path


def great_circle(v, i):
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    return np.arccos(np.clip(u @ u[i], -1, 1))


@pytest.fixture(scope="module")
def sphere4():
    return icosphere(4)


def test_flat_grid_is_euclidean():
    m = grid(21)
    src = np.array([0, 220, 440])
    truth = np.linalg.norm(m.vertices[None, :, :] - m.vertices[src][:, None, :], axis=2)
    exact = make_geodesic_solver(m.vertices, m.faces, "exact").distances_from(src)
    np.testing.assert_allclose(exact, truth, atol=1e-9)
    heat = make_geodesic_solver(m.vertices, m.faces, "heat").distances_from(src)
    far = truth > 0.2
    rel = np.abs(heat[far] - truth[far]) / truth[far]
    assert rel.mean() < 0.03 and rel.max() < 0.1  # Neumann boundaries bend heat-method distances
    dij = make_geodesic_solver(m.vertices, m.faces, "dijkstra").distances_from(src)
    assert np.all(dij >= truth - 1e-12)


def test_sphere_against_great_circles(sphere4):
    src = np.array([0, 100, 2000])
    truth = np.stack([great_circle(sphere4.vertices, i) for i in src])
    far = truth > 0.3
    for kind, tol in (("exact", 0.01), ("heat", 0.03)):
        d = make_geodesic_solver(sphere4.vertices, sphere4.faces, kind).distances_from(src)
        assert np.mean(np.abs(d[far] - truth[far]) / truth[far]) < tol, kind
        np.testing.assert_allclose(d[np.arange(3), src], 0.0, atol=1e-12)


def test_pair_distances_match_rows(sphere4, rng):
    solver = sphere4.geodesic_solver("heat")
    a = rng.integers(0, sphere4.n_vertices, 300)
    b = rng.integers(0, sphere4.n_vertices, 300)
    rows = solver.distances_from(np.unique(a))
    lookup = {s: i for i, s in enumerate(np.unique(a))}
    expected = rows[[lookup[x] for x in a], b]
    np.testing.assert_allclose(solver.pair_distances(a, b), expected)
    ex = sphere4.geodesic_solver("exact")
    full = ex.distances_from(a[:5])
    np.testing.assert_allclose(ex.pair_distances(a[:5], b[:5]), full[np.arange(5), b[:5]], atol=1e-9)


def test_components_are_unreachable():
    s = icosphere(2)
    v = np.vstack([s.vertices, s.vertices + 10])
    f = np.vstack([s.faces, s.faces + s.n_vertices])
    for kind in ("heat", "dijkstra"):
        d = make_geodesic_solver(v, f, kind).distances_from(np.array([0]))[0]
        assert np.all(np.isinf(d[s.n_vertices :])) and np.all(np.isfinite(d[: s.n_vertices]))


def test_exact_cleaning_of_fins():
    s = icosphere(1)
    v = np.vstack([s.vertices, s.vertices[s.faces[0]].mean(0, keepdims=True) * 1.3])
    apex = len(v) - 1
    a, b, _ = s.faces[0]
    fin = np.array([[a, b, apex], [b, a, apex]])  # zero-thickness flap on edge (a, b)
    f = np.vstack([s.faces, fin])
    f_clean, note = clean_for_exact(v, f)
    assert len(f_clean) == len(s.faces) and "fin" in note
    solver = make_geodesic_solver(v, f, "exact")
    d = solver.distances_from(np.array([apex, 0]))
    assert d[0, apex] == 0 and np.all(np.isfinite(d))
    # the lone apex stands in for its nearest vertex plus the gap
    gap = np.min(np.linalg.norm(s.vertices - v[apex], axis=1))
    assert d[0].min(initial=np.inf, where=np.arange(len(v)) != apex) >= gap - 1e-12
    # heat handles the non-manifold mesh directly
    h = make_geodesic_solver(v, f, "heat").distances_from(np.array([0]))
    assert np.all(np.isfinite(h))


def test_exact_refuses_true_non_manifold():
    s = icosphere(1)
    v = np.vstack([s.vertices, [[0.0, 0.0, 3.0]]])
    a, b, _ = s.faces[0]
    f = np.vstack([s.faces, [[a, b, len(v) - 1]]])
    with pytest.raises(ValueError, match="non-manifold"):
        make_geodesic_solver(v, f, "exact")


def test_intrinsic_delaunay_weights_are_nonnegative(rng):
    m = icosphere(3)
    v = m.vertices * (1 + 0.3 * rng.random((m.n_vertices, 1)))  # bumpy: many non-Delaunay edges
    f_id, lengths, n_flips = intrinsic_delaunay(v, m.faces)
    assert n_flips > 0
    G, area = intrinsic_gradient_operator(f_id, lengths, len(v))
    from scipy import sparse

    L = G.T @ sparse.diags(np.repeat(area, 2)) @ G
    off = L - sparse.diags(L.diagonal())
    assert off.max() <= 1e-9  # off-diagonal = -cot weights <= 0
    # the metric is unchanged: total area is preserved
    assert area.sum() == pytest.approx(TriangleMesh(v, m.faces).area, rel=1e-9)


def test_bad_kind():
    m = icosphere(1)
    with pytest.raises(ValueError, match="unknown geodesic kind"):
        make_geodesic_solver(m.vertices, m.faces, "fmm")


@pytest.mark.data
def test_heat_accuracy_on_kid00(topkids_low):
    mesh = topkids_low["kid00"].mesh
    src = np.random.default_rng(1).choice(mesh.n_vertices, 4, replace=False)
    exact = mesh.geodesic_solver("exact").distances_from(src)
    heat = mesh.geodesic_solver("heat").distances_from(src)
    ok = exact > 0.05 * exact.max()
    rel = np.abs(heat[ok] - exact[ok]) / exact[ok]
    assert rel.mean() < 0.03
    assert np.mean(heat[ok] - exact[ok]) / np.mean(exact[ok]) < 0.02
    data_path("topkids", "low_res")
