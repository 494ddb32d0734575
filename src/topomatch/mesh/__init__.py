"""Triangle meshes: geometry, Laplacian, eigenbasis, geodesics, sampling."""

from topomatch.mesh.geodesics import (
    DijkstraGeodesicSolver,
    ExactGeodesicSolver,
    GeodesicKind,
    GeodesicSolver,
    HeatGeodesicSolver,
    make_geodesic_solver,
)
from topomatch.mesh.laplacian import (
    cotangent_laplacian,
    gradient_operator,
    laplacian,
    robust_laplacian,
)
from topomatch.mesh.mesh import TriangleMesh
from topomatch.mesh.sampling import farthest_point_sampling
from topomatch.mesh.spectral import Eigenbasis, SparseCholesky, laplacian_eigenbasis

__all__ = [
    "DijkstraGeodesicSolver",
    "Eigenbasis",
    "ExactGeodesicSolver",
    "GeodesicKind",
    "GeodesicSolver",
    "HeatGeodesicSolver",
    "SparseCholesky",
    "TriangleMesh",
    "cotangent_laplacian",
    "farthest_point_sampling",
    "gradient_operator",
    "laplacian",
    "laplacian_eigenbasis",
    "make_geodesic_solver",
    "robust_laplacian",
]
