"""Does ``deform`` (or ``template``) depend on the shapes sharing a frame? Match kid00 -> kidNN as given and rotated.

TOPKIDS shapes come in one coordinate frame, so the matcher's "as-given" rigid
hypothesis starts close to the answer, and ``template``'s training poses are in that
frame too. A user's scans need not be. For each target this script runs the matcher
twice in the same process: on the target as distributed, and on the target moved by a
random rigid motion (rotation uniform over SO(3), seeded per shape, plus a shift of one
shape diameter). Geodesic errors are scored on the original shapes (a rigid motion
changes no geodesic), with the project's scorer. Training pairs only.

``--method template`` fits the template matcher on the training split *without the
target* for each target: the moved copy has other content than the shape, so the
matcher's own leave-one-out (by content) would not keep the target's ground-truth pose
away from it.

    python benchmarks/deform_rotation.py --data DATA kid01 kid02 ... kid15 --json out.jsonl
    python benchmarks/deform_rotation.py --data DATA --method template kid01 ... kid15
"""

from __future__ import annotations

import time

import numpy as np
from _common import emit_row, fit_shapes, load_topkids25, topkids_targets_parser
from scipy.spatial.transform import Rotation

from topomatch.evaluation.scoring import score_maps
from topomatch.matching import make_matcher
from topomatch.mesh import TriangleMesh


def main() -> None:
    ap = topkids_targets_parser(__doc__.split("\n")[0], "append one JSON line per pair and variant")
    ap.add_argument("--method", default="deform", choices=["deform", "template"])
    args = ap.parse_args()
    coll, prot, ref, src = load_topkids25(ap, args)
    m = make_matcher("deform")  # template: fitted per target below
    maps, info = {}, {}
    missing = [t for t in args.targets if t not in coll]
    if missing:
        ap.error(f"no shape {', '.join(missing)} in {args.data} (present: {', '.join(coll.names)})")
    for t in args.targets:
        # the rotation is seeded by the shape (its place in the collection, kid01 -> 0), not by
        # its place on the command line, so a target alone is moved as in the full run
        i = coll.names.index(t) - 1
        tgt = coll[t].mesh
        R = Rotation.random(random_state=np.random.default_rng(1000 + i)).as_matrix()
        V = tgt.vertices
        shift = np.ptp(V, axis=0).max() * np.array([1.0, 0.0, 0.0])
        moved = TriangleMesh(V @ R.T + shift, tgt.faces, name=f"{t}-moved")
        angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
        if args.method == "template":  # leave the target's own pose out, whatever its frame
            m = make_matcher("template").fit([coll[n] for n in fit_shapes(coll) if n != t])
        for variant, mesh in (("as-given", tgt), ("moved", moved)):
            t0 = time.perf_counter()
            c = m.match(src, mesh)
            maps[(variant, f"{t}-{ref}")] = c.p2p_21
            info[(variant, f"{t}-{ref}")] = {"seconds": time.perf_counter() - t0, "hypothesis": c.info.get("hypothesis", c.info.get("hypotheses", {}).get("target")), "angle_deg": angle}
    pooled: dict[str, list[float]] = {"as-given": [0.0, 0.0], "moved": [0.0, 0.0]}
    for s in score_maps(coll, prot, maps, geodesic=args.geodesic):
        emit_row({"method": args.method, "pair": s.pair, "variant": s.method, "error_x100": 100 * s.mean_error, "auc": s.auc, **info[(s.method, s.pair)]}, args.json)
        pooled[s.method][0] += s.sum_error
        pooled[s.method][1] += s.n_scored
    for variant, (tot, n) in pooled.items():
        emit_row({"method": args.method, "variant": variant, "pairs": len(args.targets), "mean_error_x100_pooled": 100 * tot / n}, args.json)


if __name__ == "__main__":
    main()
