"""Correspondence files: TOPKIDS ground truth, ``.vts``, plain maps, SHREC'16 submissions.

On disk every index is one-based (as in the TOPKIDS release and MATLAB tooling); in memory
every index is zero-based and ``-1`` means "none" (no match, no symmetric partner).

Formats
-------
``_ref``
    Two columns ``i j``: vertex ``i`` of the shape corresponds to vertex ``j`` of the
    reference (null) shape. Rows may repeat either column (many-to-many at high res).
``_sym``
    Two columns ``i j``: the left-right mirror of vertex ``i`` is ``j`` (``0`` = none);
    or one column (the TOPKIDS null shape): value ``k`` on line ``i`` is the mirror of
    vertex ``i``. Values may be integer or float formatted (``6.1000000e+01``); line ends
    may be LF or CRLF; a one-column file may also be written as a single row.
``_indmap``
    One value per vertex, ``1`` = the vertex has no reliable ground truth, ``0`` = it has.
``.vts``
    One value per line: the one-based vertex index on the other shape.
plain vertex map (``read_p2p``)
    One value per vertex of the mapped shape: a one-based vertex index on the other
    shape, ``0`` or ``-1`` for "unmatched".
SHREC'16 submission
    One row per vertex of the mapped shape: ``t w1 w2 w3``, ``t`` a one-based triangle of
    the other shape and ``w`` barycentric weights on its corners, or ``-1 0 0 0`` for
    "unmatched".
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from topomatch.typing import BoolArray, FloatArray, IndexArray, PathType

__all__ = [
    "read_indmap",
    "read_p2p",
    "read_ref",
    "read_shrec16_map",
    "read_sym",
    "read_vts",
    "write_indmap",
    "write_p2p",
    "write_ref",
    "write_shrec16_map",
    "write_sym",
    "write_vts",
]


def _read_table(path: PathType, what: str) -> tuple[Path, FloatArray, list[int]]:
    """Read a whitespace table of numbers; returns values (rows, cols) and line numbers.

    A single-row file is returned as one row. Rows of unequal length raise.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such {what} file")
    text = path.read_bytes().decode("ascii", errors="replace")
    rows: list[str] = []
    linenos: list[int] = []
    for ln, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            rows.append(s)
            linenos.append(ln)
    if not rows:
        raise ValueError(f"{path}: empty {what} file")
    ncols = len(rows[0].split())
    try:
        vals = np.array(" ".join(rows).split(), dtype=np.float64)
    except ValueError:
        for r, ln in zip(rows, linenos):
            for tok in r.split():
                try:
                    float(tok)
                except ValueError as err:
                    raise ValueError(f"{path}:{ln}: expected a number in the {what} file, found {tok!r}") from err
        raise
    if len(rows) == 1:
        return path, vals.reshape(1, -1), linenos
    if vals.size != ncols * len(rows):
        for r, ln in zip(rows, linenos):
            if len(r.split()) != ncols:
                raise ValueError(
                    f"{path}:{ln}: expected {ncols} column(s) as on line {linenos[0]} of the {what} file, "
                    f"found {len(r.split())}: {r!r}"
                )
    return path, vals.reshape(len(rows), ncols), linenos


def _as_int(path: Path, vals: FloatArray, linenos: list[int], what: str) -> IndexArray:
    if not np.all(np.isfinite(vals)) or not np.all(vals == np.round(vals)):
        bad = np.flatnonzero(~(np.isfinite(vals) & (vals == np.round(vals))).all(axis=1))[0]
        ln = linenos[bad] if len(linenos) == len(vals) else linenos[0]
        raise ValueError(f"{path}:{ln}: expected integer vertex indices in the {what} file, found {vals[bad].tolist()}")
    return vals.astype(np.int64)


def _check_range(path: Path, idx: IndexArray, lo: int, hi: int | None, linenos: list[int], what: str, col: str) -> None:
    if hi is None:
        bad = np.flatnonzero(idx < lo)
    else:
        bad = np.flatnonzero((idx < lo) | (idx > hi))
    if bad.size:
        b = int(bad[0])
        ln = linenos[b] if len(linenos) == len(idx) else linenos[0]
        rng = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise ValueError(f"{path}:{ln}: {col} index {idx[b]} outside {rng} in the {what} file")


def read_ref(path: PathType, n_vertices: int | None = None, n_reference: int | None = None) -> IndexArray:
    """Read a TOPKIDS ``_ref`` file.

    Parameters
    ----------
    path : str or PathLike
        The ``kidNN_ref.txt`` file.
    n_vertices, n_reference : int, optional
        Vertex counts of the shape and of the reference shape, to check the indices.

    Returns
    -------
    pairs : ndarray, shape (n_pairs, 2)
        Zero-based ``(vertex on the shape, vertex on the reference)`` rows, as in the file.
    """
    path, vals, linenos = _read_table(path, "_ref")
    if vals.shape[1] != 2:
        raise ValueError(f"{path}:{linenos[0]}: expected 2 columns (vertex, reference vertex) in the _ref file, found {vals.shape[1]}")
    idx = _as_int(path, vals, linenos, "_ref")
    _check_range(path, idx[:, 0], 1, n_vertices, linenos, "_ref", "first-column")
    _check_range(path, idx[:, 1], 1, n_reference, linenos, "_ref", "second-column")
    return idx - 1


def read_sym(path: PathType, n_vertices: int | None = None) -> IndexArray:
    """Read a TOPKIDS ``_sym`` file (two columns, or the null shape's one column).

    Parameters
    ----------
    path : str or PathLike
        The ``kidNN_sym.txt`` file.
    n_vertices : int, optional
        Vertex count of the shape. Required to size the map when a two-column file
        omits vertices; checked against a one-column file's length.

    Returns
    -------
    sym : ndarray, shape (n_vertices,)
        ``sym[i]`` is the mirror vertex of ``i``, or ``-1`` where none exists.
    """
    path, vals, linenos = _read_table(path, "_sym")
    if vals.shape[0] == 1 and vals.shape[1] > 2:  # one column written as a single row
        vals = vals.reshape(-1, 1)
        linenos = linenos * len(vals)
    idx = _as_int(path, vals, linenos, "_sym")
    if idx.shape[1] == 1:
        col = idx[:, 0]
        if n_vertices is not None and len(col) != n_vertices:
            raise ValueError(f"{path}: one-column _sym file has {len(col)} values, expected one per vertex ({n_vertices})")
        _check_range(path, col, 0, len(col) if n_vertices is None else n_vertices, linenos, "_sym", "mirror")
        return col - 1
    if idx.shape[1] != 2:
        raise ValueError(f"{path}:{linenos[0]}: expected 1 or 2 columns in the _sym file, found {idx.shape[1]}")
    n = int(idx[:, 0].max()) if n_vertices is None else n_vertices
    _check_range(path, idx[:, 0], 1, n, linenos, "_sym", "first-column")
    _check_range(path, idx[:, 1], 0, n, linenos, "_sym", "mirror")
    sym = np.full(n, -1, dtype=np.int64)
    sym[idx[:, 0] - 1] = idx[:, 1] - 1
    return sym


def read_indmap(path: PathType, n_vertices: int | None = None) -> BoolArray:
    """Read a TOPKIDS ``_indmap`` file.

    Returns
    -------
    no_match : ndarray of bool, shape (n_vertices,)
        True where the vertex has no (reliable) ground truth.
    """
    path, vals, linenos = _read_table(path, "_indmap")
    vals = vals.reshape(-1)
    if not np.all((vals == 0) | (vals == 1)):
        bad = int(np.flatnonzero((vals != 0) & (vals != 1))[0])
        ln = linenos[bad] if len(linenos) == len(vals) else linenos[0]
        raise ValueError(f"{path}:{ln}: expected 0 or 1 in the _indmap file, found {vals[bad]}")
    if n_vertices is not None and len(vals) != n_vertices:
        raise ValueError(f"{path}: _indmap has {len(vals)} values, expected one per vertex ({n_vertices})")
    return vals.astype(bool)


def read_vts(path: PathType, n_reference: int | None = None) -> IndexArray:
    """Read a one-column ``.vts`` file (one-based indices) into a zero-based array.

    Note that in the learning-code layout (``corres/kidNN_ref.vts``), line ``k`` holds
    the reference vertex of vertex ``k`` of kidNN.
    """
    path, vals, linenos = _read_table(path, ".vts")
    if vals.shape[0] == 1 and vals.shape[1] > 1:
        vals = vals.reshape(-1, 1)
        linenos = linenos * len(vals)
    if vals.shape[1] != 1:
        raise ValueError(f"{path}:{linenos[0]}: expected one column in the .vts file, found {vals.shape[1]}")
    idx = _as_int(path, vals, linenos, ".vts")[:, 0]
    _check_range(path, idx, 1, n_reference, linenos, ".vts", "vertex")
    return idx - 1


def read_p2p(path: PathType, n_vertices: int | None = None, n_other: int | None = None) -> IndexArray:
    """Read a plain vertex map: one one-based index per line, ``0`` or ``-1`` = unmatched.

    Returns
    -------
    p2p : ndarray, shape (n_vertices,)
        Zero-based indices on the other shape, ``-1`` where unmatched.
    """
    path, vals, linenos = _read_table(path, "vertex map")
    if vals.shape[0] == 1 and vals.shape[1] > 1:
        vals = vals.reshape(-1, 1)
        linenos = linenos * len(vals)
    if vals.shape[1] != 1:
        raise ValueError(f"{path}:{linenos[0]}: expected one column in the vertex map file, found {vals.shape[1]}")
    idx = _as_int(path, vals, linenos, "vertex map")[:, 0]
    if n_vertices is not None and len(idx) != n_vertices:
        raise ValueError(f"{path}: vertex map has {len(idx)} rows, expected one per vertex ({n_vertices})")
    _check_range(path, idx, -1, n_other, linenos, "vertex map", "vertex")
    out = idx - 1
    out[idx <= 0] = -1
    return out


def read_shrec16_map(
    path: PathType,
    faces_other: IndexArray,
    n_vertices: int | None = None,
    *,
    return_barycentric: bool = False,
) -> IndexArray | tuple[IndexArray, IndexArray, FloatArray]:
    """Read a SHREC'16 submission file (``t w1 w2 w3`` per row, ``-1 0 0 0`` = unmatched).

    Parameters
    ----------
    path : str or PathLike
        The submission file: one row per vertex of the mapped shape.
    faces_other : ndarray, shape (n_faces, 3)
        Triangles of the shape the rows point into (``t`` is a one-based row of it).
    n_vertices : int, optional
        Vertex count of the mapped shape, checked against the row count.
    return_barycentric : bool
        Also return the triangle indices and weights.

    Returns
    -------
    p2p : ndarray, shape (n_vertices,)
        For each row, the corner of ``t`` with the largest weight (zero-based vertex
        index), ``-1`` where unmatched.
    triangles : ndarray, shape (n_vertices,)
        Zero-based triangle per row, ``-1`` where unmatched (only if requested).
    weights : ndarray, shape (n_vertices, 3)
        Barycentric weights (only if requested).
    """
    faces_other = np.asarray(faces_other, dtype=np.int64)
    path, vals, linenos = _read_table(path, "SHREC'16 map")
    if vals.shape[1] != 4:
        raise ValueError(f"{path}:{linenos[0]}: expected 4 columns 'triangle w1 w2 w3' in the SHREC'16 map, found {vals.shape[1]}")
    if n_vertices is not None and len(vals) != n_vertices:
        raise ValueError(f"{path}: SHREC'16 map has {len(vals)} rows, expected one per vertex ({n_vertices})")
    tri = _as_int(path, vals[:, :1], linenos, "SHREC'16 map")[:, 0]
    unmatched = tri == -1
    _check_range(path, np.where(unmatched, 1, tri), 1, len(faces_other), linenos, "SHREC'16 map", "triangle")
    w = vals[:, 1:]
    bad = ~unmatched & ~(np.all(w >= -1e-6, axis=1) & (np.abs(w.sum(axis=1) - 1.0) < 1e-3))
    if np.any(bad):
        b = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{path}:{linenos[b]}: barycentric weights {w[b].tolist()} must be >= 0 and sum to 1")
    t0 = np.where(unmatched, 0, tri - 1)
    corner = np.argmax(w, axis=1)
    p2p = faces_other[t0, corner]
    p2p[unmatched] = -1
    if return_barycentric:
        return p2p, np.where(unmatched, -1, t0), w
    return p2p


def _atomic_write_text(path: PathType, text: str) -> None:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text, encoding="ascii")
    os.replace(tmp, path)


def write_ref(path: PathType, pairs: IndexArray) -> None:
    """Write a ``_ref`` file from zero-based ``(vertex, reference vertex)`` rows, shape (n_pairs, 2)."""
    pairs = np.asarray(pairs, dtype=np.int64) + 1
    _atomic_write_text(path, "".join(f"{a:6d} {b:6d}\n" for a, b in pairs))


def write_sym(path: PathType, sym: IndexArray) -> None:
    """Write a two-column ``_sym`` file from ``sym`` of shape (n_vertices,), ``-1`` = none."""
    sym = np.asarray(sym, dtype=np.int64)
    _atomic_write_text(path, "".join(f"{i + 1:6d} {j + 1:6d}\n" for i, j in enumerate(sym)))


def write_indmap(path: PathType, no_match: BoolArray) -> None:
    """Write an ``_indmap`` file (``1`` = no reliable ground truth), shape (n_vertices,)."""
    _atomic_write_text(path, "".join("1\n" if b else "0\n" for b in np.asarray(no_match, dtype=bool)))


def write_vts(path: PathType, idx: IndexArray) -> None:
    """Write a one-column ``.vts`` file from zero-based indices, shape (n,)."""
    _atomic_write_text(path, "".join(f"{i + 1}\n" for i in np.asarray(idx, dtype=np.int64)))


def write_p2p(path: PathType, p2p: IndexArray) -> None:
    """Write a plain vertex map (one-based, ``0`` = unmatched) from ``p2p`` of shape (n,)."""
    _atomic_write_text(path, "".join(f"{i + 1}\n" for i in np.asarray(p2p, dtype=np.int64)))


def write_shrec16_map(path: PathType, p2p: IndexArray, faces_other: IndexArray) -> None:
    """Write a vertex map in the SHREC'16 submission format.

    Each matched vertex ``j`` of the other shape is written as a triangle containing it
    (the first one found) with weight 1 on that corner; unmatched rows are ``-1 0 0 0``.

    Parameters
    ----------
    p2p : ndarray, shape (n_vertices,)
        Zero-based vertex indices on the other shape, ``-1`` = unmatched.
    faces_other : ndarray, shape (n_faces, 3)
        Triangles of the other shape.
    """
    p2p = np.asarray(p2p, dtype=np.int64)
    faces_other = np.asarray(faces_other, dtype=np.int64)
    n_other = int(faces_other.max()) + 1 if faces_other.size else 0
    first_face = np.full(n_other, len(faces_other), dtype=np.int64)  # lowest face holding each vertex
    for c in range(3):
        np.minimum.at(first_face, faces_other[:, c], np.arange(len(faces_other)))
    rows = []
    for j in p2p:
        if j < 0:
            rows.append("-1 0 0 0\n")
            continue
        t = first_face[j]
        if t >= len(faces_other):
            raise ValueError(f"vertex {j} of the other shape belongs to no triangle; cannot write it as a SHREC'16 row")
        w = (faces_other[t] == j).astype(int)
        rows.append(f"{t + 1} {w[0]} {w[1]} {w[2]}\n")
    _atomic_write_text(path, "".join(rows))
