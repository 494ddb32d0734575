"""Point descriptors."""

from topomatch.descriptors.processing import normalize_descriptors
from topomatch.descriptors.spectral import hks, hks_times, mesh_hks, mesh_wks, wks, wks_energies

__all__ = ["hks", "hks_times", "mesh_hks", "mesh_wks", "normalize_descriptors", "wks", "wks_energies"]
