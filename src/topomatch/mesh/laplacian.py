"""Laplace-Beltrami operators: PSD stiffness ``L`` and lumped mass ``M``.

Convention: ``L`` is symmetric positive semi-definite (rows sum to zero), ``M`` is a
diagonal lumped mass; the generalised eigenproblem is ``L phi = lambda M phi``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy import sparse

from topomatch.mesh.geometry import face_areas
from topomatch.typing import FloatArray, IndexArray

__all__ = ["LaplacianKind", "cotangent_laplacian", "gradient_operator", "laplacian", "robust_laplacian"]

LaplacianKind = Literal["robust", "cotan"]


def cotangent_laplacian(vertices: FloatArray, faces: IndexArray) -> tuple[sparse.csc_matrix, sparse.dia_matrix]:
    """Plain cotangent Laplacian and barycentric lumped mass on the given triangulation.

    Degenerate (zero-area) faces contribute nothing. On meshes with obtuse or sliver
    triangles ``L`` has negative off-diagonal entries but stays PSD, because
    ``L = G^T diag(A) G`` (see :func:`gradient_operator`).

    Returns
    -------
    L : scipy.sparse.csc_matrix, shape (n_vertices, n_vertices)
    M : scipy.sparse.dia_matrix, shape (n_vertices, n_vertices)
    """
    n = len(vertices)
    area = face_areas(vertices, faces)
    ok = area > 0
    f = faces[ok]
    a = area[ok]
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = f[:, (k + 1) % 3], f[:, (k + 2) % 3], f[:, k]
        e1 = vertices[i] - vertices[o]
        e2 = vertices[j] - vertices[o]
        cot = np.einsum("ij,ij->i", e1, e2) / (2.0 * a)  # |e1||e2|cos / (|e1 x e2|) with 2a = |e1 x e2|
        w = 0.5 * cot
        rows += [i, j]
        cols += [j, i]
        vals += [-w, -w]
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    v = np.concatenate(vals)
    off = sparse.coo_matrix((v, (r, c)), shape=(n, n)).tocsr()
    lap = off - sparse.diags(np.asarray(off.sum(axis=1)).ravel())
    mass = np.zeros(n)
    for k in range(3):
        np.add.at(mass, f[:, k], a / 3.0)
    return lap.tocsc(), sparse.diags(mass)


def gradient_operator(vertices: FloatArray, faces: IndexArray) -> tuple[sparse.csr_matrix, FloatArray]:
    """Per-face gradient of piecewise-linear functions.

    Returns
    -------
    G : scipy.sparse.csr_matrix, shape (3 * n_faces, n_vertices)
        Row ``3 f + d`` gives component ``d`` of the gradient on face ``f``.
    areas : ndarray, shape (n_faces,)
        Face areas; ``G^T diag(repeat(areas, 3)) G`` is the cotangent Laplacian.
        Degenerate faces get zero rows.
    """
    n = len(vertices)
    v = [vertices[faces[:, k]] for k in range(3)]
    nrm = np.cross(v[1] - v[0], v[2] - v[0])
    dbl = np.linalg.norm(nrm, axis=1)  # twice the area
    ok = dbl > 0
    unit = np.divide(nrm, dbl[:, None], out=np.zeros_like(nrm), where=ok[:, None])
    rows, cols, vals = [], [], []
    fidx = np.arange(len(faces))
    for k in range(3):
        e = v[(k + 2) % 3] - v[(k + 1) % 3]  # edge opposite corner k
        g = np.cross(unit, e) / np.where(ok, dbl, 1.0)[:, None]  # (n_faces, 3)
        g[~ok] = 0.0
        for d in range(3):
            rows.append(3 * fidx + d)
            cols.append(faces[:, k])
            vals.append(g[:, d])
    G = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * len(faces), n))
    return G, 0.5 * dbl


def robust_laplacian(vertices: FloatArray, faces: IndexArray, mollify_factor: float = 1e-5) -> tuple[sparse.csc_matrix, sparse.dia_matrix]:
    """Intrinsic-Delaunay Laplacian on the tufted cover (Sharp & Crane 2020).

    Correct on non-manifold edges and vertices, boundaries, degenerate and duplicated
    faces: the operator used throughout topomatch by default. Wraps
    ``robust_laplacian.mesh_laplacian``.

    Returns
    -------
    L : scipy.sparse.csc_matrix, shape (n_vertices, n_vertices)
        PSD stiffness.
    M : scipy.sparse.dia_matrix, shape (n_vertices, n_vertices)
        Lumped mass (zero for vertices in no face).

    References
    ----------
    N. Sharp and K. Crane, "A Laplacian for Nonmanifold Triangle Meshes", SGP 2020.
    """
    import robust_laplacian as rl

    L, M = rl.mesh_laplacian(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        mollify_factor=mollify_factor,
    )
    return sparse.csc_matrix(L), sparse.diags(M.diagonal())


def laplacian(vertices: FloatArray, faces: IndexArray, kind: LaplacianKind = "robust") -> tuple[sparse.csc_matrix, sparse.dia_matrix]:
    """Stiffness and mass of the requested kind (``"robust"`` or ``"cotan"``).

    Vertices that belong to no face get a zero row, column and mass, whatever the
    backend does with them, so that they drop out of eigenproblems.
    """
    if kind == "robust":
        L, M = robust_laplacian(vertices, faces)
    elif kind == "cotan":
        L, M = cotangent_laplacian(vertices, faces)
    else:
        raise ValueError(f"unknown Laplacian kind {kind!r}; expected 'robust' or 'cotan'")
    used = np.zeros(len(vertices), dtype=bool)
    used[np.asarray(faces).ravel()] = True
    if not np.all(used):
        keep = sparse.diags(used.astype(np.float64))
        L = (keep @ L @ keep).tocsc()
        L.eliminate_zeros()
        M = sparse.diags(np.where(used, M.diagonal(), 0.0))
    return L, M
