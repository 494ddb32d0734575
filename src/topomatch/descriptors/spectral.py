"""Spectral point descriptors: heat kernel signature and wave kernel signature.

Array-level functions take ``(evals, evecs)``; mesh-level wrappers take a
:class:`~topomatch.mesh.TriangleMesh`.
"""

from __future__ import annotations

import numpy as np

from topomatch._blas import one_blas_thread
from topomatch.mesh import Eigenbasis, TriangleMesh
from topomatch.typing import FloatArray

__all__ = ["hks", "hks_times", "mesh_hks", "mesh_wks", "wks", "wks_energies"]


def hks_times(evals: FloatArray, n_times: int) -> FloatArray:
    """Log-spaced diffusion times from ``4 ln 10 / lambda_max`` to ``4 ln 10 / lambda_1``.

    ``lambda_1`` is the first non-zero eigenvalue (Sun, Ovsjanikov, Guibas 2009).
    """
    ev = np.asarray(evals, dtype=np.float64)
    pos = ev[ev > 1e-10 * max(float(ev.max(initial=0.0)), 1e-300)]
    if pos.size == 0:
        raise ValueError("need at least one positive eigenvalue to choose HKS times")
    tmin = 4 * np.log(10) / pos.max()
    tmax = 4 * np.log(10) / pos.min()
    return np.geomspace(tmin, tmax, n_times)


def hks(evals: FloatArray, evecs: FloatArray, times: FloatArray, *, scaled: bool = True) -> FloatArray:
    """Heat kernel signature ``sum_i exp(-t lambda_i) phi_i(x)^2``.

    Parameters
    ----------
    evals : ndarray, shape (k,)
    evecs : ndarray, shape (n_vertices, k)
    times : ndarray, shape (n_times,)
    scaled : bool
        Divide each time's column by ``sum_i exp(-t lambda_i)`` (scale-invariant form).

    Returns
    -------
    ndarray, shape (n_vertices, n_times)
    """
    coefs = np.exp(-np.outer(times, evals))  # (n_times, k)
    with one_blas_thread():  # the same bits whatever the BLAS threads
        out = (evecs**2) @ coefs.T  # (n_vertices, n_times)
    if scaled:
        out /= coefs.sum(axis=1)[None, :]
    return out


def wks_energies(evals: FloatArray, n_energies: int, sigma_factor: float = 7.0) -> tuple[FloatArray, float]:
    """Log-energies spanning the spectrum and the Gaussian width (Aubry et al. 2011).

    Returns
    -------
    energies : ndarray, shape (n_energies,)
    sigma : float
    """
    ev = np.asarray(evals, dtype=np.float64)
    pos = ev[ev > 1e-10 * max(float(ev.max(initial=0.0)), 1e-300)]
    if pos.size < 2:
        raise ValueError("need at least two positive eigenvalues for the WKS")
    lmin, lmax = np.log(pos.min()), np.log(pos.max())
    sigma = sigma_factor * (lmax - lmin) / n_energies
    e = np.linspace(lmin + 2 * sigma, lmax - 2 * sigma, n_energies)
    return e, float(sigma)


def wks(evals: FloatArray, evecs: FloatArray, energies: FloatArray, sigma: float) -> FloatArray:
    """Wave kernel signature with Gaussian bands in log-eigenvalue.

    ``WKS(x, e) = sum_i phi_i(x)^2 exp(-(e - log lambda_i)^2 / (2 sigma^2)) / C_e``,
    zero eigenvalues excluded.

    Returns
    -------
    ndarray, shape (n_vertices, n_energies)
    """
    ev = np.asarray(evals, dtype=np.float64)
    pos = ev > 1e-10 * max(float(ev.max(initial=0.0)), 1e-300)
    logl = np.log(ev[pos])
    coefs = np.exp(-((np.asarray(energies)[:, None] - logl[None, :]) ** 2) / (2 * sigma**2))  # (n_e, k)
    with one_blas_thread():  # the same bits whatever the BLAS threads
        out = (evecs[:, pos] ** 2) @ coefs.T
    out /= coefs.sum(axis=1)[None, :]
    return out


def _basis(mesh: TriangleMesh | Eigenbasis, k: int) -> Eigenbasis:
    return mesh.eigenbasis(k) if isinstance(mesh, TriangleMesh) else mesh.truncate(min(k, mesh.k))


def mesh_hks(mesh: TriangleMesh | Eigenbasis, n_times: int = 16, k: int = 100) -> FloatArray:
    """HKS of a mesh with automatic times; shape (n_vertices, n_times)."""
    b = _basis(mesh, k)
    return hks(b.evals, b.evecs, hks_times(b.evals, n_times))


def mesh_wks(mesh: TriangleMesh | Eigenbasis, n_energies: int = 100, k: int = 100) -> FloatArray:
    """WKS of a mesh with automatic energies; shape (n_vertices, n_energies)."""
    b = _basis(mesh, k)
    e, s = wks_energies(b.evals, n_energies)
    return wks(b.evals, b.evecs, e, s)
