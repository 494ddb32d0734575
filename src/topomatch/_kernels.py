"""Numba kernels for inner loops that numpy cannot express without large temporaries."""

from __future__ import annotations

import numba
import numpy as np
from numba import types

from topomatch._lapack import register_lapack_symbol

# SciPy's LAPACK routines (those behind numba's ``np.linalg`` and SciPy's ``cho_factor`` /
# ``cho_solve``) by symbol names, so that the kernels calling them stay cached on disk (an
# address would be baked in); every argument is a pointer (Fortran)
_VP = types.voidptr
_dgesdd = types.ExternalFunction("topomatch_dgesdd", types.void(*(_VP,) * 14))
_dpotrf = types.ExternalFunction("topomatch_dpotrf", types.void(*(_VP,) * 5))
_dpotrs = types.ExternalFunction("topomatch_dpotrs", types.void(*(_VP,) * 8))
_dpbtrf = types.ExternalFunction("topomatch_dpbtrf", types.void(*(_VP,) * 6))
_dpbtrs = types.ExternalFunction("topomatch_dpbtrs", types.void(*(_VP,) * 9))
for _name in ("dgesdd", "dpotrf", "dpotrs", "dpbtrf", "dpbtrs"):
    register_lapack_symbol(f"topomatch_{_name}", _name)


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


@numba.njit(cache=True, nogil=True)
def cholesky_factor_solve(A, B):  # pragma: no cover - compiled
    """LAPACK's ``dpotrf`` then ``dpotrs`` (upper triangle) on Fortran-ordered ``A`` (n, n) and ``B`` (n, r), in place; LAPACK's ``info``.

    The routines SciPy's ``cho_factor`` and ``cho_solve`` call, on the same arrays: the same
    bits (:func:`topomatch._lapack.cholesky_solve`).
    """
    n = A.shape[0]
    uplo = np.array([ord("U")], np.uint8)
    size = np.array([n], np.int32)
    cols = np.array([B.shape[1]], np.int32)
    info = np.zeros(1, np.int32)
    _dpotrf(uplo.ctypes, size.ctypes, A.ctypes, size.ctypes, info.ctypes)
    if info[0] != 0:
        return info[0]
    _dpotrs(uplo.ctypes, size.ctypes, cols.ctypes, A.ctypes, size.ctypes, B.ctypes, size.ctypes, info.ctypes)
    return info[0]


@numba.njit(cache=True, nogil=True)
def banded_cholesky_factor_solve(AB, B):  # pragma: no cover - compiled
    """LAPACK's ``dpbtrf`` then ``dpbtrs`` (upper band storage) on Fortran-ordered ``AB`` (kd + 1, n) and ``B`` (n, r), in place; LAPACK's ``info``.

    ``AB[kd + i - j, j]`` holds ``A[i, j]`` for ``max(0, j - kd) <= i <= j``.
    """
    n = AB.shape[1]
    uplo = np.array([ord("U")], np.uint8)
    size = np.array([n], np.int32)
    kd = np.array([AB.shape[0] - 1], np.int32)
    ld = np.array([AB.shape[0]], np.int32)
    cols = np.array([B.shape[1]], np.int32)
    info = np.zeros(1, np.int32)
    _dpbtrf(uplo.ctypes, size.ctypes, kd.ctypes, AB.ctypes, ld.ctypes, info.ctypes)
    if info[0] != 0:
        return info[0]
    _dpbtrs(uplo.ctypes, size.ctypes, kd.ctypes, cols.ctypes, AB.ctypes, ld.ctypes, B.ctypes, size.ctypes, info.ctypes)
    return info[0]


@numba.njit(cache=True, nogil=True, fastmath=False)
def rotation_step(
    positions, rest, dir_a, dir_b, dir_rest, wl, vertices, skin_indptr, skin_indices, skin_data, source, c, points, previous, out,
    quaternion=False,
):  # pragma: no cover - compiled
    """The embedded deformation's Procrustes step into ``out`` (m, 3, 3): each node's best rotation.

    Bit for bit the numpy and SciPy formula it replaced (``GraphDeformation.update_rotations``
    before session 49, kept as :func:`topomatch.deform._reference.rotations`) with numpy
    2.4 on x86-64, without holding the GIL:

    - the link sums ``S_a = sum_k (wl_k e_k) cur_k^T`` over the directed links ``k = a -> b``
      in link order (``e_k`` the rest offset, ``cur_k = g_b - g_a``; the order in which
      ``Ia @ outer`` adds them);
    - the data sums over the pairs in pair order and each pair's skinning entries in
      stored order (the order of ``csc_matvecs`` for ``skin[source].T @ X``): per node
      ``sum P c v y^T``, ``sum P c v``, ``sum P c y``, ``sum P c``, combined as
      ``((S_vy - sv g^T) - g0 sy^T) + (sc g0) g^T``;
    - the rotation maximising ``tr(R S)`` from LAPACK's SVD (``dgesdd``, as ``np.linalg.svd``
      calls it) of ``S + 1e-12 I``
      (``R = V U^T``, ``V``'s last column negated when ``det < 0``), the previous rotation
      kept where the trace of ``|S|`` is below 1e-300. With ``quaternion``, the same
      rotation by Horn's quaternion instead (:func:`_horn_rotation`: equal to about
      1e-13, in about 0.4 of the SVD's time; what the library passes since session 62,
      :data:`topomatch.deform.register.QUATERNION_ROTATIONS`).

    ``source`` of length zero means no data term. ``c`` holds the pairs' weights already
    multiplied by the data weight. The caller passes ``out`` as the transpose of a
    C-ordered (m, 3, 3) array (strides (72, 8, 24)), the layout numpy's ``einsum`` gave
    the rotations before: the products with them elsewhere (``einsum`` over the
    rotations of the links) then add in the same order as before.
    """
    m = rest.shape[0]
    S = np.zeros((m, 3, 3))
    for k in range(dir_a.shape[0]):
        a_node = dir_a[k]
        b_node = dir_b[k]
        for a in range(3):
            t = wl[k] * dir_rest[k, a]
            for b in range(3):
                S[a_node, a, b] += t * (positions[b_node, b] - positions[a_node, b])
    if source.shape[0] > 0:
        sums = np.zeros((m, 16))
        x = np.empty(16)
        for p in range(source.shape[0]):
            i = source[p]
            cp = c[p]
            for a in range(3):
                cv = cp * vertices[i, a]
                for b in range(3):
                    x[3 * a + b] = cv * points[p, b]
                x[9 + a] = cv
                x[12 + a] = cp * points[p, a]
            x[15] = cp
            for e in range(skin_indptr[i], skin_indptr[i + 1]):
                node = skin_indices[e]
                w = skin_data[e]
                for j in range(16):
                    sums[node, j] += w * x[j]
        for n in range(m):
            for a in range(3):
                for b in range(3):
                    S[n, a, b] += (
                        (sums[n, 3 * a + b] - sums[n, 9 + a] * positions[n, b]) - rest[n, a] * sums[n, 12 + b]
                    ) + (sums[n, 15] * rest[n, a]) * positions[n, b]
    # LAPACK's dgesdd called as numba's ``np.linalg.svd`` calls it (jobz "A", Fortran order,
    # the queried optimal workspace), with the buffers and the workspace made once here
    # rather than for every node: the same bits
    jobz = np.array([ord("A")], np.uint8)
    three = np.array([3], np.int32)
    info = np.zeros(1, np.int32)
    lwork = np.array([-1], np.int32)
    M = np.zeros(9)  # column-major: M[a + 3 b]
    sv = np.empty(3)
    U = np.empty(9)  # column-major, as Vt
    Vt = np.empty(9)
    iwork = np.empty(24, np.int32)
    query = np.zeros(1)
    if not quaternion:  # the workspace query only for the SVDs
        _dgesdd(jobz.ctypes, three.ctypes, three.ctypes, M.ctypes, three.ctypes, sv.ctypes, U.ctypes, three.ctypes, Vt.ctypes,
                three.ctypes, query.ctypes, lwork.ctypes, iwork.ctypes, info.ctypes)
    lwork[0] = np.int32(query[0])
    work = np.empty(max(1, lwork[0]))
    N = np.empty((4, 4))  # Horn's matrix and its eigenvectors (quaternion)
    V = np.empty((4, 4))
    for n in range(m):
        if abs(S[n, 0, 0]) + abs(S[n, 1, 1]) + abs(S[n, 2, 2]) < 1e-300:
            out[n] = previous[n]
            continue
        for a in range(3):
            for b in range(3):
                M[a + 3 * b] = S[n, a, b] + (1e-12 if a == b else 0.0)
                if not np.isfinite(M[a + 3 * b]):  # numba's np.linalg.svd checked this
                    raise np.linalg.LinAlgError("Array must not contain infs or NaNs.")
        if quaternion:
            _horn_rotation(M, N, V, out[n])
            continue
        _dgesdd(jobz.ctypes, three.ctypes, three.ctypes, M.ctypes, three.ctypes, sv.ctypes, U.ctypes, three.ctypes, Vt.ctypes,
                three.ctypes, work.ctypes, lwork.ctypes, iwork.ctypes, info.ctypes)
        if info[0] != 0:
            raise np.linalg.LinAlgError("SVD did not converge.")
        # U[i, j] is U[i + 3 j], Vt[i, j] is Vt[i + 3 j]
        for i in range(3):
            for k in range(3):
                out[n, i, k] = Vt[3 * i] * U[k] + Vt[1 + 3 * i] * U[k + 3] + Vt[2 + 3 * i] * U[k + 6]
        # the sign of the determinant (+-1 up to rounding; LAPACK's LU was used before)
        o = out[n]
        det = (o[0, 0] * (o[1, 1] * o[2, 2] - o[1, 2] * o[2, 1]) - o[0, 1] * (o[1, 0] * o[2, 2] - o[1, 2] * o[2, 0])
               + o[0, 2] * (o[1, 0] * o[2, 1] - o[1, 1] * o[2, 0]))
        if det < 0:
            for i in range(3):
                for k in range(3):
                    out[n, i, k] = Vt[3 * i] * U[k] + Vt[1 + 3 * i] * U[k + 3] - Vt[2 + 3 * i] * U[k + 6]


@numba.njit(cache=True, nogil=True, fastmath=False)
def _horn_rotation(M, N, V, R):  # pragma: no cover - compiled
    """The rotation ``R`` (3, 3) maximising ``tr(R A)`` by Horn's quaternion (Horn 1987), ``A`` given column-major in ``M`` (9,).

    Read row by row, ``M`` holds ``A^T = B``, and ``tr(R A) = sum_ij R_ij B_ij``, which is
    ``q^T N q`` for the unit quaternion ``q`` of ``R`` and Horn's symmetric ``N`` (4, 4)
    of ``B``: ``q`` is the eigenvector of ``N``'s largest eigenvalue. ``N`` is
    diagonalised in place by cyclic Jacobi rotations, ``V`` (4, 4) receives the
    eigenvectors. The same rotation as the SVD's (``V U^T`` with the determinant's sign
    fixed) to about 1e-13.
    """
    N[0, 0] = M[0] + M[4] + M[8]
    N[1, 1] = M[0] - M[4] - M[8]
    N[2, 2] = -M[0] + M[4] - M[8]
    N[3, 3] = -M[0] - M[4] + M[8]
    N[0, 1] = N[1, 0] = M[7] - M[5]
    N[0, 2] = N[2, 0] = M[2] - M[6]
    N[0, 3] = N[3, 0] = M[3] - M[1]
    N[1, 2] = N[2, 1] = M[1] + M[3]
    N[1, 3] = N[3, 1] = M[2] + M[6]
    N[2, 3] = N[3, 2] = M[5] + M[7]
    for i in range(4):
        for j in range(4):
            V[i, j] = 1.0 if i == j else 0.0
    for _ in range(50):
        off = 0.0
        scale = 0.0
        for i in range(4):
            scale += N[i, i] * N[i, i]
            for j in range(i + 1, 4):
                off += N[i, j] * N[i, j]
        if off <= 1e-36 * scale or off == 0.0:
            break
        for p in range(3):
            for q in range(p + 1, 4):
                apq = N[p, q]
                if apq == 0.0:
                    continue
                theta = (N[q, q] - N[p, p]) / (2.0 * apq)
                t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(4):  # columns p, q of N
                    nkp = N[k, p]
                    nkq = N[k, q]
                    N[k, p] = c * nkp - s * nkq
                    N[k, q] = s * nkp + c * nkq
                for k in range(4):  # rows p, q
                    npk = N[p, k]
                    nqk = N[q, k]
                    N[p, k] = c * npk - s * nqk
                    N[q, k] = s * npk + c * nqk
                for k in range(4):
                    vkp = V[k, p]
                    vkq = V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq
    best = 0
    for i in range(1, 4):
        if N[i, i] > N[best, best]:
            best = i
    norm = 0.0
    for k in range(4):
        norm += V[k, best] * V[k, best]
    norm = np.sqrt(norm)
    w = V[0, best] / norm
    x = V[1, best] / norm
    y = V[2, best] / norm
    z = V[3, best] / norm
    R[0, 0] = w * w + x * x - y * y - z * z
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = w * w - x * x + y * y - z * z
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = w * w - x * x - y * y + z * z


@numba.njit(cache=True, nogil=True, fastmath=False)
def skinned_vertices(rotations, rest, indptr, indices, data, vertices, rows, every, positions, add_positions, out):  # pragma: no cover
    """Embedded-deformation vertices into ``out``: ``sum_q w_iq R_q (v_i - g0_q)`` (+ ``sum_q w_iq g_q``).

    For the vertices ``rows`` (``every``: all vertices, ``rows`` ignored), skinning
    weights from the CSR arrays ``indptr, indices, data`` (sorted indices), the
    translation part ``sum_q w_iq g_q`` added when ``add_positions``. Bit for bit the
    numpy and SciPy formula it replaced (``GraphDeformation._affine_part`` and
    ``deformed`` before session 49, :mod:`topomatch.deform._reference`) with numpy 2.4 on
    x86-64: the blends
    ``sum_q w_iq [R_q, R_q g0_q]`` and ``sum_q w_iq g_q`` summed over the row's entries
    in order from zero (``csr_matvecs``); ``R_q g0_q`` summed in order and ``B_i v_i`` as
    ``(x_0 y_0 + x_2 y_2) + x_1 y_1``, the orders in which numpy's ``einsum`` adds them
    there (the rotations are stored 3 x 3 transposed, see :func:`rotation_step`; the
    blends' rows are contiguous, which einsum adds in two SIMD lanes); then ``- b_i``
    and the translation added.
    """
    m = rest.shape[0]
    X = np.empty((m, 12))
    for q in range(m):
        for a in range(3):
            for b in range(3):
                X[q, 3 * a + b] = rotations[q, a, b]
            X[q, 9 + a] = (rotations[q, a, 0] * rest[q, 0] + rotations[q, a, 1] * rest[q, 1]) + rotations[q, a, 2] * rest[q, 2]
    n_out = vertices.shape[0] if every else rows.shape[0]
    blend = np.empty(12)
    shift = np.empty(3)
    for r in range(n_out):
        i = r if every else rows[r]
        for j in range(12):
            blend[j] = 0.0
        for j in range(3):
            shift[j] = 0.0
        for e in range(indptr[i], indptr[i + 1]):
            q = indices[e]
            w = data[e]
            for j in range(12):
                blend[j] += w * X[q, j]
            if add_positions:
                for j in range(3):
                    shift[j] += w * positions[q, j]
        for a in range(3):
            t = ((blend[3 * a] * vertices[i, 0] + blend[3 * a + 2] * vertices[i, 2]) + blend[3 * a + 1] * vertices[i, 1]) - blend[9 + a]
            out[r, a] = t + shift[a] if add_positions else t


@numba.njit(cache=True, nogil=True, fastmath=False)
def gram_entries(vp_indptr, vp_indices, vp_data, n_vertices, source, weights, out):  # pragma: no cover - compiled
    """``out[e, j] = sum_i vp[i, e] sum_{p: source_p = i} weights[p, j]``: the Gram matrices' upper triangles.

    ``vp`` is ``_GramPattern.vertex_products`` (CSR arrays); ``out`` (n_entries, k) zeroed.
    Bit for bit ``_GramPattern.grams`` before session 49: the per-vertex sums in pair
    order (``np.bincount``), then the vertices with a non-zero sum in order, each
    row's entries in stored order (``csc_matvecs`` of ``vp[active].T @ per_vertex[active]``).
    """
    k = weights.shape[1]
    per_vertex = np.zeros((n_vertices, k))
    for p in range(source.shape[0]):
        for j in range(k):
            per_vertex[source[p], j] += weights[p, j]
    for i in range(n_vertices):
        active = False
        for j in range(k):
            if per_vertex[i, j] != 0.0:
                active = True
        if not active:
            continue
        for e in range(vp_indptr[i], vp_indptr[i + 1]):
            q = vp_indices[e]
            w = vp_data[e]
            for j in range(k):
                out[q, j] += w * per_vertex[i, j]


@numba.njit(cache=True, nogil=True, fastmath=False)
def position_terms(
    rotations, dir_a, dir_b, dir_rest, wl, skin_indptr, skin_indices, skin_data, source, c, resid, normals, reg, mu_point, mu_plane, r_out, w_out
):  # pragma: no cover - compiled
    """The position step's right-hand side into ``r_out`` (m, 3) and its pairs' Gram weights into ``w_out``.

    ``r = reg D (wl R_a e) + P^T (mu_point c resid) [+ P^T ((mu_plane c (n . resid)) n)]``
    with ``P = skin[source]``; ``w_out`` (p, 6) holds ``mu_plane c n_i n_j (+ mu_point c
    for i = j)`` for ``(i, j)`` = (0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2) when
    ``mu_plane > 0``, else (p, 1) ``mu_point c``. Bit for bit the numpy and SciPy formula
    it replaced (``GraphDeformation.update_positions`` before session 49) with numpy 2.4
    on x86-64: ``R_a e`` summed in order (the rotations' transposed layout, see
    :func:`rotation_step`); the link sums over the links in order, ``+x`` into the
    link's end and ``-x`` into its start (``csr_matvecs`` with the incidence matrix);
    the skin sums over the pairs in order, each pair's skinning entries in stored
    order (``csc_matvecs`` of ``skin[source].T @ X``); ``n . resid`` summed as
    ``(n_0 r_0 + n_2 r_2) + n_1 r_1`` (numpy's einsum on contiguous rows).
    """
    m = r_out.shape[0]
    rhs = np.zeros((m, 3))
    x = np.empty(3)
    for k in range(dir_a.shape[0]):
        a_node = dir_a[k]
        b_node = dir_b[k]
        for a in range(3):
            d = (rotations[a_node, a, 0] * dir_rest[k, 0] + rotations[a_node, a, 1] * dir_rest[k, 1]) + rotations[a_node, a, 2] * dir_rest[k, 2]
            x[a] = wl[k] * d
        for a in range(3):
            rhs[b_node, a] += x[a]
        for a in range(3):
            rhs[a_node, a] += -1.0 * x[a]
    y1 = np.zeros((m, 3))
    plane = mu_plane > 0
    y2 = np.zeros((m, 3))
    x2 = np.empty(3)
    for p in range(source.shape[0]):
        i = source[p]
        cp = c[p]
        mc = mu_point * cp
        for a in range(3):
            x[a] = mc * resid[p, a]
        if plane:
            proj = (normals[p, 0] * resid[p, 0] + normals[p, 2] * resid[p, 2]) + normals[p, 1] * resid[p, 1]
            s = (mu_plane * cp) * proj
            for a in range(3):
                x2[a] = s * normals[p, a]
            pc = mu_plane * cp
            col = 0
            for a in range(3):
                for b in range(a, 3):
                    v = (pc * normals[p, a]) * normals[p, b]
                    w_out[p, col] = v + mc if a == b else v + 0.0
                    col += 1
        else:
            w_out[p, 0] = mc
        for e in range(skin_indptr[i], skin_indptr[i + 1]):
            q = skin_indices[e]
            w = skin_data[e]
            for a in range(3):
                y1[q, a] += w * x[a]
            if plane:
                for a in range(3):
                    y2[q, a] += w * x2[a]
    for q in range(m):
        for a in range(3):
            t = reg * rhs[q, a] + y1[q, a]
            r_out[q, a] = t + y2[q, a] if plane else t


@numba.njit(cache=True, nogil=True, fastmath=False)
def robust_pairs(
    src, j, d, tgt, i, d2, source_normals, target_vertices, target_normals, sigma, min_cos, out_source, out_points, out_normals, out_weights
):  # pragma: no cover - compiled
    """The closest-point pairs of both directions with a positive robust weight, in order; returns their count.

    Forward pairs ``(src[p] -> target j[p])`` at distance ``d[p]``, then backward pairs
    ``(source i[p] <- target tgt[p])`` at ``d2[p]``; each weighs ``1 / (1 + (d / sigma)^2)``
    where the two normals' cosine is at least ``min_cos``, else 0, and only pairs with a
    positive weight are written to ``out_*`` (each of length ``len(src) + len(tgt)``).
    Bit for bit the numpy formula it replaced (``closest_pairs`` before session 58:
    ``_robust_weights`` on gathered rows, ``DataPairs.concat`` and ``weighted``) with
    numpy 2.4 on x86-64: the cosine summed as ``(x_0 y_0 + x_2 y_2) + x_1 y_1`` (numpy's
    einsum on contiguous rows) and ``(d / sigma)^2`` as a product (numpy's square).
    """
    n = 0
    n_forward = src.shape[0]
    for p in range(n_forward + tgt.shape[0]):
        if p < n_forward:
            a, b, dist = src[p], j[p], d[p]
        else:
            a, b, dist = i[p - n_forward], tgt[p - n_forward], d2[p - n_forward]
        # the same products either way round: the backward pairs' cosine (target normal first) alike
        cos = (source_normals[a, 0] * target_normals[b, 0] + source_normals[a, 2] * target_normals[b, 2]) + source_normals[a, 1] * target_normals[b, 1]
        w = 0.0
        if cos >= min_cos:
            t = dist / sigma
            w = 1.0 / (1.0 + t * t)
        if w > 0:
            out_source[n] = a
            for c in range(3):
                out_points[n, c] = target_vertices[b, c]
                out_normals[n, c] = target_normals[b, c]
            out_weights[n] = w
            n += 1
    return n


@numba.njit(cache=True, nogil=True, fastmath=False)
def dense_blocks(rows, cols, block_i, block_j, values, m, eps, H):  # pragma: no cover - compiled
    """Write a symmetric ``d x d`` block matrix's upper triangle into ``H`` (zeroed, ``d m x d m``), plus ``eps`` on its diagonal.

    Block ``(block_i[k], block_j[k])`` (``i <= j``) holds ``values[k]`` at the pattern
    entries ``(rows[e], cols[e])`` (``rows <= cols``); an off-diagonal block also at
    ``(cols[e], rows[e])``. The same matrix as ``_GramPattern.solve``'s fancy-indexed
    assignments before session 58 (later blocks overwrite earlier ones alike).
    """
    for k in range(block_i.shape[0]):
        bi = block_i[k] * m
        bj = block_j[k] * m
        off = block_i[k] != block_j[k]
        for e in range(rows.shape[0]):
            v = values[k, e]
            H[bi + rows[e], bj + cols[e]] = v
            if off:
                H[bi + cols[e], bj + rows[e]] = v
    for r in range(H.shape[0]):
        H[r, r] += eps


@numba.njit(cache=True, nogil=True, fastmath=False)
def _band_put(AB, kd, a, b, v):  # pragma: no cover - compiled
    """Entry ``(a, b)`` (and ``(b, a)``) of a symmetric matrix into its upper band storage ``AB``."""
    if a <= b:
        AB[kd + a - b, b] = v
    else:
        AB[kd + b - a, a] = v


@numba.njit(cache=True, nogil=True, fastmath=False)
def banded_blocks(rows, cols, block_i, block_j, values, d, eps, position, AB):  # pragma: no cover - compiled
    """:func:`dense_blocks`'s ``d x d`` block matrix reordered and written in LAPACK's upper band storage ``AB`` (zeroed, (kd + 1, d m)).

    Unknown ``(coordinate c, node k)`` (index ``c m + k`` in :func:`dense_blocks`) becomes
    ``d position[k] + c``: each node's coordinates side by side, the nodes in the order
    ``position``. Every entry of the symmetric matrix is written once, in the upper triangle
    of the new order (later blocks overwrite earlier ones alike).
    """
    kd = AB.shape[0] - 1
    for k in range(block_i.shape[0]):
        bi = block_i[k]
        bj = block_j[k]
        off = bi != bj
        for e in range(rows.shape[0]):
            v = values[k, e]
            _band_put(AB, kd, d * position[rows[e]] + bi, d * position[cols[e]] + bj, v)
            if off:
                _band_put(AB, kd, d * position[cols[e]] + bi, d * position[rows[e]] + bj, v)
    for r in range(AB.shape[1]):
        AB[kd, r] += eps
