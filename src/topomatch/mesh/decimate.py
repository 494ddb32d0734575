"""Working copies of large meshes: quadric decimation and transfer back to the full mesh.

A matcher whose steps do not need every vertex of a 60K-vertex scan (``deform``'s
hypotheses and registrations) runs on a decimated copy and carries its result back:
:func:`decimate` makes the copy (quadric error metric, ``fast-simplification``),
:func:`surface_weights` expresses points (the full mesh's vertices) as barycentric
combinations of the copy's vertices, so any per-vertex quantity of the copy (a
displacement) interpolates onto them.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from topomatch.datasets._surface import SurfaceLocator
from topomatch.mesh.mesh import TriangleMesh
from topomatch.typing import FloatArray

__all__ = ["decimate", "surface_weights"]


def decimate(mesh: TriangleMesh, n_vertices: int) -> TriangleMesh:
    """A copy of ``mesh`` with about ``n_vertices`` vertices (quadric edge collapses).

    Parameters
    ----------
    mesh : TriangleMesh
    n_vertices : int
        Target vertex count; a mesh with at most this many vertices is returned as is.

    Returns
    -------
    TriangleMesh
        Named ``<name>@<n>``; its vertices are new positions (not a subset of the
        mesh's), unreferenced ones dropped.

    Raises
    ------
    ValueError
        If ``n_vertices`` is below 100 or the decimation leaves no face.
    """
    if not isinstance(n_vertices, (int, np.integer)) or n_vertices < 100:
        raise ValueError(f"decimate: n_vertices must be an integer >= 100, got {n_vertices!r}")
    if mesh.n_vertices <= n_vertices:
        return mesh
    import fast_simplification

    v, f = fast_simplification.simplify(
        np.ascontiguousarray(mesh.vertices, dtype=np.float32), np.ascontiguousarray(mesh.faces, dtype=np.int32),
        target_reduction=1.0 - n_vertices / mesh.n_vertices,
    )
    f = np.asarray(f, dtype=np.int64)
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    if len(f) == 0:
        raise ValueError(f"decimate: {mesh.name or 'mesh'} lost every face at {n_vertices} vertices")
    used, f = np.unique(f, return_inverse=True)
    name = f"{mesh.name or 'mesh'}@{len(used)}"
    return TriangleMesh(np.asarray(v, dtype=np.float64)[used], f.reshape(-1, 3), name=name)


def surface_weights(points: FloatArray, mesh: TriangleMesh, *, k: int = 4) -> sparse.csr_matrix:
    """Each point's closest point on ``mesh``, as barycentric weights of the mesh's vertices.

    The closest point is searched on the faces around the point's ``k`` nearest
    vertices (for points on or near the surface, as a finer mesh's vertices are, that
    is the closest point of the surface; a decimated mesh's long triangles can reach
    past the nearest vertex's own faces).

    Parameters
    ----------
    points : ndarray, shape (q, 3)
    mesh : TriangleMesh
    k : int

    Returns
    -------
    scipy.sparse.csr_matrix, shape (q, n_vertices)
        Rows sum to 1, at most three non-zeros each; ``W @ values`` interpolates
        per-vertex values of the mesh at the points.
    """
    P = np.ascontiguousarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or not np.isfinite(P).all():
        raise ValueError(f"surface_weights: points must be a finite (q, 3) array, got shape {P.shape}")
    face, bary, _ = SurfaceLocator(mesh.vertices, mesh.faces, k=k).query(P)
    cols = mesh.faces[np.maximum(face, 0)]
    lost = face < 0  # none of the k nearest vertices has a face: the nearest vertex itself
    if lost.any():
        cols[lost] = np.asarray(cKDTree(mesh.vertices).query(P[lost])[1], dtype=np.int64)[:, None]
    rows = np.repeat(np.arange(len(P)), 3)
    return sparse.csr_matrix((bary.ravel(), (rows, cols.ravel())), shape=(len(P), mesh.n_vertices))
