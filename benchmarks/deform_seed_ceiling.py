"""How good can ``deform``'s registration be? Register kid00 -> kidNN from ground-truth seeds.

``deform`` turns hypotheses (candidate correspondences) into registrations and picks
one. This script replaces the hypothesis by the *truth*: each target sample's
ground-truth source vertex seeds the same registration ``deform`` runs on its
hypotheses, so whatever error is left is the registration's own (its graph, its
closest-point iterations, the map read-off), not the hypotheses' or the judge's. Stages,
each scored with the project's scorer on the ``topkids25`` protocol:

- ``seed-fit``: the coarse graph fitted to the seeds only (no closest-point iteration);
- ``seed-coarse``: the verification registration (fit, then closest-point iterations);
- ``seed-fine``: ``seed-coarse`` registered again on the fine graph, as ``deform``'s
  last step does;
- ``deform`` (with ``--deform``): the matcher itself, for comparison.

Each stage also reports the judge's score (``residual + distortion_weight x
distortion``, the number ``deform`` chooses by) so a run shows whether the judge would
prefer the truth-seeded registration to the one ``deform`` found. Uses ground truth:
a diagnostic, never a matcher. Training pairs only.

    python benchmarks/deform_seed_ceiling.py --data DATA kid01 ... kid15 [--mu-point 1.0] [--deform] --json out.jsonl
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from _common import emit_row, load_topkids25, topkids_targets_parser
from threadpoolctl import threadpool_limits

from topomatch.deform.graph import build_deformation_graph
from topomatch.deform.register import DataPairs, RegistrationSchedule, register
from topomatch.evaluation.scoring import score_maps
from topomatch.matching.deform import FINE_SIGMA, DeformMatcher, map_from_deformed
from topomatch.mesh.sampling import farthest_point_sampling


def main() -> None:
    ap = topkids_targets_parser(__doc__.split("\n")[0], "append one JSON line per pair and stage")
    ap.add_argument("--mu-point", type=float, default=RegistrationSchedule.mu_point,
                    help="weight of the point-to-point term in the closest-point iterations (point-to-plane: 1)")
    ap.add_argument("--deform", action="store_true", help="also run the matcher itself")
    args = ap.parse_args()
    coll, prot, ref, src = load_topkids25(ap, args)
    m = DeformMatcher()
    V, F = src.vertices, src.faces
    s1 = farthest_point_sampling(min(m.n_samples, src.n_vertices), points=V, first=0)
    coarse_graph = build_deformation_graph(V, F, m.coarse_nodes)
    fine_graph = build_deformation_graph(V, F, m.fine_nodes)
    coarse = RegistrationSchedule(
        n_nodes=coarse_graph.n_nodes, fit_iterations=m.coarse_fit_iterations, icp_iterations=m.coarse_icp_iterations,
        alpha_icp=tuple(m.coarse_alpha), mu_point=args.mu_point,
    )
    fine = RegistrationSchedule(
        n_nodes=fine_graph.n_nodes, fit_iterations=0, icp_iterations=m.fine_icp_iterations, alpha_icp=tuple(m.fine_alpha),
        sigma_icp=FINE_SIGMA, mu_point=args.mu_point,
    )
    maps, info = {}, {}
    for t in args.targets:
        shape = coll[t]
        tgt = shape.mesh
        W, Nt = tgt.vertices, tgt.vertex_normals
        s2 = farthest_point_sampling(min(m.n_samples, tgt.n_vertices), points=W, first=0)
        truth = shape.ref_p2p
        tv = s2[truth[s2] >= 0]
        seeds = DataPairs(truth[tv], W[tv], Nt[tv], np.ones(len(tv)))
        pair = f"{t}-{ref}"
        with threadpool_limits(limits=1, user_api="blas"):
            t0 = time.perf_counter()
            fit = register(V, F, W, tgt.faces, seeds, replace(coarse, icp_iterations=0), graph=coarse_graph, samples=(s1, s2))
            r_coarse = register(V, F, W, tgt.faces, seeds, coarse, graph=coarse_graph, samples=(s1, s2))
            r_fine = register(V, F, W, tgt.faces, None, fine, graph=fine_graph, start=r_coarse.deformed)
            seconds = time.perf_counter() - t0
        for stage, r in (("seed-fit", fit), ("seed-coarse", r_coarse), ("seed-fine", r_fine)):
            maps[(stage, pair)] = map_from_deformed(tgt, r.deformed, F)
            info[(stage, pair)] = {"score": r.residual + m.distortion_weight * r.distortion, "residual": r.residual,
                                   "distortion": r.distortion, "seconds_three_stages": seconds}
        if args.deform:
            t0 = time.perf_counter()
            c = m.match(src, tgt)
            maps[("deform", pair)] = c.p2p_21
            info[("deform", pair)] = {"hypothesis": c.info["hypothesis"], "residual": c.info["residual"],
                                      "distortion": c.info["distortion"], "seconds": time.perf_counter() - t0}
    pooled: dict[str, list[float]] = {}
    for s in score_maps(coll, prot, maps, geodesic=args.geodesic):
        emit_row({"pair": s.pair, "stage": s.method, "error_x100": 100 * s.mean_error, **info[(s.method, s.pair)]}, args.json)
        acc = pooled.setdefault(s.method, [0.0, 0.0, 0.0])
        acc[0] += s.sum_error
        acc[1] += s.n_scored
        acc[2] += 100 * s.mean_error
    for stage, (tot, n, per_pair) in pooled.items():
        emit_row({"stage": stage, "pairs": len(args.targets), "mu_point": args.mu_point, "mean_error_x100_pooled": 100 * tot / n,
                  "mean_error_x100_mean_of_pairs": per_pair / len(args.targets)}, args.json)


if __name__ == "__main__":
    main()
