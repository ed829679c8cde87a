"""Robust losses (nrmpc_ros/core/loss.py): Huber's values, IRLS weights and derivatives; the MSAC score."""

import numpy as np
import pytest

from nrmpc_ros.core.loss import HuberLoss, msac_score


def test_huber_is_quadratic_inside_and_linear_beyond_delta():
    loss = HuberLoss(2.0)
    r = np.array([0.0, 0.5, 2.0, 3.0, 10.0])
    np.testing.assert_allclose(loss.loss(r**2), [0.0, 0.125, 2.0, 2.0 * (3.0 - 1.0), 2.0 * (10.0 - 1.0)])
    # beyond delta the cost grows by delta per unit of r: an outlier weighs linearly
    assert loss.loss(101.0**2) - loss.loss(100.0**2) == pytest.approx(2.0)


def test_huber_weight_is_twice_the_derivative_of_the_cost_in_r2():
    loss = HuberLoss(1.5)
    r2 = np.random.default_rng(0).uniform(0.01, 16.0, 200)
    r2 = r2[np.abs(np.sqrt(r2) - 1.5) > 1e-3]  # away from the kink
    h = 1e-6 * r2
    numeric = (loss.loss(r2 + h) - loss.loss(r2 - h)) / (2 * h)
    np.testing.assert_allclose(loss.weight(r2), 2.0 * numeric, rtol=1e-6)
    r = np.sqrt(r2)
    np.testing.assert_allclose(loss.weight(r2), np.where(r <= 1.5, 1.0, 1.5 / r))


def test_huber_is_continuous_with_its_slope_at_delta():
    loss = HuberLoss(0.7)
    below, above = 0.7 * (1 - 1e-9), 0.7 * (1 + 1e-9)
    assert loss.loss(below**2) == pytest.approx(loss.loss(above**2), rel=1e-8)
    assert loss.weight(below**2) == pytest.approx(loss.weight(above**2), rel=1e-8)
    assert loss.weight(0.0) == 1.0  # no division by a zero residual


@pytest.mark.parametrize("delta", [0.0, -1.0, float("nan")])
def test_huber_needs_a_positive_delta(delta):
    with pytest.raises(ValueError, match="delta"):
        HuberLoss(delta)


def test_msac_score_truncates_each_squared_error_at_the_threshold():
    e = np.array([[0.1, -0.2, 5.0], [0.0, 1.0, -3.0]])
    assert msac_score(e, 0.5) == pytest.approx(0.01 + 0.04 + 0.25 + 0.0 + 0.25 + 0.25)
    np.testing.assert_allclose(msac_score(e, 0.5, axis=1), [0.3, 0.5])
    assert type(msac_score(e, 0.5)) is float
    # a better model (smaller errors of the inliers) scores lower; outliers beyond the threshold all cost the same
    assert msac_score([0.1, 0.1, 9.0], 0.5) < msac_score([0.2, 0.1, 0.6], 0.5)
    assert msac_score([0.6], 0.5) == msac_score([60.0], 0.5)


def test_an_error_that_is_not_a_number_counts_as_an_outlier():
    """A landmark no ray intersection places has no error: in MSAC it is an outlier (threshold^2), not a NaN that
    makes every candidate's score incomparable (a sequence's gravity candidates then had no winner at all)."""
    assert msac_score([0.1, np.nan, np.inf], 0.5) == pytest.approx(0.01 + 0.25 + 0.25)
    np.testing.assert_allclose(msac_score(np.array([[np.nan, 0.2]]), 0.5, axis=1), [0.29])
