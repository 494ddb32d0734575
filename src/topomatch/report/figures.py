"""The track's figures from stored results: curves (Fig. 6, 7) and pair renderings (Fig. 4, 5).

Every function reads :class:`~topomatch.report.results.Series` (stored scores and maps)
and writes a PNG; nothing is matched or scored again. matplotlib is imported inside the
functions, never at module import, and used without pyplot (no global state, no backend
switch in the caller's session).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from topomatch.report.colors import position_colors, transfer_colors
from topomatch.report.render import View, projected_size, render_mesh
from topomatch.report.results import Series
from topomatch.typing import FloatArray

__all__ = ["PairPick", "best_worst", "plot_breakdown", "plot_curves", "plot_pairs"]

logger = logging.getLogger(__name__)


def _figure(nrows: int, ncols: int, figsize: tuple[float, float], dpi: int) -> tuple[Any, Any]:
    """Make a figure and its axes grid without pyplot: no global state, no backend switch."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    return fig, fig.subplots(nrows, ncols, squeeze=False)


def _groups(series: list[Series]) -> list[str]:
    return list(dict.fromkeys(s.group for s in series))


def _style(ax: Any, protocol: str, thresholds: FloatArray) -> None:
    ax.set_xlim(thresholds[0], thresholds[-1])
    ax.set_ylim(-1.5, 101.5)  # a curve at 0 % or 100 % stays visible
    ax.set_xlabel("geodesic error (fraction of sqrt(area))")
    ax.set_ylabel("% correspondences")
    ax.grid(True, alpha=0.3, linewidth=0.5)


def plot_curves(series: list[Series], protocol: str, path: Path) -> Path | None:
    """Fig. 6: the mean cumulative curve of every method, one panel per data group.

    Parameters
    ----------
    series : list of Series
    protocol : str
        ``"shrec16"`` or ``"topkids25"``; series without scores under it are skipped.
    path : Path
        PNG to write.

    Returns
    -------
    Path or None
        ``None`` when no series has scores under ``protocol``.
    """
    groups = [g for g in _groups(series) if any(s.group == g and s.run.pairs(protocol, s.method) for s in series)]
    if not groups:
        return None
    fig, axes = _figure(1, len(groups), (max(6.4, 5.2 * len(groups)), 4.2), 110)
    for ax, g in zip(axes[0], groups):
        geos = set()
        for s in series:
            if s.group != g:
                continue
            t, curves, pairs, aucs = s.run.curves(protocol, s.method)
            if not pairs:
                continue
            geos.add(s.run.primary_geodesic(protocol))
            mean = np.nanmean(curves, axis=0)
            ax.plot(t, 100 * mean, linewidth=1.8, linestyle="--" if s.uses_ground_truth else "-",
                    label=f"{s.label}: AUC {np.nanmean(aucs):.3f} ({len(pairs)} pairs)")
            _style(ax, protocol, t)
        ax.set_title(f"{g} ({protocol}, {', '.join(sorted(geos))} geodesics)", fontsize=10)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle("Cumulative error curves, mean over pairs", fontsize=11)
    fig.tight_layout()
    fig.savefig(path)
    return path


def plot_breakdown(series: list[Series], protocol: str, path: Path) -> Path | None:
    """Fig. 7: per method, the mean curve with +-1 std shading, the best and the worst pair.

    One row per method, one column per data group.

    Returns
    -------
    Path or None
        ``None`` when no series has scores under ``protocol``.
    """
    groups = _groups(series)
    labels = list(dict.fromkeys(s.label for s in series if s.run.pairs(protocol, s.method)))
    if not labels:
        return None
    fig, axes = _figure(len(labels), len(groups), (max(6.4, 4.6 * len(groups)), 0.4 + 3.2 * len(labels)), 110)
    for i, label in enumerate(labels):
        for j, g in enumerate(groups):
            ax = axes[i][j]
            s = next((x for x in series if x.label == label and x.group == g), None)
            if s is None or not s.run.pairs(protocol, s.method):
                ax.set_axis_off()
                ax.text(0.5, 0.5, f"{label}\nnot run on {g}", ha="center", va="center", fontsize=8, transform=ax.transAxes)
                continue
            t, curves, pairs, aucs = s.run.curves(protocol, s.method)
            mean, std = np.nanmean(curves, axis=0), np.nanstd(curves, axis=0)
            b, w = s.run.best_worst(protocol, s.method, pairs, aucs)
            ax.fill_between(t, 100 * np.clip(mean - std, 0, 1), 100 * np.clip(mean + std, 0, 1), color="0.6", alpha=0.35, linewidth=0, label="+-1 std")
            ax.plot(t, 100 * curves[b], color="tab:blue", linewidth=1.4, label=f"best {pairs[b]} (AUC {aucs[b]:.3f})")
            ax.plot(t, 100 * curves[w], color="tab:red", linewidth=1.4, label=f"worst {pairs[w]} (AUC {aucs[w]:.3f})")
            ax.plot(t, 100 * mean, color="black", linewidth=1.8, label=f"mean of {len(pairs)} (AUC {np.nanmean(aucs):.3f})")
            _style(ax, protocol, t)
            ax.set_title(f"{label} - {g}", fontsize=9)
            ax.legend(fontsize=6.5, loc="best")
    fig.suptitle(f"Per-method breakdown ({protocol}): mean, best and worst pair", fontsize=11)
    fig.tight_layout()
    fig.savefig(path)
    return path


def best_worst(pairs: list[str], aucs: FloatArray) -> tuple[int, int]:
    """Return the indices of the best and the worst pair by AUC (first of ties, as the summary)."""
    a = np.asarray(aucs, dtype=np.float64)
    if a.size == 0:
        raise ValueError("no pairs to choose from")
    b = int(np.argmax(np.where(np.isnan(a), -np.inf, a)))
    w = int(np.argmin(np.where(np.isnan(a), np.inf, a)))
    return b, w


@dataclass
class PairPick:
    """A pair chosen for a rendering."""

    kind: str  # "best" or "worst"
    pair: str
    auc: float


def _picks(s: Series, protocol: str) -> list[PairPick]:
    _, _, pairs, aucs = s.run.curves(protocol, s.method)
    if not pairs:
        return []
    b, w = s.run.best_worst(protocol, s.method, pairs, aucs)
    picks = [PairPick("best", pairs[b], float(aucs[b]))]
    if w != b:
        picks.append(PairPick("worst", pairs[w], float(aucs[w])))
    return picks


def plot_pairs(series: list[Series], protocol: str, group: str, path: Path, *, view: View | None = None, dpi: int = 110) -> tuple[Path | None, list[float]]:
    """Fig. 4 / 5: the best and the worst pair of every method of one data group, rendered.

    Each row is a method; the columns are the best pair (source, target) and the worst
    pair (source, target). The source is painted with :func:`position_colors`, the
    target through the stored map (grey where unmatched).

    Returns
    -------
    path : Path or None
        ``None`` when the group has no scored pair or its meshes cannot be loaded.
    seconds : list of float
        Time of each mesh rendering (preparation plus its share of the final save).
    """
    rows = [(s, _picks(s, protocol)) for s in series if s.group == group]
    rows = [(s, p) for s, p in rows if p]
    if not rows:
        return None, []
    view = view or View()
    fig, axes = _figure(len(rows), 4, (11.0, 3.5 * len(rows)), dpi)
    prep: list[float] = []
    for i, (s, picks) in enumerate(rows):
        coll = s.run.collection
        names = [n for pk in picks for n in pk.pair.split("-", 1)]
        sizes = np.array([projected_size(coll[n].mesh.vertices, view) for n in names])
        size = (float(sizes[:, 0].max()), float(sizes[:, 1].max()))  # one scale per row
        for j, pk in enumerate(picks):
            target_name, source_name = pk.pair.split("-", 1)
            p2p = s.run.load_map(s.method, pk.pair)
            src, tgt = coll[source_name].mesh, coll[target_name].mesh
            if p2p is None or len(p2p) != tgt.n_vertices:
                for ax in axes[i][2 * j : 2 * j + 2]:
                    ax.set_axis_off()
                    ax.text(0.5, 0.5, f"map of {pk.pair} missing", ha="center", transform=ax.transAxes, fontsize=8)
                continue
            src_rgb, tgt_rgb = transfer_colors(p2p, position_colors(src.vertices), fade_unhit=False)
            head = f"{pk.kind} {pk.pair} (AUC {pk.auc:.3f})"
            prep.append(render_mesh(axes[i][2 * j], src.vertices, src.faces, src_rgb, view, title=f"{head}\nsource {source_name}", size=size))
            prep.append(render_mesh(axes[i][2 * j + 1], tgt.vertices, tgt.faces, tgt_rgb, view, title=f"target {target_name}", size=size))
        if len(picks) == 1:
            for ax in axes[i][2:]:
                ax.set_axis_off()
            axes[i][2].text(1.0, 0.5, "the summary names the same\npair as best and worst", ha="center", va="center", fontsize=8, transform=axes[i][2].transAxes)
        axes[i][0].text(-0.08, 0.5, s.label, rotation=90, ha="right", va="center", fontsize=9, transform=axes[i][0].transAxes)
    fig.suptitle(f"Best and worst pairs, {group} ({protocol}): corresponding points share a colour, grey = unmatched", fontsize=10)
    fig.tight_layout()
    t0 = time.perf_counter()
    fig.savefig(path)
    save = time.perf_counter() - t0
    n = max(len(prep), 1)
    return path, [p + save / n for p in prep]
