"""A hold the body turns through slowly: the gyro's mean rate over the hold, and the stretch of a creep the
windowed stillness test cut into pieces."""

import math

import numpy as np
import pytest

from nrmpc_ros.frontend.steady_turn import creep_span, flicker_rate, steady_turn
from nrmpc_ros.frontend.zupt import ImuNoise, ZuptConfig

BIAS = np.array([0.002, -0.0015, 0.0007])  # rad/s
AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
CFG = ZuptConfig()


def _noise(sigma=0.002):
    return ImuNoise(accel_sigma=0.02, gyro_sigma=sigma, gyro_bias=BIAS)


def _gyro(rng, rate_hz, seconds, turn_deg_s=0.0, sigma=0.002):
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    w = BIAS + math.radians(turn_deg_s) * AXIS + rng.normal(0.0, sigma, (len(t), 3))
    return t, w


@pytest.mark.parametrize("rate_hz", [50, 100, 200, 1000])
def test_still_holds_are_still_at_every_imu_rate_and_length(rate_hz):
    """200 still holds of 0.2-3 s at each rate, the bias known as the stillness test estimates it: none turns."""
    rng = np.random.default_rng(rate_hz)
    for seconds in rng.uniform(0.2, 3.0, 200):
        t, w = _gyro(rng, rate_hz, seconds)
        out = steady_turn(t, w, _noise(), CFG)
        assert out is not None and not out.turning, out


@pytest.mark.parametrize("rate_hz", [50, 200, 1000])
@pytest.mark.parametrize("deg_s", [0.2, 0.5])
def test_a_creep_through_a_hold_is_a_turn_at_every_imu_rate(rate_hz, deg_s):
    """A body turning at 0.2 deg/s through a 1.5 s hold, below what the windowed test sees at 50-200 Hz
    (:func:`flicker_rate`): the mean rate tells it from the bias."""
    rng = np.random.default_rng(int(rate_hz * deg_s * 10))
    t, w = _gyro(rng, rate_hz, 1.5, deg_s)
    out = steady_turn(t, w, _noise(), CFG)
    assert out.turning, out.describe()
    assert math.degrees(out.rate_rad_s) == pytest.approx(deg_s, abs=0.05)
    if rate_hz <= 200 and deg_s == 0.2:
        assert math.radians(deg_s) < flicker_rate(_noise(), CFG, 1.0 / rate_hz) / 2.0 * 1.5


def test_a_bias_within_its_stability_is_no_turn():
    """The bias the recording gave, strayed by 0.03 deg/s (its stability) in one axis: still."""
    rng = np.random.default_rng(3)
    t, w = _gyro(rng, 200, 3.0)
    w = w + math.radians(0.03) * np.array([1.0, 0.0, 0.0])
    assert not steady_turn(t, w, _noise(), CFG).turning


def _move_creep_move(rng, rate_hz, creep_deg_s):
    """1 s moving (0.5 rad/s, cosine ends), 2 s creeping (or still), 1 s moving: t, gyro, the creep's span."""
    t = np.arange(0.0, 4.0, 1.0 / rate_hz)
    speed = np.where(t < 1.0, 0.5 * np.sin(np.pi * t) ** 2, 0.0) + \
        np.where(t >= 3.0, 0.5 * np.sin(np.pi * (t - 3.0)) ** 2, 0.0)
    creep = np.where((t >= 1.0) & (t < 3.0), math.radians(creep_deg_s), 0.0)
    w = BIAS + (speed + creep)[:, None] * AXIS + rng.normal(0.0, 0.002, (len(t), 3))
    return t, w


@pytest.mark.parametrize("rate_hz", [50, 200, 1000])
def test_a_piece_of_a_creep_is_tested_over_the_whole_creep(rate_hz):
    """A piece of 0.1 s in the middle of a 2 s creep at 0.2 deg/s (the windowed test passed only it): its span
    widens to the creep, not into the moves either side, and the creep is a turn there."""
    rng = np.random.default_rng(rate_hz)
    t, w = _move_creep_move(rng, rate_hz, 0.2)
    t0, t1 = creep_span(t, w, _noise(), CFG, 1.95, 2.05)
    assert 0.8 < t0 < 1.1 and 2.9 < t1 < 3.2, (t0, t1)
    inside = (t >= t0) & (t <= t1)
    assert steady_turn(t[inside], w[inside], _noise(), CFG).turning


@pytest.mark.parametrize("rate_hz", [50, 200, 1000])
def test_a_still_hold_between_moves_takes_the_stops_last_instants_and_stays_still(rate_hz):
    rng = np.random.default_rng(rate_hz + 1)
    t, w = _move_creep_move(rng, rate_hz, 0.0)
    t0, t1 = creep_span(t, w, _noise(), CFG, 1.5, 2.5)
    assert 0.8 < t0 < 1.1 and 2.9 < t1 < 3.2, (t0, t1)
    inside = (t >= t0) & (t <= t1)
    assert not steady_turn(t[inside], w[inside], _noise(), CFG).turning


def test_a_span_that_holds_a_move_is_not_widened():
    rng = np.random.default_rng(5)
    t, w = _move_creep_move(rng, 200, 0.0)
    assert creep_span(t, w, _noise(), CFG, 0.4, 1.5) == (0.4, 1.5)


@pytest.mark.parametrize("frequency_hz", [1.5, 4.0])
def test_an_imu_on_a_ringing_bar_is_not_turning_for_its_ringing(frequency_hz):
    """An IMU inside a camera on a bar that rings down after the stop (0.05 rad/s at damping 0.03) over a hold of
    a second: the ringing's turn between the span's ends is no steady turn; a creep under it still is."""
    rng = np.random.default_rng(int(frequency_hz * 10))
    t, w = _gyro(rng, 200, 1.0)
    omega = 2 * np.pi * frequency_hz
    ring = 0.05 * np.exp(-0.03 * omega * t) * np.cos(omega * t + 0.7)
    w_ring = w + ring[:, None] * AXIS
    if frequency_hz < 2.0:  # taken for a body's rate, a slow bar's ringing is a turn
        assert steady_turn(t, w_ring, _noise(), CFG).turning
    assert not steady_turn(t, w_ring, _noise(), CFG, ringing_hz=frequency_hz).turning
    t, w = _gyro(rng, 200, 3.0, 2.0)
    w = w + (0.05 * np.exp(-0.03 * omega * t) * np.cos(omega * t + 0.7))[:, None] * AXIS
    assert steady_turn(t, w, _noise(), CFG, ringing_hz=frequency_hz).turning
