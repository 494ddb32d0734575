"""Shapes with ground truth to a reference shape, and collections of them."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy import sparse

from topomatch.mesh import TriangleMesh
from topomatch.typing import BoolArray, IndexArray

__all__ = ["Shape", "ShapeCollection", "ground_truth_21", "ref_matrix"]


def ref_matrix(pairs: IndexArray, n_vertices: int, n_reference: int) -> sparse.csr_matrix:
    """Boolean ground-truth matrix from ``(vertex, reference vertex)`` rows.

    Parameters
    ----------
    pairs : ndarray, shape (n_pairs, 2)
    n_vertices, n_reference : int

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_vertices, n_reference)
        Entry ``(i, j)`` is 1 when vertex ``i`` corresponds to reference vertex ``j``.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    m = sparse.csr_matrix(
        (np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n_vertices, n_reference)
    )
    m.sum_duplicates()
    m.data[:] = 1
    return m


@dataclass(frozen=True, eq=False)
class Shape:
    """A mesh with its ground truth to the collection's reference (null) shape.

    Attributes
    ----------
    name : str
    mesh : TriangleMesh
    ref : scipy.sparse.csr_matrix, shape (n_vertices, n_reference), or None
        Ground truth to the reference shape; a row may hold several entries
        (many-to-many at TOPKIDS high res) or none.
    sym : ndarray, shape (n_vertices,), or None
        Left-right mirror vertex on this shape, ``-1`` where none.
    unreliable : ndarray of bool, shape (n_vertices,), or None
        Vertices whose ground truth is not reliable (TOPKIDS ``_indmap``); they are
        excluded from evaluation.
    """

    name: str
    mesh: TriangleMesh
    ref: sparse.csr_matrix | None = None
    sym: IndexArray | None = None
    unreliable: BoolArray | None = None

    def __post_init__(self) -> None:
        n = self.mesh.n_vertices
        if self.ref is not None and self.ref.shape[0] != n:
            raise ValueError(f"{self.name}: ground truth has {self.ref.shape[0]} rows for {n} vertices")
        if self.sym is not None and len(self.sym) != n:
            raise ValueError(f"{self.name}: symmetry map has {len(self.sym)} entries for {n} vertices")
        if self.unreliable is not None and len(self.unreliable) != n:
            raise ValueError(f"{self.name}: unreliable mask has {len(self.unreliable)} entries for {n} vertices")

    @property
    def n_vertices(self) -> int:
        """Number of mesh vertices."""
        return self.mesh.n_vertices

    @cached_property
    def ref_p2p(self) -> IndexArray:
        """One reference vertex per vertex (the first listed), ``-1`` where none, shape (n_vertices,)."""
        if self.ref is None:
            raise ValueError(f"{self.name} has no ground truth")
        out = np.full(self.n_vertices, -1, dtype=np.int64)
        r = self.ref.tocsr()
        has = np.diff(r.indptr) > 0
        out[has] = r.indices[r.indptr[:-1][has]]
        return out


def ground_truth_21(target: Shape, source: Shape, *, mirrored: bool = False) -> sparse.csr_matrix:
    """Acceptable source vertices for each target vertex, composed through the reference.

    ``y`` on the source is a correct image of ``x`` on the target when they share a
    reference vertex: ``ref_source(y) & ref_target(x)`` is not empty. Vertices flagged
    unreliable on either side are removed. With ``mirrored=True`` every acceptable
    ``y`` is replaced by its left-right mirror ``source.sym[y]`` (dropped where there is
    none): the ground truth of the symmetric solution.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_target, n_source)
        Boolean; an empty row means the target vertex is excluded from evaluation.
    """
    if target.ref is None or source.ref is None:
        raise ValueError(f"ground truth missing for {target.name if target.ref is None else source.name}")
    g = (target.ref.astype(np.int32) @ source.ref.T.astype(np.int32)).tocsr()
    g.data[:] = 1
    if mirrored:
        if source.sym is None:
            raise ValueError(f"{source.name} has no symmetry map; symmetric solutions cannot be scored")
        ok = source.sym >= 0
        n = source.n_vertices
        S = sparse.csr_matrix((np.ones(int(ok.sum()), dtype=np.int32), (np.flatnonzero(ok), source.sym[ok])), shape=(n, n))
        g = (g @ S).tocsr()
        g.data[:] = 1
    if target.unreliable is not None and target.unreliable.any():
        keep = sparse.diags((~target.unreliable).astype(np.int32), dtype=np.int32)
        g = (keep @ g).tocsr()
    if source.unreliable is not None and source.unreliable.any():
        keep = sparse.diags((~source.unreliable).astype(np.int32), dtype=np.int32)
        g = (g @ keep).tocsr()
    g.eliminate_zeros()
    g.data = g.data.astype(np.int8)
    return g


@dataclass
class ShapeCollection:
    """Named shapes with ground truth to one reference shape, loaded on demand.

    Attributes
    ----------
    name : str
        E.g. ``"topkids/low_res"``.
    reference : str
        Name of the reference (null) shape.
    loaders : dict of str to callable
        ``loaders[name]()`` builds the :class:`Shape`; only present shapes are listed.
    splits : dict of str to list of str
        ``"train"`` and ``"test"`` shape names (present or not).
    missing : list of str
        Human-readable notes about files that are absent.
    root : Path or None
        Where the data was found.
    """

    name: str
    reference: str
    loaders: dict[str, Callable[[], Shape]]
    splits: dict[str, list[str]] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
    root: Path | None = None
    _cache: dict[str, Shape] = field(default_factory=dict, repr=False)

    @property
    def names(self) -> list[str]:
        """Names of the shapes present, in order."""
        return list(self.loaders)

    def __contains__(self, name: object) -> bool:
        return name in self.loaders

    def __getitem__(self, name: str) -> Shape:
        if name not in self.loaders:
            raise KeyError(f"{self.name}: no shape {name!r} (present: {', '.join(self.names) or 'none'})")
        if name not in self._cache:
            self._cache[name] = self.loaders[name]()
        return self._cache[name]

    def present(self, names: Iterable[str]) -> list[str]:
        """The names among ``names`` that are present."""
        return [n for n in names if n in self.loaders]

    def forget(self, name: str) -> None:
        """Drop a loaded shape from memory."""
        self._cache.pop(name, None)
