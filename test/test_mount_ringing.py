"""An IMU mount that rings: the accelerometer's mean with the mount's oscillation taken out, and its std."""

import math

import numpy as np
import pytest

from nrmpc_ros.core.so3 import exp_so3, right_jacobian
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


@pytest.mark.parametrize("rate, frequency_hz, swing_rad", [(50.0, 1.5, 0.15), (200.0, 1.5, 0.15)])
def test_a_mount_that_swings_by_tenths_of_a_radian_turned_back_by_its_gyro(rng, rate, frequency_hz, swing_rad):
    """A tip that swings by phi reads gravity turned by -phi: besides the oscillation, 1/2 phi x (phi x g) of
    second order, which no fit at the ringing's frequency takes out (0.1 m/s^2 at 0.15 rad, dozens of the
    mean's std). Turned back by the turn its gyro saw, the samples' constant is the reading at rest, within its
    std; the gyro's bias is found by the same fit. (On stiffer bars the same stop swings the tip less, as
    1 / f^2; there the tip's own acceleration, whose decay the fit takes as linear, limits the constant.)"""
    omega = 2.0 * math.pi * frequency_hz
    t = 100.0 + np.arange(0.0, 2.5 / frequency_hz, 1.0 / rate)
    tau = t - t[0] + 0.3
    env, decay = swing_rad * np.exp(-0.03 * omega * tau), -0.03 * omega
    c, s = np.cos(omega * tau), np.sin(omega * tau + 0.4)
    ex, ey = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    phi = env[:, None] * (np.outer(c, ex) + 0.6 * np.outer(s, ey))
    dphi = env[:, None] * (np.outer(decay * c - omega * np.sin(omega * tau), ex)
                           + 0.6 * np.outer(decay * s + omega * np.cos(omega * tau + 0.4), ey))
    tip = np.cross(-omega ** 2 * phi, np.array([0.3, 0.0, 0.0]))  # the tip's own acceleration, a 0.3 m lever
    a = np.einsum("nji,nj->ni", exp_so3(phi), TRUE + tip) + rng.normal(scale=0.02, size=phi.shape)
    bias = np.array([0.003, -0.002, 0.001])
    w = np.einsum("nij,nj->ni", right_jacobian(phi), dphi) + bias + rng.normal(scale=0.002, size=phi.shape)
    mean, mean_std, spread = mean_under_ringing(t, a, frequency_hz, w)
    assert np.abs(mean - TRUE).max() <= 4.0 * mean_std
    assert spread == pytest.approx(0.02, rel=0.3)
    plain, plain_std, _ = mean_under_ringing(t, a, frequency_hz)
    assert np.abs(plain - TRUE).max() > 5.0 * plain_std
