"""Tiny meshes built in code, for tests, docs and examples."""

from __future__ import annotations

import numpy as np

from topomatch.mesh import TriangleMesh

__all__ = ["grid", "icosphere", "torus"]


def icosphere(subdivisions: int = 2, radius: float = 1.0) -> TriangleMesh:
    """Unit icosphere: 12 vertices subdivided ``subdivisions`` times (642 at 3).

    Returns
    -------
    TriangleMesh
    """
    t = (1.0 + 5**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        inv = inv.ravel()
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = len(v) + inv.reshape(3, -1).T  # midpoints of edges (01, 12, 20) per face
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        ab, bc, ca = m[:, 0], m[:, 1], m[:, 2]
        f = np.concatenate([np.c_[a, ab, ca], np.c_[b, bc, ab], np.c_[c, ca, bc], np.c_[ab, bc, ca]])
        v = np.concatenate([v, mid])
    return TriangleMesh(v * radius, f, name=f"icosphere{subdivisions}")


def torus(n_major: int = 32, n_minor: int = 16, major: float = 1.0, minor: float = 0.35) -> TriangleMesh:
    """Torus of genus 1 with ``n_major * n_minor`` vertices."""
    u, w = np.meshgrid(np.arange(n_major) * 2 * np.pi / n_major, np.arange(n_minor) * 2 * np.pi / n_minor, indexing="ij")
    x = (major + minor * np.cos(w)) * np.cos(u)
    y = (major + minor * np.cos(w)) * np.sin(u)
    z = minor * np.sin(w)
    v = np.c_[x.ravel(), y.ravel(), z.ravel()]
    idx = np.arange(n_major * n_minor).reshape(n_major, n_minor)
    i0 = idx
    i1 = np.roll(idx, -1, axis=0)
    i2 = np.roll(idx, -1, axis=1)
    i3 = np.roll(np.roll(idx, -1, axis=0), -1, axis=1)
    f = np.concatenate([np.c_[i0.ravel(), i1.ravel(), i3.ravel()], np.c_[i0.ravel(), i3.ravel(), i2.ravel()]])
    return TriangleMesh(v, f, name="torus")


def grid(n: int = 11, size: float = 1.0) -> TriangleMesh:
    """Flat ``n x n`` square grid in the z = 0 plane (a disc with one boundary loop)."""
    x, y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n), indexing="xy")
    v = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    idx = np.arange(n * n).reshape(n, n)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    f = np.concatenate([np.c_[a, b, d], np.c_[a, d, c]])
    return TriangleMesh(v, f, name=f"grid{n}")
