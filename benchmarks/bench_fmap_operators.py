"""The orientation operators of the functional-map energy: all descriptors in one product against one per descriptor.

``topomatch.maps.fmap.orientation_operators`` builds, for each descriptor, the
operator ``g -> <n x grad d, grad g>`` in the reduced basis. It used to loop over the
descriptors (an ``einsum`` over the faces and one ``k x n_faces x k`` product each);
it now forms the derivatives of all descriptors in one batched product per chunk of
faces. This script times both in the same run on the settings ``deform`` uses (HKS,
20 operator descriptors, k = 50) on the built-in shapes, or on TOPKIDS shapes with
``--data``, and checks that they agree. Prints medians of ``--repeat`` runs and the
ratio.

    python benchmarks/bench_fmap_operators.py [--data DATA] [--shapes kid00 kid13] [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from topomatch.maps.fmap import orientation_operators
from topomatch.matching.fmap import spectral_descriptors
from topomatch.mesh.geometry import face_normals
from topomatch.mesh.laplacian import gradient_operator


def per_descriptor(vertices: np.ndarray, faces: np.ndarray, basis, descriptors: np.ndarray) -> np.ndarray:
    """The former formulation: one einsum and one product per descriptor (the baseline)."""
    G, areas = gradient_operator(vertices, faces)
    scale = 1.0 / np.sqrt(areas.sum())
    nf = len(faces)
    grad_phi = (G @ basis.evecs).reshape(nf, 3, -1) / scale
    grad_d = (G @ descriptors).reshape(nf, 3, -1) / scale
    rot = np.cross(face_normals(vertices, faces)[:, :, None], grad_d, axis=1)
    face_phi = basis.evecs[faces].mean(axis=1) * areas[:, None]
    out = np.empty((descriptors.shape[1], basis.k, basis.k))
    for j in range(descriptors.shape[1]):
        out[j] = face_phi.T @ np.einsum("tc,tck->tk", rot[:, :, j], grad_phi)
    return out


def _median(fn, repeat: int, *args) -> tuple[float, np.ndarray]:
    times, res = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = fn(*args)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--shapes", nargs="+", default=None, help="TOPKIDS low-res shapes (default kid00 kid13) or built-in ones")
    ap.add_argument("--k", type=int, default=50)
    ap.add_argument("--descriptors", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    if args.data:
        from topomatch.datasets.topkids import load_topkids

        shapes = load_topkids(args.data, "low")
        names = args.shapes or ["kid00", "kid13"]
    else:
        from topomatch.datasets.builtin import builtin_benchmark

        shapes = builtin_benchmark()
        names = args.shapes or ["syn00", "syn05"]
    print(f"{'shape':>8} {'faces':>7} {'per-descriptor s':>17} {'batched s':>10} {'ratio':>6} {'max rel diff':>13}")
    for name in names:
        mesh = shapes[name].mesh
        basis = mesh.eigenbasis(100).truncate(args.k)
        d = spectral_descriptors(mesh, "hks", 100, 100)
        d = d[:, np.unique(np.linspace(0, d.shape[1] - 1, args.descriptors).round().astype(int))]
        inputs = (mesh.vertices, mesh.faces, basis, d)
        t_old, o_old = _median(per_descriptor, args.repeat, *inputs)
        t_new, o_new = _median(orientation_operators, args.repeat, *inputs)
        diff = float(np.abs(o_new - o_old).max() / np.abs(o_old).max())
        print(f"{name:>8} {len(mesh.faces):>7} {t_old:>17.3f} {t_new:>10.3f} {t_old / t_new:>6.2f} {diff:>13.1e}")


if __name__ == "__main__":
    main()
