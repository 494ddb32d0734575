"""Read and write triangle meshes: OFF, PLY (ASCII and binary) and OBJ.

All readers return ``(vertices, faces)`` with ``vertices`` of shape ``(n_vertices, 3)``
(float64) and ``faces`` of shape ``(n_faces, 3)`` (int64, 0-based). Polygons with more
than three corners are split into a triangle fan. Malformed files raise ``ValueError``
naming the file, the line (or byte offset for binary PLY) and what was expected.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from topomatch.typing import FloatArray, IndexArray, PathType

__all__ = ["read_mesh", "read_obj", "read_off", "read_ply", "write_mesh", "write_obj", "write_off", "write_ply"]


class _Lines:
    """Iterator over the meaningful lines of a text file, keeping line numbers."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.lines = text.splitlines()
        self.i = 0

    def next(self, what: str) -> tuple[int, list[str]]:
        while self.i < len(self.lines):
            raw = self.lines[self.i]
            self.i += 1
            content = raw.split("#", 1)[0].strip()
            if content:
                return self.i, content.split()
        raise ValueError(f"{self.path}: unexpected end of file, expected {what}")


def _fan(polys: list[list[int]]) -> list[list[int]]:
    tris: list[list[int]] = []
    for p in polys:
        tris.extend([p[0], p[j], p[j + 1]] for j in range(1, len(p) - 1))
    return tris


def _finish(path: Path, vertices: FloatArray, faces: IndexArray) -> tuple[FloatArray, IndexArray]:
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        bad = int(np.flatnonzero((faces < 0).any(1) | (faces >= len(vertices)).any(1))[0])
        raise ValueError(
            f"{path}: face {bad} refers to vertex {faces[bad].tolist()} but the file has "
            f"{len(vertices)} vertices"
        )
    if not np.all(np.isfinite(vertices)):
        bad = int(np.flatnonzero(~np.isfinite(vertices).all(1))[0])
        raise ValueError(f"{path}: vertex {bad} has a non-finite coordinate")
    return vertices, faces


def read_off(path: PathType) -> tuple[FloatArray, IndexArray]:
    """Read an ASCII OFF file.

    Parameters
    ----------
    path : str or PathLike
        The ``.off`` file. ``OFF``, ``COFF`` and ``NOFF`` headers are accepted; the counts
        may follow the keyword on the same line. Per-vertex extras (colours, normals)
        and per-face colours are ignored.

    Returns
    -------
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="ascii", errors="strict")
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not an ASCII OFF file (binary OFF is not supported)") from err
    lines = _Lines(path, text)
    ln, tok = lines.next("the OFF header")
    key = tok[0].upper()
    if not key.endswith("OFF"):
        raise ValueError(f"{path}:{ln}: expected an 'OFF' header, found {tok[0]!r}")
    counts = tok[1:]
    if not counts:
        ln, counts = lines.next("the counts line 'n_vertices n_faces n_edges'")
    try:
        nv, nf = int(counts[0]), int(counts[1])
    except (ValueError, IndexError) as err:
        raise ValueError(f"{path}:{ln}: expected 'n_vertices n_faces [n_edges]', found {' '.join(counts)!r}") from err
    if nv < 0 or nf < 0:
        raise ValueError(f"{path}:{ln}: negative counts {nv} {nf}")
    fast = _off_fast(lines, nv, nf)
    if fast is not None:
        return _finish(path, *fast)
    vertices = np.empty((nv, 3))
    for i in range(nv):
        ln, tok = lines.next(f"vertex {i} of {nv}")
        try:
            vertices[i] = [float(t) for t in tok[:3]]
        except ValueError as err:
            raise ValueError(f"{path}:{ln}: expected three coordinates for vertex {i}, found {' '.join(tok)!r}") from err
    polys: list[list[int]] = []
    for i in range(nf):
        ln, tok = lines.next(f"face {i} of {nf}")
        try:
            n = int(tok[0])
            idx = [int(t) for t in tok[1 : 1 + n]]
        except ValueError as err:
            raise ValueError(f"{path}:{ln}: expected 'n i1 ... in' for face {i}, found {' '.join(tok)!r}") from err
        if n < 3 or len(idx) != n:
            raise ValueError(f"{path}:{ln}: face {i} declares {n} corners but lists {len(idx)} (need >= 3)")
        polys.append(idx)
    faces = np.asarray(_fan(polys), dtype=np.int64).reshape(-1, 3)
    return _finish(path, vertices, faces)


def _off_fast(lines: _Lines, nv: int, nf: int) -> tuple[FloatArray, IndexArray] | None:
    """Vectorised OFF body parser for the common case; ``None`` means: use the careful path."""
    start = lines.i
    body = lines.lines[start:]
    if any("#" in ln for ln in body):
        return None
    body = [ln for ln in body if ln.strip()]
    if len(body) < nv + nf:
        return None
    try:
        v = np.array(" ".join(body[:nv]).split(), dtype=np.float64)
        f = np.array(" ".join(body[nv : nv + nf]).split(), dtype=np.int64)
    except ValueError:
        return None
    if v.size != 3 * nv or f.size != 4 * nf:
        return None
    f = f.reshape(nf, 4)
    if nf and not np.all(f[:, 0] == 3):
        return None
    return v.reshape(nv, 3), np.ascontiguousarray(f[:, 1:])


def read_obj(path: PathType) -> tuple[FloatArray, IndexArray]:
    """Read a Wavefront OBJ file (``v`` and ``f`` records; texture/normal indices ignored).

    Negative (relative) indices are supported. Returns ``(vertices, faces)`` as
    :func:`read_off`.
    """
    path = Path(path)
    verts: list[list[float]] = []
    polys: list[list[int]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for ln, raw in enumerate(fh, start=1):
            content = raw.split("#", 1)[0].split()
            if not content:
                continue
            key = content[0]
            if key == "v":
                try:
                    verts.append([float(t) for t in content[1:4]])
                except ValueError as err:
                    raise ValueError(f"{path}:{ln}: expected 'v x y z', found {raw.strip()!r}") from err
                if len(verts[-1]) != 3:
                    raise ValueError(f"{path}:{ln}: expected 'v x y z', found {raw.strip()!r}")
            elif key == "f":
                try:
                    idx = [int(t.split("/")[0]) for t in content[1:]]
                except ValueError as err:
                    raise ValueError(f"{path}:{ln}: expected 'f i j k' with integer indices, found {raw.strip()!r}") from err
                if len(idx) < 3 or 0 in idx:
                    raise ValueError(f"{path}:{ln}: a face needs >= 3 one-based indices, found {raw.strip()!r}")
                n = len(verts)
                polys.append([i - 1 if i > 0 else n + i for i in idx])
    faces = np.asarray(_fan(polys), dtype=np.int64).reshape(-1, 3)
    return _finish(path, np.asarray(verts, dtype=np.float64).reshape(-1, 3), faces)


_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def read_ply(path: PathType) -> tuple[FloatArray, IndexArray]:
    """Read a PLY file, ASCII or binary (little or big endian).

    Only the ``vertex`` (``x``, ``y``, ``z``) and ``face`` (``vertex_indices`` or
    ``vertex_index`` list) elements are used; other elements and properties are skipped.
    Returns ``(vertices, faces)`` as :func:`read_off`.
    """
    path = Path(path)
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file (expected 'ply' ... 'end_header')")
    nl = data.find(b"\n", end)
    body_start = nl + 1 if nl >= 0 else len(data)
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[tuple[str, int, list[tuple]]] = []
    for ln, line in enumerate(header, start=1):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info", "ply"):
            continue
        if tok[0] == "format":
            fmt = tok[1] if len(tok) > 1 else ""
        elif tok[0] == "element":
            if len(tok) != 3:
                raise ValueError(f"{path}:{ln}: expected 'element NAME COUNT', found {line!r}")
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if not elements:
                raise ValueError(f"{path}:{ln}: property before any element")
            if tok[1] == "list":
                if len(tok) != 5 or tok[2] not in _PLY_TYPES or tok[3] not in _PLY_TYPES:
                    raise ValueError(f"{path}:{ln}: malformed list property {line!r}")
                elements[-1][2].append(("list", tok[4], _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]]))
            else:
                if len(tok) != 3 or tok[1] not in _PLY_TYPES:
                    raise ValueError(f"{path}:{ln}: malformed property {line!r}")
                elements[-1][2].append(("scalar", tok[2], _PLY_TYPES[tok[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"{path}: unknown PLY format {fmt!r}")
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise ValueError(f"{path}: PLY header declares no 'vertex' element")
    vertices = None
    faces = np.zeros((0, 3), dtype=np.int64)
    if fmt == "ascii":
        lines = _Lines(path, data[body_start:].decode("ascii", errors="replace"))
        offset = data[:body_start].count(b"\n")
        for name, count, props in elements:
            rows = []
            for i in range(count):
                ln, tok = lines.next(f"{name} {i} of {count}")
                vals, k = {}, 0
                try:
                    for p in props:
                        if p[0] == "list":
                            n = int(tok[k])
                            vals[p[1]] = [int(float(t)) for t in tok[k + 1 : k + 1 + n]]
                            if len(vals[p[1]]) != n:
                                raise ValueError
                            k += 1 + n
                        else:
                            vals[p[1]] = float(tok[k])
                            k += 1
                except (ValueError, IndexError) as err:
                    raise ValueError(f"{path}:{ln + offset}: malformed {name} record {' '.join(tok)!r}") from err
                rows.append(vals)
            if name == "vertex":
                try:
                    vertices = np.array([[r["x"], r["y"], r["z"]] for r in rows], dtype=np.float64).reshape(-1, 3)
                except KeyError as err:
                    raise ValueError(f"{path}: vertex element lacks property {err}") from err
            elif name == "face":
                key = _face_key(path, props)
                faces = np.asarray(_fan([r[key] for r in rows]), dtype=np.int64).reshape(-1, 3)
    else:
        endian = "<" if fmt == "binary_little_endian" else ">"
        pos = body_start
        for name, count, props in elements:
            if all(p[0] == "scalar" for p in props):
                dt = np.dtype([(p[1], endian + p[2]) for p in props])
                need = dt.itemsize * count
                if pos + need > len(data):
                    raise ValueError(f"{path}: file ends inside element '{name}' (byte {len(data)}, need {pos + need})")
                arr = np.frombuffer(data, dtype=dt, count=count, offset=pos)
                pos += need
                if name == "vertex":
                    try:
                        vertices = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
                    except (KeyError, ValueError) as err:
                        raise ValueError(f"{path}: vertex element lacks x/y/z") from err
                continue
            if name == "face":
                key = _face_key(path, props)
            out, pos = _read_binary_lists(path, data, pos, count, props, endian, name)
            if name == "face":
                faces = np.asarray(_fan(out[key]), dtype=np.int64).reshape(-1, 3)
    if vertices is None:
        raise ValueError(f"{path}: no vertices read")
    return _finish(path, vertices, faces)


def _face_key(path: Path, props: list[tuple]) -> str:
    for p in props:
        if p[0] == "list" and p[1] in ("vertex_indices", "vertex_index"):
            return p[1]
    raise ValueError(f"{path}: face element has no 'vertex_indices' list property")


def _read_binary_lists(path, data, pos, count, props, endian, name):
    out: dict[str, list] = {p[1]: [] for p in props}
    # fast path: a single list of constant length 3 (the usual triangle mesh)
    if len(props) == 1 and props[0][0] == "list":
        _, pname, ctype, itype = props[0]
        cdt, idt = np.dtype(endian + ctype), np.dtype(endian + itype)
        if pos + cdt.itemsize <= len(data):
            n0 = int(np.frombuffer(data, dtype=cdt, count=1, offset=pos)[0])
            rec = np.dtype([("n", cdt), ("i", idt, (n0,))])
            if n0 >= 3 and pos + rec.itemsize * count <= len(data):
                arr = np.frombuffer(data, dtype=rec, count=count, offset=pos)
                if np.all(arr["n"] == n0):
                    out[pname] = arr["i"].astype(np.int64).tolist()
                    return out, pos + rec.itemsize * count
    for i in range(count):
        for p in props:
            if p[0] == "list":
                cdt, idt = np.dtype(endian + p[2]), np.dtype(endian + p[3])
                if pos + cdt.itemsize > len(data):
                    raise ValueError(f"{path}: file ends inside {name} {i} (byte {pos})")
                n = int(np.frombuffer(data, dtype=cdt, count=1, offset=pos)[0])
                pos += cdt.itemsize
                if pos + idt.itemsize * n > len(data):
                    raise ValueError(f"{path}: file ends inside {name} {i} (byte {pos})")
                out[p[1]].append(np.frombuffer(data, dtype=idt, count=n, offset=pos).astype(np.int64).tolist())
                pos += idt.itemsize * n
            else:
                dt = np.dtype(endian + p[2])
                if pos + dt.itemsize > len(data):
                    raise ValueError(f"{path}: file ends inside {name} {i} (byte {pos})")
                out[p[1]].append(np.frombuffer(data, dtype=dt, count=1, offset=pos)[0])
                pos += dt.itemsize
    return out, pos


_READERS = {".off": read_off, ".ply": read_ply, ".obj": read_obj}


def read_mesh(path: PathType) -> tuple[FloatArray, IndexArray]:
    """Read a triangle mesh, choosing the reader from the file suffix.

    Parameters
    ----------
    path : str or PathLike
        An ``.off``, ``.ply`` or ``.obj`` file.

    Returns
    -------
    vertices : ndarray, shape (n_vertices, 3)
    faces : ndarray, shape (n_faces, 3)
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such mesh file")
    reader = _READERS.get(path.suffix.lower())
    if reader is None:
        raise ValueError(f"{path}: unknown mesh format {path.suffix!r} (expected .off, .ply or .obj)")
    return reader(path)


def _atomic_write_bytes(path: Path, payload: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "wb") as fh:
        fh.write(payload)
    os.replace(tmp, path)


def write_off(path: PathType, vertices: FloatArray, faces: IndexArray) -> None:
    """Write an ASCII OFF file (coordinates with 9 significant digits)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    lines = [f"OFF\n{len(v)} {len(f)} 0\n"]
    lines.append("".join(f"{x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in v))
    lines.append("".join(f"3 {a} {b} {c}\n" for a, b, c in f))
    _atomic_write_bytes(Path(path), "".join(lines).encode("ascii"))


def write_obj(path: PathType, vertices: FloatArray, faces: IndexArray) -> None:
    """Write a Wavefront OBJ file (one-based face indices)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64) + 1
    text = "".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in v)
    text += "".join(f"f {a} {b} {c}\n" for a, b, c in f)
    _atomic_write_bytes(Path(path), text.encode("ascii"))


def write_ply(path: PathType, vertices: FloatArray, faces: IndexArray, *, binary: bool = True) -> None:
    """Write a PLY file, binary little endian (default) or ASCII."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fmt = "binary_little_endian" if binary else "ascii"
    header = (
        f"ply\nformat {fmt} 1.0\nelement vertex {len(v)}\nproperty double x\nproperty double y\n"
        f"property double z\nelement face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode("ascii")
    if binary:
        vb = v.astype("<f8").tobytes()
        rec = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        rec["n"] = 3
        rec["i"] = f
        body = vb + rec.tobytes()
    else:
        body = ("".join(f"{x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in v) + "".join(f"3 {a} {b} {c}\n" for a, b, c in f)).encode("ascii")
    _atomic_write_bytes(Path(path), header + body)


_WRITERS = {".off": write_off, ".ply": write_ply, ".obj": write_obj}


def write_mesh(path: PathType, vertices: FloatArray, faces: IndexArray) -> None:
    """Write a triangle mesh, choosing the format from the file suffix (atomic)."""
    path = Path(path)
    writer = _WRITERS.get(path.suffix.lower())
    if writer is None:
        raise ValueError(f"{path}: unknown mesh format {path.suffix!r} (expected .off, .ply or .obj)")
    writer(path, vertices, faces)

