"""Headless mesh renderings with matplotlib (PNG through Agg): the track's Fig. 4 and 5.

A mesh is projected orthographically, its triangles sorted back to front (painter's
algorithm) and drawn in one call to the renderer's Gouraud-triangle primitive, with
vertex colours times a Lambert term computed by hand from the vertex normals and a
light near the viewer (two-sided, so inconsistently oriented faces are lit too). This
avoids mplot3d's own projection and sorting and one ``Path`` object per triangle (a
``PolyCollection`` took about 4x longer at 60K vertices).

matplotlib is imported inside the functions, never at module import.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from topomatch.typing import FloatArray, IndexArray, PathType

__all__ = ["View", "project", "projected_size", "render_mesh", "save_rendering", "shade_vertices"]

logger = logging.getLogger(__name__)

_UP = {"x": 0, "y": 1, "z": 2}
_FRONT = {"z": (0.0, -1.0, 0.0), "y": (0.0, 0.0, 1.0), "x": (0.0, 0.0, 1.0)}


@dataclass(frozen=True)
class View:
    """Where the camera looks from.

    Attributes
    ----------
    elev : float
        Degrees above the horizontal plane.
    azim : float
        Degrees around the up axis; 0 looks at the front: from -y when ``up="z"``
        (the TOPKIDS and built-in shapes), from +z when ``up`` is ``"y"`` or ``"x"``.
    up : {"x", "y", "z"}
        The axis drawn vertically.
    """

    elev: float = 10.0
    azim: float = 0.0
    up: str = "z"

    def basis(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Screen right, screen up and the direction toward the camera, each shape (3,)."""
        if self.up not in _UP:
            raise ValueError(f"up must be 'x', 'y' or 'z', got {self.up!r}")
        u = np.zeros(3)
        u[_UP[self.up]] = 1.0
        f = np.array(_FRONT[self.up])
        a, e = np.radians(self.azim), np.radians(self.elev)
        side = np.cross(u, f)
        horiz = np.cos(a) * f + np.sin(a) * side
        cam = np.cos(e) * horiz + np.sin(e) * u
        right = np.cross(u, cam)
        right /= np.linalg.norm(right)
        up = np.cross(cam, right)
        return right, up, cam


def project(vertices: FloatArray, view: View) -> tuple[FloatArray, FloatArray]:
    """Orthographic projection.

    Returns
    -------
    xy : ndarray, shape (n_vertices, 2)
        Screen coordinates.
    depth : ndarray, shape (n_vertices,)
        Larger is nearer the camera.
    """
    right, up, cam = view.basis()
    v = np.asarray(vertices, dtype=np.float64)
    return np.stack([v @ right, v @ up], axis=1), v @ cam


def shade_vertices(vertices: FloatArray, faces: IndexArray, vertex_colors: FloatArray, view: View, *, ambient: float = 0.35) -> FloatArray:
    """Per-vertex colours times a two-sided Lambert term from the vertex normals.

    The light comes from near the camera (slightly above and to the left).

    Parameters
    ----------
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
    vertex_colors : ndarray, shape (n_vertices, 3)
        RGB in [0, 1].
    view : View
    ambient : float
        Light that reaches every vertex.

    Returns
    -------
    ndarray, shape (n_vertices, 3)
    """
    from topomatch.mesh.geometry import vertex_normals

    right, up, cam = view.basis()
    light = cam + 0.35 * up - 0.25 * right
    light /= np.linalg.norm(light)
    n = vertex_normals(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64))
    lam = np.abs(n @ light)
    c = np.asarray(vertex_colors, dtype=np.float64)
    return np.clip(c * (ambient + (1.0 - ambient) * lam)[:, None], 0.0, 1.0)


def _gouraud_artist(triangles: FloatArray, colors: FloatArray) -> Any:
    """Make a matplotlib artist drawing smooth-shaded triangles in the given order, in one call."""
    from matplotlib.artist import Artist

    class GouraudTriangles(Artist):
        def __init__(self) -> None:
            super().__init__()
            self._tri = triangles
            self._rgba = colors

        def draw(self, renderer: Any) -> None:
            if not self.get_visible():
                return
            gc = renderer.new_gc()
            renderer.draw_gouraud_triangles(gc, self._tri, self._rgba, self.axes.transData.frozen())
            gc.restore()

    return GouraudTriangles()


def projected_size(vertices: FloatArray, view: View | None = None) -> tuple[float, float]:
    """Return the width and height of the mesh's projected bounding box (for a common scale)."""
    xy, _ = project(vertices, view or View())
    w, h = xy.max(axis=0) - xy.min(axis=0)
    return float(w), float(h)


def render_mesh(
    ax: Any,
    vertices: FloatArray,
    faces: IndexArray,
    vertex_colors: FloatArray,
    view: View | None = None,
    *,
    title: str | None = None,
    size: tuple[float, float] | None = None,
) -> float:
    """Draw a mesh into a matplotlib ``Axes`` (2-D, aspect equal, no frame).

    Triangles are projected orthographically, sorted back to front by mean depth and
    drawn as Gouraud-shaded triangles (colours interpolated from the vertices) in a
    single renderer call.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
    vertex_colors : ndarray, shape (n_vertices, 3)
        RGB in [0, 1], before shading.
    view : View, optional
    title : str, optional
    size : (float, float), optional
        Width and height of the window shown, in mesh units, centred on the mesh (give
        the same value to several axes to draw them at one scale); default: fit the mesh.

    Returns
    -------
    float
        Seconds spent preparing the triangles (rasterising happens when the figure is
        saved).
    """
    t0 = time.perf_counter()
    view = view or View()
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    colors = np.asarray(vertex_colors, dtype=np.float64)
    if colors.shape != v.shape:
        raise ValueError(f"vertex_colors must have shape {v.shape}, got {colors.shape}")
    xy, depth = project(v, view)
    order = np.argsort(depth[f].mean(axis=1), kind="stable")  # far to near
    fo = f[order]
    shaded = shade_vertices(v, f, colors, view)
    rgba = np.concatenate([shaded, np.ones((len(v), 1))], axis=1)[fo]
    ax.add_artist(_gouraud_artist(xy[fo], rgba))
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    if size is None:
        pad = 0.02 * float(np.max(hi - lo))
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
    else:
        c = (lo + hi) / 2
        half = 0.51 * np.maximum(np.asarray(size, dtype=np.float64), hi - lo)
        ax.set_xlim(c[0] - half[0], c[0] + half[0])
        ax.set_ylim(c[1] - half[1], c[1] + half[1])
    ax.set_aspect("equal")
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=8)
    return time.perf_counter() - t0


def save_rendering(
    path: PathType,
    vertices: FloatArray,
    faces: IndexArray,
    vertex_colors: FloatArray,
    view: View | None = None,
    *,
    size: tuple[float, float] = (3.0, 4.0),
    dpi: int = 120,
    title: str | None = None,
) -> float:
    """Render one mesh to a PNG file.

    Parameters
    ----------
    path : path
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
    vertex_colors : ndarray, shape (n_vertices, 3)
    view : View, optional
    size : (float, float)
        Figure size in inches.
    dpi : int
    title : str, optional

    Returns
    -------
    float
        Seconds for the whole rendering (preparation and writing the file).
    """
    from matplotlib.figure import Figure

    t0 = time.perf_counter()
    fig = Figure(figsize=size, dpi=dpi)
    render_mesh(fig.add_subplot(), vertices, faces, vertex_colors, view, title=title)
    fig.savefig(path)
    return time.perf_counter() - t0
