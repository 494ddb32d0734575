"""k-d trees for the registration's searches (numba): 3-D nearest compatible points, and any dimension.

Every closest-point iteration of :func:`topomatch.deform.register.register`, every limb
turn tried by :func:`topomatch.matching.deform.turn_limb` and every fit residual asks
the same question: for each query point, the nearest reference point whose normal
agrees with the query's (among its ``k`` nearest; the nearest when none agrees).
:class:`PointTree` answers it in one compiled depth-first search per query (since
session 35; before, a second ``k``-nearest search followed for the queries whose nearest
point disagrees, about 30 % of a registration's), without holding the GIL, so the
registrations that run on threads search side by side. Queries that come in no spatial
order (farthest-point samples) are searched cell by cell (:func:`_query_order`, about 7 %
faster; session 58). The answers are exact and equal to a brute-force search's (the registration's maps were unchanged against scipy's
``cKDTree``, and again by the one-search form). On the queries of one ``deform`` match
(kid00 -> kid13, one thread, every tenth query, ``benchmarks/bench_kdtree.py``) they
took 0.128 s against 0.387 s for ``cKDTree`` (x3.0; the two-search form: 0.203 s, x1.9;
all 444,651 answers equal); building is slower (about 1.1 ms against 0.8 ms at 10K
points), which the registration avoids by refitting.

A tree built on one set of positions answers exactly for moved positions of the same
points after :meth:`PointTree.refit` (only the boxes are recomputed, O(n)), which the
registration uses for the deformed source between closest-point iterations.

:class:`JointTree` is the same structure for points of any dimension with plain
nearest-point queries: the feature stage's searches in ``[position, scaled feature]``
(8 dimensions), where both point sets change every iteration. Refitted between
rebuilds, it replaced two scipy ``cKDTree`` builds and queries per iteration with the
same answers (the training pairs' maps were identical): at 60K vertices a ``deform``
match took 27.3 s instead of 35.8 s (``benchmarks/bench_flagship.py``, two pairs);
``benchmarks/bench_jointtree.py`` times the searches alone. Its search is compiled once per
dimension (:func:`_nearest_kernel`; session 59): the same answers in 0.86-0.92 of the time.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numba
import numpy as np

from topomatch.typing import FloatArray, IndexArray

__all__ = ["JointTree", "PointTree"]

_LEAF_SIZE = 12


@numba.njit(cache=True, nogil=True)
def _select(P, perm, keys, left, right, k, dim):  # pragma: no cover - compiled
    """Reorder ``perm[left:right+1]`` so that ``perm[k]`` holds the k-th smallest ``P[:, dim]`` (Hoare)."""
    for i in range(left, right + 1):
        keys[i] = P[perm[i], dim]
    while right > left:
        pivot = keys[(left + right) // 2]
        i, j = left, right
        while i <= j:
            while keys[i] < pivot:
                i += 1
            while keys[j] > pivot:
                j -= 1
            if i <= j:
                t = perm[i]
                perm[i] = perm[j]
                perm[j] = t
                tk = keys[i]
                keys[i] = keys[j]
                keys[j] = tk
                i += 1
                j -= 1
        if k <= j:
            right = j
        elif k >= i:
            left = i
        else:
            return


@numba.njit(cache=True, nogil=True)
def _refit(P, perm, lo, hi, left, bmin, bmax):  # pragma: no cover - compiled
    """Tight boxes of every node for positions ``P`` (any dimension); children have larger indices than parents."""
    dims = P.shape[1]
    for node in range(len(lo) - 1, -1, -1):
        if left[node] < 0:
            for d in range(dims):
                mn = np.inf
                mx = -np.inf
                for i in range(lo[node], hi[node]):
                    v = P[perm[i], d]
                    mn = min(mn, v)
                    mx = max(mx, v)
                bmin[node, d] = mn
                bmax[node, d] = mx
        else:
            a = left[node]
            for d in range(dims):
                bmin[node, d] = min(bmin[a, d], bmin[a + 1, d])
                bmax[node, d] = max(bmax[a, d], bmax[a + 1, d])


@numba.njit(cache=True, nogil=True)
def _build(P, leaf):  # pragma: no cover - compiled
    """Median splits along the widest side of each node's (loose) box; tight boxes at the end (any dimension)."""
    n, dims = P.shape
    perm = np.arange(n)
    max_nodes = 2 * (n // max(leaf // 2, 1) + 1) + 1
    lo = np.empty(max_nodes, np.int64)
    hi = np.empty(max_nodes, np.int64)
    left = np.full(max_nodes, -1, np.int64)
    bmin = np.empty((max_nodes, dims))
    bmax = np.empty((max_nodes, dims))
    stack = np.empty(max_nodes, np.int64)
    keys = np.empty(n)
    for d in range(dims):
        bmin[0, d] = P[:, d].min()
        bmax[0, d] = P[:, d].max()
    lo[0] = 0
    hi[0] = n
    n_nodes = 1
    sp = 1
    stack[0] = 0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        a, b = lo[node], hi[node]
        if b - a <= leaf:
            continue
        dim = 0
        for d in range(1, dims):
            if bmax[node, d] - bmin[node, d] > bmax[node, dim] - bmin[node, dim]:
                dim = d
        mid = (a + b) // 2
        _select(P, perm, keys, a, b - 1, mid, dim)
        cut = P[perm[mid], dim]
        c = n_nodes
        n_nodes += 2
        lo[c], hi[c], lo[c + 1], hi[c + 1] = a, mid, mid, b
        left[node] = c
        for d in range(dims):
            bmin[c, d] = bmin[node, d]
            bmax[c, d] = bmax[node, d]
            bmin[c + 1, d] = bmin[node, d]
            bmax[c + 1, d] = bmax[node, d]
        bmax[c, dim] = cut
        bmin[c + 1, dim] = cut
        stack[sp] = c + 1
        stack[sp + 1] = c
        sp += 2
    lo, hi, left = lo[:n_nodes].copy(), hi[:n_nodes].copy(), left[:n_nodes].copy()
    bmin, bmax = bmin[:n_nodes].copy(), bmax[:n_nodes].copy()
    _refit(P, perm, lo, hi, left, bmin, bmax)
    return perm, lo, hi, left, bmin, bmax


@numba.njit(inline="always")
def _box_d2_3(qx, qy, qz, bmin, bmax, node):  # pragma: no cover - compiled
    """Squared distance from ``(qx, qy, qz)`` to the box of ``node`` (0 inside)."""
    t0 = max(bmin[node, 0] - qx, qx - bmax[node, 0], 0.0)
    t1 = max(bmin[node, 1] - qy, qy - bmax[node, 1], 0.0)
    t2 = max(bmin[node, 2] - qz, qz - bmax[node, 2], 0.0)
    return t0 * t0 + t1 * t1 + t2 * t2


@numba.njit(cache=True, nogil=True)
def _query_order(Q):  # pragma: no cover - compiled
    """An order in which to search the query points: cell by cell (an 8 x 8 x 8 grid on their box, cells in Morton order).

    Successive searches then walk the same part of the tree: about 7 % faster for
    farthest-point samples, which come in no spatial order (``kid00`` -> ``kid05``, 1,500
    samples each way). Queries whose successive points lie closer than a cell on
    average (a mesh's vertices in their own order) keep their order. The answers do not
    depend on the order in which the queries are searched. Counting sort, O(q).
    """
    n = Q.shape[0]
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    step = 0.0
    for i in range(n):
        for c in range(3):
            lo[c] = min(lo[c], Q[i, c])
            hi[c] = max(hi[c], Q[i, c])
            if i > 0:
                step += abs(Q[i, c] - Q[i - 1, c])
    span = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
    if not step < np.inf or step <= (n - 1) * span / 8.0:
        return np.arange(n)
    scale = 8.0 / span
    keys = np.empty(n, np.int64)
    count = np.zeros(513, np.int64)
    for i in range(n):
        key = 0
        for c in range(3):
            cell = min(int((Q[i, c] - lo[c]) * scale), 7)
            for b in range(3):
                key |= ((cell >> b) & 1) << (3 * b + c)
        keys[i] = key
        count[key + 1] += 1
    for c in range(512):
        count[c + 1] += count[c]
    order = np.empty(n, np.int64)
    for i in range(n):
        order[count[keys[i]]] = i
        count[keys[i]] += 1
    return order


@numba.njit(cache=True, nogil=True)
def _nearest_compatible(Ps, perm, lo, hi, left, bmin, bmax, Q, NQ, RN, k, min_cos, out_i, out_d):  # pragma: no cover
    """For each query, the nearest compatible point among its ``k`` nearest (else the nearest), in one search (3-D).

    The two-search formulation (the nearest; when its normal disagrees, the ``k``
    nearest) in one depth-first pass: the pass keeps the nearest compatible point found
    and the ``k`` nearest incompatible ones, and prunes at the nearer of the compatible
    point and the ``k``-th incompatible one (a compatible point beyond ``k`` closer
    incompatible ones is not among the ``k`` nearest). Same answers (up to exact
    distance ties), about two thirds of the time: about 30 % of a registration's
    queries found their nearest point's normal disagreeing and searched twice.
    """
    stack_n = np.empty(2 * len(lo) + 2, np.int64)
    stack_d = np.empty(2 * len(lo) + 2)
    inc_d = np.empty(max(k, 1))
    inc_i = np.empty(max(k, 1), np.int64)
    k = max(k, 1)
    use_normals = k > 1
    order = _query_order(Q)
    for qq in range(Q.shape[0]):
        q = order[qq]
        qx, qy, qz = Q[q, 0], Q[q, 1], Q[q, 2]
        nx = ny = nz = 0.0
        if use_normals:
            nx, ny, nz = NQ[q, 0], NQ[q, 1], NQ[q, 2]
        for j in range(k):
            inc_d[j] = np.inf
            inc_i[j] = -1
        bc_d = np.inf  # the nearest compatible point so far
        bc_i = -1
        bound = np.inf
        stack_n[0] = 0
        stack_d[0] = 0.0
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack_n[sp]
            if stack_d[sp] >= bound:
                continue
            if left[node] < 0:
                for i in range(lo[node], hi[node]):
                    a = Ps[i, 0] - qx
                    b = Ps[i, 1] - qy
                    c = Ps[i, 2] - qz
                    d2 = a * a + b * b + c * c
                    if d2 >= bound:
                        continue
                    p = perm[i]
                    if not use_normals or nx * RN[p, 0] + ny * RN[p, 1] + nz * RN[p, 2] >= min_cos:
                        bc_d = d2
                        bc_i = p
                    else:  # into the sorted k nearest incompatible (equal distances keep the visit order)
                        j = k - 1
                        while j > 0 and inc_d[j - 1] > d2:
                            inc_d[j] = inc_d[j - 1]
                            inc_i[j] = inc_i[j - 1]
                            j -= 1
                        inc_d[j] = d2
                        inc_i[j] = p
                    bound = min(bc_d, inc_d[k - 1])
                continue
            # the children pushed as in _nearest_kernel, written out: a shared inlined helper made
            # this search 28 % slower (0.31 -> 0.40 s on the queries of attempt #102)
            a = left[node]
            da = _box_d2_3(qx, qy, qz, bmin, bmax, a)
            db = _box_d2_3(qx, qy, qz, bmin, bmax, a + 1)
            if da <= db:
                near, d_near, far, d_far = a, da, a + 1, db
            else:
                near, d_near, far, d_far = a + 1, db, a, da
            if d_far < bound:
                stack_n[sp] = far
                stack_d[sp] = d_far
                sp += 1
            if d_near < bound:
                stack_n[sp] = near
                stack_d[sp] = d_near
                sp += 1
        closer = 0  # incompatible points nearer than the compatible one
        for j in range(k):
            if inc_d[j] < bc_d:
                closer += 1
        if bc_i >= 0 and closer < k:
            out_i[q] = bc_i
            out_d[q] = np.sqrt(bc_d)
        else:  # no compatible point among the k nearest: the nearest
            out_i[q] = inc_i[0]
            out_d[q] = np.sqrt(inc_d[0])


@functools.cache
def _nearest_kernel(dims: int) -> Callable[..., None]:
    """The nearest-point search of :class:`JointTree` compiled for ``dims`` dimensions (a constant: the loops unrolled).

    About 0.87 of the time of the same search with the dimension read at run time
    (feature-stage queries of one ``template`` match, 8 dimensions), with the same
    answers: each distance adds its terms in the same order.
    """

    @numba.njit(cache=True, nogil=True)
    def nearest(Ps, perm, lo, hi, left, bmin, bmax, Q, out_i, out_d):  # pragma: no cover - compiled
        stack_n = np.empty(2 * len(lo) + 2, np.int64)
        stack_d = np.empty(2 * len(lo) + 2)
        q = np.empty(dims)
        for qi in range(Q.shape[0]):
            for d in range(dims):
                q[d] = Q[qi, d]
            best = np.inf
            best_i = -1
            stack_n[0] = 0
            stack_d[0] = 0.0
            sp = 1
            while sp > 0:
                sp -= 1
                node = stack_n[sp]
                if stack_d[sp] >= best:
                    continue
                if left[node] < 0:
                    for i in range(lo[node], hi[node]):
                        d2 = 0.0
                        for d in range(dims):
                            t = Ps[i, d] - q[d]
                            d2 += t * t
                        if d2 < best:  # equal distances keep the first visited
                            best = d2
                            best_i = perm[i]
                    continue
                a = left[node]
                da = 0.0
                db = 0.0
                for d in range(dims):
                    t = max(bmin[a, d] - q[d], q[d] - bmax[a, d], 0.0)
                    da += t * t
                for d in range(dims):
                    t = max(bmin[a + 1, d] - q[d], q[d] - bmax[a + 1, d], 0.0)
                    db += t * t
                if da <= db:
                    near, d_near, far, d_far = a, da, a + 1, db
                else:
                    near, d_near, far, d_far = a + 1, db, a, da
                if d_far < best:
                    stack_n[sp] = far
                    stack_d[sp] = d_far
                    sp += 1
                if d_near < best:
                    stack_n[sp] = near
                    stack_d[sp] = d_near
                    sp += 1
            out_i[qi] = best_i
            out_d[qi] = np.sqrt(best)

    return nearest


def _points(x: FloatArray, name: str) -> np.ndarray:
    a = np.ascontiguousarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"PointTree: {name} must have shape (n, 3), got {a.shape}")
    return a


class PointTree:
    """Exact nearest-point queries among fixed-count 3-D points.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Reference points (at least one).

    Attributes
    ----------
    data : ndarray, shape (n, 3)
        The reference points (as of the last :meth:`refit`).
    n : int
    """

    def __init__(self, points: FloatArray) -> None:
        P = _points(points, "points")
        if len(P) == 0:
            raise ValueError("PointTree: no points")
        if not np.isfinite(P).all():
            raise ValueError("PointTree: points must be finite")
        self.data = P
        self.n = len(P)
        self._perm, self._lo, self._hi, self._left, self._bmin, self._bmax = _build(P, _LEAF_SIZE)
        self._sorted = np.ascontiguousarray(P[self._perm])

    def refit(self, points: FloatArray) -> PointTree:
        """Move the reference points (same count and order); the structure is kept.

        Queries stay exact for any positions (only the boxes are recomputed); they slow
        down as the positions drift from those the tree was built on.
        """
        P = _points(points, "points")
        if len(P) != self.n:
            raise ValueError(f"PointTree.refit: expected {self.n} points, got {len(P)}")
        if not np.isfinite(P).all():
            raise ValueError("PointTree: points must be finite")
        self.data = P
        _refit(P, self._perm, self._lo, self._hi, self._left, self._bmin, self._bmax)
        self._sorted = np.ascontiguousarray(P[self._perm])
        return self

    def nearest_compatible(
        self, points: FloatArray, normals: FloatArray, ref_normals: FloatArray, *, k: int = 8, min_cos: float = 0.0
    ) -> tuple[IndexArray, FloatArray]:
        """For each query, the nearest reference point with ``normal . ref_normal >= min_cos``.

        Among the ``k`` nearest reference points the first (nearest) that agrees is taken;
        when none does, or with ``k = 1``, the nearest.

        Parameters
        ----------
        points : ndarray, shape (q, 3)
        normals : ndarray, shape (q, 3)
        ref_normals : ndarray, shape (n, 3)
            Normals of the reference points.
        k : int
        min_cos : float

        Returns
        -------
        index : ndarray, shape (q,)
        distance : ndarray, shape (q,)
        """
        Q = _points(points, "points")
        NQ = _points(normals, "normals")
        RN = _points(ref_normals, "ref_normals")
        if len(NQ) != len(Q) or len(RN) != self.n:
            raise ValueError(f"PointTree: {len(Q)} points need {len(Q)} normals (got {len(NQ)}), and {self.n} reference normals (got {len(RN)})")
        k = int(min(max(int(k), 1), self.n))
        out_i = np.empty(len(Q), dtype=np.int64)
        out_d = np.empty(len(Q), dtype=np.float64)
        _nearest_compatible(self._sorted, self._perm, self._lo, self._hi, self._left, self._bmin, self._bmax, Q, NQ, RN, k, float(min_cos), out_i, out_d)
        return out_i, out_d

    def query(self, points: FloatArray) -> tuple[FloatArray, IndexArray]:
        """Nearest reference point of each query (``cKDTree.query(points, k=1)``'s order).

        Returns
        -------
        distance : ndarray, shape (q,)
        index : ndarray, shape (q,)
        """
        Q = _points(points, "points")
        idx, dist = self.nearest_compatible(Q, np.zeros_like(Q), np.zeros((self.n, 3)), k=1)
        return dist, idx


class JointTree:
    """Exact nearest-point queries among fixed-count points of any dimension.

    The feature stage of the registration pairs points nearest in ``[position,
    scaled feature]`` (:func:`topomatch.deform.register.feature_pairs`); both its
    point sets change every iteration (the source deforms, the feature weight falls), so
    the tree is refitted (boxes recomputed, O(n)) rather than rebuilt, as
    :class:`PointTree` is for positions. Answers are exact for any refitted positions;
    they equal scipy's ``cKDTree.query(points, k=1)`` up to exact ties.

    Parameters
    ----------
    points : ndarray, shape (n, d)
        Reference points (at least one, finite).

    Attributes
    ----------
    data : ndarray, shape (n, d)
        The reference points (as of the last :meth:`refit`).
    n, dim : int
    """

    def __init__(self, points: FloatArray) -> None:
        P = self._checked(points, None)
        if len(P) == 0:
            raise ValueError("JointTree: no points")
        self.data = P
        self.n, self.dim = P.shape
        self._perm, self._lo, self._hi, self._left, self._bmin, self._bmax = _build(P, _LEAF_SIZE)
        self._sorted = np.ascontiguousarray(P[self._perm])

    def _checked(self, points: FloatArray, dim: int | None) -> np.ndarray:
        a = np.ascontiguousarray(points, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] < 1 or (dim is not None and a.shape[1] != dim):
            want = "(n, d)" if dim is None else f"(n, {dim})"
            raise ValueError(f"JointTree: points must have shape {want}, got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError("JointTree: points must be finite")
        return a

    def refit(self, points: FloatArray) -> JointTree:
        """Move the reference points (same count, order and dimension); the structure is kept."""
        P = self._checked(points, self.dim)
        if len(P) != self.n:
            raise ValueError(f"JointTree.refit: expected {self.n} points, got {len(P)}")
        self.data = P
        _refit(P, self._perm, self._lo, self._hi, self._left, self._bmin, self._bmax)
        self._sorted = np.ascontiguousarray(P[self._perm])
        return self

    def query(self, points: FloatArray) -> tuple[FloatArray, IndexArray]:
        """Nearest reference point of each query (``cKDTree.query(points, k=1)``'s order).

        Parameters
        ----------
        points : ndarray, shape (q, d)

        Returns
        -------
        distance : ndarray, shape (q,)
        index : ndarray, shape (q,)
        """
        Q = self._checked(points, self.dim)
        out_i = np.empty(len(Q), dtype=np.int64)
        out_d = np.empty(len(Q), dtype=np.float64)
        _nearest_kernel(self.dim)(self._sorted, self._perm, self._lo, self._hi, self._left, self._bmin, self._bmax, Q, out_i, out_d)
        return out_d, out_i
