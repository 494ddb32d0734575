"""Functional map matcher: descriptors -> functional map -> point-to-point map."""

from __future__ import annotations

from typing import Literal

import numpy as np

from topomatch.descriptors import mesh_hks, mesh_wks, normalize_descriptors
from topomatch.maps.conversion import p2p_from_fmap
from topomatch.maps.fmap import FmapWeights, estimate_fmap
from topomatch.matching.base import Correspondence, Matcher
from topomatch.mesh import TriangleMesh
from topomatch.typing import FloatArray

__all__ = ["FunctionalMapMatcher", "spectral_descriptors"]


def spectral_descriptors(
    mesh: TriangleMesh, kind: Literal["wks", "hks"] = "wks", n_descriptors: int = 100, k: int = 100
) -> FloatArray:
    """WKS or HKS of a mesh, each column scaled to unit area-weighted norm.

    Returns
    -------
    ndarray, shape (n_vertices, n_descriptors)
    """
    basis = mesh.eigenbasis(k)
    if kind == "wks":
        d = mesh_wks(basis, n_descriptors, k)
    elif kind == "hks":
        d = mesh_hks(basis, n_descriptors, k)
    else:
        raise ValueError(f"descriptor must be 'wks' or 'hks', got {kind!r}")
    return normalize_descriptors(d, basis.mass)


class FunctionalMapMatcher(Matcher):
    """Functional map from descriptor preservation, converted to a point map.

    The map minimises descriptor preservation + Laplacian commutativity + descriptor
    commutativity + an orientation-preserving term (see :mod:`topomatch.maps.fmap`),
    then each target vertex takes the nearest source vertex in the aligned spectral
    embeddings. No refinement: this is the classic pipeline of Ovsjanikov et al. 2012.

    Parameters
    ----------
    descriptor : {"wks", "hks"}
    n_descriptors : int
        Energies (WKS) or times (HKS).
    k_descriptors : int
        Eigenpairs used to compute the descriptors.
    k : int
        Functional map size.
    w_laplacian, w_commutativity, w_orientation : float
        Relative weights (descriptor preservation has weight 1).
    n_operator_descriptors : int
        Descriptors used to build commutativity and orientation operators.
    """

    name = "fmap"

    def __init__(
        self,
        *,
        descriptor: Literal["wks", "hks"] = "wks",
        n_descriptors: int = 100,
        k_descriptors: int = 100,
        k: int = 30,
        w_laplacian: float = 1e-2,
        w_commutativity: float = 1e-1,
        w_orientation: float = 1.0,
        n_operator_descriptors: int = 20,
    ) -> None:
        self.descriptor = descriptor
        self.n_descriptors = n_descriptors
        self.k_descriptors = k_descriptors
        self.k = k
        self.w_laplacian = w_laplacian
        self.w_commutativity = w_commutativity
        self.w_orientation = w_orientation
        self.n_operator_descriptors = n_operator_descriptors

    def _check(self) -> None:
        for name in ("n_descriptors", "k_descriptors", "k", "n_operator_descriptors"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        for name in ("w_laplacian", "w_commutativity", "w_orientation"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")

    def estimate(self, source: TriangleMesh, target: TriangleMesh) -> FloatArray:
        """Estimate the functional map ``C_12``, shape (k, k)."""
        self._check()
        d1 = spectral_descriptors(source, self.descriptor, self.n_descriptors, self.k_descriptors)
        d2 = spectral_descriptors(target, self.descriptor, self.n_descriptors, self.k_descriptors)
        weights = FmapWeights(
            descriptors=1.0, laplacian=self.w_laplacian, commutativity=self.w_commutativity, orientation=self.w_orientation
        )
        return estimate_fmap(source, target, d1, d2, k_1=self.k, weights=weights, n_operator_descriptors=self.n_operator_descriptors)

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:  # noqa: D102
        C = self.estimate(source, target)
        p2p = p2p_from_fmap(C, source.eigenbasis(self.k), target.eigenbasis(self.k))
        return Correspondence(p2p, fmap_12=C, info={"k": self.k})
