"""LAPACK's Cholesky solve called from compiled code, so that threads solve side by side.

``scipy.linalg.cho_factor`` and ``cho_solve`` hold the GIL while LAPACK runs (measured:
two threads factorising 450 x 450 matrices took as long as one thread doing both
matrices' work). The registrations that :class:`~topomatch.matching.deform.DeformMatcher`
verifies on threads solve such a system in every iteration, so each solve stalled the
other thread. Here the same LAPACK routines of SciPy's own LAPACK (``dpotrf`` then
``dpotrs``, upper triangle, through :mod:`scipy.linalg.cython_lapack`) are called from a
numba function that releases the GIL (:func:`topomatch._kernels.cholesky_factor_solve`):
the same routine on the same Fortran-ordered matrix, hence the same bits as
``cho_solve(cho_factor(a, lower=False), b)``.

:func:`banded_cholesky_solve` does the same for band matrices (``dpbtrf`` then ``dpbtrs``,
the routines of SciPy's ``cholesky_banded`` and ``cho_solve_banded``). Where the LAPACK
entry points cannot be found (an unusual SciPy build), both fall back to SciPy's
functions, with the same results.

:func:`register_lapack_symbol` gives numba kernels a LAPACK routine by name, so that they
are cached on disk: that solve, and the registration's rotation step
(:func:`topomatch._kernels.rotation_step`), which calls ``dgesdd`` for its 3 x 3 SVDs as
numba's ``np.linalg.svd`` does, with its buffers and workspace made once per step instead
of once per node (the same bits, about a third less time).
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable

import numpy as np
from scipy.linalg import cho_factor, cho_solve, cho_solve_banded, cholesky_banded

from topomatch.typing import FloatArray

__all__ = ["banded_cholesky_solve", "cholesky_solve", "register_lapack_symbol"]


def _lapack_address(name: str) -> int:
    """The address of a routine of :mod:`scipy.linalg.cython_lapack` (a PyCapsule in its C API table)."""
    from scipy.linalg import cython_lapack

    capsule = cython_lapack.__pyx_capi__[name]
    get_name = ctypes.pythonapi.PyCapsule_GetName
    get_name.restype = ctypes.c_char_p
    get_name.argtypes = [ctypes.py_object]
    get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
    get_pointer.restype = ctypes.c_void_p
    get_pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
    address = get_pointer(capsule, get_name(capsule))
    if not address:
        raise RuntimeError(f"no address for LAPACK {name}")
    return int(address)


@functools.cache
def register_lapack_symbol(symbol: str, name: str) -> None:
    """Make routine ``name`` of :mod:`scipy.linalg.cython_lapack` known to numba's linker as ``symbol``.

    Compiled code that declares ``numba.types.ExternalFunction(symbol, ...)`` then calls it
    by name, so that it can be cached on disk (a ctypes function's address would be baked
    in, and it changes from process to process). numba's own ``np.linalg`` functions
    reach LAPACK through the same table of SciPy's.
    """
    import llvmlite.binding

    llvmlite.binding.add_symbol(symbol, _lapack_address(name))


@functools.cache
def _compiled(name: str = "cholesky_factor_solve") -> Callable[[FloatArray, FloatArray], int] | None:
    """A compiled factorise-and-solve of :mod:`topomatch._kernels` (``cholesky_factor_solve`` or ``banded_cholesky_factor_solve``), or ``None`` when LAPACK's entry points are not reachable."""
    try:
        from topomatch import _kernels
    except Exception:  # pragma: no cover - unusual SciPy builds
        return None
    return getattr(_kernels, name)  # type: ignore[no-any-return]


def cholesky_solve(a: FloatArray, b: FloatArray) -> FloatArray:
    """Solve ``a x = b`` for a symmetric positive definite ``a`` from its upper triangle, without the GIL.

    Bit for bit ``cho_solve(cho_factor(a, lower=False, check_finite=False), b)``.

    Parameters
    ----------
    a : ndarray, shape (n, n)
        Only the upper triangle is read. Overwritten by the factor when it is
        Fortran-ordered float64 (build it with ``order="F"`` to avoid a copy).
    b : ndarray, shape (n,) or (n, r)

    Returns
    -------
    ndarray, shape of ``b``

    Raises
    ------
    numpy.linalg.LinAlgError
        When ``a`` is not positive definite.
    """
    A = np.asfortranarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or b.shape[:1] != A.shape[:1] or b.ndim not in (1, 2):
        raise ValueError(f"cholesky_solve: a must be (n, n) and b (n,) or (n, r), got {A.shape} and {b.shape}")
    fn = _compiled()
    if fn is None:  # unusual SciPy builds
        return cho_solve(cho_factor(A, lower=False, overwrite_a=True, check_finite=False), b, check_finite=False)
    B = np.array(b.reshape(len(b), -1), dtype=np.float64, order="F")
    _check_info(fn(A, B))
    return B.reshape(b.shape)


def banded_cholesky_solve(ab: FloatArray, b: FloatArray) -> FloatArray:
    """Solve ``a x = b`` for a symmetric positive definite band matrix in LAPACK's upper band storage, without the GIL.

    LAPACK's ``dpbtrf`` then ``dpbtrs`` (:func:`topomatch._kernels.banded_cholesky_factor_solve`).

    Parameters
    ----------
    ab : ndarray, shape (kd + 1, n)
        ``ab[kd + i - j, j] = a[i, j]`` for ``max(0, j - kd) <= i <= j``; Fortran-ordered
        float64, overwritten by the factor.
    b : ndarray, shape (n,) or (n, r)

    Returns and raises as :func:`cholesky_solve` (bit for bit SciPy's ``cho_solve_banded(
    (cholesky_banded(ab), False), b)``, the same two routines, which it falls back to).
    """
    fn = _compiled("banded_cholesky_factor_solve")
    if fn is None:  # unusual SciPy builds
        factor = cholesky_banded(ab, overwrite_ab=True, lower=False, check_finite=False)
        return cho_solve_banded((factor, False), b, check_finite=False)
    B = np.array(np.reshape(b, (len(b), -1)), dtype=np.float64, order="F")
    _check_info(fn(ab, B))
    return B.reshape(np.shape(b))


def _check_info(info: int) -> None:
    """Raise for a Cholesky routine's nonzero LAPACK ``info``."""
    if info > 0:
        raise np.linalg.LinAlgError(f"{info}-th leading minor of the array is not positive definite")
    if info < 0:  # pragma: no cover - the arguments are built here
        raise ValueError(f"LAPACK: illegal value in the {-info}-th argument")
