"""The feature stage's joint searches: ``JointTree`` against scipy's ``cKDTree``.

The last stage of ``deform`` pairs points nearest in ``[position, w x feature]`` (the
local wave-kernel features of :func:`topomatch.matching.deform.local_wks_features`, five
directions, so 8 dimensions), in both directions, with the weight ``w`` falling from
0.045 x sqrt(area) to 0 over the iterations. For a few weights of that range this
script builds both trees on the target's joint points, queries them with the source's
(and the other way round), times building, refitting (``JointTree`` only: the tree of
the first weight moved to the current points, as the registration does between
rebuilds) and querying (median of ``--repeat``), checks that the answers agree, and
prints milliseconds and ratios.

    python benchmarks/bench_jointtree.py [--data DATA] [--resolution low|high] [--target kid06] [--repeat 5]

Without ``--data`` the built-in pair syn00 -> syn05 is used.
"""

from __future__ import annotations

import argparse
import os
import time
from functools import partial

import numpy as np
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from topomatch.deform.kdtree import JointTree
from topomatch.matching.deform import local_wks_features
from topomatch.mesh import TriangleMesh


def _median(fn, repeat: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times)), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--resolution", default="low", choices=("low", "high"))
    ap.add_argument("--target", default="kid06")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    if args.data:
        from topomatch.datasets.topkids import load_topkids

        coll = load_topkids(args.data, args.resolution)
        a, b = coll["kid00"].mesh, coll[args.target].mesh
        label = f"kid00 -> {args.target} ({args.resolution} res)"
    else:
        from topomatch.datasets.builtin import builtin_benchmark

        coll = builtin_benchmark()
        a, b = coll["syn00"].mesh, coll["syn05"].mesh
        label = "syn00 -> syn05 (built-in)"
    source, target = TriangleMesh(a.vertices, a.faces), TriangleMesh(b.vertices, b.faces)
    with threadpool_limits(limits=1, user_api="blas"):
        f1, f2 = local_wks_features(source, target, k=100)
    scale = float(np.sqrt(source.area))
    print(f"{label}: {source.n_vertices} x {target.n_vertices} points, {3 + f1.shape[1]} dimensions, one thread")
    print(f"{'weight':>8} {'':>10} {'cKDTree build':>14} {'JointTree build':>16} {'refit':>7} "
          f"{'cKDTree query':>14} {'JointTree query':>16} {'(refitted)':>11} {'query ratio':>12} {'same':>6}")
    JointTree(np.c_[target.vertices, f2]).refit(np.c_[target.vertices, f2]).query(np.c_[source.vertices, f1])  # load the compiled code
    first: dict[str, JointTree] = {}
    totals = {"ckd": 0.0, "jt": 0.0}
    for w in (0.045, 0.03, 0.015, 0.001):
        for direction, (ref, qry) in {
            "forward": (np.c_[target.vertices, w * scale * f2], np.c_[source.vertices, w * scale * f1]),
            "backward": (np.c_[source.vertices, w * scale * f1], np.c_[target.vertices, w * scale * f2]),
        }.items():
            cb, ck = _median(partial(cKDTree, ref), args.repeat)
            cq, (cd, ci) = _median(partial(ck.query, qry), args.repeat)
            jb, jt = _median(partial(JointTree, ref), args.repeat)
            jq, (jd, ji) = _median(partial(jt.query, qry), args.repeat)
            old = first.setdefault(direction, JointTree(ref))
            rf, _ = _median(partial(old.refit, ref), args.repeat)
            rq, (rd, ri) = _median(partial(old.query, qry), args.repeat)
            same = bool(np.array_equal(ci, ji) and np.array_equal(ci, ri) and np.allclose(cd, jd, rtol=1e-12) and np.allclose(cd, rd, rtol=1e-12))
            totals["ckd"] += cb + cq
            totals["jt"] += rf + rq
            print(f"{w:8.3f} {direction:>10} {cb:12.1f}ms {jb:14.1f}ms {rf:5.1f}ms {cq:12.1f}ms {jq:14.1f}ms {rq:9.1f}ms "
                  f"{cq / jq:11.2f}x {'yes' if same else 'NO':>6}")
    print(f"build + query per search, summed: cKDTree {totals['ckd']:.1f} ms, JointTree refitted {totals['jt']:.1f} ms "
          f"(x{totals['jt'] / totals['ckd']:.2f})")


if __name__ == "__main__":
    main()
