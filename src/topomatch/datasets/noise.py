"""Topological noise made the way TOPKIDS was: fuse what touches, keep the outer surface.

TOPKIDS (SHREC'16) posed one template and kept only the outer hull of each pose:
wherever parts touched or interpenetrated, their surfaces merged, interior parts
vanished, and the result was remeshed. This module does the same to any collection of
posed meshes in correspondence with a template:

1. the posed mesh (its small holes capped) becomes an inside/outside field on a grid:
   exact winding numbers (so interpenetrating parts are simply inside) times the
   distance to the surface;
2. optional shortcuts: capsules joining spatially close but geodesically far patches
   are added to the solid (the mode for collections without touching poses);
3. a morphological closing by half the merge distance fuses parts closer than the
   merge distance, and flooding from the grid border keeps only the outer surface
   (interior parts and cavities are filled);
4. marching tetrahedra extract that single outer surface, which is decimated to the
   chosen resolution and relaxed for even triangles;
5. every output vertex gets the closest point on the clean posed mesh: its ground
   truth on the null shape (barycentric point carried to the rest pose, then nearest
   null vertex), its left-right mirror, and an "unreliable" flag where the surface
   moved away from the clean one (merged seams, filled gaps, shortcuts).

The public entry points are :func:`topological_noise` (one pose), :func:`noisy_collection`
(a null shape and many poses, as a :class:`~topomatch.datasets.base.ShapeCollection`),
:func:`write_topkids` (the TOPKIDS release layout) and :func:`noise_files` (what
``topomatch noise`` runs). See ``docs/noise.md``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage, sparse
from scipy.spatial import cKDTree

from topomatch._validation import check_faces, check_random_state, check_vertices
from topomatch.datasets._isosurface import marching_tetrahedra, winding_numbers
from topomatch.datasets._surface import (
    HoleCaps,
    SurfaceLocator,
    compact,
    decimate,
    keep_largest_component,
    relax_onto,
)
from topomatch.datasets.base import Shape, ShapeCollection, ref_matrix
from topomatch.mesh import TriangleMesh
from topomatch.mesh.geometry import edges_with_counts, face_areas
from topomatch.typing import BoolArray, FloatArray, IndexArray, PathType, RandomState

__all__ = [
    "NoiseParams",
    "NoisyMesh",
    "Shortcut",
    "find_shortcuts",
    "noise_files",
    "noisy_collection",
    "outer_surface",
    "topological_noise",
    "write_topkids",
]

logger = logging.getLogger(__name__)

# fixed sub-voxel offset of the grid: keeps grid columns off axis-aligned vertices and
# edges of synthetic inputs (winding-number ties are handled anyway; this just avoids them)
_GRID_JITTER = np.array([0.3183099, 0.2718282, 0.1414214])


def mean_edge_for(area: float, n_vertices: int) -> float:
    """Edge length of an even triangulation of ``area`` with ``n_vertices`` vertices."""
    return float(np.sqrt(2.0 * area / (np.sqrt(3.0) * max(n_vertices, 1))))


@dataclass(frozen=True)
class Shortcut:
    """A synthetic shortcut: a capsule of ``radius`` joining surface points ``a`` and ``b``.

    ``vertex_a`` / ``vertex_b`` are the template vertices the ends were grown from.
    """

    a: FloatArray
    b: FloatArray
    radius: float
    vertex_a: int = -1
    vertex_b: int = -1


@dataclass(frozen=True)
class NoiseParams:
    """Parameters of the generator; lengths are absolute (same units as the meshes).

    ``None`` means "derived from the shape": with ``L`` the mean edge length of an even
    triangulation of the clean surface at ``n_vertices`` vertices, the defaults are
    ``voxel_size = 0.6 L``, ``merge_distance = L``, ``unreliable_distance = L / 2``,
    ``shortcut_radius = 1.5 L``, ``shortcut_max_gap = 0.15 sqrt(area)``.

    Attributes
    ----------
    n_vertices : int
        Output resolution: vertex count the clean surface would have (default 10,000).
    scale_by_area : bool
        Scale each output's vertex count by its area over the clean surface's area, so
        that all shapes share one edge length and shapes that lost area (interior parts
        removed) get fewer vertices, as in TOPKIDS.
    voxel_size : float, optional
        Grid spacing of the inside/outside field.
    merge_distance : float, optional
        Gaps narrower than about this are closed (parts fuse). The effective value is
        at least 1.5 voxels.
    unreliable_distance : float, optional
        Output vertices farther than this from the clean posed surface are flagged
        unreliable (their ground truth is a guess).
    shortcuts : int
        Number of synthetic shortcuts to add (second mode).
    shortcut_radius : float, optional
        Radius of a shortcut capsule.
    shortcut_max_gap : float, optional
        Largest Euclidean distance bridged by a shortcut.
    shortcut_min_ratio : float
        Smallest ratio geodesic / Euclidean distance between the two ends.
    unreliable_rings : int
        Rings of neighbours added around the vertices found unreliable.
    relax_iterations : int
        Tangential relaxation steps after decimation (0 = none).
    keep_holes : bool
        Re-open the template's boundary loops (capped for the inside/outside test) in the
        output, as TOPKIDS kept the KIDS holes.
    """

    n_vertices: int = 10_000
    scale_by_area: bool = True
    voxel_size: float | None = None
    merge_distance: float | None = None
    unreliable_distance: float | None = None
    shortcuts: int = 0
    shortcut_radius: float | None = None
    shortcut_max_gap: float | None = None
    shortcut_min_ratio: float = 3.0
    unreliable_rings: int = 0
    relax_iterations: int = 2
    keep_holes: bool = True

    def validate(self) -> None:
        """Raise ``ValueError`` for out-of-range values."""
        if int(self.n_vertices) < 100:
            raise ValueError(f"n_vertices must be at least 100, got {self.n_vertices}")
        for name in ("voxel_size", "merge_distance", "unreliable_distance", "shortcut_radius", "shortcut_max_gap"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a non-negative number, got {v!r}")
        if self.voxel_size is not None and self.voxel_size <= 0:
            raise ValueError(f"voxel_size must be positive, got {self.voxel_size}")
        if self.shortcuts < 0:
            raise ValueError(f"shortcuts must be >= 0, got {self.shortcuts}")
        if self.shortcut_min_ratio < 1:
            raise ValueError(f"shortcut_min_ratio must be >= 1, got {self.shortcut_min_ratio}")
        if self.unreliable_rings < 0:
            raise ValueError(f"unreliable_rings must be >= 0, got {self.unreliable_rings}")
        if self.relax_iterations < 0:
            raise ValueError(f"relax_iterations must be >= 0, got {self.relax_iterations}")

    def resolved(self, area: float) -> dict[str, float]:
        """Absolute lengths for a clean surface of total ``area``."""
        edge = mean_edge_for(area, int(self.n_vertices))
        return {
            "edge": edge,
            "voxel_size": self.voxel_size if self.voxel_size is not None else 0.6 * edge,
            "merge_distance": self.merge_distance if self.merge_distance is not None else edge,
            "unreliable_distance": self.unreliable_distance if self.unreliable_distance is not None else 0.5 * edge,
            "shortcut_radius": self.shortcut_radius if self.shortcut_radius is not None else 1.5 * edge,
            "shortcut_max_gap": self.shortcut_max_gap if self.shortcut_max_gap is not None else 0.15 * float(np.sqrt(area)),
        }


@dataclass(frozen=True)
class NoisyMesh:
    """One noisy shape and where each of its vertices lies on the clean posed mesh.

    Attributes
    ----------
    mesh : TriangleMesh
    face : ndarray, shape (n_vertices,)
        Closest face of the clean (capped) template, in the template's face numbering
        (cap faces come after the template's own).
    bary : ndarray, shape (n_vertices, 3)
        Barycentric weights of the closest point on that face.
    distance : ndarray, shape (n_vertices,)
        Distance to the clean posed surface.
    unreliable : ndarray of bool, shape (n_vertices,)
    shortcuts : tuple of Shortcut
    info : dict
        Parameters used and timings.
    """

    mesh: TriangleMesh
    face: IndexArray
    bary: FloatArray
    distance: FloatArray
    unreliable: BoolArray
    shortcuts: tuple[Shortcut, ...] = ()
    info: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------
# the inside/outside field and the outer surface
# ---------------------------------------------------------------------------------------
def _surface_samples(vertices: FloatArray, faces: IndexArray, spacing: float) -> FloatArray:
    """Vertices plus points inside every face larger than ``spacing``, shape (n, 3)."""
    tri = vertices[faces]
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    n_sub = np.ceil(longest / spacing).astype(np.int64)
    out = [vertices]
    for n in np.unique(n_sub[n_sub > 1]):
        sel = tri[n_sub == n]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        ok = i + j <= n
        w = np.c_[i[ok], j[ok]] / n
        w = np.c_[w, 1.0 - w.sum(1)]
        out.append(np.einsum("sk,fkd->fsd", w, sel).reshape(-1, 3))
    return np.concatenate(out)


def _capsule_sdf(points: FloatArray, a: FloatArray, b: FloatArray, radius: float) -> FloatArray:
    ab = b - a
    t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1) - radius


def solid_field(
    vertices: FloatArray,
    faces: IndexArray,
    *,
    voxel_size: float,
    merge_distance: float = 0.0,
    shortcuts: Sequence[Shortcut] = (),
) -> tuple[np.ndarray, FloatArray]:
    """Signed field of the fused outer solid on a grid (negative inside).

    Parameters
    ----------
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
        A closed, consistently oriented surface (self-intersections allowed).
    voxel_size : float
    merge_distance : float
        Gaps narrower than about this are filled.
    shortcuts : sequence of Shortcut
        Capsules added to the solid.

    Returns
    -------
    field : ndarray of float32, shape (nx, ny, nz)
    origin : ndarray, shape (3,)
        Position of grid point (0, 0, 0); spacing is ``voxel_size``.
    """
    h = float(voxel_size)
    rho = max(0.5 * float(merge_distance), 0.75 * h)
    margin = h
    pad = rho + margin + 3 * h + max((s.radius for s in shortcuts), default=0.0)
    lo = vertices.min(axis=0) - pad - _GRID_JITTER * h
    hi = vertices.max(axis=0) + pad
    for s in shortcuts:
        lo = np.minimum(lo, np.minimum(s.a, s.b) - pad)
        hi = np.maximum(hi, np.maximum(s.a, s.b) + pad)
    shape = tuple(int(n) for n in np.ceil((hi - lo) / h).astype(np.int64) + 1)
    if int(np.prod(shape)) > 60_000_000:
        raise ValueError(f"the voxel grid would have {shape} points; choose a larger voxel_size")
    origin = lo
    wind = winding_numbers(vertices, faces, origin, h, shape)
    # distance to the surface: approximate everywhere, exact in a band around it
    samples = _surface_samples(vertices, faces, h)
    idx = np.clip(np.rint((samples - origin) / h).astype(np.int64), 0, np.array(shape) - 1)
    seed = np.ones(shape, dtype=bool)
    seed[idx[:, 0], idx[:, 1], idx[:, 2]] = False
    dist = ndimage.distance_transform_edt(seed, sampling=h).astype(np.float32)
    # the approximate distance is within 1.4 h of the true one (seed voxels hold samples
    # at most h apart): outside this band the true distance exceeds rho for sure
    band = np.flatnonzero(dist.ravel() <= rho + 1.5 * h)
    bi, bj, bk = np.unravel_index(band, shape)
    pts = origin + h * np.c_[bi, bj, bk]
    _, _, d_exact = SurfaceLocator(vertices, faces, k=4).query(pts)
    dist.ravel()[band] = d_exact
    sdf = np.where(wind != 0, -dist, dist)
    del dist, wind
    for s in shortcuts:  # union with the capsules, on their bounding boxes only
        r = s.radius + rho + 3 * h
        i0 = np.maximum(np.floor((np.minimum(s.a, s.b) - r - origin) / h).astype(np.int64), 0)
        i1 = np.minimum(np.ceil((np.maximum(s.a, s.b) + r - origin) / h).astype(np.int64) + 1, shape)
        sub = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(i0, i1)], indexing="ij"), axis=-1).reshape(-1, 3)
        cap = _capsule_sdf(origin + h * sub, s.a, s.b, s.radius).reshape(tuple(i1 - i0))
        view = sdf[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]]
        np.minimum(view, cap.astype(np.float32), out=view)
    # closing: the exterior is what a ball of radius rho reaches from the grid border
    labels, _ = ndimage.label(sdf > rho)
    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(), labels[:, :, [0, -1]].ravel()]))
    border = border[border > 0]
    exterior = np.isin(labels, border)
    del labels
    d_ext = ndimage.distance_transform_edt(~exterior, sampling=h).astype(np.float32)
    closing = (rho + margin) - d_ext
    return np.minimum(sdf, closing), origin


def outer_surface(
    vertices: FloatArray,
    faces: IndexArray,
    *,
    voxel_size: float,
    merge_distance: float = 0.0,
    shortcuts: Sequence[Shortcut] = (),
) -> tuple[FloatArray, IndexArray]:
    """Extract the single outer surface of a posed mesh at voxel resolution (not decimated).

    Parameters are those of :func:`solid_field`. The mesh must be closed (cap small
    holes first); self-intersections are welcome.

    Returns
    -------
    vertices : ndarray, shape (n, 3)
    faces : ndarray, shape (m, 3)
        A closed, edge-manifold, outward-oriented surface with one component.
    """
    field_, origin = solid_field(vertices, faces, voxel_size=voxel_size, merge_distance=merge_distance, shortcuts=shortcuts)
    v, f = marching_tetrahedra(field_, origin, voxel_size)
    if len(f) == 0:
        raise ValueError("the posed mesh encloses no volume at this voxel size (is it closed and outward oriented?)")
    return keep_largest_component(v, f)


# ---------------------------------------------------------------------------------------
# shortcuts (second mode)
# ---------------------------------------------------------------------------------------
def _template_geodesics(rest_vertices: FloatArray, faces: IndexArray, sources: IndexArray) -> FloatArray:
    """Dijkstra distances on the edge graph from ``sources`` to every vertex, shape (k, n)."""
    from scipy.sparse.csgraph import dijkstra

    from topomatch.mesh.geometry import edge_graph

    return dijkstra(edge_graph(rest_vertices, faces), indices=sources)


def find_shortcuts(
    posed_vertices: FloatArray,
    faces: IndexArray,
    n: int,
    *,
    radius: float,
    max_gap: float,
    min_ratio: float = 4.0,
    rest_vertices: FloatArray | None = None,
    n_candidates: int = 400,
    random_state: RandomState = None,
) -> list[Shortcut]:
    """Pick ``n`` pairs of spatially close but geodesically far surface patches.

    Candidates are pairs of farthest-point samples whose Euclidean gap in the pose is at
    most ``max_gap`` while their geodesic distance (on the rest pose, which has the same
    intrinsic geometry) is at least ``min_ratio`` times the gap and at least four
    radii. Pairs are drawn at random, favouring short gaps, and kept apart from each
    other by at least four radii.

    Returns
    -------
    list of Shortcut
        Possibly fewer than ``n`` when the pose has fewer candidates.
    """
    if n <= 0:
        return []
    from topomatch.mesh import farthest_point_sampling

    rng = check_random_state(random_state)
    rest = posed_vertices if rest_vertices is None else rest_vertices
    n_candidates = min(n_candidates, len(posed_vertices))
    samples = np.asarray(farthest_point_sampling(n_candidates, points=posed_vertices, random_state=rng), dtype=np.int64)
    geo = _template_geodesics(rest, faces, samples)[:, samples]
    p = posed_vertices[samples]
    eu = np.linalg.norm(p[:, None] - p[None], axis=2)
    ok = (eu <= max_gap) & (geo >= min_ratio * eu) & (geo >= 4 * radius) & np.triu(np.ones_like(eu, dtype=bool), 1)
    ii, jj = np.nonzero(ok)
    if len(ii) == 0:
        logger.info("no shortcut candidates (max_gap=%.3g, min_ratio=%.3g)", max_gap, min_ratio)
        return []
    weight = 1.0 / (eu[ii, jj] + radius)
    order = rng.choice(len(ii), size=len(ii), replace=False, p=weight / weight.sum())
    normals = TriangleMesh(posed_vertices, faces).vertex_normals
    chosen: list[Shortcut] = []
    used: list[FloatArray] = []
    for t in order:
        a, b = samples[ii[t]], samples[jj[t]]
        pa, pb = posed_vertices[a], posed_vertices[b]
        if any(min(np.linalg.norm(pa - q), np.linalg.norm(pb - q)) < 4 * radius for q in used):
            continue
        # sink the ends half a radius under the surface so the capsule grows out of it
        ea = pa - 0.5 * radius * normals[a]
        eb = pb - 0.5 * radius * normals[b]
        chosen.append(Shortcut(ea, eb, float(radius), int(a), int(b)))
        used += [pa, pb]
        if len(chosen) == n:
            break
    if len(chosen) < n:
        logger.info("only %d of %d shortcuts found", len(chosen), n)
    return chosen


# ---------------------------------------------------------------------------------------
# one pose
# ---------------------------------------------------------------------------------------
def _reopen_holes(vertices: FloatArray, faces: IndexArray, on_cap: BoolArray) -> tuple[FloatArray, IndexArray, IndexArray]:
    """Remove faces lying on hole caps; returns (vertices, faces, kept vertex ids)."""
    drop = on_cap[faces].all(axis=1)
    if not drop.any():
        return vertices, faces, np.arange(len(vertices))
    f = faces[~drop]
    # a vertex where two caps' openings touch would be non-manifold: drop its faces too
    for _ in range(3):
        e, counts = edges_with_counts(f)
        bverts = e[counts == 1].ravel()
        deg = np.bincount(bverts, minlength=len(vertices))
        bad = deg > 2
        if not bad.any():
            break
        f = f[~bad[f].any(axis=1)]
    used = np.zeros(len(vertices), dtype=bool)
    used[f.ravel()] = True
    kept = np.flatnonzero(used)
    v, f = compact(vertices, f)
    return v, f, kept


def _seam_vertices(
    vertices: FloatArray, faces: IndexArray, rest: FloatArray, template_faces: IndexArray, face: IndexArray, bary: FloatArray, edge: float
) -> BoolArray:
    """Flag the ends of output edges that join parts lying apart in the rest pose (a fused seam).

    An ordinary edge joins points about as far apart in the rest pose as in the pose
    (the deformation is nearly isometric); an edge across a seam where two parts fused
    joins points that were far apart.
    """
    rest_points = np.einsum("ij,ijk->ik", bary, rest[template_faces[face]])
    e, _ = edges_with_counts(faces)
    posed_len = np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1)
    rest_len = np.linalg.norm(rest_points[e[:, 0]] - rest_points[e[:, 1]], axis=1)
    seam = e[rest_len > 2.5 * posed_len + edge]
    out = np.zeros(len(vertices), dtype=bool)
    out[seam.ravel()] = True
    return out


def _dilate(faces: IndexArray, mask: BoolArray, rings: int) -> BoolArray:
    """Grow a vertex mask by ``rings`` rings of face neighbours."""
    out = mask.copy()
    for _ in range(rings):
        hit = out[faces].any(axis=1)
        out[faces[hit].ravel()] = True
    return out


def topological_noise(
    vertices: FloatArray,
    faces: IndexArray,
    params: NoiseParams | None = None,
    *,
    caps: HoleCaps | None = None,
    clean_area: float | None = None,
    rest_vertices: FloatArray | None = None,
    shortcuts: Sequence[Shortcut] | None = None,
    random_state: RandomState = None,
    name: str = "",
) -> NoisyMesh:
    """Fuse what touches in one posed mesh and keep its outer surface.

    Parameters
    ----------
    vertices : ndarray, shape (n_vertices, 3)
        The posed clean mesh.
    faces : ndarray, shape (n_faces, 3)
        Its triangles (shared by every pose of the template). Boundary loops are capped
        for the inside/outside test.
    params : NoiseParams, optional
    caps : HoleCaps, optional
        Precomputed caps of ``faces`` (saves time over many poses).
    clean_area : float, optional
        Area the resolution refers to (default: this pose's area).
    rest_vertices : ndarray, shape (n_vertices, 3), optional
        Rest pose (nothing touching), used to find fused seams (output edges joining
        points that are far apart in the rest pose: their ends are flagged unreliable)
        and for the geodesic distances of shortcut selection.
    shortcuts : sequence of Shortcut, optional
        Use these instead of drawing ``params.shortcuts`` at random.
    random_state : None, int or numpy.random.Generator
    name : str

    Returns
    -------
    NoisyMesh
        ``face`` / ``bary`` index the capped template (``faces`` then ``caps.faces``).
    """
    params = params or NoiseParams()
    params.validate()
    t0 = time.perf_counter()
    vertices = check_vertices(vertices, f"{name or 'posed mesh'} vertices")
    faces = check_faces(faces, len(vertices), f"{name or 'posed mesh'} faces")
    rng = check_random_state(random_state)
    caps = caps or HoleCaps.build(faces, len(vertices))
    vx = caps.extend(vertices)
    fx = np.concatenate([faces, caps.faces])
    area = float(face_areas(vertices, faces).sum()) if clean_area is None else float(clean_area)
    p = params.resolved(area)
    if shortcuts is None:
        shortcuts = find_shortcuts(
            vertices, faces, params.shortcuts, radius=p["shortcut_radius"], max_gap=p["shortcut_max_gap"],
            min_ratio=params.shortcut_min_ratio, rest_vertices=rest_vertices, random_state=rng,
        )
    fine_v, fine_f = outer_surface(vx, fx, voxel_size=p["voxel_size"], merge_distance=p["merge_distance"], shortcuts=shortcuts)
    t_field = time.perf_counter() - t0
    target = int(params.n_vertices)
    if params.scale_by_area:
        target = round(target * float(face_areas(fine_v, fine_f).sum()) / area)
    v, f = decimate(fine_v, fine_f, target)
    if params.relax_iterations:
        v = relax_onto(v, f, SurfaceLocator(fine_v, fine_f, k=4), iterations=params.relax_iterations)
    locator = SurfaceLocator(vx, fx)
    face, bary, dist = locator.query(v)
    n_template_faces = len(faces)
    if params.keep_holes and caps.n_caps:
        on_cap = (face >= n_template_faces) & (dist <= p["unreliable_distance"])
        v, f, kept = _reopen_holes(v, f, on_cap)
        face, bary, dist = face[kept], bary[kept], dist[kept]
    unreliable = (dist > p["unreliable_distance"]) | (face >= n_template_faces)
    if rest_vertices is not None:
        unreliable |= _seam_vertices(v, f, caps.extend(np.asarray(rest_vertices, dtype=np.float64)), fx, face, bary, p["edge"])
    unreliable = _dilate(f, unreliable, params.unreliable_rings)
    mesh = TriangleMesh(v, f, name=name)
    info = {
        **{k: float(val) for k, val in p.items()},
        "target_vertices": target,
        "fine_vertices": len(fine_v),
        "n_shortcuts": len(shortcuts),
        "seconds_field": t_field,
        "seconds": time.perf_counter() - t0,
    }
    logger.info("%s: %d vertices, genus %d, %.1f%% unreliable, %.1f s", name or "shape", mesh.n_vertices, mesh.genus, 100 * unreliable.mean(), info["seconds"])
    return NoisyMesh(mesh, face, bary, dist, unreliable, tuple(shortcuts), info)


# ---------------------------------------------------------------------------------------
# a collection: null shape + noisy poses, ground truth and symmetry
# ---------------------------------------------------------------------------------------
def _template_sym_extended(sym: IndexArray | None, caps: HoleCaps) -> IndexArray | None:
    """Template symmetry map extended to the cap centres (mirror of the nearest cap)."""
    if sym is None:
        return None
    if not caps.n_caps:
        return sym
    ext = np.full(caps.n_vertices + caps.n_caps, -1, dtype=np.int64)
    ext[: caps.n_vertices] = sym
    for i, loop in enumerate(caps.loops):
        mirrored = sym[loop]
        mirrored = mirrored[mirrored >= 0]
        if len(mirrored) == 0:
            continue
        for j, other in enumerate(caps.loops):
            if np.isin(mirrored, other).mean() > 0.5:
                ext[caps.n_vertices + i] = caps.n_vertices + j
                break
    return ext


def _mirror_points(faces: IndexArray, face: IndexArray, bary: FloatArray, sym: IndexArray, vertices: FloatArray) -> tuple[FloatArray, BoolArray]:
    """Mirror images of surface points ``(face, bary)``: the same weights on the corners' mirrors.

    Returns the points, shape (n, 3), and whether every corner has a mirror, shape (n,).
    """
    corners = faces[face]
    m = sym[corners]
    ok = (m >= 0).all(axis=1)
    pts = np.einsum("ij,ijk->ik", bary, vertices[np.maximum(m, 0)])
    return pts, ok


def _make_null(
    rest: FloatArray, faces: IndexArray, caps: HoleCaps, n_vertices: int, name: str
) -> tuple[TriangleMesh, IndexArray, FloatArray]:
    """Make the null shape: the rest-pose template decimated directly (its holes kept)."""
    v, f = decimate(rest, faces, n_vertices)
    v, f = keep_largest_component(v, f)
    mesh = TriangleMesh(v, f, name=name)
    vx = caps.extend(rest)
    fx = np.concatenate([faces, caps.faces])
    face, bary, _ = SurfaceLocator(vx, fx).query(mesh.vertices)
    return mesh, face, bary


def noisy_collection(
    rest_vertices: FloatArray,
    faces: IndexArray,
    poses: Mapping[str, FloatArray],
    params: NoiseParams | None = None,
    *,
    pose_params: Mapping[str, NoiseParams] | None = None,
    template_sym: IndexArray | None = None,
    null_vertices: int | None = None,
    reference: str = "kid00",
    splits: Mapping[str, list[str]] | None = None,
    name: str = "synthetic",
    random_state: RandomState = None,
    n_jobs: int = 1,
) -> ShapeCollection:
    """Make a null shape and noisy poses with exact-as-possible ground truth, in memory.

    Parameters
    ----------
    rest_vertices : ndarray, shape (n_vertices, 3)
        The template in its rest (null) pose.
    faces : ndarray, shape (n_faces, 3)
        Template triangles, shared by every pose.
    poses : mapping of str to ndarray of shape (n_vertices, 3)
        Posed template vertices, by output shape name.
    params : NoiseParams, optional
    pose_params : mapping of str to NoiseParams, optional
        Parameters for particular poses (e.g. shortcuts in some only); others use
        ``params``.
    template_sym : ndarray, shape (n_vertices,), optional
        Left-right mirror vertex of each template vertex (-1 = none); enables ``sym``.
    null_vertices : int, optional
        Vertices of the null shape (default ``params.n_vertices``).
    reference : str
        Name of the null shape.
    splits : mapping, optional
        ``"train"`` / ``"test"`` / ``"all"`` lists (default: all poses in ``"all"`` and
        ``"train"``, none in ``"test"``).
    random_state : None, int or numpy.random.Generator
        Each pose gets its own generator spawned from it, in order, so results do not
        depend on ``n_jobs``.
    n_jobs : int
        Worker processes.

    Returns
    -------
    ShapeCollection
        Every shape has ``ref`` (one null vertex per vertex), ``unreliable`` and, with
        ``template_sym``, ``sym``.
    """
    params = params or NoiseParams()
    params.validate()
    pose_params = dict(pose_params or {})
    for key, pp in pose_params.items():
        if key not in poses:
            raise ValueError(f"pose_params names {key!r}, which is not a pose")
        pp.validate()
    rest = check_vertices(rest_vertices, "rest vertices")
    faces = check_faces(faces, len(rest), "template faces")
    if template_sym is not None:
        template_sym = np.asarray(template_sym, dtype=np.int64)
        if template_sym.shape != (len(rest),):
            raise ValueError(f"template_sym must have shape ({len(rest)},), got {template_sym.shape}")
    for key, pv in poses.items():
        if np.shape(pv) != rest.shape:
            raise ValueError(f"pose {key!r} has shape {np.shape(pv)}; the template has {rest.shape}")
    if reference in poses:
        raise ValueError(f"pose name {reference!r} is the reference's name")
    rng = check_random_state(random_state)
    caps = HoleCaps.build(faces, len(rest))
    fx = np.concatenate([faces, caps.faces])
    sym_x = _template_sym_extended(template_sym, caps)
    area = float(face_areas(rest, faces).sum())
    null_mesh, null_face, null_bary = _make_null(rest, faces, caps, int(null_vertices or params.n_vertices), reference)
    null_tree = cKDTree(null_mesh.vertices)
    rest_x = caps.extend(rest)

    seeds = rng.spawn(len(poses))
    names = list(poses)
    jobs = [(k, poses[k], s) for k, s in zip(names, seeds)]

    def one(key: str, posed: FloatArray, gen: np.random.Generator) -> NoisyMesh:
        return topological_noise(posed, faces, pose_params.get(key, params), caps=caps, clean_area=area, rest_vertices=rest, random_state=gen, name=key)

    if n_jobs > 1 and len(jobs) > 1:
        from joblib import Parallel, delayed

        results = Parallel(n_jobs=n_jobs)(delayed(one)(*j) for j in jobs)
    else:
        results = [one(*j) for j in jobs]

    shapes: dict[str, Shape] = {}
    # null shape: identity ground truth; symmetry through the template
    n_null = null_mesh.n_vertices
    null_sym = None
    if sym_x is not None:
        pts, ok = _mirror_points(fx, null_face, null_bary, sym_x, rest_x)
        _, j = null_tree.query(pts)
        null_sym = np.where(ok, j, -1).astype(np.int64)
    shapes[reference] = Shape(reference, null_mesh, ref=sparse.identity(n_null, dtype=np.int8, format="csr"), sym=null_sym)
    sym_tol = 1.5 * params.resolved(area)["edge"]
    for key, res in zip(names, results):
        rest_points = np.einsum("ij,ijk->ik", res.bary, rest_x[fx[res.face]])
        _, ref = null_tree.query(rest_points)
        n = res.mesh.n_vertices
        sym = None
        if sym_x is not None:
            pts, ok = _mirror_points(fx, res.face, res.bary, sym_x, caps.extend(poses[key]))
            d, u = cKDTree(res.mesh.vertices).query(pts)
            sym = np.where(ok & (d <= sym_tol) & ~res.unreliable, u, -1).astype(np.int64)
            sym[res.unreliable[np.maximum(sym, 0)] & (sym >= 0)] = -1
        shapes[key] = Shape(key, res.mesh, ref=ref_matrix(np.c_[np.arange(n), ref], n, n_null), sym=sym, unreliable=res.unreliable)
    if splits is None:
        splits = {"train": list(names), "test": [], "all": list(names)}
    return ShapeCollection(
        name=name,
        reference=reference,
        loaders={k: (lambda s=s: s) for k, s in shapes.items()},
        splits={k: list(v) for k, v in splits.items()},
        missing=[],
        root=None,
    )


# ---------------------------------------------------------------------------------------
# TOPKIDS layout
# ---------------------------------------------------------------------------------------
def write_topkids(
    collection: ShapeCollection, out_dir: PathType, *, resolution: str = "low", names: Mapping[str, str] | None = None
) -> Path:
    """Write a collection in the TOPKIDS release layout, into ``out_dir/low_res`` (or ``high_res``).

    Files: ``kid00.off`` and ``kid00_sym.txt`` (one column) for the reference, and for
    every other shape ``kidNN.off``, ``kidNN_ref.txt`` (vertex, null vertex; one-based),
    ``kidNN_sym.txt`` (vertex, mirror vertex; 0 = none), ``kidNN_indmap.txt`` (1 =
    unreliable) and ``kidNN_info.txt`` (counts, as in the release), so :func:`topomatch.datasets.topkids.load_topkids` reads it unchanged.

    Parameters
    ----------
    collection : ShapeCollection
    out_dir : path
        Data directory; the files go to its ``low_res`` (``high_res``) folder, or into
        ``out_dir`` itself when it is already called so. Pass it as ``--data``.
    resolution : {"low", "high"}
    names : mapping, optional
        Shape name -> file stem (default: the reference becomes ``kid00``, the others
        ``kid01``, ``kid02``, ... in collection order).

    Returns
    -------
    Path
        The folder holding the files.
    """
    from topomatch.io import write_indmap, write_off, write_ref

    if resolution not in ("low", "high"):
        raise ValueError(f"resolution must be 'low' or 'high', got {resolution!r}")
    sub = f"{resolution}_res"
    out = Path(out_dir)
    if out.name != sub:
        out = out / sub
    out.mkdir(parents=True, exist_ok=True)
    if names is None:
        others = [n for n in collection.names if n != collection.reference]
        if len(others) > 25:
            raise ValueError(f"the TOPKIDS layout holds kid01..kid25; {collection.name} has {len(others)} shapes")
        names = {collection.reference: "kid00", **{n: f"kid{i + 1:02d}" for i, n in enumerate(others)}}
    for name, stem in names.items():
        s = collection[name]
        write_off(out / f"{stem}.off", s.mesh.vertices, s.mesh.faces)
        if name == collection.reference:
            if s.sym is not None:
                _write_sym_column(out / f"{stem}_sym.txt", s.sym)
            continue
        if s.ref is None:
            raise ValueError(f"{name} has no ground truth to write")
        pairs = np.c_[np.arange(s.n_vertices), s.ref_p2p]
        write_ref(out / f"{stem}_ref.txt", pairs[pairs[:, 1] >= 0])
        if s.sym is not None:
            _write_sym_pairs(out / f"{stem}_sym.txt", s.sym)
        unrel = np.zeros(s.n_vertices, bool) if s.unreliable is None else s.unreliable
        write_indmap(out / f"{stem}_indmap.txt", unrel)
        info = (
            f"Number of vertices: {s.n_vertices:6d} \nNumber of faces: {s.mesh.n_faces:6d} \n"
            f"Percentage of vertices matched to reference: {100 * (1 - unrel.mean()):g} \n"
        )
        if s.sym is not None:
            info += f"Percentage of vertices with symmetry: {float(np.mean(s.sym >= 0)):g} \n"
        (out / f"{stem}_info.txt").write_text(info)
    return out


def _write_sym_column(path: Path, sym: IndexArray) -> None:
    """One-column ``_sym`` file (the TOPKIDS null shape's): line i holds i's mirror, 0 = none."""
    import os

    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text("".join(f"{int(v) + 1}\n" for v in sym))
    os.replace(tmp, path)


def _write_sym_pairs(path: Path, sym: IndexArray) -> None:
    from topomatch.io import write_sym

    write_sym(path, sym)


# ---------------------------------------------------------------------------------------
# files in, TOPKIDS layout out (the ``topomatch noise`` command)
# ---------------------------------------------------------------------------------------
def noise_files(
    null: PathType,
    poses: Sequence[PathType],
    out_dir: PathType,
    params: NoiseParams | None = None,
    *,
    vertex_maps: Sequence[PathType] | None = None,
    sym: PathType | None = None,
    mirror_axis: str | None = "auto",
    null_vertices: int | None = None,
    random_state: RandomState = None,
    n_jobs: int = 1,
) -> ShapeCollection:
    """Read a clean null shape and its poses, make them noisy, write the TOPKIDS layout.

    Parameters
    ----------
    null : path
        The clean null (rest-pose) mesh: the template.
    poses : sequence of paths
        Clean posed meshes, with the null shape's connectivity, or any connectivity
        plus a vertex map (``vertex_maps``).
    out_dir : path
    params : NoiseParams, optional
    vertex_maps : sequence of paths, optional
        One per pose: a one-based vertex map (one line per null vertex: its vertex on
        the pose), so poses with their own vertex order or connectivity can be used;
        the pose's vertices are then taken in null order.
    sym : path, optional
        The null shape's left-right map (TOPKIDS ``_sym`` format, one or two columns).
    mirror_axis : {"auto", "x", "y", "z"} or None
        Without ``sym``: find the map by reflecting the null shape across the middle
        plane normal to this axis (``"auto"`` tries x, y, z and keeps the first across
        which the shape is symmetric up to its sampling; ``None`` = no symmetry).
    null_vertices : int, optional
    random_state : None, int or numpy.random.Generator
    n_jobs : int

    Returns
    -------
    ShapeCollection
        As read back from ``out_dir`` by :func:`~topomatch.datasets.topkids.load_topkids`.
    """
    from topomatch.datasets.topkids import TEST_SHAPES, TRAIN_SHAPES, load_topkids
    from topomatch.io import read_mesh, read_p2p, read_sym

    if len(poses) == 0:
        raise ValueError("no pose given")
    if len(poses) > 25:
        raise ValueError(f"the TOPKIDS layout holds 25 poses (kid01..kid25); got {len(poses)}")
    if vertex_maps is not None and len(vertex_maps) != len(poses):
        raise ValueError(f"{len(vertex_maps)} vertex maps for {len(poses)} poses")
    rest, faces = read_mesh(null)
    posed: dict[str, FloatArray] = {}
    for i, path in enumerate(poses):
        v, f = read_mesh(path)
        key = f"kid{i + 1:02d}"
        if vertex_maps is not None:
            vm = read_p2p(vertex_maps[i], len(rest), len(v))
            if (vm < 0).any():
                raise ValueError(f"{vertex_maps[i]}: every null vertex needs a vertex on {path}")
            v = v[vm]
        elif len(v) != len(rest) or not np.array_equal(f, faces):
            raise ValueError(f"{path}: connectivity differs from {null}; pass a vertex map for it")
        posed[key] = v
    tsym = None
    if sym is not None:
        tsym = read_sym(sym, len(rest))
    elif mirror_axis is not None:
        tsym = _find_mirror(rest, faces, mirror_axis)
        if tsym is None:
            logger.warning("%s is not mirror-symmetric along %s: no symmetry maps written", null, mirror_axis)
    names = list(posed)
    splits = {"train": [n for n in names if n in TRAIN_SHAPES], "test": [n for n in names if n in TEST_SHAPES], "all": names}
    coll = noisy_collection(
        rest, faces, posed, params, template_sym=tsym, null_vertices=null_vertices, reference="kid00",
        splits=splits, name=str(out_dir), random_state=random_state, n_jobs=n_jobs,
    )
    folder = write_topkids(coll, out_dir, names={n: n for n in ["kid00", *names]})
    return load_topkids(folder, "low")


def _find_mirror(rest: FloatArray, faces: IndexArray, axis: str) -> IndexArray | None:
    """Left-right map by reflection, if the shape is mirror-symmetric across one axis.

    An axis is accepted when the reflected vertices land as close to vertices as points
    of the surface itself would (median within 0.4 and 95% within 0.8 of the median
    edge length); each vertex then gets the nearest vertex to its reflection (``-1``
    when that is farther than 1.5 edges).
    """
    edge = float(np.median(np.linalg.norm(rest[faces[:, 0]] - rest[faces[:, 1]], axis=1)))
    axes = {"x": [0], "y": [1], "z": [2], "auto": [0, 1, 2]}
    if axis not in axes:
        raise ValueError(f"mirror_axis must be auto, x, y, z or None, got {axis!r}")
    tree = cKDTree(rest)
    for a in axes[axis]:
        m = rest.copy()
        mid = 0.5 * (rest[:, a].min() + rest[:, a].max())
        m[:, a] = 2 * mid - m[:, a]
        d, j = tree.query(m)
        if np.median(d) <= 0.4 * edge and np.percentile(d, 95) <= 0.8 * edge:
            return np.where(d <= 1.5 * edge, j, -1).astype(np.int64)
    return None
