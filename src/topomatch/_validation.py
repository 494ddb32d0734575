"""Input checks shared by the library (never ``assert``)."""

from __future__ import annotations

import numbers

import numpy as np

from topomatch.typing import FloatArray, IndexArray, RandomState


def check_random_state(random_state: RandomState) -> np.random.Generator:
    """Turn ``random_state`` into a ``numpy.random.Generator``.

    ``None`` gives a generator seeded with 0, so that library results are reproducible
    unless the caller asks otherwise; an int seeds a new generator; a generator is
    returned as is.
    """
    if random_state is None:
        return np.random.default_rng(0)
    if isinstance(random_state, np.random.Generator):
        return random_state
    if isinstance(random_state, numbers.Integral) and not isinstance(random_state, bool):
        return np.random.default_rng(int(random_state))
    raise TypeError(
        f"random_state must be None, an int or a numpy Generator, got {type(random_state).__name__}"
    )


def check_vertices(vertices: object, name: str = "vertices") -> FloatArray:
    v = np.asarray(vertices)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n_vertices, 3), got {v.shape}")
    if not np.issubdtype(v.dtype, np.number):
        raise TypeError(f"{name} must be numeric, got dtype {v.dtype}")
    v = np.ascontiguousarray(v, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        bad = int(np.flatnonzero(~np.isfinite(v).all(axis=1))[0])
        raise ValueError(f"{name} contains non-finite coordinates (first at vertex {bad})")
    return v


def check_faces(faces: object, n_vertices: int, name: str = "faces") -> IndexArray:
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n_faces, 3) (triangles), got {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer) and not np.all(np.mod(f, 1) == 0):
        raise TypeError(f"{name} must hold integer vertex indices, got dtype {f.dtype}")
    f = np.ascontiguousarray(f, dtype=np.int64)
    if f.size and (f.min() < 0 or f.max() >= n_vertices):
        raise ValueError(
            f"{name} index out of range: found [{f.min()}, {f.max()}] for {n_vertices} vertices"
        )
    return f


def check_p2p(p2p: object, n_out: int, n_in: int, name: str = "p2p", allow_unmatched: bool = True) -> IndexArray:
    """Check a point-to-point map with one entry per vertex of the mapped shape.

    Parameters
    ----------
    p2p : array_like, shape (n_out,)
        Vertex indices on the other shape, ``-1`` for unmatched when allowed.
    n_out : int
        Number of vertices of the mapped shape (length of ``p2p``).
    n_in : int
        Number of vertices of the shape the indices point into.
    """
    p = np.asarray(p2p)
    if p.ndim != 1 or p.shape[0] != n_out:
        raise ValueError(f"{name} must have shape ({n_out},), got {p.shape}")
    if p.size and not np.issubdtype(p.dtype, np.integer):
        raise TypeError(f"{name} must hold integer vertex indices, got dtype {p.dtype}")
    p = np.asarray(p, dtype=np.int64)
    lo = -1 if allow_unmatched else 0
    if p.size and (p.min() < lo or p.max() >= n_in):
        raise ValueError(
            f"{name} values must lie in [{lo}, {n_in - 1}], found [{p.min()}, {p.max()}]"
        )
    return p
