"""RF: random-forest correspondence (Rodolà et al. 2014, as modified for SHREC'16 §4.3).

References: E. Rodolà, S. Rota Bulò, T. Windheuser, M. Vestner, D. Cremers, "Dense
Non-Rigid Shape Correspondence Using Random Forests", CVPR 2014; its SHREC'16 entry as
described in Lähner et al., "SHREC'16: Matching of Deformable Shapes with Topological
Noise", §4.3.

Method
------
* *Labels.* Every vertex of the reference (null) shape kid00 is a class. A training
  shape (kid01..kid15) contributes, for each class its ground truth reaches, one of the
  vertices that correspond to it (at most one point per training shape per label).
* *Features.* The heat kernel signature ``HKS(x, t) = sum_{i<=k} exp(-t lambda_i)
  phi_i(x)^2`` from ``k`` eigenpairs at ``T`` diffusion times
  (log-spaced over the reference's spectrum, surfaces rescaled to unit area), taken in
  log scale.
* *Forest.* ``n_trees`` (15) trees; each node draws ``n_tests`` binary tests with random
  parameters, ``log HKS(x, t_a) <= tau`` or ``log HKS(x, t_a) - log HKS(x, t_b) <= tau``
  (a ratio of two diffusion times), and keeps the one with the largest information
  gain. A leaf keeps the labels of the training points that reached it; the forest's
  prediction for a vertex is the average of its leaves' label distributions.
* *Matching a pair.* The SHREC'16 pairs are two test shapes, so the forest labels both:
  ``P_t`` (target vertices x labels) and ``P_s`` (source vertices x labels). Their
  composition, the soft map ``P_t D P_s^T`` (``D`` normalises each label's mass on the
  source), is applied to the source's first ``k_lowpass`` (90) eigenfunctions and the
  result projected on the target's first 90 eigenfunctions: the functional map
  ``C_12 = Phi_t^T M_t P_t D P_s^T Phi_s``. The point map is recovered by nearest
  neighbours in the spectral domain (each target vertex's low-passed coordinates
  ``Phi_t C_12`` against the source's ``Phi_s``): the track's "low-pass" regularisation.

Departures, and why
-------------------
* The forest is our own (``topomatch.matching._forest``, numba), not scikit-learn's: a
  scikit-learn tree stores a dense ``n_nodes x n_classes`` table, ~9 GB per tree at
  12,000 classes (``reference/dependencies.md`` §7); ours stores each leaf's labels
  sparsely, so the full label set (every kid00 vertex) is kept, as in the paper.
* The random tests read a table of ``T`` precomputed diffusion times rather than a
  continuous time drawn per test; with ``T`` large the difference is immaterial and
  training is much faster.
* The paper matches a test shape to the reference; the track's pairs join two test
  shapes, which we compose through the labels (above). The contest entry's exact
  composition is not described.
* ``k``, ``T`` and the node-test count are not given in the track; the defaults were
  chosen on held-out training shapes (train kid01..kid10, validate kid11..kid15;
  ``benchmarks/rf_holdout.py``, ``docs/shrec16-methods.md``). At high resolution the
  documented runs use ``k = 100`` (an eigenbasis of 500 pairs on 60K vertices is costly).

The trained model is cached on disk (content-keyed by the training meshes, their
ground truth and every hyperparameter) when a cache directory is configured, and can be
written to / read from a file (``topomatch fit rf --out MODEL``, ``model=PATH``). It is
never part of the repository.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from topomatch import _cache
from topomatch._validation import check_random_state
from topomatch.datasets.base import Shape
from topomatch.descriptors import hks, hks_times
from topomatch.maps import p2p_from_fmap
from topomatch.matching._forest import Forest, grow_tree, predict_distributions
from topomatch.matching._spectral import (
    check_positive_int,
    find_reference,
    reference_to_vertex,
    unit_basis,
)
from topomatch.matching.base import Correspondence, Matcher, NotFittedError
from topomatch.mesh import TriangleMesh
from topomatch.mesh.spectral import Eigenbasis
from topomatch.typing import FloatArray, IndexArray, PathType, RandomState

__all__ = ["RandomForestMatcher", "hks_features"]

logger = logging.getLogger(__name__)

#: Bump when the training code changes what a given configuration produces.
MODEL_VERSION = "rf-2"


def hks_features(basis: Eigenbasis, times: FloatArray, n_squared: int = 0) -> FloatArray:
    """Point features: log of the HKS at ``times``, then ``n_squared`` squared eigenfunctions.

    The HKS is not divided by the heat trace: on unit-area surfaces it is already
    comparable across shapes, and the heat trace is a global quantity that a
    topological change anywhere on the shape shifts (dividing by it cost 0.12 AUC on
    held-out training pairs, see ``docs/shrec16-methods.md``).

    Parameters
    ----------
    basis : Eigenbasis
        Unit-area basis with ``k`` eigenpairs.
    times : ndarray, shape (T,)
    n_squared : int
        Also return ``phi_i(x)^2`` for ``i = 2..n_squared + 1`` (the individual terms of
        the HKS sum, each a sign-free function).

    Returns
    -------
    ndarray, shape (n_vertices, T + n_squared), float32
    """
    h = hks(basis.evals, basis.evecs, times, scaled=False)
    out = np.log(np.maximum(h, 1e-30))
    if n_squared > 0:
        out = np.hstack([out, basis.evecs[:, 1 : n_squared + 1] ** 2])
    return out.astype(np.float32)


class RandomForestMatcher(Matcher):
    """Random-forest labels on the reference, composed and low-pass filtered; see the module docstring.

    Parameters
    ----------
    n_trees : int
        Trees (15 in the track).
    k : int
        Eigenpairs in the HKS. 500 by default: on held-out training shapes the AUC rose
        steadily with ``k`` (0.314 at 100, 0.394 at 500), because more eigenpairs reach
        smaller diffusion times, i.e. a more local feature (``benchmarks/rf_holdout.py``,
        ``docs/shrec16-methods.md``).
    n_times : int
        Diffusion times ``T``.
    n_squared : int
        Individual squared eigenfunctions ``phi_i^2`` (i = 2..n_squared+1) added to the
        features (0: the HKS only).
    n_tests : int
        Random tests tried per node.
    p_pair : float
        Probability that a test compares two diffusion times.
    min_samples_leaf : int
        Smallest leaf.
    max_depth : int
        Depth limit.
    k_lowpass : int
        Eigenfunctions of the low-pass step (90 in the track).
    adjoint : bool
        Recover the point map from the low-passed coordinates ``Phi_t C_12`` (True) or
        from ``Phi_s C_12^T`` against ``Phi_t`` (False, Ovsjanikov et al. 2012).
    training_shapes : sequence of str, optional
        Names of the shapes to train on (default: every shape given to ``fit`` except
        the reference). Use it to hold shapes out.
    model : str, optional
        Path of a model written by :meth:`save_model`; ``fit`` then loads it.
    n_jobs : int
        Threads growing trees.
    random_state : int, Generator or None
    """

    name = "rf"
    requires_fit = True

    def __init__(
        self,
        *,
        n_trees: int = 15,
        k: int = 500,
        n_times: int = 64,
        n_squared: int = 0,
        n_tests: int = 50,
        p_pair: float = 0.5,
        min_samples_leaf: int = 1,
        max_depth: int = 100,
        k_lowpass: int = 90,
        adjoint: bool = False,
        training_shapes: Sequence[str] | None = None,
        model: str | None = None,
        n_jobs: int = 2,
        random_state: RandomState = None,
    ) -> None:
        self.n_trees = n_trees
        self.k = k
        self.n_times = n_times
        self.n_squared = n_squared
        self.n_tests = n_tests
        self.p_pair = p_pair
        self.min_samples_leaf = min_samples_leaf
        self.max_depth = max_depth
        self.k_lowpass = k_lowpass
        self.adjoint = adjoint
        self.training_shapes = training_shapes
        self.model = model
        self.n_jobs = n_jobs
        self.random_state = random_state

    # -- hyperparameters -------------------------------------------------------------------
    def _training_params(self) -> dict[str, Any]:
        owner = type(self).__name__
        out = {
            "n_trees": check_positive_int(self.n_trees, "n_trees", owner),
            "k": check_positive_int(self.k, "k", owner, 2),
            "n_times": check_positive_int(self.n_times, "n_times", owner),
            "n_squared": check_positive_int(self.n_squared, "n_squared", owner, 0),
            "n_tests": check_positive_int(self.n_tests, "n_tests", owner),
            "min_samples_leaf": check_positive_int(self.min_samples_leaf, "min_samples_leaf", owner),
            "max_depth": check_positive_int(self.max_depth, "max_depth", owner),
        }
        if not isinstance(self.p_pair, (int, float)) or not 0.0 <= self.p_pair <= 1.0:
            raise ValueError(f"{owner}: p_pair must lie in [0, 1], got {self.p_pair!r}")
        out["p_pair"] = float(self.p_pair)
        if isinstance(self.random_state, np.random.Generator):
            raise TypeError(f"{owner}: random_state must be an int or None (it keys the model cache), not a Generator")
        out["random_state"] = 0 if self.random_state is None else int(self.random_state)  # type: ignore[arg-type]
        return out

    # -- training ----------------------------------------------------------------------------
    def _select(self, shapes: Sequence[Shape]) -> tuple[Shape, list[Shape]]:
        ref = find_reference(shapes)
        if ref is None:
            raise ValueError("rf: fit needs the reference shape (ground truth = identity) among the shapes")
        train = [s for s in shapes if s is not ref and s.ref is not None]
        if self.training_shapes is not None:
            wanted = set(self.training_shapes)
            unknown = wanted - {s.name for s in train}
            if unknown:
                raise ValueError(f"rf: training_shapes not among the shapes given to fit: {', '.join(sorted(unknown))}")
            train = [s for s in train if s.name in wanted]
        if not train:
            raise ValueError("rf: no training shape with ground truth was given to fit")
        return ref, train

    def _model_key(self, ref: Shape, train: Sequence[Shape], params: dict[str, Any]) -> str:
        parts = [ref.mesh.content_hash]
        for s in train:
            r = s.ref.tocsr()  # type: ignore[union-attr]
            bad = s.unreliable if s.unreliable is not None else np.zeros(0, bool)
            parts.append(s.mesh.content_hash + _cache.array_hash(r.indptr, r.indices, bad))
        extra = MODEL_VERSION + repr(sorted(params.items())) + "|".join(parts)
        return _cache.array_hash(extra=extra)

    def fit(self, shapes: Sequence[Shape] = (), /) -> RandomForestMatcher:
        """Train the forest (or load it from ``model`` or the cache).

        Parameters
        ----------
        shapes : sequence of Shape
            The reference shape and training shapes with ground truth to it.

        Returns
        -------
        self
        """
        params = self._training_params()
        if self.model is not None:
            return self.load_model(self.model)
        ref, train = self._select(shapes)
        key = self._model_key(ref, train, params)
        hit = _cache.load("rf-model", key)
        if hit is not None:
            logger.info("rf: loaded the trained forest from the cache (%s)", key[:12])
            self._set_state(hit)
            self.fit_seconds_ = 0.0
            self.from_cache_ = True
            return self
        t0 = time.perf_counter()
        arrays = self._train(ref, train, params)
        arrays["key"] = np.array(key)
        self._set_state(arrays)
        self.fit_seconds_ = time.perf_counter() - t0
        self.from_cache_ = False
        _cache.save("rf-model", key, arrays)
        return self

    def _train(self, ref: Shape, train: Sequence[Shape], params: dict[str, Any]) -> dict[str, np.ndarray]:
        rng = check_random_state(params["random_state"])
        ref_basis = unit_basis(ref.mesh, params["k"])
        times = hks_times(ref_basis.evals, params["n_times"])
        feats, labels = [], []
        for s in train:
            r = reference_to_vertex(s)  # (n_ref, n)
            has = np.flatnonzero(np.diff(r.indptr) > 0)
            # one vertex per label and shape: a random one among those that correspond
            counts = np.diff(r.indptr)[has]
            pick = r.indptr[has] + (rng.random(len(has)) * counts).astype(np.int64)
            verts = r.indices[pick]
            F = hks_features(unit_basis(s.mesh, params["k"]), times, params["n_squared"])
            feats.append(F[verts])
            labels.append(has)
        F = np.concatenate(feats)
        y = np.concatenate(labels).astype(np.int64)
        n_classes = ref.n_vertices
        seeds = rng.integers(0, 2**63 - 1, size=params["n_trees"])
        logger.info("rf: growing %d trees on %d samples, %d classes", params["n_trees"], len(y), n_classes)

        def one(seed: int):
            return grow_tree(
                F, y, n_classes, n_tests=params["n_tests"], p_pair=params["p_pair"], min_samples_split=2,
                min_samples_leaf=params["min_samples_leaf"], max_depth=params["max_depth"], seed=int(seed),
            )

        n_jobs = max(1, int(self.n_jobs))
        if n_jobs > 1:
            from joblib import Parallel, delayed

            trees = Parallel(n_jobs=n_jobs, prefer="threads")(delayed(one)(sd) for sd in seeds)
        else:
            trees = [one(sd) for sd in seeds]
        forest = Forest(list(trees), n_classes)
        out = forest.to_arrays()
        out["times"] = times
        out["k"] = np.array(params["k"])
        out["n_squared"] = np.array(params["n_squared"])
        out["n_train_samples"] = np.array(len(y))
        out["training_shapes"] = np.array([s.name for s in train])
        return out

    def _set_state(self, arrays: dict[str, np.ndarray]) -> None:
        self.forest_ = Forest.from_arrays(arrays)
        self.times_ = np.asarray(arrays["times"], dtype=np.float64)
        self.k_features_ = int(arrays["k"])
        self.n_squared_ = int(arrays["n_squared"])
        self.n_train_samples_ = int(arrays["n_train_samples"])
        self.training_shapes_ = [str(s) for s in arrays["training_shapes"]]
        self._arrays = arrays

    # -- model files ---------------------------------------------------------------------------
    def save_model(self, path: PathType) -> Path:
        """Write the trained model to ``path`` (``.npz``), atomically."""
        if not hasattr(self, "forest_"):
            raise NotFittedError("rf: fit before save_model")
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(path.suffix + ".npz")
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        np.savez_compressed(tmp, **self._arrays)
        os.replace(tmp, path)
        return path

    def load_model(self, path: PathType) -> RandomForestMatcher:
        """Load a model written by :meth:`save_model`."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"rf model file not found: {path}")
        try:
            with np.load(path) as z:
                arrays = {k: z[k] for k in z.files}
            self._set_state(arrays)
        except (KeyError, ValueError, OSError) as err:
            raise ValueError(f"{path} is not an rf model file ({err})") from None
        self.fit_seconds_ = 0.0
        self.from_cache_ = True
        return self

    # -- prediction ------------------------------------------------------------------------------
    def predict_labels(self, mesh: TriangleMesh) -> sparse.csr_matrix:
        """Label distribution of every vertex, shape (n_vertices, n_reference_vertices)."""
        if not hasattr(self, "forest_"):
            raise NotFittedError("rf: call fit (with the reference and training shapes) before match")
        F = hks_features(unit_basis(mesh, self.k_features_), self.times_, self.n_squared_)
        return predict_distributions(self.forest_, F)

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:  # noqa: D102
        k_lp = check_positive_int(self.k_lowpass, "k_lowpass", type(self).__name__)
        P_s = self.predict_labels(source)  # (n1, L)
        P_t = self.predict_labels(target)  # (n2, L)
        b1 = unit_basis(source, k_lp)
        b2 = unit_basis(target, k_lp)
        p2p, info = compose_lowpass(P_t, P_s, b1, b2, adjoint=bool(self.adjoint))
        return Correspondence(p2p, fmap_12=info.pop("C_12"), info=info)


def compose_lowpass(P_t: sparse.csr_matrix, P_s: sparse.csr_matrix, basis_1: Eigenbasis, basis_2: Eigenbasis, *, adjoint: bool = True) -> tuple[IndexArray, dict[str, Any]]:
    """Point map from two label distributions through a low-pass functional map.

    Parameters
    ----------
    P_t : sparse matrix, shape (n2, L)
        Label distributions of the target's vertices.
    P_s : sparse matrix, shape (n1, L)
        Label distributions of the source's vertices.
    basis_1, basis_2 : Eigenbasis
        Source / target bases with ``k`` functions (the low-pass band).
    adjoint : bool
        See :class:`RandomForestMatcher`.

    Returns
    -------
    p2p_21 : ndarray, shape (n2,)
    info : dict
        ``C_12`` (k, k) and ``unsupported_fraction`` (target area whose labels never
        occur on the source; those rows carry no information into ``C_12``).
    """
    P_s = sparse.csr_matrix(P_s)
    P_t = sparse.csr_matrix(P_t)
    mass_l = np.asarray(P_s.sum(axis=0)).ravel()  # (L,)
    inv = np.where(mass_l > 0, 1.0 / np.where(mass_l > 0, mass_l, 1.0), 0.0)
    Q = inv[:, None] * (P_s.T @ basis_1.evecs)  # (L, k1): mean source coordinates per label
    F = P_t @ Q  # (n2, k1)
    support = P_t @ (mass_l > 0).astype(np.float64)  # (n2,) mass of supported labels
    ok = support > 1e-12
    F[ok] /= support[ok, None]
    w = basis_2.mass * ok
    C_12 = basis_2.evecs.T @ (w[:, None] * F)  # (k2, k1) projection of the composed map
    p2p = p2p_from_fmap(C_12, basis_1, basis_2, adjoint=adjoint)
    unsupported = float(basis_2.mass[~ok].sum() / basis_2.mass.sum())
    return p2p, {"C_12": C_12, "unsupported_fraction": unsupported}
