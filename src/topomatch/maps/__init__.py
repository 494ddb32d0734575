"""Point-to-point and functional maps."""

from topomatch.maps.conversion import fmap_from_p2p, p2p_from_fmap
from topomatch.maps.fmap import (
    FmapWeights,
    descriptor_coefficients,
    estimate_fmap,
    multiplication_operators,
    orientation_operators,
    scale_free_evals,
    solve_fmap,
)
from topomatch.maps.knn import nearest_neighbors
from topomatch.maps.operations import (
    compose_p2p,
    coverage,
    folded_fraction,
    invert_p2p,
    transfer_function,
)
from topomatch.maps.symmetry import flip_mirror_patches
from topomatch.maps.zoomout import zoomout, zoomout_schedule

__all__ = [
    "FmapWeights",
    "compose_p2p",
    "coverage",
    "descriptor_coefficients",
    "estimate_fmap",
    "flip_mirror_patches",
    "fmap_from_p2p",
    "folded_fraction",
    "invert_p2p",
    "multiplication_operators",
    "nearest_neighbors",
    "orientation_operators",
    "p2p_from_fmap",
    "scale_free_evals",
    "solve_fmap",
    "transfer_function",
    "zoomout",
    "zoomout_schedule",
]
