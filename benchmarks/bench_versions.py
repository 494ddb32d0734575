"""Two versions of the library, pair by pair: time per pair and map equality, alternating.

A change meant to keep every map and save time is measured here: each version runs in
its own long-lived process (``--baseline``: the ``src`` folder of another checkout, e.g.
``git worktree add ../base <commit>``; the other process imports the installed
topomatch), both fitted once, and every target is matched by one, then the other, the
order swapped from target to target (ABBA), so that the machine's drift, which moves a
pair's time by more than most changes save, falls on both alike. Each match starts
afresh (the template's registrations kept by ``TemplateMatcher`` are cleared); with
``--warmup`` each worker first matches that shape unmeasured. Printed:
each target's two times, their ratio and whether the two maps are equal bit for bit;
then the median of the per-target ratios (each target's median over ``--rounds``) and
each version's median time. Without ``--warmup`` the first target's times include what
a version compiles or caches on its first pair. ``--cache-dir`` turns the disk cache of
eigenbases on in both workers, as ``topomatch bench`` does (default: off, unless
``TOPOMATCH_CACHE_DIR`` is set; without it the ``deform`` matchers compute each target's
eigenbasis in a forked child). Two rounds resolve about 3 % of a pair's time on a
2-core machine (session 59: the same change measured 0.955, then 0.981 with more in it).

    python benchmarks/bench_versions.py --baseline ../base/src [--data DATA] [--method template]
        [--targets kid01,kid02,...] [--rounds 2] [--warmup kid15] [--cache-dir DIR] [--json out.json]

Without ``--targets`` the 14 training shapes kid01..kid14 (kid15 is challenged, about
three pairs' time). Session 58 (#188) measured its change with this script.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time

_TRAINING = ",".join(f"kid{i:02d}" for i in range(1, 15))


def _worker(data: str, method: str) -> None:
    """The child: fit ``method`` on the TOPKIDS reference and training shapes, then match the targets read from stdin."""
    import numpy as np
    from _common import fit_shapes

    from topomatch._memory import PeakMemory
    from topomatch.datasets.topkids import load_topkids
    from topomatch.matching import make_matcher

    coll = load_topkids(data, "low")
    matcher = make_matcher(method)
    if matcher.requires_fit:
        matcher.fit([coll[n] for n in fit_shapes(coll)])
    source = coll[coll.reference].mesh
    print("ready", flush=True)
    for line in sys.stdin:
        name = line.strip()
        if not name:
            break
        getattr(matcher, "registrations_", {}).clear()  # no registration kept from an earlier round
        with PeakMemory():  # as topomatch bench measures a pair
            t0 = time.perf_counter()
            corr = matcher.match(source, coll[name].mesh)
            seconds = time.perf_counter() - t0
        digest = hashlib.sha256(np.ascontiguousarray(corr.p2p_21).tobytes()).hexdigest()[:16]
        print(name, f"{seconds:.4f}", digest, flush=True)


def _start(data: str, method: str, pythonpath: str | None, cache_dir: str | None) -> subprocess.Popen:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if pythonpath:
        env["PYTHONPATH"] = os.path.abspath(pythonpath)
    if cache_dir:
        env["TOPOMATCH_CACHE_DIR"] = os.path.abspath(cache_dir)
    proc = subprocess.Popen(
        [sys.executable, os.path.abspath(__file__), "--worker", "--data", data, "--method", method],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
    )
    if proc.stdout.readline().strip() != "ready":
        raise SystemExit(f"bench_versions: the worker ({pythonpath or 'installed topomatch'}) did not start")
    return proc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", help="src folder of the baseline checkout (imported through PYTHONPATH)")
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--method", default="template")
    ap.add_argument("--targets", default=_TRAINING, help="comma-separated TOPKIDS shapes matched from kid00")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--warmup", help="a shape each version matches once, unmeasured, before the targets")
    ap.add_argument("--cache-dir", help="the disk cache of eigenbases for both workers (topomatch bench's default: $XDG_CACHE_HOME/topomatch)")
    ap.add_argument("--json", help="write every time and digest here")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if not args.data:
        raise SystemExit("bench_versions: give --data or set TOPOMATCH_DATA (the TOPKIDS folder)")
    if args.worker:
        _worker(args.data, args.method)
        return
    if not args.baseline or not os.path.isdir(os.path.join(args.baseline, "topomatch")):
        raise SystemExit(f"bench_versions: --baseline must be a src folder holding topomatch/, got {args.baseline!r}")
    targets = [t for t in args.targets.split(",") if t]
    procs = {v: _start(args.data, args.method, path, args.cache_dir) for v, path in (("baseline", args.baseline), ("this", None))}
    runs: dict[str, dict[str, list[tuple[float, str]]]] = {k: {} for k in procs}

    def ask(version: str, name: str) -> tuple[float, str]:
        proc = procs[version]
        proc.stdin.write(name + "\n")
        proc.stdin.flush()
        reply = proc.stdout.readline().split()
        if len(reply) != 3:
            raise SystemExit(f"bench_versions: the {version} worker failed on {name}")
        return float(reply[1]), reply[2]

    if args.warmup:
        for version in procs:
            ask(version, args.warmup)
    print(f"{'target':8s} {'baseline s':>11s} {'this s':>8s} {'ratio':>7s}  maps")
    k = 0
    for _ in range(args.rounds):
        for name in targets:
            order = ("baseline", "this") if k % 2 == 0 else ("this", "baseline")
            for version in order:
                runs[version].setdefault(name, []).append(ask(version, name))
            k += 1
            (tb, hb), (tt, ht) = runs["baseline"][name][-1], runs["this"][name][-1]
            print(f"{name:8s} {tb:11.2f} {tt:8.2f} {tt / tb:7.3f}  {'equal' if hb == ht else 'DIFFER'}", flush=True)
    for proc in procs.values():
        proc.stdin.write("\n")
        proc.stdin.flush()
        proc.wait()
    med = {v: {t: statistics.median(s for s, _ in runs[v][t]) for t in targets} for v in procs}
    ratios = [med["this"][t] / med["baseline"][t] for t in targets]
    differ = sorted({t for t in targets for (_, a), (_, b) in zip(runs["baseline"][t], runs["this"][t]) if a != b})
    print(f"per-target time ratio median {statistics.median(ratios):.4f} (range {min(ratios):.3f}-{max(ratios):.3f}); "
          f"median s per pair: baseline {statistics.median(med['baseline'].values()):.2f}, this {statistics.median(med['this'].values()):.2f}; "
          f"maps {'all equal' if not differ else 'differ on ' + ', '.join(differ)}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"baseline": args.baseline, "method": args.method, "runs": runs}, fh)


if __name__ == "__main__":
    main()
