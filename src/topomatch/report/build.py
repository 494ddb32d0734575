"""``build_report``: every figure, table and the HTML page from run directories."""

from __future__ import annotations

import logging
import os
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from topomatch.evaluation.rundir import write_json
from topomatch.evaluation.tables import method_rows, to_csv, to_latex, to_markdown, track_rows
from topomatch.report.render import View
from topomatch.report.results import RunResults, Series, collect_series
from topomatch.typing import PathType

__all__ = ["build_report"]

logger = logging.getLogger(__name__)

PROTOCOL_ORDER = ("shrec16", "topkids25")


def _slug(s: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", s.lower()).strip("-") or "data"


def _protocols(runs: list[RunResults]) -> list[str]:
    names = list(dict.fromkeys(p for r in runs for p in r.protocols))
    return sorted(names, key=lambda p: (PROTOCOL_ORDER.index(p) if p in PROTOCOL_ORDER else len(PROTOCOL_ORDER), p))


def _main_protocol(series: list[Series], group: str, protocols: list[str]) -> str | None:
    for p in protocols:
        if any(s.group == group and s.run.pairs(p, s.method) for s in series):
            return p
    return None


def build_report(
    runs: list[PathType],
    out_dir: PathType,
    *,
    renderings: bool = True,
    html: bool = True,
    view: View | None = None,
    max_html_mb: float = 60.0,
) -> Path:
    """Write the track's figures and table and the HTML report for one or more runs.

    Reads only what the runs stored (manifest, summary, per-pair scores with per-vertex
    errors, maps); meshes are reloaded from the data the manifest names, for the
    renderings and the viewer. Nothing is matched or scored again.

    Parameters
    ----------
    runs : list of path
        Run directories written by ``topomatch bench`` or ``topomatch evaluate``. Runs
        on different data (low / high res) become side-by-side panels.
    out_dir : path
        Created if missing. Receives ``table1.{md,csv,tex}``, ``curves_<protocol>.png``
        (Fig. 6), ``breakdown_<protocol>.png`` (Fig. 7), ``pairs_<data>.png`` (Fig. 4 / 5),
        ``report.html`` and ``report.json`` (what was written, with timings).
    renderings : bool
        Render the best and worst pairs (needs the meshes).
    html : bool
        Write ``report.html``.
    view : View, optional
        Camera of the renderings (default: front view, z up).
    max_html_mb : float
        Budget for the mesh and map data embedded in the HTML viewer; pairs beyond it
        are left out (best and worst pairs first), never decimated, and the page says so.

    Returns
    -------
    Path
        ``report.html`` (or ``table1.md`` when ``html=False``).
    """
    t_start = time.perf_counter()
    if isinstance(runs, (str, os.PathLike)):
        raise TypeError("runs must be a list of run directories, not a single path")
    if not runs:
        raise ValueError("build_report needs at least one run directory")
    results = [RunResults.load(r) for r in runs]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    series = collect_series(results)
    protocols = _protocols(results)
    groups = list(dict.fromkeys(s.group for s in series))
    index: dict[str, Any] = {"runs": [str(r.path) for r in results], "files": {}, "seconds": {}, "notes": []}
    notes: list[str] = index["notes"]

    # Table 1 -------------------------------------------------------------------------
    t0 = time.perf_counter()
    entries = [(s.group, s.label, s.run.summary["methods"].get(s.method, {}), s.uses_ground_truth) for s in series]
    rows, bold = track_rows(entries)
    (out / "table1.md").write_text(to_markdown(rows, bold))
    (out / "table1.csv").write_text(to_csv(rows))
    (out / "table1.tex").write_text(to_latex(rows, bold))
    index["files"]["table1"] = ["table1.md", "table1.csv", "table1.tex"]
    protocol_tables = []
    for r in results:
        labels = {s.method: s.label for s in series if s.run is r}
        protocol_tables.append((f"{r.path.name} ({r.group}): every protocol", method_rows(r.summary, labels)))
    index["seconds"]["tables"] = time.perf_counter() - t0

    # curves --------------------------------------------------------------------------
    from topomatch.report.figures import plot_breakdown, plot_curves, plot_pairs

    figures: list[tuple[str, str, Path]] = []
    t0 = time.perf_counter()
    for p in protocols:
        f6 = plot_curves(series, p, out / f"curves_{p}.png")
        if f6:
            figures.append((f"fig-curves-{p}", f"Fig. 6 ({p}): cumulative error curves, mean over pairs", f6))
        f7 = plot_breakdown(series, p, out / f"breakdown_{p}.png")
        if f7:
            figures.append((f"fig-breakdown-{p}", f"Fig. 7 ({p}): per method, mean +-1 std, best and worst pair", f7))
    index["seconds"]["curves"] = time.perf_counter() - t0

    # renderings ----------------------------------------------------------------------
    main = {g: _main_protocol(series, g, protocols) for g in groups}
    render_times: list[float] = []
    if renderings:
        t0 = time.perf_counter()
        for g in groups:
            p = main[g]
            if p is None:
                continue
            try:
                path, secs = plot_pairs(series, p, g, out / f"pairs_{_slug(g)}.png", view=view)
            except (ValueError, FileNotFoundError, KeyError) as err:
                notes.append(f"renderings of {g} skipped: {err}")
                logger.warning("renderings of %s skipped: %s", g, err)
                continue
            if path:
                fig_no = {"high res": "Fig. 4", "low res": "Fig. 5"}.get(g, "Fig. 4/5")
                figures.append((f"fig-pairs-{_slug(g)}", f"{fig_no} ({g}): best and worst pair of each method", path))
                render_times += secs
        index["seconds"]["renderings"] = time.perf_counter() - t0
        if render_times:
            index["seconds"]["per_mesh_rendering_median"] = float(np.median(render_times))
            index["n_mesh_renderings"] = len(render_times)
    index["files"]["figures"] = [p.name for _, _, p in figures]

    # HTML ----------------------------------------------------------------------------
    result = out / "table1.md"
    if html:
        from topomatch.report.html import render_html, viewer_data

        t0 = time.perf_counter()
        viewer = None
        vp = {g: p for g, p in main.items() if p is not None}
        try:
            viewer = viewer_data(series, vp, max_bytes=int(max_html_mb * 1e6))
        except (ValueError, FileNotFoundError, KeyError) as err:
            notes.append(f"3D viewer left out: {err}")
            logger.warning("3D viewer left out: %s", err)
        if viewer is not None:
            for g, n in viewer.omitted.items():
                notes.append(
                    f"3D viewer, {g}: meshes not available, no pairs embedded" if n < 0
                    else f"3D viewer, {g}: {n} pairs not embedded to keep the page under {max_html_mb:.0f} MB of data (best and worst pairs of each method are always in)"
                )
            index["viewer"] = {"pairs_embedded": viewer.n_pairs, "data_bytes": viewer.bytes, "omitted": viewer.omitted}
        index["seconds"]["viewer_data"] = time.perf_counter() - t0
        run_info = [
            {
                "name": r.path.name,
                "path": str(r.path),
                "group": r.group,
                "config": r.config,
                "protocols": r.manifest.get("protocols"),
                "versions": r.manifest.get("versions"),
                "git_revision": r.manifest.get("git_revision"),
                "started": r.manifest.get("started"),
                "finished": r.manifest.get("finished"),
            }
            for r in results
        ]
        title = "topomatch report: " + ", ".join(f"{r.path.name} ({r.group})" for r in results)
        page = render_html(
            title=title, runs=run_info, table1=(rows, bold), protocol_tables=protocol_tables,
            figures=figures, viewer=viewer, notes=notes,
        )
        result = out / "report.html"
        tmp = result.with_name(f".{result.name}.{os.getpid()}.tmp")
        tmp.write_text(page, encoding="utf-8")
        os.replace(tmp, result)
        index["files"]["html"] = result.name
        index["html_bytes"] = result.stat().st_size
    index["seconds"]["total"] = time.perf_counter() - t_start
    write_json(out / "report.json", index)
    logger.info("report written to %s in %.1f s", out, index["seconds"]["total"])
    return result
