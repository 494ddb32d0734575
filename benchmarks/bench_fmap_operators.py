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

import numpy as np
from _common import median_seconds

from topomatch.maps.fmap import _orientation_factors, orientation_operators
from topomatch.matching.fmap import spectral_descriptors


def per_descriptor(vertices: np.ndarray, faces: np.ndarray, basis, descriptors: np.ndarray) -> np.ndarray:
    """The former formulation: the same per-face factors, one einsum and one product per descriptor (the baseline)."""
    rot, grad_phi, face_phi = _orientation_factors(vertices, faces, basis, descriptors)
    out = np.empty((descriptors.shape[1], basis.k, basis.k))
    for j in range(descriptors.shape[1]):
        out[j] = face_phi.T @ np.einsum("tc,tck->tk", rot[:, :, j], grad_phi)
    return out


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
        t_old, o_old = median_seconds(per_descriptor, args.repeat, *inputs)
        t_new, o_new = median_seconds(orientation_operators, args.repeat, *inputs)
        diff = float(np.abs(o_new - o_old).max() / np.abs(o_old).max())
        print(f"{name:>8} {len(mesh.faces):>7} {t_old:>17.3f} {t_new:>10.3f} {t_old / t_new:>6.2f} {diff:>13.1e}")


if __name__ == "__main__":
    main()
