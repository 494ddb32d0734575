"""Run methods on a benchmark and score them: the engine behind ``topomatch bench``.

A run is resumable: every map and every score row is its own atomically written file
in the run directory, so a run killed half way and started again computes only what is
missing and ends with the same numbers. A pair that fails is recorded with its error
and the run goes on.
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import subprocess
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from topomatch import __version__
from topomatch._memory import PeakMemory
from topomatch.datasets.base import ShapeCollection
from topomatch.evaluation.protocols import PairSpec, get_protocol
from topomatch.evaluation.rundir import RunDir, write_json
from topomatch.evaluation.scoring import score_maps, summarize
from topomatch.matching import DEFAULT_METHOD, MATCHERS, Matcher, make_matcher

__all__ = ["BenchmarkConfig", "build_summary", "load_collection", "resolve_protocols", "run_benchmark", "score_stored_maps"]

logger = logging.getLogger(__name__)


@dataclass
class BenchmarkConfig:
    """What to run.

    Attributes
    ----------
    dataset : {"builtin", "topkids"}
    data_dir : str, optional
        For ``topkids``; defaults to ``TOPOMATCH_DATA``.
    resolution : {"low", "high"}
    protocols : list of str
    split : str, optional
        ``"train"``, ``"test"`` or ``"all"``; ``None`` uses each protocol's default
        (shrec16: test, topkids25: all).
    methods : list of str
    params : dict
        Hyperparameters per method name.
    symmetric : bool, optional
        Override the protocols' symmetric-solution switch.
    geodesics : list of str, optional
        Override the geodesic kinds scored (first = primary).
    jobs : int
        Worker processes.
    random_state : int
        Passed to every matcher that takes one (and to the built-in data).
    max_pairs : int, optional
        Score at most this many pairs per protocol: an evenly spaced, deterministic subset
        of the protocol's ordered pair list (for expensive methods, e.g. at high res).
        Summaries then state ``n_pairs`` honestly; ``None`` runs every pair.
    pairs : list of str, optional
        Run only these pairs (ids ``"<target>-<source>"``), each of which must belong to
        every selected protocol's split. Applied before ``max_pairs``. Useful at high
        resolution, where scoring costs per *source* shape: pairs that share a source
        share that cost.
    """

    dataset: str = "builtin"
    data_dir: str | None = None
    resolution: str = "low"
    protocols: list[str] = field(default_factory=lambda: ["shrec16", "topkids25"])
    split: str | None = None
    methods: list[str] = field(default_factory=lambda: [DEFAULT_METHOD])
    params: dict[str, dict[str, Any]] = field(default_factory=dict)
    symmetric: bool | None = None
    geodesics: list[str] | None = None
    jobs: int = 1
    random_state: int = 0
    external: bool = False
    max_pairs: int | None = None
    pairs: list[str] | None = None

    def validate(self) -> None:
        """Raise ``ValueError`` on unknown names."""
        if self.dataset not in ("builtin", "topkids"):
            raise ValueError(f"dataset must be 'builtin' or 'topkids', got {self.dataset!r}")
        if self.resolution not in ("low", "high"):
            raise ValueError(f"resolution must be 'low' or 'high', got {self.resolution!r}")
        for p in self.protocols:
            get_protocol(p)
        for m in [] if self.external else self.methods:
            if m not in MATCHERS:
                raise ValueError(f"unknown method {m!r}; available: {', '.join(MATCHERS)}")
        for g in self.geodesics or []:
            if g not in ("heat", "exact", "dijkstra"):
                raise ValueError(f"unknown geodesic kind {g!r}")
        if self.split not in (None, "train", "test", "all"):
            raise ValueError(f"split must be train, test or all, got {self.split!r}")
        if self.jobs < 1:
            raise ValueError("jobs must be >= 1")
        if self.max_pairs is not None and (isinstance(self.max_pairs, bool) or int(self.max_pairs) < 1):
            raise ValueError(f"max_pairs must be a positive integer, got {self.max_pairs!r}")
        if self.pairs is not None and not self.pairs:
            raise ValueError("pairs must not be empty when given")
        for pid in self.pairs or []:
            PairSpec.from_id(pid)


_COLLECTIONS: dict[str, ShapeCollection] = {}


def subset_pairs(pairs: list[PairSpec], max_pairs: int) -> list[PairSpec]:
    """An evenly spaced, deterministic subset of at most ``max_pairs`` pairs (order kept)."""
    if len(pairs) <= max_pairs:
        return list(pairs)
    idx = np.unique(np.round(np.linspace(0, len(pairs) - 1, int(max_pairs))).astype(np.int64))
    return [pairs[i] for i in idx]


def load_collection(config: BenchmarkConfig) -> ShapeCollection:
    """The dataset named by ``config`` (cached per process)."""
    key = f"{config.dataset}|{config.data_dir}|{config.resolution}|{config.random_state}"
    if key not in _COLLECTIONS:
        if config.dataset == "builtin":
            from topomatch.datasets.builtin import builtin_benchmark

            _COLLECTIONS[key] = builtin_benchmark(random_state=config.random_state)
        else:
            from topomatch.datasets.topkids import load_topkids

            _COLLECTIONS[key] = load_topkids(config.data_dir, config.resolution)  # type: ignore[arg-type]
    return _COLLECTIONS[key]


def _git_revision() -> str | None:
    try:
        here = Path(__file__).resolve().parent
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if out.returncode == 0:
            dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here, capture_output=True, text=True, timeout=5)
            return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        pass
    return None


def cpu_model() -> str:
    """The processor's model name (Linux ``/proc/cpuinfo``; else :func:`platform.processor`; else ``"unknown"``).

    Recorded beside timings: the same code ran 1.45x slower on one machine of our kind
    than on another (``docs/flagship.md``, session 19), so a time means little without it.
    """
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {
        "python": platform.python_version(), "topomatch": __version__, "platform": platform.platform(),
        "cpu": cpu_model(), "cpu_count": str(os.cpu_count()),
    }
    for pkg in ("numpy", "scipy", "scikit-learn", "robust-laplacian", "potpourri3d", "cholespy", "pygeodesic", "numba"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = "absent"
    return out


def _data_checksums(collection: ShapeCollection) -> dict[str, str]:
    if collection.root is None:
        return {}
    out = {}
    for p in sorted(Path(collection.root).rglob("*")):
        if p.is_file() and p.suffix in (".off", ".txt", ".vts"):
            out[str(p.relative_to(collection.root))] = hashlib.sha256(p.read_bytes()).hexdigest()[:16]
    return out


def _make(config: BenchmarkConfig, method: str) -> Matcher:
    params = dict(config.params.get(method, {}))
    m = make_matcher(method, **params)
    if "random_state" in m.get_params() and "random_state" not in params:
        m.set_params(random_state=config.random_state)
    return m


def _fit(config: BenchmarkConfig, matcher: Matcher, collection: ShapeCollection) -> float:
    t0 = time.perf_counter()
    if matcher.uses_ground_truth:
        names = collection.names  # the oracle must know every shape it is asked about
    else:
        names = collection.present([collection.reference, *collection.splits.get("train", [])])
    if matcher.requires_fit:
        matcher.fit([collection[n] for n in names])
    return time.perf_counter() - t0


def _match_task(
    config: BenchmarkConfig, run_path: str, method: str, matcher: Matcher, pair_id: str, meshes: tuple | None = None
) -> tuple[str, str, str]:
    """Run one pair (in a worker); store the map or the failure. Returns (method, pair, status).

    ``meshes`` = (source, target) when given; otherwise they are loaded from the dataset
    in this process (cheap for files, and their caches then serve later pairs).
    """
    run = RunDir(run_path)
    pair = PairSpec.from_id(pair_id)
    t0 = time.perf_counter()
    try:
        if meshes is None:
            collection = load_collection(config)
            source, target = collection[pair.source].mesh, collection[pair.target].mesh
        else:
            source, target = meshes
        with PeakMemory() as mem:
            t0 = time.perf_counter()
            corr = matcher.match(source, target)
            seconds = time.perf_counter() - t0
        p2p = np.asarray(corr.p2p_21)
        if p2p.shape != (target.n_vertices,):
            raise ValueError(f"{method} returned a map of shape {p2p.shape} for {target.n_vertices} target vertices")
        if p2p.size and (p2p.max() >= source.n_vertices or p2p.min() < -1):
            raise ValueError(f"{method} returned indices outside [-1, {source.n_vertices - 1}]")
        run.save_map(method, pair_id, p2p, seconds=seconds, peak_rss_mb=mem.peak_mb, info=dict(corr.info))
        return method, pair_id, "ok"
    except Exception as err:  # a failing pair is recorded, never fatal
        run.save_failure(method, pair_id, f"{type(err).__name__}: {err}", traceback.format_exc(), time.perf_counter() - t0)
        logger.warning("%s failed on %s: %s", method, pair_id, err)
        return method, pair_id, "error"


def _ship(config: BenchmarkConfig, collection: ShapeCollection, pair_id: str) -> tuple | None:
    """Meshes to send to a worker, or ``None`` to let the worker read them.

    Generated datasets travel (regenerating them in every worker costs tens of
    seconds); file datasets are read by the worker itself.
    """
    if config.dataset != "builtin":
        return None
    pair = PairSpec.from_id(pair_id)
    return collection[pair.source].mesh, collection[pair.target].mesh


def _progress(total: int, desc: str, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, disable=not enabled, leave=False, dynamic_ncols=True)


def run_benchmark(
    config: BenchmarkConfig,
    out: str | os.PathLike[str],
    *,
    progress: bool = True,
    retry_failed: bool = False,
    on_event: Callable[[str], None] | None = None,
    dask_scheduler: str | None = None,
) -> dict:
    """Run (or resume) a benchmark into the run directory ``out``.

    Parameters
    ----------
    config : BenchmarkConfig
    out : path
        Run directory; created if missing. If it holds a run with a different
        configuration, ``ValueError`` is raised.
    progress : bool
        Show progress bars (stderr).
    retry_failed : bool
        Re-run pairs recorded as failed.
    on_event : callable, optional
        Receives one-line status messages (the CLI prints them).
    dask_scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``): pairs are matched and
        scored on its workers (``pip install "topomatch[dask]"``; every worker needs
        topomatch and the data at the same path). ``config.jobs`` is ignored then.

    Returns
    -------
    dict
        The summary (also written to ``summary.json``).
    """
    config.validate()
    if dask_scheduler is not None:
        return _run_on_dask(config, out, dask_scheduler, progress=progress, retry_failed=retry_failed, on_event=on_event)
    say = on_event or (lambda s: logger.info("%s", s))
    run = RunDir(out)
    run.path.mkdir(parents=True, exist_ok=True)
    old = run.manifest()
    cfg = asdict(config)
    if old is not None:
        prev = dict(old.get("config", {}))
        prev_cmp = {k: v for k, v in prev.items() if k != "jobs"}
        cur_cmp = {k: v for k, v in cfg.items() if k != "jobs"}
        if prev_cmp != cur_cmp:
            raise ValueError(
                f"{run.path} holds a run with a different configuration; use a new --out directory "
                f"(differences: {sorted(k for k in cur_cmp if prev_cmp.get(k) != cur_cmp.get(k))})"
            )
        say(f"resuming the run in {run.path}")
    t_start = time.perf_counter()
    collection = load_collection(config)
    protocols = resolve_protocols(config)
    pair_sets = {p.name: p.pairs(collection, config.split) for p in protocols}
    for p in protocols:
        exp = p.expected_pairs(collection, config.split)
        if config.pairs is not None:
            known = {pr.id: pr for pr in pair_sets[p.name]}
            bad = [pid for pid in config.pairs if pid not in known]
            if bad:
                raise ValueError(
                    f"{p.name}: pair(s) {', '.join(bad)} not in the {config.split or p.default_split} split "
                    f"of {collection.name} ({config.resolution} res); ids are <target>-<source>"
                )
            pair_sets[p.name] = [known[pid] for pid in dict.fromkeys(config.pairs)]
            say(f"{p.name}: {len(pair_sets[p.name])} of {exp} pairs (--pair)")
        if config.max_pairs is not None and len(pair_sets[p.name]) > config.max_pairs:
            pair_sets[p.name] = subset_pairs(pair_sets[p.name], config.max_pairs)
            say(f"{p.name}: {config.max_pairs} of {exp} pairs (evenly spaced subset, --max-pairs)")
        elif len(pair_sets[p.name]) < exp:
            say(f"{p.name}: {len(pair_sets[p.name])} of {exp} pairs present ({'; '.join(collection.missing[:3])}...)")
    all_pairs = list(dict.fromkeys(pr.id for prs in pair_sets.values() for pr in prs))
    manifest = {
        "config": cfg,
        "dataset": {"name": collection.name, "root": str(collection.root) if collection.root else None, "missing": collection.missing},
        "versions": _versions(),
        "git_revision": _git_revision(),
        "protocols": {
            p.name: {"symmetric": p.symmetric, "geodesics": list(p.geodesics), "thresholds": [float(t) for t in p.thresholds], "n_pairs": len(pair_sets[p.name])}
            for p in protocols
        },
        "methods": {},
        "started": old.get("started") if old else time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    manifest["data_checksums"] = old.get("data_checksums") if old else _data_checksums(collection)
    write_json(run.path / "manifest.json", manifest)

    # 1. fit and match ------------------------------------------------------------------
    fit_seconds = {}
    for method in config.methods:
        todo = []
        for pid in all_pairs:
            if run.load_map(method, pid) is not None:
                continue
            if run.load_failure(method, pid) is not None and not retry_failed:
                continue
            todo.append(pid)
        matcher = _make(config, method)
        manifest["methods"][method] = {"params": {k: repr(v) for k, v in matcher.get_params().items()}, "uses_ground_truth": matcher.uses_ground_truth}
        if not todo:
            say(f"{method}: all {len(all_pairs)} maps present")
            continue
        fit_seconds[method] = _fit(config, matcher, collection)
        manifest["methods"][method]["fit_seconds"] = fit_seconds[method]
        say(f"{method}: matching {len(todo)} pair(s)" + (f" (fit {fit_seconds[method]:.1f} s)" if matcher.requires_fit else ""))
        bar = _progress(len(todo), method, progress)
        if config.jobs > 1 and len(todo) > 1 and matcher.shares_work:
            say(f"{method}: pairs run in this process (the matcher reuses work across pairs)")
        if config.jobs > 1 and len(todo) > 1 and not matcher.shares_work:
            from joblib import Parallel, delayed

            gen = Parallel(n_jobs=config.jobs, return_as="generator")(
                delayed(_match_task)(config, str(run.path), method, matcher, pid, _ship(config, collection, pid)) for pid in todo
            )
            for _ in gen:
                bar.update(1)
        else:
            for pid in todo:
                _match_task(config, str(run.path), method, matcher, pid)
                bar.update(1)
        bar.close()
    write_json(run.path / "manifest.json", manifest)

    score_stored_maps(run, config, collection, protocols, pair_sets, say)
    summary = build_summary(run, config, protocols, pair_sets)
    manifest["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    manifest["wall_seconds_this_session"] = time.perf_counter() - t_start
    write_json(run.path / "manifest.json", manifest)
    return summary


def _run_on_dask(config: BenchmarkConfig, out: str | os.PathLike[str], address: str, **kw: Any) -> dict:
    """Run through joblib's Dask backend on an existing cluster."""
    try:
        from dask.distributed import Client
    except ImportError as err:
        raise ValueError('the Dask backend needs dask.distributed: pip install "topomatch[dask]"') from err
    from dataclasses import replace

    import joblib

    with Client(address) as client:
        n_workers = max(1, sum(client.nthreads().values()))
        with joblib.parallel_config(backend="dask"):
            return run_benchmark(replace(config, jobs=max(2, n_workers)), out, **kw)


def score_stored_maps(run: RunDir, config: BenchmarkConfig, collection: ShapeCollection, protocols: list, pair_sets: dict, say: Callable[[str], None]) -> None:
    """Score every stored map that has no score yet, for each protocol and geodesic kind."""
    for p in protocols:
        for kind in p.geodesics:
            maps = {}
            for method in config.methods:
                for pr in pair_sets[p.name]:
                    if run.load_score(p.name, kind, method, pr.id) is not None:
                        continue
                    rec = run.load_map(method, pr.id)
                    if rec is not None:
                        maps[(method, pr.id)] = rec["p2p_21"]
            if not maps:
                continue
            say(f"scoring {len(maps)} map(s) under {p.name} with {kind} geodesics")
            t0 = time.perf_counter()
            scores = score_maps(collection, p, maps, geodesic=kind, n_jobs=config.jobs)
            for sc in scores:
                run.save_score(p.name, kind, sc.row(), sc.errors)
            say(f"  done in {time.perf_counter() - t0:.1f} s")


def resolve_protocols(config: BenchmarkConfig) -> list:
    """The configured protocols with the symmetric / geodesic overrides applied."""
    protocols = []
    for name in config.protocols:
        p = get_protocol(name)
        if config.symmetric is not None:
            p = p.with_options(symmetric=config.symmetric)
        if config.geodesics:
            p = p.with_options(geodesics=tuple(config.geodesics))
        protocols.append(p)
    return protocols


def build_summary(run: RunDir, config: BenchmarkConfig, protocols: list, pair_sets: dict) -> dict:
    """Aggregate stored maps and scores into ``summary.json`` and ``pairs.csv``."""

    class _Row:
        def __init__(self, d: dict) -> None:
            self.__dict__.update(d)

    out: dict[str, Any] = {"dataset": config.dataset, "resolution": config.resolution, "methods": {}}
    csv_rows = []
    for method in config.methods:
        mres = out["methods"].setdefault(method, {})
        for p in protocols:
            pairs = pair_sets[p.name]
            secs, mems, failed = [], [], []
            for pr in pairs:
                rec = run.load_map(method, pr.id)
                if rec is not None:
                    secs.append(rec["seconds"])
                    mems.append(rec["peak_rss_mb"])
                elif run.load_failure(method, pr.id) is not None:
                    failed.append(pr.id)
            block: dict[str, Any] = {
                "n_pairs_expected": len(pairs),
                "n_failed": len(failed),
                "failed_pairs": failed,
                "symmetric": p.symmetric,
                "seconds_per_pair_median": float(np.median(secs)) if secs else None,
                "seconds_per_pair_mean": float(np.mean(secs)) if secs else None,
                "seconds_total": float(np.sum(secs)) if secs else None,
                "peak_rss_mb": float(np.max(mems)) if mems else None,
                "mean_error": {},
                "geodesics": {},
            }
            for kind in p.geodesics:
                rows = []
                for pr in pairs:
                    r = run.load_score(p.name, kind, method, pr.id)
                    if r is None:
                        continue
                    rows.append(_Row(r))
                    rec = run.load_map(method, pr.id)
                    csv_rows.append({"protocol": p.name, **r, "seconds": rec["seconds"] if rec else None, "peak_rss_mb": rec["peak_rss_mb"] if rec else None, "status": "ok"})
                s = summarize(rows, p)  # type: ignore[arg-type]
                block["geodesics"][kind] = s
                block["mean_error"][kind] = s.get("mean_error")
            primary = block["geodesics"].get(p.geodesics[0], {})
            for k in ("n_pairs", "auc_mean", "auc_std", "auc_best", "auc_best_pair", "auc_worst", "auc_worst_pair", "area_matched", "excluded_fraction", "unmatched_fraction", "symmetric_fraction"):
                block[k] = primary.get(k)
            block["primary_geodesic"] = p.geodesics[0]
            mres[p.name] = block
            for pid in failed:
                fail = run.load_failure(method, pid) or {}
                csv_rows.append({"protocol": p.name, "method": method, "pair": pid, "status": "error", "error": fail.get("error")})
    run.write_pairs_csv(csv_rows)
    write_json(run.path / "summary.json", out)
    return out
