"""The flagship matcher: spectral hypotheses, verified and refined by deforming the source.

1. **Hypotheses.** Functional maps are estimated for several descriptor families and
   basis sizes (by default three orientation-preserving HKS maps, k = 50, 30, 10;
   orientation-reversing settings can be added to catch maps whose orientation term was
   fooled), and each is upsampled by ZoomOut on farthest-point samples. Under topological noise any one of them may be wrong, but
   different settings fail on different pairs.
2. **Verification.** Each hypothesis seeds a coarse non-rigid registration of the
   source onto the target (embedded deformation graph, robust fit to the hypothesis'
   correspondences, then closest-point iterations). The source keeps its own
   connectivity, so it cannot take the target's shortcuts; a wrong hypothesis leaves a
   poor fit. The hypothesis whose registered source fits the target best (mean capped
   two-sided distance) wins. No ground truth is involved.
   Besides the functional maps, *rigid* hypotheses are verified the same way: the
   source scaled to the target's area and rotated into the target's frame (as given,
   and by the four proper alignments of the principal axes), refined by a short rigid
   ICP, then nearest points. They are blind to intrinsic structure and so cannot be
   fooled by the target's shortcuts, which is where the functional maps fail. To reach
   poses far from the source's, the source is also bent in two (at the median of its
   Fiedler vector, one half turned by 60, 90 or 120 degrees either way) and the three
   best-fitting bent copies are aligned the same way (*articulated* hypotheses). Where the
   source is known in other poses (``register(..., poses=...)``: ``template`` gives the
   template in its training shapes' poses), the three best rigid alignments of the
   posed copies are verified too (*pose* hypotheses). Maps of other axiomatic
   matchers (e.g. ``ge``, ``em``) can be added as hypotheses.
3. **Assembly.** Under heavy noise no single registration is right everywhere, so
   regions where another verified registration differs from the winner are swapped in
   when that lowers the fit residual (:func:`swap_regions`).
4. **Choice.** The (assembled) winner and the next best-verified registrations continue
   their closest-point iterations on the coarse graph, which can still move whole limbs;
   the one with the lowest fit residual plus a weighted graph distortion goes on (a body
   turned front to back fits almost as well, but only by bending out of shape).
5. **Limbs.** A limb left in the wrong place (an arm lying on a leg of a folded
   figure) fits locally, so the closest-point iterations keep it there. The source's
   limbs and their outer halves (:func:`source_limbs`) are each turned about their root
   through a fixed set of rotations; the two parts whose best turns best cover what
   the target has left uncovered are each turned (:func:`turn_limb`), the coarse
   registration continues from each, and the better of them is kept if the residual
   plus distortion drops; up to three such rounds.
6. **Refinement.** It is registered again on a finer graph with point-to-plane closest
   points on all vertices.
7. **Features against sliding.** The closest points let the surfaces slide along each
   other where the shape does not tell places apart, so a last registration pairs
   vertices nearest in position *and* local shape features (:func:`local_wks_features`),
   the features' weight falling to zero; every target vertex then takes the nearest
   deformed source vertex with a compatible normal (:func:`map_from_deformed`).

A pair with a mesh larger than ``working_vertices`` (12,000 by default) goes through
steps 1-7 as decimated copies of each of ``working_sizes`` (8,000, 12,000 and 20,000
vertices); each copy's deformation is carried back to the full source, and the one
that fits the full target best (residual plus weighted distortion) is kept before the
map is read off.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass
from functools import partial
from itertools import chain, product
from types import MappingProxyType
from typing import Any, NamedTuple, TypeVar

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from topomatch._blas import one_blas_thread
from topomatch._cache import array_hash
from topomatch.deform.graph import DeformationGraph, build_deformation_graph
from topomatch.deform.kdtree import PointTree
from topomatch.deform.register import (
    DataPairs,
    GraphDeformation,
    RegistrationResult,
    RegistrationSchedule,
    fit_residual,
    nearest_compatible,
    register,
)
from topomatch.descriptors.spectral import mesh_wks
from topomatch.maps.fmap import (
    FmapWeights,
    descriptor_coefficients,
    multiplication_operators,
    orientation_operators,
    scale_free_evals,
    solve_fmap,
)
from topomatch.maps.knn import nearest_neighbors
from topomatch.maps.operations import folded_fraction
from topomatch.maps.patches import fill_small_patches
from topomatch.maps.zoomout import _fmap_from_p2p_rows, zoomout_schedule
from topomatch.matching.base import Correspondence, Matcher
from topomatch.matching.fmap import spectral_descriptors
from topomatch.mesh import TriangleMesh
from topomatch.mesh.decimate import decimate, surface_weights
from topomatch.mesh.geometry import axis_rotation, edges_with_counts, face_areas, vertex_normals
from topomatch.mesh.mesh import EigenbasisJob
from topomatch.mesh.sampling import farthest_point_sampling
from topomatch.typing import BoolArray, FloatArray, IndexArray

__all__ = [
    "ACCURATE",
    "DeformMatcher",
    "Hypothesis",
    "align_poses",
    "articulated_hypotheses",
    "bend_in_two",
    "local_wks_features",
    "map_from_deformed",
    "pose_hypotheses",
    "rigid_hypotheses",
    "source_limbs",
    "spectral_hypotheses",
    "swap_regions",
    "turn_limb",
]

logger = logging.getLogger(__name__)

_T = TypeVar("_T")
_R = TypeVar("_R")


@dataclass(frozen=True)
class Hypothesis:
    """A candidate correspondence on the target's samples.

    Attributes
    ----------
    label : str
        How it was made, e.g. ``"hks k=30 preserving"``.
    p2p : ndarray, shape (n_target_samples,)
        Source vertex for each target sample.
    """

    label: str
    p2p: IndexArray
    target: IndexArray | None = None
    """Target vertices the map is given on (``None``: the target samples)."""


@dataclass
class _Verified:
    """One registration's steps 1-2 (hypotheses and their verification), waiting for steps 3-6."""

    source: TriangleMesh
    target: TriangleMesh
    start: int
    samples: tuple[IndexArray, IndexArray]
    graph: DeformationGraph
    hyps: list[Hypothesis]
    results: list[Any]
    """The verifications' RegistrationResults (futures on a shared pool) once :func:`_collected`."""
    order: IndexArray
    """The results by residual, best first (empty until :func:`_collected`)."""
    seconds: float
    intrinsic: TriangleMesh | None = None
    """The mesh whose intrinsic data (the spectral hypotheses, the feature stage's local
    features) stand for the source's: the source as it is for a registration of the source
    in a pose (``pose_sources``); ``None``: the source."""
    surface: IndexArray | None = None
    """The coarse registrations' surface subset (``surface_vertices``, :meth:`DeformMatcher._surface`; ``None``: every vertex)."""
    resume: Callable[[list[RegistrationResult]], list[Any]] | None = None
    """With ``race_iterations``, until :func:`_raced`: takes the verifications stopped in
    the race that go on and returns their whole registrations (futures on a shared pool)."""
    keep: int = 0
    """How many go on after the race (``race_keep``)."""
    kept: IndexArray | None = None
    """After the race: the verifications that went on (the others stopped early)."""


class _Working(NamedTuple):
    """One working size of :meth:`DeformMatcher.register`, made once and shared by the contenders' and the challengers' runs."""

    source: TriangleMesh
    target: TriangleMesh
    poses: Sequence[tuple[str, FloatArray]]
    """The source's known poses carried to the source's copy."""
    memo: dict[str, Any]
    """The poses' alignments to the target (on start 0's samples)."""
    back: FloatArray | None
    """Barycentric weights from the source's vertices to its copy's (``None``: no copy)."""
    ranked: list[int]
    """The posed sources, best-fitting first: ``pose_sources`` of them, then the challengers."""


@dataclass
class _Spectral:
    evals: FloatArray
    basis_evecs: FloatArray
    mass: FloatArray
    coeffs: dict
    mult_ops: dict
    orient_ops: dict


def _raced(v: _Verified) -> _Verified:
    """``v`` after its race (``race_iterations``): the ``keep`` best of the stopped verifications go on.

    Waits for the stopped verifications; the ones that go on are submitted (to a shared
    pool, their futures in ``results``) or registered here. Without a race: ``v``.
    """
    if v.resume is None:
        return v
    t0 = time.perf_counter()
    results = [r.result() if isinstance(r, Future) else r for r in v.results]
    kept = np.sort(np.argsort([r.residual for r in results], kind="stable")[: v.keep])
    resumed = v.resume([results[i] for i in kept])
    for i, r in zip(kept, resumed):
        results[i] = r
    return dataclasses.replace(v, results=results, resume=None, kept=kept, seconds=v.seconds + time.perf_counter() - t0)


def _collected(v: _Verified) -> _Verified:
    """``v`` with its verifications' results (futures when submitted to a shared pool) in hand, and their order.

    The order is by residual, best first; after a race the verifications that went on
    come first (their residuals are after the whole schedule, the others' after the race).
    """
    v = _raced(v)
    t0 = time.perf_counter()
    results = [r.result() if isinstance(r, Future) else r for r in v.results]
    residuals = [r.residual for r in results]
    if v.kept is None:
        order = np.argsort(residuals, kind="stable")
    else:
        stopped = np.ones(len(results), dtype=bool)
        stopped[v.kept] = False
        order = np.lexsort((residuals, stopped))
    return dataclasses.replace(v, results=results, order=order, seconds=v.seconds + time.perf_counter() - t0)


def _spectral_data(mesh: TriangleMesh, kinds: tuple[str, ...], k_ops: int, k_basis: int, n_desc: int, n_ops: int) -> _Spectral:
    basis = mesh.eigenbasis(k_basis)
    small = basis.truncate(k_ops)
    coeffs, mult, orient = {}, {}, {}
    for kind in kinds:
        d = spectral_descriptors(mesh, kind, n_desc, k_basis)
        cols = np.unique(np.linspace(0, d.shape[1] - 1, min(n_ops, d.shape[1])).round().astype(int))
        coeffs[kind] = descriptor_coefficients(small, d)
        mult[kind] = multiplication_operators(small, d[:, cols])
        orient[kind] = orientation_operators(mesh.vertices, mesh.faces, small, d[:, cols])
    return _Spectral(scale_free_evals(basis), basis.evecs, basis.mass, coeffs, mult, orient)


_SPECTRAL_KEPT = 4
"""Shapes whose spectral data (:func:`_spectral_data`) stay in memory, the latest used:
a template's, registered onto every shape, and the shapes of the pairs at hand."""

_SPECTRAL: OrderedDict[tuple[Any, ...], _Spectral] = OrderedDict()
_SPECTRAL_LOCK = threading.Lock()


def _shape_spectral(mesh: TriangleMesh, kinds: tuple[str, ...], k_ops: int, k_basis: int, n_desc: int, n_ops: int) -> _Spectral:
    """:func:`_spectral_data`, kept for the ``_SPECTRAL_KEPT`` shapes used last (by content: a pure function of the mesh).

    A shape's data do not depend on the other shape or on the samples: the target's
    serve every registration onto it (sampling starts, posed sources), the template's
    every pair.
    """
    key = (mesh.content_hash, kinds, k_ops, k_basis, n_desc, n_ops)
    with _SPECTRAL_LOCK:
        data = _SPECTRAL.get(key)
        if data is not None:
            _SPECTRAL.move_to_end(key)
            return data
    data = _spectral_data(mesh, kinds, k_ops, k_basis, n_desc, n_ops)
    with _SPECTRAL_LOCK:
        _SPECTRAL[key] = data
        while len(_SPECTRAL) > _SPECTRAL_KEPT:
            _SPECTRAL.popitem(last=False)
    return data


_PREPARED_KEPT = 16
"""Farthest-point samples and deformation graphs (:func:`_prepared`) that stay in memory,
the latest used: a template's (the same for every pair: each sampling start's samples,
coarse and fine graphs) and the pair's target's (shared by its registrations)."""

_PREPARED: OrderedDict[tuple[Any, ...], Any] = OrderedDict()
_PREPARED_LOCK = threading.Lock()


def _prepared(key: tuple[Any, ...], make: Callable[[], _T]) -> _T:
    """``make()``, kept for the ``_PREPARED_KEPT`` keys used last; ``key`` must name everything ``make`` depends on.

    For pure functions of a mesh (keyed by its content) that every registration of a
    pair, and every pair of a template, would otherwise redo: the samples and graphs
    are the same arrays, so the registrations are the same bit for bit. Kept arrays
    are made read-only (one object serves registrations on several threads).
    """
    with _PREPARED_LOCK:
        value = _PREPARED.get(key)
        if value is not None:
            _PREPARED.move_to_end(key)
            return value
    value = make()
    if isinstance(value, np.ndarray):
        value.setflags(write=False)
    with _PREPARED_LOCK:
        value = _PREPARED.setdefault(key, value)
        _PREPARED.move_to_end(key)
        while len(_PREPARED) > _PREPARED_KEPT:
            _PREPARED.popitem(last=False)
    return value


def spectral_hypotheses(
    source: TriangleMesh,
    target: TriangleMesh,
    samples_1: IndexArray,
    samples_2: IndexArray,
    settings: list[tuple[str, int, bool]],
    *,
    k_zoomout: int = 100,
    step: int = 5,
    n_descriptors: int = 100,
    n_operator_descriptors: int = 20,
    weights: FmapWeights | None = None,
    cache: dict[Any, Any] | None = None,
) -> Iterator[Hypothesis]:
    """Functional-map hypotheses upsampled by ZoomOut on samples, generated lazily.

    Parameters
    ----------
    source, target : TriangleMesh
    samples_1 : ndarray, shape (m1,)
        Source vertex samples.
    samples_2 : ndarray, shape (m2,)
        Target vertex samples.
    settings : list of (descriptor, k, reversing)
        Descriptor family (``"hks"`` or ``"wks"``), initial functional map size, and
        whether the orientation term asks for an orientation-reversing map; in the
        order the hypotheses are produced.
    k_zoomout : int
        Final ZoomOut size (and eigenpairs used).
    step : int
    n_descriptors, n_operator_descriptors : int
    weights : FmapWeights, optional
        Default: ``FmapWeights(orientation=1.0)``.
    cache : dict, optional
        Keeps the initial functional maps (they do not depend on the samples) for later
        calls on the same pair with other samples, e.g. the sampling starts of
        :class:`DeformMatcher` (``n_starts``), and each hypothesis for a later call with
        the same samples (read-only arrays). Each shape's eigenbasis, descriptors and
        operators are kept by content in any case, for the last few shapes used
        (:func:`_shape_spectral`).

    Yields
    ------
    Hypothesis
        A map from the target samples to source vertices.
    """
    weights = FmapWeights(orientation=1.0) if weights is None else weights
    kinds = tuple(dict.fromkeys(kind for kind, _, _ in settings))
    k_ops = max(k for _, k, _ in settings)
    if k_ops > k_zoomout:
        raise ValueError(f"initial sizes must not exceed k_zoomout={k_zoomout}, got {k_ops}")
    key = ("spectral", kinds, k_ops, k_zoomout, n_descriptors, n_operator_descriptors, source.content_hash, target.content_hash)
    s1, s2 = (_shape_spectral(mesh, kinds, k_ops, k_zoomout, n_descriptors, n_operator_descriptors) for mesh in (source, target))
    e1 = s1.basis_evecs[samples_1]
    e2 = s2.basis_evecs[samples_2]
    m2 = s2.mass[samples_2] * (s2.mass.sum() / s2.mass[samples_2].sum())
    # the hypotheses themselves depend on the samples too: kept per pair, setting and samples
    sampled = (array_hash(np.asarray(samples_1, dtype=np.int64), np.asarray(samples_2, dtype=np.int64)), step)
    for kind, k, rev in settings:
        h_key = (key, kind, k, rev, weights, sampled)
        kept = cache.get(h_key) if cache is not None else None
        if kept is not None:
            yield Hypothesis(_spectral_label(kind, k, rev), kept)
            continue
        sign = -1.0 if rev else 1.0
        # the initial map does not depend on the samples: solved once per pair and setting
        c_key = (key, kind, k, rev, weights)
        C = cache.get(c_key) if cache is not None else None
        if C is None:
            C = solve_fmap(
                s1.coeffs[kind][:k], s2.coeffs[kind][:k], s1.evals[:k], s2.evals[:k], weights=weights,
                commutativity_ops=(s1.mult_ops[kind][:, :k, :k], s2.mult_ops[kind][:, :k, :k]),
                orientation_ops=(s1.orient_ops[kind][:, :k, :k], sign * s2.orient_ops[kind][:, :k, :k]),
            )
            if cache is not None:
                cache[c_key] = C
        for kk in zoomout_schedule(k, k_zoomout, step)[1:]:
            kc = C.shape[0]
            p = nearest_neighbors(e1[:, :kc] @ C.T, e2[:, :kc])
            C = _fmap_from_p2p_rows(p, e1[:, :kk], e2[:, :kk], m2)
        p = nearest_neighbors(e1[:, : C.shape[0]] @ C.T, e2[:, : C.shape[0]])
        mapped = np.asarray(samples_1)[p]
        if cache is not None:
            mapped.setflags(write=False)
            cache[h_key] = mapped
        yield Hypothesis(_spectral_label(kind, k, rev), mapped)


def _followed(label: str, only: frozenset[str]) -> bool:
    """Whether a follower (``DeformMatcher.follow_top``) verifies ``label``: listed in ``only``, or in a family listed as ``"<prefix>*"``."""
    return label in only or any(x.endswith("*") and label.startswith(x[:-1]) for x in only)


def _spectral_label(kind: str, k: int, reversing: bool) -> str:
    """The label of :func:`spectral_hypotheses`' hypothesis for one setting, e.g. ``"hks k=10 preserving"``."""
    return f"{kind} k={k} {'reversing' if reversing else 'preserving'}"


RIGID_FRAMES = ("as-given", "principal-axes")

ACCURATE: Mapping[str, Any] = MappingProxyType({"n_starts": 5})
""":class:`DeformMatcher` settings for when a registration may take about five times the
default's: five registrations from different farthest-point sampling starts, the one
that fits best kept (``n_starts``). On the training pairs (kid00 -> kid01..kid15, mean
geodesic error x100, Dijkstra, pooled) 2.70 -> 2.36 (kid14 7.24 -> 5.04, kid15 14.85 ->
12.47), on the built-in topkids25-style pairs 1.70 -> 1.37; the ``template`` matcher
registers with them when it has no training poses, since each of its registrations
serves every pair of the shape (``docs/flagship.md``, attempt #85; with training poses
it registers with two starts, which do better on the training pairs, attempt #86). Until session 26 these were
``{"fine_icp_iterations": 80, "limb_judge": "fine", "limb_judge_iterations": 25}``
(training pairs 2.63; with three starts 2.57 against 2.53 for the default settings
with three starts)."""


def _rigid_icp(
    X: FloatArray, NX: FloatArray, Y: FloatArray, NY: FloatArray, R: FloatArray, t: FloatArray, iterations: int, tree: PointTree | None = None
) -> tuple[FloatArray, FloatArray]:
    """Refine ``x -> R x + t`` by point-to-point ICP with normal-compatible, robustly weighted pairs.

    ``tree``: a :class:`PointTree` on ``Y`` (one serves every alignment onto the same
    points); ``None`` builds one.
    """
    tree = PointTree(Y) if tree is None else tree
    for _ in range(iterations):
        Xt = X @ R.T + t
        j, d = nearest_compatible(Xt, NX @ R.T, tree, NY, min_cos=0.3)
        w = 1.0 / (1.0 + (d / (np.median(d) + 1e-12)) ** 2)
        mx = w @ Xt / w.sum()
        my = w @ Y[j] / w.sum()
        U, _, Vt = np.linalg.svd(((Xt - mx) * w[:, None]).T @ (Y[j] - my))
        dR = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
        R = dR @ R
        t = dR @ (t - mx) + my
    return R, t


def _nearest_aligned(W: FloatArray, Nw: FloatArray, X: FloatArray, NX: FloatArray) -> IndexArray:
    """For each target sample ``W`` (normals ``Nw``), the nearest aligned source vertex ``X`` (normals ``NX``) with a compatible normal."""
    j, _ = nearest_compatible(W, Nw, PointTree(X), NX, min_cos=0.3)
    return np.asarray(j, dtype=np.int64)


def rigid_hypotheses(
    source: TriangleMesh,
    target: TriangleMesh,
    samples_1: IndexArray,
    samples_2: IndexArray,
    frames: tuple[str, ...] = RIGID_FRAMES,
    *,
    icp_iterations: int = 15,
) -> Iterator[Hypothesis]:
    """Extrinsic hypotheses: rigid alignments of the source onto the target, then nearest points.

    The source is scaled by ``sqrt(area_target / area_source)`` and centred on the
    target's centroid, with the rotation

    - ``"as-given"``: the identity (the shapes' own frames agree, as for scans from one
      rig or a dataset in a common frame);
    - ``"principal-axes"``: each of the four proper rotations that map the source's
      principal axes onto the target's (the sign ambiguity of the axes).

    Each start is refined by a rigid ICP on the samples; each target sample then takes
    the nearest aligned source vertex with a compatible normal.

    Parameters
    ----------
    source, target : TriangleMesh
    samples_1 : ndarray, shape (m1,)
        Source vertex samples.
    samples_2 : ndarray, shape (m2,)
        Target vertex samples.
    frames : tuple of str
        Any of ``"as-given"`` and ``"principal-axes"``.
    icp_iterations : int

    Yields
    ------
    Hypothesis
        A map from the target samples to source vertices.
    """
    bad = [f for f in frames if f not in RIGID_FRAMES]
    if bad:
        raise ValueError(f"rigid frames must be among {RIGID_FRAMES}, got {bad}")
    s1 = np.asarray(samples_1)
    V = source.vertices
    W = target.vertices[samples_2]
    Nw = target.vertex_normals[samples_2]
    scale = float(np.sqrt(target.area / source.area))
    c1 = V.mean(axis=0)
    c2 = target.vertices.mean(axis=0)
    starts = [("rigid " + (suffix.strip() or "as-given"), R) for suffix, R in _frame_rotations(V, target.vertices, frames)]
    X = scale * V[s1]
    NX = source.vertex_normals[s1]
    tree = PointTree(W)
    for label, R0 in starts:
        R, t = _rigid_icp(X, NX, W, Nw, R0, c2 - scale * (R0 @ c1), icp_iterations, tree)
        yield Hypothesis(label, _nearest_aligned(W, Nw, scale * V @ R.T + t, source.vertex_normals @ R.T))


def bend_in_two(
    vertices: FloatArray, faces: IndexArray, fiedler: FloatArray, mass: FloatArray, angles: Sequence[float]
) -> list[tuple[str, FloatArray]]:
    """The source bent in two at the median of its Fiedler vector, each half turned both ways.

    The split is at the area-weighted median of ``fiedler`` (the vertices at the median
    join the lighter side, so the split does not depend on the eigenvector's sign); the hinge is the centroid
    of the vertices on edges that cross it, and the hinge axis is the source's widest
    direction perpendicular to the split direction (the line between the two halves'
    centroids). For a standing figure the halves are the upper and lower body and the
    axis runs left to right, so the four shapes are: legs forward and backward, upper
    body forward and backward.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
    faces : ndarray, shape (f, 3)
    fiedler : ndarray, shape (n,)
        First non-constant Laplacian eigenvector.
    mass : ndarray, shape (n,)
        Vertex areas.
    angles : sequence of float
        Degrees; the split, hinge and axis are computed once for all of them.

    Returns
    -------
    list of (str, ndarray of shape (n, 3))
        A label and the bent vertex positions, four per angle in the order of
        ``angles``: half a (``fiedler`` above the median) turned by ``+angle`` and
        ``-angle``, then half b; empty if the split leaves a half empty. The set does
        not depend on the eigenvector's sign.
    """
    V = np.asarray(vertices, dtype=np.float64)
    order = np.argsort(fiedler, kind="stable")
    cum = np.cumsum(mass[order])
    f_mid = fiedler[order[min(np.searchsorted(cum, 0.5 * cum[-1]), len(order) - 1)]]
    above, below = fiedler > f_mid, fiedler < f_mid
    # the vertices at the median go to the lighter side: the split does not depend on the sign
    half_a = above | ((fiedler == f_mid) & (mass[above].sum() < mass[below].sum()))
    E = edges_with_counts(np.asarray(faces))[0]
    cross = E[half_a[E[:, 0]] != half_a[E[:, 1]]]
    if not half_a.any() or half_a.all() or len(cross) == 0:
        return []
    hinge = V[np.unique(cross)].mean(axis=0)
    d = V[half_a].mean(axis=0) - V[~half_a].mean(axis=0)
    d /= np.linalg.norm(d)
    axes = np.linalg.svd(V - V.mean(axis=0), full_matrices=False)[2]
    perp = axes - np.outer(axes @ d, d)
    axis = perp[int(np.argmax(np.linalg.norm(perp, axis=1) > 0.5))]  # axis_rotation normalises it
    out = []
    for angle, (name, half), sign in product(angles, (("a", half_a), ("b", ~half_a)), (1.0, -1.0)):
        R = axis_rotation(axis, np.deg2rad(sign * angle))
        Vb = V.copy()
        Vb[half] = (V[half] - hinge) @ R.T + hinge
        out.append((f"half {name} {sign * angle:+.0f}", Vb))
    return out


#: The labels of :func:`articulated_hypotheses`' bent copies begin with this.
_BENT = "bent "


def articulated_hypotheses(
    source: TriangleMesh,
    target: TriangleMesh,
    samples_1: IndexArray,
    samples_2: IndexArray,
    *,
    n_keep: int = 3,
    angles: tuple[float, ...] = (60.0, 90.0, 120.0),
    icp_iterations: int = 15,
) -> Iterator[Hypothesis]:
    """Rigid hypotheses of the source bent in two (sitting, bending forward, ...).

    Rigid hypotheses cannot reach a pose far from the source's, and under fusion the
    spectral ones often fail there too. Here the source is first bent in two
    (:func:`bend_in_two`: at the median of its Fiedler vector, one half turned by
    each of ``+-angles`` about the hinge), then each bent copy is placed like the ``"as-given"``
    rigid hypothesis (scaled to the target's area, centred on it, not rotated), refined
    by rigid ICP on the samples, and scored by its mean capped two-sided distance to the
    target; the ``n_keep`` best are yielded, each target sample taking the nearest
    bent, aligned source vertex with a compatible normal. Like ``"as-given"`` they
    assume the shapes share an up direction.

    Parameters
    ----------
    source, target : TriangleMesh
    samples_1 : ndarray, shape (m1,)
        Source vertex samples.
    samples_2 : ndarray, shape (m2,)
        Target vertex samples.
    n_keep : int
        How many of the bent sources (four per angle) to yield, best fitting first.
    angles : tuple of float
        Bending angles in degrees.
    icp_iterations : int

    Yields
    ------
    Hypothesis
        A map from the target samples to source vertices.
    """
    basis = source.eigenbasis(2)
    bent = bend_in_two(source.vertices, source.faces, basis.evecs[:, 1], basis.mass, angles)
    scale = float(np.sqrt(target.area / source.area))
    posed = [(_BENT + label, Vb, scale) for label, Vb in bent]
    for label, X, NX, _ in _align_posed(target, source.faces, samples_1, samples_2, posed, ("as-given",), n_keep, icp_iterations):
        yield Hypothesis(label, _nearest_aligned(target.vertices[samples_2], target.vertex_normals[samples_2], X, NX))


def _align_posed(
    target: TriangleMesh,
    faces: IndexArray,
    samples_1: IndexArray,
    samples_2: IndexArray,
    posed: Sequence[tuple[str, FloatArray, float]],
    frames: tuple[str, ...],
    n_keep: int | None,
    icp_iterations: int,
    n_threads: int = 1,
) -> list[tuple[str, FloatArray, FloatArray, int]]:
    """Rigidly align copies of the source in other poses to the target; the ``n_keep`` best fitting (all for ``None``).

    Each ``(label, vertices, scale)`` of ``posed`` is scaled, centred on the target and
    rotated by each start of ``frames`` (as in :func:`rigid_hypotheses`), refined by
    rigid ICP on the samples and scored by its mean capped two-sided distance to the
    target samples. Returns the ``n_keep`` best as (label, aligned vertices, their
    normals, index of the copy in ``posed``), best first. The alignments run on
    ``n_threads`` threads; the result does not depend on it.
    """
    s1 = np.asarray(samples_1)
    W = target.vertices[samples_2]
    Nw = target.vertex_normals[samples_2]
    cap = 0.05 * float(np.sqrt(target.area))
    c2 = target.vertices.mean(axis=0)
    tree = PointTree(W)
    jobs = []
    for index, (name, Vb, scale) in enumerate(posed):
        Nb = vertex_normals(Vb, faces)
        for suffix, R0 in _frame_rotations(Vb, target.vertices, frames):
            jobs.append((index, name + suffix, Vb, Nb, scale, R0))

    def align(job: tuple[int, str, FloatArray, FloatArray, float, FloatArray]) -> tuple[float, str, FloatArray, FloatArray, FloatArray, FloatArray, float, int]:
        index, label, Vb, Nb, scale, R0 = job
        R, t = _rigid_icp(scale * Vb[s1], Nb[s1], W, Nw, R0, c2 - scale * (R0 @ Vb.mean(axis=0)), icp_iterations, tree)
        X = scale * Vb[s1] @ R.T + t
        NX = Nb[s1] @ R.T
        _, d1 = nearest_compatible(X, NX, tree, Nw, min_cos=0.3)
        _, d2 = nearest_compatible(W, Nw, PointTree(X), NX, min_cos=0.3)
        residual = 0.5 * (float(np.mean(np.minimum(d1, cap))) + float(np.mean(np.minimum(d2, cap))))
        return residual, label, Vb, Nb, R, t, scale, index

    scored = _thread_map(align, jobs, n_threads)  # in the jobs' order, so ties sort as before
    scored.sort(key=lambda x: x[0])
    for residual, label, *_ in scored[:n_keep]:
        logger.debug("%s: rigid residual %.4f", label, residual / np.sqrt(target.area))
    return [(label, scale * Vb @ R.T + t, Nb @ R.T, index) for _, label, Vb, Nb, R, t, scale, index in scored[:n_keep]]


def _frame_rotations(V: FloatArray, target_vertices: FloatArray, frames: tuple[str, ...]) -> list[tuple[str, FloatArray]]:
    """Label suffixes and starting rotations of ``V`` onto the target for ``frames`` (see :func:`rigid_hypotheses`)."""
    out: list[tuple[str, FloatArray]] = []
    if "as-given" in frames:
        out.append(("", np.eye(3)))
    if "principal-axes" in frames:
        A1 = np.linalg.svd(V - V.mean(axis=0), full_matrices=False)[2]
        A2 = np.linalg.svd(target_vertices - target_vertices.mean(axis=0), full_matrices=False)[2]
        flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(A1) * np.linalg.det(A2))])
        for signs in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
            out.append((" axes " + "".join("+" if x > 0 else "-" for x in signs), A2.T @ np.diag(signs) @ flip @ A1))
    return out


def pose_hypotheses(
    source: TriangleMesh,
    target: TriangleMesh,
    samples_1: IndexArray,
    samples_2: IndexArray,
    poses: Sequence[tuple[str, FloatArray]],
    *,
    n_keep: int = 3,
    frames: tuple[str, ...] = RIGID_FRAMES,
    icp_iterations: int = 15,
) -> Iterator[Hypothesis]:
    """Rigid hypotheses of the source in other, known poses (e.g. the training shapes' poses).

    A prior for a source that has been seen in other poses: a template with training
    shapes whose ground truth gives the template's vertices in their poses
    (:func:`~topomatch.matching.template.pose_from_ground_truth`). Each posed copy
    is scaled to the target's area, centred on it, started from each rotation of
    ``frames`` (as for :func:`rigid_hypotheses`), refined by rigid ICP on the samples
    and scored by its mean capped two-sided distance to the target; the ``n_keep``
    best alignments (over all poses and starts) are yielded, each target sample taking
    the nearest posed, aligned source vertex with a compatible normal.

    Parameters
    ----------
    source, target : TriangleMesh
    samples_1 : ndarray, shape (m1,)
        Source vertex samples.
    samples_2 : ndarray, shape (m2,)
        Target vertex samples.
    poses : sequence of (str, ndarray of shape (n_source, 3))
        A name and the source's vertex positions in that pose (the source's faces).
    n_keep : int
        How many alignments to yield, best fitting first.
    frames : tuple of str
        Any of ``"as-given"`` and ``"principal-axes"``.
    icp_iterations : int

    Yields
    ------
    Hypothesis
        Labelled ``"pose <name>"`` (plus the principal-axes signs), a map from the
        target samples to source vertices.
    """
    aligned = align_poses(source, target, samples_1, samples_2, poses, n_keep=n_keep, frames=frames, icp_iterations=icp_iterations)
    W, Nw = target.vertices[samples_2], target.vertex_normals[samples_2]
    for label, X, NX in aligned:
        yield Hypothesis(label, _nearest_aligned(W, Nw, X, NX))


def align_poses(
    source: TriangleMesh,
    target: TriangleMesh,
    samples_1: IndexArray,
    samples_2: IndexArray,
    poses: Sequence[tuple[str, FloatArray]],
    *,
    n_keep: int = 3,
    frames: tuple[str, ...] = RIGID_FRAMES,
    icp_iterations: int = 15,
) -> list[tuple[str, FloatArray, FloatArray]]:
    """The alignments behind :func:`pose_hypotheses`: the ``n_keep`` best, as posed source vertices placed on the target.

    Parameters are those of :func:`pose_hypotheses`.

    Returns
    -------
    list of (str, ndarray of shape (n_source, 3), ndarray of shape (n_source, 3))
        Label, the posed source's aligned vertices and their normals; best fitting first.
    """
    ranked = _rank_poses(source, target, samples_1, samples_2, poses, n_keep, frames, icp_iterations)
    return [(label, X, NX) for label, X, NX, _ in ranked]


def _rank_poses(
    source: TriangleMesh,
    target: TriangleMesh,
    samples_1: IndexArray,
    samples_2: IndexArray,
    poses: Sequence[tuple[str, FloatArray]],
    n_keep: int | None,
    frames: tuple[str, ...],
    icp_iterations: int = 15,
    n_threads: int = 1,
) -> list[tuple[str, FloatArray, FloatArray, int]]:
    """:func:`align_poses` with each alignment's index into ``poses``; every alignment for ``n_keep=None`` (on ``n_threads`` threads)."""
    bad = [f for f in frames if f not in RIGID_FRAMES]
    if bad:
        raise ValueError(f"pose frames must be among {RIGID_FRAMES}, got {bad}")
    posed = []
    for name, P in _checked_poses(source, poses):
        area = float(face_areas(P, source.faces).sum())
        if not area > 0:
            raise ValueError(f"pose {name!r}: the posed source has zero area")
        posed.append((f"pose {name}", P, float(np.sqrt(target.area / area))))
    return _align_posed(target, source.faces, samples_1, samples_2, posed, frames, n_keep, icp_iterations, n_threads)


def source_limbs(graph: DeformationGraph, *, min_nodes: int = 3) -> list[IndexArray]:
    """The source's limbs and their outer halves, as sets of deformation-graph nodes.

    Distances along the graph's links are measured from its centre (the node with the
    smallest eccentricity). The nodes farther than a radius ``r`` fall into connected
    parts; ``r`` is the smallest quantile of the distances (0.10, 0.125, ..., 0.90) at
    which the most parts of at least ``min_nodes`` nodes appear. For a figure these are
    the head, the arms and the legs, each from the shoulder or hip outwards. Each such
    limb's nodes beyond the median of its own distances (forearm and hand, lower leg
    and foot) are added as a further part.

    Parameters
    ----------
    graph : DeformationGraph
    min_nodes : int
        Smallest part.

    Returns
    -------
    list of ndarray
        Node indices of each part: the limbs first, then their outer halves (those with
        at least ``min_nodes`` nodes). Empty for a graph without such parts.
    """
    L, r = graph.links, graph.rest
    m = graph.n_nodes
    if len(L) == 0:
        return []
    w = np.linalg.norm(r[L[:, 0]] - r[L[:, 1]], axis=1)
    A = sparse.csr_matrix((np.r_[w, w], (np.r_[L[:, 0], L[:, 1]], np.r_[L[:, 1], L[:, 0]])), shape=(m, m))
    D = csgraph.shortest_path(A, directed=False)
    ecc = np.where(np.isfinite(D), D, -np.inf).max(axis=1)
    d = D[int(np.argmin(ecc))]
    fin = np.isfinite(d)
    limbs: list[IndexArray] = []
    for q in np.linspace(0.1, 0.9, 33):
        sel = np.flatnonzero(fin & (d > np.quantile(d[fin], q)))
        if len(sel) < min_nodes:
            break
        _, lab = csgraph.connected_components(A[sel][:, sel], directed=False)
        parts = [sel[lab == c] for c in range(lab.max() + 1) if np.sum(lab == c) >= min_nodes]
        if len(parts) > len(limbs):
            limbs = parts
    outer = [nodes[d[nodes] > np.median(d[nodes])] for nodes in limbs]
    return limbs + [nodes for nodes in outer if len(nodes) >= min_nodes]


FINE_SIGMA = (0.03, 0.01)
"""Robust scale (start, end; units of sqrt(source area)) of the final registration's
closest-point weights (``benchmarks/deform_seed_ceiling.py`` reuses it)."""
FEATURE_ALPHA = (0.05, 0.01)
"""Stiffness (start, end) of the last registration, the one with local features in its closest points."""
FEATURE_SIGMA = (0.01, 0.01)
"""Its robust scale (units of sqrt(source area))."""

_LIMB_REACH = 0.2
"""Target samples nearer than this (times the cap, 0.05 x sqrt(source area)) to the rest of
the source count as covered whatever a limb does, so they need no search (about a third
of them; the same turns as searching all on the training pairs tried; at 0.5, the
samples' spacing, the search is 3x faster but misses kid14's turn: 3.97 -> 4.13)."""


def _start_vertex(n_vertices: int, start: int, n_starts: int) -> int:
    """Where start ``start`` of ``n_starts`` begins its farthest-point sampling: vertex ``start x n / n_starts``."""
    return (int(start) * int(n_vertices)) // max(int(n_starts), 1)


def _thread_map(fn: Callable[[_T], _R], items: Sequence[_T], n_threads: int) -> list[_R]:
    """``[fn(x) for x in items]``, on up to ``n_threads`` threads (in order)."""
    n = min(n_threads, len(items))
    if n <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=n) as pool:
        return list(pool.map(fn, items))


def _sphere_directions(n: int) -> FloatArray:
    """``n`` evenly spread unit vectors (a Fibonacci sphere), shape (n, 3)."""
    k = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * k / n)
    theta = np.pi * (1.0 + np.sqrt(5.0)) * k
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def turn_limb(
    source: TriangleMesh,
    target: TriangleMesh,
    deformed: FloatArray,
    graph: DeformationGraph,
    parts: Sequence[IndexArray],
    samples: tuple[IndexArray, IndexArray],
    *,
    angles: tuple[float, ...] = (60.0, 120.0, 180.0),
    n_axes: int = 26,
    min_gain: float = 0.005,
    n_best: int = 1,
    n_threads: int = 1,
) -> list[tuple[FloatArray, tuple[int, float]]]:
    """The turns of limbs that best cover the target, each applied to a registered source.

    Each part (vertices of the given graph nodes' cells) is turned rigidly about its
    root (the centroid of its vertices on edges leaving it) by every rotation of
    ``angles`` about ``n_axes`` evenly spread axes. A turn is scored by how well the
    registered source then covers the target: the mean distance, capped at 0.05 x
    sqrt(source area), from each target sample to the nearest source sample with a
    compatible normal (target samples within a fifth of the cap of the rest of the
    source count as covered either way). Only coverage counts: a limb lying on another
    part (doubling it) costs nothing where it is, so the two-sided fit would keep it
    there; moved to where the target has a limb left uncovered, it lowers the coverage
    distance. Parts with fewer than 16 source samples (or leaving fewer than 16 for the
    rest) are skipped. Each part's best turn that lowers the coverage distance by
    ``min_gain`` is a candidate; the ``n_best`` best candidates (different parts) are
    returned, best first.

    Parameters
    ----------
    source, target : TriangleMesh
    deformed : ndarray, shape (n_source, 3)
        Registered source positions.
    graph : DeformationGraph
        The source graph the parts are node sets of.
    parts : sequence of ndarray
        Node indices of each part (:func:`source_limbs`).
    samples : pair of ndarray
        Source and target vertex samples.
    angles : tuple of float
        Degrees.
    n_axes : int
    min_gain : float
        Smallest relative drop of the coverage distance for a turn to count.
    n_best : int
        Most candidates returned.
    n_threads : int
        Threads searching the parts (the result does not depend on it).

    Returns
    -------
    list of (moved, (part, ratio))
        ``moved`` (ndarray, shape (n_source, 3)): a copy of ``deformed`` with one part
        turned; ``part``: its index in ``parts``; ``ratio``: the coverage distance
        after / before. Best (lowest ratio) first; empty if no turn lowers the coverage
        distance by ``min_gain``.
    """
    if not isinstance(n_best, (int, np.integer)) or n_best < 1:
        raise ValueError(f"turn_limb: n_best must be an integer >= 1, got {n_best!r}")
    s1, s2 = (np.asarray(x, dtype=np.int64) for x in samples)
    W, Nw = target.vertices[s2], target.vertex_normals[s2]
    cap = 0.05 * float(np.sqrt(source.area))
    cur = np.array(deformed, dtype=np.float64)
    N = vertex_normals(cur, source.faces)
    E = source.edges
    rotations = [axis_rotation(a, np.deg2rad(angle)) for a in _sphere_directions(n_axes) for angle in angles]

    def search(nodes: IndexArray) -> tuple[float, BoolArray, FloatArray, FloatArray] | None:
        """The best turn of one part: (coverage ratio, part's vertices, root, rotation)."""
        limb = np.isin(graph.labels, nodes)
        inner = limb[s1]
        if inner.sum() < 16 or (~inner).sum() < 16:
            return None
        leaving = limb[E[:, 0]] != limb[E[:, 1]]
        ring = np.unique(np.where(limb[E[leaving, 0]], E[leaving, 0], E[leaving, 1]))
        if len(ring) == 0:
            return None
        root = cur[ring].mean(axis=0)
        rest, moving = s1[~inner], s1[inner]
        _, d_rest = nearest_compatible(W, Nw, PointTree(cur[rest]), N[rest], min_cos=0.3)
        d_rest = np.minimum(d_rest, cap)
        # only the target samples the rest leaves uncovered can gain (_LIMB_REACH); turning
        # the limb by R about the root = turning those samples by R^T (one tree per part)
        far = np.flatnonzero(d_rest > _LIMB_REACH * cap)
        if len(far) == 0:
            return None
        tree = PointTree(cur[moving] - root)
        Wc, Nc, Nl = W[far] - root, Nw[far], N[moving]
        covered, d_far = float(d_rest[d_rest <= _LIMB_REACH * cap].sum()), d_rest[far]
        costs = []
        for R in [np.eye(3), *rotations]:
            _, d = nearest_compatible(Wc @ R, Nc @ R, tree, Nl, min_cos=0.3)
            costs.append(covered + float(np.minimum(d_far, d).sum()))
        if costs[0] <= 0:
            return None
        k = int(np.argmin(costs[1:]))
        return costs[1 + k] / costs[0], limb, root, rotations[k]

    found = _thread_map(search, parts, n_threads)
    ranked = sorted((f[0], i) for i, f in enumerate(found) if f is not None and f[0] < 1.0 - min_gain)
    out = []
    for ratio, i in ranked[:n_best]:
        _, limb, root, R = found[i]  # type: ignore[misc]
        moved = cur.copy()
        moved[limb] = (moved[limb] - root) @ R.T + root
        out.append((moved, (i, ratio)))
    return out


def swap_regions(
    source: TriangleMesh,
    target: TriangleMesh,
    deformed: Sequence[FloatArray],
    *,
    threshold: float = 0.05,
    min_vertices: int = 50,
    n_sweeps: int = 2,
    samples: tuple[IndexArray, IndexArray] | None = None,
) -> tuple[FloatArray, float, list[tuple[int, int]]]:
    """Assemble a deformed source from the best registration and regions of the others.

    Under heavy topological noise no single registration may be right everywhere: one
    gets the legs, another an arm. Starting from ``deformed[0]``, each registration in
    turn is compared with the current assembly; every connected region of the source
    (at least ``min_vertices`` vertices) where the two differ by more than
    ``threshold`` is copied in if that lowers the two-sided fit residual
    (:func:`topomatch.deform.register.fit_residual`). Because the regions end where the
    two agree to within ``threshold``, the seams are short jumps, which the final
    registration closes. Up to ``n_sweeps`` passes over the registrations, stopping
    after a pass without a change. No ground truth is involved.

    Parameters
    ----------
    source, target : TriangleMesh
    deformed : sequence of ndarray, each of shape (n_source, 3)
        Registered source positions, best first.
    threshold : float
        Difference that separates regions, in units of sqrt(source area).
    min_vertices : int
    n_sweeps : int
    samples : pair of ndarray, optional
        Source and target vertex samples for the residual (default: all vertices).

    Returns
    -------
    assembled : ndarray, shape (n_source, 3)
    residual : float
        Its fit residual.
    swaps : list of (int, int)
        For each accepted swap, the index into ``deformed`` and the number of vertices.
    """
    F = source.faces
    W, Nt = target.vertices, target.vertex_normals
    tree = PointTree(W)
    scale = float(np.sqrt(source.area))
    smp = samples if samples is not None else (None, None)
    E = source.edges
    n = source.n_vertices

    def residual(X: FloatArray) -> float:
        return fit_residual(X, F, W, Nt, tree, scale=scale, samples=smp)

    cur = np.array(deformed[0], dtype=np.float64)
    r_cur = residual(cur)
    swaps: list[tuple[int, int]] = []
    for _ in range(n_sweeps):
        changed = False
        for h, X in enumerate(deformed):
            diff = np.linalg.norm(cur - X, axis=1) > threshold * scale
            if diff.sum() < min_vertices:
                continue
            e = E[diff[E[:, 0]] & diff[E[:, 1]]]
            adj = sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
            _, comp = csgraph.connected_components(adj, directed=False)
            comp = np.where(diff, comp, -1)
            ids, counts = np.unique(comp[comp >= 0], return_counts=True)
            for c in ids[counts >= min_vertices]:
                region = comp == c
                cand = cur.copy()
                cand[region] = X[region]
                r = residual(cand)
                if r < r_cur - 1e-4:
                    logger.debug("region of %d vertices from registration %d: residual %.4f -> %.4f", region.sum(), h, r_cur, r)
                    cur, r_cur, changed = cand, r, True
                    swaps.append((h, int(region.sum())))
        if not changed:
            break
    return cur, r_cur, swaps


def local_wks_features(
    source: TriangleMesh, target: TriangleMesh, *, k: int = 100, n_energies: int = 50, first: int = 25, n_components: int = 5
) -> tuple[FloatArray, FloatArray]:
    """Local shape features of both shapes for the final registration's closest points.

    The wave kernel signature at its higher energies (``first`` onwards of
    ``n_energies``, from each shape's own ``k`` eigenpairs): the local half, which a
    shortcut far away changes little (the low energies are global and follow the
    target's topological noise). Each shape's columns are scaled to unit root mean
    square, then both are projected on the source's ``n_components`` principal
    directions and divided by the source's root mean square row norm, so a feature
    distance of 1 is the source's typical spread. The energies are strongly correlated:
    on kid00 the first three directions hold 99.99 % of the variance, so five lose
    nothing (the training pairs' maps with 5 and 10 agree to two decimals) and keep the
    joint searches in 8 dimensions instead of 13.

    Returns
    -------
    source_features : ndarray, shape (n_source, n_components)
    target_features : ndarray, shape (n_target, n_components)
    """
    if not 0 <= first < n_energies:
        raise ValueError(f"local_wks_features: need 0 <= first < n_energies, got first={first}, n_energies={n_energies}")

    def unit_columns(mesh: TriangleMesh) -> FloatArray:
        d = mesh_wks(mesh, n_energies=n_energies, k=k)[:, first:]
        return d / np.linalg.norm(d, axis=0, keepdims=True) * np.sqrt(len(d))

    ws, wt = unit_columns(source), unit_columns(target)
    mu = ws.mean(axis=0)
    _, _, vt = np.linalg.svd(ws - mu, full_matrices=False)
    P = vt[: min(n_components, vt.shape[0])].T
    zs = (ws - mu) @ P
    spread = float(np.sqrt(np.mean(np.sum(zs**2, axis=1))))
    return zs / spread, ((wt - mu) @ P) / spread


def _checked_poses(source: TriangleMesh, poses: Sequence[tuple[str, FloatArray]] | None) -> list[tuple[str, FloatArray]]:
    """``poses`` as a list of (name, float array of the source's vertex shape); a clear error otherwise."""
    out = []
    for item in poses or ():
        if not isinstance(item, (tuple, list)) or len(item) != 2:
            raise ValueError(f"poses must be (name, vertices) pairs, got {type(item).__name__}")
        name, P = item
        P = np.asarray(P, dtype=np.float64)
        if P.shape != source.vertices.shape or not np.isfinite(P).all():
            raise ValueError(
                f"pose {name!r} of {source.name or 'the source'}: vertices must be a finite array of shape {source.vertices.shape}, got {P.shape}"
            )
        out.append((str(name), P))
    return out


def map_from_deformed(target: TriangleMesh, deformed: FloatArray, source_faces: IndexArray) -> IndexArray:
    """Read a map off a registration: each target vertex takes the nearest deformed source vertex.

    Among the nearest deformed source vertices, the first whose normal is compatible
    with the target's (cosine >= 0.3) is taken.

    Parameters
    ----------
    target : TriangleMesh
    deformed : ndarray, shape (n_source, 3)
        Deformed source vertices.
    source_faces : ndarray, shape (f1, 3)

    Returns
    -------
    ndarray, shape (n_target,)
        Source vertex for each target vertex.
    """
    p2p, _ = nearest_compatible(target.vertices, target.vertex_normals, PointTree(deformed), vertex_normals(deformed, source_faces), min_cos=0.3)
    return p2p


WORKING_SIZES: tuple[int, ...] = (8000, 12000, 20000)
"""Copy sizes (vertices) at which a pair with a mesh above ``working_vertices`` is
registered, the best registration by its full-resolution score kept: on the noisy
high-res training shapes one copy size alone leaves a knife-edge choice (kid10 turned
front to back at 12,000, right at 8,000 and 20,000); see ``docs/flagship.md``, attempt #84."""

DEFAULT_SETTINGS: tuple[tuple[str, int, bool], ...] = (
    ("hks", 50, False),
    ("hks", 30, False),
    ("hks", 10, False),
)
"""Orientation-preserving HKS maps of three sizes: on the training pairs kid01-kid15 the
reversing and WKS variants were almost never the only good hypothesis, and with the rigid
hypotheses k = 20 never won (see docs/flagship.md)."""


class DeformMatcher(Matcher):
    """Spectral and rigid hypotheses verified and refined by non-rigid registration (the flagship).

    See the module docstring for the method. Lengths are relative to the square root
    of the source's area; all sampling is deterministic (farthest points from vertex
    0), so results are reproducible.

    Parameters
    ----------
    hypotheses : sequence of (descriptor, k, reversing)
        Functional-map settings tried in order (see :func:`spectral_hypotheses`).
    accept_residual : float
        Stop trying hypotheses once one verifies with a residual below this (units of
        sqrt(source area)); ``0`` tries them all.
    k_zoomout : int
        ZoomOut target size (eigenpairs per shape).
    n_samples : int
        Farthest-point samples per shape for ZoomOut and the verification.
    coarse_nodes : int
        Deformation graph size for the verification registrations (at most the number of
        source vertices, as is ``fine_nodes``).
    coarse_fit_iterations, coarse_icp_iterations : int
        Iterations of the two phases of each verification registration.
    coarse_alpha : tuple of float
        Stiffness at the start and end of the verification's closest-point iterations.
    fine_nodes : int
        Graph size of the final registration.
    fine_icp_iterations : int
        Closest-point iterations of the final registration (on the training pairs, mean
        geodesic error x100, Dijkstra, pooled: 12 -> 25 5.80 -> 5.63; 25 -> 40 3.65 ->
        3.54 (11 of 15 pairs better), about 0.3 s more per pair on two cores).
    fine_alpha : tuple of float
        Stiffness at the start and end of the final closest-point iterations. On 12
        training pairs (mean of the pairs' errors x100, Dijkstra) (0.5, 0.05) gave
        4.69, (0.2, 0.01) 4.51, (0.1, 0.005) 4.56, (0.5, 0.2) 4.88; see
        ``docs/flagship.md``, attempt #41.
    feature_icp_iterations : int
        Closest-point iterations of a last registration on the fine graph whose pairs
        are nearest in position *and* local shape features (:func:`local_wks_features`,
        weighted by ``feature_weight``; :func:`~topomatch.deform.register.feature_pairs`).
        The closest-point iterations let the surfaces slide along each other (a limb
        turned about its own axis, a torso turned about its height fits as well);
        features that tell places apart hold them. ``0`` skips it. On the training
        pairs (mean geodesic error x100, Dijkstra, pooled): none 3.54, 20 iterations
        2.94 (20 more iterations without features: 3.40; attempt #64), 40 **2.70**,
        60 2.66, 80 2.58 (attempts #66, #73); with the joint searches on a compiled
        tree (:class:`~topomatch.deform.kdtree.JointTree`, attempt #71) an iteration
        costs about 25 ms at 10K vertices, and 80 iterations about 1 s more per
        low-res pair than 40; ``docs/flagship.md``. 80 since session 37 (attempt #115: on
        today's pipeline, with the filling, training pairs 2.55 -> 2.37 and the 210
        noisy-noisy training pairs AUC 0.656 -> 0.658, at about 0.5 s more per pair); 40
        until then. ``template`` with training poses runs 60
        (:data:`~topomatch.matching.template.FEATURE_ITERATIONS`).
    feature_weight : float
        Length (units of sqrt(source area)) that a feature distance of 1 (the
        source's typical feature spread) counts as in those pairs at the first of
        those iterations, going linearly to 0 at the last (the positions have the
        last word). Training pairs: 0.03: 3.24, 0.045: 2.94, 0.06: 2.97, 0.09: 3.04;
        held at 0.03 throughout: 3.11.
    swap_threshold : float
        Before the final registration, regions where another verified registration
        differs from the best by more than this (units of sqrt(source area)) are
        swapped in when that lowers the fit residual (:func:`swap_regions`); ``0``
        disables it. On the training pairs: 8.38 -> 7.79 (mean geodesic error x100,
        Dijkstra; see ``docs/flagship.md``).
    swap_min_vertices : int
        Smallest region :func:`swap_regions` considers.
    continue_icp_iterations : int
        Closest-point iterations that continue the chosen (and assembled) coarse
        registration on the coarse graph, with stiffness going from ``continue_alpha[0]``
        to ``continue_alpha[1]``, before the fine registration; ``0`` skips them. The
        coarse graph can still move whole limbs, which the fine one cannot. On the
        training pairs: 7.79 -> 7.05.
    continue_alpha : tuple of float
    n_continue : int
        How many of the best-verified registrations are continued (the first one
        after the region swaps); the one with the lowest ``residual +
        distortion_weight * distortion`` after the continuation gets the fine
        registration. With ``continue_icp_iterations=0`` the best-verified (assembled)
        one is refined.
    limb_rounds : int
        Rounds of limb turns after the choice (:func:`turn_limb` on the parts from
        :func:`source_limbs`): each round takes the ``limb_candidates`` turns (of
        different parts) that best cover the target, continues the coarse registration
        from each (``continue_icp_iterations``) and keeps the best of them if
        ``residual + distortion_weight * distortion`` drops; the rounds stop at the
        first round nothing is kept. ``0`` (or ``continue_icp_iterations=0``) skips
        them. On the training pairs (one candidate): 4.47 -> 3.97 (mean geodesic error
        x100, Dijkstra, pooled; kid13 10.22 -> 7.35, kid14 13.64 -> 10.98, kid06 7.29 ->
        5.80, no pair worse); built-in pairs 2.16 -> 1.75 (see ``docs/flagship.md``).
    limb_min_gain : float
        Smallest relative drop of the coverage distance for a turn to be tried.
    limb_candidates : int
        Turns continued per round (the best-covering turn of each of that many parts;
        the continuations run on the thread pool, so two cost about one on two cores).
        On the training pairs: 1: 3.97, 2: 3.81 (kid06 5.80 -> 3.51, no pair worse), 3:
        3.78 (also kid15 18.65 -> 18.09, but 11.3 s instead of 9.8 s median per pair),
        5: 3.81.
    limb_judge : {"coarse", "fine"}
        What decides whether a round's best turn is kept. ``"coarse"``: the continued
        coarse registration's ``residual + distortion_weight x distortion`` must drop.
        ``"fine"``: each continued candidate and the current state are also registered
        on the fine graph (as in the final step) and that score must drop there. On the
        training pairs with 25 final iterations 3.65 -> 3.40 (kid13 6.91 -> 3.67); with
        the default 40 only 3.54 -> 3.52 (``docs/flagship.md``, attempts #43, #48); about
        1.3 s more per candidate and round on one thread. Not the default.
    limb_judge_iterations : int or None
        Closest-point iterations of the fine judge's registrations; ``None``: as the final
        registration (``fine_icp_iterations``), whose registration is then the judge's.
        Otherwise the final registration is computed afresh from the kept state. On the
        training pairs 25 with the default 40 final iterations: 3.54 -> 3.25 (kid13 6.67
        -> 2.96; attempt #49), about 3 s more per pair with limb rounds on two cores.
    distortion_weight : float
        Weight of the graph distortion (mean link stretch over mean link length) in
        that choice. A registration that fits the target only by bending the source
        out of shape (typically a body turned front to back) pays for it. On the
        training pairs (coarse study, exact geodesics, mean of pairs) the choice among
        the three continued went from 7.21 (best verified) to 5.72, the best of the
        three on every pair, for weights 0.005-0.03; on the built-in synthetic pairs
        from 12.22 to 2.80 for 0.025-0.05. In the matcher (Dijkstra, pooled): training
        pairs 7.05 -> 5.80, built-in 12.04 -> 2.74 (see ``docs/flagship.md``).
    rigid_frames : tuple of str
        Rigid hypotheses verified after the spectral ones (see
        :func:`rigid_hypotheses`): ``"as-given"`` and/or ``"principal-axes"``; ``()``
        for none. With them and the longer verification (25 closest-point iterations)
        the training pairs went from 16.70 to 8.38 (mean geodesic error x100,
        Dijkstra; see ``docs/flagship.md``).
    rigid_frames_with_poses : tuple of str or None
        The rigid hypotheses' frames in a registration that has the poses among its
        hypotheses (``poses`` of :meth:`register`; the poses' own alignments start from
        every frame of ``rigid_frames`` in any case). ``None``: ``rigid_frames``. There
        the posed alignments started from the principal axes cover what the rigid
        principal-axes hypotheses would: on the training pairs those were verified 120
        times in such registrations, in a top 3 three times and never the best
        (attempts #146, #148 in ``docs/flagship.md``).
    articulated : int
        How many *bent* rigid hypotheses are verified after the rigid ones (see
        :func:`articulated_hypotheses`): the source bent in two at the median of its
        Fiedler vector, one half turned by each of ``bend_angles`` both ways about the
        hinge, each bent copy aligned like ``"as-given"``; the ``articulated`` that fit
        the target best are kept; ``0`` for none. They reach poses no rigid hypothesis
        reaches (sitting, bending forward), where the spectral ones are fooled by the
        fusion. On the training pairs (mean geodesic error x100, Dijkstra, pooled),
        with the default angles: 5.63 -> 4.47 (keeping 4: 4.62); built-in pairs
        2.73 -> 2.16 (see ``docs/flagship.md``).
    bend_angles : tuple of float
        Bending angles in degrees; four bent copies per angle. Training pairs, keeping
        2: 90 alone 4.86, 60 alone 4.94, 120 alone 5.13, (60, 90) 4.63.
    matcher_hypotheses : sequence of str
        Names of other registered matchers (e.g. ``"em"``, ``"ge"``) whose maps are
        verified as further hypotheses, after the rigid ones. Only matchers that use
        no ground truth and need no training are accepted. A sparse map (``-1`` where
        unmatched) contributes its matched target vertices. Default: none (``("ge",
        "em")`` was the default before the rigid hypotheses; with them, adding these two
        made the choice worse on the training pairs, 9.65 -> 11.38 at the coarse level,
        see ``docs/flagship.md``).
    working_vertices : int or None
        A pair with a mesh of more vertices than this is registered through copies
        decimated to the sizes of ``working_sizes`` (quadric edge collapses,
        :func:`~topomatch.mesh.decimate.decimate`); each copy's displacements are
        carried to the source's own vertices by barycentric interpolation on the copy
        (:func:`~topomatch.mesh.decimate.surface_weights`), and the map is read off at
        full resolution. Every step of the method works on samples, graphs and local
        features that a 12K-vertex copy of a body resolves; on the 13 high-res training
        shapes (kid00 -> kidNN, 52K-62K vertices; Euclidean error x100 on kid00) full
        resolution gave 6.80 and one 12K copy 6.48 in session 25, at 8.7 s per match
        instead of 28.7 s (``docs/flagship.md``, attempt #80). ``None`` registers every
        mesh as it is. The low-res TOPKIDS shapes (at most 12,000 vertices) are never
        decimated.
    working_sizes : tuple of int
        The copy sizes of a pair above ``working_vertices`` (a mesh with at most that
        many vertices takes part as it is; sizes that give the same pair of meshes run
        once). The pair is registered at each, and the registration with the lowest
        full-resolution score is kept: the fit residual (:func:`~topomatch.deform.register.fit_residual`)
        of the carried-back source against the full target on ``n_samples``
        farthest-point samples of each, plus ``distortion_weight`` x the copy's
        distortion. On the noisy high-res shapes the choice among hypotheses is a
        knife edge that one copy size can lose (kid10 turned front to back at 12,000
        vertices, right at 8,000 and 20,000); on the 13 high-res training shapes
        (Euclidean error x100 on kid00) 8,000 alone gave 3.92, 12,000 6.94, 20,000 3.74,
        and the three judged at full resolution **3.44** (``docs/flagship.md``,
        attempt #84), at about the three registrations' summed time. ``(12000,)``
        registers as session 25 did. ``info["runs"]`` lists every registration's size,
        start and score, ``info["run"]`` the kept one.
    start_sizes : tuple of int or None
        The sizes of ``working_sizes`` at which the source *as it is* is registered
        (its ``n_starts`` starts, and ``pose_runs="extra"``'s run); the posed sources
        (``pose_sources``) are registered at every size. ``None`` (default): every
        size. ``template`` with training poses uses the smallest size: on the six
        high-res training shapes of its benchmark a posed run won every registration
        (session 30), and with ``(8000,)`` the six pairs' maps were identical at 41.5 s
        per pair instead of 73.4 s (median; attempt #91, ``docs/flagship.md``).
    n_starts : int
        Registrations per pair (and per working size) whose farthest-point sampling
        (samples and graph nodes) begins at vertex ``k n / n_starts`` of each mesh,
        ``k = 0 .. n_starts - 1``; the one with the lowest score on the full meshes
        (as for ``working_sizes``, on the samples of start 0) is kept. The choices
        among hypotheses and limb turns are knife edges on the folded poses, and a
        different sampling tips them either way (attempt #85, ``docs/flagship.md``);
        ``n_starts`` registrations cost ``n_starts`` times the time. ``1`` (default):
        one registration, from vertex 0.
    pose_keep : int
        When :meth:`register` is given the source in other known poses (``poses``):
        how many of their best rigid alignments to the target are verified as
        hypotheses (:func:`pose_hypotheses`, started from the ``rigid_frames``). With
        the training shapes' poses of ``kid00`` (left out when registering the pose's own
        shape) three took the training pairs kid00 -> kid01..kid15 from 2.70 to 2.37
        (one start, Dijkstra x100; attempt #86, ``docs/flagship.md``). ``0``: poses are
        ignored.
    pose_samples : int or None
        How many of the samples (the first of the farthest-point order, itself a
        farthest-point sample) the poses' rigid alignments are fitted and ranked on;
        ``None``: all ``n_samples``. The ranked alignments are placed on every vertex
        in any case. With ``template``'s ``quick`` settings on the training pairs 500
        gave 1.8245 against 1.7766 and no time saved (attempt #148, ``docs/flagship.md``).
    pose_sources : int
        When :meth:`register` is given the source in other known poses: how many of
        them (those of the best rigid alignments to the target, as ranked for
        :func:`pose_hypotheses`) are also registered *as the source*, beside the
        ``n_starts`` registrations of the source as it is: the posed source's vertices
        are the rest state of the deformation graph, so a folded forearm that the pose
        already folds is not straightened by the stiffness terms. Each such registration
        (sampling start 0, no pose hypotheses) is judged with the others by its
        full-mesh score; its distortion is measured against the pose, and its spectral
        hypotheses and feature stage read the source's own eigenbasis and local features
        (the posed copy is the same surface in another pose; its intrinsic data, computed on
        a surface bent by interpolation, are not the source's: ``template``'s training pairs
        1.797 -> 1.770 with the features, attempt #123, -> 1.690 with the hypotheses too,
        #124). A prior from the
        training poses only, like ``pose_keep``. With ``template``'s two starts and the
        training poses of ``kid00`` (leave-one-out), one took the training pairs kid00 ->
        kid01..kid15 from 2.30 to 2.04 (Dijkstra x100); two were no better than one in
        the study behind it (attempt #90, ``docs/flagship.md``). ``0`` (default): none.
    pose_runs : {"every", "extra"}
        Where the pose hypotheses go: ``"every"``, into every registration (each
        sampling start and working size); ``"extra"``, into one more registration per
        working size (from sampling start 0) beside the ``n_starts`` without them, the
        best full-mesh score of all kept. Training pairs (attempt #86): one start 2.37
        either way ("extra" at twice the time), five starts 2.49 ("every") and 2.40
        ("extra"), against 2.36 for five starts without poses.
    refine_runs : int or None
        When :meth:`register` makes several registrations (``n_starts``, working sizes,
        ``pose_sources``, ``pose_runs="extra"``): how many of them get steps 3-6 (swaps,
        continuation, limb turns, fine registration), which cost about half of each.
        Every registration is verified first; its best verified registration is scored
        on the full meshes like a finished one (fit residual plus ``distortion_weight``
        x distortion), and the ``refine_runs`` best by that score are refined, the best
        final score of those kept. ``None`` (default): all of them, as before. ``template``
        with training poses uses 2 of its 3 low-res registrations: on the training pairs
        14 of 15 maps were identical and the pooled error 2.0367 -> 2.0366 (Dijkstra x100;
        one refinement fewer per shape; attempt #97, ``docs/flagship.md``).
    n_threads : int or None
        Threads for the verification and the continued registrations (they release
        the GIL in their tree queries and array operations), for the poses' rigid
        alignments, and for the refinements of several registrations (``n_starts``,
        working sizes, posed sources), which then run side by side on one thread each
        (alone, one keeps about 1.3 of two cores busy); their verifications share one
        pool, so that the next registration's hypotheses are made while the previous
        ones are verified (attempt #100, ``docs/flagship.md``); ``None``: the CPU count, at
        most 4. The result does not depend on it. The verification ignores it when
        ``accept_residual > 0`` (the early exit needs them in order).
    background_eigenbasis : bool
        With two or more threads, compute the target's eigenbasis in a forked process
        (:meth:`TriangleMesh.eigenbasis_in_background`; the eigensolver holds the GIL and
        would stall the verification threads). Same result either way; ``False`` for
        environments where forking is unwelcome.
    fill_patches : bool
        Give the vertices of the map's small islands that are second copies of a region
        the rest of the map covers the image of the nearest vertex of the map's large
        pieces (:func:`~topomatch.maps.patches.fill_small_patches`, the repair
        ``template`` runs on its map to the template; ``info["filled"]`` counts the
        vertices). Training pairs kid00 -> kid01..kid15 (Euclidean x100 on kid00): 2.271
        -> 2.137 (kid14 6.19 -> 5.33, kid15 10.63 -> 10.31; kid03 1.83 -> 1.91 the one
        loss), attempt #113 in ``docs/flagship.md``. ``False``: the map as read off.
    orientation_weight : float
        When several registrations are refined, choose among them by the fit residual plus
        this weight times the share of the target's area that the run's map turns over on
        the source (:func:`~topomatch.maps.folded_fraction`: a limb laid on the wrong part
        folds the map there), instead of ``residual + distortion_weight x distortion``.
        ``0`` (default): by the score. With ``template``'s training poses, six refined
        registrations per shape and weight 0.1 took kid20 (test) from 19.98 to 5.50 but
        kid19 from 3.93 to 10.81 and kid23 from 0.96 to 3.83, on near-ties of the folded
        share (attempt #135, ``docs/flagship.md``).
    pose_challengers : int
        With known poses: how many more posed sources (the poses ranked next after the
        ``pose_sources`` ones) are registered and refined *only to challenge the choice*.
        The choice is made among the other runs as usual; when the chosen run's map turns
        over at least ``challenge_above`` of the target's area, the challengers are
        registered, and a refined run (challenger or not) whose map turns over at least
        ``challenge_margin`` less than the chosen run's replaces it. ``refine_runs``
        counts the other runs: the challengers are always refined. ``info["challenge"]``
        records the chosen run's folded share, whether the challengers were registered
        and a replacement. ``0`` (default): none. Attempts #136-#137 in
        ``docs/flagship.md``.
    challenge_margin : float
        The share of the target's area (in [0, 1]) by which a run's folded share must be
        lower than the chosen run's to replace it (``pose_challengers``). Default 0.01:
        the middle of the range [0.005, 0.015] over which ``template``'s training maps (the
        benchmark's leave-one-out and the harder leave-three-out of
        ``benchmarks/template_novel_poses.py --k 2``) are the same, kid15's at ``K = 2``
        replaced (19.30 -> 12.39); at 0.002 kid06 and kid13 also switch, to worse runs, and
        at 0.02 nothing does. Only with ``challenge_judge="folded"``.
    challenge_judge : {"folded", "score"}
        How the challengers challenge (``pose_challengers``). ``"folded"`` (default): a
        refined run whose map turns over at least ``challenge_margin`` less than the
        chosen run's replaces it (#136). ``"score"``: once the challengers are registered,
        the refined run with the lowest score (the choice's own criterion) is kept, among
        the challengers and the refined runs the choice was made from (#139).
    challenge_above : float
        The folded share (in [0, 1]) of the chosen run's map at and above which the
        challengers are registered (``pose_challengers``); below it, the choice stands and
        the registration costs what it costs without challengers. Default 0.06: just
        above the folded shares of ``template``'s chosen maps on the 15 training shapes
        with their own pose left out (0.018-0.055); with the two nearest training poses
        also left out (``K = 2``), only kid14 (0.063) and kid15 (0.104, the one map a
        challenger replaces) reach it. ``0``: always (attempt #136; #137 gates it).
    follow_top : int
        When :meth:`register` makes registrations from several sampling starts
        (``n_starts``): a registration from a later start verifies only the hypotheses
        (by label) that ranked among the ``follow_top`` best in the verification of
        start 0 at the same working size and with the same poses; the spectral settings
        and bent copies outside them are not computed. Its continuation, swaps and
        refinement are as before, on its own samples and graph. ``0`` (default): every
        start verifies every hypothesis. ``template`` uses 4 with training poses since
        session 51 (:data:`~topomatch.matching.template.FOLLOW_TOP`). Attempts #158 and
        #164 in ``docs/flagship.md``.
    follow_spectral : bool
        With ``follow_top``: a later start also verifies every spectral setting
        (``hypotheses``) on its own samples, beside the first start's best. ``False``
        (default): only the first start's best. Attempt #165 in ``docs/flagship.md``.
    follow_bent : bool
        With ``follow_top``: when the first start's best include a bent copy
        (``articulated``), a later start also verifies every bent copy it makes on its own
        samples (its ``articulated`` best fitting, which need not be the first start's).
        ``False`` (default): only the first start's best. Attempt #167 in
        ``docs/flagship.md``.
    features_after_choice : bool
        When several registrations are refined: compare them (the choice, the folded
        shares and the challengers' judgement) after the fine registration, and give only
        the kept one the final stage with local features (``feature_icp_iterations``),
        which then costs once per shape instead of once per refined run. ``False``
        (default): every refined run gets it and the comparison comes after it. ``template``
        with training poses, training pairs (leave-one-out, Dijkstra x100): 1.6901 ->
        1.7310 at 0.94 of the time per pair; kid06's near tie goes to the run that ends
        worse (attempts #144 and #151, ``docs/flagship.md``).
    race_iterations : int
        ``0`` (default): every hypothesis is verified through the whole schedule
        (``coarse_fit_iterations`` + ``coarse_icp_iterations``). Else a race: each
        hypothesis is registered through the fit and this many closest-point iterations,
        and only the ``race_keep`` best by their residual there go on through the rest of
        the schedule, exactly as one uninterrupted registration (``register``'s
        ``stop_after`` and ``resume``); the others keep their residual at the stop and come
        after them in the order. Not with ``accept_residual`` (the early exit verifies
        one hypothesis at a time). Attempts #143, #162 and #177-#178 in
        ``docs/flagship.md``: at 10 / 6 with ``template``'s settings, 14 of the 15
        training maps unchanged at 0.93 of the time per pair; not ``template``'s default.
    race_keep : int
        How many hypotheses of a registration go on after the race (at least
        ``n_continue``; with as many as the hypotheses, the race changes nothing).
    surface_vertices : int
        ``0`` (default): the coarse registrations (verification, continuation, limb turns)
        deform every source vertex in each closest-point iteration. Else they deform and
        search only the source's samples and its first ``surface_vertices`` farthest-point
        vertices from the same start (``register``'s ``surface``): the backward search
        pairs each target sample with the nearest of these, whose normals are the rest
        normals turned by the deformation. Attempt #180 in ``docs/flagship.md``.
    feature_gate : float
        ``0`` (default): every refined run gets the final stage with local features and the
        choice among them is made after it. Else each refined run stops after its fine
        registration; when the best fine-stage score leads the next by at least this share
        of it, only that run gets the feature stage and is the choice; otherwise every
        refined run gets it and the choice is made after it, as by default. The
        challengers' gate and judgement (``pose_challengers``) read the final maps: when
        the challengers are registered, every refined run gets its feature stage first.
        Not with ``features_after_choice`` (a gate that always passes, with the
        challengers judged on fine-stage maps) nor ``orientation_weight``. Attempts #179
        and #181 in ``docs/flagship.md``.
    """

    name = "deform"

    def __init__(
        self,
        *,
        hypotheses: tuple[tuple[str, int, bool], ...] = DEFAULT_SETTINGS,
        accept_residual: float = 0.0,
        k_zoomout: int = 100,
        n_samples: int = 1500,
        coarse_nodes: int = 150,
        coarse_fit_iterations: int = 6,
        coarse_icp_iterations: int = 25,
        coarse_alpha: tuple[float, float] = (1.0, 0.1),
        fine_nodes: int = 500,
        fine_icp_iterations: int = 40,
        fine_alpha: tuple[float, float] = (0.2, 0.01),
        feature_icp_iterations: int = 80,
        feature_weight: float = 0.045,
        swap_threshold: float = 0.05,
        swap_min_vertices: int = 50,
        continue_icp_iterations: int = 25,
        continue_alpha: tuple[float, float] = (0.3, 0.1),
        n_continue: int = 3,
        distortion_weight: float = 0.025,
        rigid_frames: tuple[str, ...] = RIGID_FRAMES,
        rigid_frames_with_poses: tuple[str, ...] | None = None,
        matcher_hypotheses: tuple[str, ...] = (),
        articulated: int = 3,
        bend_angles: tuple[float, ...] = (60.0, 90.0, 120.0),
        limb_rounds: int = 3,
        limb_min_gain: float = 0.005,
        limb_candidates: int = 2,
        limb_judge: str = "coarse",
        limb_judge_iterations: int | None = None,
        working_vertices: int | None = 12000,
        working_sizes: tuple[int, ...] = WORKING_SIZES,
        start_sizes: tuple[int, ...] | None = None,
        n_starts: int = 1,
        pose_keep: int = 3,
        pose_samples: int | None = None,
        pose_sources: int = 0,
        pose_runs: str = "every",
        refine_runs: int | None = None,
        n_threads: int | None = None,
        background_eigenbasis: bool = True,
        fill_patches: bool = True,
        orientation_weight: float = 0.0,
        pose_challengers: int = 0,
        challenge_margin: float = 0.01,
        challenge_above: float = 0.06,
        challenge_judge: str = "folded",
        features_after_choice: bool = False,
        follow_top: int = 0,
        follow_spectral: bool = False,
        follow_bent: bool = False,
        race_iterations: int = 0,
        race_keep: int = 6,
        surface_vertices: int = 0,
        feature_gate: float = 0.0,
    ) -> None:
        self.hypotheses = hypotheses
        self.accept_residual = accept_residual
        self.k_zoomout = k_zoomout
        self.n_samples = n_samples
        self.coarse_nodes = coarse_nodes
        self.coarse_fit_iterations = coarse_fit_iterations
        self.coarse_icp_iterations = coarse_icp_iterations
        self.coarse_alpha = coarse_alpha
        self.fine_nodes = fine_nodes
        self.fine_icp_iterations = fine_icp_iterations
        self.fine_alpha = fine_alpha
        self.feature_icp_iterations = feature_icp_iterations
        self.feature_weight = feature_weight
        self.swap_threshold = swap_threshold
        self.swap_min_vertices = swap_min_vertices
        self.continue_icp_iterations = continue_icp_iterations
        self.continue_alpha = continue_alpha
        self.n_continue = n_continue
        self.distortion_weight = distortion_weight
        self.rigid_frames = rigid_frames
        self.rigid_frames_with_poses = rigid_frames_with_poses
        self.matcher_hypotheses = matcher_hypotheses
        self.articulated = articulated
        self.bend_angles = bend_angles
        self.limb_rounds = limb_rounds
        self.limb_min_gain = limb_min_gain
        self.limb_candidates = limb_candidates
        self.limb_judge = limb_judge
        self.limb_judge_iterations = limb_judge_iterations
        self.working_vertices = working_vertices
        self.working_sizes = working_sizes
        self.start_sizes = start_sizes
        self.n_starts = n_starts
        self.pose_keep = pose_keep
        self.pose_samples = pose_samples
        self.pose_sources = pose_sources
        self.pose_runs = pose_runs
        self.refine_runs = refine_runs
        self.n_threads = n_threads
        self.background_eigenbasis = background_eigenbasis
        self.fill_patches = fill_patches
        self.orientation_weight = orientation_weight
        self.pose_challengers = pose_challengers
        self.challenge_margin = challenge_margin
        self.challenge_above = challenge_above
        self.challenge_judge = challenge_judge
        self.features_after_choice = features_after_choice
        self.follow_top = follow_top
        self.follow_spectral = follow_spectral
        self.follow_bent = follow_bent
        self.race_iterations = race_iterations
        self.race_keep = race_keep
        self.surface_vertices = surface_vertices
        self.feature_gate = feature_gate

    def _check(self) -> list[tuple[str, int, bool]]:
        for flag in ("background_eigenbasis", "fill_patches", "follow_spectral", "follow_bent"):
            if not isinstance(getattr(self, flag), (bool, np.bool_)):
                raise ValueError(f"deform: {flag} must be True or False, got {getattr(self, flag)!r}")
        settings = []
        for h in self.hypotheses:
            if len(h) != 3 or h[0] not in ("hks", "wks") or not isinstance(h[1], (int, np.integer)) or not 2 <= h[1] <= self.k_zoomout:
                raise ValueError(f"each hypothesis must be (descriptor in hks|wks, 2 <= k <= k_zoomout, reversing), got {h!r}")
            settings.append((str(h[0]), int(h[1]), bool(h[2])))
        if not settings:
            raise ValueError("hypotheses must not be empty")
        if self.n_threads is not None and (not isinstance(self.n_threads, (int, np.integer)) or self.n_threads < 1):
            raise ValueError(f"n_threads must be a positive integer or None, got {self.n_threads!r}")
        if not isinstance(self.swap_threshold, (int, float, np.integer, np.floating)) or not self.swap_threshold >= 0:
            raise ValueError(f"swap_threshold must be a number >= 0, got {self.swap_threshold!r}")
        if not isinstance(self.distortion_weight, (int, float, np.integer, np.floating)) or not self.distortion_weight >= 0:
            raise ValueError(f"distortion_weight must be a number >= 0, got {self.distortion_weight!r}")
        if isinstance(self.orientation_weight, bool) or not isinstance(self.orientation_weight, (int, float, np.integer, np.floating)) or not self.orientation_weight >= 0:
            raise ValueError(f"orientation_weight must be a number >= 0, got {self.orientation_weight!r}")
        if not isinstance(self.articulated, (int, np.integer)) or self.articulated < 0:
            raise ValueError(f"articulated must be an integer >= 0, got {self.articulated!r}")
        angles = self.bend_angles
        if self.articulated > 0 and (
            not isinstance(angles, (tuple, list)) or not angles
            or not all(isinstance(a, (int, float, np.integer, np.floating)) and 0 < a <= 180 for a in angles)
        ):
            raise ValueError(f"bend_angles must be a non-empty tuple of degrees in (0, 180], got {angles!r}")
        wv = self.working_vertices
        if wv is not None and (isinstance(wv, (bool, np.bool_)) or not isinstance(wv, (int, np.integer)) or wv < 1000):
            raise ValueError(f"working_vertices must be an integer >= 1000 or None, got {wv!r}")
        ws = self.working_sizes
        if (
            not isinstance(ws, (tuple, list)) or not ws
            or not all(isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_)) and x >= 1000 for x in ws)
        ):
            raise ValueError(f"working_sizes must be a non-empty tuple of integers >= 1000, got {ws!r}")
        ss = self.start_sizes
        if ss is not None and (not isinstance(ss, (tuple, list)) or not ss or not all(x in ws for x in ss)):
            raise ValueError(f"start_sizes must be None or a non-empty tuple of sizes among working_sizes {tuple(ws)}, got {ss!r}")
        if not isinstance(self.limb_rounds, (int, np.integer)) or self.limb_rounds < 0:
            raise ValueError(f"limb_rounds must be an integer >= 0, got {self.limb_rounds!r}")
        if not isinstance(self.limb_min_gain, (int, float, np.integer, np.floating)) or not 0 <= self.limb_min_gain < 1:
            raise ValueError(f"limb_min_gain must be a number in [0, 1), got {self.limb_min_gain!r}")
        if not isinstance(self.limb_candidates, (int, np.integer)) or self.limb_candidates < 1:
            raise ValueError(f"limb_candidates must be an integer >= 1, got {self.limb_candidates!r}")
        if self.limb_judge not in ("coarse", "fine"):
            raise ValueError(f"limb_judge must be 'coarse' or 'fine', got {self.limb_judge!r}")
        j = self.limb_judge_iterations
        if j is not None and (not isinstance(j, (int, np.integer)) or j < 1):
            raise ValueError(f"limb_judge_iterations must be a positive integer or None, got {j!r}")
        if not isinstance(self.feature_icp_iterations, (int, np.integer)) or self.feature_icp_iterations < 0:
            raise ValueError(f"feature_icp_iterations must be an integer >= 0, got {self.feature_icp_iterations!r}")
        w = self.feature_weight
        if not isinstance(w, (int, float, np.integer, np.floating)) or not (np.isfinite(w) and w >= 0):
            raise ValueError(f"feature_weight must be a finite number >= 0, got {w!r}")
        if not isinstance(self.continue_icp_iterations, (int, np.integer)) or self.continue_icp_iterations < 0:
            raise ValueError(f"continue_icp_iterations must be an integer >= 0, got {self.continue_icp_iterations!r}")
        if isinstance(self.pose_keep, (bool, np.bool_)) or not isinstance(self.pose_keep, (int, np.integer)) or self.pose_keep < 0:
            raise ValueError(f"pose_keep must be an integer >= 0, got {self.pose_keep!r}")
        ps = self.pose_sources
        if isinstance(ps, (bool, np.bool_)) or not isinstance(ps, (int, np.integer)) or ps < 0:
            raise ValueError(f"pose_sources must be an integer >= 0, got {ps!r}")
        pc = self.pose_challengers
        if isinstance(pc, (bool, np.bool_)) or not isinstance(pc, (int, np.integer)) or pc < 0:
            raise ValueError(f"pose_challengers must be an integer >= 0, got {pc!r}")
        for name in ("challenge_margin", "challenge_above"):  # shares of the target's area
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)) or not 0 <= v <= 1:
                raise ValueError(f"{name} must be a number in [0, 1], got {v!r}")
        if self.challenge_judge not in ("folded", "score"):
            raise ValueError(f"challenge_judge must be 'folded' or 'score', got {self.challenge_judge!r}")
        if not isinstance(self.features_after_choice, (bool, np.bool_)):
            raise ValueError(f"features_after_choice must be True or False, got {self.features_after_choice!r}")
        ft = self.follow_top
        if isinstance(ft, (bool, np.bool_)) or not isinstance(ft, (int, np.integer)) or ft < 0:
            raise ValueError(f"follow_top must be an integer >= 0, got {ft!r}")
        rr = self.refine_runs
        if rr is not None and (isinstance(rr, (bool, np.bool_)) or not isinstance(rr, (int, np.integer)) or rr < 1):
            raise ValueError(f"refine_runs must be a positive integer or None, got {rr!r}")
        ps = self.pose_samples
        if ps is not None and (isinstance(ps, bool) or not isinstance(ps, (int, np.integer)) or ps < 4):
            raise ValueError(f"pose_samples must be an integer >= 4 or None, got {ps!r}")
        if self.pose_runs not in ("every", "extra"):
            raise ValueError(f"pose_runs must be 'every' or 'extra', got {self.pose_runs!r}")
        for name in ("n_samples", "coarse_nodes", "fine_nodes", "n_continue", "k_zoomout", "swap_min_vertices", "n_starts"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        fg = self.feature_gate
        if isinstance(fg, (bool, np.bool_)) or not isinstance(fg, (int, float, np.integer, np.floating)) or not fg >= 0:
            raise ValueError(f"feature_gate must be a number >= 0, got {fg!r}")
        if fg > 0 and (self.features_after_choice or self.orientation_weight > 0):
            raise ValueError("feature_gate cannot be combined with features_after_choice or orientation_weight")
        sv = self.surface_vertices
        if isinstance(sv, (bool, np.bool_)) or not isinstance(sv, (int, np.integer)) or sv < 0:
            raise ValueError(f"surface_vertices must be an integer >= 0, got {sv!r}")
        ri, rk = self.race_iterations, self.race_keep
        if isinstance(ri, (bool, np.bool_)) or not isinstance(ri, (int, np.integer)) or not 0 <= ri < self.coarse_icp_iterations:
            raise ValueError(f"race_iterations must be an integer in [0, coarse_icp_iterations), got {ri!r}")
        if isinstance(rk, (bool, np.bool_)) or not isinstance(rk, (int, np.integer)) or rk < self.n_continue:
            raise ValueError(f"race_keep must be an integer >= n_continue ({self.n_continue}), got {rk!r}")
        if ri > 0 and self.accept_residual > 0:
            raise ValueError("race_iterations needs accept_residual = 0 (the early exit verifies one hypothesis at a time)")
        frame_sets = {"rigid_frames": self.rigid_frames}
        if self.rigid_frames_with_poses is not None:
            frame_sets["rigid_frames_with_poses"] = self.rigid_frames_with_poses
        for name, frames in frame_sets.items():
            if isinstance(frames, str) or not isinstance(frames, (tuple, list)):
                raise ValueError(f"{name} must be a tuple of frames among {RIGID_FRAMES}, got {frames!r}")
            bad = [f for f in frames if f not in RIGID_FRAMES]
            if bad:
                raise ValueError(f"{name} must be among {RIGID_FRAMES}, got {bad}")
        from topomatch.matching import MATCHERS

        for name in self.matcher_hypotheses:
            cls = MATCHERS.get(name)
            if cls is None or name == self.name:
                raise ValueError(f"matcher_hypotheses: unknown or invalid matcher {name!r}")
            if cls.uses_ground_truth or cls.requires_fit:
                raise ValueError(f"matcher_hypotheses: {name!r} uses ground truth or needs training; only axiomatic matchers are accepted")
        return settings

    def _matcher_hypotheses(self, source: TriangleMesh, target: TriangleMesh, samples_2: IndexArray) -> Iterator[Hypothesis]:
        from topomatch.matching import make_matcher

        for name in self.matcher_hypotheses:
            m = make_matcher(name)
            if "random_state" in m.get_params():
                m.set_params(random_state=0)
            p = np.asarray(m.match(source, target).p2p_21, dtype=np.int64)
            tv = samples_2 if np.mean(p[samples_2] >= 0) > 0.5 else np.flatnonzero(p >= 0)
            tv = tv[p[tv] >= 0]
            if len(tv) >= 4:
                yield Hypothesis(name, p[tv], tv)

    def _pose_hypotheses(
        self, source: TriangleMesh, target: TriangleMesh, s1: IndexArray, s2: IndexArray,
        poses: Sequence[tuple[str, FloatArray]], memo: dict[str, Any],
    ) -> Iterator[Hypothesis]:
        """:func:`pose_hypotheses`: the ``pose_keep`` best of :meth:`_ranked_poses` (made by an earlier start or on these samples)."""
        if not self._has_pose_hypotheses(poses):
            return
        W, Nw = target.vertices[s2], target.vertex_normals[s2]
        for label, X, NX, _ in self._ranked_poses(source, target, s1, s2, poses, memo)[: self.pose_keep]:
            yield Hypothesis(label, _nearest_aligned(W, Nw, X, NX))

    def _ranked_poses(
        self, source: TriangleMesh, target: TriangleMesh, s1: IndexArray, s2: IndexArray,
        poses: Sequence[tuple[str, FloatArray]], memo: dict[str, Any],
    ) -> list[tuple[str, FloatArray, FloatArray, int]]:
        """Every rigid alignment of the poses to the target, best first (:func:`align_poses` with pose indices).

        Aligned on the samples ``s1, s2`` of the first call for the pair (start 0's:
        :meth:`register` asks in start order) and kept in ``memo`` for the others.
        """
        if "ranked" not in memo:
            with one_blas_thread():
                n = len(s1) if self.pose_samples is None else min(int(self.pose_samples), len(s1), len(s2))
                memo["ranked"] = _rank_poses(source, target, s1[:n], s2[:n], poses, None, tuple(self.rigid_frames), n_threads=self._n_threads())
        return memo["ranked"]

    def _posed_sources(
        self, source: TriangleMesh, target: TriangleMesh, poses: Sequence[tuple[str, FloatArray]], memo: dict[str, Any], n: int
    ) -> list[int]:
        """The indices of the ``n`` poses whose best rigid alignments to the target fit best (``pose_sources``, then ``pose_challengers``).

        The ranking of the pose hypotheses (:meth:`_ranked_poses`, on start 0's samples).
        """
        ranked = self._ranked_poses(source, target, self._samples(source, 0), self._samples(target, 0), poses, memo)
        order: list[int] = []
        for *_, i in ranked:
            if i not in order:
                order.append(i)
        return order[:n]

    def _samples(self, mesh: TriangleMesh, start: int) -> IndexArray:
        """Start ``start``'s farthest-point samples of ``mesh`` (:func:`_start_vertex`): at most ``n_samples``."""
        first = _start_vertex(mesh.n_vertices, start, self.n_starts)
        n = min(self.n_samples, mesh.n_vertices)
        return _prepared(("samples", mesh.content_hash, n, first), lambda: farthest_point_sampling(n, points=mesh.vertices, first=first))

    def _surface(self, source: TriangleMesh, samples: IndexArray) -> IndexArray | None:
        """The coarse registrations' ``surface`` (``surface_vertices``) for the source samples ``samples`` of :meth:`_samples`, sorted; ``None`` when off.

        Made once per run by :meth:`_setup`, beside the samples it contains.
        """
        n = int(self.surface_vertices)
        if n <= 0:
            return None
        first = farthest_point_sampling(min(n, source.n_vertices), points=source.vertices, first=int(samples[0]))
        return np.union1d(first, samples)

    def _has_pose_hypotheses(self, poses: Sequence[tuple[str, FloatArray]]) -> bool:
        """Whether a registration given ``poses`` verifies pose hypotheses (:meth:`_pose_hypotheses`)."""
        return bool(poses) and self.pose_keep > 0

    def _rigid_frames(self, with_poses: bool) -> tuple[str, ...]:
        """The rigid hypotheses' frames: ``rigid_frames_with_poses`` in a registration with pose hypotheses, if set."""
        if with_poses and self.rigid_frames_with_poses is not None:
            return tuple(self.rigid_frames_with_poses)
        return tuple(self.rigid_frames)

    def _score(self, r: RegistrationResult) -> float:
        """The choice's and the limb judge's score: ``residual + distortion_weight x distortion``."""
        return float(r.residual + self.distortion_weight * r.distortion)

    def _n_threads(self) -> int:
        return self.n_threads if self.n_threads is not None else min(4, os.cpu_count() or 1)

    def _map(self, fn: Callable[[_T], RegistrationResult], items: Sequence[_T]) -> list[RegistrationResult]:
        """``[fn(x) for x in items]``, on ``n_threads`` threads (the CPU count, at most 4, by default)."""
        return _thread_map(fn, items, self._n_threads())

    def _setup(
        self, source: TriangleMesh, target: TriangleMesh, start: int = 0
    ) -> tuple[tuple[IndexArray, IndexArray], DeformationGraph, IndexArray | None, EigenbasisJob | None]:
        """Check the pair; farthest-point samples of both shapes, the coarse graph and the coarse registrations' surface subset (:meth:`_surface`), shared by every step.

        ``start`` (of ``n_starts``) says where the farthest-point sampling of the
        samples and of the graph's nodes begins (:func:`_start_vertex`).

        With two or more threads the target's eigenbasis starts in a forked process
        first (the eigensolver holds the GIL: computed here it would stall the
        verification threads); ``None`` otherwise.
        """
        for mesh in (source, target):
            if mesh.n_vertices <= self.k_zoomout:
                raise ValueError(
                    f"deform: mesh {mesh.name or '(unnamed)'} has {mesh.n_vertices} vertices; the spectral hypotheses need more "
                    f"than k_zoomout = {self.k_zoomout} (set k_zoomout and the hypotheses' k lower for such small meshes)"
                )
        target_basis = None
        if self.background_eigenbasis and self._n_threads() > 1 and self.accept_residual <= 0:
            target_basis = target.eigenbasis_in_background(self.k_zoomout)
        s1, s2 = self._samples(source, start), self._samples(target, start)
        graph = self._graph(source, self.coarse_nodes, start)
        return (s1, s2), graph, self._surface(source, s1), target_basis

    def verify_hypotheses(
        self, source: TriangleMesh, target: TriangleMesh, *, poses: Sequence[tuple[str, FloatArray]] = ()
    ) -> tuple[list[Hypothesis], list[RegistrationResult]]:
        """Steps 1-2: every hypothesis with its coarse registration (in the order tried).

        Stops after the first hypothesis whose residual is below ``accept_residual``.
        ``poses`` as for :meth:`register`.

        Returns
        -------
        hypotheses : list of Hypothesis
        results : list of RegistrationResult
            The coarse registration seeded by each hypothesis; ``residual`` is the
            selection criterion. With ``race_iterations``, the ones that did not go on
            after the race are the registrations stopped there (``resume_at`` set).
        """
        settings = self._check()
        poses = _checked_poses(source, poses)
        samples, graph, surface, target_basis = self._setup(source, target)
        hyps, results, resume = self._verify(source, target, settings, samples, graph, surface, target_basis, poses)
        if resume is not None:  # the race's best go on (here: the results are in hand)
            results = _raced(_Verified(source, target, 0, samples, graph, hyps, results, np.empty(0, np.int64), 0.0, surface=surface,
                                       resume=resume, keep=int(self.race_keep))).results
        return hyps, results

    def _verify(
        self,
        source: TriangleMesh,
        target: TriangleMesh,
        settings: list[tuple[str, int, bool]],
        samples: tuple[IndexArray, IndexArray],
        graph: DeformationGraph,
        surface: IndexArray | None = None,
        target_basis: EigenbasisJob | None = None,
        poses: Sequence[tuple[str, FloatArray]] = (),
        memo: dict[str, Any] | None = None,
        pool: ThreadPoolExecutor | None = None,
        intrinsic: TriangleMesh | None = None,
        only: frozenset[str] | None = None,
        deferred: list[Callable[[], None]] | None = None,
    ) -> tuple[list[Hypothesis], list[Any], Callable[[list[RegistrationResult]], list[Any]] | None]:
        """:meth:`verify_hypotheses` on samples, a coarse graph, its surface subset and a background job from :meth:`_setup`.

        With ``race_iterations`` the verifications stop there, and the third item
        continues those that go on (see :func:`_raced`); else it is ``None``.

        ``memo`` keeps the poses' alignments (:func:`align_poses`) and the shapes'
        spectral data (:func:`spectral_hypotheses`' ``cache``) for the next starts: the
        first call aligns the poses on its samples, later calls only read the map off.
        ``only``: verify only the hypotheses with these labels (``follow_top``), an entry
        ``"<prefix>*"`` standing for every label that begins with the prefix
        (``follow_bent``); the spectral settings and bent copies without one are not
        computed. ``None``: all.

        ``deferred`` (with a ``pool``): only the extrinsic hypotheses are made and
        submitted now; a step appended to ``deferred`` makes and submits the spectral
        and the matchers' ones, filling the returned lists in place (the same order as
        without it). The caller runs the steps before it reads the lists, so that the
        pool verifies the next runs' extrinsic hypotheses while this thread computes
        the spectral ones (each verification's result does not depend on when it runs).
        """
        s1, s2 = samples
        W = target.vertices
        Nt = target.vertex_normals
        coarse = RegistrationSchedule(
            n_nodes=graph.n_nodes,
            fit_iterations=self.coarse_fit_iterations,
            icp_iterations=self.coarse_icp_iterations,
            alpha_icp=tuple(self.coarse_alpha),
        )
        if self.articulated > 0 and intrinsic is None:
            # the bent copies split at the Fiedler vector: take it from the basis the
            # spectral hypotheses compute anyway (no separate two-eigenpair solve). A
            # posed copy's spectral hypotheses read ``intrinsic``'s basis: the copy itself
            # only needs its Fiedler vector, a two-eigenpair solve.
            source.eigenbasis(self.k_zoomout)
        # generators: nothing is computed before a hypothesis is asked for
        # (the maps are between vertex indices: ``intrinsic`` has the source's vertices, in order)
        if only is not None:
            settings = [x for x in settings if _followed(_spectral_label(*x), only)]
        spectral = (
            spectral_hypotheses(source if intrinsic is None else intrinsic, target, s1, s2, settings, k_zoomout=self.k_zoomout, cache=memo)
            if settings
            else iter(())
        )
        bent = self.articulated > 0 and (only is None or any(label.startswith(_BENT) for label in only))
        extrinsic = chain(
            rigid_hypotheses(source, target, s1, s2, self._rigid_frames(self._has_pose_hypotheses(poses))),
            articulated_hypotheses(source, target, s1, s2, n_keep=self.articulated, angles=tuple(self.bend_angles)) if bent else iter(()),
            self._pose_hypotheses(source, target, s1, s2, poses, {} if memo is None else memo),
        )
        others = self._matcher_hypotheses(source, target, s2)
        if only is not None:  # the rigid, bent and pose alignments are cheap beside a verification
            extrinsic = (h for h in extrinsic if _followed(h.label, only))
            others = (h for h in others if _followed(h.label, only))

        race = int(self.race_iterations) if self.race_iterations > 0 else None

        def verify(h: Hypothesis) -> RegistrationResult:
            tv = s2 if h.target is None else h.target
            pairs = DataPairs(h.p2p, W[tv], Nt[tv], np.ones(len(tv)))
            r = register(source.vertices, source.faces, W, target.faces, pairs, coarse, graph=graph, samples=(s1, s2), stop_after=race, surface=surface)
            logger.debug("%s: residual %.4f distortion %.3f%s", h.label, r.residual, r.distortion, "" if race is None else f" after {race}")
            return r

        def go_on(r: RegistrationResult) -> RegistrationResult:
            return register(source.vertices, source.faces, W, target.faces, None, coarse, graph=graph, samples=(s1, s2), resume=r, surface=surface)

        def go_on_here(rs: list[RegistrationResult]) -> list[RegistrationResult]:
            with one_blas_thread():
                return self._map(go_on, rs)

        here = None if race is None else go_on_here

        if self.accept_residual > 0:
            hyps, results = [], []
            for h in chain(spectral, extrinsic, others):
                hyps.append(h)
                results.append(verify(h))
                if results[-1].residual < self.accept_residual:
                    break
            return hyps, results, None
        n = self._n_threads()
        if n <= 1 and pool is None:
            hyps = list(chain(spectral, extrinsic, others))
            with one_blas_thread():
                results = self._map(verify, hyps)
            return hyps, results, here
        # pipelined: the extrinsic hypotheses (cheap) are verified on the pool while this
        # thread computes the spectral ones (the costly part); the lists keep the order
        # spectral, extrinsic, others. The registrations' small dense solves lose to BLAS
        # threads competing with ours. With a ``pool`` from the caller the verifications
        # are only submitted (their futures returned): :meth:`register` makes the next
        # run's hypotheses while the pool verifies this one's; with ``deferred`` the
        # spectral ones wait until every run's extrinsic ones are submitted.
        own = pool is None  # a pool of this call's own: its results are waited for here
        hyps_out: list[Hypothesis] = []
        futures: list[Any] = []
        with one_blas_thread(), (ThreadPoolExecutor(max_workers=n) if own else nullcontext(pool)) as ex:
            later = [(h, ex.submit(verify, h)) for h in extrinsic]

            def rest() -> None:
                with one_blas_thread():
                    if target_basis is not None:  # waits without the GIL while the pool verifies
                        target_basis.result()
                    first = [(h, ex.submit(verify, h)) for h in spectral]
                    last = [(h, ex.submit(verify, h)) for h in others]
                done = first + later + last
                hyps_out[:] = [h for h, _ in done]
                futures[:] = [f for _, f in done]

            if deferred is None or own:
                rest()
            else:
                deferred.append(rest)
            if own:
                return hyps_out, [f.result() for f in futures], here
        go_on_pool = None if race is None else (lambda rs: [ex.submit(go_on, r) for r in rs])
        return hyps_out, futures, go_on_pool

    def _refine(
        self,
        source: TriangleMesh,
        target: TriangleMesh,
        hyps: list[Hypothesis],
        results: list[RegistrationResult],
        order: IndexArray,
        samples: tuple[IndexArray, IndexArray],
        graph: DeformationGraph,
        start: int = 0,
        intrinsic: TriangleMesh | None = None,
        features: bool = True,
        surface: IndexArray | None = None,
    ) -> tuple[int, RegistrationResult, list[tuple[str, int]], dict[str, tuple[float, float]], list[dict]]:
        """Steps 3-6: swaps, continuation and choice, limb turns, fine registration (the last with the local features of ``intrinsic``, default ``source``; ``features=False`` stops before it)."""
        W = target.vertices
        fine_graph = self._fine_graph(source, start)
        fine = RegistrationSchedule(
            n_nodes=fine_graph.n_nodes, fit_iterations=0, icp_iterations=self.fine_icp_iterations, alpha_icp=tuple(self.fine_alpha),
            sigma_icp=FINE_SIGMA,
        )
        starts: dict[int, GraphDeformation | FloatArray] = {int(i): results[i].deformation for i in order[: self.n_continue]}
        swaps: list[tuple[str, int]] = []
        if self.swap_threshold > 0 and len(results) > 1:
            assembled, _, sw = swap_regions(
                source, target, [results[i].deformed for i in order],
                threshold=self.swap_threshold, min_vertices=self.swap_min_vertices, samples=samples,
            )
            starts[int(order[0])] = assembled
            swaps = [(hyps[order[h]].label, nv) for h, nv in sw]
        i_best = int(order[0])
        continued: dict[str, tuple[float, float]] = {}
        if self.continue_icp_iterations > 0:
            cont = RegistrationSchedule(
                n_nodes=graph.n_nodes, fit_iterations=0, icp_iterations=self.continue_icp_iterations,
                alpha_icp=tuple(self.continue_alpha),
            )

            def go(i: int) -> RegistrationResult:
                return register(source.vertices, source.faces, W, target.faces, None, cont, graph=graph, start=starts[i], samples=samples, surface=surface)

            ids = list(starts)
            runs = self._map(go, ids)
            scores = [self._score(r) for r in runs]
            k_best = int(np.argmin(scores))
            i_best = ids[k_best]
            for i, r in zip(ids, runs):
                starts[i] = r.deformed
                continued[hyps[i].label] = (float(r.residual), float(r.distortion))
            limbs, r_best = self._turn_limbs(source, target, starts, i_best, scores[k_best], graph, samples, cont, (fine_graph, fine), surface)
        else:
            limbs, r_best = [], None
        if r_best is None:
            r_best = register(source.vertices, source.faces, W, target.faces, None, fine, graph=fine_graph, start=starts[i_best], n_threads=self._n_threads())
        if features and self._has_feature_stage():
            r_best = self._feature_stage(source, target, fine_graph, r_best.deformed, intrinsic)
        return i_best, r_best, swaps, continued, limbs

    def _fine_graph(self, source: TriangleMesh, start: int) -> DeformationGraph:
        """The deformation graph of the fine and feature stages (one per source and sampling start)."""
        return self._graph(source, self.fine_nodes, start)

    def _graph(self, source: TriangleMesh, n_nodes: int, start: int) -> DeformationGraph:
        """The deformation graph of ``n_nodes`` nodes of sampling start ``start`` (kept across pairs, :func:`_prepared`)."""
        n = min(n_nodes, source.n_vertices)
        first = _start_vertex(source.n_vertices, start, self.n_starts)
        return _prepared(("graph", source.content_hash, n, first), lambda: build_deformation_graph(source.vertices, source.faces, n, first=first))

    def _feature_stage(
        self, source: TriangleMesh, target: TriangleMesh, fine_graph: DeformationGraph, fine: FloatArray, intrinsic: TriangleMesh | None
    ) -> RegistrationResult:
        """Step 6's last stage (when :meth:`_has_feature_stage`): the fine registration's vertices ``fine`` registered on with the local features of ``intrinsic`` (default ``source``)."""
        features = local_wks_features(source if intrinsic is None else intrinsic, target, k=self.k_zoomout)
        last = RegistrationSchedule(
            n_nodes=fine_graph.n_nodes, fit_iterations=0, icp_iterations=self.feature_icp_iterations,
            alpha_icp=FEATURE_ALPHA, sigma_icp=FEATURE_SIGMA, feature_weight=(float(self.feature_weight), 0.0),
        )
        return register(source.vertices, source.faces, target.vertices, target.faces, None, last, graph=fine_graph, start=fine,
                        n_threads=self._n_threads(), features=features)

    def _has_feature_stage(self) -> bool:
        """Whether the registrations end with the feature stage (``feature_icp_iterations`` and ``feature_weight`` both above 0)."""
        return self.feature_icp_iterations > 0 and self.feature_weight > 0

    def _turn_limbs(
        self,
        source: TriangleMesh,
        target: TriangleMesh,
        starts: dict[int, GraphDeformation | FloatArray],
        i_best: int,
        score: float,
        graph: DeformationGraph,
        samples: tuple[IndexArray, IndexArray],
        cont: RegistrationSchedule,
        fine: tuple[DeformationGraph, RegistrationSchedule],
        surface: IndexArray | None = None,
    ) -> tuple[list[dict], RegistrationResult | None]:
        """Step 5: rounds of limb turns on the chosen continued registration (updates ``starts[i_best]``).

        Returns the rounds and, when ``limb_judge="fine"`` judged at least one round with
        the final registration's schedule, the fine registration of the final state (the
        final step's registration, already computed for the judging).
        """
        rounds: list[dict] = []
        fine_graph, fine_schedule = fine
        final_schedule = fine_schedule
        if self.limb_judge_iterations is not None:
            fine_schedule = dataclasses.replace(fine_schedule, icp_iterations=int(self.limb_judge_iterations))

        def fine_registration(X: FloatArray) -> RegistrationResult:
            return register(source.vertices, source.faces, target.vertices, target.faces, None, fine_schedule, graph=fine_graph, start=X)

        fine_now: RegistrationResult | None = None  # the fine registration of starts[i_best]
        parts = source_limbs(graph) if self.limb_rounds > 0 else []
        by_fine = self.limb_judge == "fine"

        def continued(X: FloatArray) -> tuple[RegistrationResult, RegistrationResult | None]:
            r = register(source.vertices, source.faces, target.vertices, target.faces, None, cont, graph=graph, start=X, samples=samples, surface=surface)
            return r, (fine_registration(r.deformed) if by_fine else None)

        for _ in range(self.limb_rounds):
            t0 = time.perf_counter()
            cands = turn_limb(
                source, target, np.asarray(starts[i_best]), graph, parts, samples,
                min_gain=self.limb_min_gain, n_best=self.limb_candidates, n_threads=self._n_threads(),
            )
            t_turn = time.perf_counter() - t0
            if not cands:
                break
            # one job per candidate (continued, then fine-registered when judged fine) and,
            # the first time, the fine registration of the current state, side by side
            jobs: list[Callable[[], Any]] = [partial(continued, c[0]) for c in cands]
            first = by_fine and fine_now is None
            if first:
                jobs.insert(0, partial(fine_registration, np.asarray(starts[i_best])))
            done = _thread_map(lambda job: job(), jobs, self._n_threads())
            if first:
                fine_now = done.pop(0)
            runs = [r for r, _ in done]
            scores = [self._score(r) for r in runs]
            judged: dict[str, float] = {}
            if by_fine and fine_now is not None:
                fine_runs = [f for _, f in done]
                fines = [self._score(f) for f in fine_runs]
                k = int(np.argmin(fines))  # the first of equals: the better coverage
                kept = bool(fines[k] < self._score(fine_now))
                judged = {"fine_score": self._score(fine_now), "fine_score_after": fines[k]}
                if kept:
                    fine_now = fine_runs[k]
            else:
                k = int(np.argmin(scores))  # the first of equals: the better coverage
                kept = bool(scores[k] < score)
            r, new, move = runs[k], scores[k], cands[k][1]
            rounds.append({"part": move[0], "coverage_ratio": move[1], "score": float(score), "score_after": float(new), "kept": kept,
                           "tried": [c[1][0] for c in cands], **judged,
                           "seconds": (t_turn, time.perf_counter() - t0 - t_turn)})
            logger.debug("limb part %d turned: coverage x%.3f, score %.5f -> %.5f (%s)", move[0], move[1], score, new, "kept" if kept else "dropped")
            if not kept:
                break
            starts[i_best], score = r.deformed, new
        return rounds, (fine_now if fine_schedule == final_schedule else None)

    def through_copies(self, source: TriangleMesh, target: TriangleMesh) -> bool:
        """Whether :meth:`register` registers the pair through working copies (a mesh above ``working_vertices``)."""
        wv = self.working_vertices
        return wv is not None and max(source.n_vertices, target.n_vertices) > wv

    def register(
        self, source: TriangleMesh, target: TriangleMesh, *, poses: Sequence[tuple[str, FloatArray]] = ()
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Deform the source onto the target (the registration behind :meth:`match`).

        When a mesh has more than ``working_vertices`` vertices, the pair is registered
        once per size of ``working_sizes``: each mesh above the size through a decimated
        copy (:func:`~topomatch.mesh.decimate.decimate`), whose displacements are carried
        to the source's own vertices by barycentric interpolation
        (:func:`~topomatch.mesh.decimate.surface_weights`); of these registrations the one
        with the lowest full-resolution score (the fit residual of the carried-back source
        against the full target, plus ``distortion_weight`` x its distortion) is returned.
        With ``n_starts > 1`` each size is registered from that many sampling starts,
        judged the same way.

        Parameters
        ----------
        source : TriangleMesh
            Shape 1, the shape that is deformed.
        target : TriangleMesh
            Shape 2.
        poses : sequence of (str, ndarray of shape (n_source, 3)), optional
            The source's vertices in other known poses (a name and the positions, the
            source's faces): the ``pose_keep`` best rigid alignments of them to the
            target join the hypotheses (:func:`pose_hypotheses`). Carried to a working
            copy by barycentric interpolation of their displacements.

        Returns
        -------
        deformed : ndarray, shape (n_source, 3)
            The source's vertices after the chosen registration.
        info : dict
            Diagnostics, as in ``Correspondence.info``.
        """
        settings = self._check()
        poses = _checked_poses(source, poses)
        large = self.through_copies(source, target)
        extra = bool(poses) and self.pose_keep > 0 and self.pose_runs == "extra"
        n_posed = int(self.pose_sources) if poses and self.rigid_frames else 0
        n_chal = int(self.pose_challengers) if poses and self.rigid_frames else 0
        if not large and self.n_starts == 1 and not extra and not n_posed + n_chal:
            return self._register(source, target, settings, poses=poses)
        scale = float(np.sqrt(source.area))
        samples = (self._samples(source, 0), self._samples(target, 0))
        tree = PointTree(target.vertices)
        done: set[tuple[int, int, int, bool, int | None]] = set()
        seconds = {"decimation": 0.0, "hypotheses_and_verification": 0.0, "refinement": 0.0}

        def carried(deformed: FloatArray, v: _Verified, back: FloatArray | None, home: FloatArray) -> tuple[FloatArray, float]:
            """A registration of ``v``'s copy as the source's own vertices, and its fit residual on the full meshes."""
            if back is not None:
                deformed = home + back @ (deformed - v.source.vertices)
            # judged on the full meshes and one set of samples: the runs' own residuals
            # (their copies, their samples) are not comparable
            return deformed, fit_residual(deformed, source.faces, target.vertices, target.vertex_normals, tree, scale=scale, samples=samples)

        # with threads, one pool verifies every run's hypotheses: this thread makes the next
        # run's samples and hypotheses while the pool verifies the previous ones' (the
        # results do not depend on it; each verification runs on one BLAS thread)
        shared = self._n_threads() > 1 and self.accept_residual <= 0
        sizes = [int(x) for x in self.working_sizes] if large else [None]
        prepared: dict[int | None, _Working] = {}

        def prepare(size: int | None) -> _Working:
            """The working copies of one size, the poses carried to them and the ranked posed sources (made once)."""
            if size not in prepared:
                t0 = time.perf_counter()
                src, tgt = (source, target) if size is None else (decimate(source, size), decimate(target, size))
                src_poses, memo = poses, {}  # the poses are aligned once per size (on start 0's samples)
                back = None if src is source else surface_weights(source.vertices, src)
                if poses and src is not source:
                    carry = surface_weights(src.vertices, source)
                    src_poses = [(name, src.vertices + carry @ (P - source.vertices)) for name, P in poses]
                seconds["decimation"] += time.perf_counter() - t0
                ranked = self._posed_sources(src, tgt, src_poses, memo, n_posed + n_chal) if n_posed + n_chal else []
                prepared[size] = _Working(src, tgt, src_poses, memo, back, ranked)
            return prepared[size]

        def submit(
            size: int | None, start: int, with_poses: bool, posed: int | None, challengers: bool, only: frozenset[str] | None,
            pool: ThreadPoolExecutor | None, deferred: list[Callable[[], None]] | None = None,
        ) -> tuple[_Verified, dict[str, Any], FloatArray | None, FloatArray]:
            """One run's hypotheses, submitted for verification (to ``pool``, if any), with its record (``deferred``: see :meth:`_verify`)."""
            src, tgt, src_poses, memo, back, _ = prepare(size)
            rest = src if posed is None else TriangleMesh(src_poses[posed][1], src.faces, name=f"{src.name} posed {src_poses[posed][0]}")
            # the posed copy is the source's surface in another pose: its intrinsic data
            # (spectral hypotheses, local features) are the source's own
            v = self._verified(rest, tgt, settings, start, src_poses if with_poses else (), memo, pool,
                               intrinsic=None if posed is None else src, only=only, deferred=deferred)
            home = source.vertices if posed is None else poses[posed][1]
            run = {"working_size": size, "start": start, "poses": bool(with_poses and src_poses),
                   "source_pose": None if posed is None else src_poses[posed][0],
                   "vertices": (src.n_vertices, tgt.n_vertices), "challenger": challengers}
            return v, run, back, home

        def verify(challengers: bool) -> list[tuple[_Verified, dict[str, Any], FloatArray | None, FloatArray]]:
            """Verify the contenders' runs (``challengers=False``) or the challengers' (``True``), in plan order."""
            t_verify, decimation = time.perf_counter(), seconds["decimation"]
            submitted: list[tuple[_Verified, dict[str, Any], FloatArray | None, FloatArray]] = []
            with (one_blas_thread() if shared else nullcontext()), (ThreadPoolExecutor(max_workers=self._n_threads()) if shared else nullcontext()) as pool:
                for size in sizes:
                    src, tgt, _, _, _, ranked = prepare(size)
                    # (start, with the poses, posed source): "extra" registers the poses apart,
                    # from start 0; each posed source (an index into poses) is registered from start 0
                    if challengers:  # the next-ranked poses: registered only to challenge the choice
                        plan: list[tuple[int, bool, int | None]] = [(0, False, i) for i in ranked[n_posed:]]
                    else:
                        plain = size is None or self.start_sizes is None or size in self.start_sizes
                        plan = [(k, not extra, None) for k in range(int(self.n_starts))] if plain else []
                        plan += [(0, True, None)] if extra and plain else []
                        plan += [(0, False, i) for i in ranked[:n_posed]]
                    # follow_top: a later start's run waits for start 0's (same poses) and verifies
                    # only its best hypotheses; it is made after the others, in its place in the plan
                    leaders: dict[bool, int] = {}  # start 0's run (with or without the poses): its index in submitted
                    followers: list[tuple[int, int, bool]] = []
                    # every run's extrinsic hypotheses (cheap) first, then their spectral ones: the pool
                    # verifies the next runs' while this thread makes the spectral (as many, the same results)
                    deferred: list[Callable[[], None]] | None = [] if pool is not None else None
                    for start, with_poses, posed in plan:
                        key = (src.n_vertices, tgt.n_vertices, start, with_poses, posed)
                        if key in done:  # e.g. both meshes within two sizes
                            continue
                        done.add(key)
                        if self.follow_top > 0 and posed is None and start > 0 and with_poses in leaders:
                            followers.append((len(submitted), start, with_poses))
                            submitted.append(None)  # type: ignore[arg-type]
                            continue
                        submitted.append(submit(size, start, with_poses, posed, challengers, None, pool, deferred))
                        if posed is None and start == 0:
                            leaders[with_poses] = len(submitted) - 1
                    for step in deferred or ():
                        step()
                    if pool is not None and followers and self.follow_spectral and settings:
                        # a follower verifies every spectral setting on its own samples: made here, while
                        # the pool verifies, and kept for it (its other hypotheses wait for its leader)
                        with one_blas_thread():
                            for _, start, _ in followers:
                                for _ in spectral_hypotheses(src, tgt, self._samples(src, start), self._samples(tgt, start), settings,
                                                             k_zoomout=self.k_zoomout, cache=prepared[size].memo):
                                    pass
                    for index, start, with_poses in followers:
                        k_lead = leaders[with_poses]
                        # collected once, kept in place (a race's best go on only once)
                        lead = _collected(submitted[k_lead][0])
                        submitted[k_lead] = (lead, *submitted[k_lead][1:])
                        only = frozenset(lead.hyps[i].label for i in lead.order[: int(self.follow_top)])
                        if self.follow_spectral:  # every spectral setting on the follower's own samples
                            only |= frozenset(_spectral_label(*x) for x in settings)
                        if self.follow_bent and any(label.startswith(_BENT) for label in only):
                            only |= {_BENT + "*"}  # every bent copy of the follower's own
                        submitted[index] = submit(size, start, with_poses, None, challengers, only, pool)
                        submitted[index][1]["followed"] = sorted(only)
                # every run's race first (its best go on in the pool), then every run's results
                submitted = [(_raced(v), run, back, home) for v, run, back, home in submitted]
                submitted = [(_collected(v), run, back, home) for v, run, back, home in submitted]
            out = []
            for v, run, back, home in submitted:
                best = v.results[v.order[0]]
                _, verified = carried(best.deformed, v, back, home)
                label = v.hyps[v.order[0]].label
                run.update({"verified_score": verified + self.distortion_weight * float(best.distortion),
                            "refined": False, "full_residual": None, "score": None,
                            "hypothesis": label if run["source_pose"] is None else f"posed {run['source_pose']}: {label}"})
                out.append((v, run, back, home))
            # the time spent here (the poses' ranking included), less the decimation prepare made meanwhile
            seconds["hypotheses_and_verification"] += time.perf_counter() - t_verify - (seconds["decimation"] - decimation)
            return out

        finished: dict[int, tuple[float, FloatArray, dict[str, Any]]] = {}
        # features_after_choice: the runs are refined up to the fine registration and compared
        # there; their vertices on the working copies wait here for the kept run's feature stage
        after = self.features_after_choice and self._has_feature_stage()
        # feature_gate: the same, but every refined run gets the feature stage unless the
        # fine-stage leader leads clearly (and before the challengers are judged)
        gated = self.feature_gate > 0 and self._has_feature_stage()
        before_features: dict[int, FloatArray] = {}

        def refine(ks: list[int], features: bool) -> None:
            """Refine the runs ``pending[k]`` into ``finished[k]`` (their score, the source's vertices, the info); ``features=False``: up to the fine registration."""
            t2 = time.perf_counter()
            if self._n_threads() > 1 and len(ks) > 1:
                # side by side, one thread each (a refinement's result does not depend on its threads;
                # alone, it keeps about 1.3 of two cores busy)
                solo = copy.copy(self)
                solo.n_threads = 1
                with one_blas_thread():
                    refined = _thread_map(lambda k: solo._refined(pending[k][0], features=features), ks, self._n_threads())
            else:
                refined = [self._refined(pending[k][0], features=features) for k in ks]
            for k, (deformed, info) in zip(ks, refined):
                if not features:
                    before_features[k] = deformed
                v, run, back, home = pending[k]
                if run["source_pose"] is not None:
                    info["hypothesis"] = f"posed {run['source_pose']}: {info['hypothesis']}"
                deformed, residual = carried(deformed, v, back, home)
                run.update(refined=True, full_residual=residual, score=residual + self.distortion_weight * float(info["distortion"]),
                           hypothesis=info["hypothesis"])
                if run["working_size"] is not None:
                    info["working_vertices"] = run["vertices"]
                info["run"] = k
                finished[k] = (run["score"], deformed, info)
            seconds["refinement"] += time.perf_counter() - t2

        def add_features(ks: list[int]) -> None:
            """The feature stage for the refined runs ``ks`` that have not had it (``features_after_choice``, ``feature_gate``), side by side: ``finished`` updated."""
            ks = [k for k in ks if k in before_features]
            if not ks:
                return
            t3 = time.perf_counter()

            def stage(solo: DeformMatcher, k: int) -> RegistrationResult:
                v = pending[k][0]
                # the run's fine graph built again (the same graph, about 45 ms once per shape) rather than
                # carried out of every refinement for the one run that is kept
                return solo._feature_stage(v.source, v.target, solo._fine_graph(v.source, v.start), before_features[k], v.intrinsic)

            with one_blas_thread():
                if self._n_threads() > 1 and len(ks) > 1:  # as refine: one thread each, the same results
                    solo = copy.copy(self)
                    solo.n_threads = 1
                    rs = _thread_map(partial(stage, solo), ks, self._n_threads())
                else:
                    rs = [stage(self, k) for k in ks]
            dt = (time.perf_counter() - t3) / len(ks)
            for k, r in zip(ks, rs):
                del before_features[k]
                v, run, back, home = pending[k]
                deformed, residual = carried(r.deformed, v, back, home)
                info = finished[k][2]
                run.update(fine_score=run["score"], full_residual=residual, score=residual + self.distortion_weight * float(r.distortion))
                info.update(residual=r.residual, distortion=r.distortion, features_after_choice=True)
                info["seconds"]["refinement"] += dt
                finished[k] = (run["score"], deformed, info)
            seconds["refinement"] += time.perf_counter() - t3

        folded: dict[int, float] = {}

        def fold(ks: list[int]) -> None:
            """The share of the target's area that each refined run's map turns over on the source."""
            for k in ks:
                if k not in folded:
                    p2p = map_from_deformed(target, finished[k][1], source.faces)
                    folded[k] = folded_fraction(p2p, source.vertices, source.vertex_normals, target.faces, target.face_areas)
                    pending[k][1]["folded"] = folded[k]

        # every registration is verified first (steps 1-2); the refine_runs best by their
        # best verified registration's full-mesh score are then refined (steps 3-6)
        pending: list[tuple[_Verified, dict[str, Any], FloatArray | None, FloatArray]] = verify(challengers=False)
        n_refine = len(pending) if self.refine_runs is None else min(int(self.refine_runs), len(pending))
        # in plan order: equal scores go to the smaller copy, the earlier start
        chosen = sorted(int(i) for i in np.argsort([run["verified_score"] for _, run, _, _ in pending], kind="stable")[:n_refine])
        refine(chosen, features=not (after or gated))
        gate: dict[str, Any] | None = None
        if gated:
            fine_keys = sorted(finished[k][0] for k in chosen)
            lead = chosen[int(np.argmin([finished[k][0] for k in chosen]))]
            margin = (fine_keys[1] - fine_keys[0]) / fine_keys[0] if len(chosen) > 1 and fine_keys[0] > 0 else float("inf")
            gate = {"margin": margin, "above": float(self.feature_gate), "passed": margin >= self.feature_gate}
            add_features([lead] if gate["passed"] else chosen)
        # the choice among the refined runs: by score, or by fit and folding (#135)
        if self.orientation_weight > 0 and len(chosen) > 1:
            fold(chosen)
            keys = [float(pending[k][1]["full_residual"]) + float(self.orientation_weight) * folded[k] for k in chosen]
            k_best = chosen[int(np.argmin(keys))]  # the first of equals
        elif gate is not None and gate["passed"]:  # the others' fine-stage scores do not compete
            k_best = lead
        else:
            k_best = chosen[int(np.argmin([finished[k][0] for k in chosen]))]  # the first of equals
        challenge: dict[str, Any] | None = None
        if n_chal and len(poses) > n_posed:
            # challengers (#136): registered only when the choice's map turns over at least
            # challenge_above of the target; then a refined run whose map turns over clearly
            # less (challenge_margin) replaces the choice, or (#139) the lowest score of all
            fold([k_best])
            challenge = {"folded": folded[k_best], "above": float(self.challenge_above), "registered": folded[k_best] >= self.challenge_above}
            if challenge["registered"] and gated:  # every refined run is judged on its final map
                add_features(chosen)
            fold(chosen)
            if challenge["registered"]:
                first = len(pending)
                pending += verify(challengers=True)
                refine(list(range(first, len(pending))), features=not after)
                fold(list(range(first, len(pending))))
            if self.challenge_judge == "score":
                k_new = min(finished, key=lambda k: (finished[k][0], k)) if challenge["registered"] else k_best
            else:
                k_least = min(folded, key=folded.__getitem__)  # the first of equals, in plan order
                k_new = k_least if folded[k_least] < folded[k_best] - float(self.challenge_margin) else k_best
            if k_new != k_best:
                challenge["replaced"] = {"chosen": k_best, "by": k_new}
                k_best = k_new
        if after or gated:  # (a gated run may have had it)
            add_features([k_best])
        _, deformed, info = finished[k_best]
        info["runs"] = [run for _, run, _, _ in pending]
        if challenge is not None:
            info["challenge"] = challenge
        if gate is not None:
            info["feature_gate"] = gate
        info["seconds"] = seconds
        return deformed, info

    def _register(
        self,
        source: TriangleMesh,
        target: TriangleMesh,
        settings: list[tuple[str, int, bool]],
        start: int = 0,
        poses: Sequence[tuple[str, FloatArray]] = (),
        memo: dict[str, Any] | None = None,
    ) -> tuple[FloatArray, dict[str, Any]]:
        """:meth:`register` on meshes of working size (``settings`` from :meth:`_check`), one start."""
        return self._refined(_collected(self._verified(source, target, settings, start, poses, memo)))

    def _verified(
        self,
        source: TriangleMesh,
        target: TriangleMesh,
        settings: list[tuple[str, int, bool]],
        start: int = 0,
        poses: Sequence[tuple[str, FloatArray]] = (),
        memo: dict[str, Any] | None = None,
        pool: ThreadPoolExecutor | None = None,
        intrinsic: TriangleMesh | None = None,
        only: frozenset[str] | None = None,
        deferred: list[Callable[[], None]] | None = None,
    ) -> _Verified:
        """Steps 1-2 of one registration: samples and coarse graph, hypotheses, verification (of the labels ``only``, if given).

        The results are ordered by :func:`_collected`, which also waits for them when they
        were only submitted to a ``pool``. ``deferred``: as for :meth:`_verify` (the
        hypotheses and results are filled in when its steps run).
        """
        t0 = time.perf_counter()
        samples, graph, surface, target_basis = self._setup(source, target, start)
        hyps, results, resume = self._verify(source, target, settings, samples, graph, surface, target_basis, poses, memo, pool, intrinsic, only, deferred)
        return _Verified(
            source, target, start, samples, graph, hyps, results, np.empty(0, np.int64), time.perf_counter() - t0, intrinsic,
            surface=surface, resume=resume, keep=int(self.race_keep),
        )

    def _refined(self, v: _Verified, features: bool = True) -> tuple[FloatArray, dict[str, Any]]:
        """Steps 3-6 of a verified registration (``features=False``: without the feature stage): the deformed source and the diagnostics."""
        t1 = time.perf_counter()
        with one_blas_thread():
            i_best, r_best, swaps, continued, limbs = self._refine(
                v.source, v.target, v.hyps, v.results, v.order, v.samples, v.graph, v.start, v.intrinsic, features, v.surface
            )
        info = {
            "hypothesis": v.hyps[i_best].label,
            "residuals": {h.label: float(r.residual) for h, r in zip(v.hyps, v.results)},
            "swaps": swaps,
            "continued": continued,
            "limbs": limbs,
            "residual": r_best.residual,
            "distortion": r_best.distortion,
            "seconds": {"hypotheses_and_verification": v.seconds, "refinement": time.perf_counter() - t1},
        }
        return r_best.deformed, info

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:  # noqa: D102
        deformed, info = self.register(source, target)
        t0 = time.perf_counter()
        p2p = map_from_deformed(target, deformed, source.faces)
        if self.fill_patches:
            p2p, info["filled"] = fill_small_patches(p2p, target.vertices, target.faces, source.vertices, source.faces)
        info["seconds"]["refinement"] += time.perf_counter() - t0
        return Correspondence(p2p, info=info)
