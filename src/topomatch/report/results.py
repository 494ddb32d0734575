"""What a report reads: run directories, never recomputing a match or a score.

A :class:`RunResults` wraps one run directory (``manifest.json``, ``summary.json``,
``scores/...`` and ``maps/...``) and a list of them becomes :class:`Series`, one per
(run, method), grouped by data (``"low res"``, ``"high res"``, ``"builtin"``...).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from topomatch.evaluation.rundir import RunDir
from topomatch.typing import FloatArray, IndexArray, PathType

__all__ = ["RunResults", "Series", "collect_series"]

logger = logging.getLogger(__name__)


@dataclass
class RunResults:
    """The stored results of one run directory.

    Attributes
    ----------
    path : Path
    manifest : dict
    summary : dict
    """

    path: Path
    manifest: dict
    summary: dict
    _curves: dict = field(default_factory=dict, init=False, repr=False)

    @classmethod
    def load(cls, path: PathType) -> RunResults:
        """Read a run directory; ``ValueError`` when it holds no finished run."""
        p = Path(path)
        if not p.is_dir():
            raise ValueError(f"{p}: not a run directory (no such folder)")
        run = RunDir(p)
        manifest = run.manifest()
        summary = run.summary()
        if manifest is None or summary is None:
            missing = [n for n, v in (("manifest.json", manifest), ("summary.json", summary)) if v is None]
            raise ValueError(f"{p}: not a finished run directory ({', '.join(missing)} missing); run 'topomatch bench' first")
        if not isinstance(summary.get("methods"), dict):
            raise ValueError(f"{p}/summary.json: expected a 'methods' table")
        return cls(p, manifest, summary)

    @property
    def rundir(self) -> RunDir:
        """The :class:`~topomatch.evaluation.rundir.RunDir` reader."""
        return RunDir(self.path)

    @property
    def config(self) -> dict:
        """The benchmark configuration stored in the manifest."""
        return dict(self.manifest.get("config") or {})

    @property
    def dataset(self) -> str:
        """``"builtin"``, ``"topkids"`` or what the run names."""
        return str(self.config.get("dataset") or self.summary.get("dataset") or "unknown")

    @property
    def resolution(self) -> str:
        """``"low"`` or ``"high"``."""
        return str(self.config.get("resolution") or self.summary.get("resolution") or "low")

    @property
    def group(self) -> str:
        """Label of the data the run was made on: ``"low res"``, ``"high res"``, ``"builtin"``."""
        if self.dataset == "topkids":
            return f"{self.resolution} res"
        if self.dataset == "builtin":
            return "builtin"
        return f"{self.dataset} {self.resolution}"

    @property
    def methods(self) -> list[str]:
        """Methods in the summary, in run order."""
        return list(self.summary["methods"])

    @property
    def protocols(self) -> list[str]:
        """Protocols scored in the run."""
        names: list[str] = []
        for blocks in self.summary["methods"].values():
            names.extend(p for p in blocks if p not in names)
        return names

    def block(self, method: str, protocol: str) -> dict:
        """Return the summary block of ``method`` under ``protocol`` (empty if absent)."""
        return dict(self.summary["methods"].get(method, {}).get(protocol) or {})

    def primary_geodesic(self, protocol: str) -> str | None:
        """Return the geodesic kind whose scores the protocol reports first."""
        for m in self.methods:
            g = self.block(m, protocol).get("primary_geodesic")
            if g:
                return str(g)
        geos = (self.manifest.get("protocols") or {}).get(protocol, {}).get("geodesics") or []
        return geos[0] if geos else None

    def uses_ground_truth(self, method: str) -> bool:
        """Whether the manifest flags ``method`` as using ground truth at test time."""
        return bool(((self.manifest.get("methods") or {}).get(method) or {}).get("uses_ground_truth"))

    def pairs(self, protocol: str, method: str, geodesic: str | None = None) -> list[str]:
        """Pair ids with a stored score, sorted."""
        geodesic = geodesic or self.primary_geodesic(protocol)
        if geodesic is None:
            return []
        d = self.path / "scores" / protocol / geodesic / method
        return sorted(p.name[:-4] for p in d.glob("*.npz")) if d.is_dir() else []

    def score(self, protocol: str, method: str, pair: str, *, geodesic: str | None = None, with_errors: bool = False) -> dict | None:
        """Read a stored score row (with the per-vertex ``errors`` when asked)."""
        geodesic = geodesic or self.primary_geodesic(protocol)
        if geodesic is None:
            return None
        return self.rundir.load_score(protocol, geodesic, method, pair, with_errors=with_errors)

    def curves(self, protocol: str, method: str) -> tuple[FloatArray, FloatArray, list[str], FloatArray]:
        """Per-pair cumulative curves of ``method`` under the primary geodesic.

        Returns
        -------
        thresholds : ndarray, shape (n_thresholds,)
        curves : ndarray, shape (n_pairs, n_thresholds)
            Fraction of scored vertices with error ``<= t``, as stored.
        pairs : list of str
        aucs : ndarray, shape (n_pairs,)
        """
        key = (protocol, method)
        if key in self._curves:
            return self._curves[key]
        if not self.pairs(protocol, method):  # this run did not score the protocol
            return np.zeros(0), np.zeros((0, 0)), [], np.zeros(0)
        t = self.thresholds(protocol)
        pairs, curves, aucs = [], [], []
        for pid in self.pairs(protocol, method):
            row = self.score(protocol, method, pid)
            if row is None or not row.get("curve"):
                continue
            c = np.array([np.nan if v is None else v for v in row["curve"]], dtype=np.float64)
            if len(c) != len(t):
                raise ValueError(f"{self.path}: {method} {pid} has a curve of {len(c)} points for {len(t)} thresholds")
            pairs.append(pid)
            curves.append(c)
            aucs.append(np.nan if row.get("auc") is None else float(row["auc"]))
        out = (t, np.array(curves).reshape(len(curves), len(t)), pairs, np.array(aucs, dtype=np.float64))
        self._curves[key] = out
        return out

    def best_worst(self, protocol: str, method: str, pairs: list[str], aucs: FloatArray) -> tuple[int, int]:
        """Return indices (into ``pairs``) of the best and worst pair: as the summary names them, else by AUC."""
        from topomatch.report.figures import best_worst

        b, w = best_worst(pairs, aucs)
        blk = self.block(method, protocol)
        named = blk.get("auc_best_pair"), blk.get("auc_worst_pair")
        if named[0] in pairs:
            b = pairs.index(named[0])
        if named[1] in pairs:
            w = pairs.index(named[1])
        return b, w

    def thresholds(self, protocol: str) -> FloatArray:
        """Return the curve thresholds of ``protocol`` in this run."""
        t = (self.manifest.get("protocols") or {}).get(protocol, {}).get("thresholds")
        if not t:
            for m in self.methods:
                t = (self.block(m, protocol).get("geodesics") or {}).get(self.primary_geodesic(protocol) or "", {}).get("thresholds")
                if t:
                    break
        if not t:
            raise ValueError(f"{self.path}: no thresholds stored for protocol {protocol!r}")
        return np.asarray(t, dtype=np.float64)

    def load_map(self, method: str, pair: str) -> IndexArray | None:
        """Read the stored ``p2p_21`` of ``method`` on ``pair``, shape (n_target,), or ``None``."""
        rec = self.rundir.load_map(method, pair)
        return None if rec is None else np.asarray(rec["p2p_21"], dtype=np.int64)

    @cached_property
    def collection(self) -> Any:
        """The shape collection the run was made on (reloaded from the manifest's config)."""
        from topomatch.evaluation.benchmark import BenchmarkConfig, load_collection

        cfg = self.config
        known = set(BenchmarkConfig.__dataclass_fields__)
        config = BenchmarkConfig(**{k: v for k, v in cfg.items() if k in known})
        if config.dataset == "topkids" and config.data_dir and not Path(config.data_dir).is_dir():
            raise ValueError(
                f"{self.path}: the run's data folder {config.data_dir} is not here; renderings need the meshes"
            )
        return load_collection(config)


@dataclass
class Series:
    """One method of one run, as drawn in figures and listed in tables.

    Attributes
    ----------
    run : RunResults
    method : str
    label : str
        Display label (ground-truth use and, when two runs of the same data share a
        method name, the run folder are added).
    group : str
        Data label (``"low res"``...).
    uses_ground_truth : bool
    """

    run: RunResults
    method: str
    label: str
    group: str
    uses_ground_truth: bool


def _gt_note(method: str) -> str:
    try:
        from topomatch.matching import MATCHERS
    except ImportError:  # pragma: no cover - matching always importable in the package
        return "uses ground truth"
    cls = MATCHERS.get(method)
    return cls.ground_truth_note if cls is not None else "uses ground truth"


def collect_series(runs: list[RunResults]) -> list[Series]:
    """One :class:`Series` per (run, method), with unambiguous labels, grouped by data."""
    out: list[Series] = []
    seen: dict[tuple[str, str], int] = {}
    for r in runs:
        for m in r.methods:
            seen[(r.group, m)] = seen.get((r.group, m), 0) + 1
    for r in runs:
        for m in r.methods:
            gt = r.uses_ground_truth(m)
            label = m + (f" [{r.path.name}]" if seen[(r.group, m)] > 1 else "")
            if gt:
                label += f" ({_gt_note(m)})"
            out.append(Series(r, m, label, r.group, gt))
    order = list(dict.fromkeys(r.group for r in runs))
    out.sort(key=lambda s: order.index(s.group))
    return out
