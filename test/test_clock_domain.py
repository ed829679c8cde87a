"""ClockDomains: an IMU whose arrival lag is far off the cameras' is on another clock, moved onto theirs."""

from __future__ import annotations

import numpy as np
import pytest

from nrmpc_ros.frontend.clock_domain import CAMERA_LAGS_KEPT, FAR_CLOCK_S, ClockDomains

T0 = 1_700_000_000.0


def run(imu_offset_s: float, camera_offset_s: float = 0.0, camera_delay_s: float = 0.03, imu_delay_s: float = 0.001,
        seconds: float = 1.0, rng=None):
    """Cameras at 10 Hz and an IMU at 200 Hz over ``seconds``, each message arriving its delay (plus up to 20 ms
    of jitter from ``rng``) after it was taken, stamped by clocks ``camera_offset_s`` and ``imu_offset_s`` off
    the arrival clock: the rebases :class:`ClockDomains` returns, in arrival order."""
    rng = rng or np.random.default_rng(0)
    msgs = [(t + camera_delay_s + rng.uniform(0, 0.02), "camera", t + camera_offset_s)
            for t in T0 + np.arange(0, seconds, 0.1)]
    msgs += [(t + imu_delay_s + rng.uniform(0, 0.02), "imu", t + imu_offset_s)
             for t in T0 + np.arange(0, seconds, 0.005)]
    d, out, moved = ClockDomains(confirm=3), [], 0.0
    for arrival, kind, stamp in sorted(msgs):
        r = d.camera(stamp, arrival) if kind == "camera" else d.imu(stamp + moved, arrival)
        if r is not None:  # the feeder moves the IMU's later stamps by it
            out.append(r)
            moved += r.offset_s
    return out


@pytest.mark.parametrize("imu_offset_s", [-T0 + 1000.0, 3600.0, -2 * FAR_CLOCK_S, 1.5 * FAR_CLOCK_S])
def test_an_imu_far_off_the_cameras_is_moved_onto_the_arrival_clock_they_stamp_with(imu_offset_s):
    """Cameras stamped by the arrival clock (a delay of 30-50 ms): the IMU is moved once, onto the arrival clock,
    its samples then late by their quickest delivery among the first (1-21 ms here), whatever the size of its
    offset."""
    got = run(imu_offset_s)
    assert len(got) == 1 and got[0].onto_arrival
    assert -imu_offset_s + 0.001 <= got[0].offset_s <= -imu_offset_s + 0.021


def test_cameras_on_their_own_clock_take_the_imu_onto_theirs():
    """Cameras stamped by a device clock a day off the arrival clock (or a bag played without its clock): the IMU
    is moved onto the cameras' clock, off by the difference of the quickest deliveries (about 30 ms here)."""
    got = run(imu_offset_s=-T0 + 1000.0, camera_offset_s=-86400.0)
    assert len(got) == 1 and not got[0].onto_arrival
    assert got[0].offset_s == pytest.approx(T0 - 1000.0 - 86400.0 - 0.03, abs=0.02)


@pytest.mark.parametrize("imu_offset_s", [0.0, 0.25, -3.0, 0.9 * FAR_CLOCK_S])
def test_an_imu_within_the_far_bound_is_left_to_the_measured_searches(imu_offset_s):
    assert run(imu_offset_s, rng=np.random.default_rng(1)) == []


def test_a_bag_played_on_a_later_clock_moves_nothing():
    """Every input a day behind the arrival clock (a bag played into the node without its clock): one clock."""
    assert run(imu_offset_s=-86400.0, camera_offset_s=-86400.0) == []


def test_a_decision_needs_a_camera_and_confirm_samples_in_a_row_that_agree():
    d = ClockDomains(confirm=3)
    assert d.imu(1000.0, T0) is None and d.imu(1000.005, T0 + 0.005) is None
    assert d.imu(1000.01, T0 + 0.01) is None, "no camera yet"
    assert d.camera(T0 + 0.01, T0 + 0.04) is not None
    d = ClockDomains(confirm=3)
    d.camera(T0, T0 + 0.03)
    assert d.imu(T0 + 0.005, T0 + 0.006) is None
    assert d.imu(T0 + 3600.0, T0 + 0.011) is None and d.imu(T0 + 0.015, T0 + 0.016) is None, "one corrupt stamp"
    assert d.imu(np.array([T0 - 500.0, T0 + 0.02, T0 + 0.025]), T0 + 0.026) is None, "the block's samples disagree"


def test_the_cameras_lags_are_their_latest():
    """A camera clock that changed (a driver restarted on another clock) is judged by its latest frames."""
    d = ClockDomains(confirm=3)
    for k in range(CAMERA_LAGS_KEPT):
        d.camera(T0 - 5000.0 + 0.1 * k, T0 + 0.1 * k)
    for k in range(CAMERA_LAGS_KEPT):
        d.camera(T0 + 6.4 + 0.1 * k, T0 + 6.4 + 0.1 * k + 0.03)
    got = [d.imu(T0 + 12.8 + 0.005 * k, T0 + 12.8 + 0.005 * k + 0.001) for k in range(3)]
    assert got == [None] * 3
