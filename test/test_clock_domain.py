"""ClockDomains: inputs whose arrival lags are far off the others' are on other clocks, moved onto theirs."""

from __future__ import annotations

import numpy as np
import pytest

from nrmpc_ros.frontend.clock_domain import FAR_CLOCK_S, ClockDomains

T0 = 1_700_000_000.0
IMU = "imu"


def run(imu_offset_s=0.0, camera_offsets_s=(0.0, 0.0, 0.0), camera_delay_s=0.03, imu_delay_s=0.001,
        seconds=1.0, rng=None):
    """Cameras at 10 Hz and an IMU at 200 Hz over ``seconds``, each message arriving its delay (plus up to 20 ms
    of jitter from ``rng``) after it was taken, each input stamped by a clock that far off the arrival clock:
    the rebases :class:`ClockDomains` returns, in arrival order, each applied to its input's later stamps (as the
    feeder does)."""
    rng = rng or np.random.default_rng(0)
    msgs = [(t + camera_delay_s + rng.uniform(0, 0.02), i, t + off) for t in T0 + np.arange(0, seconds, 0.1)
            for i, off in enumerate(camera_offsets_s)]
    msgs += [(t + imu_delay_s + rng.uniform(0, 0.02), IMU, t + imu_offset_s)
             for t in T0 + np.arange(0, seconds, 0.005)]
    streams = list(range(len(camera_offsets_s))) + [IMU]
    d, out, moved = ClockDomains(streams, confirm=3), [], dict.fromkeys(streams, 0.0)
    for arrival, stream, stamp in sorted(msgs, key=lambda m: m[0]):
        for r in d.seen(stream, stamp + moved[stream], arrival):
            out.append(r)
            moved[r.stream] += r.offset_s
    return out, moved


@pytest.mark.parametrize("imu_offset_s", [-T0 + 1000.0, 3600.0, -2 * FAR_CLOCK_S, 1.5 * FAR_CLOCK_S])
def test_an_imu_far_off_the_cameras_is_moved_onto_the_arrival_clock_they_stamp_with(imu_offset_s):
    """Cameras stamped by the arrival clock (a delay of 30-50 ms): the IMU is moved once, onto the arrival clock,
    its samples then late by their quickest delivery among the first (1-21 ms here), whatever its offset."""
    got, moved = run(imu_offset_s)
    assert [r.stream for r in got] == [IMU] and got[0].onto_arrival
    assert -imu_offset_s + 0.001 <= moved[IMU] <= -imu_offset_s + 0.021
    assert moved[0] == moved[1] == moved[2] == 0.0


def test_cameras_on_a_device_clock_are_moved_onto_the_arrival_clock_the_imu_stamps_with():
    """Every camera on its own device clock, the IMU on the host's: each camera moved onto the arrival clock
    (late by its quickest delivery: 30-50 ms), the IMU left."""
    got, moved = run(camera_offsets_s=(-T0 + 3000.0, -T0 + 3000.0, -T0 + 90.0))
    assert sorted(r.stream for r in got) == [0, 1, 2] and all(r.onto_arrival for r in got)
    assert moved[0] == pytest.approx(T0 - 3000.0 + 0.04, abs=0.011) and moved[IMU] == 0.0
    assert moved[2] == pytest.approx(T0 - 90.0 + 0.04, abs=0.011)


def test_one_camera_on_its_own_clock_is_the_only_one_moved():
    got, moved = run(camera_offsets_s=(0.0, -T0 + 2500.0, 0.0))
    assert [r.stream for r in got] == [1] and moved[1] == pytest.approx(T0 - 2500.0 + 0.04, abs=0.011)


def test_without_an_input_on_the_arrival_clock_the_others_go_onto_the_first_cameras():
    """Every input a day behind the arrival clock (a bag played into the node without its clock), the IMU on its
    own counter as well: the IMU is moved onto the first camera's clock, off by the difference of the quickest
    deliveries (about 30 ms here); the cameras stay."""
    day = -86400.0
    got, moved = run(imu_offset_s=-T0 + 1000.0, camera_offsets_s=(day, day, day))
    assert [r.stream for r in got] == [IMU] and not got[0].onto_arrival
    assert moved[IMU] == pytest.approx(T0 - 1000.0 + day - 0.03, abs=0.02)


@pytest.mark.parametrize("imu_offset_s", [0.0, 0.25, -3.0, 0.9 * FAR_CLOCK_S])
def test_an_imu_within_the_far_bound_is_left_to_the_measured_searches(imu_offset_s):
    assert run(imu_offset_s, rng=np.random.default_rng(1))[0] == []


def test_a_bag_played_on_a_later_clock_moves_nothing():
    """Every input a day behind the arrival clock: one clock, whatever the arrival clock says."""
    assert run(imu_offset_s=-86400.0, camera_offsets_s=(-86400.0,) * 3)[0] == []


def test_a_decision_needs_confirm_messages_in_a_row_that_agree_and_a_second_input():
    d = ClockDomains([0, IMU], confirm=3)
    assert d.seen(IMU, 1000.0, T0) == [] and d.seen(IMU, 1000.005, T0 + 0.005) == []
    assert d.seen(IMU, 1000.01, T0 + 0.01) == [], "no camera yet"
    assert d.seen(0, T0, T0 + 0.03) == [] and d.seen(0, T0 + 0.1, T0 + 0.13) == []
    assert d.apart(IMU) and d.apart(0) and d.lag(0) is None
    got = d.seen(0, T0 + 0.2, T0 + 0.23)
    assert [r.stream for r in got] == [IMU] and d.lag(IMU) is None, "a moved input's lags start anew"
    d = ClockDomains([0, IMU], confirm=3)
    for k in range(3):
        d.seen(0, T0 + 0.1 * k, T0 + 0.1 * k + 0.03)
    assert d.seen(IMU, T0 + 0.005, T0 + 0.006) == []
    assert d.seen(IMU, T0 + 3600.0, T0 + 0.011) == [] and d.seen(IMU, T0 + 0.015, T0 + 0.016) == [], \
        "one corrupt stamp"
    assert d.seen(IMU, np.array([T0 - 500.0, T0 + 0.02, T0 + 0.025]), T0 + 0.026) == [], "the samples disagree"


def test_off_the_arrival_clock_a_spoken_but_undecided_input_is_waited_for():
    """Two inputs far off the arrival clock and a third that spoke but is not decided yet: it may stamp with the
    arrival clock, so nothing moves until it is decided (no detour through the first camera's clock)."""
    d = ClockDomains([0, 1, IMU], confirm=3)
    d.seen(1, T0, T0 + 0.03)  # the host's camera, once
    for k in range(3):
        d.seen(0, 100.0 + 0.1 * k, T0 + 0.1 * k + 0.03)
    assert d.seen(IMU, np.array([50.0, 50.005, 50.01]), T0 + 0.011) == []
    d.seen(1, T0 + 0.1, T0 + 0.13)
    got = d.seen(1, T0 + 0.2, T0 + 0.23)
    assert sorted(map(str, (r.stream for r in got))) == ["0", "imu"] and all(r.onto_arrival for r in got)
