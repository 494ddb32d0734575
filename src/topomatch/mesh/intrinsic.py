"""Intrinsic Delaunay triangulation by edge flips (Bobenko & Springborn 2007).

Only edge lengths change: the surface's metric is kept exactly, while the
triangulation becomes Delaunay, so its cotangent Laplacian has non-negative weights.
Used by the heat-method geodesics, whose accuracy on the (very obtuse) TOPKIDS meshes
depends on it.
"""

from __future__ import annotations

import math

import numpy as np

from topomatch.typing import FloatArray, IndexArray

__all__ = ["intrinsic_delaunay", "intrinsic_gradient_operator"]


def intrinsic_delaunay(vertices: FloatArray, faces: IndexArray, *, max_flips: int | None = None) -> tuple[IndexArray, FloatArray, int]:
    """Flip edges until the intrinsic triangulation is Delaunay.

    Edges shared by exactly two consistently oriented faces are flippable; boundary,
    non-manifold and inconsistently oriented edges are kept (treated as boundary).

    Parameters
    ----------
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
    max_flips : int, optional
        Safety cap (default ``50 * n_faces``).

    Returns
    -------
    faces : ndarray, shape (n_faces, 3)
        Intrinsic triangles (vertex indices; a triangle may repeat a vertex in rare
        Delta-complex configurations).
    lengths : ndarray, shape (n_faces, 3)
        ``lengths[f, c]`` is the length of the edge opposite corner ``c`` of face ``f``.
    n_flips : int
        Number of flips performed.

    References
    ----------
    A. Bobenko, B. Springborn, "A Discrete Laplace-Beltrami Operator for Simplicial
    Surfaces", Discrete Comput. Geom. 2007.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    nf = len(F)
    # halfedge h = 3 f + c goes from corner c to corner c+1 of face f; next(h) = 3f + (c+1)%3
    tail = F.reshape(-1)
    head = F[:, [1, 2, 0]].reshape(-1)
    hl = np.linalg.norm(V[head] - V[tail], axis=1)
    # twins: pair (a->b) with (b->a) when the undirected edge has exactly these two halfedges
    key_u = np.minimum(tail, head)
    key_v = np.maximum(tail, head)
    order = np.lexsort((key_v, key_u))
    ku, kv = key_u[order], key_v[order]
    starts = np.flatnonzero(np.r_[True, (ku[1:] != ku[:-1]) | (kv[1:] != kv[:-1])])
    counts = np.diff(np.r_[starts, len(order)])
    twin = np.full(3 * nf, -1, dtype=np.int64)
    two = starts[counts == 2]
    h1, h2 = order[two], order[two + 1]
    ok = (tail[h1] == head[h2]) & (head[h1] == tail[h2]) & (tail[h1] != head[h1])
    twin[h1[ok]] = h2[ok]
    twin[h2[ok]] = h1[ok]

    tl = tail.tolist()
    ln = hl.tolist()
    tw = twin.tolist()
    cap = 50 * nf if max_flips is None else max_flips

    def nxt(h: int) -> int:
        return h - h % 3 + (h + 1) % 3

    def cot_opposite(h: int) -> float:
        # cotangent of the angle opposite halfedge h in its face
        a = ln[h]
        b = ln[nxt(h)]
        c = ln[nxt(nxt(h))]
        s = 0.5 * (a + b + c)
        area2 = s * (s - a) * (s - b) * (s - c)
        if area2 <= 0.0:
            return -1e30 if a * a > b * b + c * c else 1e30
        return (b * b + c * c - a * a) / (4.0 * math.sqrt(area2))

    stack = [h for h in range(3 * nf) if tw[h] > h]
    in_stack = [False] * (3 * nf)
    for h in stack:
        in_stack[h] = True
    n_flips = 0
    while stack and n_flips < cap:
        h = stack.pop()
        in_stack[h] = False
        t = tw[h]
        if t < 0:
            continue
        if cot_opposite(h) + cot_opposite(t) >= -1e-12:
            continue
        # face f: h (a->b), h1 (b->c), h2 (c->a); face g: t (b->a), t1 (a->d), t2 (d->b)
        h1, h2 = nxt(h), nxt(nxt(h))
        t1, t2 = nxt(t), nxt(nxt(t))
        a, b, c, d = tl[h], tl[h1], tl[h2], tl[t2]
        if c == d:
            continue
        lab, lbc, lca, lad, ldb = ln[h], ln[h1], ln[h2], ln[t1], ln[t2]
        # lay out a=(0,0), b=(lab,0); c above, d below
        cx = (lab * lab + lca * lca - lbc * lbc) / (2.0 * lab)
        cy = math.sqrt(max(lca * lca - cx * cx, 0.0))
        dx = (lab * lab + lad * lad - ldb * ldb) / (2.0 * lab)
        dy = -math.sqrt(max(lad * lad - dx * dx, 0.0))
        lcd = math.hypot(cx - dx, cy - dy)
        fb, gb = h - h % 3, t - t % 3
        # records (tail, length, twin) of the surviving outer halfedges
        rec_ca = (c, lca, tw[h2])
        rec_ad = (a, lad, tw[t1])
        rec_db = (d, ldb, tw[t2])
        rec_bc = (b, lbc, tw[h1])
        # new f: (c->a), (a->d), (d->c); new g: (d->b), (b->c), (c->d)
        new = [(fb, rec_ca), (fb + 1, rec_ad), (gb, rec_db), (gb + 1, rec_bc)]
        for slot, (tv, lv, twv) in new:
            tl[slot], ln[slot], tw[slot] = tv, lv, twv
            if twv >= 0:
                tw[twv] = slot
        tl[fb + 2], ln[fb + 2], tw[fb + 2] = d, lcd, gb + 2
        tl[gb + 2], ln[gb + 2], tw[gb + 2] = c, lcd, fb + 2
        n_flips += 1
        for s in (fb, fb + 1, gb, gb + 1):
            e = s if tw[s] < 0 or s < tw[s] else tw[s]
            if tw[e] >= 0 and not in_stack[e]:
                in_stack[e] = True
                stack.append(e)
    faces_id = np.asarray(tl, dtype=np.int64).reshape(nf, 3)
    L = np.asarray(ln).reshape(nf, 3)  # L[f, c] = length of halfedge from corner c to c+1
    lengths = L[:, [1, 2, 0]]  # edge opposite corner c is the halfedge from corner c+1
    return faces_id, lengths, n_flips


def intrinsic_gradient_operator(faces: IndexArray, lengths: FloatArray, n_vertices: int):
    """Per-face gradient on an intrinsic triangulation, in each face's own 2D frame.

    Parameters
    ----------
    faces : ndarray, shape (n_faces, 3)
    lengths : ndarray, shape (n_faces, 3)
        Length of the edge opposite each corner.
    n_vertices : int

    Returns
    -------
    G : scipy.sparse.csr_matrix, shape (2 * n_faces, n_vertices)
        Row ``2 f + d`` is component ``d`` of the gradient on face ``f``.
    areas : ndarray, shape (n_faces,)
        Face areas (zero for degenerate faces, whose rows are zero).
    """
    from scipy import sparse

    l0, l1, l2 = lengths[:, 0], lengths[:, 1], lengths[:, 2]
    # corner 0 at origin, corner 1 on the x axis: |p1 - p0| = l2, |p2 - p0| = l1, |p2 - p1| = l0
    x2 = (l2 * l2 + l1 * l1 - l0 * l0) / (2.0 * np.where(l2 > 0, l2, 1.0))
    y2 = np.sqrt(np.maximum(l1 * l1 - x2 * x2, 0.0))
    area = 0.5 * l2 * y2
    ok = area > 1e-14 * max(float(area.max(initial=0.0)), 1e-300)
    P = np.zeros((len(faces), 3, 2))
    P[:, 1, 0] = l2
    P[:, 2, 0] = x2
    P[:, 2, 1] = y2
    rows, cols, vals = [], [], []
    fidx = np.arange(len(faces))
    inv2a = np.where(ok, 1.0 / np.where(ok, 2.0 * area, 1.0), 0.0)
    for k in range(3):
        e = P[:, (k + 2) % 3] - P[:, (k + 1) % 3]  # edge opposite corner k (counter-clockwise)
        g = np.stack([-e[:, 1], e[:, 0]], axis=1) * inv2a[:, None]  # rotate by +90 degrees
        for d in range(2):
            rows.append(2 * fidx + d)
            cols.append(faces[:, k])
            vals.append(g[:, d])
    G = sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(2 * len(faces), n_vertices),
    )
    return G, np.where(ok, area, 0.0)
