"""A procedural articulated figure: skeleton, smooth implicit body, poses by skinning.

The figure is a child-like humanoid about one unit tall (z up, +y forward, its left on
+x), mirror-symmetric across x = 0. Its body is the smooth union of tapered capsules
and ellipsoids, each attached to a bone; the rest (null) pose stands with arms and legs
apart so that nothing touches. The template mesh is that implicit surface triangulated
once in the rest pose; a pose moves its vertices by linear blend skinning (weights from
how close each vertex is to each bone's parts), so every pose has exactly the
template's connectivity and ground truth. Arms and legs are placed by two-bone inverse
kinematics on hand and ankle targets, which makes touching poses (hands on hips, arms
crossed, knees together) easy to write down.

Everything is deterministic and defined in code: no data files.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from topomatch.datasets._isosurface import marching_tetrahedra
from topomatch.datasets._surface import decimate, keep_largest_component, mirror_symmetry
from topomatch.mesh import TriangleMesh
from topomatch.mesh.geometry import axis_rotation
from topomatch.typing import FloatArray, IndexArray

__all__ = ["POSES", "Figure", "Pose", "build_figure"]

# ---------------------------------------------------------------------------------------
# skeleton: bone -> (parent, head joint, tail joint) in the rest pose
# ---------------------------------------------------------------------------------------
_A = np.radians(28.0)  # arm abduction in the rest pose
_L = np.radians(4.0)  # leg abduction
_SH = np.array([0.115, 0.0, 0.77])
_EL = _SH + 0.165 * np.array([np.sin(_A), 0.0, -np.cos(_A)])
_WR = _EL + 0.150 * np.array([np.sin(_A), 0.0, -np.cos(_A)])
_HT = _WR + 0.085 * np.array([np.sin(_A), 0.0, -np.cos(_A)])
_HP = np.array([0.062, 0.0, 0.485])
_KN = _HP + 0.215 * np.array([np.sin(_L), 0.0, -np.cos(_L)])
_AN = _KN + 0.205 * np.array([np.sin(_L), 0.0, -np.cos(_L)])
_TO = _AN + np.array([0.0, 0.085, -0.030])

_MIRROR = np.array([-1.0, 1.0, 1.0])


def _both(name: str, parent: str | None, head: FloatArray, tail: FloatArray) -> dict[str, tuple[str | None, FloatArray, FloatArray]]:
    out = {}
    for side, s in (("l", 1.0), ("r", -1.0)):
        m = np.array([s, 1.0, 1.0])
        par = parent.replace("*", side) if parent else None
        out[name.replace("*", side)] = (par, head * m, tail * m)
    return out


BONES: dict[str, tuple[str | None, FloatArray, FloatArray]] = {
    "pelvis": (None, np.array([0.0, 0.0, 0.50]), np.array([0.0, 0.0, 0.62])),
    "chest": ("pelvis", np.array([0.0, 0.0, 0.62]), np.array([0.0, 0.0, 0.78])),
    "head": ("chest", np.array([0.0, 0.0, 0.79]), np.array([0.0, 0.0, 0.98])),
    **_both("upperarm_*", "chest", _SH, _EL),
    **_both("forearm_*", "upperarm_*", _EL, _WR),
    **_both("hand_*", "forearm_*", _WR, _HT),
    **_both("thigh_*", "pelvis", _HP, _KN),
    **_both("shin_*", "thigh_*", _KN, _AN),
    **_both("foot_*", "shin_*", _AN, _TO),
}


# ---------------------------------------------------------------------------------------
# body: primitives (kind, bone, parameters); smooth union of their distance fields
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Part:
    bone: str
    a: FloatArray
    b: FloatArray
    ra: float
    rb: float
    flat: FloatArray | None = None  # unit axis across which the section is squashed
    squash: float = 1.0  # section radius along ``flat`` = squash * radius


def _parts() -> list[_Part]:
    parts = [
        _Part("pelvis", np.array([0.0, 0.0, 0.50]), np.array([0.0, 0.0, 0.56]), 0.092, 0.086, np.array([0.0, 1.0, 0.0]), 0.72),
        _Part("pelvis", np.array([0.0, 0.0, 0.56]), np.array([0.0, 0.0, 0.63]), 0.086, 0.088, np.array([0.0, 1.0, 0.0]), 0.72),
        _Part("chest", np.array([0.0, 0.0, 0.63]), np.array([0.0, 0.0, 0.735]), 0.092, 0.104, np.array([0.0, 1.0, 0.0]), 0.66),
        _Part("chest", np.array([-0.05, 0.0, 0.745]), np.array([0.05, 0.0, 0.745]), 0.046, 0.046),  # shoulders
        _Part("head", np.array([0.0, 0.0, 0.77]), np.array([0.0, 0.0, 0.84]), 0.032, 0.030),  # neck
        _Part("head", np.array([0.0, 0.004, 0.885]), np.array([0.0, 0.0, 0.935]), 0.068, 0.062, np.array([1.0, 0.0, 0.0]), 0.90),
        _Part("head", np.array([0.0, 0.066, 0.885]), np.array([0.0, 0.076, 0.878]), 0.011, 0.008),  # nose
    ]
    for s in (1.0, -1.0):
        m = np.array([s, 1.0, 1.0])
        side = "l" if s > 0 else "r"
        armdir = (_WR - _EL) / np.linalg.norm(_WR - _EL)
        palm = np.array([np.cos(_A), 0.0, np.sin(_A)]) * m  # hands flattened across the palm
        parts += [
            _Part(f"upperarm_{side}", _SH * m, _EL * m, 0.036, 0.028),
            _Part(f"forearm_{side}", _EL * m, _WR * m, 0.027, 0.021),
            _Part(f"hand_{side}", (_WR + 0.012 * armdir) * m, (_HT - 0.018 * armdir) * m, 0.026, 0.022, palm, 0.45),
            _Part(f"thigh_{side}", (_HP + np.array([0.004, 0.0, 0.02])) * m, _KN * m, 0.056, 0.037),
            _Part(f"shin_{side}", _KN * m, _AN * m, 0.035, 0.023),
            _Part(f"foot_{side}", (_AN + np.array([0.0, -0.012, -0.012])) * m, _TO * m, 0.026, 0.020, np.array([0.0, 0.0, 1.0]), 0.62),
        ]
    return parts


def _part_distance(p: _Part, x: FloatArray) -> FloatArray:
    """Approximate signed distance to a tapered capsule with a squashed section, shape (n,)."""
    ab = p.b - p.a
    ll = float(ab @ ab)
    t = np.clip(((x - p.a) @ ab) / ll, 0.0, 1.0)
    r = p.ra + t * (p.rb - p.ra)
    d = x - (p.a + t[:, None] * ab)
    if p.flat is not None and p.squash != 1.0:
        k = d @ p.flat
        d = d + ((1.0 / p.squash) - 1.0) * k[:, None] * p.flat[None, :]
        return (np.linalg.norm(d, axis=1) - r) * p.squash
    return np.linalg.norm(d, axis=1) - r


def _smooth_min(a: FloatArray, b: FloatArray, k: float) -> FloatArray:
    h = np.clip(k - np.abs(a - b), 0.0, None) / k
    return np.minimum(a, b) - h * h * k * 0.25


def body_distance(x: FloatArray, blend: float = 0.03) -> tuple[FloatArray, dict[str, FloatArray]]:
    """Signed distance (approximate) of the rest-pose body and the distance per bone.

    Parameters
    ----------
    x : ndarray, shape (n, 3)
    blend : float
        Radius of the smooth union.

    Returns
    -------
    distance : ndarray, shape (n,)
    per_bone : dict of str to ndarray of shape (n,)
    """
    per_bone: dict[str, FloatArray] = {}
    total = None
    for p in _parts():
        d = _part_distance(p, x)
        per_bone[p.bone] = d if p.bone not in per_bone else np.minimum(per_bone[p.bone], d)
        total = d if total is None else _smooth_min(total, d, blend)
    return total, per_bone


def body_grid(origin: FloatArray, spacing: float, shape: tuple[int, int, int], blend: float = 0.03) -> FloatArray:
    """:func:`body_distance` on a grid, each part evaluated only in its bounding box.

    Away from every part the value is only a positive placeholder (the distance is not
    needed there, its sign is). Returns an array of shape ``shape``.
    """
    out = np.full(shape, 1.0)
    margin = blend + 3 * spacing
    for p in _parts():
        r = max(p.ra, p.rb) + margin
        i0 = np.maximum(np.floor((np.minimum(p.a, p.b) - r - origin) / spacing).astype(np.int64), 0)
        i1 = np.minimum(np.ceil((np.maximum(p.a, p.b) + r - origin) / spacing).astype(np.int64) + 1, shape)
        if np.any(i1 <= i0):
            continue
        axes = [origin[k] + spacing * np.arange(i0[k], i1[k]) for k in range(3)]
        g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        d = _part_distance(p, g).reshape(tuple(i1 - i0))
        view = out[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]]
        view[...] = _smooth_min(view, d, blend)
    return out


# ---------------------------------------------------------------------------------------
# poses
# ---------------------------------------------------------------------------------------
def _align(u: FloatArray, v: FloatArray) -> FloatArray:
    """Smallest rotation taking direction u to direction v."""
    u = u / np.linalg.norm(u)
    v = v / np.linalg.norm(v)
    c = float(u @ v)
    axis = np.cross(u, v)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        return axis_rotation(perp, np.pi)
    return axis_rotation(axis, float(np.arctan2(s, c)))


@dataclass
class Pose:
    """World rotations of bones (rest = identity) and a root offset.

    Build one with the helpers: :meth:`turn` (rotate a bone and its children about its
    head joint), :meth:`reach` (two-bone IK for an arm or a leg).
    """

    rotations: dict[str, FloatArray] = field(default_factory=dict)
    offset: FloatArray = field(default_factory=lambda: np.zeros(3))

    def world(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Per bone ``(R, t)`` with posed ``x' = R x + t``."""
        out: dict[str, tuple[FloatArray, FloatArray]] = {}
        for name, (parent, head, _) in BONES.items():  # parents come first
            if parent is None:
                head_posed = head + self.offset
            else:
                rp, tp = out[parent]
                head_posed = rp @ head + tp
            r = self.rotations.get(name)
            if r is None:
                r = out[parent][0] if parent is not None else np.eye(3)
            out[name] = (r, head_posed - r @ head)
        return out

    def joint(self, bone: str, which: str = "head") -> FloatArray:
        """Posed position of a bone's head or tail joint."""
        r, t = self.world()[bone]
        return r @ BONES[bone][1 if which == "head" else 2] + t

    def turn(self, bone: str, axis: FloatArray, degrees: float) -> Pose:
        """Rotate ``bone`` (and, through inheritance, its children) about world ``axis``."""
        rot = axis_rotation(np.asarray(axis, dtype=np.float64), np.radians(degrees))
        cur = self.world()[bone][0]
        below = {bone}
        for name, (parent, _, _) in BONES.items():  # parents are listed before children
            if parent in below:
                below.add(name)
                if name in self.rotations:
                    self.rotations[name] = rot @ self.rotations[name]
        self.rotations[bone] = rot @ cur
        return self

    def reach(self, limb: str, side: str, target: FloatArray, pole: FloatArray, extra: float = 0.0) -> Pose:
        """Two-bone IK: put the end of ``limb`` ("arm" or "leg") of ``side`` at ``target``.

        ``extra`` extends the second bone (e.g. to half a hand, to place the palm rather
        than the wrist). ``pole`` is a direction the middle joint (elbow, knee) bends to.
        """
        b1, b2, b3 = ("upperarm", "forearm", "hand") if limb == "arm" else ("thigh", "shin", "foot")
        b1, b2, b3 = f"{b1}_{side}", f"{b2}_{side}", f"{b3}_{side}"
        w = self.world()
        r0 = w[BONES[b1][0]][0]  # parent's rotation
        root = self.joint(b1)
        l1 = float(np.linalg.norm(BONES[b1][2] - BONES[b1][1]))
        l2 = float(np.linalg.norm(BONES[b2][2] - BONES[b2][1])) + extra
        tgt = np.asarray(target, dtype=np.float64)
        d_vec = tgt - root
        d = float(np.clip(np.linalg.norm(d_vec), abs(l1 - l2) + 1e-4, l1 + l2 - 1e-4))
        n = d_vec / np.linalg.norm(d_vec)
        a = (l1 * l1 - l2 * l2 + d * d) / (2 * d)
        hgt = np.sqrt(max(l1 * l1 - a * a, 0.0))
        pv = np.asarray(pole, dtype=np.float64)
        pv = pv - (pv @ n) * n
        pv = pv / max(np.linalg.norm(pv), 1e-12)
        mid = root + a * n + hgt * pv
        end = root + d * n
        rest1 = r0 @ (BONES[b1][2] - BONES[b1][1])
        r1 = _align(rest1, mid - root) @ r0
        rest2 = r1 @ (BONES[b2][2] - BONES[b2][1])
        r2 = _align(rest2, end - mid) @ r1
        self.rotations[b1] = r1
        self.rotations[b2] = r2
        if limb == "arm":
            self.rotations[b3] = r2
        else:  # keep the foot's rest orientation relative to the world (flat on the floor)
            self.rotations.setdefault(b3, r0)
        return self


def _pose_hands_on_hips() -> Pose:
    p = Pose()
    for s, side in ((1, "l"), (-1, "r")):
        p.reach("arm", side, [s * 0.092, 0.01, 0.56], [s * 1.0, -0.6, 0.1], extra=0.035)
    return p


def _pose_hand_on_head() -> Pose:
    p = Pose().turn("head", [0, 1, 0], -8)
    p.reach("arm", "r", [-0.02, 0.0, 0.975], [-1.0, 0.2, 0.3], extra=0.035)
    p.reach("arm", "l", [0.20, 0.05, 0.50], [1.0, -0.5, 0.0], extra=0.035)
    return p


def _pose_arms_crossed() -> Pose:
    p = Pose()
    p.reach("arm", "r", [0.095, 0.085, 0.665], [-0.3, 0.3, -1.0], extra=0.03)
    p.reach("arm", "l", [-0.10, 0.105, 0.65], [0.3, 0.3, -1.0], extra=0.03)
    return p


def _pose_legs_crossed() -> Pose:
    p = Pose()
    p.reach("leg", "r", [0.035, 0.05, 0.055], [0.0, 1.0, 0.0])
    p.reach("leg", "l", [0.085, -0.01, 0.055], [0.0, 1.0, 0.0])
    p.reach("arm", "l", [0.19, 0.02, 0.48], [1.0, -0.5, 0.0], extra=0.035)
    return p


def _pose_knees_together() -> Pose:
    p = Pose(offset=np.array([0.0, 0.0, -0.045])).turn("chest", [1, 0, 0], 10)
    for s, side in ((1, "l"), (-1, "r")):
        p.reach("leg", side, [s * 0.10, 0.0, 0.055], [-s * 0.45, 1.0, 0.0])
    return p


def _pose_hands_clasped() -> Pose:
    p = Pose()
    p.reach("arm", "r", [-0.012, 0.115, 0.50], [-1.0, -0.3, -0.2], extra=0.035)
    p.reach("arm", "l", [0.012, 0.115, 0.50], [1.0, -0.3, -0.2], extra=0.035)
    return p


def _pose_hand_on_shoulder() -> Pose:
    p = Pose().turn("chest", [0, 0, 1], 12)
    p.reach("arm", "r", [0.095, 0.05, 0.765], [0.0, 0.3, -1.0], extra=0.035)
    p.reach("arm", "l", [0.20, 0.03, 0.47], [1.0, -0.4, 0.0], extra=0.035)
    return p


def _pose_thinker() -> Pose:
    p = Pose().turn("head", [1, 0, 0], 10)
    p.reach("arm", "r", [-0.005, 0.085, 0.825], [0.0, 0.4, -1.0], extra=0.035)
    p.reach("arm", "l", [-0.075, 0.08, 0.60], [0.4, 0.2, -1.0], extra=0.035)
    return p


def _pose_arms_at_sides() -> Pose:
    p = Pose().turn("head", [0, 0, 1], 20)
    for s, side in ((1, "l"), (-1, "r")):
        p.reach("arm", side, [s * 0.118, 0.0, 0.43], [s * 0.3, -1.0, 0.0], extra=0.035)
    return p


def _pose_hands_behind_head() -> Pose:
    p = Pose()
    for s, side in ((1, "l"), (-1, "r")):
        p.reach("arm", side, [s * 0.035, -0.06, 0.92], [s * 1.0, 0.2, 0.2], extra=0.035)
    return p


def _pose_knee_up() -> Pose:
    p = Pose()
    p.reach("leg", "r", [-0.07, 0.15, 0.25], [0.0, 1.0, 0.3])
    p.reach("arm", "r", [-0.075, 0.17, 0.33], [-1.0, 0.0, 0.0], extra=0.035)
    p.reach("arm", "l", [0.13, 0.04, 0.52], [1.0, -0.5, 0.0], extra=0.035)
    return p


def _pose_free() -> Pose:
    p = Pose().turn("chest", [0, 0, 1], -15).turn("head", [0, 1, 0], 12)
    p.reach("arm", "r", [-0.30, 0.12, 0.95], [-0.5, -1.0, 0.0], extra=0.035)
    p.reach("arm", "l", [0.28, 0.18, 0.55], [1.0, -1.0, 0.0], extra=0.035)
    p.reach("leg", "l", [0.12, 0.10, 0.07], [0.0, 1.0, 0.0])
    return p


POSES: dict[str, Callable[[], Pose]] = {
    "hands_on_hips": _pose_hands_on_hips,
    "hand_on_head": _pose_hand_on_head,
    "arms_crossed": _pose_arms_crossed,
    "legs_crossed": _pose_legs_crossed,
    "knees_together": _pose_knees_together,
    "hands_clasped": _pose_hands_clasped,
    "hand_on_shoulder": _pose_hand_on_shoulder,
    "thinker": _pose_thinker,
    "arms_at_sides": _pose_arms_at_sides,
    "hands_behind_head": _pose_hands_behind_head,
    "knee_up": _pose_knee_up,
    "free": _pose_free,
}
"""Named poses; all but ``free`` bring parts into contact."""


# ---------------------------------------------------------------------------------------
# the template
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Figure:
    """The figure's template mesh in the rest pose, its skinning weights and symmetry.

    Attributes
    ----------
    mesh : TriangleMesh
        Rest (null) pose.
    bones : list of str
    weights : ndarray, shape (n_vertices, n_bones)
        Skinning weights, rows sum to one.
    sym : ndarray, shape (n_vertices,)
        Mirror vertex across x = 0 (nearest vertex to the reflection), ``-1`` if none.
    """

    mesh: TriangleMesh
    bones: list[str]
    weights: FloatArray
    sym: IndexArray

    def pose(self, pose: Pose | str) -> FloatArray:
        """Posed template vertices by linear blend skinning, shape (n_vertices, 3)."""
        if isinstance(pose, str):
            if pose not in POSES:
                raise ValueError(f"unknown pose {pose!r}; available: {', '.join(POSES)}")
            pose = POSES[pose]()
        world = pose.world()
        v = self.mesh.vertices
        out = np.zeros_like(v)
        for j, b in enumerate(self.bones):
            w = self.weights[:, j]
            sel = w > 0
            if not sel.any():
                continue
            r, t = world[b]
            out[sel] += w[sel, None] * (v[sel] @ r.T + t)
        return out


def build_figure(n_vertices: int = 10_000, *, voxel_size: float = 0.007, blend: float = 0.012) -> Figure:
    """Triangulate the rest-pose body and compute skinning weights and the symmetry map.

    Parameters
    ----------
    n_vertices : int
        Template resolution after decimation.
    voxel_size : float
        Grid spacing for the iso-surface (the figure is about 1 unit tall).
    blend : float
        Width of the skinning-weight transition between bones.

    Returns
    -------
    Figure
    """
    h = float(voxel_size)
    lo = np.array([-0.40, -0.16, -0.04])
    hi = -lo * np.array([1.0, 1.0, 0.0]) + np.array([0.0, 0.0, 1.04])
    n = np.ceil((hi - lo) / h).astype(np.int64) + 1
    n[0] += (n[0] + 1) % 2  # odd count: a grid plane on x = 0, so the grid is mirror-symmetric
    origin = np.array([-(n[0] - 1) / 2 * h, lo[1], lo[2]])
    v, f = marching_tetrahedra(body_grid(origin, h, tuple(int(k) for k in n)), origin, h)
    v, f = keep_largest_component(v, f)
    v, f = decimate(v, f, n_vertices)
    mesh = TriangleMesh(v, f, name="figure")
    _, per_bone = body_distance(mesh.vertices)
    bones = list(BONES)
    d = np.stack([per_bone[b] if b in per_bone else np.full(mesh.n_vertices, np.inf) for b in bones], axis=1)
    d = d - d.min(axis=1, keepdims=True)
    w = np.exp(-d / blend)
    w[w < 1e-4] = 0.0
    w /= w.sum(axis=1, keepdims=True)
    edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
    sym = mirror_symmetry(mesh.vertices, 0, tolerance=1.5 * edge)
    return Figure(mesh, bones, w, sym)
