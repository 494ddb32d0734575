"""Ground-truth validity of a noisy set made from clean shapes in vertex correspondence.

Usage
-----
    python benchmarks/gt_validity.py --data SYNTH_DIR --null NULL.off POSE1.off POSE2.off ...

``SYNTH_DIR`` is what ``topomatch noise NULL POSE1 POSE2 ... --out SYNTH_DIR`` wrote
(kid01 = POSE1, ...). The clean poses share the null shape's connectivity, so the true
position in the pose of any point of the null shape is known exactly: a kid00 vertex
is located on the clean null mesh (closest point, barycentric) and carried to the pose
with the same barycentric weights. For every vertex v of kidNN the error of its
transferred ground truth g = ref(v) is |pose(g) - v| / sqrt(area(kidNN)), reported for
reliable vertices (away from merged regions: _indmap 0) and for unreliable ones, next to
the floor that any vertex-to-vertex ground truth has at this resolution (distance from
v to the nearest carried kid00 vertex).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

from topomatch.datasets._surface import SurfaceLocator
from topomatch.datasets.topkids import load_topkids
from topomatch.mesh import TriangleMesh


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True)
    p.add_argument("--null", required=True)
    p.add_argument("poses", nargs="+")
    args = p.parse_args()
    coll = load_topkids(args.data, "low")
    null = TriangleMesh.from_file(args.null)
    kid00 = coll["kid00"].mesh
    face, bary, dist = SurfaceLocator(null.vertices, null.faces).query(kid00.vertices)
    print(f"kid00 vertices off the clean null surface: median {np.median(dist) / np.sqrt(null.area):.2e} sqrt(area)")
    rel_all, unrel_all, floor_all = [], [], []
    print("| shape | reliable median | reliable p95 | reliable max | unreliable median | unreliable p95 | floor median | floor p95 | % vertices unreliable |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i, path in enumerate(args.poses):
        name = f"kid{i + 1:02d}"
        s = coll[name]
        pose = TriangleMesh.from_file(path)
        if not np.array_equal(pose.faces, null.faces):
            raise SystemExit(f"{path}: connectivity differs from the null shape")
        carried = np.einsum("ij,ijk->ik", bary, pose.vertices[null.faces[face]])  # kid00 vertices in this pose
        scale = np.sqrt(s.mesh.area)
        err = np.linalg.norm(carried[s.ref_p2p] - s.mesh.vertices, axis=1) / scale
        floor, _ = cKDTree(carried).query(s.mesh.vertices)
        floor /= scale
        u = s.unreliable if s.unreliable is not None else np.zeros(s.n_vertices, bool)
        r = ~u
        rel_all.append(err[r])
        unrel_all.append(err[u])
        floor_all.append(floor[r])
        q = lambda a, k: float(np.percentile(a, k)) if len(a) else float("nan")  # noqa: E731
        print(
            f"| {name} | {q(err[r], 50):.4f} | {q(err[r], 95):.4f} | {err[r].max():.4f} | {q(err[u], 50):.4f} | {q(err[u], 95):.4f} | "
            f"{q(floor[r], 50):.4f} | {q(floor[r], 95):.4f} | {100 * u.mean():.1f} |"
        )
    a, b, c = np.concatenate(rel_all), np.concatenate(unrel_all), np.concatenate(floor_all)
    print(
        f"| all | {np.median(a):.4f} | {np.percentile(a, 95):.4f} | {a.max():.4f} | {np.median(b):.4f} | {np.percentile(b, 95):.4f} | "
        f"{np.median(c):.4f} | {np.percentile(c, 95):.4f} | {100 * len(b) / (len(a) + len(b)):.1f} |"
    )


if __name__ == "__main__":
    main()
