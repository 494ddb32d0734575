"""Point-to-point and functional maps."""

from topomatch.maps.knn import nearest_neighbors

__all__ = ["nearest_neighbors"]
