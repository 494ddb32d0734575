"""The registration's compiled steps against the numpy and SciPy formulas they replaced.

One coarse registration of ``kid00`` onto ``--target`` (150 nodes, 1,500 samples: the
verification's) and one fine registration after it (500 nodes, every vertex) give two
realistic states and their closest-point pairs; on each, the rotation step, the
position step and the deformed vertices are timed as the library computes them
(compiled, :mod:`topomatch._kernels`) and as the reference formulas do
(:mod:`topomatch.deform._reference`, the library's code before session 49), medians of
``--repeat``. Then both ways step one copy of the state ``--steps`` times on one
thread, and two copies side by side on two threads (one BLAS thread each), as the
verifications do: the compiled steps release the GIL. Printed: milliseconds per step, the ratios, the
largest difference between the two results.

    python benchmarks/bench_register_steps.py [--data DATA] [--target kid05] [--repeat 20] [--steps 40]

Without ``--data`` the built-in pair syn00 -> syn05 is used.
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from _common import median_seconds
from scipy.spatial import cKDTree

from topomatch._blas import one_blas_thread
from topomatch.deform import _reference as ref
from topomatch.deform.register import (
    DataPairs,
    GraphDeformation,
    RegistrationSchedule,
    closest_pairs,
    register,
)
from topomatch.mesh import TriangleMesh
from topomatch.mesh.geometry import vertex_normals
from topomatch.mesh.sampling import farthest_point_sampling


def _states(source: TriangleMesh, target: TriangleMesh) -> list[tuple[str, GraphDeformation, DataPairs, float]]:
    """(name, state, its closest-point pairs, mu_plane) after a coarse and after a fine registration."""
    _, j = cKDTree(target.vertices).query(source.vertices)
    src = np.arange(0, source.n_vertices, 7)
    init = DataPairs(src, target.vertices[j[src]], np.zeros((len(src), 3)), np.ones(len(src)))
    sched = RegistrationSchedule(n_nodes=150, n_samples=1500, icp_iterations=25)
    coarse = register(source.vertices, source.faces, target.vertices, target.faces, init, sched)
    fine = register(source.vertices, source.faces, target.vertices, target.faces, None,
                    RegistrationSchedule(n_nodes=500, icp_iterations=10), start=coarse.deformed)
    Nt = vertex_normals(target.vertices, target.faces)
    tree = cKDTree(target.vertices)
    out = []
    for name, r, subset in (("coarse (150 nodes, 1,500 samples)", coarse, 1500), ("fine (500 nodes, every vertex)", fine, None)):
        D = r.deformation
        Vd = D.deformed()
        s_src = t_src = None
        if subset:
            s_src = farthest_point_sampling(subset, points=source.vertices, first=0)
            t_src = farthest_point_sampling(subset, points=target.vertices, first=0)
        pairs = closest_pairs(Vd, vertex_normals(Vd, source.faces), target.vertices, Nt, tree, sigma=0.02 * np.sqrt(source.area),
                              source_subset=s_src, target_subset=t_src)
        out.append((name, D, pairs, 1.0))
    return out


def _bench_state(name: str, D: GraphDeformation, pairs: DataPairs, mu_plane: float, repeat: int, n_steps: int) -> None:
    """Time the three steps both ways on one state, alone and then on two threads side by side."""
    # np.copy keeps the rotations' layout (stored transposed: the layout einsum adds them in as before)
    keep = (np.copy(D.rotations), np.copy(D.positions))
    alpha = 0.1

    def rot_lib() -> np.ndarray:
        D.update_rotations(pairs)
        out = D.rotations
        D.rotations = keep[0]
        return out

    def pos_lib() -> np.ndarray:
        D.update_positions(pairs, alpha=alpha, mu_point=0.1, mu_plane=mu_plane)
        out = D.positions
        D.positions = keep[1]
        return out

    steps = [
        ("rotation step", lambda: ref.rotations(D, pairs), rot_lib),
        ("position step", lambda: ref.position_step(D, pairs, alpha=alpha, mu_point=0.1, mu_plane=mu_plane), pos_lib),
        ("deformed", lambda: ref.deformed(D), D.deformed),
    ]
    for step, fn_ref, fn_lib in steps:
        diff = float(np.abs(np.asarray(fn_ref()) - np.asarray(fn_lib())).max())
        t_ref, t_lib = (1e3 * median_seconds(fn, repeat)[0] for fn in (fn_ref, fn_lib))
        print(f"{name:36s} {step:16s} {t_ref:12.3f} {t_lib:12.3f} {t_lib / t_ref:7.3f} {diff:10.1e}")

    def run(C: GraphDeformation, compiled: bool) -> None:
        """``n_steps`` rotation, position and deformed-vertex steps on ``C``."""
        for _ in range(n_steps):
            if compiled:
                C.update_rotations(pairs)
                C.update_positions(pairs, alpha=alpha, mu_point=0.1, mu_plane=mu_plane)
                C.deformed()
            else:
                C.rotations = ref.rotations(C, pairs)
                C.positions = ref.position_step(C, pairs, alpha=alpha, mu_point=0.1, mu_plane=mu_plane)
                ref.deformed(C)

    copies = [GraphDeformation(D.vertices, D.faces, D.graph) for _ in range(2)]
    for C in copies:
        C.link_scale = D.link_scale.copy()
    walls = {}
    for compiled in (False, True):
        for C in copies:
            C.rotations, C.positions = np.copy(keep[0]), np.copy(keep[1])
        with one_blas_thread():
            t0 = time.perf_counter()
            run(copies[0], compiled)
            one = time.perf_counter() - t0
        for C in copies:
            C.rotations, C.positions = np.copy(keep[0]), np.copy(keep[1])
        with one_blas_thread(), ThreadPoolExecutor(2) as pool:  # as the verifications run
            t0 = time.perf_counter()
            list(pool.map(run, copies, [compiled] * 2))
            two = time.perf_counter() - t0
        walls[compiled] = (one, two)
    (r1, r2), (c1, c2) = walls[False], walls[True]
    print(f"{name:36s} {'2 threads':16s} {'reference':>12s} {'compiled':>12s}   (wall of {n_steps} steps per thread; "
          f"one thread alone: {1e3 * r1 / n_steps:.2f} / {1e3 * c1 / n_steps:.2f} ms per step)")
    print(f"{'':36s} {'':16s} {r2:11.2f}s {c2:11.2f}s {c2 / r2:7.3f}   two threads' speed-up over one: x{2 * r1 / r2:.2f} / x{2 * c1 / c2:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--target", default="kid05")
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--steps", type=int, default=40, help="steps per thread in the two-thread rows")
    args = ap.parse_args()
    if args.data:
        from topomatch.datasets.topkids import load_topkids

        coll = load_topkids(args.data, "low")
        pair, label = (coll["kid00"].mesh, coll[args.target].mesh), f"kid00 -> {args.target}"
    else:
        from topomatch.datasets.builtin import builtin_benchmark

        coll = builtin_benchmark()
        pair, label = (coll["syn00"].mesh, coll["syn05"].mesh), "syn00 -> syn05 (built-in)"
    source, target = (TriangleMesh(m.vertices.copy(), m.faces.copy()) for m in pair)
    print(f"{label}: {source.n_vertices} -> {target.n_vertices} vertices; {os.cpu_count()} CPUs; one thread: medians of {args.repeat}")
    print(f"{'state':36s} {'step':16s} {'reference ms':>12s} {'compiled ms':>12s} {'ratio':>7s} {'max |diff|':>10s}")
    for name, D, pairs, mu_plane in _states(source, target):
        _bench_state(name, D, pairs, mu_plane, args.repeat, args.steps)

if __name__ == "__main__":
    main()
