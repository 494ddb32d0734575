"""Helpers shared by the SHREC'16 entrants (EM, GE, RF): bases, sampling, MDS, landmarks."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import sparse

from topomatch.datasets.base import Shape
from topomatch.mesh import TriangleMesh
from topomatch.mesh.biharmonic import unit_area_basis
from topomatch.mesh.sampling import farthest_point_sampling
from topomatch.mesh.spectral import Eigenbasis
from topomatch.typing import FloatArray, IndexArray, RandomState


def check_positive_int(value: object, name: str, owner: str, minimum: int = 1) -> int:
    """``value`` as an int >= ``minimum`` or a ``ValueError`` naming the hyperparameter."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise ValueError(f"{owner}: {name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def unit_basis(mesh: TriangleMesh, k: int) -> Eigenbasis:
    """The first ``k`` eigenpairs of ``mesh`` rescaled to unit area (fewer on tiny meshes)."""
    k = min(k, mesh.n_vertices - 1)
    return unit_area_basis(mesh.eigenbasis(k), mesh.area)


def fps(mesh: TriangleMesh, n: int, points: FloatArray | None = None, *, first: int | None = None, random_state: RandomState = None) -> IndexArray:
    """``n`` farthest-point samples (all vertices if ``n`` exceeds their number)."""
    pts = mesh.vertices if points is None else points
    n = min(n, len(pts))
    return farthest_point_sampling(n, points=pts, first=first, random_state=random_state)


def classical_mds(D: FloatArray, dim: int) -> FloatArray:
    """Classical (Torgerson) multidimensional scaling.

    Parameters
    ----------
    D : ndarray, shape (n, n)
        Symmetric distances.
    dim : int
        Embedding dimension.

    Returns
    -------
    ndarray, shape (n, dim)
        Coordinates along the principal axes, largest variance first; columns whose
        eigenvalue is not positive are zero.
    """
    D = np.asarray(D, dtype=np.float64)
    n = D.shape[0]
    if D.ndim != 2 or D.shape[1] != n:
        raise ValueError(f"D must be a square distance matrix, got shape {D.shape}")
    J = np.eye(n) - 1.0 / n
    B = -0.5 * J @ (D**2) @ J
    B = 0.5 * (B + B.T)
    w, v = np.linalg.eigh(B)
    order = np.argsort(w)[::-1][:dim]
    w, v = w[order], v[:, order]
    # deterministic signs: largest-magnitude entry of each axis positive
    big = np.argmax(np.abs(v), axis=0)
    v = v * np.sign(v[big, np.arange(v.shape[1])])
    return v * np.sqrt(np.maximum(w, 0.0))


def find_reference(shapes: Sequence[Shape]) -> Shape | None:
    """The shape whose ground truth is the identity (the collection's null shape), if given."""
    for s in shapes:
        r = s.ref
        if r is None or r.shape[0] != r.shape[1] or r.nnz != r.shape[0]:
            continue
        r = r.tocsr()
        if np.array_equal(r.indices, np.arange(r.shape[0])) and np.array_equal(np.diff(r.indptr), np.ones(r.shape[0])):
            return s
    return None


def reference_to_vertex(shape: Shape) -> sparse.csr_matrix:
    """Reliable ground truth from reference vertices to ``shape``'s vertices, shape (n_ref, n)."""
    if shape.ref is None:
        raise ValueError(f"{shape.name} has no ground truth")
    r = shape.ref.tocsr().astype(np.int8)
    if shape.unreliable is not None and shape.unreliable.any():
        r = sparse.csr_matrix(r.multiply((~shape.unreliable).astype(np.int8)[:, None]))
    r = r.T.tocsr()
    r.eliminate_zeros()
    return r
