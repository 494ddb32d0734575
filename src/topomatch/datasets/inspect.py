"""Describe a data directory: what is present, what is missing, what each shape is like."""

from __future__ import annotations

from typing import Any

import numpy as np

from topomatch.datasets.topkids import load_topkids, locate_topkids, resolve_data_dir
from topomatch.typing import PathType

__all__ = ["data_report", "format_report"]


def data_report(data: PathType | None, resolution: str = "both", *, check: bool = False) -> tuple[dict[str, Any], bool]:
    """Per-shape counts, topology and ground-truth coverage.

    With ``check=True`` every file is parsed (errors are collected, not raised).

    Returns
    -------
    report : dict
    ok : bool
        False when any file failed to parse (``check``) or nothing was found.
    """
    root = resolve_data_dir(data)
    if root is None:
        raise FileNotFoundError("no data directory: pass --data DIR or set TOPOMATCH_DATA")
    out: dict[str, Any] = {"root": str(root), "resolutions": {}}
    ok = True
    found = False
    for res in (["low", "high"] if resolution == "both" else [resolution]):
        if locate_topkids(root, res) is None:  # type: ignore[arg-type]
            out["resolutions"][res] = {"found": False}
            continue
        found = True
        coll = load_topkids(root, res)  # type: ignore[arg-type]
        shapes = {}
        for name in coll.names:
            try:
                s = coll[name]
            except (ValueError, OSError) as err:
                ok = False
                shapes[name] = {"error": str(err)}
                continue
            info = s.mesh.summary()
            if s.ref is not None:
                info["ref_coverage"] = float(np.mean(np.diff(s.ref.tocsr().indptr) > 0))
                info["ref_many"] = int(np.sum(np.diff(s.ref.tocsr().indptr) > 1))
            info["sym_coverage"] = None if s.sym is None else float(np.mean(s.sym >= 0))
            info["unreliable_fraction"] = None if s.unreliable is None else float(np.mean(s.unreliable))
            shapes[name] = info
            if not check:
                coll.forget(name)
        out["resolutions"][res] = {"found": True, "path": str(coll.root), "layout": "release" if (coll.root and coll.root.name.endswith("_res")) else "learning", "shapes": shapes, "missing": coll.missing}
    return out, ok and found


def format_report(report: dict[str, Any]) -> str:
    """Plain-text rendering of :func:`data_report`."""
    lines = [f"data: {report['root']}"]
    for res, r in report["resolutions"].items():
        if not r.get("found"):
            lines.append(f"\n{res} res: not found")
            continue
        lines.append(f"\n{res} res: {r['path']} ({len(r['shapes'])} shapes)")
        lines.append(f"  {'shape':6} {'verts':>6} {'faces':>7} {'comp':>4} {'holes':>5} {'genus':>5} {'nm-edges':>8} {'gt%':>6} {'sym%':>6} {'unrel%':>6}")
        for name, s in r["shapes"].items():
            if "error" in s:
                lines.append(f"  {name:6} ERROR {s['error']}")
                continue

            def pct(v: float | None) -> str:
                return "-" if v is None else f"{100 * v:.1f}"

            lines.append(
                f"  {name:6} {s['n_vertices']:>6} {s['n_faces']:>7} {s['n_components']:>4} {s['n_boundary_loops']:>5} {s['genus']:>5} "
                f"{s['non_manifold_edges']:>8} {pct(s.get('ref_coverage')):>6} {pct(s.get('sym_coverage')):>6} {pct(s.get('unreliable_fraction')):>6}"
            )
        for m in r["missing"]:
            lines.append(f"  missing: {m}")
    return "\n".join(lines) + "\n"
