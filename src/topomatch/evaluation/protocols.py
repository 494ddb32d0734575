"""The two evaluation protocols, defined exactly (see ``docs/protocols.md``).

``shrec16`` — the SHREC'16 track's own protocol
    Pairs: all 90 ordered pairs (M, N), M != N, of the test shapes kid16..kid25 (the
    training split kid01..kid15 gives 210 pairs). The map sends every vertex x of M
    to a vertex y of N. Ground truth: the vertices y* of N that share a kid00 vertex
    with x (composed through the null shape; at high res flagged vertices are
    removed). Error: ``min_{y*} d_N(y*, y) / sqrt(area(N))``. Vertices without ground
    truth are excluded and counted. Symmetric solutions are accepted: the whole map
    is also scored against the mirrored ground truth (``sym_N`` applied to every y*)
    and the better AUC of the two counts. Curves over t = 0, 0.01, ..., 0.25, AUC by
    the trapezoid rule normalised to [0, 1]. Geodesics: heat method (default) or exact.

``topkids25`` — the protocol of recent papers (ULRSSM, Hybrid fmaps, MDND)
    Pairs: kid00 -> kidNN, NN = 01..25 (or the train / test part). The map gives every
    vertex y of kidNN a vertex of kid00. Error: ``d_kid00(ref_NN(y), p2p(y)) /
    sqrt(area(kid00))``. Reported: the mean over all vertices of all pairs pooled, x100.
    No symmetric credit. Geodesics: Dijkstra on the edge graph (as published) and exact
    (or heat) beside it.

In topomatch's convention (shape 1 = source, shape 2 = target, ``p2p_21`` one entry
per target vertex), the shrec16 pair (M, N) has target M and source N, and the
topkids25 pair has target kidNN and source kid00. A pair's identifier is
``"<target>-<source>"``: the shape whose vertices are mapped, then the shape they land on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import permutations
from typing import Literal

from topomatch.datasets.base import ShapeCollection
from topomatch.evaluation.metrics import SHREC16_THRESHOLDS
from topomatch.mesh.geodesics import GeodesicKind
from topomatch.typing import FloatArray

__all__ = ["PROTOCOLS", "PairSpec", "Protocol", "get_protocol"]

Split = Literal["train", "test", "all"]


@dataclass(frozen=True)
class PairSpec:
    """One ordered pair: the target's vertices are mapped onto the source."""

    target: str
    source: str

    @property
    def id(self) -> str:
        """``"<target>-<source>"``."""
        return f"{self.target}-{self.source}"

    @classmethod
    def from_id(cls, pair_id: str) -> PairSpec:
        """Parse ``"<target>-<source>"``."""
        parts = pair_id.split("-")
        if len(parts) != 2 or not all(parts):
            raise ValueError(f"pair id {pair_id!r} is not of the form '<target>-<source>'")
        return cls(parts[0], parts[1])


@dataclass(frozen=True)
class Protocol:
    """An evaluation protocol.

    Attributes
    ----------
    name : str
    symmetric : bool
        Accept symmetric solutions (score against the mirrored ground truth too).
    geodesics : tuple of str
        Geodesic kinds to report; the first is the primary one.
    thresholds : ndarray
        Curve thresholds (in units of sqrt(area)).
    pooled_mean : bool
        Report the mean error pooled over all vertices of all pairs (topkids25), not
        only per-pair means.
    error_scale : float
        Factor applied to mean errors in tables (100 for topkids25).
    """

    name: str
    symmetric: bool
    geodesics: tuple[GeodesicKind, ...]
    thresholds: FloatArray = field(default_factory=lambda: SHREC16_THRESHOLDS.copy())
    pooled_mean: bool = False
    error_scale: float = 1.0
    default_split: Split = "test"

    def with_options(self, *, symmetric: bool | None = None, geodesics: tuple[GeodesicKind, ...] | None = None) -> Protocol:
        """A copy with the symmetric switch and/or the geodesic kinds changed."""
        return Protocol(
            self.name,
            self.symmetric if symmetric is None else symmetric,
            self.geodesics if geodesics is None else geodesics,
            self.thresholds,
            self.pooled_mean,
            self.error_scale,
            self.default_split,
        )

    def pairs(self, collection: ShapeCollection, split: Split | None = None) -> list[PairSpec]:
        """The protocol's pairs among the shapes present in ``collection``."""
        split = split or self.default_split
        if split not in collection.splits:
            raise ValueError(f"{collection.name} has no split {split!r} (has {', '.join(collection.splits)})")
        names = collection.present(collection.splits[split])
        if self.name == "shrec16":
            return [PairSpec(m, n) for m, n in permutations(names, 2)]
        if self.name == "topkids25":
            ref = collection.reference
            return [PairSpec(n, ref) for n in names if n != ref]
        raise ValueError(f"unknown protocol {self.name!r}")

    def expected_pairs(self, collection: ShapeCollection, split: Split | None = None) -> int:
        """How many pairs the split would have with every shape present."""
        split = split or self.default_split
        n = len([s for s in collection.splits[split] if s != collection.reference])
        return n * (n - 1) if self.name == "shrec16" else n


PROTOCOLS: dict[str, Protocol] = {
    "shrec16": Protocol("shrec16", symmetric=True, geodesics=("heat",), default_split="test"),
    "topkids25": Protocol(
        "topkids25", symmetric=False, geodesics=("dijkstra", "heat"), pooled_mean=True, error_scale=100.0, default_split="all"
    ),
}


def get_protocol(name: str) -> Protocol:
    """The protocol called ``name`` (``"shrec16"`` or ``"topkids25"``)."""
    try:
        return PROTOCOLS[name]
    except KeyError:
        raise ValueError(f"unknown protocol {name!r}; choose from {', '.join(PROTOCOLS)}") from None


