"""The cost of ``template``'s map repairs: ``maps.symmetry.flip_mirror_patches`` and ``maps.patches.fill_small_patches``.

For each target, the template (the collection's null shape) is put in the target's pose
from the ground truth (``pose_from_ground_truth``) and the map is read off it with
``map_from_deformed``, the step the repair follows in ``template``. Patches of that map are
then sent to the mirror side (``--patches`` discs of ``--radius`` sqrt(area) on parts far
from the symmetry plane, about the size of the exchanges the repair finds on kid13 and
kid14) and the repairs are run on the damaged map, as ``template`` runs them (the mirror repair, then the
filling of small islands on its output). Printed per target: vertex count, milliseconds of
the read-off and of each repair (median of ``--repeat``), the filling also without its
duplicate test (``duplicate=0``, attempt #112) and the test's cost as a ratio to that, the two repairs' ratio to the
read-off, and how many of the damaged vertices the mirror repair restored. A damaged patch that touches the part it was
mirrored onto (where the target's hands or a hand and a leg are fused) joins the rest of
the map through the contact and is not restored: the limit attempt #109 describes for
kid13.

    python benchmarks/bench_mirror_patches.py [--data DATA] [--resolution low] [kid13 kid14 ...] [--repeat 5]

Without ``--data`` (or ``$TOPOMATCH_DATA``) the built-in shapes syn01-syn03 are used.
"""

from __future__ import annotations

import argparse
import os
from functools import partial

import numpy as np
from _common import median_seconds

from topomatch.datasets.builtin import builtin_benchmark
from topomatch.datasets.topkids import load_topkids
from topomatch.maps.patches import fill_small_patches
from topomatch.maps.symmetry import flip_mirror_patches
from topomatch.matching.deform import map_from_deformed
from topomatch.matching.template import pose_from_ground_truth
from topomatch.mesh import TriangleMesh


def _damage(p2p: np.ndarray, target: TriangleMesh, template: TriangleMesh, sym: np.ndarray, n_patches: int, radius: float, rng: np.random.Generator) -> np.ndarray:
    """Mirror ``n_patches`` Euclidean discs of the target, on parts far from the symmetry plane.

    A disc keeps the vertices whose template image lies at least 0.3 sqrt(area) from its
    mirror vertex (a hand, a foot, a limb; near the plane a mirrored vertex is no exchange).
    """
    out = p2p.copy()
    V, W = target.vertices, template.vertices
    far = (sym[p2p] >= 0) & (np.linalg.norm(W[p2p] - W[np.maximum(sym[p2p], 0)], axis=1) > 0.3 * np.sqrt(template.area))
    damaged = np.zeros(len(V), bool)
    for c in rng.choice(np.flatnonzero(far), size=n_patches, replace=False):
        damaged |= far & (np.linalg.norm(V - V[c], axis=1) < radius * np.sqrt(target.area))
    out[damaged] = sym[p2p[damaged]]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("targets", nargs="*", help="target shapes (default: kid13 kid14 kid05 with data, syn01-syn03 without)")
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--resolution", default="low", choices=["low", "high"])
    ap.add_argument("--patches", type=int, default=2)
    ap.add_argument("--radius", type=float, default=0.05)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    coll = load_topkids(args.data, args.resolution) if args.data else builtin_benchmark()
    targets = args.targets or (["kid13", "kid14", "kid05"] if args.data else ["syn01", "syn02", "syn03"])
    ref = coll[coll.reference]
    if ref.sym is None:
        ap.error(f"{ref.name} has no symmetry map")
    template, sym = ref.mesh, ref.sym
    rng = np.random.default_rng(0)
    print(f"{'target':>8} {'vertices':>9} {'read-off ms':>12} {'mirror ms':>10} {'fill ms':>8} {'no-dup ms':>10} {'dup x':>6} {'ratio':>6} {'restored':>14}")
    for name in targets:
        shape = coll[name]
        posed = pose_from_ground_truth(template, shape)
        t_read, p2p = median_seconds(map_from_deformed, args.repeat, shape.mesh, posed, template.faces)
        damaged = _damage(p2p, shape.mesh, template, sym, args.patches, args.radius, rng)
        t_fix, (fixed, _) = median_seconds(flip_mirror_patches, args.repeat, damaged, shape.mesh.faces, template.vertices, template.faces, sym)
        t_fill, _ = median_seconds(fill_small_patches, args.repeat, fixed, shape.mesh.vertices, shape.mesh.faces, template.vertices, template.faces)
        t_all, _ = median_seconds(partial(fill_small_patches, duplicate=0.0), args.repeat, fixed, shape.mesh.vertices, shape.mesh.faces, template.vertices, template.faces)
        hit = damaged != p2p
        restored = int(np.sum(fixed[hit] == p2p[hit]))
        ratio = (t_fix + t_fill) / t_read
        print(f"{name:>8} {shape.mesh.n_vertices:>9} {1e3 * t_read:>12.1f} {1e3 * t_fix:>10.1f} {1e3 * t_fill:>8.1f} {1e3 * t_all:>10.1f} {t_fill / t_all:>6.2f} {ratio:>6.2f} {restored:>6} / {int(hit.sum()):<6}")


if __name__ == "__main__":
    main()
