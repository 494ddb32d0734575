"""``topomatch`` command line."""

from __future__ import annotations

import argparse
import ast
import json
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["main"]


def _parse_params(items: Sequence[str], methods: Sequence[str] | None = None) -> dict[str, dict[str, Any]]:
    """``method.key=value`` (or ``key=value`` for every method) into a nested dict."""
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        if "=" not in item:
            raise SystemExit(f"error: --param expects KEY=VALUE or METHOD.KEY=VALUE, got {item!r}")
        key, raw = item.split("=", 1)
        try:
            value = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            value = raw
        if "." in key:
            m, k = key.split(".", 1)
            out.setdefault(m, {})[k] = value
        else:
            for m in methods or ["*"]:
                out.setdefault(m, {})[key] = value
    return out


def _add_data_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", metavar="DIR", help="TOPKIDS data directory (default: $TOPOMATCH_DATA)")
    p.add_argument("--resolution", choices=["low", "high"], default="low")


def _build_parser() -> argparse.ArgumentParser:
    from topomatch import __version__
    from topomatch.matching import DEFAULT_METHOD, MATCHERS

    parser = argparse.ArgumentParser(prog="topomatch", description="Dense shape correspondence under topological noise.")
    parser.add_argument("--version", action="version", version=f"topomatch {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True)

    b = sub.add_parser("bench", help="run methods on a benchmark and score them")
    _add_data_args(b)
    b.add_argument("--dataset", choices=["builtin", "topkids"], help="default: topkids when --data or $TOPOMATCH_DATA is set, else builtin")
    b.add_argument("--protocol", action="append", choices=["shrec16", "topkids25"], help="repeatable (default: both)")
    b.add_argument("--split", choices=["train", "test", "all"], help="default: shrec16 test, topkids25 all")
    b.add_argument("--method", action="append", choices=sorted(MATCHERS), help=f"repeatable (default: {DEFAULT_METHOD})")
    b.add_argument("--param", action="append", default=[], metavar="METHOD.KEY=VALUE", help="hyperparameter (repeatable)")
    b.add_argument("--out", metavar="RUN", help="run directory (default: runs/<dataset>-<time>)")
    b.add_argument("--jobs", type=int, default=1, help="worker processes")
    b.add_argument("--seed", type=int, default=0, help="random_state for every method")
    sym = b.add_mutually_exclusive_group()
    sym.add_argument("--symmetric", dest="symmetric", action="store_true", default=None, help="accept symmetric solutions")
    sym.add_argument("--no-symmetric", dest="symmetric", action="store_false", help="score the direct ground truth only")
    b.add_argument("--geodesic", action="append", choices=["heat", "exact", "dijkstra"], help="geodesic kinds to score (first = primary)")
    b.add_argument("--retry-failed", action="store_true", help="re-run pairs that failed before")
    b.add_argument("--no-cache", action="store_true", help="do not cache eigenbases on disk")
    b.add_argument("--quiet", action="store_true", help="no progress bars or status lines")

    e = sub.add_parser("evaluate", help="score a folder of correspondence files from any method")
    e.add_argument("submission", metavar="SUBMISSION_DIR")
    _add_data_args(e)
    e.add_argument("--protocol", required=True, choices=["shrec16", "topkids25"])
    e.add_argument("--split", choices=["train", "test", "all"])
    e.add_argument("--name", default="submission", help="method label in the results")
    e.add_argument("--out", metavar="RUN", help="run directory (default: runs/evaluate-<name>-<time>)")
    e.add_argument("--jobs", type=int, default=1)
    esym = e.add_mutually_exclusive_group()
    esym.add_argument("--symmetric", dest="symmetric", action="store_true", default=None)
    esym.add_argument("--no-symmetric", dest="symmetric", action="store_false")
    e.add_argument("--geodesic", action="append", choices=["heat", "exact", "dijkstra"])
    e.add_argument("--quiet", action="store_true")

    m = sub.add_parser("match", help="match one pair of meshes")
    m.add_argument("source", help="shape 1 (the map's values index its vertices)")
    m.add_argument("target", help="shape 2 (one map entry per vertex)")
    m.add_argument("--method", default=DEFAULT_METHOD, choices=sorted(MATCHERS))
    m.add_argument("--param", action="append", default=[], metavar="KEY=VALUE")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--out", required=True, metavar="MAP", help="output file (.txt one-based vertex map, .npy zero-based, or --format shrec16)")
    m.add_argument("--format", choices=["p2p", "shrec16", "npy"], help="default from the suffix (.npy -> npy, else p2p)")

    f = sub.add_parser("fit", help="train a learning method (e.g. rf) and cache / save its model")
    f.add_argument("method", choices=sorted(n for n, c in MATCHERS.items() if c.requires_fit and not c.uses_ground_truth))
    _add_data_args(f)
    f.add_argument("--dataset", choices=["builtin", "topkids"], help="default: topkids when --data or $TOPOMATCH_DATA is set, else builtin")
    f.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="hyperparameter (repeatable)")
    f.add_argument("--seed", type=int, default=0, help="random_state")
    f.add_argument("--out", metavar="MODEL", help="also write the model to this .npz file")
    f.add_argument("--no-cache", action="store_true", help="do not use the model cache")

    d = sub.add_parser("data", help="inspect the data")
    dsub = d.add_subparsers(dest="data_command", required=True)
    for name, help_ in (("info", "counts, topology and ground-truth coverage per shape"), ("check", "parse every file; exit 1 on any problem")):
        dp = dsub.add_parser(name, help=help_)
        dp.add_argument("--data", metavar="DIR")
        dp.add_argument("--resolution", choices=["low", "high", "both"], default="both")
        dp.add_argument("--json", action="store_true", help="machine-readable output")
    return parser


def _setup_logging(verbose: int) -> None:
    level = logging.WARNING if verbose == 0 else (logging.INFO if verbose == 1 else logging.DEBUG)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def _enable_cache(disabled: bool) -> None:
    from topomatch import _cache

    if not disabled and _cache.cache_dir() is None:
        _cache.set_cache_dir(_cache.default_cache_dir())


def _print_table(summary: dict, run: Path, labels: dict[str, str]) -> None:
    from topomatch.evaluation.tables import method_rows, to_csv, to_latex, to_markdown

    rows = method_rows(summary, labels)
    table = to_markdown(rows)
    out = run / "report"
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(table)
    (out / "table.csv").write_text(to_csv(rows))
    (out / "table.tex").write_text(to_latex(rows))
    sys.stdout.write(table)


def _labels(methods: Sequence[str]) -> dict[str, str]:
    from topomatch.matching import MATCHERS

    return {m: f"{m} ({MATCHERS[m].ground_truth_note})" for m in methods if m in MATCHERS and MATCHERS[m].uses_ground_truth}


def cmd_bench(args: argparse.Namespace) -> int:
    import os

    from topomatch.evaluation.benchmark import BenchmarkConfig, run_benchmark
    from topomatch.matching import DEFAULT_METHOD

    dataset = args.dataset or ("topkids" if (args.data or os.environ.get("TOPOMATCH_DATA")) else "builtin")
    methods = args.method or [DEFAULT_METHOD]
    config = BenchmarkConfig(
        dataset=dataset,
        data_dir=str(Path(args.data).resolve()) if args.data else None,
        resolution=args.resolution,
        protocols=args.protocol or ["shrec16", "topkids25"],
        split=args.split,
        methods=methods,
        params=_parse_params(args.param, methods),
        symmetric=args.symmetric,
        geodesics=args.geodesic,
        jobs=args.jobs,
        random_state=args.seed,
    )
    out = Path(args.out) if args.out else Path("runs") / f"{dataset}-{time.strftime('%Y%m%d-%H%M%S')}"
    _enable_cache(args.no_cache)
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    try:
        summary = run_benchmark(config, out, progress=not args.quiet and sys.stderr.isatty(), retry_failed=args.retry_failed, on_event=say)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    _print_table(summary, out, _labels(methods))
    _report(out, say)
    say(f"run directory: {out}")
    return 0


def _report(run: Path, say) -> None:
    """Figures and the HTML report when the report package is available."""
    try:
        from topomatch.report import build_report
    except ImportError:
        return
    try:
        build_report([run], run / "report")
    except Exception as err:  # the numbers are already safe on disk
        say(f"report failed: {err}")


def cmd_evaluate(args: argparse.Namespace) -> int:
    from topomatch.evaluation.submission import evaluate_submission

    out = Path(args.out) if args.out else Path("runs") / f"evaluate-{args.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    try:
        summary = evaluate_submission(
            args.submission,
            protocol=args.protocol,
            data_dir=args.data,
            resolution=args.resolution,
            split=args.split,
            name=args.name,
            out=out,
            symmetric=args.symmetric,
            geodesics=args.geodesic,
            jobs=args.jobs,
            on_event=say,
        )
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    _print_table(summary, out, {})
    say(f"run directory: {out}")
    return 0


def cmd_match(args: argparse.Namespace) -> int:
    from topomatch.io import write_p2p, write_shrec16_map
    from topomatch.matching import make_matcher
    from topomatch.mesh import TriangleMesh

    try:
        source = TriangleMesh.from_file(args.source)
        target = TriangleMesh.from_file(args.target)
        params = _parse_params(args.param, [args.method]).get(args.method, {})
        matcher = make_matcher(args.method, **params)
        if "random_state" in matcher.get_params() and "random_state" not in params:
            matcher.set_params(random_state=args.seed)
        if matcher.requires_fit and not getattr(matcher, "model", None):
            raise ValueError(f"{args.method} needs training; use 'topomatch bench', or 'topomatch fit {args.method} --out MODEL' and --param model=MODEL")
        if matcher.requires_fit:
            matcher.fit([])  # loads the model file given as --param model=...
    except (ValueError, FileNotFoundError, TypeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    _enable_cache(False)
    t0 = time.perf_counter()
    corr = matcher.match(source, target)
    seconds = time.perf_counter() - t0
    fmt = args.format or ("npy" if args.out.endswith(".npy") else "p2p")
    if fmt == "npy":
        import numpy as np

        np.save(args.out, corr.p2p_21)
    elif fmt == "shrec16":
        write_shrec16_map(args.out, corr.p2p_21, source.faces)
    else:
        write_p2p(args.out, corr.p2p_21)
    print(f"{args.method}: {target.n_vertices} target vertices mapped onto {source.n_vertices} source vertices in {seconds:.2f} s -> {args.out}", file=sys.stderr)
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    import os

    from topomatch.evaluation.fitting import fit_method

    dataset = args.dataset or ("topkids" if (args.data or os.environ.get("TOPOMATCH_DATA")) else "builtin")
    _enable_cache(args.no_cache)
    try:
        res = fit_method(
            args.method,
            dataset=dataset,
            data_dir=Path(args.data).resolve() if args.data else None,
            resolution=args.resolution,
            params=_parse_params(args.param, [args.method]).get(args.method, {}),
            random_state=args.seed,
            out=args.out,
        )
    except (ValueError, FileNotFoundError, TypeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    how = "loaded from the cache" if res.from_cache else f"trained in {res.seconds:.1f} s"
    print(f"{args.method}: {how} on {len(res.shapes)} shapes ({', '.join(res.shapes)})", file=sys.stderr)
    if res.model_path is not None:
        print(f"model written to {res.model_path}", file=sys.stderr)
    return 0


def cmd_data(args: argparse.Namespace) -> int:
    from topomatch.datasets.inspect import data_report

    try:
        report, ok = data_report(args.data, args.resolution, check=args.data_command == "check")
    except FileNotFoundError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        from topomatch.datasets.inspect import format_report

        sys.stdout.write(format_report(report))
    return 0 if ok else 1


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    parser = _build_parser()
    args = parser.parse_args(argv)
    _setup_logging(args.verbose)
    if args.command == "bench":
        return cmd_bench(args)
    if args.command == "evaluate":
        return cmd_evaluate(args)
    if args.command == "match":
        return cmd_match(args)
    if args.command == "data":
        return cmd_data(args)
    if args.command == "fit":
        return cmd_fit(args)
    parser.error(f"unknown command {args.command}")
    return 2
