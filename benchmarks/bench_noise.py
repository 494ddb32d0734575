"""Speed of the topological-noise generator and of the built-in benchmark's generation.

Usage
-----
    python benchmarks/bench_noise.py [--data DIR] [--repeats 3]

Prints median wall times of each stage for one pose of the procedural figure at the
built-in resolution (5,000 vertices) and, with ``--data`` (folder holding kids/), for a
clean KIDS pose at 10,000 vertices; the baseline measured in the same run is one
Laplacian eigenbasis (k = 100) of the output mesh, what the default matcher spends per
shape. Then the whole built-in benchmark with 1 and 2 worker processes, and the
one-off numba compilation of the generator's kernels (in a fresh process with an
empty numba cache).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def median_time(fn, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return float(np.median(out))


def stages(vertices, faces, rest, params, repeats, area=None):
    from topomatch.datasets import noise as nz
    from topomatch.datasets._isosurface import marching_tetrahedra
    from topomatch.datasets._surface import (
        HoleCaps,
        SurfaceLocator,
        decimate,
        keep_largest_component,
        relax_onto,
    )
    from topomatch.mesh import TriangleMesh

    caps = HoleCaps.build(faces, len(vertices))
    vx = caps.extend(vertices)
    fx = np.concatenate([faces, caps.faces])
    area = area or TriangleMesh(vertices, faces).area
    p = params.resolved(area)
    res = {}
    field = {}

    def f_field():
        field["f"], field["o"] = nz.solid_field(vx, fx, voxel_size=p["voxel_size"], merge_distance=p["merge_distance"])

    res["inside/outside field"] = median_time(f_field, repeats)

    def f_mt():
        v, f = marching_tetrahedra(field["f"], field["o"], p["voxel_size"])
        field["fine"] = keep_largest_component(v, f)

    res["marching tetrahedra"] = median_time(f_mt, repeats)
    fine_v, fine_f = field["fine"]

    def f_dec():
        field["dec"] = decimate(fine_v, fine_f, params.n_vertices)

    res["decimation"] = median_time(f_dec, repeats)
    v, f = field["dec"]
    res["relaxation"] = median_time(lambda: relax_onto(v, f, SurfaceLocator(fine_v, fine_f, k=4), params.relax_iterations), repeats)
    res["ground-truth query"] = median_time(lambda: SurfaceLocator(vx, fx).query(v), repeats)
    out = {}

    def full():
        out["r"] = nz.topological_noise(vertices, faces, params, caps=caps, clean_area=area, rest_vertices=rest)

    res["topological_noise (total)"] = median_time(full, repeats)
    m = out["r"].mesh
    res["baseline: eigenbasis k=100 of the output"] = median_time(lambda: TriangleMesh(m.vertices, m.faces).eigenbasis(100), repeats)
    return res, len(fine_v), m.n_vertices


def show(title, res, fine, n):
    base = res["baseline: eigenbasis k=100 of the output"]
    print(f"\n{title} (fine surface {fine} vertices -> {n} vertices)")
    print(f"  {'stage':45} {'median s':>9} {'x baseline':>10}")
    for k, t in res.items():
        print(f"  {k:45} {t:9.3f} {t / base:10.2f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", help="folder holding kids/0001.null.0.off etc.")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-cold", action="store_true", help="skip the cold-compile measurement")
    args = ap.parse_args()
    from topomatch.datasets import builtin
    from topomatch.datasets.figure import build_figure
    from topomatch.datasets.noise import NoiseParams

    t0 = time.perf_counter()
    fig = build_figure(10_000)
    print(f"figure template (10,000 vertices): {time.perf_counter() - t0:.2f} s")
    res, fine, n = stages(fig.pose("arms_crossed"), fig.mesh.faces, fig.mesh.vertices, NoiseParams(n_vertices=5000), args.repeats, fig.mesh.area)
    show("figure pose 'arms_crossed' at 5,000 vertices", res, fine, n)
    if args.data:
        from topomatch.mesh import TriangleMesh

        k = Path(args.data) / "kids"
        null = TriangleMesh.from_file(k / "0001.null.0.off")
        pose = TriangleMesh.from_file(k / "0001.isometry.15.off")
        res, fine, n = stages(pose.vertices, pose.faces, null.vertices, NoiseParams(), max(1, args.repeats - 1), null.area)
        show("KIDS 0001.isometry.15 at 10,000 vertices", res, fine, n)
    print("\nbuilt-in benchmark (10 poses + null, no cache):")
    for jobs in (1, 2):
        builtin._MEMO.clear()
        t0 = time.perf_counter()
        builtin._generate(5000, 0, jobs)
        print(f"  n_jobs={jobs}: {time.perf_counter() - t0:.1f} s")
    if not args.skip_cold:
        code = (
            "import time, numpy as np; t=time.perf_counter();"
            "from topomatch.datasets.toy import icosphere; from topomatch.datasets._surface import SurfaceLocator, decimate;"
            "s=icosphere(2); SurfaceLocator(s.vertices, s.faces).query(np.zeros((2,3))); decimate(s.vertices, s.faces, 100);"
            "print(time.perf_counter()-t)"
        )
        with tempfile.TemporaryDirectory() as tmp:
            env = dict(os.environ, NUMBA_CACHE_DIR=tmp)
            cold = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout)
            warm = float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout)
        print(f"\nnumba kernels, first use in a fresh process: cold cache {cold:.1f} s, warm cache {warm:.1f} s")


if __name__ == "__main__":
    main()
