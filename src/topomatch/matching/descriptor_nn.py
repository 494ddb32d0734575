"""Baseline: nearest neighbours in spectral descriptor space."""

from __future__ import annotations

from typing import Literal

import numpy as np

from topomatch.descriptors import mesh_hks, mesh_wks
from topomatch.maps.knn import nearest_neighbors
from topomatch.matching.base import Correspondence, Matcher
from topomatch.mesh import TriangleMesh
from topomatch.typing import FloatArray

__all__ = ["DescriptorNNMatcher"]


def _normalize(desc: FloatArray, mass: FloatArray) -> FloatArray:
    """Scale each descriptor dimension to unit area-weighted L2 norm."""
    norms = np.sqrt(mass @ desc**2)
    return desc / np.where(norms > 0, norms, 1.0)


class DescriptorNNMatcher(Matcher):
    """Each target vertex goes to the source vertex with the closest descriptor.

    Descriptors are computed independently on each shape from its Laplacian
    eigenbasis (HKS or WKS), each dimension normalised to unit area-weighted norm.
    No spatial regularity is imposed: intrinsic descriptors cannot tell left from
    right, so the map mixes the two sides. This is the floor every method should beat.

    Parameters
    ----------
    descriptor : {"wks", "hks"}
    n_descriptors : int
        Energies (WKS) or times (HKS).
    k : int
        Eigenpairs used.
    """

    name = "descriptor-nn"

    def __init__(self, *, descriptor: Literal["wks", "hks"] = "wks", n_descriptors: int = 100, k: int = 100) -> None:
        self.descriptor = descriptor
        self.n_descriptors = n_descriptors
        self.k = k

    def _describe(self, mesh: TriangleMesh) -> FloatArray:
        basis = mesh.eigenbasis(self.k)
        if self.descriptor == "wks":
            d = mesh_wks(basis, self.n_descriptors, self.k)
        elif self.descriptor == "hks":
            d = mesh_hks(basis, self.n_descriptors, self.k)
        else:
            raise ValueError(f"descriptor must be 'wks' or 'hks', got {self.descriptor!r}")
        return _normalize(d, basis.mass)

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:  # noqa: D102
        d1 = self._describe(source)
        d2 = self._describe(target)
        return Correspondence(nearest_neighbors(d1, d2))
