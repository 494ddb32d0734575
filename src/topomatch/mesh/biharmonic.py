"""Biharmonic distance and the Green's function embedding (Lipman, Rustamov, Funkhouser 2010).

Both come from the Laplacian eigenbasis. With ``L phi_i = lambda_i M phi_i`` and
``phi_i`` M-orthonormal, the embedding

    x -> (phi_i(x) / lambda_i)_{i = 2..k}

is (up to truncation) the Green's function ``g_x`` of the Laplacian written in the
eigenbasis, and Euclidean distances between embedded points are biharmonic distances:

    d_B(x, y)^2 = sum_{i >= 2} (phi_i(x) - phi_i(y))^2 / lambda_i^2.

Because ``1 / lambda_i^2`` decays fast, a hundred eigenpairs give the distance to well
under 1 % on the meshes we use; small topological shortcuts move only the upper end of
the spectrum, which is why the SHREC'16 entrants EM and GE use this metric.

All functions can rescale the basis to unit surface area first, so that embeddings of
two shapes of different sizes are comparable (``lambda`` scales like 1 / area, the
M-orthonormal ``phi`` like 1 / sqrt(area)).
"""

from __future__ import annotations

import numpy as np

from topomatch.mesh.spectral import Eigenbasis
from topomatch.typing import FloatArray, IndexArray

__all__ = ["biharmonic_distances", "biharmonic_embedding", "unit_area_basis"]


def unit_area_basis(basis: Eigenbasis, area: float) -> Eigenbasis:
    """The eigenbasis of the same surface rescaled to unit area.

    Parameters
    ----------
    basis : Eigenbasis
        ``k`` eigenpairs of a surface of total area ``area``.
    area : float
        Total surface area (``mesh.area``).

    Returns
    -------
    Eigenbasis
        ``evals * area``, ``evecs * sqrt(area)``, ``mass / area``: still M-orthonormal.
    """
    if not np.isfinite(area) or area <= 0:
        raise ValueError(f"area must be a positive number, got {area}")
    return Eigenbasis(basis.evals * area, basis.evecs * np.sqrt(area), basis.mass / area)


def biharmonic_embedding(basis: Eigenbasis, *, rows: IndexArray | None = None, tol: float = 1e-10) -> FloatArray:
    """Green's function / biharmonic embedding ``phi_i(x) / lambda_i`` for ``i >= 2``.

    Eigenpairs whose eigenvalue is (numerically) zero are left out: the constant
    function, and one per extra connected component.

    Parameters
    ----------
    basis : Eigenbasis
        ``k`` eigenpairs, ascending.
    rows : ndarray of int, shape (m,), optional
        Only these vertices (default: all).
    tol : float
        Eigenvalues below ``tol * max(evals)`` count as zero.

    Returns
    -------
    ndarray, shape (n_vertices or m, k_pos)
        ``k_pos`` = number of positive eigenvalues.
    """
    ev = np.asarray(basis.evals, dtype=np.float64)
    if ev.size == 0:
        raise ValueError("the eigenbasis is empty")
    pos = ev > tol * max(float(ev.max()), 1e-300)
    if not np.any(pos):
        raise ValueError("the eigenbasis has no positive eigenvalue; ask for more eigenpairs")
    phi = basis.evecs if rows is None else basis.evecs[np.asarray(rows, dtype=np.int64)]
    return phi[:, pos] / ev[pos]


def biharmonic_distances(embedding: FloatArray, rows: IndexArray, cols: IndexArray | None = None) -> FloatArray:
    """Biharmonic distances between embedded vertices.

    Parameters
    ----------
    embedding : ndarray, shape (n_vertices, d)
        From :func:`biharmonic_embedding`.
    rows : ndarray of int, shape (a,)
    cols : ndarray of int, shape (b,), optional
        Default: all vertices.

    Returns
    -------
    ndarray, shape (a, b)
    """
    e = np.asarray(embedding, dtype=np.float64)
    if e.ndim != 2:
        raise ValueError(f"embedding must be 2-D (n_vertices, d), got shape {e.shape}")
    a = e[np.asarray(rows, dtype=np.int64)]
    b = e if cols is None else e[np.asarray(cols, dtype=np.int64)]
    d2 = (a**2).sum(1)[:, None] + (b**2).sum(1)[None, :] - 2.0 * a @ b.T
    return np.sqrt(np.maximum(d2, 0.0))
