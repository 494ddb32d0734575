"""Point-to-point and functional maps."""

from topomatch.maps.conversion import fmap_from_p2p, p2p_from_fmap
from topomatch.maps.knn import nearest_neighbors

__all__ = ["fmap_from_p2p", "nearest_neighbors", "p2p_from_fmap"]
