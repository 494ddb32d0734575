"""Score maps under a protocol: per-pair rows, grouped by the shape distances live on.

All maps whose errors are measured on the same shape share one geodesic solver and
one batch of distance queries, so every distance field is computed once however many
methods and pairs use it.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field

import numpy as np

from topomatch import _cache
from topomatch.datasets.base import Shape, ShapeCollection, ground_truth_21
from topomatch.evaluation.metrics import (
    area_matched,
    auc,
    cumulative_curve,
    error_queries,
    reduce_min,
)
from topomatch.evaluation.protocols import PairSpec, Protocol
from topomatch.mesh.geodesics import GeodesicKind, make_geodesic_solver
from topomatch.typing import FloatArray, IndexArray

__all__ = ["PairScore", "exact_distance_matrix", "score_maps", "summarize"]

logger = logging.getLogger(__name__)

EXACT_MATRIX_MAX_VERTICES = 20_000


@dataclass
class PairScore:
    """Scores of one map on one pair under one geodesic kind.

    ``errors`` (shape (n_target,), ``nan`` = not scored) is kept for curves and is
    stored separately from the table row.
    """

    method: str
    pair: str
    target: str
    source: str
    geodesic: str
    n_target: int
    n_scored: int
    n_excluded: int
    n_unmatched: int
    mean_error: float
    sum_error: float
    median_error: float
    auc: float
    area_matched: float
    symmetric_used: bool
    auc_direct: float
    auc_mirrored: float
    curve: list[float] = field(default_factory=list)
    errors: FloatArray | None = field(default=None, repr=False)

    def row(self) -> dict:
        """The table row (everything but the per-vertex errors)."""
        d = asdict(self)
        d.pop("errors")
        return d


def exact_distance_matrix(shape: Shape, n_jobs: int = 1) -> FloatArray:
    """All-pairs exact geodesic distances, shape (n, n), float32; cached on disk.

    Only for meshes up to 20,000 vertices. Computed in ``n_jobs`` processes (the
    exact code runs one source at a time); kid00 at low res takes about half an hour on
    two cores, once.
    """
    mesh = shape.mesh
    n = mesh.n_vertices
    if n > EXACT_MATRIX_MAX_VERTICES:
        raise ValueError(f"{shape.name}: {n} vertices is too many for an all-pairs exact matrix")
    key = _cache.array_hash(mesh.vertices, mesh.faces, extra="exact-allpairs-f32")
    hit = _cache.load("geodesic", key)
    if hit is not None:
        return hit["d"]
    from joblib import Parallel, delayed

    chunks = np.array_split(np.arange(n), max(1, 8 * n_jobs))
    logger.info("computing exact all-pairs geodesics on %s (%d vertices, %d jobs)", shape.name, n, n_jobs)
    parts = Parallel(n_jobs=n_jobs)(delayed(_exact_rows)(mesh.vertices, mesh.faces, c) for c in chunks)
    d = np.concatenate(parts).astype(np.float32)
    d = np.minimum(d, d.T)  # MMP is symmetric up to rounding
    _cache.save("geodesic", key, {"d": d})
    return d


def _exact_rows(vertices: FloatArray, faces: IndexArray, rows: IndexArray) -> FloatArray:
    solver = make_geodesic_solver(vertices, faces, "exact")
    return solver.distances_from(rows).astype(np.float32)


def _score_group(
    source: Shape,
    jobs: list[tuple[str, PairSpec, Shape, IndexArray]],
    protocol: Protocol,
    kind: GeodesicKind,
    exact_matrix: FloatArray | None,
) -> list[PairScore]:
    """Score every (method, pair) whose errors live on ``source``."""
    t0 = time.perf_counter()
    norm = float(np.sqrt(source.mesh.area))
    plans = []
    all_gt, all_pred = [], []
    offset = 0
    for method, pair, target, p2p in jobs:
        variants = [("direct", ground_truth_21(target, source))]
        if protocol.symmetric and source.sym is not None:
            variants.append(("mirrored", ground_truth_21(target, source, mirrored=True)))
        for name, gt in variants:
            rows, g, p = error_queries(p2p, gt)
            plans.append((method, pair, target, p2p, name, gt, rows, offset, offset + len(rows)))
            all_gt.append(g)
            all_pred.append(p)
            offset += len(rows)
    gt_cat = np.concatenate(all_gt) if all_gt else np.zeros(0, dtype=np.int64)
    pred_cat = np.concatenate(all_pred) if all_pred else np.zeros(0, dtype=np.int64)
    if exact_matrix is not None:
        dist = exact_matrix[gt_cat, pred_cat].astype(np.float64)
    else:
        solver = source.mesh.geodesic_solver(kind)
        dist = solver.pair_distances(gt_cat, pred_cat)
    logger.info("%s: %d distance queries on %s in %.1f s", kind, len(dist), source.name, time.perf_counter() - t0)
    by_job: dict[tuple[str, str], dict[str, tuple]] = defaultdict(dict)
    for method, pair, target, p2p, name, gt, rows, a, b in plans:
        err = reduce_min(len(p2p), rows, dist[a:b]) / norm
        by_job[(method, pair.id)][name] = (pair, target, p2p, gt, err)
    out = []
    va = source.mesh.vertex_areas
    for (method, _), variants in by_job.items():
        scored = {}
        for name, (_, _, _, gt, err) in variants.items():
            curve = cumulative_curve(err, protocol.thresholds)
            scored[name] = (auc(curve, protocol.thresholds), curve, err, gt)
        use = "direct"
        if "mirrored" in scored and scored["mirrored"][0] > scored["direct"][0]:
            use = "mirrored"
        a_used, curve, err, gt = scored[use]
        pair, target, p2p = variants[use][0], variants[use][1], variants[use][2]
        has_gt = np.diff(gt.indptr) > 0
        unmatched = p2p < 0
        ok = ~np.isnan(err)
        e = err[ok]
        out.append(
            PairScore(
                method=method,
                pair=pair.id,
                target=pair.target,
                source=pair.source,
                geodesic=kind,
                n_target=len(p2p),
                n_scored=int(ok.sum()),
                n_excluded=int((~has_gt).sum()),
                n_unmatched=int((unmatched & has_gt).sum()),
                mean_error=float(e.mean()) if e.size else float("nan"),
                sum_error=float(e.sum()),
                median_error=float(np.median(e)) if e.size else float("nan"),
                auc=a_used,
                area_matched=area_matched(p2p, va),
                symmetric_used=use == "mirrored",
                auc_direct=scored["direct"][0],
                auc_mirrored=scored["mirrored"][0] if "mirrored" in scored else float("nan"),
                curve=[float(c) for c in curve],
                errors=err.astype(np.float32),
            )
        )
    return out


def score_maps(
    collection: ShapeCollection,
    protocol: Protocol,
    maps: Mapping[tuple[str, str], IndexArray],
    *,
    geodesic: GeodesicKind | None = None,
    n_jobs: int = 1,
) -> list[PairScore]:
    """Score maps under ``protocol``.

    Parameters
    ----------
    collection : ShapeCollection
    protocol : Protocol
    maps : mapping of (method, pair id) to ndarray
        ``p2p_21`` for each pair: shape (n_target,), a source vertex per target vertex,
        ``-1`` = unmatched. Pair ids are ``"<target>-<source>"``.
    geodesic : {"heat", "exact", "dijkstra"}, optional
        Defaults to the protocol's primary kind.
    n_jobs : int
        Processes across source shapes (and for the exact all-pairs matrix).

    Returns
    -------
    list of PairScore
        In the order of ``maps``.
    """
    kind = geodesic or protocol.geodesics[0]
    groups: dict[str, list[tuple[str, PairSpec, IndexArray]]] = defaultdict(list)
    for (method, pair_id), p2p in maps.items():
        pair = PairSpec.from_id(pair_id)
        groups[pair.source].append((method, pair, np.asarray(p2p, dtype=np.int64)))

    def run(source_name: str) -> list[PairScore]:
        source = collection[source_name]
        jobs = []
        for method, pair, p2p in groups[source_name]:
            target = collection[pair.target]
            if len(p2p) != target.n_vertices:
                raise ValueError(
                    f"{method} {pair.id}: the map has {len(p2p)} entries, {pair.target} has {target.n_vertices} vertices"
                )
            if p2p.size and (p2p.max() >= source.n_vertices or p2p.min() < -1):
                raise ValueError(f"{method} {pair.id}: map values outside [-1, {source.n_vertices - 1}]")
            jobs.append((method, pair, target, p2p))
        mat = None
        if kind == "exact" and source.n_vertices <= EXACT_MATRIX_MAX_VERTICES:
            mat = exact_distance_matrix(source, n_jobs=n_jobs)
        res = _score_group(source, jobs, protocol, kind, mat)
        source.mesh.drop_caches()
        return res

    names = list(groups)
    if n_jobs > 1 and len(names) > 1 and kind != "exact":
        from joblib import Parallel, delayed

        results = Parallel(n_jobs=n_jobs)(delayed(run)(s) for s in names)
    else:
        results = [run(s) for s in names]
    flat = {(r.method, r.pair): r for group in results for r in group}
    return [flat[k] for k in maps]


def summarize(scores: Iterable[PairScore], protocol: Protocol) -> dict:
    """Aggregate per-pair scores of one method and geodesic kind.

    Returns
    -------
    dict
        ``n_pairs``, ``mean_error`` (pooled over all scored vertices, times the
        protocol's ``error_scale``), ``auc_mean``, ``auc_std``, ``auc_best`` /
        ``auc_worst`` (with their pairs), ``area_matched`` (mean over pairs),
        ``excluded_fraction``, ``unmatched_fraction``, ``symmetric_fraction``, and the
        mean curve with its standard deviation.
    """
    s = list(scores)
    if not s:
        return {"n_pairs": 0}
    aucs = np.array([x.auc for x in s])
    n_scored = sum(x.n_scored for x in s)
    n_target = sum(x.n_target for x in s)
    curves = np.array([x.curve for x in s], dtype=np.float64)
    best = int(np.nanargmax(aucs)) if np.any(~np.isnan(aucs)) else 0
    worst = int(np.nanargmin(aucs)) if np.any(~np.isnan(aucs)) else 0
    return {
        "n_pairs": len(s),
        "mean_error": protocol.error_scale * sum(x.sum_error for x in s) / n_scored if n_scored else float("nan"),
        "mean_error_scale": protocol.error_scale,
        "auc_mean": float(np.nanmean(aucs)),
        "auc_std": float(np.nanstd(aucs)),
        "auc_best": float(aucs[best]),
        "auc_best_pair": s[best].pair,
        "auc_worst": float(aucs[worst]),
        "auc_worst_pair": s[worst].pair,
        "area_matched": float(np.mean([x.area_matched for x in s])),
        "excluded_fraction": sum(x.n_excluded for x in s) / n_target if n_target else float("nan"),
        "unmatched_fraction": sum(x.n_unmatched for x in s) / n_target if n_target else float("nan"),
        "symmetric_fraction": float(np.mean([x.symmetric_used for x in s])),
        "curve_mean": [float(c) for c in np.nanmean(curves, axis=0)],
        "curve_std": [float(c) for c in np.nanstd(curves, axis=0)],
        "thresholds": [float(t) for t in protocol.thresholds],
    }
