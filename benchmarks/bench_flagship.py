"""Flagship vs our ZoomOut vs pyFM's ZoomOut on the same pairs, in one run.

For every pair and method the script builds fresh meshes (no eigenbasis reuse between
methods, no disk cache), times the whole match call including Laplacian, eigenbasis and
descriptors, and samples the process's resident memory during it. All maps are then
scored with the project's scorer. Printed: median seconds per pair, peak memory (the
largest RSS seen during any call, and the largest rise above the RSS before the call),
accuracy, and the time / memory ratios of each method to ``zoomout`` and ``pyfm-zoomout``.

pyFM (PyPI ``pyfmaps``) is a benchmark-only dependency: ``pip install topomatch[bench]``.
Its pipeline is the one measured in the project's reference notes: WKS descriptors,
k = 30 with the orientation term, ZoomOut to 110 in steps of 5.

Examples
--------
    python benchmarks/bench_flagship.py --data DATA --protocol topkids25 --split train
    python benchmarks/bench_flagship.py --data DATA --protocol shrec16 --split train --max-pairs 10
    python benchmarks/bench_flagship.py --data DATA --resolution high --protocol shrec16 --split train --max-pairs 4
    python benchmarks/bench_flagship.py --data DATA --resolution high --max-pairs 2 --geodesic none
    python benchmarks/bench_flagship.py --data DATA --methods deform,zoomout --param deform.fine_icp_iterations=25
    python benchmarks/bench_flagship.py --data DATA --methods deform,deform@f40 --param deform@f40.fine_icp_iterations=40 --repeat 3
    python benchmarks/bench_flagship.py --data DATA --split test --methods template,template@ch --param 'template@ch.deform={"pose_challengers": 3}' --repeat 2 --geodesic dijkstra

A method that needs fitting (``template``) is fitted first, untimed, on the reference
shape and the training split, as ``topomatch bench`` does; it registers every shape
afresh on every call.

A method written ``name@label`` is our method ``name`` with the parameters given as
``--param name@label.key=value``: two settings of one method timed side by side in one
run, with its ratio to ``name`` printed. ``--repeat N`` runs every pair N times (the
methods' order reversed on every other repetition) and takes each pair's median time.

Timings depend on the machine and its load: quote medians, rerun on a quiet machine.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from topomatch._memory import PeakMemory, current_rss_mb
from topomatch.cli.main import _parse_params
from topomatch.datasets.topkids import load_topkids
from topomatch.evaluation.benchmark import _versions
from topomatch.evaluation.protocols import get_protocol
from topomatch.evaluation.scoring import score_maps, summarize
from topomatch.matching import DEFAULT_METHOD, make_matcher
from topomatch.mesh import TriangleMesh


def pyfm_zoomout(source: TriangleMesh, target: TriangleMesh) -> np.ndarray:
    """pyFM's full pipeline; returns p2p_21 (target vertex -> source vertex)."""
    from pyFM.functional import FunctionalMapping
    from pyFM.mesh import TriMesh

    m1 = TriMesh(np.array(source.vertices), np.array(source.faces))
    m2 = TriMesh(np.array(target.vertices), np.array(target.faces))
    fm = FunctionalMapping(m1, m2)
    fm.preprocess(n_descr=100, descr_type="WKS", subsample_step=5, k_process=110)
    fm.fit(K=30, w_descr=1.0, w_lap=1e-2, w_dcomm=1e-1, w_orient=1.0)
    C = fm.zoomout_refine(nit=16, step=5)
    return np.asarray(fm.get_p2p(FM=C), dtype=np.int64)


def ours(name: str, params: dict | None = None, training: Callable[[], list] | None = None):
    """Our matcher ``name`` as a timed call; one that needs fitting is fitted on ``training()`` first (not timed)."""
    matcher = make_matcher(name, **(params or {}))
    if matcher.requires_fit:
        matcher.fit(training() if training is not None else [])

    def run(source: TriangleMesh, target: TriangleMesh) -> np.ndarray:
        # a matcher that keeps each shape's registration (template) registers afresh on every call
        getattr(matcher, "registrations_", {}).clear()
        return matcher.match(source, target).p2p_21

    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"), help="folder holding topkids/")
    ap.add_argument("--protocol", default="topkids25", choices=["topkids25", "shrec16"])
    ap.add_argument("--split", default="train", choices=["train", "test", "all"])
    ap.add_argument("--resolution", default="low", choices=["low", "high"])
    ap.add_argument("--methods", default=f"{DEFAULT_METHOD},zoomout,pyfm-zoomout")
    ap.add_argument("--max-pairs", type=int, default=None, help="first N pairs of the split (evenly spread for shrec16)")
    ap.add_argument("--geodesic", default=None, help="geodesic kind for scoring (default: the protocol's); 'none': timings only")
    ap.add_argument("--json", default=None, help="write the per-pair figures to this file")
    ap.add_argument("--param", action="append", default=[], metavar="METHOD.KEY=VALUE", help="parameter of one of our methods (repeatable)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per pair and method (median time; order alternated)")
    args = ap.parse_args()
    if not args.data:
        ap.error("give --data or set TOPOMATCH_DATA")
    if os.environ.pop("TOPOMATCH_CACHE_DIR", None):
        print("TOPOMATCH_CACHE_DIR ignored: every method computes its eigenbases", file=sys.stderr)

    coll = load_topkids(args.data, args.resolution)
    prot = get_protocol(args.protocol)
    pairs = prot.pairs(coll, args.split)
    if args.max_pairs is not None and args.max_pairs < len(pairs):
        idx = np.unique(np.linspace(0, len(pairs) - 1, args.max_pairs).round().astype(int))
        pairs = [pairs[i] for i in idx]
    methods = [m for m in args.methods.split(",") if m]
    if len(set(methods)) != len(methods):
        ap.error("--methods lists a method twice; name a second setting name@label")
    if args.repeat < 1:
        ap.error("--repeat must be at least 1")
    params = _parse_params(args.param, [m for m in methods if m != "pyfm-zoomout"])
    unknown = sorted(set(params) - set(methods) - {"*"})
    if unknown:
        ap.error(f"--param for {', '.join(unknown)}, which --methods does not list")
    # trained methods (template) learn from the reference shape and the training split, as in topomatch bench
    def training() -> list:
        return [coll[n] for n in coll.present([coll.reference, *coll.splits.get("train", [])])]

    runners = {m: (pyfm_zoomout if m == "pyfm-zoomout" else ours(m.split("@")[0], params.get(m), training)) for m in methods}
    machine = _versions()
    print(f"{len(pairs)} pairs ({args.protocol}, {args.split}, {args.resolution} res); methods: {', '.join(methods)}")
    print(f"machine: {machine['cpu']}, {machine['cpu_count']} CPUs; Python {machine['python']}, numpy {machine['numpy']}, scipy {machine['scipy']}")

    maps: dict[tuple[str, str], np.ndarray] = {}
    secs: dict[str, list[float]] = {m: [] for m in methods}
    peak: dict[str, list[float]] = {m: [] for m in methods}
    rise: dict[str, list[float]] = {m: [] for m in methods}
    runs: dict[str, list[list[float]]] = {m: [] for m in methods}
    for pair in pairs:
        src_shape, tgt_shape = coll[pair.source], coll[pair.target]
        times: dict[str, list[float]] = {m: [] for m in methods}
        for rep in range(args.repeat):
            for m in methods if rep % 2 == 0 else methods[::-1]:
                # fresh meshes: every method computes its own operators
                src = TriangleMesh(src_shape.mesh.vertices, src_shape.mesh.faces, name=pair.source)
                tgt = TriangleMesh(tgt_shape.mesh.vertices, tgt_shape.mesh.faces, name=pair.target)
                gc.collect()
                before = current_rss_mb()
                with PeakMemory() as pm:
                    t0 = time.perf_counter()
                    p2p = runners[m](src, tgt)
                    dt = time.perf_counter() - t0
                maps.setdefault((m, pair.id), p2p)
                times[m].append(dt)
                if rep == 0:
                    peak[m].append(pm.peak_mb)
                    rise[m].append(pm.peak_mb - before)
                print(f"  {pair.id:12s} {m:14s} {dt:7.1f} s  peak {pm.peak_mb:7.0f} MB (+{pm.peak_mb - before:.0f})", flush=True)
                del src, tgt
        for m in methods:
            secs[m].append(float(np.median(times[m])))
            runs[m].append(times[m])

    geos = [args.geodesic] if args.geodesic else list(prot.geodesics)
    acc: dict[str, dict[str, dict]] = {m: {} for m in methods}
    variants = [(geo, prot) for geo in geos]
    if args.geodesic == "none":  # e.g. at high res, where scoring costs more than matching
        variants = []
    elif prot.name == "shrec16":
        variants = [(geos[0], prot), (geos[0] + " no-sym", prot.with_options(symmetric=False))]
    for label, p in variants:
        geo = label.split()[0]
        scores = score_maps(coll, p, maps, geodesic=geo)
        for m in methods:
            acc[m][label] = summarize([s for s in scores if s.method == m], p)

    def med(x: list[float]) -> float:
        return float(np.median(x)) if x else float("nan")

    print()
    head = f"{'method':16s} {'s/pair':>8s} {'peak MB':>8s} {'+MB':>7s}"
    for label, _ in variants:
        head += f"  {('err x100 ' if prot.name == 'topkids25' else 'AUC avg/worst ') + label:>26s}"
    print(head)
    for m in methods:
        row = f"{m:16s} {med(secs[m]):8.1f} {max(peak[m]):8.0f} {max(rise[m]):7.0f}"
        for label, _ in variants:
            s = acc[m][label]
            if prot.name == "topkids25":
                row += f"  {s['mean_error']:26.2f}"
            else:
                row += f"  {s['auc_mean']:19.3f} / {s['auc_worst']:.3f}"
        print(row)
    print()
    for m in methods:
        base = m.split("@")[0]
        if base != m and base in methods and base not in ("zoomout", "pyfm-zoomout"):  # those two: below
            print(f"{m} / {base}: time x{med(secs[m]) / med(secs[base]):.2f}, peak memory x{max(peak[m]) / max(peak[base]):.2f}")
    for base in ("zoomout", "pyfm-zoomout"):
        if base not in methods:
            continue
        for m in methods:
            if m == base:
                continue
            print(
                f"{m} / {base}: time x{med(secs[m]) / med(secs[base]):.2f}, "
                f"peak memory x{max(peak[m]) / max(peak[base]):.2f}, rise x{max(rise[m]) / max(max(rise[base]), 1.0):.2f}"
            )
    if args.json:
        out = {
            "pairs": [p.id for p in pairs],
            "args": vars(args),
            "machine": machine,
            "seconds": secs,
            "seconds_runs": runs,
            "peak_mb": peak,
            "rise_mb": rise,
            "accuracy": {m: {k: {kk: vv for kk, vv in v.items() if not isinstance(vv, list)} for k, v in acc[m].items()} for m in methods},
        }
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
