"""An IMU mount that rings: the accelerometer's mean with the mount's oscillation taken out, and its std."""

import math

import numpy as np
import pytest

from nrmpc_ros.frontend.mount_ringing import mean_under_ringing

TRUE = np.array([0.3, -0.2, 9.79])


def ringing_samples(rng, rate, seconds, frequency_hz, zeta=0.03, amplitude=1.0, noise=0.02):
    t = 100.0 + np.arange(0.0, seconds, 1.0 / rate)  # stamps far from zero, as a recording's
    tau = t - t[0]
    phase = rng.uniform(0.0, 2.0 * math.pi, 3)
    osc = amplitude * np.exp(-zeta * 2 * math.pi * frequency_hz * tau)[:, None] * \
        np.sin(2 * math.pi * frequency_hz * tau[:, None] + phase)
    return t, TRUE + osc + rng.normal(scale=noise, size=(len(t), 3))


@pytest.mark.parametrize("rate, frequency_hz, seconds", [(50.0, 1.5, 1.5), (200.0, 4.0, 0.6), (1000.0, 8.0, 0.3)])
def test_a_span_of_a_period_or_more_takes_the_oscillation_out(rng, rate, frequency_hz, seconds):
    """Over one to a few periods of a decaying 1 m/s^2 ringing the fitted constant is within its std of the
    truth, where the plain mean is off by tens of that std."""
    t, a = ringing_samples(rng, rate, seconds, frequency_hz)
    mean, mean_std, spread = mean_under_ringing(t, a, frequency_hz)
    assert np.abs(mean - TRUE).max() <= 4.0 * mean_std
    assert spread == pytest.approx(0.02, rel=0.3)  # the residual is the noise: the model follows the ringing
    assert np.abs(a.mean(axis=0) - TRUE).max() > 10.0 * mean_std


def test_less_than_a_period_keeps_the_oscillation_in_the_mean_and_says_so(rng):
    t, a = ringing_samples(rng, 200.0, 0.2, 1.5)
    mean, mean_std, _ = mean_under_ringing(t, a, 1.5)
    assert np.array_equal(mean, a.mean(axis=0))
    assert np.abs(mean - TRUE).max() <= 2.0 * mean_std  # what the mean keeps of the ringing is in its std


def test_without_ringing_the_plain_mean(rng):
    t = np.arange(0.0, 1.0, 0.005)
    a = TRUE + rng.normal(scale=0.02, size=(len(t), 3))
    mean, mean_std, spread = mean_under_ringing(t, a, 0.0)
    assert np.array_equal(mean, a.mean(axis=0)) and mean_std == pytest.approx(spread / math.sqrt(len(t)))
