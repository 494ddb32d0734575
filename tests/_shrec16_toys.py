"""Small test shapes with a known answer for the SHREC'16 entrants (EM, GE, RF).

``sheet()`` is a flat grid with an off-centre notch and hole, so it has no intrinsic
symmetry; ``bent(sheet, radius)`` rolls it around an axis, which is an exact isometry;
``shuffled`` renumbers the vertices. The correct map of a bent, shuffled copy back to
the flat sheet is therefore known exactly, and errors can be measured in the flat
sheet's plane (where geodesic = Euclidean distance within the convex parts).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from topomatch.datasets.base import Shape
from topomatch.datasets.toy import grid
from topomatch.mesh import TriangleMesh


def sheet(n: int = 29) -> TriangleMesh:
    """Unit square grid minus a corner notch and an off-centre hole (no symmetry)."""
    g = grid(n)
    v, f = np.array(g.vertices), np.array(g.faces)
    c = v[f].mean(1)
    drop = ((c[:, 0] > 0.72) & (c[:, 1] > 0.55)) | (np.hypot(c[:, 0] - 0.3, c[:, 1] - 0.62) < 0.09)
    f = f[~drop]
    used = np.unique(f)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    return TriangleMesh(v[used], remap[f], name="sheet")


def bent(mesh: TriangleMesh, radius: float, name: str = "bent") -> TriangleMesh:
    """Roll the flat sheet (z = 0) around the y axis: an exact isometry."""
    v = np.array(mesh.vertices)
    x = v[:, 0] - 0.5
    out = np.c_[radius * np.sin(x / radius), v[:, 1], radius * (1 - np.cos(x / radius))]
    return TriangleMesh(out, mesh.faces, name=name)


def shuffled(mesh: TriangleMesh, seed: int, name: str | None = None) -> tuple[TriangleMesh, np.ndarray]:
    """Renumber the vertices; returns the mesh and ``orig`` (new vertex i = old ``orig[i]``)."""
    rng = np.random.default_rng(seed)
    orig = rng.permutation(mesh.n_vertices)
    inv = np.empty_like(orig)
    inv[orig] = np.arange(len(orig))
    return TriangleMesh(mesh.vertices[orig], inv[mesh.faces], name=name or mesh.name), orig


def as_shape(mesh: TriangleMesh, orig: np.ndarray, n_ref: int, name: str) -> Shape:
    """A Shape whose vertex i corresponds to reference vertex ``orig[i]``."""
    ref = sparse.csr_matrix((np.ones(len(orig), dtype=np.int8), (np.arange(len(orig)), orig)), shape=(len(orig), n_ref))
    return Shape(name, mesh, ref=ref, sym=None)


def reference_shape(mesh: TriangleMesh, name: str = "ref") -> Shape:
    """The null shape: ground truth = identity."""
    n = mesh.n_vertices
    return Shape(name, mesh, ref=sparse.identity(n, dtype=np.int8, format="csr"))


def planar_errors(flat: TriangleMesh, p2p_21: np.ndarray, truth_21: np.ndarray) -> np.ndarray:
    """Distances in the flat sheet's plane between mapped and true vertices / sqrt(area).

    Only entries with ``p2p_21 >= 0``.
    """
    ok = p2p_21 >= 0
    d = np.linalg.norm(flat.vertices[p2p_21[ok]] - flat.vertices[truth_21[ok]], axis=1)
    return d / np.sqrt(flat.area)
