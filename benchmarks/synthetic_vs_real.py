"""Does the synthetic benchmark rank methods like real TOPKIDS does?

Runs every method spec on the built-in synthetic benchmark and on real TOPKIDS low res,
both under the shrec16 protocol (test split, symmetric solutions accepted, heat
geodesics), and prints each method's AUC on both and the Spearman rank correlation
of the AUCs (also without the oracle, whose AUC is 1 by construction on both).

Usage
-----
    python benchmarks/synthetic_vs_real.py --data ../shared/data --out runs/svr \\
        oracle descriptor-nn descriptor-nn:descriptor=hks descriptor-nn:k=30

A spec is ``METHOD[:KEY=VALUE[,KEY=VALUE...]]``; values are Python literals. Runs go
to ``OUT/<set>/<spec>`` and are resumed when present (so the lead can re-run with more
methods and only the new ones are computed).
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from topomatch import _cache
from topomatch.evaluation.benchmark import BenchmarkConfig, run_benchmark


def parse_spec(spec: str) -> tuple[str, dict]:
    name, _, rest = spec.partition(":")
    params = {}
    for item in filter(None, rest.split(",")):
        k, v = item.split("=", 1)
        try:
            params[k] = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            params[k] = v
    return name, params


def run(spec: str, dataset: str, data: str | None, out: Path, jobs: int) -> float:
    name, params = parse_spec(spec)
    cfg = BenchmarkConfig(
        dataset=dataset, data_dir=data, resolution="low", protocols=["shrec16"], split="test",
        methods=[name], params={name: params} if params else {}, jobs=jobs,
    )
    folder = out / dataset / re.sub(r"[^A-Za-z0-9_.=-]+", "_", spec)
    t0 = time.perf_counter()
    summary = run_benchmark(cfg, folder, progress=False)
    auc = summary["methods"][name]["shrec16"]["auc_mean"]
    print(f"  {dataset:8} {spec:40} AUC {auc:.3f}  ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    return float(auc)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("specs", nargs="+")
    p.add_argument("--data", required=True, help="folder holding topkids/low_res")
    p.add_argument("--out", default="runs/synthetic_vs_real")
    p.add_argument("--jobs", type=int, default=1)
    args = p.parse_args()
    if _cache.cache_dir() is None:
        _cache.set_cache_dir(_cache.default_cache_dir())
    out = Path(args.out)
    rows = []
    for spec in args.specs:
        rows.append((spec, run(spec, "builtin", None, out, args.jobs), run(spec, "topkids", args.data, out, args.jobs)))
    print("| method | AUC synthetic (builtin, shrec16 test) | AUC real (TOPKIDS low, shrec16 test) |")
    print("|---|---|---|")
    for spec, a, b in rows:
        print(f"| {spec} | {a:.3f} | {b:.3f} |")
    syn = np.array([r[1] for r in rows])
    real = np.array([r[2] for r in rows])
    if len(rows) >= 3:
        rho, pval = spearmanr(syn, real)
        print(f"\nSpearman rank correlation over {len(rows)} methods: {rho:.3f} (p = {pval:.3f})")
        keep = [i for i, r in enumerate(rows) if not r[0].startswith("oracle")]
        if len(keep) >= 3 and len(keep) < len(rows):
            rho2, p2 = spearmanr(syn[keep], real[keep])
            print(f"without the oracle ({len(keep)} methods): {rho2:.3f} (p = {p2:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
