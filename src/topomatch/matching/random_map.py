"""Chance level: every target vertex goes to a uniformly random source vertex."""

from __future__ import annotations

from topomatch._validation import check_random_state
from topomatch.matching.base import Correspondence, Matcher
from topomatch.mesh import TriangleMesh
from topomatch.typing import RandomState

__all__ = ["RandomMatcher"]


class RandomMatcher(Matcher):
    """Uniformly random map: the chance level of every metric.

    Under ``shrec16`` without symmetric credit its expected curve is
    ``E[curve(t)] = mean_x P_y(d(y*(x), y) <= t)`` for y uniform over the source's
    vertices; for small t on a surface ``P ~ pi t^2`` (t in units of sqrt(area)), so the
    expected AUC over [0, 0.25] is about ``pi * 0.25^2 / 3 = 0.065`` (less where thin
    parts and boundaries cut geodesic discs short). ``docs/protocols.md`` has the
    derivation and the measured values.

    Parameters
    ----------
    random_state : int, Generator or None
    """

    name = "random"

    def __init__(self, *, random_state: RandomState = 0) -> None:
        self.random_state = random_state

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:  # noqa: D102
        rng = check_random_state(self.random_state)
        return Correspondence(rng.integers(0, source.n_vertices, target.n_vertices))
