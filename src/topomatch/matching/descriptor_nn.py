"""Baseline: nearest neighbours in spectral descriptor space."""

from __future__ import annotations

from typing import Literal

from topomatch.maps.knn import nearest_neighbors
from topomatch.matching.base import Correspondence, Matcher
from topomatch.matching.fmap import spectral_descriptors
from topomatch.mesh import TriangleMesh
from topomatch.typing import FloatArray

__all__ = ["DescriptorNNMatcher"]


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
        return spectral_descriptors(mesh, self.descriptor, self.n_descriptors, self.k)

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:  # noqa: D102
        d1 = self._describe(source)
        d2 = self._describe(target)
        return Correspondence(nearest_neighbors(d1, d2))
