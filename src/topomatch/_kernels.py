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
