"""How much of ``template``'s training figure comes from near-duplicate training poses?

``template`` registers kid00 onto a shape with the training shapes' poses as hypotheses and
as a posed source, the shape's own pose left out. The training split has near-duplicate
poses (kid01-kid03, kid05/kid08, kid10/kid11, kid13-kid15), so leaving out only the shape's
own pose still leaves a pose close to the answer, which a test shape need not have. This
script fits ``template`` for each training target on the training split without the
target *and without its* ``K`` *nearest training poses*, then scores the 15 ``topkids25``
training pairs (kid00 -> kidNN) with the project's scorer. ``K = 0`` is the benchmark's
own leave-one-out and reproduces its training figure.

The distance between two poses is the root mean square distance between the template's
vertices in the two poses (from the ground truth, :func:`pose_from_ground_truth`) after
a rigid Procrustes alignment, over sqrt(area of kid00).

    python benchmarks/template_novel_poses.py --data DATA --k 0 2 [--json out.jsonl]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
from _common import emit_row, fit_shapes, load_topkids25

from topomatch.evaluation.scoring import score_maps
from topomatch.matching.template import TemplateMatcher


def pose_distance(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance between two posings of the same vertices after the best rotation and translation."""
    A, B = a - a.mean(axis=0), b - b.mean(axis=0)
    U, _, Vt = np.linalg.svd(B.T @ A)
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return float(np.sqrt(np.mean(np.sum((A @ R.T - B) ** 2, axis=1))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--k", type=int, nargs="+", default=[0, 2], help="nearest training poses left out besides the target's own")
    ap.add_argument("--geodesic", default="dijkstra", choices=["dijkstra", "heat", "exact"])
    ap.add_argument("--json", default=None, help="append one JSON line per pair and setting")
    args = ap.parse_args()
    coll, prot, ref, template = load_topkids25(ap, args)
    train = [n for n in fit_shapes(coll) if n != ref]
    if not train:
        ap.error(f"{args.data}: no training shapes with ground truth")
    scale = float(np.sqrt(template.area))
    poses = {name: P for name, _, P in TemplateMatcher().fit([coll[n] for n in fit_shapes(coll)]).poses_}
    for k in args.k:
        maps, info = {}, {}
        for name in train:
            near = sorted((pose_distance(poses[name], poses[o]) / scale, o) for o in poses if o != name)
            left_out = [o for _, o in near[:k]]
            matcher = TemplateMatcher().fit([coll[ref], *(coll[n] for n in train if n != name and n not in left_out)])
            t0 = time.perf_counter()
            c = matcher.match(template, coll[name].mesh)
            pair = f"{name}-{ref}"
            maps[(f"K={k}", pair)] = c.p2p_21
            info[pair] = {"seconds": time.perf_counter() - t0, "left_out": left_out,
                          "nearest_kept": near[k][1] if k < len(near) else None,
                          "nearest_kept_distance": near[k][0] if k < len(near) else None,
                          "hypothesis": c.info.get("hypotheses", {}).get("target")}
        tot = n = 0.0
        for s in score_maps(coll, prot, maps, geodesic=args.geodesic):
            emit_row({"k": k, "pair": s.pair, "error_x100": 100 * s.mean_error, "auc": s.auc, **info[s.pair]}, args.json)
            tot += s.sum_error
            n += s.n_scored
        emit_row({"k": k, "pairs": len(train), f"mean_error_x100_pooled_{args.geodesic}": 100 * tot / n,
                  "seconds_per_pair_median": statistics.median(v["seconds"] for v in info.values())}, args.json)


if __name__ == "__main__":
    main()
