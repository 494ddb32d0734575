"""Tables from a run's summary only (never recomputing): Markdown, CSV and LaTeX."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from typing import Any

__all__ = ["TRACK_COLUMNS", "method_rows", "to_csv", "to_latex", "to_markdown", "track_rows"]


def _fmt(v: Any, spec: str) -> str:
    if v is None:
        return "-"
    try:
        return format(v, spec)
    except (TypeError, ValueError):
        return str(v)


def method_rows(summary: dict, labels: dict[str, str] | None = None) -> list[dict[str, str]]:
    """One formatted row per method and protocol.

    Columns: method, protocol, pairs, % area matched, AUC avg / best / worst, mean
    error for each geodesic kind (x100 for topkids25), % excluded, seconds per pair
    (median, and mean: they differ for methods that reuse work across pairs, such as
    ``template``), peak memory (MB).
    """
    labels = labels or {}
    rows = []
    for method, protos in summary.get("methods", {}).items():
        for proto, b in protos.items():
            n = b.get("n_pairs") or 0
            exp = b.get("n_pairs_expected") or 0
            err = "; ".join(
                f"{k} {_fmt(v, '.2f' if proto == 'topkids25' else '.4f')}" for k, v in (b.get("mean_error") or {}).items()
            )
            rows.append(
                {
                    "method": labels.get(method, method),
                    "protocol": proto + ("" if b.get("symmetric") is None else (" (sym)" if b.get("symmetric") else "")),
                    "pairs": f"{n}/{exp}" + (f" ({b['n_failed']} failed)" if b.get("n_failed") else ""),
                    "area matched %": _fmt(None if b.get("area_matched") is None else 100 * b["area_matched"], ".2f"),
                    "AUC avg": _fmt(b.get("auc_mean"), ".3f"),
                    "AUC best": _fmt(b.get("auc_best"), ".3f"),
                    "AUC worst": _fmt(b.get("auc_worst"), ".3f"),
                    "mean error": (err + " (x100)" if err and proto == "topkids25" else err) or "-",
                    "excluded %": _fmt(None if b.get("excluded_fraction") is None else 100 * b["excluded_fraction"], ".1f"),
                    "s/pair": _fmt(b.get("seconds_per_pair_median"), ".2f"),
                    "s/pair mean": _fmt(b.get("seconds_per_pair_mean"), ".2f"),
                    "peak MB": _fmt(b.get("peak_rss_mb"), ".0f"),
                }
            )
    return rows


def _emphasise(rows: list[dict[str, str]], bold: set[tuple[int, str]] | None, fmt: str) -> list[dict[str, str]]:
    if not bold:
        return rows
    return [{k: (fmt.format(v) if (i, k) in bold else v) for k, v in r.items()} for i, r in enumerate(rows)]


def to_markdown(rows: list[dict[str, str]], bold: set[tuple[int, str]] | None = None) -> str:
    """Format a GitHub-flavoured Markdown table (cells ``(row index, column)`` in ``bold`` in bold)."""
    if not rows:
        return "(no results)\n"
    rows = _emphasise(rows, bold, "**{}**")
    keys: list[str] = []
    for r in rows:
        keys.extend(k for k in r if k not in keys)
    widths = {k: max(len(k), *(len(str(r.get(k, ""))) for r in rows)) for k in keys}
    head = "| " + " | ".join(k.ljust(widths[k]) for k in keys) + " |"
    sep = "|" + "|".join("-" * (widths[k] + 2) for k in keys) + "|"
    body = ["| " + " | ".join(str(r.get(k, "")).ljust(widths[k]) for k in keys) + " |" for r in rows]
    return "\n".join([head, sep, *body]) + "\n"


def to_csv(rows: list[dict[str, str]]) -> str:
    """CSV text."""
    if not rows:
        return ""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def to_latex(rows: list[dict[str, str]], bold: set[tuple[int, str]] | None = None) -> str:
    """Format a LaTeX ``tabular`` (booktabs; cells ``(row index, column)`` in ``bold`` in bold)."""
    if not rows:
        return ""
    keys = list(rows[0])
    bold = bold or set()

    def esc(s: str) -> str:
        return str(s).replace("%", r"\%").replace("_", r"\_").replace("&", r"\&")

    def cell(i: int, k: str) -> str:
        text = esc(rows[i].get(k, ""))
        return r"\textbf{" + text + "}" if (i, k) in bold else text

    lines = [r"\begin{tabular}{" + "l" * 2 + "r" * (len(keys) - 2) + "}", r"\toprule", " & ".join(esc(k) for k in keys) + r" \\", r"\midrule"]
    lines += [" & ".join(cell(i, k) for k in keys) + r" \\" for i in range(len(rows))]
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"


TRACK_COLUMNS = (
    "data",
    "method",
    "pairs",
    "area matched %",
    "AUC avg",
    "AUC best",
    "AUC worst",
    "best pair",
    "worst pair",
    "topkids25 error x100",
    "s/pair",
)
"""Columns of :func:`track_rows` (the track's Table 1 plus the topkids25 error and time)."""


def track_rows(entries: Sequence[tuple[str, str, dict, bool]]) -> tuple[list[dict[str, str]], set[tuple[int, str]]]:
    """Build the SHREC'16 track's Table 1, one row per (data, method), from run summaries only.

    Parameters
    ----------
    entries : sequence of (data label, method label, protocol blocks, uses ground truth)
        ``protocol blocks`` is ``summary["methods"][method]`` of a run: a dict from
        protocol name to its block. ``data label`` groups rows (e.g. ``"low res"``).

    Returns
    -------
    rows : list of dict
        Formatted cells keyed by :data:`TRACK_COLUMNS`. % area matched and the AUC
        columns come from the ``shrec16`` block (``-`` when absent); the topkids25
        column gives the pooled mean error x100 for each geodesic kind scored, the
        primary kind first; ``s/pair`` is the median seconds per pair.
    bold : set of (row index, column)
        The best value of each numeric column within each data label (largest area and
        AUC, smallest topkids25 error), among the methods that do not use ground truth,
        when at least two such rows compete.
    """
    rows: list[dict[str, str]] = []
    raw: list[dict[str, float | None]] = []
    for data, label, blocks, _gt in entries:
        s = blocks.get("shrec16") or {}
        t = blocks.get("topkids25") or {}
        timing = s or t
        errs = t.get("mean_error") or {}
        primary = t.get("primary_geodesic")
        order = sorted(errs, key=lambda k: k != primary)
        n = s.get("n_pairs") or 0
        exp = s.get("n_pairs_expected") or 0
        rows.append(
            {
                "data": data,
                "method": label,
                "pairs": f"{n}/{exp}" + (f" ({s['n_failed']} failed)" if s.get("n_failed") else "") if s else "-",
                "area matched %": _fmt(None if s.get("area_matched") is None else 100 * s["area_matched"], ".2f"),
                "AUC avg": _fmt(s.get("auc_mean"), ".3f"),
                "AUC best": _fmt(s.get("auc_best"), ".3f"),
                "AUC worst": _fmt(s.get("auc_worst"), ".3f"),
                "best pair": s.get("auc_best_pair") or "-",
                "worst pair": s.get("auc_worst_pair") or "-",
                "topkids25 error x100": "; ".join(f"{k} {_fmt(errs[k], '.2f')}" for k in order) or "-",
                "s/pair": _fmt(timing.get("seconds_per_pair_median"), ".2f"),
            }
        )
        raw.append(
            {
                "area matched %": s.get("area_matched"),
                "AUC avg": s.get("auc_mean"),
                "AUC best": s.get("auc_best"),
                "AUC worst": s.get("auc_worst"),
                "topkids25 error x100": None if primary is None else -errs.get(primary) if errs.get(primary) is not None else None,
            }
        )
    bold: set[tuple[int, str]] = set()
    for data in dict.fromkeys(e[0] for e in entries):
        idx = [i for i, e in enumerate(entries) if e[0] == data and not e[3]]
        if len(idx) < 2:
            continue
        for col in raw[0] if raw else ():
            vals = [(raw[i][col], i) for i in idx if raw[i][col] is not None]
            if len(vals) < 2:
                continue
            best = max(v for v, _ in vals)
            bold.update((i, col) for v, i in vals if v == best)
    return rows, bold
