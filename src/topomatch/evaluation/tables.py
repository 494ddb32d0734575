"""Tables from a run's summary only (never recomputing): Markdown, CSV and LaTeX."""

from __future__ import annotations

import csv
import io
from typing import Any

__all__ = ["method_rows", "to_csv", "to_latex", "to_markdown"]


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
    (median), peak memory (MB).
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
                    "peak MB": _fmt(b.get("peak_rss_mb"), ".0f"),
                }
            )
    return rows


def to_markdown(rows: list[dict[str, str]]) -> str:
    """A GitHub-flavoured Markdown table."""
    if not rows:
        return "(no results)\n"
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


def to_latex(rows: list[dict[str, str]]) -> str:
    """A LaTeX ``tabular`` (booktabs)."""
    if not rows:
        return ""
    keys = list(rows[0])

    def esc(s: str) -> str:
        return str(s).replace("%", r"\%").replace("_", r"\_").replace("&", r"\&")

    lines = [r"\begin{tabular}{" + "l" * 2 + "r" * (len(keys) - 2) + "}", r"\toprule", " & ".join(esc(k) for k in keys) + r" \\", r"\midrule"]
    lines += [" & ".join(esc(r.get(k, "")) for k in keys) + r" \\" for r in rows]
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"
