"""The oracle: returns the ground truth. For validating scorers, never a method."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from topomatch.datasets.base import Shape
from topomatch.matching.base import Correspondence, Matcher, NotFittedError
from topomatch.mesh import TriangleMesh

__all__ = ["MirroredOracleMatcher", "OracleMatcher"]


class OracleMatcher(Matcher):
    """Ground-truth map, looked up from the shapes given to ``fit``.

    ``fit`` must receive every shape to be matched (with ground truth to a common
    reference); ``match`` recognises meshes by content and returns, for each target
    vertex, the first source vertex that shares a reference vertex with it, or ``-1``.
    With ``mirrored=True`` it returns the left-right mirror of that vertex instead
    (the symmetric solution), ``-1`` where the source has no mirror.

    Reports label its rows "oracle (uses ground truth)". Its purpose is to check the
    scorer: it must score error 0 and AUC 1.

    Parameters
    ----------
    mirrored : bool
        Return the symmetric solution.
    """

    name = "oracle"
    requires_fit = True
    uses_ground_truth = True

    def __init__(self, *, mirrored: bool = False) -> None:
        self.mirrored = mirrored

    def fit(self, shapes: Sequence[Shape] = (), /) -> OracleMatcher:  # noqa: D102
        self.shapes_ = {s.mesh.content_hash: s for s in shapes}
        return self

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:  # noqa: D102
        from topomatch.datasets.base import ground_truth_21

        if not hasattr(self, "shapes_"):
            raise NotFittedError("OracleMatcher.fit must be given the shapes with ground truth first")
        try:
            s = self.shapes_[source.content_hash]
            t = self.shapes_[target.content_hash]
        except KeyError:
            raise ValueError(f"the oracle knows no ground truth for {source.name or 'source'} / {target.name or 'target'}") from None
        g = ground_truth_21(t, s, mirrored=self.mirrored)
        p2p = np.full(g.shape[0], -1, dtype=np.int64)
        has = np.diff(g.indptr) > 0
        p2p[has] = g.indices[g.indptr[:-1][has]]
        return Correspondence(p2p, info={"uses_ground_truth": True})


class MirroredOracleMatcher(OracleMatcher):
    """The symmetric solution (the ground truth's left-right mirror), for scorer checks.

    Under ``shrec16`` with symmetric solutions accepted it must score AUC 1; without,
    clearly less.
    """

    name = "oracle-mirror"
    ground_truth_note = "mirrored ground truth"

    def __init__(self, *, mirrored: bool = True) -> None:
        self.mirrored = mirrored
