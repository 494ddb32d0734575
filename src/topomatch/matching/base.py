"""The Matcher interface and the Correspondence it returns."""

from __future__ import annotations

import inspect
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from topomatch.datasets.base import Shape
from topomatch.mesh import TriangleMesh
from topomatch.typing import FloatArray, IndexArray

__all__ = ["Correspondence", "Matcher", "NotFittedError"]


class NotFittedError(RuntimeError):
    """A trainable matcher was used before ``fit``."""


@dataclass(frozen=True, eq=False)
class Correspondence:
    """A map from the target's vertices to the source's.

    Attributes
    ----------
    p2p_21 : ndarray, shape (n_target,)
        Source vertex for each target vertex, ``-1`` = unmatched (sparse maps).
    fmap_12 : ndarray, shape (k_target, k_source), optional
        Functional map, when the method has one.
    info : dict
        Method-specific diagnostics (iterations, energies, labels used...).
    """

    p2p_21: IndexArray
    fmap_12: FloatArray | None = None
    info: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        p = np.asarray(self.p2p_21)
        if p.ndim != 1 or (p.size and not np.issubdtype(p.dtype, np.integer)):
            raise TypeError(f"p2p_21 must be a 1-D integer array, got shape {p.shape} dtype {p.dtype}")
        object.__setattr__(self, "p2p_21", p.astype(np.int64))

    @property
    def is_sparse(self) -> bool:
        """True when some target vertices are unmatched."""
        return bool(np.any(self.p2p_21 < 0))


class Matcher:
    """Base class of every matching method (scikit-learn estimator contract).

    Hyperparameters are keyword-only ``__init__`` arguments stored unchanged as
    attributes of the same name, with no validation or logic in ``__init__``. State
    learned by ``fit`` ends with an underscore. Randomness comes from a
    ``random_state`` hyperparameter.

    Subclasses implement :meth:`match` and, if trainable, :meth:`fit`.
    """

    #: Short name used in the CLI and in reports.
    name: ClassVar[str] = ""
    #: True when ``fit`` must be called with training shapes before ``match``.
    requires_fit: ClassVar[bool] = False
    #: True when the method uses ground truth at test time (the oracle, landmark
    #: variants); ``fit`` then receives every shape, and reports flag the row.
    uses_ground_truth: ClassVar[bool] = False
    #: How reports describe that use, e.g. "uses 4 ground-truth landmarks".
    ground_truth_note: ClassVar[str] = "uses ground truth"
    #: True when one matcher object reuses work across pairs (``template`` keeps each
    #: shape's registration); ``topomatch bench`` then runs its pairs in one process.
    shares_work: ClassVar[bool] = False
    #: What ``topomatch match`` says when a method that needs ``fit`` gets no ``model``
    #: (empty: the generic advice to train one).
    model_hint: ClassVar[str] = ""

    def fit(self, shapes: Sequence[Shape] = (), /) -> Matcher:
        """Learn from training shapes with ground truth; axiomatic matchers do nothing.

        Parameters
        ----------
        shapes : sequence of Shape
            Training shapes with ``ref`` ground truth to a common reference.

        Returns
        -------
        self
        """
        return self

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:
        """Map every target vertex to a source vertex.

        Parameters
        ----------
        source : TriangleMesh
            Shape 1; the map's values index its vertices.
        target : TriangleMesh
            Shape 2; the map has one entry per target vertex.

        Returns
        -------
        Correspondence
        """
        raise NotImplementedError

    # -- estimator plumbing ----------------------------------------------------------------
    @classmethod
    def _param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [p.name for p in sig.parameters.values() if p.name != "self" and p.kind == p.KEYWORD_ONLY]

    def get_params(self) -> dict[str, Any]:
        """Hyperparameters as a dictionary."""
        return {k: getattr(self, k) for k in self._param_names()}

    def set_params(self, **params: Any) -> Matcher:
        """Set hyperparameters; unknown names raise ``ValueError``."""
        valid = set(self._param_names())
        for k, v in params.items():
            if k not in valid:
                raise ValueError(f"{type(self).__name__} has no hyperparameter {k!r} (has: {', '.join(sorted(valid))})")
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"
