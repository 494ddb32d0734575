"""Numba kernels for inner loops that numpy cannot express without large temporaries."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(parallel=True, cache=True, fastmath=False)
def heat_divergence(u_t, faces, coef, area, out):  # pragma: no cover - compiled
    """Integrated divergence of X = -grad u / |grad u| for each row of ``u_t``.

    u_t : (B, n) heat solutions, one row per source
    faces : (F, 3) int64, coef : (F, 3, 2) per-corner gradient coefficients
    area : (F,) face areas; out : (B, n) zeroed output
    """
    B = u_t.shape[0]
    nf = faces.shape[0]
    for b in numba.prange(B):
        u = u_t[b]
        o = out[b]
        for f in range(nf):
            i0 = faces[f, 0]
            i1 = faces[f, 1]
            i2 = faces[f, 2]
            gx = coef[f, 0, 0] * u[i0] + coef[f, 1, 0] * u[i1] + coef[f, 2, 0] * u[i2]
            gy = coef[f, 0, 1] * u[i0] + coef[f, 1, 1] * u[i1] + coef[f, 2, 1] * u[i2]
            nrm = np.sqrt(gx * gx + gy * gy)
            if nrm <= 0.0:
                continue
            s = -area[f] / nrm
            xx = gx * s
            xy = gy * s
            o[i0] += coef[f, 0, 0] * xx + coef[f, 0, 1] * xy
            o[i1] += coef[f, 1, 0] * xx + coef[f, 1, 1] * xy
            o[i2] += coef[f, 2, 0] * xx + coef[f, 2, 1] * xy


@numba.njit(cache=True, nogil=True, fastmath=False)
def vertex_normal_sums(vertices, faces, out):  # pragma: no cover - compiled
    """Unit area-weighted vertex normals into ``out`` (n, 3), zero where the sum vanishes.

    Bit for bit the numpy formula of :func:`topomatch.mesh.geometry.vertex_normals`: each
    face's cross product (np.cross's formula) added to its corners' sums in the order
    ``np.bincount(faces.T.ravel())`` adds them (every face's first corner, then second,
    then third), then divided by the norm ``sqrt((x^2 + y^2) + z^2)``.
    """
    n = vertices.shape[0]
    nf = faces.shape[0]
    for v in range(n):
        out[v, 0] = 0.0
        out[v, 1] = 0.0
        out[v, 2] = 0.0
    cx = np.empty(nf)
    cy = np.empty(nf)
    cz = np.empty(nf)
    for f in range(nf):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        ax = vertices[i1, 0] - vertices[i0, 0]
        ay = vertices[i1, 1] - vertices[i0, 1]
        az = vertices[i1, 2] - vertices[i0, 2]
        bx = vertices[i2, 0] - vertices[i0, 0]
        by = vertices[i2, 1] - vertices[i0, 1]
        bz = vertices[i2, 2] - vertices[i0, 2]
        cx[f] = ay * bz - az * by
        cy[f] = az * bx - ax * bz
        cz[f] = ax * by - ay * bx
    for corner in range(3):
        for f in range(nf):
            v = faces[f, corner]
            out[v, 0] += cx[f]
            out[v, 1] += cy[f]
            out[v, 2] += cz[f]
    for v in range(n):
        s = np.sqrt(out[v, 0] * out[v, 0] + out[v, 1] * out[v, 1] + out[v, 2] * out[v, 2])
        if s > 0.0:
            out[v, 0] /= s
            out[v, 1] /= s
            out[v, 2] /= s
        else:
            out[v, 0] = 0.0
            out[v, 1] = 0.0
            out[v, 2] = 0.0


@numba.njit(cache=True, nogil=True, fastmath=False)
def farthest_points(cols, first, out):  # pragma: no cover - compiled
    """Greedy farthest-point samples of the points ``cols`` (d, n) into ``out``, from ``first``.

    Bit for bit the numpy loop it replaced: each distance ``sqrt(((c_0^2 + c_1^2) + ...))``
    summed over the coordinates in order, the running minimum kept per point, the chosen
    points marked -1, the next sample the first point of largest minimum (``np.argmax``).
    """
    d, n = cols.shape
    dmin = np.full(n, np.inf)
    dist = np.empty(n)
    cur = first
    for k in range(out.shape[0]):
        out[k] = cur
        if d == 3:  # unrolled: the loop over the points vectorises
            x, y, z = cols[0, cur], cols[1, cur], cols[2, cur]
            for i in range(n):
                a = cols[0, i] - x
                b = cols[1, i] - y
                c = cols[2, i] - z
                dist[i] = np.sqrt(a * a + b * b + c * c)
        else:
            for i in range(n):
                dist[i] = 0.0
            for c in range(d):
                x = cols[c, cur]
                for i in range(n):
                    t = cols[c, i] - x
                    dist[i] += t * t
            for i in range(n):
                dist[i] = np.sqrt(dist[i])
        for i in range(n):
            dmin[i] = min(dmin[i], dist[i])
        dmin[cur] = -1.0
        best = 0
        for i in range(1, n):
            if dmin[i] > dmin[best]:
                best = i
        cur = best

