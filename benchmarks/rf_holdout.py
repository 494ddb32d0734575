"""Hold-out tuning of ``rf`` on the training split only (no test shape is touched).

The forest is trained on kid01..kid10 and validated on the held-out training shapes
kid11..kid15: the 20 ordered pairs among them under the ``shrec16`` protocol (two
unseen shapes composed through the labels, as in the track; heat geodesics, symmetric
credit) and the 5 pairs kid00 -> kid11..kid15 under ``topkids25``. One line per
configuration: training seconds, validation AUC (mean / worst) and mean error.

Configurations are JSON objects of ``RandomForestMatcher`` parameters, e.g.

    python benchmarks/rf_holdout.py --data DATA '{}' '{"min_samples_leaf": 5}' '{"k": 50}'

Trained forests and eigenbases go to the disk cache (``TOPOMATCH_CACHE_DIR``, else the
default cache, as for the command line; ``--no-cache`` turns it off), so configurations
that differ only in matching parameters (``k_lowpass``, ``adjoint``) reuse the same
forest and a re-run retrains nothing; ``cached`` in the output says which.
"""

from __future__ import annotations

import argparse
import json
import os
import time

from _common import emit_row

from topomatch import _cache
from topomatch.datasets.topkids import load_topkids
from topomatch.evaluation.protocols import PairSpec, get_protocol
from topomatch.evaluation.scoring import score_maps, summarize
from topomatch.matching.rf import RandomForestMatcher

TRAIN = [f"kid{i:02d}" for i in range(1, 11)]
HELD = [f"kid{i:02d}" for i in range(11, 16)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("configs", nargs="+", help="JSON objects of rf parameters")
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--resolution", default="low", choices=["low", "high"])
    ap.add_argument("--n-jobs", type=int, default=2)
    ap.add_argument("--json", default=None, help="append one JSON line per configuration to this file")
    ap.add_argument("--no-cache", action="store_true", help="do not use the disk cache")
    args = ap.parse_args()
    if not args.data:
        ap.error("give --data or set TOPOMATCH_DATA")
    if not args.no_cache and _cache.cache_dir() is None:
        _cache.set_cache_dir(_cache.default_cache_dir())
    coll = load_topkids(args.data, args.resolution)
    ref = coll.reference
    train = [n for n in TRAIN if n in coll.names]
    held = [n for n in HELD if n in coll.names]
    shapes = [coll[ref]] + [coll[n] for n in train]
    pairs16 = [PairSpec(t, s) for s in held for t in held if s != t]
    pairs25 = [PairSpec(t, ref) for t in held]
    p16 = get_protocol("shrec16")
    p25 = get_protocol("topkids25")
    print(f"train {train[0]}..{train[-1]} ({len(train)}), validate {held[0]}..{held[-1]}: "
          f"{len(pairs16)} shrec16 pairs, {len(pairs25)} topkids25 pairs", flush=True)
    for text in args.configs:
        params = json.loads(text)
        m = RandomForestMatcher(training_shapes=train, n_jobs=args.n_jobs, random_state=0, **params)
        t0 = time.perf_counter()
        m.fit(shapes)
        fit_s = time.perf_counter() - t0
        maps16, maps25 = {}, {}
        t1 = time.perf_counter()
        for p in pairs16:
            maps16[("rf", p.id)] = m.match(coll[p.source].mesh, coll[p.target].mesh).p2p_21
        for p in pairs25:
            maps25[("rf", p.id)] = m.match(coll[p.source].mesh, coll[p.target].mesh).p2p_21
        match_s = (time.perf_counter() - t1) / (len(pairs16) + len(pairs25))
        s16 = summarize(score_maps(coll, p16, maps16), p16)
        s25 = summarize(score_maps(coll, p25, maps25, geodesic="heat"), p25)
        row = {
            "params": params,
            "fit_s": round(fit_s, 1),
            "cached": bool(getattr(m, "from_cache_", False)),
            "match_s": round(match_s, 2),
            "shrec16_auc": round(s16["auc_mean"], 4),
            "shrec16_worst": round(s16["auc_worst"], 4),
            "shrec16_err": round(s16["mean_error"], 4),
            "tk25_auc": round(s25["auc_mean"], 4),
            "tk25_err_x100": round(s25["mean_error"], 2),
        }
        emit_row(row, args.json)


if __name__ == "__main__":
    main()
