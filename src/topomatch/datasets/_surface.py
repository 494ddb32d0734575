"""Surface helpers of the noise generator: closest points, hole caps, decimation, clean-up."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from topomatch.datasets._noise_kernels import closest_points, decimate_heap
from topomatch.mesh.geometry import connected_components, face_areas
from topomatch.typing import BoolArray, FloatArray, IndexArray

__all__ = ["HoleCaps", "SurfaceLocator", "decimate", "keep_largest_component", "relax_onto", "vertex_faces"]


def vertex_faces(faces: IndexArray, n_vertices: int) -> tuple[IndexArray, IndexArray]:
    """Faces around each vertex as CSR arrays ``(ptr (n_vertices + 1,), idx (3 n_faces,))``."""
    m = sparse.csr_matrix(
        (np.ones(faces.size, dtype=np.int8), (faces.ravel(), np.repeat(np.arange(len(faces)), 3))),
        shape=(n_vertices, len(faces)),
    )
    m.sort_indices()
    return m.indptr.astype(np.int64), m.indices.astype(np.int64)


class SurfaceLocator:
    """Closest points on a triangle mesh (face, barycentric weights, distance).

    Candidate faces are those around the ``k`` nearest vertices of each query, which
    finds the exact closest face on meshes whose triangles are not much larger than
    their neighbours' spacing (always true of the meshes the generator makes).
    """

    def __init__(self, vertices: FloatArray, faces: IndexArray, k: int = 8) -> None:
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.k = min(k, len(self.vertices))
        self._tree = cKDTree(self.vertices)
        self._ptr, self._idx = vertex_faces(self.faces, len(self.vertices))

    def query(self, points: FloatArray) -> tuple[IndexArray, FloatArray, FloatArray]:
        """Closest surface point of each query.

        Parameters
        ----------
        points : ndarray, shape (n, 3)

        Returns
        -------
        face : ndarray, shape (n,)
        bary : ndarray, shape (n, 3)
            Weights of the face's corners.
        distance : ndarray, shape (n,)
        """
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        n = len(p)
        face = np.empty(n, dtype=np.int64)
        bary = np.empty((n, 3))
        d2 = np.empty(n)
        feat = np.empty(n, dtype=np.int8)
        if n == 0:
            return face, bary, d2
        _, knn = self._tree.query(p, k=self.k)
        knn = np.ascontiguousarray(np.asarray(knn, dtype=np.int64).reshape(n, -1))
        closest_points(p, self.vertices, self.faces, knn, self._ptr, self._idx, face, bary, d2, feat)
        return face, bary, np.sqrt(d2)

    def points(self, face: IndexArray, bary: FloatArray, vertices: FloatArray | None = None) -> FloatArray:
        """Positions of surface points ``(face, bary)`` on ``vertices`` (default: this mesh's)."""
        v = self.vertices if vertices is None else vertices
        return np.einsum("ij,ijk->ik", bary, v[self.faces[face]])


@dataclass(frozen=True)
class HoleCaps:
    """Fans closing the boundary loops of a mesh, one new vertex per loop.

    The new vertices are appended after the mesh's own: cap vertex ``i`` is the mean
    of loop ``i``'s vertices in whatever pose :meth:`extend` is given.
    """

    loops: tuple[IndexArray, ...]
    faces: IndexArray  # (n_cap_faces, 3), indices into the extended vertex array
    n_vertices: int  # vertices of the mesh before capping

    @classmethod
    def build(cls, faces: IndexArray, n_vertices: int) -> HoleCaps:
        """Caps for every boundary loop of ``faces``."""
        be = _boundary_edges(faces)
        loops = _chain_loops(be)
        if not loops:
            return cls((), np.zeros((0, 3), dtype=np.int64), n_vertices)
        loop_of = {}
        for i, loop in enumerate(loops):
            for v in loop:
                loop_of.setdefault(int(v), i)
        centre = np.array([n_vertices + loop_of[int(a)] for a in be[:, 0]], dtype=np.int64)
        return cls(loops, np.c_[be[:, 1], be[:, 0], centre].astype(np.int64), n_vertices)

    @property
    def n_caps(self) -> int:
        """Number of capped loops."""
        return len(self.loops)

    def extend(self, vertices: FloatArray) -> FloatArray:
        """``vertices`` followed by the cap centres, shape (n_vertices + n_caps, 3)."""
        if not self.loops:
            return np.asarray(vertices, dtype=np.float64)
        centres = np.array([vertices[loop].mean(axis=0) for loop in self.loops])
        return np.concatenate([vertices, centres])


def _boundary_edges(faces: IndexArray) -> IndexArray:
    """Edges in exactly one face, oriented as in it, shape (n, 2) (integer keys: fast)."""
    d = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    n = int(d.max()) + 1 if d.size else 0
    key = np.minimum(d[:, 0], d[:, 1]) * n + np.maximum(d[:, 0], d[:, 1])
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    return d[counts[inv] == 1]


def _chain_loops(be: IndexArray) -> tuple[IndexArray, ...]:
    """Chain oriented boundary edges into loops (at a pinch, the first outgoing edge)."""
    nxt: dict[int, list[int]] = {}
    for k, a in enumerate(be[:, 0].tolist()):
        nxt.setdefault(a, []).append(k)
    used = np.zeros(len(be), dtype=bool)
    loops = []
    for start in range(len(be)):
        if used[start]:
            continue
        loop = []
        k = start
        while not used[k]:
            used[k] = True
            loop.append(int(be[k, 0]))
            cand = [j for j in nxt.get(int(be[k, 1]), []) if not used[j]]
            if not cand:
                break
            k = cand[0]
        loops.append(np.asarray(loop, dtype=np.int64))
    return tuple(loops)


def keep_largest_component(vertices: FloatArray, faces: IndexArray) -> tuple[FloatArray, IndexArray]:
    """The face-connected component with the largest area, unreferenced vertices dropped."""
    n_comp, labels = connected_components(len(vertices), faces)
    if n_comp > 1:
        areas = np.bincount(labels[faces[:, 0]], weights=face_areas(vertices, faces), minlength=n_comp)
        faces = faces[labels[faces[:, 0]] == int(np.argmax(areas))]
    return compact(vertices, faces)


def compact(vertices: FloatArray, faces: IndexArray) -> tuple[FloatArray, IndexArray]:
    """Drop vertices in no face and renumber."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    new = np.cumsum(used) - 1
    return vertices[used], new[faces].astype(np.int64)


def decimate(
    vertices: FloatArray, faces: IndexArray, n_vertices: int, *, edge_weight: float = 0.02, min_quality: float = 0.1
) -> tuple[FloatArray, IndexArray]:
    """Quadric edge-collapse decimation to ``n_vertices`` vertices, topology preserved.

    Collapses keep the surface manifold and its genus, boundary loops and components
    unchanged (link condition), never fold a face, and favour short edges so that the
    triangles come out even. Returns the input unchanged when it already has no more
    vertices than asked; may stop above the target when no further collapse is valid.

    Returns
    -------
    vertices : ndarray, shape (n, 3)
    faces : ndarray, shape (m, 3)
    """
    if len(vertices) <= n_vertices:
        return vertices, faces
    v, f, alive, n_left = decimate_heap(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        int(n_vertices),
        float(edge_weight),
        float(min_quality),
        24,
    )
    if n_left < 0:
        raise ValueError("decimate: a vertex has more than 32 faces; the input is not a reasonable mesh")
    return compact(v, f[alive])


def relax_onto(vertices: FloatArray, faces: IndexArray, surface: SurfaceLocator, iterations: int = 3, step: float = 0.5) -> FloatArray:
    """Tangential smoothing that evens out triangle sizes, each step projected back onto ``surface``.

    Every vertex moves ``step`` of the way to the area-weighted centroid of its
    neighbouring faces, along the tangent plane only, then snaps to the closest point
    of ``surface`` (the fine iso-surface), so the shape does not shrink.
    """
    v = np.array(vertices, dtype=np.float64)
    n = len(v)
    for _ in range(iterations):
        tri = v[faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area = 0.5 * np.linalg.norm(fn, axis=1)
        cen = tri.mean(axis=1)
        idx = faces.ravel()
        wsum = np.bincount(idx, weights=np.repeat(area, 3), minlength=n)
        target = np.stack([np.bincount(idx, weights=np.repeat(cen[:, d] * area, 3), minlength=n) for d in range(3)], axis=1)
        target /= np.maximum(wsum, 1e-300)[:, None]
        nrm = np.stack([np.bincount(idx, weights=np.repeat(fn[:, d], 3), minlength=n) for d in range(3)], axis=1)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        d = target - v
        d -= np.einsum("ij,ij->i", d, nrm)[:, None] * nrm
        moved = v + step * d
        face, bary, _ = surface.query(moved)
        v = surface.points(face, bary)
    return v


def mirror_symmetry(vertices: FloatArray, axis: int, *, tolerance: float) -> IndexArray:
    """Left-right map of a mirror-symmetric shape: nearest vertex to each reflected vertex.

    The mirror plane is ``x_axis = mean``; vertices whose reflection lies farther than
    ``tolerance`` from every vertex get ``-1``.

    Returns
    -------
    ndarray, shape (n_vertices,)
    """
    v = np.asarray(vertices, dtype=np.float64)
    m = v.copy()
    mid = 0.5 * (v[:, axis].min() + v[:, axis].max())
    m[:, axis] = 2 * mid - m[:, axis]
    d, j = cKDTree(v).query(m)
    return np.where(d <= tolerance, j, -1).astype(np.int64)


def mask_faces(faces: IndexArray, keep: BoolArray) -> IndexArray:
    """Faces whose three vertices are all in ``keep``."""
    return faces[keep[faces].all(axis=1)]
