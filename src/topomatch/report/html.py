"""The single-file HTML report: tables, figures and an interactive WebGL correspondence viewer.

The page works offline: the figures are embedded PNGs (base64) and the viewer is a small
self-written WebGL program (``assets/viewer.js``) reading mesh and map data embedded in
the page as zlib-compressed, base64-encoded little-endian arrays (decompressed in the
browser with the standard ``DecompressionStream``). Nothing is fetched from a network.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import zlib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from topomatch.report.results import Series

__all__ = ["ViewerData", "encode_array", "render_html", "viewer_data"]

logger = logging.getLogger(__name__)

ERROR_UNIT = 1e-4
"""Per-vertex errors are embedded as uint16 multiples of this (65535 = not scored)."""


def encode_array(a: np.ndarray) -> dict[str, Any]:
    """Encode a little-endian array as ``{"dtype", "n", "z"}`` (zlib, then base64).

    ``dtype`` is one of ``f4``, ``u2``, ``u4``, ``i4``.
    """
    dt = np.dtype(a.dtype).newbyteorder("<")
    code = {"f4": "f4", "u2": "u2", "u4": "u4", "i4": "i4"}.get(dt.str[1:])
    if code is None:
        raise TypeError(f"cannot embed an array of dtype {a.dtype}; use float32, uint16, uint32 or int32")
    raw = np.ascontiguousarray(a, dtype=dt).tobytes()
    return {"dtype": code, "n": int(a.size), "z": base64.b64encode(zlib.compress(raw, 6)).decode("ascii")}


def _encode_map(p2p: np.ndarray, n_source: int) -> dict[str, Any]:
    p = np.asarray(p2p, dtype=np.int64)
    if n_source < 65535:
        return encode_array(np.where(p < 0, 65535, p).astype(np.uint16))
    return encode_array(p.astype(np.int32))


def _encode_errors(err: np.ndarray) -> dict[str, Any]:
    e = np.asarray(err, dtype=np.float64)
    q = np.where(np.isnan(e), 65535, np.clip(np.round(e / ERROR_UNIT), 0, 65534))
    return encode_array(q.astype(np.uint16))


def _blob_size(b: dict[str, Any]) -> int:
    return len(b["z"]) + 40


@dataclass
class ViewerData:
    """What the viewer embeds, and what it had to leave out.

    Attributes
    ----------
    data : dict
        JSON-ready; ``groups`` with shapes, methods and per-pair blobs.
    n_pairs : int
        (method, pair) maps embedded.
    omitted : dict
        Group -> number of pairs left out to respect the size budget.
    bytes : int
        Size of the embedded blobs (base64 characters).
    """

    data: dict[str, Any]
    n_pairs: int = 0
    omitted: dict[str, int] = field(default_factory=dict)
    bytes: int = 0


def _order_pairs(pairs: list[str], firsts: list[str]) -> list[str]:
    """Put the best and worst pair of each method first, then the others in order."""
    return list(dict.fromkeys([*firsts, *pairs]))


def viewer_data(series: list[Series], protocols: dict[str, str], *, max_bytes: int = 60_000_000) -> ViewerData:
    """Collect meshes, maps and per-vertex errors of every group for the viewer.

    Parameters
    ----------
    series : list of Series
    protocols : dict
        Group -> the protocol whose pairs the viewer shows.
    max_bytes : int
        Budget for the embedded data. The best and worst pair of every method are
        always embedded; the other pairs follow in order while the budget lasts.
        Meshes are never decimated. Pairs left out are
        counted in :attr:`ViewerData.omitted` (and said in the page).

    Returns
    -------
    ViewerData
    """
    out = ViewerData({"groups": [], "error_unit": ERROR_UNIT})
    for group, protocol in protocols.items():
        ss = [s for s in series if s.group == group and s.run.pairs(protocol, s.method)]
        if not ss:
            continue
        try:
            collections = {id(s.run): s.run.collection for s in ss}
        except (ValueError, FileNotFoundError) as err:
            logger.warning("viewer: %s skipped: %s", group, err)
            out.omitted[group] = -1
            continue
        per_method = {}
        firsts: list[str] = []
        for s in ss:
            _, _, ps, aucs = s.run.curves(protocol, s.method)
            per_method[s.label] = (ps, aucs)
            if ps:
                b, w = s.run.best_worst(protocol, s.method, ps, aucs)
                firsts += [ps[b], ps[w]]
        all_pairs = sorted({p for ps, _ in per_method.values() for p in ps})
        shapes: dict[str, Any] = {}
        methods = [
            {
                "label": s.label,
                "method": s.method,
                "uses_ground_truth": s.uses_ground_truth,
                "geodesic": s.run.primary_geodesic(protocol),
                "auc_mean": float(np.nanmean(per_method[s.label][1])) if len(per_method[s.label][1]) else None,
                "pairs": {},
            }
            for s in ss
        ]
        kept: list[str] = []
        for pid in _order_pairs(all_pairs, firsts):
            target_name, source_name = pid.split("-", 1)
            add_shapes, add_pairs, size = {}, [], 0
            for name in (source_name, target_name):
                if name in shapes or name in add_shapes:
                    continue
                coll = collections[id(next(s for s in ss if pid in per_method[s.label][0]).run)]
                mesh = coll[name].mesh
                idx_dtype = np.uint16 if mesh.n_vertices < 65536 else np.uint32
                add_shapes[name] = {
                    "n_vertices": mesh.n_vertices,
                    "n_faces": mesh.n_faces,
                    "vertices": encode_array(np.asarray(mesh.vertices, dtype=np.float32)),
                    "faces": encode_array(np.asarray(mesh.faces).astype(idx_dtype)),
                }
                size += _blob_size(add_shapes[name]["vertices"]) + _blob_size(add_shapes[name]["faces"])
            n_source = (shapes.get(source_name) or add_shapes[source_name])["n_vertices"]
            for k, s in enumerate(ss):
                if pid not in per_method[s.label][0]:
                    continue
                p2p = s.run.load_map(s.method, pid)
                row = s.run.score(protocol, s.method, pid, with_errors=True)
                if p2p is None or row is None:
                    continue
                entry = {
                    "map": _encode_map(p2p, n_source),
                    "errors": _encode_errors(row["errors"]),
                    "auc": row.get("auc"),
                    "mean_error": row.get("mean_error"),
                    "area_matched": row.get("area_matched"),
                    "symmetric_used": bool(row.get("symmetric_used")),
                }
                size += _blob_size(entry["map"]) + _blob_size(entry["errors"])
                add_pairs.append((k, entry))
            if pid not in firsts and out.bytes + size > max_bytes:
                continue  # the best and worst pairs of every method are always in
            shapes.update(add_shapes)
            for k, entry in add_pairs:
                methods[k]["pairs"][pid] = entry
            out.bytes += size
            out.n_pairs += len(add_pairs)
            kept.append(pid)
        omitted = len(all_pairs) - len(kept)
        if omitted:
            out.omitted[group] = omitted
            logger.warning("viewer: %d of %d pairs of %s left out to stay under %.0f MB", omitted, len(all_pairs), group, max_bytes / 1e6)
        out.data["groups"].append(
            {"name": group, "protocol": protocol, "pairs": sorted(kept), "n_pairs_total": len(all_pairs), "shapes": shapes, "methods": methods}
        )
    return out


def _asset(name: str) -> str:
    return resources.files("topomatch.report").joinpath("assets", name).read_text(encoding="utf-8")


def _png_data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def _table_html(rows: list[dict[str, str]], bold: set[tuple[int, str]] | None = None) -> str:
    if not rows:
        return "<p>(no results)</p>"
    keys = list(dict.fromkeys(k for r in rows for k in r))
    bold = bold or set()
    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = []
    for i, r in enumerate(rows):
        cells = []
        for k in keys:
            v = html.escape(str(r.get(k, "")))
            cells.append(f"<td><b>{v}</b></td>" if (i, k) in bold else f"<td>{v}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f'<table class="results"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'


def render_html(
    *,
    title: str,
    runs: list[dict[str, Any]],
    table1: tuple[list[dict[str, str]], set[tuple[int, str]]],
    protocol_tables: list[tuple[str, list[dict[str, str]]]],
    figures: list[tuple[str, str, Path]],
    viewer: ViewerData | None,
    notes: list[str],
) -> str:
    """Assemble the report page as one string.

    Parameters
    ----------
    title : str
    runs : list of dict
        Per run: ``name``, ``path``, ``group``, ``config``, ``versions``, ``git_revision``.
    table1 : (rows, bold)
        From :func:`topomatch.evaluation.tables.track_rows`.
    protocol_tables : list of (caption, rows)
        Full per-protocol tables (:func:`topomatch.evaluation.tables.method_rows`).
    figures : list of (id, caption, png path)
    viewer : ViewerData or None
    notes : list of str
        Plain-text notes shown under the title (omissions, missing data...).
    """
    e = html.escape
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        '<link rel="icon" href="data:,">',
        f"<title>{e(title)}</title>",
        f"<style>{_asset('report.css')}</style>",
        "</head><body>",
        f"<h1>{e(title)}</h1>",
    ]
    if notes:
        parts.append('<ul class="notes">' + "".join(f"<li>{e(n)}</li>" for n in notes) + "</ul>")
    parts.append('<nav><a href="#table1">Table 1</a> <a href="#viewer">3D viewer</a> ' + " ".join(f'<a href="#{e(fid)}">{e(cap.split(":")[0])}</a>' for fid, cap, _ in figures) + ' <a href="#runs">Runs</a></nav>')
    parts.append('<section id="table1"><h2>Table 1: area matched, AUC, topkids25 error, time</h2>')
    parts.append(_table_html(*table1))
    parts.append(
        "<p class='caption'>% area matched and AUC under the shrec16 protocol (AUC normalised to [0, 1] over errors 0..0.25; best and worst pair by AUC); "
        "topkids25: mean error over all vertices of all pairs, x100, per geodesic kind (primary first); s/pair: median seconds per pair. "
        "Bold: best among methods that use no ground truth.</p></section>"
    )
    if viewer is not None and viewer.data["groups"]:
        parts.append(
            '<section id="viewer"><h2>Correspondence viewer</h2>'
            '<div class="controls">'
            '<label>data <select id="sel-group"></select></label> '
            '<label>method <select id="sel-method"></select></label> '
            '<label>pair <select id="sel-pair"></select></label> '
            '<button id="btn-best" type="button">best</button> <button id="btn-worst" type="button">worst</button> '
            '<label>colour <select id="sel-colour"><option value="corr">correspondence</option><option value="error">error on target</option><option value="coverage">coverage of source</option></select></label> '
            '<button id="btn-reset" type="button">reset view</button>'
            "</div>"
            '<div id="viewer-wrap"><canvas id="viewer-canvas"></canvas>'
            '<div class="vlabel" id="label-source"></div><div class="vlabel" id="label-target"></div>'
            '<div id="viewer-status">loading...</div></div>'
            '<div id="pick-info" data-side="" data-vertex="" data-match="">Click a point on either shape to see its match.</div>'
            '<div id="pair-info"></div>'
            "<p class='caption'>Left: the source (shape 1), painted with its normalised coordinates; right: the target (shape 2), each vertex "
            "painted with the colour of the source vertex the map sends it to (grey: unmatched). "
            "Drag to rotate, wheel to zoom, shift-drag (or right-drag) to pan, click to pick (yellow: the picked point; magenta: its match). "
            "Error colours: from 0 (dark purple) to 0.25 and above (yellow), grey = not scored (no ground truth, or unmatched). "
            "Coverage: source vertices that no target vertex reaches are grey (the track's % area matched counts the others).</p>"
            "</section>"
        )
        payload = json.dumps(viewer.data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
        parts.append(f'<script type="application/json" id="topomatch-data">{payload}</script>')
    for fid, caption, path in figures:
        parts.append(f'<section id="{e(fid)}"><h2>{e(caption)}</h2><img alt="{e(caption)}" src="{_png_data_uri(path)}"></section>')
    parts.append('<section id="runs"><h2>Runs</h2>')
    for cap, rows in protocol_tables:
        parts.append(f"<h3>{e(cap)}</h3>" + _table_html(rows))
    for r in runs:
        parts.append(
            f"<details><summary>{e(r['name'])} ({e(r['group'])})</summary><pre>{e(json.dumps({k: v for k, v in r.items() if k != 'name'}, indent=2, default=str))}</pre></details>"
        )
    parts.append("</section>")
    if viewer is not None and viewer.data["groups"]:
        parts.append(f"<script>{_asset('viewer.js')}</script>")
    parts.append("</body></html>")
    return "\n".join(parts)
