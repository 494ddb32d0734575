"""Train a matcher on a dataset's training split: the engine behind ``topomatch fit``.

The shapes given to ``fit`` are the ones ``topomatch bench`` would give it (the
reference and the training split; every shape for methods that use ground truth at test
time), so that a model trained here is the one a later ``bench`` run finds in the cache.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from topomatch.evaluation.benchmark import BenchmarkConfig, load_collection
from topomatch.matching import MATCHERS, Matcher, make_matcher
from topomatch.typing import PathType

__all__ = ["FitResult", "fit_method"]

logger = logging.getLogger(__name__)


@dataclass
class FitResult:
    """What :func:`fit_method` did.

    Attributes
    ----------
    matcher : Matcher
        The fitted matcher.
    shapes : list of str
        Names of the shapes given to ``fit``.
    training_shapes : list of str
        The shapes the model was trained on: the matcher's ``training_shapes_`` where it
        records them (e.g. ``rf`` with a ``training_shapes`` subset), else ``shapes``.
    seconds : float
        Wall time of ``fit`` (near zero when the model came from the cache).
    from_cache : bool
        The model was loaded, not trained.
    model_path : Path or None
        Where the model was written, if ``out`` was given.
    info : dict
    """

    matcher: Matcher
    shapes: list[str]
    training_shapes: list[str]
    seconds: float
    from_cache: bool
    model_path: Path | None = None
    info: dict[str, Any] = field(default_factory=dict)


def fit_method(
    method: str,
    *,
    dataset: str = "topkids",
    data_dir: PathType | None = None,
    resolution: str = "low",
    params: dict[str, Any] | None = None,
    random_state: int = 0,
    out: PathType | None = None,
) -> FitResult:
    """Fit ``method`` on a dataset's reference + training split and optionally save it.

    Parameters
    ----------
    method : str
        A name in ``MATCHERS`` whose class has ``requires_fit``.
    dataset : {"topkids", "builtin"}
    data_dir : path, optional
        TOPKIDS folder (default ``TOPOMATCH_DATA``).
    resolution : {"low", "high"}
    params : dict, optional
        Hyperparameters.
    random_state : int
        Used when ``params`` has no ``random_state``.
    out : path, optional
        Write the model there (the matcher must have ``save_model``).

    Returns
    -------
    FitResult
    """
    if method not in MATCHERS:
        raise ValueError(f"unknown method {method!r}; available: {', '.join(MATCHERS)}")
    params = dict(params or {})
    matcher = make_matcher(method, **params)
    if not matcher.requires_fit:
        raise ValueError(f"{method} has nothing to fit (requires_fit is False)")
    if "random_state" in matcher.get_params() and "random_state" not in params:
        matcher.set_params(random_state=random_state)
    if out is not None and not hasattr(matcher, "save_model"):
        raise ValueError(f"{method} cannot write its model to a file")
    config = BenchmarkConfig(dataset=dataset, data_dir=str(data_dir) if data_dir else None, resolution=resolution)
    config.validate()
    collection = load_collection(config)
    if matcher.uses_ground_truth:
        names = collection.names
    else:
        names = collection.present([collection.reference, *collection.splits.get("train", [])])
    t0 = time.perf_counter()
    matcher.fit([collection[n] for n in names])
    seconds = time.perf_counter() - t0
    from_cache = bool(getattr(matcher, "from_cache_", False))
    path = matcher.save_model(out) if out is not None else None  # type: ignore[attr-defined]
    info = {"training_seconds": getattr(matcher, "fit_seconds_", seconds)}
    logger.info("fitted %s on %d shapes in %.1f s%s", method, len(names), seconds, " (from the cache)" if from_cache else "")
    trained_on = [str(n) for n in getattr(matcher, "training_shapes_", None) or names]
    return FitResult(matcher, list(names), trained_on, seconds, from_cache, path, info)
