"""Descriptor post-processing shared by the matchers."""

from __future__ import annotations

import numpy as np

from topomatch.typing import FloatArray

__all__ = ["normalize_descriptors"]


def normalize_descriptors(descriptors: FloatArray, mass: FloatArray) -> FloatArray:
    """Scale each descriptor column to unit area-weighted L2 norm.

    Parameters
    ----------
    descriptors : ndarray, shape (n_vertices, d)
    mass : ndarray, shape (n_vertices,)
        Lumped vertex areas.

    Returns
    -------
    ndarray, shape (n_vertices, d)
        Columns with zero norm are left unchanged.
    """
    d = np.asarray(descriptors, dtype=np.float64)
    m = np.asarray(mass, dtype=np.float64)
    if d.ndim != 2 or m.shape != (d.shape[0],):
        raise ValueError(f"descriptors must be (n, d) and mass (n,), got {d.shape} and {m.shape}")
    norms = np.sqrt(m @ d**2)
    return d / np.where(norms > 0, norms, 1.0)
