"""Geodesic distances on triangle meshes: solver objects, built once per mesh.

Three solvers share one interface (:class:`GeodesicSolver`):

``HeatGeodesicSolver``
    The heat method (Crane, Weischedel, Wardetzky 2013) on the mesh's own
    triangulation, batched over many sources with one Cholesky factorisation per
    system. Fast (all-pairs on a 10K-vertex mesh in seconds) and robust to non-manifold
    edges, boundaries and several components. Approximate: its error against exact
    geodesics is measured in ``benchmarks/bench_geodesics.py`` and stated in
    ``docs/protocols.md``.
``ExactGeodesicSolver``
    Exact polyhedral distances (MMP, Kirsanov's implementation via ``pygeodesic``).
    That code crashes the interpreter on non-manifold, duplicated or zero-area faces,
    so the solver runs on a cleaned copy (duplicate and zero-area faces removed) and
    refuses meshes that still have non-manifold edges. Slow: for validation and for
    the exact-geodesic figures.
``DijkstraGeodesicSolver``
    Shortest paths on the edge graph with Euclidean edge lengths: the distance used by
    the published TOPKIDS numbers (ULRSSM and successors). Overestimates surface
    distance by a few percent.

All distances are in the mesh's own units (not normalised).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Literal

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from topomatch._kernels import heat_divergence
from topomatch.mesh.geometry import (
    connected_components,
    edge_graph,
    edges_with_counts,
    face_areas,
)
from topomatch.mesh.intrinsic import intrinsic_delaunay, intrinsic_gradient_operator
from topomatch.mesh.spectral import SparseCholesky
from topomatch.typing import FloatArray, IndexArray

__all__ = [
    "DijkstraGeodesicSolver",
    "ExactGeodesicSolver",
    "GeodesicKind",
    "GeodesicSolver",
    "HeatGeodesicSolver",
    "make_geodesic_solver",
]

logger = logging.getLogger(__name__)

GeodesicKind = Literal["heat", "exact", "dijkstra"]


class GeodesicSolver:
    """Base class: ``distances_from(sources)`` plus grouped pairwise queries."""

    n_vertices: int
    kind: str = ""

    def distances_from(self, sources: IndexArray) -> FloatArray:
        """Distances from each source to every vertex.

        Parameters
        ----------
        sources : ndarray, shape (n_sources,)

        Returns
        -------
        ndarray, shape (n_sources, n_vertices)
            ``inf`` for vertices in another connected component.
        """
        raise NotImplementedError

    def batch_size(self) -> int:
        """How many sources one ``distances_from`` call should take (memory bound)."""
        return 256

    def iter_rows(self, sources: IndexArray) -> Iterator[tuple[IndexArray, FloatArray]]:
        """Yield ``(batch_sources, distances)`` over ``sources`` in memory-bounded batches."""
        sources = np.asarray(sources, dtype=np.int64)
        b = self.batch_size()
        for i in range(0, len(sources), b):
            s = sources[i : i + b]
            yield s, self.distances_from(s)

    def pair_distances(self, a: IndexArray, b: IndexArray) -> FloatArray:
        """Distance from ``a[i]`` to ``b[i]`` for every ``i``.

        The distance field is computed from the vertices in ``a`` (grouped, each once).

        Parameters
        ----------
        a, b : ndarray, shape (n_pairs,)

        Returns
        -------
        ndarray, shape (n_pairs,)
        """
        a = np.asarray(a, dtype=np.int64)
        b = np.asarray(b, dtype=np.int64)
        if a.shape != b.shape:
            raise ValueError(f"a and b must have the same shape, got {a.shape} and {b.shape}")
        out = np.empty(len(a))
        if len(a) == 0:
            return out
        uniq, inv = np.unique(a, return_inverse=True)
        order = np.argsort(inv, kind="stable")
        starts = np.searchsorted(inv[order], np.arange(len(uniq) + 1))
        for i0 in range(0, len(uniq), self.batch_size()):
            rows_src = uniq[i0 : i0 + self.batch_size()]
            d = self.distances_from(rows_src)
            sel = order[starts[i0] : starts[min(i0 + len(rows_src), len(uniq))]]
            out[sel] = d[inv[sel] - i0, b[sel]]
        return out


class HeatGeodesicSolver(GeodesicSolver):
    """Heat-method geodesic distances, batched over sources.

    Parameters
    ----------
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
    t_scale : float
        Diffusion time as a multiple of the squared mean edge length (1 as in the paper).

    References
    ----------
    K. Crane, C. Weischedel, M. Wardetzky, "Geodesics in Heat", ACM TOG 2013.
    """

    kind = "heat"

    def __init__(self, vertices: FloatArray, faces: IndexArray, *, t_scale: float = 1.0) -> None:
        V = np.asarray(vertices, dtype=np.float64)
        F = np.asarray(faces, dtype=np.int64)
        self.n_vertices = n = len(V)
        # Work on the intrinsic Delaunay triangulation of the same surface: its cotangent
        # matrix is an M-matrix, so the Cholesky solve of the heat step keeps the
        # exponentially small tail of u accurate, and gradients are well conditioned on
        # the very obtuse TOPKIDS triangles.
        F_id, lengths, self.n_flips = intrinsic_delaunay(V, F)
        G, area = intrinsic_gradient_operator(F_id, lengths, n)
        A = np.repeat(area, 2)
        GtA = (G.T @ sparse.diags(A)).tocsr()
        L = (GtA @ G).tocsc()
        # gradient as per-face corner coefficients (gathers are much faster than a
        # sparse product with many right-hand sides); divergence as two sparse matrices
        Gc = G.tocsr()
        coef = np.zeros((len(F_id), 3, 2))
        for d in range(2):
            rows = Gc[d::2]
            for k in range(3):
                coef[:, k, d] = np.asarray(rows[np.arange(len(F_id)), F_id[:, k]]).ravel()
        # a repeated vertex in a face would sum its coefficients in G: keep G's values once
        dup = (F_id[:, 0] == F_id[:, 1]) | (F_id[:, 1] == F_id[:, 2]) | (F_id[:, 0] == F_id[:, 2])
        coef[dup] = 0.0
        self._faces_id = np.ascontiguousarray(F_id)
        self._coef = np.ascontiguousarray(coef)
        self._area = np.where(dup, 0.0, area)
        mass = np.zeros(n)
        for k in range(3):
            np.add.at(mass, F_id[:, k], area / 3.0)
        edges, _ = edges_with_counts(F)
        h = float(np.mean(np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1))) if len(edges) else 1.0
        t = t_scale * h * h
        iso = mass <= 0
        reg = np.where(iso, 1.0, 0.0)  # decouple vertices in no (non-degenerate) face
        self._heat = SparseCholesky((sparse.diags(mass + reg) + t * L).tocsc())
        self._eps = 1e-10 * float(np.mean(L.diagonal()[~iso] / mass[~iso])) if np.any(~iso) else 1.0
        self._poisson = SparseCholesky((L + sparse.diags(self._eps * mass + reg)).tocsc())
        n_comp, labels = connected_components(n, F)
        self._labels = labels
        self._mass = mass
        self._comp_mass = np.bincount(labels[labels >= 0], weights=mass[labels >= 0], minlength=n_comp)
        self._n_faces = len(F)

    def batch_size(self) -> int:
        """Sources per batch: small enough for the working set to stay in cache.

        Measured on a 2-core machine: 16 sources per batch ran 0.6 ms per source on a
        10K-vertex mesh against 1.0 ms with 128; 8 per batch 5 ms per source at 60K
        against 11 ms with 32 (``benchmarks/bench_geodesics.py``).
        """
        return int(np.clip(round(1.6e5 / max(self.n_vertices, 1)), 2, 256))

    def distances_from(self, sources: IndexArray) -> FloatArray:  # noqa: D102
        s = np.asarray(sources, dtype=np.int64)
        n, B = self.n_vertices, len(s)
        if B == 0:
            return np.zeros((0, n))
        delta = np.zeros((n, B))
        delta[s, np.arange(B)] = 1.0
        u = self._heat.solve(delta)  # (n, B)
        div_t = np.zeros((B, n))
        heat_divergence(np.ascontiguousarray(u.T), self._faces_id, self._coef, self._area, div_t)
        div = np.ascontiguousarray(div_t.T)  # (n, B) integrated divergence of -grad u / |grad u|
        # make the right-hand side mean-free on each component (compatibility of the Neumann problem)
        lab = self._labels
        if len(self._comp_mass) == 1 and np.all(lab >= 0):
            div -= np.outer(self._mass, div.sum(axis=0) / self._comp_mass[0])
        else:
            ok = lab >= 0
            tot = np.zeros((len(self._comp_mass), B))
            np.add.at(tot, lab[ok], div[ok])
            div[ok] -= self._mass[ok, None] * (tot / np.maximum(self._comp_mass, 1e-300)[:, None])[lab[ok]]
        phi = self._poisson.solve(div)  # (n, B)
        d = phi.T - phi[s, np.arange(B)][:, None]  # (B, n)
        np.maximum(d, 0.0, out=d)
        if len(self._comp_mass) > 1 or np.any(lab < 0):
            d[lab[None, :] != lab[s][:, None]] = np.inf
        return d


class DijkstraGeodesicSolver(GeodesicSolver):
    """Shortest-path distances on the edge graph (Euclidean edge lengths).

    Parameters
    ----------
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
    """

    kind = "dijkstra"

    def __init__(self, vertices: FloatArray, faces: IndexArray) -> None:
        self.n_vertices = len(vertices)
        self._graph = edge_graph(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64))

    def batch_size(self) -> int:  # noqa: D102
        return int(max(1, min(1024, 256e6 // (8.0 * max(self.n_vertices, 1)))))

    def distances_from(self, sources: IndexArray) -> FloatArray:  # noqa: D102
        s = np.asarray(sources, dtype=np.int64)
        if len(s) == 0:
            return np.zeros((0, self.n_vertices))
        return np.atleast_2d(csgraph.dijkstra(self._graph, directed=False, indices=s))


def _parity(faces: IndexArray) -> IndexArray:
    """0 for faces whose corners are an even permutation of their sorted order, else 1."""
    o = np.argsort(faces, axis=1)
    # a permutation of 3 elements is even iff it is a rotation of (0, 1, 2)
    even = (o[:, 1] - o[:, 0]) % 3 == 1
    return np.where(even, 0, 1)


def clean_for_exact(vertices: FloatArray, faces: IndexArray) -> tuple[IndexArray, str]:
    """Faces safe for the exact MMP code.

    Same-orientation duplicates are reduced to one copy; a triangle present with both
    orientations is a zero-thickness fin and is removed altogether; zero-area faces are
    removed.

    Returns
    -------
    faces : ndarray, shape (n_kept, 3)
    note : str
        What was removed ("" if nothing).

    Raises
    ------
    ValueError
        If non-manifold edges remain after cleaning.
    """
    F = np.asarray(faces, dtype=np.int64)
    notes = []
    key = np.sort(F, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if np.any(cnt > 1):
        par = _parity(F)
        n_par = np.bincount(inv, weights=par, minlength=len(cnt))
        fin = (cnt[inv] > 1) & (n_par[inv] > 0) & (n_par[inv] < cnt[inv])
        _, first = np.unique(inv, return_index=True)
        keep = np.zeros(len(F), dtype=bool)
        keep[first] = True
        keep &= ~fin
        n_fin = len(np.unique(inv[fin]))
        n_dup = int((cnt > 1).sum()) - n_fin
        if n_dup:
            notes.append(f"{n_dup} duplicated face(s) reduced to one copy")
        if n_fin:
            notes.append(f"{n_fin} double-sided face(s) (zero-thickness fins) removed")
        F = F[keep]
    a = face_areas(vertices, F)
    bad = a <= 1e-14 * max(float(a.max(initial=0.0)), 1e-300)
    if np.any(bad):
        notes.append(f"{int(bad.sum())} zero-area face(s) removed")
        F = F[~bad]
    _, counts = edges_with_counts(F)
    if np.any(counts > 2):
        raise ValueError(
            f"mesh has {int((counts > 2).sum())} non-manifold edge(s) after cleaning; exact "
            "geodesics (MMP) cannot run on it. Use the heat method."
        )
    return F, "; ".join(notes)


class ExactGeodesicSolver(GeodesicSolver):
    """Exact polyhedral geodesic distances (MMP, via ``pygeodesic``).

    Parameters
    ----------
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)

    Notes
    -----
    The mesh is cleaned by :func:`clean_for_exact` first; ``self.cleaning`` says what
    was removed. ``pair_distances`` stops each propagation once its query vertices
    are reached, so pairs of nearby vertices are cheap.

    References
    ----------
    J. Mitchell, D. Mount, C. Papadimitriou, "The Discrete Geodesic Problem", SIAM J.
    Comput. 1987; V. Surazhsky et al., "Fast Exact and Approximate Geodesics on Meshes",
    SIGGRAPH 2005.
    """

    kind = "exact"

    def __init__(self, vertices: FloatArray, faces: IndexArray) -> None:
        from pygeodesic import geodesic

        V = np.ascontiguousarray(vertices, dtype=np.float64)
        F, self.cleaning = clean_for_exact(V, faces)
        self.n_vertices = len(V)
        _, labels = connected_components(len(V), F)
        # vertices in no face after cleaning stand in for their nearest kept vertex,
        # at their Euclidean distance from it
        self._proxy = np.arange(len(V))
        self._offset = np.zeros(len(V))
        lone = np.flatnonzero(labels < 0)
        if len(lone):
            from scipy.spatial import cKDTree

            kept = np.flatnonzero(labels >= 0)
            dist, j = cKDTree(V[kept]).query(V[lone])
            self._proxy[lone] = kept[j]
            self._offset[lone] = dist
            self.cleaning = (self.cleaning + "; " if self.cleaning else "") + (
                f"{len(lone)} vertex(es) left in no face use their nearest vertex plus the Euclidean gap"
            )
        self._labels = labels[self._proxy]
        # the MMP code wants every vertex in a face: solve on the compacted mesh
        kept = np.flatnonzero(labels >= 0)
        self._compact = np.full(len(V), -1, dtype=np.int64)
        self._compact[kept] = np.arange(len(kept))
        self._kept = kept
        self._alg = geodesic.PyGeodesicAlgorithmExact(V[kept], np.ascontiguousarray(self._compact[F], dtype=np.int32))

    def _run(self, source: int, targets: IndexArray | None) -> FloatArray:
        """Distances on the compact mesh from one (compact) source to targets (or all)."""
        src = np.array([self._compact[self._proxy[source]]], dtype=np.int32)
        tgt = None if targets is None else np.ascontiguousarray(targets, dtype=np.int32)
        res = self._alg.geodesicDistances(src, tgt)
        if res is None:
            raise RuntimeError("the exact geodesic code rejected the mesh")
        d = np.asarray(res[0], dtype=np.float64)
        d[d > 1e300] = np.inf
        return d

    def batch_size(self) -> int:  # noqa: D102
        return 16

    def distances_from(self, sources: IndexArray) -> FloatArray:  # noqa: D102
        s = np.asarray(sources, dtype=np.int64)
        out = np.empty((len(s), self.n_vertices))
        for i, src in enumerate(s):
            d = self._run(int(src), None)  # (n_kept,)
            out[i] = d[self._compact[self._proxy]] + self._offset + self._offset[src]
            out[i, src] = 0.0
        return out

    def pair_distances(self, a: IndexArray, b: IndexArray) -> FloatArray:  # noqa: D102
        a = np.asarray(a, dtype=np.int64)
        b = np.asarray(b, dtype=np.int64)
        if a.shape != b.shape:
            raise ValueError(f"a and b must have the same shape, got {a.shape} and {b.shape}")
        out = np.empty(len(a))
        uniq, inv = np.unique(a, return_inverse=True)
        order = np.argsort(inv, kind="stable")
        starts = np.searchsorted(inv[order], np.arange(len(uniq) + 1))
        for u, src in enumerate(uniq):
            sel = order[starts[u] : starts[u + 1]]
            tgt = b[sel]
            same = self._labels[tgt] == self._labels[src]
            res = np.full(len(sel), np.inf)
            if np.any(same):
                t_u, t_inv = np.unique(self._compact[self._proxy[tgt[same]]], return_inverse=True)
                d = self._run(int(src), t_u)
                res[same] = d[t_inv.ravel()] + self._offset[tgt[same]] + self._offset[src]
            res[tgt == src] = 0.0
            out[sel] = res
        return out


def make_geodesic_solver(vertices: FloatArray, faces: IndexArray, kind: GeodesicKind = "heat") -> GeodesicSolver:
    """Build the geodesic solver of the given kind (``"heat"``, ``"exact"`` or ``"dijkstra"``)."""
    if kind == "heat":
        return HeatGeodesicSolver(vertices, faces)
    if kind == "exact":
        return ExactGeodesicSolver(vertices, faces)
    if kind == "dijkstra":
        return DijkstraGeodesicSolver(vertices, faces)
    raise ValueError(f"unknown geodesic kind {kind!r}; expected 'heat', 'exact' or 'dijkstra'")
