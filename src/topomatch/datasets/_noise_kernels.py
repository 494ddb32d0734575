"""Numba kernels of the topological-noise generator: closest points and quadric decimation."""

from __future__ import annotations

import numba
import numpy as np

# Closest-point feature codes (where on the triangle the closest point lies).
FACE, VERT_A, VERT_B, VERT_C, EDGE_AB, EDGE_BC, EDGE_CA = 0, 1, 2, 3, 4, 5, 6


@numba.njit(cache=True)
def _closest_on_triangle(px, py, pz, a, b, c):  # pragma: no cover - compiled
    """Closest point of triangle (a, b, c) to p: returns (u, v, w, feature) with p* = u a + v b + w c.

    Voronoi-region walk over the vertices, edges and interior of the triangle.
    """
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    apx, apy, apz = px - a[0], py - a[1], pz - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0, VERT_A
    bpx, bpy, bpz = px - b[0], py - b[1], pz - b[2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0, VERT_B
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        return 1.0 - t, t, 0.0, EDGE_AB
    cpx, cpy, cpz = px - c[0], py - c[1], pz - c[2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0, VERT_C
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        return 1.0 - t, 0.0, t, EDGE_CA
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - t, t, EDGE_BC
    s = va + vb + vc
    if s <= 0.0:  # degenerate triangle: fall back to its first corner
        return 1.0, 0.0, 0.0, VERT_A
    v = vb / s
    w = vc / s
    return 1.0 - v - w, v, w, FACE


@numba.njit(cache=True)
def closest_points(points, vertices, faces, knn, vf_ptr, vf_idx, out_face, out_bary, out_d2, out_feat):  # pragma: no cover
    """Closest mesh point for each query among the faces around its nearest vertices.

    points : (Q, 3); vertices : (n, 3); faces : (m, 3) int64; knn : (Q, k) nearest
    vertex ids; vf_ptr, vf_idx : vertex -> incident faces (CSR). Outputs: out_face (Q,)
    int64, out_bary (Q, 3), out_d2 (Q,) squared distance, out_feat (Q,) int8 feature code.
    """
    nq = points.shape[0]
    k = knn.shape[1]
    for q in range(nq):
        px = points[q, 0]
        py = points[q, 1]
        pz = points[q, 2]
        best = np.inf
        bf = -1
        bu = 1.0
        bv = 0.0
        bw = 0.0
        bfeat = 0
        for j in range(k):
            vi = knn[q, j]
            if vi < 0:
                continue
            for t in range(vf_ptr[vi], vf_ptr[vi + 1]):
                f = vf_idx[t]
                a = vertices[faces[f, 0]]
                b = vertices[faces[f, 1]]
                c = vertices[faces[f, 2]]
                u, v, w, feat = _closest_on_triangle(px, py, pz, a, b, c)
                x = u * a[0] + v * b[0] + w * c[0] - px
                y = u * a[1] + v * b[1] + w * c[1] - py
                z = u * a[2] + v * b[2] + w * c[2] - pz
                d2 = x * x + y * y + z * z
                if d2 < best:
                    best = d2
                    bf = f
                    bu = u
                    bv = v
                    bw = w
                    bfeat = feat
        out_face[q] = bf
        out_bary[q, 0] = bu
        out_bary[q, 1] = bv
        out_bary[q, 2] = bw
        out_d2[q] = best
        out_feat[q] = bfeat


# ---------------------------------------------------------------------------------------
# Topology-preserving quadric decimation, in passes of independent edge collapses.
# ---------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _vertex_faces(faces, alive, n):  # pragma: no cover - compiled
    ptr = np.zeros(n + 1, dtype=np.int64)
    m = faces.shape[0]
    for f in range(m):
        if alive[f]:
            for c in range(3):
                ptr[faces[f, c] + 1] += 1
    for i in range(n):
        ptr[i + 1] += ptr[i]
    idx = np.empty(ptr[n], dtype=np.int64)
    fill = ptr[:-1].copy()
    for f in range(m):
        if alive[f]:
            for c in range(3):
                v = faces[f, c]
                idx[fill[v]] = f
                fill[v] += 1
    return ptr, idx


@numba.njit(cache=True)
def _face_plane_quadrics(vertices, faces, alive):  # pragma: no cover - compiled
    """Area-weighted plane quadrics per vertex, shape (n, 10)."""
    n = vertices.shape[0]
    q = np.zeros((n, 10))
    m = faces.shape[0]
    for f in range(m):
        if not alive[f]:
            continue
        a = vertices[faces[f, 0]]
        b = vertices[faces[f, 1]]
        c = vertices[faces[f, 2]]
        nx = (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1])
        ny = (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2])
        nz = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        if ln <= 0.0:
            continue
        area = 0.5 * ln
        nx /= ln
        ny /= ln
        nz /= ln
        d = -(nx * a[0] + ny * a[1] + nz * a[2])
        for c3 in range(3):
            _add_plane(q, faces[f, c3], nx, ny, nz, d, area)
    return q


@numba.njit(cache=True)
def _add_plane(q, v, nx, ny, nz, d, w):  # pragma: no cover - compiled
    q[v, 0] += w * nx * nx
    q[v, 1] += w * nx * ny
    q[v, 2] += w * nx * nz
    q[v, 3] += w * nx * d
    q[v, 4] += w * ny * ny
    q[v, 5] += w * ny * nz
    q[v, 6] += w * ny * d
    q[v, 7] += w * nz * nz
    q[v, 8] += w * nz * d
    q[v, 9] += w * d * d


@numba.njit(cache=True)
def _q_eval(q, x, y, z):  # pragma: no cover - compiled
    return (
        q[0] * x * x + 2 * q[1] * x * y + 2 * q[2] * x * z + 2 * q[3] * x
        + q[4] * y * y + 2 * q[5] * y * z + 2 * q[6] * y
        + q[7] * z * z + 2 * q[8] * z + q[9]
    )


@numba.njit(cache=True)
def _has_edge(ptr, idx, faces, a, b):  # pragma: no cover - compiled
    """Number of live faces holding both a and b."""
    k = 0
    for t in range(ptr[a], ptr[a + 1]):
        f = idx[t]
        if faces[f, 0] == b or faces[f, 1] == b or faces[f, 2] == b:
            k += 1
    return k


@numba.njit(cache=True)
def _normal(p0, p1, p2):  # pragma: no cover - compiled
    ux, uy, uz = p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]
    vx, vy, vz = p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]
    return uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx


@numba.njit(cache=True)
def _quality(p0, p1, p2):  # pragma: no cover - compiled
    """2 sqrt(3) * twice-area / sum of squared edges: 1 for an equilateral triangle."""
    nx, ny, nz = _normal(p0, p1, p2)
    a2 = np.sqrt(nx * nx + ny * ny + nz * nz)
    s = (
        (p0[0] - p1[0]) ** 2 + (p0[1] - p1[1]) ** 2 + (p0[2] - p1[2]) ** 2
        + (p1[0] - p2[0]) ** 2 + (p1[1] - p2[1]) ** 2 + (p1[2] - p2[2]) ** 2
        + (p2[0] - p0[0]) ** 2 + (p2[1] - p0[1]) ** 2 + (p2[2] - p0[2]) ** 2
    )
    if s <= 0.0:
        return 0.0
    return 2.0 * np.sqrt(3.0) * a2 / s


@numba.njit(cache=True)
def _solve3(qq):  # pragma: no cover - compiled
    """Minimiser of the quadric (Cramer's rule); ok=False when ill-conditioned."""
    a00, a01, a02, a11, a12, a22 = qq[0], qq[1], qq[2], qq[4], qq[5], qq[7]
    b0, b1, b2 = -qq[3], -qq[6], -qq[8]
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    det = a00 * c00 + a01 * c01 + a02 * c02
    scale = a00 + a11 + a22
    if scale <= 0.0 or abs(det) <= 1e-6 * scale * scale * scale:
        return 0.0, 0.0, 0.0, False
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    x = (c00 * b0 + c01 * b1 + c02 * b2) / det
    y = (c01 * b0 + c11 * b1 + c12 * b2) / det
    z = (c02 * b0 + c12 * b1 + c22 * b2) / det
    return x, y, z, True


@numba.njit(cache=True)
def _edge_cost(v, q, a, b, bnd_a, bnd_b, edge_weight, qq):  # pragma: no cover - compiled
    """Cost and target point of collapsing edge (a, b); ``qq`` is a scratch array of 10."""
    for k in range(10):
        qq[k] = q[a, k] + q[b, k]
    l2 = (v[a, 0] - v[b, 0]) ** 2 + (v[a, 1] - v[b, 1]) ** 2 + (v[a, 2] - v[b, 2]) ** 2
    if bnd_a and not bnd_b:
        return max(_q_eval(qq, v[a, 0], v[a, 1], v[a, 2]), 0.0) + edge_weight * l2 * l2, v[a, 0], v[a, 1], v[a, 2]
    if bnd_b and not bnd_a:
        return max(_q_eval(qq, v[b, 0], v[b, 1], v[b, 2]), 0.0) + edge_weight * l2 * l2, v[b, 0], v[b, 1], v[b, 2]
    mx = 0.5 * (v[a, 0] + v[b, 0])
    my = 0.5 * (v[a, 1] + v[b, 1])
    mz = 0.5 * (v[a, 2] + v[b, 2])
    best = _q_eval(qq, mx, my, mz)
    bx, by, bz = mx, my, mz
    val = _q_eval(qq, v[a, 0], v[a, 1], v[a, 2])
    if val < best:
        best, bx, by, bz = val, v[a, 0], v[a, 1], v[a, 2]
    val = _q_eval(qq, v[b, 0], v[b, 1], v[b, 2])
    if val < best:
        best, bx, by, bz = val, v[b, 0], v[b, 1], v[b, 2]
    if not (bnd_a or bnd_b):
        x, y, z, ok = _solve3(qq)
        if ok and (x - mx) ** 2 + (y - my) ** 2 + (z - mz) ** 2 <= 0.25 * l2:
            val = _q_eval(qq, x, y, z)
            if val < best:
                best, bx, by, bz = val, x, y, z
    return max(best, 0.0) + edge_weight * l2 * l2, bx, by, bz


@numba.njit(cache=True)
def _heap_push(hc, hi, size, cost, item):  # pragma: no cover - compiled
    k = size
    hc[k] = cost
    hi[k] = item
    while k > 0:
        parent = (k - 1) >> 1
        if hc[parent] <= hc[k]:
            break
        hc[parent], hc[k] = hc[k], hc[parent]
        hi[parent], hi[k] = hi[k], hi[parent]
        k = parent
    return size + 1


@numba.njit(cache=True)
def _heap_pop(hc, hi, size):  # pragma: no cover - compiled
    item = hi[0]
    size -= 1
    hc[0] = hc[size]
    hi[0] = hi[size]
    k = 0
    while True:
        left = 2 * k + 1
        if left >= size:
            break
        c = left
        if left + 1 < size and hc[left + 1] < hc[left]:
            c = left + 1
        if hc[k] <= hc[c]:
            break
        hc[c], hc[k] = hc[k], hc[c]
        hi[c], hi[k] = hi[k], hi[c]
        k = c
    return item, size


@numba.njit(cache=True)
def _push_edge(v, q, is_bnd, version, x, y, edge_weight, qbuf, hc, hi, size, n_items, ea, eb, va, vb, pp):  # pragma: no cover
    """Score edge (x, y) and queue it; returns the new (size, n_items)."""
    if n_items >= hc.shape[0]:
        return size, n_items
    c0, x0, y0, z0 = _edge_cost(v, q, x, y, is_bnd[x], is_bnd[y], edge_weight, qbuf)
    ea[n_items] = x
    eb[n_items] = y
    va[n_items] = version[x]
    vb[n_items] = version[y]
    pp[n_items, 0] = x0
    pp[n_items, 1] = y0
    pp[n_items, 2] = z0
    size = _heap_push(hc, hi, size, c0, n_items)
    return size, n_items + 1


@numba.njit(cache=True)
def _ring_faces_ok(v, f, vf, vfc, a, b, p, min_quality):  # pragma: no cover - compiled
    """No face around a or b (other than those on edge ab) folds, flattens or becomes a needle."""
    for side in range(2):
        end = a if side == 0 else b
        for t in range(vfc[end]):
            ff = vf[end, t]
            fa, fb, fc = f[ff, 0], f[ff, 1], f[ff, 2]
            if (fa == a or fb == a or fc == a) and (fa == b or fb == b or fc == b):
                continue
            p0 = v[fa]
            p1 = v[fb]
            p2 = v[fc]
            o = _normal(p0, p1, p2)
            q0 = p if fa == end else p0
            q1 = p if fb == end else p1
            q2 = p if fc == end else p2
            nn = _normal(q0, q1, q2)
            lo = np.sqrt(o[0] ** 2 + o[1] ** 2 + o[2] ** 2)
            ln = np.sqrt(nn[0] ** 2 + nn[1] ** 2 + nn[2] ** 2)
            if ln <= 0.0 or lo <= 0.0:
                return False
            if (o[0] * nn[0] + o[1] * nn[1] + o[2] * nn[2]) < 0.2 * lo * ln:
                return False
            if _quality(q0, q1, q2) < min(min_quality, _quality(p0, p1, p2)):
                return False
    return True


@numba.njit(cache=True)
def decimate_heap(vertices, faces, target, edge_weight, min_quality, max_degree):  # pragma: no cover
    """Greedy quadric edge collapse with a priority queue, topology preserved.

    Edge cost: quadric error at the best of the midpoint, the two ends and the quadric
    optimum, plus ``edge_weight * length^4`` (favours even triangles). A collapse is
    done only if the link condition holds (common neighbours of the two ends are the
    apexes of their shared faces: manifoldness, genus and boundary loops are kept),
    no apex drops below three faces, no face folds or becomes a needle, and the
    merged vertex has at most ``max_degree`` faces. Boundary vertices stay on the
    boundary. Stale queue entries are skipped by per-vertex version counters.

    Returns (vertices, faces, alive_faces, n_alive_vertices).
    """
    v = vertices.copy()
    f = faces.copy()
    n = v.shape[0]
    m = f.shape[0]
    alive = np.ones(m, dtype=np.bool_)
    valive = np.ones(n, dtype=np.bool_)
    q = _face_plane_quadrics(v, f, alive)
    cap = max_degree + 8
    vf = np.empty((n, cap), dtype=np.int64)
    vfc = np.zeros(n, dtype=np.int64)
    for ff in range(m):
        for c in range(3):
            x = f[ff, c]
            if vfc[x] >= cap:
                return v, f, alive, -1  # valence beyond capacity: caller falls back
            vf[x, vfc[x]] = ff
            vfc[x] += 1
    ptr, idx = _vertex_faces(f, alive, n)
    is_bnd = np.zeros(n, dtype=np.bool_)
    for ff in range(m):
        for c in range(3):
            x = f[ff, c]
            y = f[ff, (c + 1) % 3]
            if _has_edge(ptr, idx, f, x, y) == 1:
                is_bnd[x] = True
                is_bnd[y] = True
    version = np.zeros(n, dtype=np.int64)
    qbuf = np.zeros(10)
    size_cap = 3 * m + 24 * n + 16
    hc = np.empty(size_cap)
    hi = np.empty(size_cap, dtype=np.int64)
    ea = np.empty(size_cap, dtype=np.int64)
    eb = np.empty(size_cap, dtype=np.int64)
    va = np.empty(size_cap, dtype=np.int64)
    vb = np.empty(size_cap, dtype=np.int64)
    pp = np.empty((size_cap, 3))
    n_items = 0
    size = 0
    for ff in range(m):
        for c in range(3):
            x = f[ff, c]
            y = f[ff, (c + 1) % 3]
            if x < y or (is_bnd[x] and is_bnd[y] and _has_edge(ptr, idx, f, x, y) == 1):
                size, n_items = _push_edge(v, q, is_bnd, version, x, y, edge_weight, qbuf, hc, hi, size, n_items, ea, eb, va, vb, pp)
    n_alive = n
    mark = np.zeros(n, dtype=np.int64)
    stamp = 2
    nb = np.empty(4 * cap, dtype=np.int64)
    while n_alive > target and size > 0:
        item, size = _heap_pop(hc, hi, size)
        a = ea[item]
        b = eb[item]
        if not valive[a] or not valive[b] or version[a] != va[item] or version[b] != vb[item]:
            continue
        # shared faces and the link condition
        shared = 0
        for t in range(vfc[a]):
            ff = vf[a, t]
            if f[ff, 0] == b or f[ff, 1] == b or f[ff, 2] == b:
                shared += 1
        if shared == 0 or (shared == 2 and is_bnd[a] and is_bnd[b]):
            continue
        if vfc[a] + vfc[b] - 2 * shared > max_degree:
            continue
        stamp += 2
        for t in range(vfc[a]):
            ff = vf[a, t]
            for c in range(3):
                mark[f[ff, c]] = stamp
        common = 0
        for t in range(vfc[b]):
            ff = vf[b, t]
            for c in range(3):
                x = f[ff, c]
                if x != a and x != b and mark[x] == stamp:
                    mark[x] = stamp - 1
                    common += 1
        if common != shared:
            continue
        ok = True
        for t in range(vfc[a]):
            ff = vf[a, t]
            if f[ff, 0] == b or f[ff, 1] == b or f[ff, 2] == b:
                for c in range(3):
                    x = f[ff, c]
                    if x != a and x != b and vfc[x] <= 3 and not is_bnd[x]:
                        ok = False
        if not ok:
            continue
        p = pp[item]
        if not _ring_faces_ok(v, f, vf, vfc, a, b, p, min_quality):
            continue
        # collapse a into b
        for t in range(vfc[a]):
            ff = vf[a, t]
            if f[ff, 0] == b or f[ff, 1] == b or f[ff, 2] == b:
                alive[ff] = False
                for c in range(3):  # drop the dead face from its other corners' lists
                    x = f[ff, c]
                    if x == a:
                        continue
                    k = 0
                    while k < vfc[x]:
                        if vf[x, k] == ff:
                            vf[x, k] = vf[x, vfc[x] - 1]
                            vfc[x] -= 1
                        else:
                            k += 1
            else:
                for c in range(3):
                    if f[ff, c] == a:
                        f[ff, c] = b
                vf[b, vfc[b]] = ff
                vfc[b] += 1
        vfc[a] = 0
        valive[a] = False
        n_alive -= 1
        v[b, 0] = p[0]
        v[b, 1] = p[1]
        v[b, 2] = p[2]
        for k in range(10):
            q[b, k] += q[a, k]
        is_bnd[b] = is_bnd[b] or is_bnd[a]
        version[b] += 1
        # re-queue the edges around b
        nn = 0
        stamp += 2
        for t in range(vfc[b]):
            ff = vf[b, t]
            for c in range(3):
                x = f[ff, c]
                if x != b and mark[x] != stamp:
                    mark[x] = stamp
                    nb[nn] = x
                    nn += 1
        for r in range(nn):
            size, n_items = _push_edge(v, q, is_bnd, version, b, nb[r], edge_weight, qbuf, hc, hi, size, n_items, ea, eb, va, vb, pp)
    return v, f, alive, n_alive
