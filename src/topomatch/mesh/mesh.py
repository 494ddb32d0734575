"""The immutable triangle mesh with lazily computed, cached derived data."""

from __future__ import annotations

import logging
import multiprocessing
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from scipy import sparse

from topomatch import _cache
from topomatch._fork import fork_is_safe
from topomatch._validation import check_faces, check_vertices
from topomatch.mesh import geometry
from topomatch.mesh.geodesics import GeodesicKind, GeodesicSolver, make_geodesic_solver
from topomatch.mesh.laplacian import LaplacianKind, laplacian
from topomatch.mesh.spectral import Eigenbasis, laplacian_eigenbasis
from topomatch.typing import BoolArray, FloatArray, IndexArray, PathType

__all__ = ["EigenbasisJob", "TriangleMesh"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """Immutable triangle mesh.

    Arrays are validated once and made read-only; every derived quantity (areas,
    Laplacian, eigenbasis, topology) is computed on first use and cached on the
    instance, so it can never go stale. Any geometric change makes a new mesh.

    Parameters
    ----------
    vertices : array_like, shape (n_vertices, 3)
    faces : array_like, shape (n_faces, 3)
        Zero-based vertex indices.
    name : str
        Used in messages and reports.

    Examples
    --------
    >>> from topomatch.datasets.toy import icosphere
    >>> mesh = icosphere(1)
    >>> mesh.n_vertices, mesh.n_faces, mesh.genus
    (42, 80, 0)
    """

    vertices: FloatArray
    faces: IndexArray
    name: str = ""
    _eig: dict[str, Eigenbasis] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        v = check_vertices(self.vertices, f"{self.name or 'mesh'} vertices")
        f = check_faces(self.faces, len(v), f"{self.name or 'mesh'} faces")
        if len(f) == 0:
            raise ValueError(f"{self.name or 'mesh'}: a mesh needs at least one face")
        v = v.copy()
        f = f.copy()
        v.flags.writeable = False
        f.flags.writeable = False
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @classmethod
    def from_file(cls, path: PathType, name: str | None = None) -> TriangleMesh:
        """Read an OFF / PLY / OBJ file."""
        from pathlib import Path

        from topomatch.io import read_mesh

        v, f = read_mesh(path)
        if len(f) == 0:  # a valid file (a point cloud) but not a mesh: say which file
            raise ValueError(f"{path}: no faces (a mesh needs at least one)")
        return cls(v, f, name=Path(path).stem if name is None else name)

    def __repr__(self) -> str:
        return f"TriangleMesh(name={self.name!r}, n_vertices={self.n_vertices}, n_faces={self.n_faces})"

    # ---- sizes and geometry -------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        """Number of triangles."""
        return len(self.faces)

    @cached_property
    def face_areas(self) -> FloatArray:
        """Triangle areas, shape (n_faces,)."""
        return geometry.face_areas(self.vertices, self.faces)

    @cached_property
    def area(self) -> float:
        """Total surface area."""
        return float(self.face_areas.sum())

    @cached_property
    def vertex_areas(self) -> FloatArray:
        """Barycentric lumped vertex areas, shape (n_vertices,); they sum to ``area``."""
        return geometry.vertex_areas(self.vertices, self.faces)

    @cached_property
    def face_normals(self) -> FloatArray:
        """Unit face normals, shape (n_faces, 3)."""
        return geometry.face_normals(self.vertices, self.faces)

    @cached_property
    def vertex_normals(self) -> FloatArray:
        """Area-weighted unit vertex normals, shape (n_vertices, 3)."""
        return geometry.vertex_normals(self.vertices, self.faces)

    @cached_property
    def content_hash(self) -> str:
        """SHA-256 of the vertex and face arrays (cache key)."""
        return _cache.array_hash(self.vertices, self.faces)

    # ---- topology -------------------------------------------------------------------------
    @cached_property
    def edges(self) -> IndexArray:
        """Unique undirected edges, shape (n_edges, 2)."""
        return geometry.edges_with_counts(self.faces)[0]

    @cached_property
    def duplicate_faces(self) -> IndexArray:
        """Indices of faces whose vertex set repeats an earlier face, shape (n,)."""
        _, first = np.unique(np.sort(self.faces, axis=1), axis=0, return_index=True)
        mask = np.ones(self.n_faces, dtype=bool)
        mask[first] = False
        return np.flatnonzero(mask)

    @cached_property
    def _faces_unique(self) -> IndexArray:
        if len(self.duplicate_faces) == 0:
            return self.faces
        return np.delete(self.faces, self.duplicate_faces, axis=0)

    @cached_property
    def non_manifold_edges(self) -> IndexArray:
        """Edges held by three or more faces, shape (n, 2) (duplicated faces counted)."""
        return geometry.non_manifold_edges(self.faces)

    @cached_property
    def boundary_loops(self) -> list[IndexArray]:
        """Boundary loops (duplicated faces ignored), longest first."""
        return geometry.boundary_loops(self._faces_unique)

    @cached_property
    def _components(self) -> tuple[int, IndexArray]:
        return geometry.connected_components(self.n_vertices, self.faces)

    @property
    def n_components(self) -> int:
        """Number of face-connected components."""
        return self._components[0]

    @property
    def component_labels(self) -> IndexArray:
        """Component of each vertex, shape (n_vertices,); ``-1`` for unreferenced vertices."""
        return self._components[1]

    @cached_property
    def unreferenced_vertices(self) -> IndexArray:
        """Vertices that belong to no face, shape (n,)."""
        return np.flatnonzero(~geometry.referenced_vertices(self.n_vertices, self.faces))

    @cached_property
    def euler_characteristic(self) -> int:
        """``V - E + F`` over referenced vertices, duplicated faces counted once."""
        n_used = self.n_vertices - len(self.unreferenced_vertices)
        return geometry.euler_characteristic(n_used, self._faces_unique)

    @cached_property
    def genus(self) -> int:
        """Total genus, from ``chi = sum_c (2 - 2 g_c - b_c)``.

        Only meaningful on manifold meshes; on non-manifold input it is the genus of the
        formula and may not be an integer, in which case it is rounded down.
        """
        g2 = 2 * self.n_components - self.euler_characteristic - len(self.boundary_loops)
        return int(g2 // 2)

    @cached_property
    def is_manifold(self) -> bool:
        """True when no edge has more than two faces (after removing duplicated faces)."""
        return len(geometry.non_manifold_edges(self._faces_unique)) == 0

    def summary(self) -> dict[str, Any]:
        """Counts and topology as a plain dictionary (for ``topomatch data info``)."""
        return {
            "name": self.name,
            "n_vertices": self.n_vertices,
            "n_faces": self.n_faces,
            "area": self.area,
            "n_components": self.n_components,
            "n_boundary_loops": len(self.boundary_loops),
            "euler_characteristic": self.euler_characteristic,
            "genus": self.genus,
            "non_manifold_edges": len(self.non_manifold_edges),
            "duplicate_faces": len(self.duplicate_faces),
            "unreferenced_vertices": len(self.unreferenced_vertices),
        }

    # ---- operators ---------------------------------------------------------------------------
    def laplacian(self, kind: LaplacianKind = "robust") -> tuple[sparse.csc_matrix, sparse.dia_matrix]:
        """Stiffness ``L`` (PSD) and lumped mass ``M``, cached per kind."""
        key = f"_lap_{kind}"
        if key not in self.__dict__:
            self.__dict__[key] = laplacian(self.vertices, self.faces, kind)
        return self.__dict__[key]

    def eigenbasis(self, k: int, *, kind: LaplacianKind = "robust") -> Eigenbasis:
        """The ``k`` smallest Laplacian eigenpairs.

        Slices a basis of ``k`` or more eigenpairs already computed on this mesh;
        otherwise solves for ``k`` (or loads them from the disk cache, when one is
        configured: see :mod:`topomatch._cache`). The disk cache keeps one entry per
        ``k``: a solve for fewer eigenpairs does not give the same bits as slicing a
        larger one, and a result must not depend on what the cache holds.
        """
        if self._has_eigenbasis(k, kind):
            return self._eig[kind].truncate(k)
        key = self._eigenbasis_key(k, kind)
        stored = _cache.load("eigen", key)
        if stored is not None and stored["evals"].shape[0] == k:
            basis = Eigenbasis(stored["evals"], stored["evecs"], stored["mass"])
        else:
            L, M = self.laplacian(kind)
            basis = laplacian_eigenbasis(L, M, k)
            _cache.save("eigen", key, {"evals": basis.evals, "evecs": basis.evecs, "mass": basis.mass})
        self._eig[kind] = basis
        return basis.truncate(k)

    def eigenbasis_in_background(self, k: int, *, kind: LaplacianKind = "robust") -> EigenbasisJob:
        """Start :meth:`eigenbasis` in a forked process; ``.result()`` waits and caches it here.

        The eigensolver (ARPACK and the Cholesky solves) holds the GIL, so a thread
        computing it stalls every other Python thread; a child process does not. The
        child computes exactly what :meth:`eigenbasis` would (same code, one BLAS
        thread), so the result is the same bits. Computes in this process instead (at
        ``result()``) where ``fork`` is unavailable, for meshes below
        ``BACKGROUND_MIN_VERTICES`` (the fork would cost more than the solve), when the
        basis is already cached (in memory or on disk), when another non-daemon thread
        is running (it could hold a lock at the fork that the child would wait for), or
        if the child fails.

        Parameters
        ----------
        k : int
            Number of eigenpairs.
        kind : str
            Laplacian kind.

        Returns
        -------
        EigenbasisJob
        """
        return EigenbasisJob(self, k, kind)

    def _eigenbasis_key(self, k: int, kind: LaplacianKind) -> str:
        """The disk cache's key of this mesh's ``k``-eigenpair basis."""
        return _cache.array_hash(self.vertices, self.faces, extra=f"eig:{kind}:{k}")

    def _has_eigenbasis(self, k: int, kind: LaplacianKind) -> bool:
        have = self._eig.get(kind)
        return have is not None and have.k >= k

    def _adopt_eigenbasis(self, basis: Eigenbasis, kind: LaplacianKind) -> None:
        have = self._eig.get(kind)
        if have is None or have.k < basis.k:
            self._eig[kind] = basis

    def geodesic_solver(self, kind: GeodesicKind = "heat") -> GeodesicSolver:
        """A geodesic solver for this mesh, cached per kind."""
        key = f"_geo_{kind}"
        if key not in self.__dict__:
            self.__dict__[key] = make_geodesic_solver(self.vertices, self.faces, kind)
        return self.__dict__[key]

    def __getstate__(self) -> dict:
        """Pickle without geodesic solvers (they hold native factorisations; rebuilt on use)."""
        return {k: v for k, v in self.__dict__.items() if not k.startswith("_geo_")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)

    def drop_caches(self) -> None:
        """Forget cached operators, bases and solvers (to free memory)."""
        for k in [k for k in self.__dict__ if k.startswith(("_lap_", "_geo_"))]:
            del self.__dict__[k]
        self._eig.clear()

    def mask_vertices_used(self) -> BoolArray:
        """Mask of vertices in at least one face, shape (n_vertices,)."""
        return geometry.referenced_vertices(self.n_vertices, self.faces)


# below this size a fork costs more than the eigensolver it takes off this process
BACKGROUND_MIN_VERTICES = 3000


class EigenbasisJob:
    """An eigenbasis being computed in a forked process (:meth:`TriangleMesh.eigenbasis_in_background`)."""

    def __init__(self, mesh: TriangleMesh, k: int, kind: LaplacianKind) -> None:
        self.mesh, self.k, self.kind = mesh, k, kind
        self._process: Any = None
        self._conn: Any = None
        if mesh.n_vertices < BACKGROUND_MIN_VERTICES or mesh._has_eigenbasis(k, kind):
            return
        if not fork_is_safe():
            # e.g. another thread of the caller's may hold a lock (BLAS, allocator) at
            # the fork, which the child would wait for forever: compute here instead
            return
        if _cache.exists("eigen", mesh._eigenbasis_key(k, kind)):
            return  # loading beats forking
        ctx = multiprocessing.get_context("fork")
        receive, send = ctx.Pipe(duplex=False)
        try:
            process = ctx.Process(target=_eigenbasis_child, args=(mesh, k, kind, send), daemon=True)
            process.start()
        except OSError as err:  # out of processes or memory: compute it here later
            logger.warning("%s: could not fork for the eigenbasis (%s); computing it in this process", mesh.name or "mesh", err)
            receive.close()
            return
        finally:
            send.close()
        self._process, self._conn = process, receive

    def result(self) -> Eigenbasis:
        """The ``k`` eigenpairs (waits for the child; computes them here if it failed)."""
        if self._process is not None:
            process, conn = self._process, self._conn
            self._process = self._conn = None
            try:
                status, payload = conn.recv()
            except (EOFError, OSError) as err:
                status, payload = "error", f"the child process ended without a result ({err!r})"
            finally:
                conn.close()
                process.join()
            if status == "ok":
                self.mesh._adopt_eigenbasis(Eigenbasis(*payload), self.kind)
            else:
                logger.warning("%s: background eigenbasis failed (%s); computing it in this process", self.mesh.name or "mesh", payload)
        return self.mesh.eigenbasis(self.k, kind=self.kind)

    def __del__(self) -> None:  # an abandoned job: do not leave the child behind
        process = getattr(self, "_process", None)
        if process is not None:
            self._conn.close()
            process.kill()
            process.join()


def _eigenbasis_child(mesh: TriangleMesh, k: int, kind: LaplacianKind, conn: Any) -> None:
    try:
        b = mesh.eigenbasis(k, kind=kind)
        conn.send(("ok", (b.evals, b.evecs, b.mass)))
    except BaseException as err:  # reported to the parent, which recomputes
        conn.send(("error", f"{type(err).__name__}: {err}"))
    finally:
        conn.close()
