"""EM: isometric embedding with expectation-maximisation (Sahillioglu & Yemez 2012; SHREC'16 §4.1).

References: Y. Sahillioglu, Y. Yemez, "Minimum-Distortion Isometric Shape Correspondence
Using EM Algorithm", IEEE TPAMI 34(11), 2012; its SHREC'16 entry as described in Lähner et
al., "SHREC'16: Matching of Deformable Shapes with Topological Noise", §4.1.

Method
------
1. *Consistent sampling.* ``n_samples`` (~250) farthest-point samples on each shape,
   under the metric below, each started at the point farthest from the shape's centre
   in that metric (so that both shapes start at an extremity).
2. *Metric.* Biharmonic distance (Lipman et al. 2010) from the Laplacian eigenbasis,
   ``d_B(x, y)^2 = sum_{i>=2} (phi_i(x) - phi_i(y))^2 / lambda_i^2``, in place of the
   geodesic distance of the original paper, which topological shortcuts destroy.
3. *Embedding.* Classical multidimensional scaling of each sample's distance matrix into
   ``R^d`` (``d = mds_dim``); the two embeddings agree up to an orthogonal transform.
4. *EM.* The source embedding, moved by an orthogonal transform ``T``, is a mixture of
   isotropic Gaussians of variance ``sigma^2`` centred at its points; the latent
   variable is which source sample generated each target sample. For every choice of
   axis signs of the source embedding (MDS axes are defined up to sign) the iteration is:

   * E-step: posteriors ``P[j, i] ~ exp(-|y_j - T x_i|^2 / 2 sigma^2)``;
   * M-step: (a) the one-to-one mapping that maximises the expected log-likelihood,
     ``sum_j log P[j, m(j)]``, by bipartite perfect matching
     (:func:`scipy.optimize.linear_sum_assignment`); (b) greedy refinement of that
     mapping by the pair swaps that most reduce its isometric distortion
     ``sum_{j,l} |D_target(j, l) - D_source(m(j), m(l))|``, until no swap helps;
     (c) ``T`` by orthogonal Procrustes on the mapping and ``sigma^2`` by the
     posterior-weighted residual;

   until the mapping stops changing (or stops improving for 3 iterations, keeping the
   best one met: the two M-step parts can otherwise cycle). The sign choice whose final mapping has the least
   distortion wins.
5. *Output.* A sparse map: each target sample gets its source sample, every other
   target vertex ``-1`` (~250 matches, as in the contest).

Departures, and why
-------------------
* The original samples high-curvature vertices evenly; the SHREC'16 entry and this
  implementation use farthest-point sampling under the biharmonic metric (the track
  says "consistent sampling"; curvature extrema are unstable under the remeshing that
  created the topological noise).
* The original refines over coarse-to-fine sample sets and can output many-to-one
  maps; the contest entry's sparse one-to-one output (~250 matches) is reproduced.
* Distances are computed on the surfaces rescaled to unit area (the original works on
  geodesic distances normalised by the diameter; both make the two metrics comparable).
* The paper's exact stopping rule and variance schedule are not in the track; we stop
  when the mapping is unchanged (or after ``max_iter``) and estimate ``sigma^2`` from the
  posteriors, as in any Gaussian-mixture EM.
"""

from __future__ import annotations

import itertools
from typing import Any

import numba
import numpy as np
from scipy.optimize import linear_sum_assignment

from topomatch._validation import check_random_state
from topomatch.matching._spectral import check_positive_int, classical_mds, unit_basis
from topomatch.matching.base import Correspondence, Matcher
from topomatch.mesh import TriangleMesh
from topomatch.mesh.biharmonic import biharmonic_distances, biharmonic_embedding
from topomatch.typing import FloatArray, IndexArray, RandomState

__all__ = ["IsometricEmbeddingEMMatcher", "em_correspondence", "greedy_refine", "isometric_distortion"]


def isometric_distortion(D1: FloatArray, D2: FloatArray, m_21: IndexArray) -> float:
    """Mean ``|D2(j, l) - D1(m(j), m(l))|`` over all ordered pairs of target samples.

    Parameters
    ----------
    D1 : ndarray, shape (n1, n1)
        Distances among source samples.
    D2 : ndarray, shape (n2, n2)
        Distances among target samples.
    m_21 : ndarray of int, shape (n2,)
        Source sample of each target sample.
    """
    return float(np.abs(D2 - D1[np.ix_(m_21, m_21)]).mean())


@numba.njit(cache=True, nogil=True)
def _row_costs(D1, D2, m):  # pragma: no cover - compiled
    """``C[p, a] = sum_q |D2(p, q) - D1(a, m(q))|``, shape (n2, n1)."""
    n2 = D2.shape[0]
    n1 = D1.shape[0]
    C = np.zeros((n2, n1))
    for p in range(n2):
        for a in range(n1):
            acc = 0.0
            for q in range(n2):
                acc += abs(D2[p, q] - D1[a, m[q]])
            C[p, a] = acc
    return C


def greedy_refine(D1: FloatArray, D2: FloatArray, m_21: IndexArray, *, max_swaps: int | None = None, tol: float = 1e-12) -> tuple[IndexArray, int]:
    """Greedy pair swaps that reduce the isometric distortion of a one-to-one mapping.

    At each step the swap of two target samples' images that lowers
    ``sum_{j,l} |D2(j, l) - D1(m(j), m(l))|`` the most is applied, until no swap
    lowers it.

    Parameters
    ----------
    D1 : ndarray, shape (n1, n1)
    D2 : ndarray, shape (n2, n2)
    m_21 : ndarray of int, shape (n2,)
        Injective mapping of target samples to source samples.
    max_swaps : int, optional
        Default ``10 * n2``.
    tol : float
        Smallest decrease, relative to the current total, that counts.

    Returns
    -------
    m_21 : ndarray, shape (n2,)
    n_swaps : int
    """
    m = np.array(m_21, dtype=np.int64)
    n2 = len(m)
    if max_swaps is None:
        max_swaps = 10 * n2
    D1 = np.ascontiguousarray(D1, dtype=np.float64)
    D2 = np.ascontiguousarray(D2, dtype=np.float64)
    C = _row_costs(D1, D2, m)
    n_swaps = _greedy_swaps(D1, D2, C, m, int(max_swaps), float(tol))
    return m, int(n_swaps)


@numba.njit(cache=True, nogil=True)
def _greedy_swaps(D1, D2, C, m, max_swaps, tol):  # pragma: no cover - compiled
    """Best-improvement swaps in place on ``m``; ``C[p, a] = sum_q |D2(p,q) - D1(a, m(q))|``."""
    n2 = m.shape[0]
    n1 = D1.shape[0]
    total = 0.0
    for j in range(n2):
        total += C[j, m[j]]
    n_swaps = 0
    while n_swaps < max_swaps:
        best = 0.0
        bj = -1
        bl = -1
        for j in range(n2):
            mj = m[j]
            cjj = C[j, mj]
            for q in range(j + 1, n2):
                ml = m[q]
                d1 = D1[mj, ml]
                d2 = D2[j, q]
                delta = C[j, ml] + C[q, mj] - cjj - C[q, ml] - 2.0 * d1 - 2.0 * d2 + 2.0 * abs(d2 - d1)
                if delta < best:
                    best = delta
                    bj = j
                    bl = q
        if bj < 0 or best >= -tol * max(total, 1e-300):
            break
        a_old = m[bj]
        b_old = m[bl]
        for p in range(n2):
            x = D2[p, bj]
            y = D2[p, bl]
            for a in range(n1):
                C[p, a] += abs(x - D1[a, b_old]) - abs(x - D1[a, a_old]) + abs(y - D1[a, a_old]) - abs(y - D1[a, b_old])
        m[bj] = b_old
        m[bl] = a_old
        total += best
        n_swaps += 1
    return n_swaps


def _procrustes(X: FloatArray, Y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Orthogonal ``R`` and translation ``t`` minimising ``|Y - (X R^T + t)|``."""
    mx, my = X.mean(0), Y.mean(0)
    U, _, Vt = np.linalg.svd((Y - my).T @ (X - mx))
    R = U @ Vt
    return R, my - mx @ R.T


def em_correspondence(
    X1: FloatArray,
    X2: FloatArray,
    D1: FloatArray,
    D2: FloatArray,
    *,
    max_iter: int = 30,
    refine: bool = True,
    patience: int = 3,
) -> tuple[IndexArray, dict[str, Any]]:
    """EM alignment of two MDS embeddings with one-to-one mappings (one sign choice).

    Parameters
    ----------
    X1 : ndarray, shape (n, d)
        Source samples' embedding (already sign-flipped as wanted).
    X2 : ndarray, shape (n, d)
        Target samples' embedding.
    D1, D2 : ndarray, shapes (n, n)
        The metric distances the embeddings came from (for the greedy refinement).
    max_iter : int
    refine : bool
        Run the greedy distortion refinement in each M-step.
    patience : int
        Stop when the mapping's distortion has not improved for this many iterations
        (the alternation can cycle between two mappings); the least distorting
        mapping met is returned.

    Returns
    -------
    m_21 : ndarray of int, shape (n,)
        Source sample of each target sample.
    info : dict
        ``iterations``, ``swaps``, ``sigma2``, ``log_likelihood``.
    """
    n, d = X2.shape
    R, t = np.eye(d), np.zeros(d)
    sigma2 = float(((X2[:, None, :] - X1[None, :, :]) ** 2).sum(-1).mean() / d)
    m = None
    best: tuple[float, IndexArray] | None = None
    since_best = 0
    swaps = 0
    loglik = -np.inf
    it = 0
    while it < max_iter:
        it += 1
        Z = X1 @ R.T + t
        sq = ((X2[:, None, :] - Z[None, :, :]) ** 2).sum(-1)  # (n2, n1)
        # E-step: posterior of each source sample for each target sample
        logp = -sq / (2.0 * sigma2)
        logp -= logp.max(1, keepdims=True)
        lognorm = np.log(np.exp(logp).sum(1, keepdims=True))
        logP = logp - lognorm
        P = np.exp(logP)
        # M-step (a): one-to-one mapping maximising the expected log-likelihood
        _, new_m = linear_sum_assignment(-logP)
        # M-step (b): greedy refinement of the mapping under isometric distortion
        if refine:
            new_m, s = greedy_refine(D1, D2, new_m)
            swaps += s
        # M-step (c): transform and variance
        R, t = _procrustes(X1[new_m], X2)
        Z = X1 @ R.T + t
        sq = ((X2[:, None, :] - Z[None, :, :]) ** 2).sum(-1)
        sigma2 = max(float((P * sq).sum() / (n * d)), 1e-12 * float(sq.mean()) + 1e-300)
        loglik = float(logP[np.arange(n), new_m].sum())
        dist = isometric_distortion(D1, D2, new_m)
        if best is None or dist < best[0] - 1e-12:
            best = (dist, new_m)
            since_best = 0
        else:
            since_best += 1
        converged = m is not None and np.array_equal(m, new_m)
        m = new_m
        # stop at a fixed point, or when the alternation cycles without improving
        if converged or since_best >= patience:
            break
    if best is not None:
        m = best[1]
    if m is None:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    return m, {"iterations": it, "swaps": swaps, "sigma2": sigma2, "log_likelihood": loglik}


class IsometricEmbeddingEMMatcher(Matcher):
    """EM on biharmonic MDS embeddings, sparse output; see the module docstring.

    Parameters
    ----------
    n_samples : int
        Samples per shape (~250 in the contest).
    k : int
        Eigenpairs for the biharmonic distance.
    mds_dim : int
        Dimension of the MDS embedding; every one of the ``2**mds_dim`` axis-sign
        choices is tried.
    max_iter : int
        EM iterations per sign choice.
    refine : bool
        Greedy refinement in the M-step.
    n_refined_signs : int
        Every sign choice first runs EM without the (costly) greedy refinement; the
        ``n_refined_signs`` least distorting ones are then run in full.
    random_state : int, Generator or None
        Unused by the deterministic sampling; kept for the common interface.
    """

    name = "em"

    def __init__(
        self,
        *,
        n_samples: int = 250,
        k: int = 100,
        mds_dim: int = 3,
        max_iter: int = 30,
        refine: bool = True,
        n_refined_signs: int = 2,
        random_state: RandomState = None,
    ) -> None:
        self.n_samples = n_samples
        self.k = k
        self.mds_dim = mds_dim
        self.max_iter = max_iter
        self.refine = refine
        self.n_refined_signs = n_refined_signs
        self.random_state = random_state

    def _sample(self, mesh: TriangleMesh) -> tuple[IndexArray, FloatArray]:
        emb = biharmonic_embedding(unit_basis(mesh, self.k))
        n = min(self.n_samples, mesh.n_vertices)
        first = int(np.argmax(np.linalg.norm(emb - (mesh.vertex_areas / mesh.area) @ emb, axis=1)))
        out = np.empty(n, dtype=np.int64)
        dmin = np.full(len(emb), np.inf)
        cur = first
        for i in range(n):
            out[i] = cur
            dmin = np.minimum(dmin, np.linalg.norm(emb - emb[cur], axis=1))
            dmin[out[: i + 1]] = -1.0
            cur = int(np.argmax(dmin))
        return out, biharmonic_distances(emb, out, out)

    def match(self, source: TriangleMesh, target: TriangleMesh) -> Correspondence:  # noqa: D102
        owner = type(self).__name__
        check_positive_int(self.n_samples, "n_samples", owner, 4)
        check_positive_int(self.k, "k", owner, 3)
        dim = check_positive_int(self.mds_dim, "mds_dim", owner)
        if dim > 8:
            raise ValueError(f"{owner}: mds_dim above 8 means more than 256 sign choices, got {dim}")
        max_iter = check_positive_int(self.max_iter, "max_iter", owner)
        check_random_state(self.random_state)
        s1, D1 = self._sample(source)
        s2, D2 = self._sample(target)
        n = min(len(s1), len(s2))
        s1, s2 = s1[:n], s2[:n]
        D1, D2 = D1[:n, :n], D2[:n, :n]
        X1 = classical_mds(D1, dim)
        X2 = classical_mds(D2, dim)
        # every sign choice without refinement, then the full EM on the most promising
        ranked = []
        for signs in itertools.product((1.0, -1.0), repeat=dim):
            m, _ = em_correspondence(X1 * np.asarray(signs), X2, D1, D2, max_iter=max_iter, refine=False)
            ranked.append((isometric_distortion(D1, D2, m), signs))
        ranked.sort()
        n_full = check_positive_int(self.n_refined_signs, "n_refined_signs", owner)
        best: tuple[float, IndexArray, dict[str, Any]] | None = None
        for _, signs in ranked[:n_full]:
            m, info = em_correspondence(X1 * np.asarray(signs), X2, D1, D2, max_iter=max_iter, refine=bool(self.refine))
            dist = isometric_distortion(D1, D2, m)
            if best is None or dist < best[0]:
                best = (dist, m, {**info, "signs": list(signs)})
        if best is None:  # pragma: no cover - the loop runs at least twice
            raise RuntimeError("no sign choice was tried")
        dist, m, info = best
        p2p = np.full(target.n_vertices, -1, dtype=np.int64)
        p2p[s2] = s1[m]
        info["distortion"] = dist / float(D2.mean())
        info["n_matches"] = int(n)
        return Correspondence(p2p, info=info)
