"""Laplacian eigenbasis by shift-invert Lanczos with a sparse Cholesky factorisation."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import linalg as sla

from topomatch._blas import one_blas_thread
from topomatch.typing import FloatArray

__all__ = ["Eigenbasis", "SparseCholesky", "laplacian_eigenbasis"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Eigenbasis:
    """Smallest eigenpairs of ``L phi = lambda M phi``.

    Attributes
    ----------
    evals : ndarray, shape (k,)
        Ascending eigenvalues, ``evals[0]`` close to zero.
    evecs : ndarray, shape (n_vertices, k)
        ``M``-orthonormal eigenvectors: ``evecs.T @ (mass[:, None] * evecs) = I``.
    mass : ndarray, shape (n_vertices,)
        Lumped mass diagonal.
    """

    evals: FloatArray
    evecs: FloatArray
    mass: FloatArray

    @property
    def k(self) -> int:
        """Number of eigenpairs."""
        return len(self.evals)

    def truncate(self, k: int) -> Eigenbasis:
        """First ``k`` eigenpairs."""
        if k > self.k:
            raise ValueError(f"asked for {k} eigenpairs, the basis holds {self.k}")
        return Eigenbasis(self.evals[:k], self.evecs[:, :k], self.mass)

    def project(self, f: FloatArray) -> FloatArray:
        """Spectral coefficients ``evecs.T M f`` of ``f`` (shape (n_vertices,) or (n_vertices, d))."""
        f = np.asarray(f, dtype=np.float64)
        mf = self.mass * f if f.ndim == 1 else self.mass[:, None] * f
        return self.evecs.T @ mf

    def reconstruct(self, coeffs: FloatArray) -> FloatArray:
        """Function from spectral coefficients (shape (k,) or (k, d))."""
        return self.evecs @ coeffs


class SparseCholesky:
    """Factorisation of a sparse SPD matrix with ``solve`` for one or many right-hand sides.

    Uses CHOLMOD through ``cholespy`` when available and SuperLU otherwise.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite (both triangles stored). A CSC matrix goes to
        CHOLMOD as it is; other formats through COO.
    """

    def __init__(self, A: sparse.spmatrix) -> None:
        if not (sparse.issparse(A) and A.format == "csc"):
            A = sparse.coo_matrix(A)
        self.n = A.shape[0]
        self._chol = None
        try:
            from cholespy import CholeskySolverD, MatrixType

            if A.format == "csc":  # CHOLMOD's own format: no conversion
                arrays, kind = (A.indptr, A.indices), MatrixType.CSC
            else:
                arrays, kind = (A.row, A.col), MatrixType.COO
            self._chol = CholeskySolverD(
                self.n,
                *(np.ascontiguousarray(a, dtype=np.int32) for a in arrays),
                np.ascontiguousarray(A.data, dtype=np.float64),
                kind,
            )
        except ImportError:  # pragma: no cover - cholespy is a core dependency
            self._lu = sla.splu(sparse.csc_matrix(A))
        except (ValueError, RuntimeError) as err:  # not positive definite: fall back to LU
            logger.warning("Cholesky factorisation failed (%s); using SuperLU", err)
            self._lu = sla.splu(sparse.csc_matrix(A))

    def solve(self, b: FloatArray) -> FloatArray:
        """Solve ``A x = b`` for ``b`` of shape (n,) or (n, m)."""
        b = np.ascontiguousarray(b, dtype=np.float64)
        if self._chol is None:
            return self._lu.solve(b)
        x = np.empty_like(b)
        self._chol.solve(b, x)
        return x


def laplacian_eigenbasis(
    L: sparse.spmatrix,
    M: sparse.spmatrix,
    k: int,
    *,
    shift: float | None = None,
) -> Eigenbasis:
    """Smallest ``k`` eigenpairs of ``L phi = lambda M phi``.

    Shift-invert Lanczos (ARPACK ``eigsh``) around ``-shift`` with the operator
    ``(L + shift M)^{-1}`` applied by a sparse Cholesky factorisation. The start vector is
    fixed and eigenvector signs are normalised (largest-magnitude entry positive), so the
    result is reproducible. Vertices with (numerically) zero mass, i.e. in no face, are left out of the
    solve and get zero in every eigenvector.

    Parameters
    ----------
    L : scipy.sparse matrix, shape (n_vertices, n_vertices)
        PSD stiffness.
    M : scipy.sparse matrix, shape (n_vertices, n_vertices)
        Diagonal lumped mass.
    k : int
        Number of eigenpairs, ``1 <= k < n_vertices``.
    shift : float, optional
        Positive shift; default ``1e-8`` times the mean of ``diag(L) / diag(M)``.

    Returns
    -------
    Eigenbasis
    """
    mass = np.asarray(M.diagonal(), dtype=np.float64)
    n_all = len(mass)
    used = mass > 1e-12 * float(mass.max(initial=0.0))  # vertices in no face carry (almost) no mass
    n = int(used.sum())
    if not 1 <= k < n:
        raise ValueError(f"k must satisfy 1 <= k < n_vertices ({n}), got {k}")
    L = sparse.csc_matrix(L)
    if not np.all(used):
        idx = np.flatnonzero(used)
        L = L[idx][:, idx]
    m = mass[used]
    if shift is None:
        shift = 1e-8 * float(np.mean(L.diagonal() / m))
    A = (L + sparse.diags(shift * m)).tocsc()
    chol = SparseCholesky(A)
    op = sla.LinearOperator((n, n), matvec=chol.solve, matmat=chol.solve, dtype=np.float64)
    v0 = np.random.default_rng(12345).standard_normal(n)
    Mu = sparse.diags(m).tocsc()
    # One BLAS thread: ARPACK's small dense updates gain little from threads on a quiet
    # machine and lose 10x or more when cores are shared (measured 1.3 s against 19 s for
    # k = 100 on an 11K-vertex mesh with the two cores busy), and a fixed thread count
    # makes the basis bit-for-bit independent of how many processes run.
    with one_blas_thread():
        if k >= n - 1 or n < 40:
            evals, evecs = _dense_eig(L, m, k)
        else:
            evals, evecs = sla.eigsh(L, k=k, M=Mu, sigma=-shift, which="LM", OPinv=op, v0=v0)
    order = np.argsort(evals)
    evals = evals[order]
    evecs = evecs[:, order]
    # M-normalise (ARPACK already does up to rounding) and fix signs
    norms = np.sqrt(np.einsum("ij,ij,i->j", evecs, evecs, m))
    evecs = evecs / norms
    big = np.argmax(np.abs(evecs), axis=0)
    evecs = evecs * np.sign(evecs[big, np.arange(evecs.shape[1])])
    evals = np.maximum(evals, 0.0)
    if not np.all(used):
        full = np.zeros((n_all, k))
        full[used] = evecs
        evecs = full
    return Eigenbasis(evals=evals, evecs=evecs, mass=mass)


def _dense_eig(L: sparse.spmatrix, m: FloatArray, k: int) -> tuple[FloatArray, FloatArray]:
    from scipy.linalg import eigh

    w, v = eigh(L.toarray(), np.diag(m))
    return w[:k], v[:, :k]
