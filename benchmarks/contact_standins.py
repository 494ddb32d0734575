"""A held-out set of contact poses: TOPKIDS training poses with a hand moved onto a leg and fused there.

kid16, the worst TOPKIDS test shape for ``template``, rests a hand on a raised knee, and the
fusion there lets the template's forearm take the shin (``docs/flagship.md``, session 42). No
training shape has a hand fused to a leg, so a change aimed at such contacts could only be
judged on the test split. This script makes shapes that have one, from the training split only:

1. **Pose.** Each clean KIDS pose ``kids/0001.isometry.i.off`` (the pose of TOPKIDS ``kid_i``,
   i = 1..15, before the outer-hull step; same connectivity as ``kids/0001.null.0.off``)
   with one hand moved onto a knee, a thigh or a shin of either leg. The arm is a
   two-joint chain (shoulder, elbow) cut from the rest pose (a T-pose: arms along x, z up)
   with linear-blend weights: the elbow bends until the palm can reach the contact, then
   the arm swings about the shoulder onto it. The contact is the point of the leg's ring
   that lies farthest towards the palm (``palm`` approach) or the shoulder (``shoulder``
   approach), lifted by 1.5 % of sqrt(area) so that the palm sinks into the leg. A pose is
   kept when the arm reaches (the contact no farther from the shoulder than the arm is
   long), the palm ends within 1 % of the leg, less than 5 % of the forearm comes within
   1 % of the rest of the body, and the palm moved at least 3 %.
2. **Noise.** The outer-hull step of ``topomatch noise`` (``topological_noise``, 12,000
   vertices, seed 0) fuses the palm into the leg; its ground truth (each output vertex's
   point on the clean posed mesh, carried to the rest pose) goes to the nearest vertex of
   TOPKIDS ``kid00``; unreliable vertices and the capped eyes and mouth are not scored.
3. **Frame.** The shape is moved into TOPKIDS' frame by the rigid motion that takes the
   clean pose onto ``kid_i`` (fitted on ``kid_i``'s ground truth).
4. **Match.** Each method is fitted on ``kid00`` and the training split *without* ``kid_i``
   (the benchmark's leave-one-out), and maps the shape to ``kid00``. The error is the mean
   Euclidean distance on ``kid00`` (a T-pose, so a limb mapped onto another limb is far
   from its truth) between each scored vertex's image and its truth, x100 over
   sqrt(area of kid00). ``--control`` also scores the clean poses through the same steps.

The first method is the baseline: the script prints each method's mean, median and worst
error, the shapes above 5, and against the baseline the shapes better or worse by more than
0.5, with the median seconds per shape.

    python benchmarks/contact_standins.py --data DATA --methods template,template@ch \\
        --param 'template@ch.deform={"pose_challengers": 3}' --json RUNS/standins.jsonl
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from _common import emit_row
from scipy.spatial import cKDTree

from topomatch.cli.main import _parse_params
from topomatch.datasets.base import ShapeCollection
from topomatch.datasets.figure import _align
from topomatch.datasets.noise import NoiseParams, topological_noise
from topomatch.datasets.topkids import load_topkids
from topomatch.io import read_mesh
from topomatch.matching import make_matcher
from topomatch.mesh import TriangleMesh
from topomatch.mesh.geometry import axis_rotation

#: Leg rings (rest-pose height of the null shape's leg, KIDS units): where a hand is put.
PLACES = {"thigh": -15.0, "knee": -27.0, "shin": -37.0}


def _smoothstep(t: np.ndarray, a: float, b: float) -> np.ndarray:
    u = np.clip((t - a) / (b - a), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


class KidsArm:
    """One arm of the KIDS null shape (a T-pose): blend weights and landmark rings, from rest coordinates.

    ``side`` is +1 for the arm along +x, -1 for the other. Thresholds are KIDS units
    (the shoulders end at |x| ~ 10, the elbows at ~ 25, the palms at 38-44).
    """

    def __init__(self, rest: np.ndarray, side: int) -> None:
        a = side * rest[:, 0]
        upper = rest[:, 2] > 10.0
        self.w_shoulder = _smoothstep(a, 10.0, 14.0) * upper
        self.w_elbow = _smoothstep(a, 23.0, 27.0) * upper
        self.shoulder = upper & (np.abs(a - 12.0) < 0.5)
        self.elbow = upper & (np.abs(a - 25.0) < 0.5)
        self.palm = upper & (a > 38.0) & (a < 44.0)

    def reach(self, posed: np.ndarray) -> float:
        s, e, h = (posed[m].mean(axis=0) for m in (self.shoulder, self.elbow, self.palm))
        return float(np.linalg.norm(e - s) + np.linalg.norm(h - e))

    def move_palm(self, posed: np.ndarray, target: np.ndarray) -> np.ndarray:
        """The posed vertices with the palm's centroid brought to ``target`` (shoulder and elbow turned), shape (n, 3)."""
        s, e, h = (posed[m].mean(axis=0) for m in (self.shoulder, self.elbow, self.palm))
        a, b = np.linalg.norm(e - s), np.linalg.norm(h - e)
        d = float(np.clip(np.linalg.norm(target - s), abs(a - b) + 1e-3, a + b - 1e-3))
        now = np.arccos(np.clip((s - e) @ (h - e) / (a * b), -1.0, 1.0))
        want = np.arccos(np.clip((a * a + b * b - d * d) / (2.0 * a * b), -1.0, 1.0))
        normal = np.cross(s - e, h - e)
        normal = normal / max(float(np.linalg.norm(normal)), 1e-12)
        # of the two senses of the elbow's turn, the one that leaves the palm d from the shoulder
        bends = [axis_rotation(normal, sign * (now - want)) for sign in (1.0, -1.0)]
        bend = min(bends, key=lambda R: abs(np.linalg.norm(e + R @ (h - e) - s) - d))
        w = self.w_elbow[:, None]
        bent = (1.0 - w) * posed + w * ((posed - e) @ bend.T + e)
        swing = _align(bent[self.palm].mean(axis=0) - s, target - s)  # the smallest rotation
        w = self.w_shoulder[:, None]
        return (1.0 - w) * bent + w * ((bent - s) @ swing.T + s)


def contact_poses(kids: Path, scale: float) -> dict[str, tuple[int, np.ndarray]]:
    """Every kept contact pose by name (``p09_+x-x_knee_palm``: pose, hand side, leg side, place, approach)."""
    rest, faces = read_mesh(kids / "0001.null.0.off")
    x, z = rest[:, 0], rest[:, 2]
    out: dict[str, tuple[int, np.ndarray]] = {}
    for i in range(1, 16):
        posed, f = read_mesh(kids / f"0001.isometry.{i}.off")
        if f.shape != faces.shape or not np.array_equal(f, faces):
            raise ValueError(f"{kids / f'0001.isometry.{i}.off'}: not the connectivity of 0001.null.0.off")
        for hand in (1, -1):
            arm = KidsArm(rest, hand)
            for leg_side in (1, -1):
                leg = (leg_side * x > 0) & (z < -5.0) & (np.abs(x) < 12.0)
                body = (arm.w_shoulder == 0) & ~leg
                forearm = arm.w_elbow > 0.99
                for place, height in PLACES.items():
                    ring = leg & (np.abs(z - height) < 3.0)
                    centre = posed[ring].mean(axis=0)
                    for approach, towards in (("palm", arm.palm), ("shoulder", arm.shoulder)):
                        u = posed[towards].mean(axis=0) - centre
                        u /= np.linalg.norm(u)
                        top = posed[ring][np.argmax((posed[ring] - centre) @ u)]
                        target = top + 0.015 * scale * u
                        shoulder = posed[arm.shoulder].mean(axis=0)
                        if np.linalg.norm(target - shoulder) >= arm.reach(posed):
                            continue
                        moved = arm.move_palm(posed, target)
                        gap = cKDTree(moved[leg]).query(moved[arm.palm])[0].min()
                        near_body = (cKDTree(moved[body]).query(moved[forearm])[0] < 0.01 * scale).mean()
                        shift = np.linalg.norm(moved[arm.palm].mean(axis=0) - posed[arm.palm].mean(axis=0))
                        if gap < 0.01 * scale and near_body < 0.05 and shift > 0.03 * scale:
                            name = f"p{i:02d}_{hand:+d}x{leg_side:+d}x_{place}_{approach}".replace("+1", "+").replace("-1", "-")
                            out[name] = (i, moved)
    return out


def noisy_shapes(
    coll: ShapeCollection, kids: Path, shapes: dict[str, tuple[int, np.ndarray]]
) -> Iterator[tuple[str, int, TriangleMesh, np.ndarray, np.ndarray]]:
    """Each posed shape fused, in kid_i's frame: (name, i, mesh, scored mask (n,), truth on kid00 (n_scored, 3))."""
    ref = coll[coll.reference].mesh
    rest, faces = read_mesh(kids / "0001.null.0.off")
    ref_tree, rest_tree = cKDTree(ref.vertices), cKDTree(rest)
    frames: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for name, (i, posed) in shapes.items():
        if i not in frames:  # the rigid motion from the clean pose onto kid_i, on kid_i's ground truth
            shape = coll[f"kid{i:02d}"]
            gt = np.asarray(shape.ref.tocsr().argmax(axis=1)).ravel()
            has = np.asarray(shape.ref.tocsr().sum(axis=1)).ravel() > 0
            clean = read_mesh(kids / f"0001.isometry.{i}.off")[0]
            a = clean[rest_tree.query(ref.vertices[gt[has]])[1]]
            b = shape.mesh.vertices[has]
            ca, cb = a.mean(axis=0), b.mean(axis=0)
            U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
            D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
            frames[i] = ((U @ D @ Vt).T, ca, cb)
        R, ca, cb = frames[i]
        noisy = topological_noise(posed, faces, NoiseParams(n_vertices=12000), rest_vertices=rest, random_state=0, name=name)
        mesh = TriangleMesh((noisy.mesh.vertices - ca) @ R.T + cb, noisy.mesh.faces)
        scored = (noisy.face < len(faces)) & ~noisy.unreliable
        at_rest = np.einsum("nk,nkd->nd", noisy.bary[scored], rest[faces[noisy.face[scored]]])
        yield name, i, mesh, scored, ref.vertices[ref_tree.query(at_rest)[1]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"), help="folder holding topkids/ and kids/")
    ap.add_argument("--methods", default="template")
    ap.add_argument("--param", action="append", default=[], metavar="METHOD.KEY=VALUE", help="parameter of one of the methods (repeatable)")
    ap.add_argument("--only", default=None, help="comma-separated shape names (default: every kept contact pose)")
    ap.add_argument("--control", action="store_true", help="also the 15 clean poses through the same steps")
    ap.add_argument("--json", default=None, help="append one JSON line per shape and method, and the summaries")
    args = ap.parse_args()
    if not args.data:
        ap.error("give --data or set TOPOMATCH_DATA")
    kids = Path(args.data) / "kids"
    if not (kids / "0001.null.0.off").is_file():
        sys.exit(f"{kids}: the clean KIDS shapes (0001.null.0.off, 0001.isometry.1..15.off) are not there")
    methods = [m for m in args.methods.split(",") if m]
    if len(set(methods)) != len(methods):
        ap.error("--methods lists a method twice; name a second setting name@label")
    params = _parse_params(args.param, methods)
    unknown = sorted(set(params) - set(methods) - {"*"})
    if unknown:
        ap.error(f"--param for {', '.join(unknown)}, which --methods does not list")

    coll = load_topkids(args.data, "low")
    ref = coll[coll.reference].mesh
    scale = float(np.sqrt(ref.area))
    train = coll.present(coll.splits.get("train", []))

    shapes = contact_poses(kids, scale)
    if args.control:
        shapes.update({f"p{i:02d}_clean": (i, read_mesh(kids / f"0001.isometry.{i}.off")[0]) for i in range(1, 16)})
    if args.only:
        missing = sorted(set(args.only.split(",")) - set(shapes))
        if missing:
            ap.error(f"--only names shapes the recipe does not keep: {', '.join(missing)}")
        shapes = {k: shapes[k] for k in args.only.split(",")}
    print(f"{len(shapes)} shapes; methods: {', '.join(methods)}", flush=True)

    fitted: dict[tuple[str, int], object] = {}
    errors: dict[str, dict[str, float]] = {m: {} for m in methods}
    seconds: dict[str, list[float]] = {m: [] for m in methods}
    for name, i, mesh, scored, truth in noisy_shapes(coll, kids, shapes):
        source = f"kid{i:02d}"
        for m in methods:
            if (m, i) not in fitted:
                matcher = make_matcher(m.split("@")[0], **params.get(m, {}))
                fitted[(m, i)] = matcher.fit([coll[coll.reference], *(coll[n] for n in train if n != source)])
            matcher = fitted[(m, i)]
            t0 = time.perf_counter()
            c = matcher.match(ref, mesh)
            sec = time.perf_counter() - t0
            err = 100.0 * float(np.linalg.norm(ref.vertices[c.p2p_21[scored]] - truth, axis=1).mean()) / scale
            errors[m][name] = err
            seconds[m].append(sec)
            runs = c.info.get("runs", {}).get("target", {})
            emit_row({"shape": name, "method": m, "error_x100": err, "seconds": sec, "vertices": mesh.n_vertices,
                      "scored": int(scored.sum()), "challenge": runs.get("challenge")}, args.json)
    base = methods[0]
    for m in methods:
        e = list(errors[m].values())
        row = {"method": m, "shapes": len(e), "mean_error_x100": statistics.fmean(e), "median_error_x100": statistics.median(e),
               "worst": max(errors[m], key=errors[m].get), "worst_error_x100": max(e), "above_5": sum(v > 5 for v in e),
               "seconds_per_shape_median": statistics.median(seconds[m])}
        if m != base:
            d = {k: errors[m][k] - errors[base][k] for k in errors[m]}
            row.update({f"better_than_{base}": sorted(k for k, v in d.items() if v < -0.5),
                        f"worse_than_{base}": sorted(k for k, v in d.items() if v > 0.5),
                        "time_ratio": statistics.median(seconds[m]) / statistics.median(seconds[base])})
        emit_row(row, args.json)


if __name__ == "__main__":
    main()
