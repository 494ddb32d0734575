"""ZoomOut: spectral upsampling of a functional map (Melzi et al., SIGGRAPH Asia 2019).

Starting from a small functional map, alternate between the point-to-point map it
induces (nearest neighbours in the aligned spectral embeddings) and the functional map
of that point map one size larger, until the final size. The point maps are computed
on all vertices, or on given vertex samples for speed; the final map is always dense.
"""

from __future__ import annotations

import logging

import numpy as np

from topomatch.maps.conversion import p2p_from_fmap
from topomatch.maps.knn import nearest_neighbors
from topomatch.mesh.spectral import Eigenbasis
from topomatch.typing import FloatArray, IndexArray

__all__ = ["zoomout", "zoomout_schedule"]

logger = logging.getLogger(__name__)


def zoomout_schedule(k_start: int, k_final: int, step: int = 1) -> list[int]:
    """Basis sizes visited by ZoomOut: ``k_start, k_start + step, ..., k_final``.

    Returns
    -------
    list of int
        Strictly increasing, ending with ``k_final``.
    """
    if k_start < 1 or k_final < k_start:
        raise ValueError(f"need 1 <= k_start <= k_final, got k_start={k_start}, k_final={k_final}")
    if step < 1:
        raise ValueError(f"step must be >= 1, got {step}")
    ks = list(range(k_start, k_final + 1, step))
    if ks[-1] != k_final:
        ks.append(k_final)
    return ks


def _fmap_from_p2p_rows(p2p_21: IndexArray, evecs_1: FloatArray, evecs_2: FloatArray, mass_2: FloatArray) -> FloatArray:
    """``C_12`` from a map given on (a sample of) shape 2's vertices, area-weighted.

    With a sample, the projection ``Phi_2^T M_2`` is replaced by a least-squares fit
    of the pulled-back functions on the sample (the sample's basis rows are not
    orthonormal).
    """
    pulled = evecs_1[p2p_21]  # (m, k1)
    w = mass_2[:, None]
    lhs = evecs_2.T @ (w * evecs_2)  # (k2, k2), identity on the full shape
    rhs = evecs_2.T @ (w * pulled)
    return np.linalg.solve(lhs, rhs)


def zoomout(
    C_12: FloatArray,
    basis_1: Eigenbasis,
    basis_2: Eigenbasis,
    *,
    k_final: int,
    step: int = 1,
    samples_1: IndexArray | None = None,
    samples_2: IndexArray | None = None,
    adjoint: bool = False,
) -> tuple[FloatArray, IndexArray]:
    """Upsample ``C_12`` to ``k_final`` and return it with its dense point map.

    Parameters
    ----------
    C_12 : ndarray, shape (k, k) or (k2, k1)
        Initial functional map; ZoomOut starts from its top-left square block of size
        ``min(k1, k2)``.
    basis_1, basis_2 : Eigenbasis with at least ``k_final`` functions
    k_final : int
    step : int
        Growth of the basis size per iteration.
    samples_1, samples_2 : ndarray of int, optional
        Vertex samples on which the intermediate point maps are computed (e.g. a few
        thousand farthest points); ``None`` uses every vertex.
    adjoint : bool
        Use the adjoint nearest-neighbour query for the point maps.

    Returns
    -------
    C_12 : ndarray, shape (k_final, k_final)
    p2p_21 : ndarray, shape (n2,)
        Dense map from the final ``C_12``.
    """
    C = np.asarray(C_12, dtype=np.float64)
    if C.ndim != 2:
        raise ValueError(f"C_12 must be a 2-D array, got shape {C.shape}")
    k0 = min(C.shape)
    if basis_1.k < k_final or basis_2.k < k_final:
        raise ValueError(f"k_final={k_final} exceeds the bases ({basis_1.k} and {basis_2.k} functions)")
    C = C[:k0, :k0]
    n1, n2 = basis_1.evecs.shape[0], basis_2.evecs.shape[0]
    s1 = np.arange(n1) if samples_1 is None else np.asarray(samples_1, dtype=np.int64)
    s2 = np.arange(n2) if samples_2 is None else np.asarray(samples_2, dtype=np.int64)
    e1 = basis_1.evecs[s1]
    e2 = basis_2.evecs[s2]
    m2 = basis_2.mass[s2] * (basis_2.mass.sum() / max(basis_2.mass[s2].sum(), 1e-300))
    for k in zoomout_schedule(k0, k_final, step)[1:]:
        kc = C.shape[0]
        if adjoint:
            p = nearest_neighbors(e1[:, :kc], e2[:, :kc] @ C)
        else:
            p = nearest_neighbors(e1[:, :kc] @ C.T, e2[:, :kc])
        C = _fmap_from_p2p_rows(p, e1[:, :k], e2[:, :k], m2)
    p2p_21 = p2p_from_fmap(C, basis_1.truncate(C.shape[1]), basis_2.truncate(C.shape[0]), adjoint=adjoint)
    return C, p2p_21
