"""Matching methods behind one interface, and the name -> class table used by the CLI.

The table is an explicit dictionary: adding a method means adding a line here.
"""

from __future__ import annotations

from typing import Any

from topomatch.matching.base import Correspondence, Matcher, NotFittedError
from topomatch.matching.deform import DeformMatcher
from topomatch.matching.descriptor_nn import DescriptorNNMatcher
from topomatch.matching.em import IsometricEmbeddingEMMatcher
from topomatch.matching.fmap import FunctionalMapMatcher
from topomatch.matching.ge import GreenEmbeddingGT4Matcher, GreenEmbeddingMatcher
from topomatch.matching.oracle import MirroredOracleMatcher, OracleMatcher
from topomatch.matching.random_map import RandomMatcher
from topomatch.matching.rf import RandomForestMatcher
from topomatch.matching.template import TemplateMatcher
from topomatch.matching.zoomout import ZoomOutMatcher

__all__ = ["DEFAULT_METHOD", "DEFAULT_WITHOUT_TEMPLATE", "MATCHERS", "Correspondence", "Matcher", "NotFittedError", "make_matcher"]

MATCHERS: dict[str, type[Matcher]] = {
    "oracle": OracleMatcher,
    "oracle-mirror": MirroredOracleMatcher,
    "random": RandomMatcher,
    "descriptor-nn": DescriptorNNMatcher,
    "em": IsometricEmbeddingEMMatcher,
    "ge": GreenEmbeddingMatcher,
    "ge-gt4": GreenEmbeddingGT4Matcher,
    "rf": RandomForestMatcher,
    "fmap": FunctionalMapMatcher,
    "zoomout": ZoomOutMatcher,
    "deform": DeformMatcher,
    "template": TemplateMatcher,
}

DEFAULT_METHOD = "template"
"""Default of ``topomatch bench`` and of ``topomatch match --template``: the flagship, the
registration of a clean template onto each shape (``deform``) with the training shapes'
poses, composed pair by pair (``topkids25`` 2.45 x100 and ``shrec16`` AUC 0.868; one
registration per shape, x1.4-1.6 of pyFM's ZoomOut's time in the same run, the seconds
varying with the machine; see ``docs/flagship.md``, "Default method")."""

DEFAULT_WITHOUT_TEMPLATE = "deform"
"""Default of ``topomatch match`` when no template is given: the flagship's registration,
source onto target."""


def make_matcher(name: str, **params: Any) -> Matcher:
    """Build the matcher registered as ``name`` with hyperparameters ``params``."""
    try:
        cls = MATCHERS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; available: {', '.join(MATCHERS)}") from None
    try:
        return cls(**params)
    except TypeError as err:
        raise ValueError(f"bad hyperparameters for {name!r}: {err}") from None
