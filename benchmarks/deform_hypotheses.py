"""Study of `deform`'s hypotheses on topkids25 pairs (kid00 -> kidNN): one line per hypothesis.

For every hypothesis the matcher verifies (the spectral settings and the matcher
hypotheses), take its coarse registration from ``DeformMatcher.verify_hypotheses`` (the
matcher's own code) and print its residual (the selection criterion), its graph distortion, and the mean
geodesic error x100 (heat) of the map read off the coarse-registered source. This is the
data behind the "coarse-level study" rows of ``docs/flagship.md``: the oracle choice
(best error per pair) against the residual's choice. Use it on training pairs only.

    python benchmarks/deform_hypotheses.py --data DATA kid01 kid02 kid03 --json out.jsonl
    python benchmarks/deform_hypotheses.py --data DATA --param "matcher_hypotheses=('ge','em')" kid01

``--param KEY=VALUE`` sets a ``DeformMatcher`` parameter (parsed as ``topomatch bench
--param`` does: a Python literal, else a string), e.g. to compare verification schedules
or add hypotheses.
"""

from __future__ import annotations

import argparse
import os

from _common import emit_row

from topomatch.cli.main import _parse_params
from topomatch.datasets.topkids import load_topkids
from topomatch.evaluation.protocols import get_protocol
from topomatch.evaluation.scoring import score_maps
from topomatch.matching.deform import DeformMatcher, map_from_deformed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("targets", nargs="+", help="target shapes, e.g. kid01 kid02")
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--json", default=None, help="append one JSON line per hypothesis")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="DeformMatcher parameter (repeatable)")
    args = ap.parse_args()
    if not args.data:
        ap.error("give --data or set TOPOMATCH_DATA")
    coll = load_topkids(args.data, "low")
    prot = get_protocol("topkids25")
    m = DeformMatcher(**_parse_params(args.param, ["deform"]).get("deform", {}))
    ref = coll.reference
    src = coll[ref].mesh
    for t in args.targets:
        tgt = coll[t].mesh
        maps, info = {}, {}
        for h, r in zip(*m.verify_hypotheses(src, tgt)):
            maps[(h.label, f"{t}-{ref}")] = map_from_deformed(tgt, r.deformed, src.faces)
            info[h.label] = {"residual": r.residual, "distortion": r.distortion}
        for s in score_maps(coll, prot, maps, geodesic="heat"):
            emit_row({"pair": s.pair, "hypothesis": s.method, "error_x100": 100 * s.mean_error, **info[s.method]}, args.json)


if __name__ == "__main__":
    main()
