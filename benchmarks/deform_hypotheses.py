"""Study of `deform`'s hypotheses on topkids25 pairs (kid00 -> kidNN): one line per hypothesis.

For every hypothesis the matcher would verify (the spectral settings and the matcher
hypotheses), run the coarse registration exactly as ``DeformMatcher.match`` does and
print its residual (the selection criterion), its graph distortion, and the mean
geodesic error x100 (heat) of the map read off the coarse-registered source. This is the
data behind the "coarse-level study" rows of ``docs/flagship.md``: the oracle choice
(best error per pair) against the residual's choice. Use it on training pairs only.

    python benchmarks/deform_hypotheses.py --data DATA kid01 kid02 kid03 --json out.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
from itertools import chain

import numpy as np
from scipy.spatial import cKDTree

from topomatch.datasets.topkids import load_topkids
from topomatch.deform.graph import build_deformation_graph
from topomatch.deform.register import DataPairs, RegistrationSchedule, nearest_compatible, register
from topomatch.evaluation.protocols import get_protocol
from topomatch.evaluation.scoring import score_maps
from topomatch.matching.deform import DeformMatcher, fast_fps, spectral_hypotheses
from topomatch.mesh.geometry import vertex_normals


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("targets", nargs="+", help="target shapes, e.g. kid01 kid02")
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--json", default=None, help="append one JSON line per hypothesis")
    args = ap.parse_args()
    if not args.data:
        ap.error("give --data or set TOPOMATCH_DATA")
    coll = load_topkids(args.data, "low")
    prot = get_protocol("topkids25")
    m = DeformMatcher()
    settings = m._check()
    ref = coll.reference
    src = coll[ref].mesh
    s1 = fast_fps(src.vertices, m.n_samples)
    coarse = RegistrationSchedule(
        n_nodes=m.coarse_nodes, fit_iterations=m.coarse_fit_iterations, icp_iterations=m.coarse_icp_iterations, alpha_icp=(1.0, 0.2)
    )
    graph = build_deformation_graph(src.vertices, src.faces, m.coarse_nodes)
    for t in args.targets:
        tgt = coll[t].mesh
        s2 = fast_fps(tgt.vertices, m.n_samples)
        W, Nt = tgt.vertices, tgt.vertex_normals
        maps, info = {}, {}
        hyps = chain(spectral_hypotheses(src, tgt, s1, s2, settings, k_zoomout=m.k_zoomout), m._matcher_hypotheses(src, tgt, s2))
        for h in hyps:
            tv = s2 if h.target is None else h.target
            r = register(src.vertices, src.faces, W, tgt.faces, DataPairs(h.p2p, W[tv], Nt[tv], np.ones(len(tv))), coarse, graph=graph, samples=(s1, s2))
            p2p, _ = nearest_compatible(W, Nt, cKDTree(r.deformed), vertex_normals(r.deformed, src.faces), min_cos=0.3)
            maps[(h.label, f"{t}-{ref}")] = p2p
            info[h.label] = {"residual": r.residual, "distortion": r.distortion}
        for s in score_maps(coll, prot, maps, geodesic="heat"):
            row = {"pair": s.pair, "hypothesis": s.method, "error_x100": 100 * s.mean_error, **info[s.method]}
            print(json.dumps(row), flush=True)
            if args.json:
                with open(args.json, "a") as fh:
                    fh.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
