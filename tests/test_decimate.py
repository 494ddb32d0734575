"""Working copies of large meshes: decimation and barycentric transfer."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from topomatch.datasets._surface import SurfaceLocator, vertex_faces
from topomatch.datasets.toy import icosphere
from topomatch.mesh.decimate import decimate, surface_weights


def test_decimate_keeps_the_surface():
    mesh = icosphere(5)  # 10,242 vertices on the unit sphere
    small = decimate(mesh, 2000)
    assert abs(small.n_vertices - 2000) < 100 and small.name == f"icosphere5@{small.n_vertices}"
    assert small.genus == 0
    # every vertex of the copy near the sphere, every vertex of the sphere near the copy
    assert np.abs(np.linalg.norm(small.vertices, axis=1) - 1).max() < 0.01
    assert cKDTree(small.vertices).query(mesh.vertices)[0].max() < 0.1
    assert decimate(small, 5000) is small  # already small enough
    for n in (99, 1500.0, True):
        with pytest.raises(ValueError, match="n_vertices"):
            decimate(mesh, n)  # type: ignore[arg-type]


def test_vertex_faces():
    faces = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4]])
    ptr, ring = vertex_faces(faces, 6)
    rings = [sorted(ring[ptr[i] : ptr[i + 1]].tolist()) for i in range(6)]
    assert rings == [[0, 1], [0], [0, 1, 2], [1, 2], [2], []]


def test_closest_point_on_a_triangle_matches_brute_force():
    rng = np.random.default_rng(0)
    V = rng.normal(size=(3, 3))
    F = np.array([[0, 1, 2]])
    P = 2 * rng.normal(size=(5000, 3))
    face, bary, _ = SurfaceLocator(V, F).query(P)  # what surface_weights builds on
    assert np.all(face == 0) and np.all(bary >= -1e-12)
    np.testing.assert_allclose(bary.sum(axis=1), 1.0, atol=1e-12)
    d = np.linalg.norm(bary @ V - P, axis=1)
    u = np.linspace(0, 1, 301)
    a, b = np.meshgrid(u, u)
    keep = a + b <= 1
    grid = V[0] + a[keep][:, None] * (V[1] - V[0]) + b[keep][:, None] * (V[2] - V[0])
    brute = cKDTree(grid).query(P)[0]
    assert np.all(d <= brute + 1e-12) and np.max(brute - d) < 0.01


def test_surface_weights_interpolate_from_the_copy():
    mesh = icosphere(4)
    small = decimate(mesh, 800)
    W = surface_weights(mesh.vertices, small)
    assert W.shape == (mesh.n_vertices, small.n_vertices) and np.diff(W.indptr).max() <= 3
    np.testing.assert_allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    X = W @ small.vertices  # the closest points on the copy
    assert np.linalg.norm(X - mesh.vertices, axis=1).max() < 0.02
    # a linear field is carried exactly; the copy's own vertices get their own values
    A, b = np.array([[1.0, 2.0, 0.5], [0.0, -1.0, 3.0], [2.0, 0.0, 1.0]]), np.array([0.3, -0.2, 1.0])
    np.testing.assert_allclose(W @ (small.vertices @ A.T + b), X @ A.T + b, atol=1e-12)
    np.testing.assert_allclose(surface_weights(small.vertices, small) @ small.vertices, small.vertices, atol=1e-12)
    with pytest.raises(ValueError, match="finite"):
        surface_weights(np.full((2, 3), np.nan), small)
