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
        if raw.lower() in ("true", "false"):  # as typed in a shell; a string would be truthy
            value: Any = raw.lower() == "true"
        else:
            try:
                value = ast.literal_eval(raw)
            except (ValueError, SyntaxError):
                try:  # JSON spellings too: null, true, false inside a dict or list
                    value = json.loads(raw)
                except ValueError:
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
    from topomatch.matching import DEFAULT_METHOD, DEFAULT_WITHOUT_TEMPLATE, MATCHERS

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
    b.add_argument("--jobs", type=int, help="worker processes (default: the CPU count, at most 4; use 1 for timings)")
    b.add_argument("--max-pairs", type=int, metavar="N", help="at most N pairs per protocol (evenly spaced subset)")
    b.add_argument("--pair", action="append", metavar="TARGET-SOURCE", help="run only this pair, e.g. kid02-kid01 (repeatable)")
    b.add_argument("--dask", metavar="SCHEDULER", help="run on an existing Dask cluster (tcp://host:8786; needs topomatch[dask])")
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
    e.add_argument("--no-cache", action="store_true", help="do not read or write the disk cache of geodesic matrices")
    e.add_argument("--jobs", type=int, default=1)
    esym = e.add_mutually_exclusive_group()
    esym.add_argument("--symmetric", dest="symmetric", action="store_true", default=None)
    esym.add_argument("--no-symmetric", dest="symmetric", action="store_false")
    e.add_argument("--geodesic", action="append", choices=["heat", "exact", "dijkstra"])
    e.add_argument("--quiet", action="store_true")

    m = sub.add_parser("match", help="match one pair of meshes")
    m.add_argument("source", help="shape 1 (the map's values index its vertices)")
    m.add_argument("target", help="shape 2 (one map entry per vertex)")
    m.add_argument("--method", choices=sorted(MATCHERS), help=f"default: {DEFAULT_METHOD} with --template, else {DEFAULT_WITHOUT_TEMPLATE}")
    m.add_argument(
        "--template",
        metavar="MESH",
        help="clean template of the shapes' class, matched through (method template): a mesh such as TOPKIDS' kid00.off, "
        "or a model from 'topomatch fit template --out MODEL.off', which brings the training poses",
    )
    m.add_argument("--param", action="append", default=[], metavar="KEY=VALUE")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--out", required=True, metavar="MAP", help="output file (.txt one-based vertex map, .npy zero-based, or --format shrec16)")
    m.add_argument("--format", choices=["p2p", "shrec16", "npy"], help="default from the suffix (.npy -> npy, else p2p)")

    r = sub.add_parser("report", help="figures, tables and the HTML report from run directories")
    r.add_argument("runs", nargs="+", metavar="RUN", help="run directories (e.g. a low-res and a high-res run side by side)")
    r.add_argument("--out", metavar="DIR", help="output folder (default: RUN/report for one run, else report-<time>)")
    r.add_argument("--no-render", action="store_true", help="skip the mesh renderings (Fig. 4/5)")
    r.add_argument("--no-html", action="store_true", help="skip report.html")
    r.add_argument("--max-html-mb", type=float, default=60.0, help="budget for mesh and map data embedded in the HTML viewer")

    nz = sub.add_parser(
        "noise",
        help="make topological-noise data (TOPKIDS layout) from clean shapes in correspondence",
        description="Fuse touching parts of each posed clean mesh, keep the single outer surface, remesh it, and "
        "write the TOPKIDS layout (kidNN.off, _ref, _sym, _indmap) into OUT/low_res. See docs/noise.md.",
    )
    nz.add_argument("null", nargs="?", help="clean null (rest-pose) mesh: the template")
    nz.add_argument("poses", nargs="*", help="clean posed meshes, same connectivity as NULL (or give --vertex-map)")
    nz.add_argument("--builtin", action="store_true", help="write the built-in synthetic benchmark instead")
    nz.add_argument("--out", required=True, metavar="DIR", help="data directory to create (files go to DIR/low_res)")
    nz.add_argument("--vertices", type=int, help="output resolution (default 10000; 5000 with --builtin)")
    nz.add_argument("--null-vertices", type=int, help="vertices of the null shape kid00 (default: --vertices)")
    nz.add_argument("--voxel-size", type=float, help="grid spacing of the inside/outside field (default 0.6 x edge)")
    nz.add_argument("--merge-distance", type=float, help="gaps narrower than this fuse (default: one edge length)")
    nz.add_argument("--unreliable-distance", type=float, help="vertices farther from the clean surface are unreliable (default 0.5 x edge)")
    nz.add_argument("--shortcuts", type=int, default=0, help="synthetic shortcuts per shape (second mode)")
    nz.add_argument("--shortcut-radius", type=float, help="shortcut capsule radius (default 1.5 x edge)")
    nz.add_argument("--shortcut-max-gap", type=float, help="longest gap a shortcut bridges (default 0.15 sqrt(area))")
    nz.add_argument("--vertex-map", action="append", default=[], metavar="FILE", help="per pose, in order: one-based vertex of the pose for each null vertex")
    nz.add_argument("--sym", metavar="FILE", help="left-right map of NULL (_sym format)")
    nz.add_argument("--mirror-axis", choices=["auto", "x", "y", "z", "none"], default="auto", help="without --sym: find the map by reflection (default auto)")
    nz.add_argument("--no-holes", action="store_true", help="do not re-open the null shape's boundary loops in the outputs")
    nz.add_argument("--seed", type=int, default=0, help="random_state")
    nz.add_argument("--jobs", type=int, default=1, help="worker processes")

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


def _print_table(summary: dict, labels: dict[str, str]) -> None:
    """Print the results table (the report writes it to files as Markdown, CSV and LaTeX)."""
    from topomatch.evaluation.tables import method_rows, to_markdown

    sys.stdout.write(to_markdown(method_rows(summary, labels)))


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
        jobs=args.jobs if args.jobs is not None else min(4, os.cpu_count() or 1),
        random_state=args.seed,
        max_pairs=args.max_pairs,
        pairs=args.pair,
    )
    out = Path(args.out) if args.out else Path("runs") / f"{dataset}-{time.strftime('%Y%m%d-%H%M%S')}"
    _enable_cache(args.no_cache)
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    try:
        summary = run_benchmark(
            config, out, progress=not args.quiet and sys.stderr.isatty(), retry_failed=args.retry_failed, on_event=say, dask_scheduler=args.dask
        )
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    _print_table(summary, _labels(methods))
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
    _enable_cache(args.no_cache)
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
    _print_table(summary, {})
    say(f"run directory: {out}")
    return 0


def cmd_match(args: argparse.Namespace) -> int:
    from topomatch.io import write_p2p, write_shrec16_map
    from topomatch.matching import DEFAULT_METHOD, DEFAULT_WITHOUT_TEMPLATE, make_matcher
    from topomatch.mesh import TriangleMesh

    method = args.method or (DEFAULT_METHOD if args.template else DEFAULT_WITHOUT_TEMPLATE)
    try:
        source = TriangleMesh.from_file(args.source)
        target = TriangleMesh.from_file(args.target)
        params = _parse_params(args.param, [method]).get(method, {})
        if args.template is not None:
            if method != "template":
                raise ValueError(f"--template is the template of method 'template', not of {method!r}")
            if params.get("model", args.template) != args.template:
                raise ValueError(f"two templates given: --template {args.template} and --param template.model={params['model']}")
            params["model"] = args.template
        matcher = make_matcher(method, **params)
        if "random_state" in matcher.get_params() and "random_state" not in params:
            matcher.set_params(random_state=args.seed)
        if matcher.requires_fit and not getattr(matcher, "model", None):
            hint = matcher.model_hint or f"{method} needs training; use 'topomatch bench', or 'topomatch fit {method} --out MODEL' and --param model=MODEL"
            raise ValueError(hint)
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
    how = method
    if method == "template":
        k = len(matcher.training_shapes_) - 1
        how = f"template through {matcher.template_name_} ({k} training pose{'s' if k != 1 else ''})"
    print(f"{how}: {target.n_vertices} target vertices mapped onto {source.n_vertices} source vertices in {seconds:.2f} s -> {args.out}", file=sys.stderr)
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from topomatch.report import build_report

    runs = [Path(r) for r in args.runs]
    out = Path(args.out) if args.out else (runs[0] / "report" if len(runs) == 1 else Path(f"report-{time.strftime('%Y%m%d-%H%M%S')}"))
    t0 = time.perf_counter()
    try:
        path = build_report(runs, out, renderings=not args.no_render, html=not args.no_html, max_html_mb=args.max_html_mb)
    except (ValueError, FileNotFoundError, TypeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    sys.stdout.write((out / "table1.md").read_text())
    print(f"report written to {out} in {time.perf_counter() - t0:.1f} s: {path}", file=sys.stderr)
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
    print(f"{args.method}: {how} on {len(res.training_shapes)} training shapes ({', '.join(res.training_shapes)})", file=sys.stderr)
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


def cmd_noise(args: argparse.Namespace) -> int:
    from topomatch.datasets.noise import NoiseParams, noise_files, write_topkids

    t0 = time.perf_counter()
    try:
        if args.builtin:
            if args.null or args.poses:
                raise ValueError("--builtin takes no input meshes")
            from topomatch.datasets.builtin import builtin_benchmark

            _enable_cache(False)
            coll = builtin_benchmark(args.vertices or 5000, random_state=args.seed)
            folder = write_topkids(coll, args.out)
        else:
            if not args.null or not args.poses:
                raise ValueError("give the null mesh and at least one posed mesh (or --builtin)")
            params = NoiseParams(
                n_vertices=args.vertices or 10_000,
                voxel_size=args.voxel_size,
                merge_distance=args.merge_distance,
                unreliable_distance=args.unreliable_distance,
                shortcuts=args.shortcuts,
                shortcut_radius=args.shortcut_radius,
                shortcut_max_gap=args.shortcut_max_gap,
                keep_holes=not args.no_holes,
            )
            coll = noise_files(
                args.null,
                args.poses,
                args.out,
                params,
                vertex_maps=args.vertex_map or None,
                sym=args.sym,
                mirror_axis=None if args.mirror_axis == "none" else args.mirror_axis,
                null_vertices=args.null_vertices,
                random_state=args.seed,
                n_jobs=args.jobs,
            )
            folder = coll.root
    except (ValueError, FileNotFoundError, TypeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {len(coll.names)} shapes to {folder} in {time.perf_counter() - t0:.1f} s; inspect with: topomatch data info --data {args.out}", file=sys.stderr)
    return 0


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
    if args.command == "report":
        return cmd_report(args)
    if args.command == "noise":
        return cmd_noise(args)
    if args.command == "fit":
        return cmd_fit(args)
    parser.error(f"unknown command {args.command}")
    return 2
