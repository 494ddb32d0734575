import numpy as np
import pytest
from scipy import sparse

from topomatch.evaluation.metrics import (
    SHREC16_THRESHOLDS,
    area_matched,
    auc,
    cumulative_curve,
    error_queries,
    pointwise_errors,
)


def test_thresholds():
    assert len(SHREC16_THRESHOLDS) == 26 and SHREC16_THRESHOLDS[-1] == 0.25


def test_perfect_and_constant_maps():
    e0 = np.zeros(100)
    c = cumulative_curve(e0)
    assert np.all(c == 1) and auc(c) == 1.0
    e = np.full(100, 0.1)
    c = cumulative_curve(e)
    assert c[9] == 0 and c[10] == 1
    # curve is 0 on [0, 0.09], jumps at 0.1; trapezoid over 26 points
    assert auc(c) == pytest.approx((0.25 - 0.1 + 0.005) / 0.25)


def test_curve_ignores_nan_and_is_monotone(rng):
    e = rng.random(500) * 0.3
    e[::10] = np.nan
    c = cumulative_curve(e)
    assert np.all(np.diff(c) >= 0)
    assert c[-1] == pytest.approx(np.mean(e[~np.isnan(e)] <= 0.25))
    assert np.isnan(cumulative_curve(np.full(3, np.nan))).all()


def test_pointwise_errors_min_over_ground_truth():
    # 3 target vertices; source distances are |i - j|
    gt = sparse.csr_matrix(np.array([[1, 0, 0, 1], [0, 0, 0, 0], [0, 1, 0, 0]]))
    p2p = np.array([2, 0, -1])
    err = pointwise_errors(p2p, gt, lambda a, b: np.abs(a - b).astype(float), normalization=2.0)
    assert err[0] == pytest.approx(0.5)  # min(|0-2|, |3-2|) / 2
    assert np.isnan(err[1]) and np.isnan(err[2])  # excluded, unmatched
    rows, _, _ = error_queries(p2p, gt)
    np.testing.assert_array_equal(rows, [0, 0])
    with pytest.raises(ValueError, match="entries"):
        error_queries(p2p[:2], gt)


def test_area_matched():
    areas = np.array([1.0, 2.0, 3.0, 4.0])
    assert area_matched(np.array([0, 0, 3, -1]), areas) == pytest.approx(0.5)
    assert area_matched(np.array([-1, -1]), areas) == 0.0
