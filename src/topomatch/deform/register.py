"""Non-rigid registration of a source surface onto a target with a deformation graph.

The source deforms by an embedded deformation (Sumner et al. 2007): node ``q`` of the
graph carries a rotation ``R_q`` and a position ``g_q``; a vertex moves to
``v'_i = sum_q w_iq (R_q (v_i - g0_q) + g_q)``. The energy is

``alpha * sum_links w_ab ||g_b - g_a - R_a (g0_b - g0_a)||^2``
``+ sum_pairs c_p (mu_point ||v'_i - y_p||^2 + mu_plane (n_p . (v'_i - y_p))^2)``

over data pairs ``(i, y_p, n_p, c_p)``: a source vertex, a target point, the target
normal there and a robust weight. It is minimised by alternating per-node rotations
(orthogonal Procrustes over links and data) with one sparse linear solve for all node
positions (as-rigid-as-possible on the graph). Links whose stretch is far above the
graph's typical stretch can be down-weighted (``robust_links``), which lets the graph
tear where the source is glued to itself by topological noise.

Because the source keeps its own connectivity, the deformed surface never takes the
target's shortcuts: a dense map is read off by nearest neighbours between the deformed
source and the target.
"""

from __future__ import annotations

import contextlib
import threading
import weakref
from collections.abc import Callable
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from topomatch._kernels import (
    banded_blocks,
    dense_blocks,
    gram_entries,
    position_terms,
    robust_pairs,
    rotation_step,
    skinned_vertices,
)
from topomatch._lapack import banded_cholesky_solve, cholesky_solve
from topomatch.deform.graph import DeformationGraph
from topomatch.deform.kdtree import JointTree, PointTree
from topomatch.mesh.geometry import vertex_normals
from topomatch.mesh.spectral import SparseCholesky
from topomatch.typing import BoolArray, FloatArray, IndexArray

__all__ = [
    "DataPairs",
    "GraphDeformation",
    "RegistrationResult",
    "RegistrationSchedule",
    "closest_pairs",
    "feature_pairs",
    "fit_residual",
    "nearest_compatible",
    "register",
]


@dataclass
class DataPairs:
    """Correspondence constraints for the registration.

    Attributes
    ----------
    source : ndarray, shape (p,)
        Source vertex of each pair.
    points : ndarray, shape (p, 3)
        Target position.
    normals : ndarray, shape (p, 3)
        Target unit normal (for the point-to-plane term).
    weights : ndarray, shape (p,)
    """

    source: IndexArray
    points: FloatArray
    normals: FloatArray
    weights: FloatArray

    def __post_init__(self) -> None:
        p = len(self.source)
        if self.points.shape != (p, 3) or self.normals.shape != (p, 3) or self.weights.shape != (p,):
            raise ValueError(
                f"DataPairs arrays disagree: source {self.source.shape}, points {self.points.shape}, "
                f"normals {self.normals.shape}, weights {self.weights.shape}"
            )

    @classmethod
    def concat(cls, *pairs: DataPairs) -> DataPairs:
        """Stack several sets of pairs."""
        return cls(
            np.concatenate([p.source for p in pairs]),
            np.concatenate([p.points for p in pairs]),
            np.concatenate([p.normals for p in pairs]),
            np.concatenate([p.weights for p in pairs]),
        )

    def weighted(self) -> DataPairs:
        """The pairs with a positive weight."""
        keep = self.weights > 0
        return DataPairs(self.source[keep], self.points[keep], self.normals[keep], self.weights[keep])


_NO_ROWS = np.zeros(0, dtype=np.int64)
"""The ``rows`` argument of :func:`skinned_vertices` for every vertex."""

_NO_DISTANCES = np.zeros(0)
"""The distances of no pairs (a :func:`closest_pairs` without its backward direction)."""

_NO_PAIRS = (np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 3)))
"""Arguments of :func:`rotation_step` for a step without data pairs."""

_DENSE_SOLVE_MAX = 600
"""Linear systems of the position step up to this size are factorised densely (LAPACK);
larger ones with the sparse Cholesky factorisation (CHOLMOD)."""

BANDED_SOLVE = True
"""Solve the coupled (point-to-plane) systems up to ``_DENSE_SOLVE_MAX`` by LAPACK's banded
Cholesky (``dpbtrf`` / ``dpbtrs``) in a reverse Cuthill-McKee order of the graph's nodes,
each node's coordinates side by side (:meth:`_GramPattern.band`), instead of the dense
factorisation: the same solutions to rounding (#198: about half the time per solve). On
since session 62 (session 61's rule in docs/flagship.md, #199, #200); ``False`` gives the
maps of sessions up to 61 bit for bit (with :data:`QUATERNION_ROTATIONS` ``False``)."""

_BAND_MAX = 0.5
"""With :data:`BANDED_SOLVE`, the band path is taken when the half-bandwidth is below this
fraction of the system's size (the TOPKIDS coarse graphs: about 0.38)."""

QUATERNION_ROTATIONS = True
"""The rotation step's rotations by Horn's quaternion instead of LAPACK's 3 x 3 SVDs
(:func:`topomatch._kernels.rotation_step`): the same rotations to about 1e-13 (#196). On
since session 62 (session 61's rule, with :data:`BANDED_SOLVE`); ``False`` takes the SVDs."""

_PCG_RTOL = 1e-10
"""Relative residual at which the conjugate gradients of the position step stop."""

_PCG_MAX_STEPS = 25
"""Conjugate-gradient steps after which the position step factorises its matrix afresh."""

_PCG_REFRESH = 12
"""A solve that needed more steps than this marks the factor stale: the next position
step factorises afresh (about 10 ms for 1,500 unknowns, against 0.15 ms per step)."""


class _LastFactor:
    """The last sparse factorisation of one registration's position system.

    Successive closest-point iterations change the system little (the stiffness by a few
    per cent, the pairs' weights locally), so the previous factor is an excellent
    preconditioner: conjugate gradients from the current positions reach the solution
    in 6-13 steps where a new factorisation would cost as much as 50 of them. The
    solution is the direct one to about 1e-10 (relative).
    """

    def __init__(self) -> None:
        self.factor: SparseCholesky | None = None


def _pcg(
    A: sparse.spmatrix, b: FloatArray, x0: FloatArray, precondition: Callable[[FloatArray], FloatArray], *, rtol: float, max_steps: int
) -> tuple[FloatArray | None, int]:
    """Preconditioned conjugate gradients for the SPD system ``A x = b`` from ``x0``.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
    b, x0 : ndarray, shape (n,) or (n, r)
        Right-hand side(s) and start; columns are solved independently.
    precondition : callable
        Applies the preconditioner to an (n, r) array.
    rtol : float
        Stop when every column's residual is below ``rtol`` times its right-hand side's norm.
    max_steps : int

    Returns
    -------
    x : ndarray, shape of ``b``, or None
        ``None`` when not converged within ``max_steps``.
    steps : int
        Preconditioner applications.
    """
    one = b.ndim == 1
    B = b[:, None] if one else b
    x = (x0[:, None] if one else x0).copy()
    r = B - A @ x
    tol = rtol * np.linalg.norm(B, axis=0)
    if np.all(np.linalg.norm(r, axis=0) <= tol):
        return (x[:, 0] if one else x), 0
    z = precondition(r)
    p = z.copy()
    rz = np.einsum("nr,nr->r", r, z)
    for step in range(1, max_steps + 1):
        Ap = A @ p
        pAp = np.einsum("nr,nr->r", p, Ap)
        a = np.divide(rz, pAp, out=np.zeros_like(rz), where=pAp > 0)
        x += a * p
        r -= a * Ap
        if np.all(np.linalg.norm(r, axis=0) <= tol):
            return (x[:, 0] if one else x), step
        z = precondition(r)
        rz_new = np.einsum("nr,nr->r", r, z)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz > 0)
        p = z + beta * p
        rz = rz_new
    return None, max_steps


@dataclass(frozen=True)
class _Layout:
    """Compressed structure of one block system on a :class:`_GramPattern` (see ``_layout``)."""

    indptr: IndexArray
    indices: IndexArray
    slots: IndexArray
    diagonal: IndexArray
    picks: list[tuple[tuple[int, int], slice | BoolArray]]


@dataclass(frozen=True, eq=False)
class _GramPattern:
    """Fixed structure of the Gram matrices ``skin^T diag(W) skin`` of one deformation graph.

    Every such matrix (and the link Laplacian) lives on one symmetric pattern of node
    pairs; its upper triangle is stored as the pattern entries ``(rows[e], cols[e])``
    with ``rows <= cols``. ``vertex_products`` holds, for each vertex ``i`` and entry
    ``e = (a, b)``, the product ``skin[i, a] skin[i, b]``, so that the upper triangle of
    ``skin^T diag(W) skin`` is ``vertex_products.T @ W`` for any vertex weights ``W``.

    Attributes
    ----------
    rows, cols : ndarray, shape (n_entries,)
        Node pair of each entry, ``rows <= cols``.
    diagonal : ndarray, shape (m,)
        Entry of each node's diagonal element.
    link_entries : ndarray, shape (n_links,)
        Entry of each link ``(a, b)``.
    vertex_products : scipy.sparse.csr_matrix, shape (n_vertices, n_entries)
    """

    rows: IndexArray
    cols: IndexArray
    diagonal: IndexArray
    link_entries: IndexArray
    vertex_products: sparse.csr_matrix
    _layouts: dict[tuple[tuple[int, int], ...], _Layout] = field(
        default_factory=dict, repr=False, compare=False
    )
    _bands: dict[int, tuple[IndexArray, IndexArray, int]] = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def build(cls, skin: sparse.csr_matrix, links: IndexArray) -> _GramPattern:
        """Pattern of a skinning matrix and its links.

        Parameters
        ----------
        skin : scipy.sparse.csr_matrix, shape (n_vertices, m)
        links : ndarray, shape (n_links, 2)
            Node pairs with ``links[:, 0] < links[:, 1]``.

        Returns
        -------
        _GramPattern
        """
        if not skin.has_canonical_format:  # sorted, no duplicates; never change the caller's matrix
            skin = skin.copy()
            skin.sum_duplicates()
        n, m = skin.shape
        counts = np.diff(skin.indptr)
        nnz = int(skin.indptr[-1])
        k = np.arange(nnz)
        # pairs (k, l) of stored entries of one row with k <= l: (a, b) = (col[k], col[l]), a <= b
        span = np.repeat(skin.indptr[1:], counts) - k
        first = np.repeat(k, span)
        second = np.arange(len(first)) - np.repeat(np.cumsum(span) - span - k, span)
        a = skin.indices[first].astype(np.int64)
        b = skin.indices[second].astype(np.int64)
        nodes = np.arange(m, dtype=np.int64)
        la, lb = np.asarray(links[:, 0], dtype=np.int64), np.asarray(links[:, 1], dtype=np.int64)
        rows, cols = np.concatenate([a, nodes, la]), np.concatenate([b, nodes, lb])
        # unique pairs, sorted by row then column, through scipy's duplicate summing
        pattern = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, m))
        pattern.sum_duplicates()
        keys = np.repeat(np.arange(m, dtype=np.int64), np.diff(pattern.indptr)) * m + pattern.indices
        inverse = np.searchsorted(keys, rows * m + cols)
        n_pairs = len(a)
        products = sparse.csr_matrix(
            (skin.data[first] * skin.data[second], (np.repeat(np.arange(n), counts)[first], inverse[:n_pairs])),
            shape=(n, len(keys)),
        )
        return cls(keys // m, keys % m, inverse[n_pairs : n_pairs + m], inverse[n_pairs + m :], products)

    @property
    def n_entries(self) -> int:
        """Number of stored (upper-triangle) entries."""
        return len(self.rows)

    def _layout(self, keys: tuple[tuple[int, int], ...], d: int) -> _Layout:
        """Compressed (CSR = CSC) structure of the ``d m x d m`` system with the blocks ``keys``.

        Each block is given by its upper-triangle values ``v``; a diagonal block stores
        ``v`` and its strict upper part mirrored, an off-diagonal block ``(i, j)`` the
        block (``v`` and its mirror) and its transpose. ``picks`` says which values of
        which block go in, in the order of ``slots``.
        """
        m = len(self.diagonal)
        r, c = self.rows, self.cols
        off = r != c
        every = slice(None)
        ii, jj, picks = [], [], []
        for i, j in keys:
            if i == j:
                parts = [(i * m + r, j * m + c, every), (j * m + c[off], i * m + r[off], off)]
            else:
                parts = [
                    (i * m + r, j * m + c, every), (i * m + c[off], j * m + r[off], off),
                    (j * m + c, i * m + r, every), (j * m + r[off], i * m + c[off], off),
                ]
            for rows, cols, pick in parts:
                ii.append(rows)
                jj.append(cols)
                picks.append(((i, j), pick))
        size = d * m
        ii.append(np.arange(size))
        jj.append(np.arange(size))
        flat = np.concatenate(ii).astype(np.int64) * size + np.concatenate(jj)
        uniq, slots = np.unique(flat, return_inverse=True)
        indptr = np.searchsorted(uniq // size, np.arange(size + 1)).astype(np.int32)
        n_values = len(flat) - size
        return _Layout(indptr, (uniq % size).astype(np.int32), slots[:n_values], slots[n_values:], picks)

    def band(self, d: int) -> tuple[IndexArray, IndexArray, int]:
        """Band order of the ``d m x d m`` block system: each node's ``d`` unknowns side by side, the nodes in reverse Cuthill-McKee order.

        Returns
        -------
        position : ndarray, shape (m,)
            Place of each node in the order.
        old_of_new : ndarray, shape (d m,)
            Index (``c m + k`` for coordinate ``c`` of node ``k``) of each reordered unknown.
        kd : int
            Half-bandwidth of the reordered matrix.
        """
        hit = self._bands.get(d)
        if hit is not None:
            return hit
        from scipy.sparse.csgraph import reverse_cuthill_mckee

        m = len(self.diagonal)
        adjacency = sparse.csr_matrix((np.ones(len(self.rows)), (self.rows, self.cols)), shape=(m, m))
        order = reverse_cuthill_mckee((adjacency + adjacency.T).tocsr(), symmetric_mode=True)
        position = np.empty(m, dtype=np.int64)
        position[order] = np.arange(m)
        kd = d * int(np.abs(position[self.rows] - position[self.cols]).max(initial=0)) + d - 1
        old_of_new = np.empty(d * m, dtype=np.int64)
        for c in range(d):
            old_of_new[d * position + c] = c * m + np.arange(m)
        return self._bands.setdefault(d, (position, old_of_new, kd))

    def grams(self, source: IndexArray, weights: FloatArray) -> FloatArray:
        """Upper triangles of ``P^T diag(w_k) P`` for ``P = skin[source]``, shape (n_entries, k).

        Parameters
        ----------
        source : ndarray, shape (p,)
            Vertex (skin row) of each pair.
        weights : ndarray, shape (p, k)
            Weights ``w_k`` of the pairs.

        Returns
        -------
        ndarray, shape (n_entries, k)
        """
        vp = self.vertex_products
        out = np.zeros((vp.shape[1], weights.shape[1]))
        gram_entries(
            vp.indptr, vp.indices, vp.data, vp.shape[0], np.ascontiguousarray(source, dtype=np.int64),
            np.ascontiguousarray(weights, dtype=np.float64), out,
        )
        return out

    def laplacian(self, weights: FloatArray) -> FloatArray:
        """Upper triangle of ``D diag(w) D^T`` over the directed links, shape (n_entries,).

        Parameters
        ----------
        weights : ndarray, shape (2 n_links,)
            Weight of each directed link: the graph's links ``a -> b`` followed by the
            same links reversed.
        """
        a, b = self.rows[self.link_entries], self.cols[self.link_entries]
        entries = np.r_[self.link_entries, self.link_entries]
        idx = np.concatenate([self.diagonal[np.r_[a, b]], self.diagonal[np.r_[b, a]], entries])
        return np.bincount(idx, weights=np.concatenate([weights, weights, -weights]), minlength=self.n_entries)

    def solve(self, blocks: dict[tuple[int, int], FloatArray], rhs: FloatArray, x0: FloatArray, last: _LastFactor | None = None) -> FloatArray:
        """Solve ``(H + eps I) x = rhs + eps x0`` for a symmetric block matrix ``H`` on this pattern.

        ``eps`` is ``1e-8`` times the mean diagonal of ``H``.

        Parameters
        ----------
        blocks : dict
            Upper-triangle entries (shape (n_entries,)) of the blocks ``(i, j)``, ``i <= j``,
            of a ``d x d`` block matrix of ``m x m`` blocks; blocks not given are zero.
        rhs : ndarray, shape (d m,) or (d m, r)
        x0 : ndarray, same shape as ``rhs``
            The current solution: the start of the conjugate gradients.
        last : _LastFactor, optional
            The calling registration's last sparse factorisation. When given, sparse
            systems are solved by conjugate gradients preconditioned with it (to a
            relative residual of ``_PCG_RTOL``) and factorised afresh when it is missing
            or stale; the new factor is kept there.

        Returns
        -------
        ndarray, same shape as ``rhs``
        """
        m = len(self.diagonal)
        d = max(max(ij) for ij in blocks) + 1
        size = d * m
        eps = 1e-8 * float(np.concatenate([blocks[i, i][self.diagonal] if (i, i) in blocks else np.zeros(m) for i in range(d)]).mean())
        r, c = self.rows, self.cols
        if size <= _DENSE_SOLVE_MAX:
            keys = list(blocks)
            block_i = np.array([i for i, _ in keys], dtype=np.int64)
            block_j = np.array([j for _, j in keys], dtype=np.int64)
            values = np.array([blocks[ij] for ij in keys], dtype=np.float64)
            b = rhs + eps * x0
            if BANDED_SOLVE and d > 1:
                position, old_of_new, kd = self.band(d)
                if kd < _BAND_MAX * size:
                    # banded Cholesky (LAPACK dpbtrf / dpbtrs) in the band order, without the GIL
                    AB = np.zeros((kd + 1, size), order="F")
                    banded_blocks(r, c, block_i, block_j, values, d, eps, position, AB)
                    x = np.empty_like(b)
                    x[old_of_new] = banded_cholesky_solve(AB, b[old_of_new])
                    return x
            H = np.zeros((size, size), order="F")  # LAPACK's order: factorised in place
            # the upper triangle of H holds each diagonal block's upper triangle and the
            # whole of each off-diagonal block (compiled: topomatch._kernels.dense_blocks)
            dense_blocks(r, c, block_i, block_j, values, m, eps, H)
            # cho_solve(cho_factor(H)) bit for bit, without holding the GIL (threads solve side by side)
            return cholesky_solve(H, b)
        keys = tuple(sorted(blocks))
        layout = self._layouts.get(keys)
        if layout is None:
            layout = self._layouts.setdefault(keys, self._layout(keys, d))
        values = np.concatenate([blocks[ij][pick] for ij, pick in layout.picks])
        data = np.bincount(layout.slots, weights=values, minlength=len(layout.indices))
        data[layout.diagonal] += eps
        # symmetric: its CSR arrays are also its CSC arrays
        H = sparse.csc_matrix((data, layout.indices, layout.indptr), shape=(size, size))
        b = rhs + eps * x0
        if last is not None and last.factor is not None and last.factor.n == size:
            x, steps = _pcg(H, b, x0, last.factor.solve, rtol=_PCG_RTOL, max_steps=_PCG_MAX_STEPS)
            if steps > _PCG_REFRESH:
                last.factor = None
            if x is not None:
                return x
        factor = SparseCholesky(H)
        if last is not None:
            last.factor = factor
        return factor.solve(b)


_PATTERNS: weakref.WeakKeyDictionary[DeformationGraph, _GramPattern] = weakref.WeakKeyDictionary()
_PATTERNS_LOCK = threading.Lock()


def _gram_pattern(graph: DeformationGraph, skin: sparse.csr_matrix) -> _GramPattern:
    """The :class:`_GramPattern` of a graph, built once per graph (registrations on threads share it).

    ``skin`` is the graph's skinning matrix with sorted indices.
    """
    with _PATTERNS_LOCK:
        pattern = _PATTERNS.get(graph)
    if pattern is None:
        pattern = _GramPattern.build(skin, graph.links)
        with _PATTERNS_LOCK:
            pattern = _PATTERNS.setdefault(graph, pattern)
    return pattern


@dataclass
class GraphDeformation:
    """The state of an embedded deformation of a source mesh.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Source rest positions.
    faces : ndarray, shape (n_faces, 3)
    graph : DeformationGraph
        Built on the same vertices.
    """

    vertices: FloatArray
    faces: IndexArray
    graph: DeformationGraph
    rotations: FloatArray = field(init=False)
    positions: FloatArray = field(init=False)
    link_scale: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        m = self.graph.n_nodes
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        self.rotations = np.tile(np.eye(3), (m, 1, 1))
        self.positions = self.graph.rest.copy()
        self.link_scale = np.ones(len(self.graph.links))
        # never sort the graph's matrix in place: one graph is shared by registrations
        # running on several threads (DeformMatcher's verification)
        skin = self.graph.skin.tocsr()
        self._skin = skin if skin.has_sorted_indices else skin.sorted_indices()
        links = self.graph.links
        self._dir_a = np.r_[links[:, 0], links[:, 1]]
        self._dir_b = np.r_[links[:, 1], links[:, 0]]
        self._dir_rest = self.graph.rest[self._dir_b] - self.graph.rest[self._dir_a]
        self._pattern = _gram_pattern(self.graph, self._skin)
        self._zero_rest = np.zeros_like(self.graph.rest)
        self._lg: FloatArray | None = None
        self._lg_scale: FloatArray | None = None
        self._last = _LastFactor()

    # ---- evaluation ------------------------------------------------------------------------
    def _affine_part(self, subset: IndexArray | None = None) -> FloatArray:
        """``a_i = sum_q w_iq R_q (v_i - g0_q)`` for all vertices or a subset, shape (n or len(subset), 3).

        Evaluated as ``(sum_q w_iq R_q) v_i - sum_q w_iq R_q g0_q`` per vertex, compiled
        (:func:`topomatch._kernels.skinned_vertices`, without the GIL).
        """
        return self._skinned(subset, with_positions=False)

    def _skinned(self, subset: IndexArray | None, *, with_positions: bool) -> FloatArray:
        every = subset is None
        rows = _NO_ROWS if subset is None else np.ascontiguousarray(subset, dtype=np.int64)
        out = np.empty((len(self.vertices) if every else len(rows), 3))
        S = self._skin
        skinned_vertices(
            self.rotations, self.graph.rest, S.indptr, S.indices, S.data, self.vertices, rows, every,
            self.positions, with_positions, out,
        )
        return out

    def deformed(self) -> FloatArray:
        """Deformed source vertices, shape (n, 3)."""
        return self._skinned(None, with_positions=True)

    def turned_normals(self, normals: FloatArray, subset: IndexArray) -> FloatArray:
        """Rest normals turned by each vertex's blended rotation, ``n_i = normalise(sum_q w_iq R_q n0_i)``, shape (len(subset), 3).

        The normals of vertices deformed without their neighbours (:func:`register`'s
        ``surface``), where the deformed mesh's own normals cannot be formed.

        Parameters
        ----------
        normals : ndarray, shape (n, 3)
            Unit vertex normals of the rest shape.
        subset : ndarray, shape (s,)
            The vertices wanted.
        """
        rows = np.ascontiguousarray(subset, dtype=np.int64)
        out = np.empty((len(rows), 3))
        S = self._skin
        # sum_q w_iq R_q (n0_i - 0): the skinning of the normals about the origin, without translations
        skinned_vertices(self.rotations, self._zero_rest, S.indptr, S.indices, S.data, normals, rows, False, self.positions, False, out)
        length = np.linalg.norm(out, axis=1, keepdims=True)
        return np.divide(out, length, out=np.zeros_like(out), where=length > 0)

    def deformed_normals(self, deformed: FloatArray | None = None) -> FloatArray:
        """Compute unit vertex normals of the deformed source, shape (n, 3)."""
        v = self.deformed() if deformed is None else deformed
        return vertex_normals(v, self.faces)

    def link_stretch(self) -> FloatArray:
        """Residual of each link, ``||g_b - g_a - R_a e_ab||`` averaged over both directions, shape (n_links,)."""
        d = self.positions[self._dir_b] - self.positions[self._dir_a] - np.einsum("kab,kb->ka", self.rotations[self._dir_a], self._dir_rest)
        r = np.linalg.norm(d, axis=1)
        nl = len(self.graph.links)
        return 0.5 * (r[:nl] + r[nl:])

    # ---- steps -----------------------------------------------------------------------------
    def _link_weights(self) -> FloatArray:
        w = self.graph.link_weights * self.link_scale
        return np.r_[w, w]

    def update_rotations(self, pairs: DataPairs | None, data_weight: float = 1.0) -> None:
        """Procrustes step: best rotation per node for the current positions.

        Compiled (:func:`topomatch._kernels.rotation_step`, without the GIL); the numpy
        and SciPy formula it replaced is :func:`topomatch.deform._reference.rotations`
        (the same bits on x86-64 with numpy 2.4).
        """
        wl = self._link_weights()
        if pairs is not None and len(pairs.source) and data_weight > 0:
            source = np.ascontiguousarray(pairs.source, dtype=np.int64)
            c = data_weight * pairs.weights
            points = np.ascontiguousarray(pairs.points, dtype=np.float64)
        else:
            source, c, points = _NO_PAIRS
        skin = self._skin
        # stored 3 x 3 transposed (strides (72, 8, 24)): the layout of the rotations
        # before session 49, in which numpy's einsum over them adds in the same order
        out = np.empty((len(self.rotations), 3, 3)).transpose(0, 2, 1)
        rotation_step(
            self.positions, self.graph.rest, self._dir_a, self._dir_b, self._dir_rest, wl, self.vertices,
            skin.indptr, skin.indices, skin.data, source, np.ascontiguousarray(c, dtype=np.float64), points,
            self.rotations, out, QUATERNION_ROTATIONS,
        )
        self.rotations = out

    def _regulariser(self, wl: FloatArray) -> FloatArray:
        """``D diag(wl) D^T`` (the graph Laplacian of the link term) on the Gram pattern, kept while the link weights stay."""
        if self._lg is None or self._lg_scale is not self.link_scale:
            self._lg = self._pattern.laplacian(wl)
            self._lg_scale = self.link_scale
        return self._lg

    def update_positions(self, pairs: DataPairs, *, alpha: float, mu_point: float = 1.0, mu_plane: float = 0.0) -> None:
        """Linear step: node positions minimising the energy for fixed rotations.

        The unknowns are ordered by coordinate (all x, then all y, then all z): the
        point-to-point and link terms are then three copies of one ``m x m`` matrix, and
        without the point-to-plane term the three coordinates are solved with one
        factorisation of that matrix. The ``m x m`` blocks ``P^T diag(w) P`` are
        accumulated on the graph's fixed pattern (:class:`_GramPattern`) and the system
        is factorised densely when small.
        """
        if len(pairs.source) == 0 or not float(pairs.weights.sum()) > 0:
            return  # no data (e.g. every closest pair had incompatible normals): keep the state
        wl = self._link_weights()
        Lg = self._regulariser(wl)
        source = np.ascontiguousarray(pairs.source, dtype=np.int64)
        resid = pairs.points - self._affine_part(source)  # y - a_i, (p, 3)
        c = pairs.weights
        data_scale = float(c.sum()) / max(float(wl.sum()), 1e-300)
        reg = alpha * data_scale
        # the right-hand side (regulariser: sum over directed links of w ||g_b - g_a - R_a e_ab||^2;
        # data: point-to-point, and point-to-plane when mu_plane > 0) and the pairs' Gram
        # weights, compiled (topomatch._kernels.position_terms)
        plane = mu_plane > 0
        r = np.empty((self.graph.n_nodes, 3))
        w = np.empty((len(source), 6 if plane else 1))
        S = self._skin
        position_terms(
            self.rotations, self._dir_a, self._dir_b, self._dir_rest, wl, S.indptr, S.indices, S.data, source,
            np.ascontiguousarray(c, dtype=np.float64), resid, np.ascontiguousarray(pairs.normals, dtype=np.float64),
            float(reg), float(mu_point), float(mu_plane), r, w,
        )
        self.positions = self._solved_positions(r, self._pattern.grams(source, w), reg, Lg)

    def _solved_positions(self, r: FloatArray, G: FloatArray, reg: float, Lg: FloatArray) -> FloatArray:
        """The position step's solution, shape (m, 3), for its right-hand side ``r`` (m, 3) and Gram sums ``G``.

        ``G`` (n_entries, 6) holds the blocks ``(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)``
        of a point-to-plane step (the coordinates coupled), (n_entries, 1) the one block of a
        point-to-point step (the three coordinates solved with one factorisation); the
        diagonal blocks get ``reg`` times the link Laplacian ``Lg``.
        """
        if G.shape[1] == 6:
            ij = [(i, j) for i in range(3) for j in range(i, 3)]
            blocks = {(i, j): G[:, k] + reg * Lg if i == j else G[:, k] for k, (i, j) in enumerate(ij)}
            x = self._pattern.solve(blocks, np.ravel(r.T), np.ravel(self.positions.T), self._last)
            return x.reshape(3, -1).T.copy()
        return self._pattern.solve({(0, 0): G[:, 0] + reg * Lg}, r, self.positions, self._last)

    def update_link_scale(self, threshold: float) -> None:
        """Down-weight links stretched more than ``threshold`` times the median stretch."""
        s = self.link_stretch()
        med = float(np.median(s)) + 1e-12 * self.graph.spacing
        x = s / (threshold * med)
        self.link_scale = 1.0 / (1.0 + x**4)

    def init_from_pairs(self, pairs: DataPairs) -> None:
        """Move each node by the weighted mean displacement its skinned vertices ask for.

        Nodes without pairs stay at rest.
        """
        m = self.graph.n_nodes
        P = self.graph.skin[pairs.source].tocsr()
        wsum = np.asarray(P.T @ pairs.weights).ravel()
        disp = P.T @ (pairs.weights[:, None] * (pairs.points - self.vertices[pairs.source]))
        has = wsum > 1e-12
        self.positions = self.graph.rest.copy()
        self.positions[has] += disp[has] / wsum[has, None]
        del m


_REBUILD_EVERY = 3
"""Closest-point iterations between rebuilds of the tree on the deformed source (refitted
in between: the same answers; kid13, one thread, backward queries 1.05 us each when
rebuilt every iteration, 1.2-1.3 every third, 1.6 every fifth, 2.0 never)."""


def _search_tree(points: FloatArray) -> PointTree:
    """A k-d tree for the nearest-neighbour queries of the registration loop.

    Parameters
    ----------
    points : ndarray, shape (n, 3)

    Returns
    -------
    PointTree
    """
    return PointTree(points)


def nearest_compatible(
    points: FloatArray,
    normals: FloatArray,
    tree: PointTree | cKDTree,
    ref_normals: FloatArray,
    *,
    k: int = 8,
    min_cos: float = 0.0,
) -> tuple[IndexArray, FloatArray]:
    """Nearest reference point whose normal agrees with each query's normal.

    Among the ``k`` nearest reference points, take the first with
    ``normal . ref_normal >= min_cos``; fall back to the nearest.

    Parameters
    ----------
    points : ndarray, shape (q, 3)
    normals : ndarray, shape (q, 3)
    tree : PointTree or scipy.spatial.cKDTree
        Built on the reference points (a :class:`~topomatch.deform.kdtree.PointTree`
        answers in one compiled pass; a ``cKDTree`` gives the same answer).
    ref_normals : ndarray, shape (n, 3)
    k : int
    min_cos : float

    Returns
    -------
    index : ndarray, shape (q,)
    distance : ndarray, shape (q,)
    """
    if isinstance(tree, PointTree):
        return tree.nearest_compatible(points, normals, ref_normals, k=k, min_cos=min_cos)
    d, idx = tree.query(points, k=1)
    if k == 1:
        return idx, d
    bad = np.flatnonzero(np.einsum("qc,qc->q", normals, ref_normals[idx]) < min_cos)
    if bad.size:
        dk, ik = tree.query(points[bad], k=k)
        cos = np.einsum("qc,qkc->qk", normals[bad], ref_normals[ik])
        ok = cos >= min_cos
        first = np.where(ok.any(axis=1), np.argmax(ok, axis=1), 0)
        r = np.arange(len(bad))
        idx[bad] = ik[r, first]
        d[bad] = dk[r, first]
    return idx, d


def closest_pairs(
    deformed: FloatArray,
    deformed_normals: FloatArray,
    target_vertices: FloatArray,
    target_normals: FloatArray,
    target_tree: PointTree | cKDTree,
    *,
    sigma: float,
    min_cos: float = 0.3,
    source_subset: IndexArray | None = None,
    target_subset: IndexArray | None = None,
    backward: bool = True,
    pool: Executor | None = None,
    source_tree: PointTree | None = None,
) -> DataPairs:
    """ICP pairs in both directions with normal compatibility and robust weights.

    Forward: each (sampled) deformed source vertex to its nearest compatible target
    vertex. Backward: each (sampled) target vertex to its nearest compatible deformed
    source vertex, so that every part of the target pulls on the source. Weights are
    ``1 / (1 + (d / sigma)^2)``; incompatible normals get weight zero. With ``pool``
    the backward search runs on it beside the forward one (same pairs). ``source_tree``:
    a tree on ``deformed`` (e.g. one refitted from the previous iteration,
    :meth:`PointTree.refit`) instead of building one (same pairs).
    """
    tgt = _NO_ROWS
    if backward:
        tgt = np.arange(len(target_vertices)) if target_subset is None else np.asarray(target_subset)

    def backward_search() -> tuple[IndexArray, FloatArray]:
        stree = _search_tree(deformed) if source_tree is None else source_tree
        return nearest_compatible(target_vertices[tgt], target_normals[tgt], stree, deformed_normals, min_cos=min_cos)

    later = pool.submit(backward_search) if backward and pool is not None else None
    src = np.arange(len(deformed)) if source_subset is None else np.asarray(source_subset)
    j, d = nearest_compatible(deformed[src], deformed_normals[src], target_tree, target_normals, min_cos=min_cos)
    i, d2 = _NO_ROWS, _NO_DISTANCES
    if later is not None:
        i, d2 = later.result()
    elif backward:
        i, d2 = backward_search()
    return _weighted_pairs(src, j, d, tgt, i, d2, deformed_normals, target_vertices, target_normals, sigma, min_cos)


def _weighted_pairs(
    src: IndexArray, j: IndexArray, d: FloatArray, tgt: IndexArray, i: IndexArray, d2: FloatArray,
    source_normals: FloatArray, target_vertices: FloatArray, target_normals: FloatArray, sigma: float, min_cos: float,
) -> DataPairs:
    """The pairs ``src -> j`` (distances ``d``) and ``i <- tgt`` (``d2``) with their robust weights, those with a positive one.

    Each pair weighs ``1 / (1 + (d / sigma)^2)`` where its two normals' cosine is at least
    ``min_cos``, else 0; the forward pairs first, each direction in order (compiled:
    :func:`topomatch._kernels.robust_pairs`; the numpy formula it replaced is
    :func:`topomatch.deform._reference.weighted_pairs`).
    """
    size = len(src) + len(tgt)
    source, points, normals, weights = np.empty(size, dtype=np.int64), np.empty((size, 3)), np.empty((size, 3)), np.empty(size)
    n = robust_pairs(
        np.ascontiguousarray(src, dtype=np.int64), np.ascontiguousarray(j, dtype=np.int64), np.ascontiguousarray(d, dtype=np.float64),
        np.ascontiguousarray(tgt, dtype=np.int64), np.ascontiguousarray(i, dtype=np.int64), np.ascontiguousarray(d2, dtype=np.float64),
        np.ascontiguousarray(source_normals, dtype=np.float64), np.ascontiguousarray(target_vertices, dtype=np.float64),
        np.ascontiguousarray(target_normals, dtype=np.float64), float(sigma), float(min_cos), source, points, normals, weights,
    )
    return DataPairs(source[:n], points[:n], normals[:n], weights[:n])


def feature_pairs(
    deformed: FloatArray,
    deformed_normals: FloatArray,
    target_vertices: FloatArray,
    target_normals: FloatArray,
    source_features: FloatArray,
    target_points: FloatArray,
    target_tree: JointTree | cKDTree,
    *,
    sigma: float,
    min_cos: float = 0.3,
    pool: Executor | None = None,
    source_tree: JointTree | None = None,
) -> DataPairs:
    """ICP pairs in both directions, nearest in positions *and* features.

    Each deformed source vertex is paired with the target vertex nearest to it in the
    joint space ``[position, scaled feature]`` and each target vertex with the
    nearest deformed source vertex there, so that a feature that tells places apart
    (a local shape descriptor) stops the surfaces sliding along each other where the
    positions alone cannot (a limb turned about its own axis). Weights as in
    :func:`closest_pairs` from the *positional* distance; a pair whose normals differ
    by more than ``min_cos`` gets weight zero (no search for a compatible one).

    Parameters
    ----------
    deformed, deformed_normals : ndarray, shape (n1, 3)
    target_vertices, target_normals : ndarray, shape (n2, 3)
    source_features : ndarray, shape (n1, d)
        Already scaled to lengths.
    target_points : ndarray, shape (n2, 3 + d)
        ``[target_vertices, scaled target features]``.
    target_tree : JointTree or cKDTree
        Built (or refitted) on ``target_points``.
    sigma, min_cos : float
    pool : Executor, optional
        Runs the backward search beside the forward one.
    source_tree : JointTree, optional
        A tree on ``[deformed, source_features]`` (refitted to them by the caller, whose
        points are then taken from it); ``None`` builds one.
    """
    joint = np.c_[deformed, source_features] if source_tree is None else source_tree.data

    def backward() -> tuple[IndexArray, FloatArray]:
        i = (JointTree(joint) if source_tree is None else source_tree).query(target_points)[1]
        return i, np.linalg.norm(target_vertices - deformed[i], axis=1)

    later = pool.submit(backward) if pool is not None else None
    j = target_tree.query(joint)[1]
    d = np.linalg.norm(deformed - target_vertices[j], axis=1)
    i, d2 = later.result() if later is not None else backward()
    every = np.arange(len(target_vertices))
    return _weighted_pairs(np.arange(len(deformed)), j, d, every, i, d2, deformed_normals, target_vertices, target_normals, sigma, min_cos)


@dataclass(frozen=True)
class RegistrationSchedule:
    """How a registration runs: graph size, iterations, stiffness and robust scales.

    Lengths (``sigma_*``, ``inlier_distance``) are in units of the square root of the
    source's surface area.

    Attributes
    ----------
    n_nodes : int
        Deformation graph nodes.
    fit_iterations : int
        Iterations pulling the source towards the initial correspondences, with robust
        weights whose scale shrinks from ``sigma_fit[0]`` to ``sigma_fit[1]``.
    alpha_fit : float
        Stiffness during those iterations (relative to the data term).
    icp_iterations : int
        Closest-point iterations; stiffness goes geometrically from ``alpha_icp[0]`` to
        ``alpha_icp[1]`` and the robust scale from ``sigma_icp[0]`` to ``sigma_icp[1]``.
    n_samples : int or None
        Farthest-point samples per shape used for the closest-point pairs (``None``: all).
    mu_point, mu_plane : float
        Weights of the point-to-point and point-to-plane terms in the closest-point phase.
    min_cos : float
        Minimum cosine between normals for a closest-point pair.
    feature_weight : tuple of float
        With ``features`` given to :func:`register`: the closest-point pairs are
        nearest in ``[position, w * sqrt(source area) * feature]`` (:func:`feature_pairs`,
        all vertices, no sampling), ``w`` going linearly from ``feature_weight[0]`` to
        ``feature_weight[1]`` over the iterations; ``(0, 0)``: positions only.
    """

    n_nodes: int = 300
    fit_iterations: int = 10
    alpha_fit: float = 1.0
    sigma_fit: tuple[float, float] = (0.2, 0.05)
    icp_iterations: int = 20
    alpha_icp: tuple[float, float] = (1.0, 0.05)
    sigma_icp: tuple[float, float] = (0.05, 0.01)
    n_samples: int | None = None
    mu_point: float = 0.1
    mu_plane: float = 1.0
    min_cos: float = 0.3
    feature_weight: tuple[float, float] = (0.0, 0.0)


@dataclass
class RegistrationResult:
    """Outcome of :func:`register`.

    Attributes
    ----------
    deformed : ndarray, shape (n_source, 3)
        Deformed source vertices.
    deformation : GraphDeformation
        Final state (can seed a finer registration).
    residual : float
        Mean two-sided distance between deformed source and target, each distance
        capped at ``cap`` (units of sqrt(source area)); lower is a better fit.
    distortion : float
        Mean link stretch over the mean link length.
    """

    deformed: FloatArray
    deformation: GraphDeformation
    residual: float
    distortion: float
    resume_at: int | None = None
    """With ``stop_after``: the closest-point iteration a ``resume`` call goes on from
    (``None``: the schedule ran to its end)."""
    _tree: PointTree | None = field(default=None, repr=False)
    """The search tree on the deformed source at the stop, carried to the resumed call."""
    _consumed: bool = field(default=False, repr=False)
    """Set when a ``resume`` call has taken the state (it can go on only once)."""


def fit_residual(
    deformed: FloatArray,
    source_faces: IndexArray,
    target_vertices: FloatArray,
    target_normals: FloatArray,
    target_tree: PointTree | cKDTree,
    *,
    scale: float,
    samples: tuple[IndexArray | None, IndexArray | None] = (None, None),
    min_cos: float = 0.3,
    cap: float = 0.05,
) -> float:
    """How well a deformed source covers the target: mean capped two-sided distance.

    Each (sampled) deformed source vertex is paired with its nearest compatible target
    vertex and each (sampled) target vertex with its nearest compatible deformed source
    vertex (see :func:`nearest_compatible`); distances are divided by ``scale`` and
    capped at ``cap``, and the two means are averaged. Lower is a better fit.

    Parameters
    ----------
    deformed : ndarray, shape (n1, 3)
    source_faces : ndarray, shape (f1, 3)
    target_vertices : ndarray, shape (n2, 3)
    target_normals : ndarray, shape (n2, 3)
    target_tree : PointTree or cKDTree
        Built on ``target_vertices``.
    scale : float
        Length unit (the square root of the source's area).
    samples : pair of ndarray or None
        Source and target vertices to use (``None``: all).

    Returns
    -------
    float
    """
    Nd = vertex_normals(deformed, source_faces)
    qs = np.arange(len(deformed)) if samples[0] is None else samples[0]
    qt = np.arange(len(target_vertices)) if samples[1] is None else samples[1]
    _, d1 = nearest_compatible(deformed[qs], Nd[qs], target_tree, target_normals, min_cos=min_cos)
    _, d2 = nearest_compatible(target_vertices[qt], target_normals[qt], _search_tree(deformed), Nd, min_cos=min_cos)
    return 0.5 * (float(np.mean(np.minimum(d1 / scale, cap))) + float(np.mean(np.minimum(d2 / scale, cap))))


def _geometric(a: tuple[float, float], t: float) -> float:
    return float(a[0] * (a[1] / a[0]) ** t) if a[0] > 0 else 0.0


def _checked_features(
    schedule: RegistrationSchedule, features: tuple[FloatArray, FloatArray] | None, n1: int, n2: int
) -> tuple[FloatArray, FloatArray] | None:
    """The features for a schedule with a non-zero ``feature_weight`` (checked), else ``None``."""
    w = schedule.feature_weight
    if not isinstance(w, (tuple, list)) or len(w) != 2 or not all(np.isfinite(x) and x >= 0 for x in w):
        raise ValueError(f"feature_weight must be two finite numbers >= 0, got {schedule.feature_weight!r}")
    if max(w) == 0:
        return None
    if features is None:
        raise ValueError("register: feature_weight > 0 needs features=(source_features, target_features)")
    f1, f2 = (np.asarray(f, dtype=np.float64) for f in features)
    if f1.ndim != 2 or f2.ndim != 2 or f1.shape[0] != n1 or f2.shape[0] != n2 or f1.shape[1] != f2.shape[1]:
        raise ValueError(f"register: features must have shapes ({n1}, d) and ({n2}, d), got {f1.shape} and {f2.shape}")
    if not (np.isfinite(f1).all() and np.isfinite(f2).all()):
        raise ValueError("register: features must be finite")
    return f1, f2


def _checked_surface(surface: IndexArray, samples: IndexArray | None, n: int) -> IndexArray:
    """``register``'s ``surface`` as sorted int64 indices, checked: within the source, holding its samples."""
    out = np.asarray(surface)
    if out.ndim != 1 or out.dtype.kind not in "iu" or len(out) == 0:
        raise ValueError(f"register: surface must be a non-empty 1-d array of vertex indices, got shape {out.shape} and dtype {out.dtype}")
    out = out.astype(np.int64, copy=False)
    if out[0] < 0 or out[-1] >= n or np.any(np.diff(out) <= 0):
        raise ValueError(f"register: surface must be sorted, distinct vertex indices in [0, {n})")
    if samples is None:
        raise ValueError("register: surface needs the source samples (samples or schedule.n_samples)")
    at = np.minimum(np.searchsorted(out, samples), len(out) - 1)
    if not np.array_equal(out[at], samples):
        raise ValueError("register: surface must hold every source sample")
    return out


def register(
    source_vertices: FloatArray,
    source_faces: IndexArray,
    target_vertices: FloatArray,
    target_faces: IndexArray,
    init_pairs: DataPairs | None,
    schedule: RegistrationSchedule = RegistrationSchedule(),
    *,
    graph: DeformationGraph | None = None,
    start: GraphDeformation | FloatArray | None = None,
    samples: tuple[IndexArray, IndexArray] | None = None,
    cap: float = 0.05,
    n_threads: int = 1,
    features: tuple[FloatArray, FloatArray] | None = None,
    stop_after: int | None = None,
    resume: RegistrationResult | None = None,
    surface: IndexArray | None = None,
) -> RegistrationResult:
    """Deform the source onto the target: correspondence fit, then closest-point ICP.

    Parameters
    ----------
    source_vertices : ndarray, shape (n1, 3)
    source_faces : ndarray, shape (f1, 3)
    target_vertices : ndarray, shape (n2, 3)
    target_faces : ndarray, shape (f2, 3)
    init_pairs : DataPairs or None
        Initial correspondences (source vertex -> target point); their weights are the
        prior confidences. ``None`` skips the fitting phase (needs ``start``).
    schedule : RegistrationSchedule
    graph : DeformationGraph, optional
        Built with ``schedule.n_nodes`` nodes when omitted.
    start : GraphDeformation or ndarray of shape (n1, 3), optional
        Initial state on another graph of the same source, or deformed source vertex
        positions; the deformed vertices seed this registration.
    samples : pair of ndarray, optional
        Source and target vertex samples for the closest-point phase; computed by
        farthest-point sampling when ``schedule.n_samples`` is set and they are omitted.
    cap : float
        Distance cap of the residual.
    n_threads : int
        With 2 or more, each closest-point iteration searches both directions side by
        side (for a registration that has the machine to itself; the result is the same).
    features : pair of ndarray, optional
        Per-vertex features of the source, shape (n1, d), and of the target, shape
        (n2, d), for ``schedule.feature_weight > 0`` (required then).
    stop_after : int, optional
        Stop after this many of the schedule's closest-point iterations (the stiffness
        and robust scales as for the whole schedule); the result's residual and
        distortion are those of that state, and its ``resume_at`` says where to go on.
    resume : RegistrationResult, optional
        A result of a call with ``stop_after`` and otherwise the same arguments
        (``init_pairs`` and ``start`` are then ignored): the schedule goes on from
        ``resume.resume_at`` and the result is the one a call without ``stop_after``
        gives, bit for bit. The state of ``resume.deformation`` is consumed.
    surface : ndarray of int, optional
        The source vertices the closest-point iterations deform and search, shape (s,),
        sorted, holding the source samples (which are needed): the backward search pairs
        each target sample with the nearest compatible of these alone, and their normals
        are the rest normals turned by each vertex's blended rotation
        (:meth:`GraphDeformation.turned_normals`). Spares the skinning, normals and search
        tree of the other vertices in every iteration. The fitting phase and the residual
        use every vertex. ``None``: every vertex, with the deformed mesh's normals.

    Returns
    -------
    RegistrationResult
    """
    from topomatch.deform.graph import build_deformation_graph
    from topomatch.mesh.geometry import face_areas
    from topomatch.mesh.sampling import farthest_point_sampling

    V = np.asarray(source_vertices, dtype=np.float64)
    F = np.asarray(source_faces, dtype=np.int64)
    W = np.asarray(target_vertices, dtype=np.float64)
    Nt = vertex_normals(W, np.asarray(target_faces, dtype=np.int64))
    scale = float(np.sqrt(face_areas(V, F).sum()))
    n_icp = schedule.icp_iterations
    if stop_after is not None and (isinstance(stop_after, (bool, np.bool_)) or not isinstance(stop_after, (int, np.integer)) or not 0 <= stop_after <= n_icp):
        raise ValueError(f"register: stop_after must be an integer in [0, {n_icp}] (the schedule's closest-point iterations), got {stop_after!r}")
    first_it = 0
    if resume is not None:  # the stopped registration's state goes on (init_pairs and start were used by it)
        if resume.resume_at is None:
            raise ValueError("register: resume must be the result of a call with stop_after")
        if resume._consumed:
            raise ValueError("register: this stopped registration has already been resumed (its state goes on only once)")
        D = resume.deformation
        if D.vertices.shape != V.shape or (graph is not None and D.graph is not graph):
            raise ValueError("register: resume comes from a registration of another source or graph")
        resume._consumed = True
        graph = D.graph
        first_it = int(resume.resume_at)
    else:
        if graph is None:
            graph = build_deformation_graph(V, F, schedule.n_nodes)
        D = GraphDeformation(V, F, graph)
        if start is not None:
            cur = start.deformed() if isinstance(start, GraphDeformation) else np.asarray(start, dtype=np.float64)
            if cur.shape != V.shape:
                raise ValueError(f"start positions have shape {cur.shape}, the source has {V.shape}")
            every = DataPairs(np.arange(len(V)), cur, np.zeros_like(cur), np.ones(len(V)))
            D.init_from_pairs(every)
            D.update_rotations(every)
        if init_pairs is not None and schedule.fit_iterations > 0:
            prior = init_pairs.weights
            if start is None:
                D.init_from_pairs(init_pairs)
            pairs = init_pairs
            for it in range(schedule.fit_iterations):
                t = it / max(schedule.fit_iterations - 1, 1)
                D.update_rotations(pairs)
                D.update_positions(pairs, alpha=schedule.alpha_fit)
                sig = scale * _geometric(schedule.sigma_fit, t)
                r2 = np.sum((D.deformed()[init_pairs.source] - init_pairs.points) ** 2, axis=1)
                pairs = DataPairs(init_pairs.source, init_pairs.points, init_pairs.normals, prior / (1.0 + r2 / sig**2))
        elif start is None and init_pairs is None:
            raise ValueError("register needs init_pairs or a start state")
    src_s = tgt_s = None
    if samples is not None:
        src_s, tgt_s = (np.asarray(x, dtype=np.int64) for x in samples)
    elif schedule.n_samples is not None:
        src_s = farthest_point_sampling(min(schedule.n_samples, len(V)), points=V, first=0)
        tgt_s = farthest_point_sampling(min(schedule.n_samples, len(W)), points=W, first=0)
    src_local = src_s
    rest_normals: FloatArray | None = None
    if surface is not None:
        surface = _checked_surface(surface, src_s, len(V))
        src_local = np.searchsorted(surface, src_s)
        rest_normals = vertex_normals(V, F)
    tree = _search_tree(W)
    stree: PointTree | None = None if resume is None else resume._tree  # on the deformed source (its surface)
    feats = _checked_features(schedule, features, len(V), len(W))
    if feats is not None and (stop_after is not None or resume is not None or surface is not None):
        raise ValueError("register: stop_after, resume and surface are for registrations without features")
    joint: tuple[float, FloatArray, JointTree] | None = None  # (weight, target's joint points, their tree)
    jtree: JointTree | None = None  # on the deformed source's joint points
    last_it = n_icp if stop_after is None else max(int(stop_after), first_it)
    with ThreadPoolExecutor(max_workers=1) if n_threads > 1 else contextlib.nullcontext() as pool:
        for it in range(first_it, last_it):
            t = it / max(n_icp - 1, 1)
            if surface is None:
                Vd = D.deformed()
                Nd = vertex_normals(Vd, F)
            else:
                Vd = D._skinned(surface, with_positions=True)
                Nd = D.turned_normals(rest_normals, surface)
            sigma = scale * _geometric(schedule.sigma_icp, t)
            if feats is not None:
                w = scale * (schedule.feature_weight[0] + (schedule.feature_weight[1] - schedule.feature_weight[0]) * t)
                # both joint trees are refitted between rebuilds, as the source's tree is
                # below: the same answers (exact searches), a fraction of the cost
                rebuild = it % _REBUILD_EVERY == 0
                if joint is None or joint[0] != w:  # the target's points change only with the weight
                    points = np.c_[W, w * feats[1]]
                    joint = (w, points, JointTree(points) if joint is None or rebuild else joint[2].refit(points))
                sf = w * feats[0]
                sj = np.c_[Vd, sf]
                jtree = JointTree(sj) if jtree is None or rebuild else jtree.refit(sj)
                pairs = feature_pairs(
                    Vd, Nd, W, Nt, sf, joint[1], joint[2], sigma=sigma, min_cos=schedule.min_cos, pool=pool, source_tree=jtree,
                )
            else:
                # a refitted tree answers exactly but slows as the source moves: rebuilt every few iterations
                stree = _search_tree(Vd) if stree is None or it % _REBUILD_EVERY == 0 else stree.refit(Vd)
                pairs = closest_pairs(
                    Vd, Nd, W, Nt, tree, sigma=sigma, min_cos=schedule.min_cos,
                    source_subset=src_local, target_subset=tgt_s, pool=pool, source_tree=stree,
                )
                if surface is not None:  # the surface's own indices back to the source's
                    pairs = DataPairs(surface[pairs.source], pairs.points, pairs.normals, pairs.weights)
            D.update_rotations(pairs)
            D.update_positions(pairs, alpha=_geometric(schedule.alpha_icp, t), mu_point=schedule.mu_point, mu_plane=schedule.mu_plane)
    Vd = D.deformed()
    residual = fit_residual(Vd, F, W, Nt, tree, scale=scale, samples=(src_s, tgt_s), min_cos=schedule.min_cos, cap=cap)
    distortion = float(np.mean(D.link_stretch())) / graph.spacing
    if last_it < n_icp:
        return RegistrationResult(Vd, D, residual, distortion, resume_at=last_it, _tree=stree)
    return RegistrationResult(Vd, D, residual, distortion)
