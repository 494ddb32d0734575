"""A classification forest for thousands of classes, compiled with numba.

scikit-learn stores a dense ``n_nodes x n_classes`` float64 table per tree, which at
12,000 classes and ~150,000 samples is ~9 GB per tree (``reference/dependencies.md``
§7). Here a leaf stores only the labels of the training samples that reached it, so a
tree costs a few bytes per node and per sample, and predictions are sparse label
distributions.

Trees are grown depth-first. At each node ``n_tests`` binary tests with random
parameters are drawn and the one with the largest information gain (Shannon entropy of
the label histogram) is kept, with the threshold chosen by a sweep over the sorted
feature values. A test reads one feature column ``F[:, a]`` or the difference of two,
``F[:, a] - F[:, b]`` (the "random parametrisation" of Rodolà et al. 2014). A node
becomes a leaf when it has fewer than ``min_samples_split`` samples, a single label,
``max_depth`` is reached, or no test separates it.

Randomness comes from a splitmix64 generator inside the compiled code, seeded per tree
from the caller's ``numpy.random.Generator``: results are reproducible bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import sparse

from topomatch.typing import FloatArray

__all__ = ["Forest", "grow_tree", "predict_distributions"]

_MASK64 = np.uint64(0xFFFFFFFFFFFFFFFF)


@numba.njit(cache=True, nogil=True)
def _next(state):  # pragma: no cover - compiled
    """splitmix64: advance ``state[0]`` and return a uint64."""
    state[0] = state[0] + np.uint64(0x9E3779B97F4A7C15)
    z = state[0]
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, nogil=True)
def _randint(state, n):  # pragma: no cover - compiled
    return np.int64(_next(state) % np.uint64(n))


@numba.njit(cache=True, nogil=True)
def _uniform(state):  # pragma: no cover - compiled
    return (_next(state) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, nogil=True)
def _grow(F, y, idx, n_classes, n_tests, p_pair, min_samples_split, min_samples_leaf, max_depth, seed):  # pragma: no cover - compiled
    n = idx.shape[0]
    n_feat = F.shape[1]
    max_nodes = 2 * n + 1
    feat_a = np.full(max_nodes, -1, np.int32)
    feat_b = np.full(max_nodes, -1, np.int32)
    thr = np.zeros(max_nodes, np.float32)
    left = np.full(max_nodes, -1, np.int32)
    right = np.full(max_nodes, -1, np.int32)
    leaf_start = np.zeros(max_nodes, np.int64)
    leaf_end = np.zeros(max_nodes, np.int64)
    state = np.zeros(1, np.uint64)
    state[0] = np.uint64(seed)
    # c log c table (a label occurs at most a few dozen times in a node)
    max_count = 1
    cnt_all = np.zeros(n_classes, np.int64)
    for i in range(n):
        cnt_all[y[idx[i]]] += 1
        if cnt_all[y[idx[i]]] > max_count:
            max_count = cnt_all[y[idx[i]]]
    xlogx = np.zeros(max_count + 2)
    for c in range(1, max_count + 2):
        xlogx[c] = c * np.log(c)
    cnt_all[:] = 0
    cnt_left = np.zeros(n_classes, np.int64)
    vals = np.empty(n, np.float32)
    best_vals = np.empty(n, np.float32)
    # stack of (node, start, end, depth)
    stack_node = np.empty(max_nodes, np.int64)
    stack_start = np.empty(max_nodes, np.int64)
    stack_end = np.empty(max_nodes, np.int64)
    stack_depth = np.empty(max_nodes, np.int64)
    sp = 0
    stack_node[0] = 0
    stack_start[0] = 0
    stack_end[0] = n
    stack_depth[0] = 0
    sp = 1
    n_nodes = 1
    while sp > 0:
        sp -= 1
        node = stack_node[sp]
        s = stack_start[sp]
        e = stack_end[sp]
        depth = stack_depth[sp]
        m = e - s
        # label histogram of the node
        s_node = 0.0
        n_labels = 0
        for i in range(s, e):
            c = y[idx[i]]
            if cnt_all[c] == 0:
                n_labels += 1
            cnt_all[c] += 1
        for i in range(s, e):
            c = y[idx[i]]
            if cnt_all[c] > 0:
                s_node += xlogx[cnt_all[c]]
                cnt_all[c] = -cnt_all[c]  # mark as counted
        for i in range(s, e):
            c = y[idx[i]]
            if cnt_all[c] < 0:
                cnt_all[c] = -cnt_all[c]
        best_obj = m * np.log(m) - s_node - 1e-9 * m
        best_a = -1
        best_b = -1
        best_thr = np.float32(0.0)
        if m >= min_samples_split and n_labels > 1 and depth < max_depth:
            for _t in range(n_tests):
                a = _randint(state, n_feat)
                b = -1
                if _uniform(state) < p_pair:
                    b = _randint(state, n_feat)
                    if b == a:
                        b = -1
                for i in range(s, e):
                    v = F[idx[i], a]
                    if b >= 0:
                        v = v - F[idx[i], b]
                    vals[i - s] = v
                order = np.argsort(vals[:m], kind="quicksort")
                s_l = 0.0
                s_r = s_node
                for r in range(m - 1):
                    c = y[idx[s + order[r]]]
                    cl = cnt_left[c]
                    cr = cnt_all[c] - cl
                    s_l += xlogx[cl + 1] - xlogx[cl]
                    s_r += xlogx[cr - 1] - xlogx[cr]
                    cnt_left[c] = cl + 1
                    nl = r + 1
                    nr = m - nl
                    if nl < min_samples_leaf or nr < min_samples_leaf:
                        continue
                    v0 = vals[order[r]]
                    v1 = vals[order[r + 1]]
                    if v1 <= v0:
                        continue
                    obj = nl * np.log(nl) - s_l + nr * np.log(nr) - s_r
                    if obj < best_obj:
                        best_obj = obj
                        best_a = a
                        best_b = b
                        best_thr = np.float32(0.5 * (v0 + v1))
                        if best_thr >= v1 or best_thr < v0:
                            best_thr = v0
                for i in range(s, e):
                    cnt_left[y[idx[i]]] = 0
        for i in range(s, e):
            cnt_all[y[idx[i]]] = 0
        if best_a < 0:
            leaf_start[node] = s
            leaf_end[node] = e
            continue
        # partition idx[s:e] by the chosen test
        for i in range(s, e):
            v = F[idx[i], best_a]
            if best_b >= 0:
                v = v - F[idx[i], best_b]
            best_vals[i - s] = v
        lo = s
        hi = e - 1
        while lo <= hi:
            if best_vals[lo - s] <= best_thr:
                lo += 1
            else:
                tmp = idx[lo]
                idx[lo] = idx[hi]
                idx[hi] = tmp
                tv = best_vals[lo - s]
                best_vals[lo - s] = best_vals[hi - s]
                best_vals[hi - s] = tv
                hi -= 1
        if lo in (s, e):  # numerically degenerate: make a leaf
            leaf_start[node] = s
            leaf_end[node] = e
            continue
        feat_a[node] = best_a
        feat_b[node] = best_b
        thr[node] = best_thr
        left[node] = n_nodes
        right[node] = n_nodes + 1
        stack_node[sp] = n_nodes + 1
        stack_start[sp] = lo
        stack_end[sp] = e
        stack_depth[sp] = depth + 1
        sp += 1
        stack_node[sp] = n_nodes
        stack_start[sp] = s
        stack_end[sp] = lo
        stack_depth[sp] = depth + 1
        sp += 1
        n_nodes += 2
    return feat_a[:n_nodes], feat_b[:n_nodes], thr[:n_nodes], left[:n_nodes], right[:n_nodes], leaf_start[:n_nodes], leaf_end[:n_nodes]


@numba.njit(cache=True, nogil=True)
def _apply(F, feat_a, feat_b, thr, left, right):  # pragma: no cover - compiled
    n = F.shape[0]
    out = np.empty(n, np.int64)
    for i in range(n):
        node = 0
        while left[node] >= 0:
            v = F[i, feat_a[node]]
            if feat_b[node] >= 0:
                v = v - F[i, feat_b[node]]
            node = left[node] if v <= thr[node] else right[node]
        out[i] = node
    return out


@dataclass
class Tree:
    """One grown tree: node arrays plus the labels stored in its leaves.

    ``leaf_start / leaf_end`` index ``labels`` for leaves (``left == -1``).
    """

    feat_a: np.ndarray
    feat_b: np.ndarray
    thr: np.ndarray
    left: np.ndarray
    right: np.ndarray
    leaf_start: np.ndarray
    leaf_end: np.ndarray
    labels: np.ndarray

    @property
    def n_nodes(self) -> int:
        """Number of nodes."""
        return len(self.left)


def grow_tree(
    F: FloatArray,
    y: np.ndarray,
    n_classes: int,
    *,
    n_tests: int,
    p_pair: float,
    min_samples_split: int,
    min_samples_leaf: int,
    max_depth: int,
    seed: int,
    sample: np.ndarray | None = None,
) -> Tree:
    """Grow one tree.

    Parameters
    ----------
    F : ndarray, shape (n_samples, n_features), float32
    y : ndarray, shape (n_samples,), int
        Labels in ``[0, n_classes)``.
    n_classes : int
    n_tests : int
        Random tests tried per node.
    p_pair : float
        Probability that a test is a difference of two features.
    min_samples_split, min_samples_leaf, max_depth : int
    seed : int
        Seeds the tree's generator.
    sample : ndarray of int, optional
        Training rows used by this tree (default all).

    Returns
    -------
    Tree
    """
    F32 = np.ascontiguousarray(F, dtype=np.float32)
    y32 = np.ascontiguousarray(y, dtype=np.int64)
    idx = np.arange(len(y32), dtype=np.int64) if sample is None else np.array(sample, dtype=np.int64)
    a, b, t, lft, rgt, ls, le = _grow(
        F32, y32, idx, int(n_classes), int(n_tests), float(p_pair), int(min_samples_split), int(min_samples_leaf), int(max_depth), int(seed) & 0xFFFFFFFFFFFFFFFF
    )
    labels = y32[idx].astype(np.int32)
    return Tree(a, b, t, lft, rgt, ls, le, labels)


@dataclass
class Forest:
    """Trees plus the number of classes."""

    trees: list[Tree]
    n_classes: int

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat arrays for ``np.savez`` (see :meth:`from_arrays`)."""
        out: dict[str, np.ndarray] = {"n_classes": np.array(self.n_classes)}
        out["node_offsets"] = np.cumsum([0] + [t.n_nodes for t in self.trees]).astype(np.int64)
        out["label_offsets"] = np.cumsum([0] + [len(t.labels) for t in self.trees]).astype(np.int64)
        for f in ("feat_a", "feat_b", "thr", "left", "right", "leaf_start", "leaf_end", "labels"):
            out[f] = np.concatenate([getattr(t, f) for t in self.trees])
        return out

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> Forest:
        """Inverse of :meth:`to_arrays`."""
        no, lo = d["node_offsets"], d["label_offsets"]
        trees = []
        for i in range(len(no) - 1):
            a, b = int(no[i]), int(no[i + 1])
            c, e = int(lo[i]), int(lo[i + 1])
            trees.append(
                Tree(*(np.ascontiguousarray(d[f][a:b]) for f in ("feat_a", "feat_b", "thr", "left", "right", "leaf_start", "leaf_end")), np.ascontiguousarray(d["labels"][c:e]))
            )
        return cls(trees, int(d["n_classes"]))


def predict_distributions(forest: Forest, F: FloatArray) -> sparse.csr_matrix:
    """Average leaf label distribution over the trees for each sample.

    Parameters
    ----------
    forest : Forest
    F : ndarray, shape (n, n_features)

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n, n_classes)
        Rows sum to 1.
    """
    F32 = np.ascontiguousarray(F, dtype=np.float32)
    n = len(F32)
    rows, cols, vals = [], [], []
    w_tree = 1.0 / len(forest.trees)
    for t in forest.trees:
        leaf = _apply(F32, t.feat_a, t.feat_b, t.thr, t.left, t.right)
        start, end = t.leaf_start[leaf], t.leaf_end[leaf]
        size = end - start
        r = np.repeat(np.arange(n), size)
        offs = np.arange(int(size.sum())) - np.repeat(np.cumsum(size) - size, size)
        pos = np.repeat(start, size) + offs
        rows.append(r)
        cols.append(t.labels[pos])
        vals.append(np.repeat(w_tree / size, size))
    P = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, forest.n_classes))
    P.sum_duplicates()
    return P
