"""The registration's nearest-compatible-point queries: ``PointTree`` against scipy's ``cKDTree``.

One ``deform`` match is run with the queries recorded (every ``--every``-th call to
``nearest_compatible``: the registrations' forward and backward searches, the limb
turns' searches, the fit residuals, the map read-off); each recorded query is then
answered by both backends, building the tree and querying timed apart (median of
``--repeat``), and the answers are compared. Printed per kind of query (query count x
tree size) and in total: milliseconds per call and the ratio.

    python benchmarks/bench_kdtree.py [--data DATA] [--target kid13] [--every 10] [--repeat 5]

Without ``--data`` the built-in pair syn00 -> syn05 is used.
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from functools import partial

import numpy as np
from scipy.spatial import cKDTree

import topomatch.deform.register as reg
import topomatch.matching.deform as dm
from topomatch.deform.kdtree import PointTree
from topomatch.matching.deform import DeformMatcher
from topomatch.mesh import TriangleMesh


def _ckd_nearest_compatible(points, normals, tree, ref_normals, k=8, min_cos=0.0):
    """The generic two-query path (cKDTree k = 1, then k nearest for the disagreeing)."""
    return reg.nearest_compatible(points, normals, tree, ref_normals, k=k, min_cos=min_cos)


def _median(fn, repeat: int) -> float:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return float(np.median(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--target", default="kid13")
    ap.add_argument("--every", type=int, default=10, help="record every n-th query")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    if args.data:
        from topomatch.datasets.topkids import load_topkids

        coll = load_topkids(args.data, "low")
        pair = (coll["kid00"].mesh, coll[args.target].mesh)
    else:
        from topomatch.datasets.builtin import builtin_benchmark

        coll = builtin_benchmark()
        pair = (coll["syn00"].mesh, coll["syn05"].mesh)
    source, target = (TriangleMesh(m.vertices.copy(), m.faces.copy()) for m in pair)
    recorded, calls = [], [0]
    original = reg.nearest_compatible

    def recording(points, normals, tree, ref_normals, *, k=8, min_cos=0.0):
        calls[0] += 1
        if calls[0] % args.every == 0:
            recorded.append((np.array(points), np.array(normals), np.array(tree.data), np.array(ref_normals), k, min_cos))
        return original(points, normals, tree, ref_normals, k=k, min_cos=min_cos)

    reg.nearest_compatible = dm.nearest_compatible = recording
    try:
        DeformMatcher(n_threads=1).match(source, target)
    finally:
        reg.nearest_compatible = dm.nearest_compatible = original
    PointTree(np.zeros((4, 3))).query(np.zeros((1, 3)))  # compile before timing
    rows: dict[str, np.ndarray] = defaultdict(lambda: np.zeros(5))
    mismatched = total = 0
    for P, N, D, RN, k, mc in recorded:
        kind = f"{len(P)} x {len(D)}" if len(D) > 1000 else f"{len(P) // 250 * 250}+ x small (<= 1000)"
        ck, pt = cKDTree(D, balanced_tree=False, compact_nodes=False), PointTree(D)
        b_ck = _median(partial(cKDTree, D, balanced_tree=False, compact_nodes=False), args.repeat)
        b_pt = _median(partial(PointTree, D), args.repeat)
        run_ck = partial(_ckd_nearest_compatible, P, N, ck, RN, k=k, min_cos=mc)
        run_pt = partial(pt.nearest_compatible, P, N, RN, k=k, min_cos=mc)
        q_ck, q_pt = _median(run_ck, args.repeat), _median(run_pt, args.repeat)
        i_ck, i_pt = run_ck()[0], run_pt()[0]
        mismatched += int(np.sum(i_ck != i_pt))
        total += len(P)
        rows[kind] += (1, b_ck, b_pt, q_ck, q_pt)
    print(f"{len(recorded)} of {calls[0]} queries recorded; {os.cpu_count()} CPUs; medians of {args.repeat}")
    print(f"{'queries x tree':28s} {'calls':>5s}  build ms cKDTree / PointTree   query ms cKDTree / PointTree (ratio)")
    tot = np.zeros(5)
    for kind, r in sorted(rows.items()):
        n = r[0]
        tot += r
        print(f"{kind:28s} {int(n):5d}  {1e3 * r[1] / n:8.2f} / {1e3 * r[2] / n:6.2f}          {1e3 * r[3] / n:8.3f} / {1e3 * r[4] / n:6.3f} (x{r[3] / r[4]:.2f})")
    print(f"{'all (sums, s)':28s} {int(tot[0]):5d}  {tot[1]:8.3f} / {tot[2]:6.3f}          {tot[3]:8.3f} / {tot[4]:6.3f} (x{tot[3] / tot[4]:.2f}); "
          f"build + query x{(tot[1] + tot[3]) / (tot[2] + tot[4]):.2f}")
    print(f"answers differing: {mismatched} of {total}")


if __name__ == "__main__":
    main()
