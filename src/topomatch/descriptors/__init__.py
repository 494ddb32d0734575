"""Point descriptors."""

from topomatch.descriptors.spectral import hks, hks_times, mesh_hks, mesh_wks, wks, wks_energies

__all__ = ["hks", "hks_times", "mesh_hks", "mesh_wks", "wks", "wks_energies"]
