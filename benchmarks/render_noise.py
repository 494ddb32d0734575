"""Render noisy shapes with their merged (unreliable) regions highlighted.

Usage
-----
    python benchmarks/render_noise.py --data DIR --shapes kid01 kid05 kid09 --out noise.png
    python benchmarks/render_noise.py --builtin --shapes syn03 syn07 syn09 --out builtin.png

Each shape is drawn from the front and from the side with flat shading; vertices
flagged unreliable (``_indmap``: where the surface moved when parts fused, or a
shortcut was added) are red, handles of the surface make no colour of their own.
A plotting helper for the noise generator's documentation; the project's report
package has its own renderers.
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np


def _rot(az: float, el: float) -> np.ndarray:
    a, e = np.radians(az), np.radians(el)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    return rx @ rz


def draw(ax, vertices, faces, highlight=None, azim=0.0, elev=0.0, up=2, title=""):
    """Orthographic flat-shaded drawing on a 2D axis (painter's algorithm)."""
    v = np.asarray(vertices, dtype=float)
    v = v - v.mean(0)
    if up != 2:  # bring the up axis to z
        perm = [0, 1, 2]
        perm[2], perm[up] = perm[up], perm[2]
        v = v[:, perm]
    v = v @ _rot(azim, elev).T
    # camera on -y looking along +y: screen x = v[:, 0], screen y = v[:, 2], depth = v[:, 1]
    tri = v[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    light = np.array([0.3, -1.0, 0.5])
    light /= np.linalg.norm(light)
    shade = 0.25 + 0.75 * np.abs(n @ light)
    base = np.tile([0.78, 0.80, 0.86], (len(faces), 1))
    if highlight is not None:
        hl = np.asarray(highlight, bool)[faces].any(axis=1)
        base[hl] = [0.90, 0.15, 0.12]
    col = np.clip(base * shade[:, None], 0, 1)
    order = np.argsort(-tri[:, :, 1].mean(1))  # far (large y) to near
    poly = [t[:, [0, 2]] for t in tri[order]]
    from matplotlib.collections import PolyCollection

    pc = PolyCollection(poly, facecolors=col[order], edgecolors=col[order], linewidths=0.15)
    ax.add_collection(pc)
    ax.set_xlim(v[:, 0].min(), v[:, 0].max())
    ax.set_ylim(v[:, 2].min(), v[:, 2].max())
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        ax.set_title(title, fontsize=8)


def render(shapes, out, up=2, views=((0, 0), (90, 0))):
    """``shapes``: list of (title, vertices, faces, highlight)."""
    fig, axes = plt.subplots(1, len(shapes) * len(views), figsize=(2.2 * len(shapes) * len(views), 4.2))
    axes = np.atleast_1d(axes)
    k = 0
    for title, v, f, hl in shapes:
        for az, el in views:
            draw(axes[k], v, f, hl, az, el, up, title if (az, el) == views[0] else "")
            k += 1
    fig.tight_layout()
    fig.savefig(out, dpi=150)
    plt.close(fig)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", help="TOPKIDS-layout data directory")
    p.add_argument("--builtin", action="store_true", help="the built-in synthetic benchmark")
    p.add_argument("--shapes", nargs="+", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--up", type=int, default=None, help="index of the up axis (default 2)")
    p.add_argument("--front", type=float, default=None, help="azimuth of the front view in degrees (default: 180 for the built-in figure, 0 otherwise)")
    args = p.parse_args()
    if args.builtin:
        from topomatch.datasets.builtin import builtin_benchmark

        coll = builtin_benchmark()
        up = 2 if args.up is None else args.up
    else:
        from topomatch.datasets.topkids import load_topkids

        coll = load_topkids(args.data, "low")
        up = 2 if args.up is None else args.up
    items = []
    for name in args.shapes:
        s = coll[name]
        m = s.mesh
        hl = s.unreliable
        frac = 0.0 if hl is None else float((m.vertex_areas * hl).sum() / m.area)
        items.append((f"{name}: {m.n_vertices} v, genus {m.genus}, {100 * frac:.1f}% unrel.", m.vertices, m.faces, hl))
    # the built-in figure (about one unit tall) faces +y, the KIDS children (about 100) -y
    height = float(np.ptp(coll[coll.reference].mesh.vertices, axis=0).max())
    front = args.front if args.front is not None else (180.0 if height < 10 else 0.0)
    render(items, args.out, up=up, views=((front, 0.0), (front - 90.0, 0.0)))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
