"""Errors of a map against a shape collection's ground truth, for tests."""

from __future__ import annotations

import numpy as np

from topomatch.datasets.base import Shape, ground_truth_21


def euclidean_errors(target: Shape, source: Shape, p2p_21: np.ndarray) -> np.ndarray:
    """Distance on the source between each mapped vertex and its true image, over sqrt(area).

    Only target vertices with ground truth count; shape (n_with_truth,).
    """
    gt = ground_truth_21(target, source).tocsr()
    rows = np.flatnonzero(np.diff(gt.indptr) > 0)
    true_src = gt.indices[gt.indptr[rows]]
    V = source.mesh.vertices
    return np.linalg.norm(V[p2p_21[rows]] - V[true_src], axis=1) / np.sqrt(source.mesh.area)
