"""Functional map estimation from descriptors (Ovsjanikov et al. 2012 and successors).

The map ``C_12`` (shape ``(k2, k1)``) carries spectral coefficients of functions on
shape 1 to shape 2. It is the minimiser of a sum of quadratic terms:

descriptor preservation
    ``||C A_1 - A_2||^2`` with ``A_i = Phi_i^+ D_i`` the coefficients of corresponding
    descriptor functions.
Laplacian commutativity
    ``||C Lambda_1 - Lambda_2 C||^2 = sum_ij C_ij^2 (lambda_2i - lambda_1j)^2``
    (eigenvalues made scale-free by multiplying with each shape's area).
descriptor commutativity (Nogneng & Ovsjanikov 2017)
    ``sum_f ||C X_1f - X_2f C||^2`` with ``X_if = Phi_i^+ diag(d_if) Phi_i`` the
    multiplication operators of the descriptors.
orientation preservation (Ren et al. 2018)
    ``sum_f ||C O_1f - O_2f C||^2`` with ``O_if`` the operator
    ``g -> <n x grad d_if, grad g>`` in the reduced basis. It is odd under a
    reflection, so it separates a map from its left-right mirror, which every
    intrinsic term above accepts equally.

Every term is quadratic in ``C``, so the minimiser solves one dense linear system in
``vec(C)`` (``k1 k2`` unknowns: 900 at k = 30, 2,500 at k = 50). Each term is divided
by the mean diagonal of its Hessian before weighting, so weights are relative and do
not depend on the shapes' scale or on how many descriptors are used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from topomatch._lapack import cholesky_solve
from topomatch.mesh.geometry import face_normals
from topomatch.mesh.laplacian import gradient_operator
from topomatch.mesh.mesh import TriangleMesh
from topomatch.mesh.spectral import Eigenbasis
from topomatch.typing import FloatArray, IndexArray

__all__ = [
    "FmapWeights",
    "descriptor_coefficients",
    "estimate_fmap",
    "multiplication_operators",
    "orientation_operators",
    "scale_free_evals",
    "solve_fmap",
]


def _check_basis_rows(name: str, arr: FloatArray, n: int) -> FloatArray:
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or a.shape[0] != n:
        raise ValueError(f"{name} must have shape (n_vertices={n}, d), got {a.shape}")
    return a


def descriptor_coefficients(basis: Eigenbasis, descriptors: FloatArray) -> FloatArray:
    """Spectral coefficients of descriptor functions, ``Phi^T M D``.

    Parameters
    ----------
    basis : Eigenbasis with ``k`` functions on ``n`` vertices
    descriptors : ndarray, shape (n, d)

    Returns
    -------
    ndarray, shape (k, d)
    """
    d = _check_basis_rows("descriptors", descriptors, basis.evecs.shape[0])
    return basis.project(d)


def multiplication_operators(basis: Eigenbasis, descriptors: FloatArray) -> FloatArray:
    """Operators ``Phi^T M diag(d) Phi`` of pointwise multiplication by each descriptor.

    Parameters
    ----------
    basis : Eigenbasis with ``k`` functions on ``n`` vertices
    descriptors : ndarray, shape (n, d)

    Returns
    -------
    ndarray, shape (d, k, k)
    """
    d = _check_basis_rows("descriptors", descriptors, basis.evecs.shape[0])
    mphi = basis.mass[:, None] * basis.evecs
    return np.stack([basis.evecs.T @ (d[:, j : j + 1] * mphi) for j in range(d.shape[1])])


def orientation_operators(
    vertices: FloatArray, faces: IndexArray, basis: Eigenbasis, descriptors: FloatArray
) -> FloatArray:
    """Orientation-aware operators ``g -> <n x grad d, grad g>`` in the reduced basis.

    For a descriptor ``d`` the operator takes a function ``g`` to the derivative of
    ``g`` along the rotated gradient of ``d`` (per face, face normal ``n``), averaged
    to vertices with face-area weights and projected: ``O[i, j] = sum_t area_t
    mean_{v in t}(phi_i(v)) <n_t x grad d, grad phi_j>_t``. Under a reflection the
    normal flips and so does ``O``. The shape is scaled to unit area first, so
    operators of different shapes are comparable.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
    faces : ndarray, shape (n_faces, 3)
        Consistently oriented triangles.
    basis : Eigenbasis with ``k`` functions on ``n`` vertices
    descriptors : ndarray, shape (n, d)

    Returns
    -------
    ndarray, shape (d, k, k)
    """
    rot, grad_phi, face_phi = _orientation_factors(vertices, faces, basis, descriptors)
    nf, nd, k = len(rot), rot.shape[2], basis.k
    # all descriptors at once, in chunks of faces (about 32 MB of derivatives each):
    # deriv[t, j, :] = (n x grad d_j)_t . grad phi_t, then one product with face_phi
    out = np.zeros((k, nd * k))
    chunk = max(1, (1 << 22) // max(1, nd * k))
    for s in range(0, nf, chunk):
        e = min(nf, s + chunk)
        deriv = np.matmul(rot[s:e].transpose(0, 2, 1), grad_phi[s:e])  # (chunk, d, k)
        out += face_phi[s:e].T @ deriv.reshape(e - s, nd * k)
    return np.ascontiguousarray(out.reshape(k, nd, k).transpose(1, 0, 2))


def _orientation_factors(
    vertices: FloatArray, faces: IndexArray, basis: Eigenbasis, descriptors: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per-face factors of :func:`orientation_operators` on the shape scaled to unit area.

    Returns ``n x grad d`` of shape (n_faces, 3, d), ``grad phi`` of shape
    (n_faces, 3, k) and ``area_t mean_{v in t} phi(v)`` of shape (n_faces, k):
    ``O[j] = face_phi.T @ sum_c rot[:, c, j, None] * grad_phi[:, c, :]``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = basis.evecs.shape[0]
    if v.shape != (n, 3):
        raise ValueError(f"vertices must have shape ({n}, 3) to match the basis, got {v.shape}")
    d = _check_basis_rows("descriptors", descriptors, n)
    G, areas = gradient_operator(v, f)
    total = areas.sum()
    if total <= 0:
        raise ValueError("the mesh has zero area")
    # the operator scales as 1/length^2; multiply by the area to make it scale-free (the
    # projection keeps the basis' own mass, so the matrix does not depend on the basis scale)
    scale = 1.0 / np.sqrt(total)
    nf = len(f)
    normals = face_normals(v, f)
    grad_phi = (G @ basis.evecs).reshape(nf, 3, -1) / scale  # (n_faces, 3, k)
    grad_d = (G @ d).reshape(nf, 3, -1) / scale  # (n_faces, 3, d)
    rot = np.cross(normals[:, :, None], grad_d, axis=1)  # n x grad d, (n_faces, 3, d)
    face_phi = basis.evecs[f].mean(axis=1) * areas[:, None]  # (n_faces, k)
    return rot, grad_phi, face_phi


@dataclass(frozen=True)
class FmapWeights:
    """Relative weights of the functional map energy terms.

    Each term is normalised by the mean diagonal of its Hessian, so only ratios
    matter and a weight of 1 gives a term the same curvature as the descriptor term.
    """

    descriptors: float = 1.0
    laplacian: float = 1e-2
    commutativity: float = 1e-1
    orientation: float = 0.0


def _kron_sum(Y: FloatArray, X: FloatArray) -> FloatArray:
    """``sum_f Y_f (x) X_f`` in row-major ``vec`` order, shape (k2 k1, k2 k1)."""
    k2 = Y.shape[1]
    k1 = X.shape[1]
    K = np.tensordot(Y, X, axes=([0], [0]))  # (k2, k2, k1, k1) indexed [a, b, c, d]
    return K.transpose(0, 2, 1, 3).reshape(k2 * k1, k2 * k1)


def _commutativity_hessian(X: FloatArray, Y: FloatArray) -> FloatArray:
    """Hessian (up to a factor 2) of ``sum_f ||C X_f - Y_f C||^2`` in row-major vec(C).

    The plain construction, kept as the reference for :func:`_add_commutativity` (which
    :func:`solve_fmap` uses) in the tests.
    """
    k1 = X.shape[1]
    k2 = Y.shape[1]
    XXt = np.einsum("fab,fcb->ac", X, X)
    YtY = np.einsum("fba,fbc->ac", Y, Y)
    H = np.kron(np.eye(k2), XXt) + np.kron(YtY, np.eye(k1))
    H -= _kron_sum(np.transpose(Y, (0, 2, 1)), np.transpose(X, (0, 2, 1)))
    H -= _kron_sum(Y, X)
    return H


def _commutativity_trace(X: FloatArray, Y: FloatArray) -> float:
    """Trace of :func:`_commutativity_hessian` without building it."""
    k1, k2 = X.shape[1], Y.shape[1]
    cross = float(np.einsum("faa->f", Y) @ np.einsum("faa->f", X))
    return float(k2 * np.sum(X * X) + k1 * np.sum(Y * Y) - 2.0 * cross)


def _add_identity_kron(H4: FloatArray, M: FloatArray) -> None:
    """``H += I (x) M`` in place, ``H4`` the (k2, k1, k2, k1) view of ``H``."""
    for a in range(H4.shape[0]):
        H4[a, :, a, :] += M


def _add_commutativity(H: FloatArray, X: FloatArray, Y: FloatArray, w: float) -> None:
    """``H += w * _commutativity_hessian(X, Y)`` in place.

    One (k1 k2)^2 temporary (the four-index product of the operators) instead of the
    reference's seven. ``H`` is C-contiguous, shape (k2 k1, k2 k1), row-major ``vec(C)``
    as in the Hessian.
    """
    k1, k2 = X.shape[1], Y.shape[1]
    H4 = H.reshape(k2, k1, k2, k1)  # [a, c, b, d]: row a k1 + c, column b k1 + d
    XXt = w * np.einsum("fab,fcb->ac", X, X)
    YtY = w * np.einsum("fba,fbc->ac", Y, Y)
    _add_identity_kron(H4, XXt)
    for c in range(k1):  # Y^T Y (x) I
        H4[:, c, :, c] += YtY
    K = np.tensordot(Y, X, axes=([0], [0]))  # [a, b, c, d] = sum_f Y_f[a, b] X_f[c, d]
    K *= w
    H4 -= K.transpose(0, 2, 1, 3)  # sum_f Y_f (x) X_f
    H4 -= K.transpose(1, 3, 0, 2)  # sum_f Y_f^T (x) X_f^T


def solve_fmap(
    A_1: FloatArray,
    A_2: FloatArray,
    evals_1: FloatArray,
    evals_2: FloatArray,
    *,
    weights: FmapWeights = FmapWeights(),
    commutativity_ops: tuple[FloatArray, FloatArray] | None = None,
    orientation_ops: tuple[FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """Minimise the functional map energy; return ``C_12``.

    Parameters
    ----------
    A_1 : ndarray, shape (k1, d)
        Descriptor coefficients on shape 1.
    A_2 : ndarray, shape (k2, d)
        Coefficients of the corresponding descriptors on shape 2.
    evals_1 : ndarray, shape (k1,)
        Eigenvalues of shape 1, already made scale-free (times the area) if the
        shapes differ in scale.
    evals_2 : ndarray, shape (k2,)
    weights : FmapWeights
    commutativity_ops : pair of ndarray, shapes (f, k1, k1) and (f, k2, k2), optional
        Multiplication operators, needed when ``weights.commutativity > 0``.
    orientation_ops : pair of ndarray, shapes (g, k1, k1) and (g, k2, k2), optional
        Orientation operators, needed when ``weights.orientation > 0``. Pass the
        second shape's operators negated to ask for an orientation-reversing map.

    Returns
    -------
    ndarray, shape (k2, k1)
    """
    A_1 = np.asarray(A_1, dtype=np.float64)
    A_2 = np.asarray(A_2, dtype=np.float64)
    if A_1.ndim != 2 or A_2.ndim != 2 or A_1.shape[1] != A_2.shape[1]:
        raise ValueError(f"A_1 and A_2 must be (k1, d) and (k2, d) with equal d, got {A_1.shape} and {A_2.shape}")
    k1, k2 = A_1.shape[0], A_2.shape[0]
    ev1 = np.asarray(evals_1, dtype=np.float64)
    ev2 = np.asarray(evals_2, dtype=np.float64)
    if ev1.shape != (k1,) or ev2.shape != (k2,):
        raise ValueError(f"evals_1 / evals_2 must have shapes ({k1},) / ({k2},), got {ev1.shape} / {ev2.shape}")
    n = k1 * k2

    def inverse_mean_diagonal(trace: float) -> float:
        s = trace / n
        return 1.0 / s if s > 0 else 0.0

    # descriptor preservation: Hessian I (x) A1 A1^T, right-hand side A2 A1^T; every term
    # is added in place to one (k2 k1)^2 matrix (at k = 50 the temporaries cost more than
    # the solve)
    AAt = A_1 @ A_1.T
    s_d = inverse_mean_diagonal(k2 * float(np.trace(AAt)))
    H = np.zeros((n, n))
    _add_identity_kron(H.reshape(k2, k1, k2, k1), (weights.descriptors * s_d) * AAt)
    rhs = weights.descriptors * s_d * (A_2 @ A_1.T).ravel()
    if weights.laplacian > 0:
        scale = max(float(np.max(np.abs(ev1), initial=0.0)), float(np.max(np.abs(ev2), initial=0.0)), 1e-300)
        diff = ((ev2[:, None] - ev1[None, :]) / scale) ** 2  # (k2, k1)
        s = float(diff.mean())
        if s > 0:
            H[np.diag_indices(n)] += weights.laplacian / s * diff.ravel()
    for w, ops, label in (
        (weights.commutativity, commutativity_ops, "commutativity_ops"),
        (weights.orientation, orientation_ops, "orientation_ops"),
    ):
        if w <= 0:
            continue
        if ops is None:
            raise ValueError(f"{label} are required when its weight is positive")
        X, Y = (np.asarray(o, dtype=np.float64) for o in ops)
        if X.ndim != 3 or Y.ndim != 3 or X.shape[1:] != (k1, k1) or Y.shape[1:] != (k2, k2) or len(X) != len(Y):
            raise ValueError(f"{label} must have shapes (f, {k1}, {k1}) and (f, {k2}, {k2}), got {X.shape} and {Y.shape}")
        _add_commutativity(H, X, Y, w * inverse_mean_diagonal(_commutativity_trace(X, Y)))
    H[np.diag_indices(n)] += 1e-10 * max(float(np.trace(H)) / n, 1e-300)
    if not (np.isfinite(H).all() and np.isfinite(rhs).all()):
        raise ValueError("solve_fmap: the system is not finite (non-finite descriptors, eigenvalues or operators)")
    # scipy.linalg.solve(H, rhs, assume_a="pos") bit for bit (the same LAPACK Cholesky on
    # the same Fortran-ordered matrix), without holding the GIL and without its checks' cost
    c = cholesky_solve(np.asfortranarray(H), rhs)
    return c.reshape(k2, k1)


def scale_free_evals(basis: Eigenbasis) -> FloatArray:
    """Eigenvalues times the total area: invariant to a uniform scaling of the shape.

    Returns
    -------
    ndarray, shape (k,)
    """
    return basis.evals * float(basis.mass.sum())


def estimate_fmap(
    mesh_1: TriangleMesh,
    mesh_2: TriangleMesh,
    descriptors_1: FloatArray,
    descriptors_2: FloatArray,
    *,
    k_1: int,
    k_2: int | None = None,
    weights: FmapWeights = FmapWeights(),
    n_operator_descriptors: int = 20,
    orientation_reversing: bool = False,
) -> FloatArray:
    """Functional map ``C_12`` between two meshes from corresponding descriptors.

    Mesh-level wrapper of :func:`solve_fmap`: takes the eigenbases from the meshes,
    projects the descriptors, and builds commutativity and orientation operators from
    ``n_operator_descriptors`` evenly spaced descriptor columns when their weights are
    positive.

    Parameters
    ----------
    mesh_1, mesh_2 : TriangleMesh
    descriptors_1 : ndarray, shape (n1, d)
    descriptors_2 : ndarray, shape (n2, d)
        Column ``j`` of both describes the same quantity.
    k_1 : int
        Basis size on shape 1.
    k_2 : int, optional
        Basis size on shape 2 (default ``k_1``).
    weights : FmapWeights
    n_operator_descriptors : int
    orientation_reversing : bool
        Ask for an orientation-reversing map instead (a mirror image).

    Returns
    -------
    ndarray, shape (k_2, k_1)
    """
    k_2 = k_1 if k_2 is None else k_2
    b1 = mesh_1.eigenbasis(k_1)
    b2 = mesh_2.eigenbasis(k_2)
    d1 = _check_basis_rows("descriptors_1", descriptors_1, mesh_1.n_vertices)
    d2 = _check_basis_rows("descriptors_2", descriptors_2, mesh_2.n_vertices)
    if d1.shape[1] != d2.shape[1]:
        raise ValueError(f"descriptors_1 and descriptors_2 have {d1.shape[1]} and {d2.shape[1]} columns")
    A1 = descriptor_coefficients(b1, d1)
    A2 = descriptor_coefficients(b2, d2)
    cols = np.unique(np.linspace(0, d1.shape[1] - 1, max(1, min(n_operator_descriptors, d1.shape[1]))).round().astype(int))
    comm = orient = None
    if weights.commutativity > 0:
        comm = (multiplication_operators(b1, d1[:, cols]), multiplication_operators(b2, d2[:, cols]))
    if weights.orientation > 0:
        o1 = orientation_operators(mesh_1.vertices, mesh_1.faces, b1, d1[:, cols])
        o2 = orientation_operators(mesh_2.vertices, mesh_2.faces, b2, d2[:, cols])
        orient = (o1, -o2 if orientation_reversing else o2)
    return solve_fmap(
        A1, A2, scale_free_evals(b1), scale_free_evals(b2), weights=weights, commutativity_ops=comm, orientation_ops=orient
    )
