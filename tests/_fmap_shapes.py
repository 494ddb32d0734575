"""Small test shapes for the functional map tests, built in code."""

from __future__ import annotations

import numpy as np

from topomatch.datasets.toy import icosphere
from topomatch.mesh import TriangleMesh


def bumpy(subdivisions: int = 3, mirror_symmetric: bool = True) -> TriangleMesh:
    """An ellipsoid with bumps: mirror-symmetric in x, no other symmetry."""
    s = icosphere(subdivisions)
    v = np.array(s.vertices) * np.array([1.0, 0.8, 0.6])
    bumps = [((0.6, 0.5, 0.3), 0.35), ((-0.6, 0.5, 0.3), 0.35), ((0.0, -0.7, 0.2), 0.5), ((0.0, 0.3, -0.5), 0.25)]
    if not mirror_symmetric:
        bumps.append(((0.7, -0.3, -0.2), 0.3))
    r = np.ones(len(v))
    for c, h in bumps:
        r += h * np.exp(-np.sum((v - np.array(c)) ** 2, axis=1) / 0.08)
    return TriangleMesh(v * r[:, None], s.faces, name="bumpy")


def shuffled(mesh: TriangleMesh, seed: int = 0) -> tuple[TriangleMesh, np.ndarray]:
    """A copy with vertices in random order; ``perm[j]`` is the original of new vertex j."""
    perm = np.random.default_rng(seed).permutation(mesh.n_vertices)
    inv = np.argsort(perm)
    return TriangleMesh(mesh.vertices[perm], inv[mesh.faces], name="shuffled"), perm


def mirrored(mesh: TriangleMesh) -> TriangleMesh:
    """Reflection x -> -x with faces flipped so normals still point outwards."""
    v = np.array(mesh.vertices) * np.array([-1.0, 1.0, 1.0])
    return TriangleMesh(v, mesh.faces[:, ::-1], name="mirrored")
