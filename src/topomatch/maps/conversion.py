"""Conversions between point-to-point maps and functional maps.

Convention (pyFM's): ``p2p_21`` has one entry per vertex of shape 2, an index on
shape 1 (a map T: S2 -> S1). Its functional map ``C_12`` carries spectral coefficients
on shape 1 to shape 2 (the pull-back of functions by T), shape ``(k2, k1)``:
``C_12 = Phi_2^+ Pi_21 Phi_1`` with ``Phi_2^+ = Phi_2^T M_2``.
"""

from __future__ import annotations

import numpy as np

from topomatch.maps.knn import nearest_neighbors
from topomatch.mesh.spectral import Eigenbasis
from topomatch.typing import FloatArray, IndexArray

__all__ = ["fmap_from_p2p", "p2p_from_fmap"]


def fmap_from_p2p(p2p_21: IndexArray, basis_1: Eigenbasis, basis_2: Eigenbasis) -> FloatArray:
    """Functional map ``C_12`` of a point-to-point map ``p2p_21``.

    Unmatched entries (``-1``) contribute nothing.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n2,)
    basis_1 : Eigenbasis with ``k1`` functions on shape 1
    basis_2 : Eigenbasis with ``k2`` functions on shape 2

    Returns
    -------
    ndarray, shape (k2, k1)
    """
    p = np.asarray(p2p_21, dtype=np.int64)
    if len(p) != basis_2.evecs.shape[0]:
        raise ValueError(f"p2p_21 has {len(p)} entries, shape 2 has {basis_2.evecs.shape[0]} vertices")
    ok = p >= 0
    pulled = np.zeros((len(p), basis_1.k))
    pulled[ok] = basis_1.evecs[p[ok]]  # (n2, k1): basis functions of shape 1 pulled back to shape 2
    return basis_2.project(pulled)


def p2p_from_fmap(C_12: FloatArray, basis_1: Eigenbasis, basis_2: Eigenbasis, *, adjoint: bool = False) -> IndexArray:
    """Point-to-point map ``p2p_21`` recovered from ``C_12`` by nearest neighbours.

    Each vertex of shape 2 is matched to the vertex of shape 1 whose transported
    spectral embedding is closest: rows of ``Phi_2`` against rows of ``Phi_1 C_12^T``
    (Ovsjanikov et al. 2012). With ``adjoint=True`` the adjoint formulation is used
    instead (rows of ``Phi_2 C_12`` against rows of ``Phi_1``), which is more
    accurate when ``C_12`` is far from orthogonal (Magnet et al.).

    Parameters
    ----------
    C_12 : ndarray, shape (k2, k1)
    basis_1, basis_2 : Eigenbasis with at least ``k1`` / ``k2`` functions

    Returns
    -------
    ndarray, shape (n2,)
    """
    k2, k1 = C_12.shape
    phi1 = basis_1.evecs[:, :k1]
    phi2 = basis_2.evecs[:, :k2]
    if adjoint:
        return nearest_neighbors(phi1, phi2 @ C_12)
    return nearest_neighbors(phi1 @ C_12.T, phi2)
