"""Time the report: one mesh rendering at low and high res, and a whole report for a run.

Usage::

    python benchmarks/bench_report.py [--data DIR] [--run RUN ...] [--repeat 5]

1. One mesh rendering (``topomatch.report.render.save_rendering``: projection, depth
   sort, shading and the PNG) on a TOPKIDS low-res (~10K vertices) and high-res (~60K)
   shape, against the baseline of a matplotlib ``PolyCollection`` of the same shaded
   triangles (the approach measured in reference/dependencies.md), timed in the same run.
   Medians over ``--repeat`` runs.
2. ``build_report`` for each ``--run`` (e.g. a 90-pair low-res shrec16 run): total time,
   its parts, and the HTML file size.

Without the data, part 1 uses the built-in shapes (2.5K vertices) and says so.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _polycollection_png(path, vertices, faces, colors, view) -> float:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from topomatch.report.render import project, shade_vertices

    t0 = time.perf_counter()
    xy, depth = project(vertices, view)
    order = np.argsort(depth[faces].mean(axis=1))
    fo = faces[order]
    fc = shade_vertices(vertices, faces, colors, view)[fo].mean(axis=1)
    fig, ax = plt.subplots(figsize=(3, 4), dpi=120)
    ax.add_collection(PolyCollection(xy[fo], facecolors=fc, edgecolors="none", antialiaseds=False))
    ax.set_xlim(xy[:, 0].min(), xy[:, 0].max())
    ax.set_ylim(xy[:, 1].min(), xy[:, 1].max())
    ax.set_aspect("equal")
    ax.set_axis_off()
    fig.savefig(path)
    plt.close(fig)
    return time.perf_counter() - t0


def bench_rendering(data: str | None, repeat: int) -> None:
    from topomatch.report.colors import position_colors
    from topomatch.report.render import View, save_rendering

    shapes = []
    if data and Path(data, "topkids", "low_res", "kid16.off").is_file():
        from topomatch.datasets.topkids import load_topkids

        shapes.append(("low res kid16", load_topkids(data, "low")["kid16"].mesh))
        if Path(data, "topkids", "high_res", "kid01.off").is_file():
            shapes.append(("high res kid01", load_topkids(data, "high")["kid01"].mesh))
    else:
        from topomatch.datasets.builtin import builtin_benchmark

        print("no TOPKIDS data: timing the built-in shape only")
        shapes.append(("builtin syn05", builtin_benchmark()["syn05"].mesh))
    view = View()
    with tempfile.TemporaryDirectory() as tmp:
        m0 = shapes[0][1]  # warm-up: matplotlib import, fonts, first figure
        save_rendering(Path(tmp, "w.png"), m0.vertices, m0.faces, position_colors(m0.vertices), view)
        _polycollection_png(Path(tmp, "w.png"), np.asarray(m0.vertices), np.asarray(m0.faces), position_colors(m0.vertices), view)
        for label, mesh in shapes:
            v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
            col = position_colors(v)
            ours = [save_rendering(Path(tmp, "a.png"), v, f, col, view) for _ in range(repeat)]
            base = [_polycollection_png(Path(tmp, "b.png"), v, f, col, view) for _ in range(repeat)]
            mo, mb = statistics.median(ours), statistics.median(base)
            print(
                f"{label:16s} {mesh.n_vertices:6d} vertices {mesh.n_faces:6d} faces: "
                f"gouraud {mo:.3f} s, PolyCollection baseline {mb:.3f} s, ratio {mb / mo:.1f}x (medians of {repeat})"
            )


def bench_report(runs: list[str]) -> None:
    from topomatch.report import build_report

    for run in runs:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            html = build_report([run], Path(tmp) / "report")
            total = time.perf_counter() - t0
            index = json.loads((Path(tmp) / "report" / "report.json").read_text())
            parts = ", ".join(f"{k} {v:.2f}" for k, v in index["seconds"].items() if k != "total")
            print(f"report of {run}: {total:.1f} s ({parts}); report.html {html.stat().st_size / 1e6:.1f} MB, "
                  f"{index.get('viewer', {}).get('pairs_embedded')} maps embedded")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--run", action="append", default=[])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    bench_rendering(args.data, args.repeat)
    bench_report(args.run)


if __name__ == "__main__":
    main()
