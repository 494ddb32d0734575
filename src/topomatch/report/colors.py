"""Colour fields for correspondence pictures (numpy only; the HTML viewer uses the same formulas).

The source (shape 1) is painted with a smooth field of its own coordinates, and every
target vertex takes the colour of the source vertex the map sends it to, so that
corresponding points share a colour. Unmatched target vertices are grey; source
vertices that no target vertex reaches are faded toward grey (they are the part of the
source that the map leaves uncovered: the "% area matched" of the track's Table 1).
"""

from __future__ import annotations

import numpy as np

from topomatch.typing import FloatArray, IndexArray

__all__ = ["GREY", "UNHIT_FADE", "coverage", "position_colors", "transfer_colors"]

GREY = np.array([0.62, 0.62, 0.62])
"""Colour of unmatched target vertices."""

UNHIT_FADE = 0.6
"""How far source vertices that no target vertex reaches are blended toward :data:`GREY`."""


def position_colors(vertices: FloatArray) -> FloatArray:
    """Colour each vertex smoothly by its coordinates normalised to the bounding box.

    ``rgb = 0.1 + 0.85 * (v - min) / (max - min)`` per axis, so that x, y and z map to
    red, green and blue and no colour is black.

    Parameters
    ----------
    vertices : ndarray, shape (n_vertices, 3)

    Returns
    -------
    ndarray, shape (n_vertices, 3)
        RGB in [0.1, 0.95].
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (n, 3), got {v.shape}")
    lo, hi = v.min(axis=0), v.max(axis=0)
    span = np.where(hi - lo > 0, hi - lo, 1.0)
    return 0.1 + 0.85 * (v - lo) / span


def coverage(p2p_21: IndexArray, n_source: int) -> np.ndarray:
    """Which source vertices the map reaches, shape (n_source,) bool."""
    p = np.asarray(p2p_21, dtype=np.int64)
    hit = np.zeros(n_source, dtype=bool)
    hit[p[p >= 0]] = True
    return hit


def transfer_colors(p2p_21: IndexArray, source_colors: FloatArray, *, fade_unhit: bool = True) -> tuple[FloatArray, FloatArray]:
    """Colours of both shapes of a pair so that corresponding points share a colour.

    Parameters
    ----------
    p2p_21 : ndarray, shape (n_target,)
        Source vertex of each target vertex, ``-1`` = unmatched.
    source_colors : ndarray, shape (n_source, 3)
        E.g. :func:`position_colors` of the source vertices.
    fade_unhit : bool
        Blend source vertices that no target vertex reaches toward grey.

    Returns
    -------
    source_rgb : ndarray, shape (n_source, 3)
    target_rgb : ndarray, shape (n_target, 3)
        ``target_rgb[x] = source_colors[p2p_21[x]]``; :data:`GREY` where unmatched.
    """
    p = np.asarray(p2p_21, dtype=np.int64)
    c = np.asarray(source_colors, dtype=np.float64)
    if p.ndim != 1:
        raise ValueError(f"p2p_21 must be 1-D, got shape {p.shape}")
    if p.size and (p.max() >= len(c) or p.min() < -1):
        raise ValueError(f"p2p_21 values must lie in [-1, {len(c) - 1}] (the source has {len(c)} vertices)")
    target = np.tile(GREY, (len(p), 1))
    ok = p >= 0
    target[ok] = c[p[ok]]
    source = c.copy()
    if fade_unhit:
        miss = ~coverage(p, len(c))
        source[miss] = (1 - UNHIT_FADE) * source[miss] + UNHIT_FADE * GREY
    return source, target
