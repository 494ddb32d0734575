"""A small built-in benchmark of procedural shapes with exact ground truth and shortcuts.

Made in about a second with no data files, so that ``topomatch bench`` runs on a fresh
machine. A closed star-shaped "figure" (a subdivided icosphere with a head, two arms and
two legs pushed out) is posed by bending its limbs; in some poses a limb is brought
close to the body and the two nearby surface patches are fused: a small disc is cut
out of each and the two holes are joined by a strip of triangles, adding a handle (a
topological shortcut). Vertex orders are shuffled per shape. Ground truth to the null
shape is exact for every kept vertex; vertices next to a fused region are flagged
unreliable, as in TOPKIDS. The figure is mirror-symmetric (x -> -x), so every shape
has an exact left-right symmetry map.

Shapes: ``syn00`` (null shape), ``syn01``-``syn04`` (train), ``syn05``-``syn08`` (test).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from topomatch.datasets.base import Shape, ShapeCollection, ref_matrix
from topomatch.datasets.toy import icosphere
from topomatch.mesh import TriangleMesh
from topomatch.mesh.geometry import boundary_loops, edges_with_counts
from topomatch.typing import FloatArray, IndexArray

__all__ = ["builtin_benchmark"]

_LIMBS = {  # direction, length of the protrusion
    "head": (np.array([0.0, 0.0, 1.0]), 0.7),
    "arm_r": (np.array([1.0, 0.0, 0.3]), 1.9),
    "arm_l": (np.array([-1.0, 0.0, 0.3]), 1.9),
    "leg_r": (np.array([0.3, 0.0, -1.0]), 2.0),
    "leg_l": (np.array([-0.3, 0.0, -1.0]), 2.0),
}
_SCALE = np.array([0.8, 0.5, 1.0])


def _figure(subdivisions: int) -> tuple[TriangleMesh, dict[str, FloatArray]]:
    sph = icosphere(subdivisions)
    v = np.array(sph.vertices)
    weights = {}
    r = np.ones(len(v))
    for name, (d, length) in _LIMBS.items():
        d = d / np.linalg.norm(d)
        c = v @ d
        w = np.clip((c - 0.90) / 0.10, 0.0, 1.0) ** 1.2  # protrusion profile
        r += length * w
        weights[name] = np.clip((c - 0.88) / 0.1, 0.0, 1.0)
    v = v * r[:, None] * _SCALE
    return TriangleMesh(v, sph.faces, name="syn00"), weights


def _rot(axis: FloatArray, angle: float) -> FloatArray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _pose(v: FloatArray, weights: dict[str, FloatArray], angles: dict[str, float]) -> FloatArray:
    out = v.copy()
    for name, ang in angles.items():
        d, _ = _LIMBS[name]
        d = d / np.linalg.norm(d)
        pivot = d * 1.0 * _SCALE
        axis = np.array([0.0, 1.0, 0.0])  # limbs bend in the frontal plane
        w = weights[name]
        for s in np.linspace(0, 1, 8)[1:]:  # blend rotations so the joint bends smoothly
            m = (w >= s - 1 / 7) & (w < s) if s < 1 else w >= s - 1 / 7
            R = _rot(axis, ang * s)
            out[m] = (out[m] - pivot) @ R.T + pivot
    return out


def _ring(faces: IndexArray, seeds: IndexArray, n_vertices: int, rings: int) -> np.ndarray:
    e, _ = edges_with_counts(faces)
    a = sparse.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n_vertices,) * 2)
    m = np.zeros(n_vertices, dtype=bool)
    m[seeds] = True
    for _ in range(rings):
        m = m | (a @ m.astype(float) > 0)
    return m


def _fuse(v: FloatArray, f: IndexArray, limb_w: FloatArray, rings: int) -> tuple[IndexArray, IndexArray, np.ndarray]:
    """Cut a disc on the limb and one on the body where they are closest, join the holes."""
    limb = np.flatnonzero(limb_w > 0.9)
    body = np.flatnonzero(limb_w == 0)
    d, j = cKDTree(v[body]).query(v[limb])
    p = limb[int(np.argmin(d))]
    q = body[j[int(np.argmin(d))]]
    cut_p = _ring(f, np.array([p]), len(v), rings)
    cut_q = _ring(f, np.array([q]), len(v), rings)
    if np.any(cut_p & cut_q):
        raise RuntimeError("fused patches overlap")
    inner_p = cut_p & ~_boundary_of(f, cut_p, len(v))
    inner_q = cut_q & ~_boundary_of(f, cut_q, len(v))
    drop = np.any(inner_p[f] | inner_q[f], axis=1)
    f2 = f[~drop]
    loops = boundary_loops(f2)
    if len(loops) != 2:
        raise RuntimeError(f"expected two holes, found {len(loops)}")
    a, b = loops
    # zipper: walk A forward and B backward (orientation), advancing whichever is behind
    # in normalised arc length, so each rung is used once and the strip is a clean tube
    b = np.roll(b, -int(np.argmin(np.linalg.norm(v[b] - v[a[0]], axis=1))))
    b = np.r_[b[:1], b[1:][::-1]]  # backward order, starting at the closest vertex
    ta = _arclength(v, a)
    tb = _arclength(v, b)
    m, n = len(a), len(b)
    i = j = 0
    new = []
    while i < m or j < n:
        if j >= n or (i < m and ta[i + 1] <= tb[j + 1]):
            new.append([a[(i + 1) % m], a[i], b[j % n]])
            i += 1
        else:
            new.append([b[j], b[(j + 1) % n], a[i % m]])
            j += 1
    f3 = np.concatenate([f2, np.asarray(new, dtype=np.int64)])
    near = _ring(f3, np.r_[a, b], len(v), 2)
    keep = ~(inner_p | inner_q)
    return f3, np.flatnonzero(keep), near


def _arclength(v: FloatArray, loop: IndexArray) -> FloatArray:
    """Normalised cumulative length at each loop vertex, closing back to 1, shape (len + 1,)."""
    seg = np.linalg.norm(v[np.roll(loop, -1)] - v[loop], axis=1)
    return np.r_[0.0, np.cumsum(seg)] / seg.sum()


def _boundary_of(f: IndexArray, region: np.ndarray, n: int) -> np.ndarray:
    """Vertices of ``region`` that have a neighbour outside it."""
    outside = _ring(f, np.flatnonzero(~region), n, 1)
    return region & outside


@dataclass(frozen=True)
class _Spec:
    name: str
    angles: dict[str, float]
    fuse: str | None


_SPECS = [  # angles in radians about the y axis (positive lowers the right arm)
    _Spec("syn01", {"arm_r": -0.5, "leg_l": 0.2}, None),
    _Spec("syn02", {"arm_l": -1.45, "arm_r": -0.3}, "arm_l"),
    _Spec("syn03", {"leg_r": -0.3, "head": 0.3}, None),
    _Spec("syn04", {"arm_r": 1.45, "leg_r": 0.15}, "arm_r"),
    _Spec("syn05", {"arm_l": -1.5, "leg_l": -0.2}, "arm_l"),
    _Spec("syn06", {"arm_r": -0.6, "head": -0.25}, None),
    _Spec("syn07", {"arm_r": 1.5, "arm_l": -0.5}, "arm_r"),
    _Spec("syn08", {"leg_l": 0.25, "arm_l": 0.4}, None),
]


def builtin_benchmark(subdivisions: int = 4, *, random_state: int = 0) -> ShapeCollection:
    """Build the built-in benchmark (deterministic for a given ``random_state``).

    Parameters
    ----------
    subdivisions : int
        Icosphere subdivisions of the figure: 4 gives 2,562 vertices per shape.
    random_state : int
        Seeds the vertex shuffles.

    Returns
    -------
    ShapeCollection
        Reference ``syn00``; splits ``train`` (syn01-04), ``test`` (syn05-08), ``all``.
    """
    null, weights = _figure(subdivisions)
    n = null.n_vertices
    center = null.vertices.mean(axis=0)
    mirrored = (null.vertices - center) * np.array([-1.0, 1.0, 1.0]) + center
    dist, sym0 = cKDTree(null.vertices).query(mirrored)
    sym0 = np.where(dist < 1e-9 * np.ptp(null.vertices), sym0, -1)
    rng = np.random.default_rng(random_state)
    shapes: dict[str, Shape] = {
        "syn00": Shape("syn00", null, ref=sparse.identity(n, dtype=np.int8, format="csr"), sym=sym0.astype(np.int64)),
    }
    for spec in _SPECS:
        v = _pose(np.array(null.vertices), weights, spec.angles)
        f = np.array(null.faces)
        keep = np.arange(n)
        unreliable_full = np.zeros(n, dtype=bool)
        if spec.fuse is not None:
            f, keep, unreliable_full = _fuse(v, f, weights[spec.fuse], rings=2)
        perm = rng.permutation(len(keep))  # new vertex i is old vertex keep[perm[i]]
        old = keep[perm]
        new_of_old = np.full(n, -1, dtype=np.int64)
        new_of_old[old] = np.arange(len(old))
        faces = new_of_old[f]
        mesh = TriangleMesh(v[old], faces, name=spec.name)
        ref = ref_matrix(np.c_[np.arange(len(old)), old], len(old), n)
        sym_old = sym0[old]
        sym = np.where(sym_old >= 0, new_of_old[np.maximum(sym_old, 0)], -1)
        shapes[spec.name] = Shape(spec.name, mesh, ref=ref, sym=sym, unreliable=unreliable_full[old])
    names = [s.name for s in _SPECS]
    return ShapeCollection(
        name="builtin",
        reference="syn00",
        loaders={k: (lambda s=s: s) for k, s in shapes.items()},
        splits={"train": names[:4], "test": names[4:], "all": names},
        missing=[],
        root=None,
    )
