"""How inputs deliver: sliding maxima of silences and ages, and the spread of delays (frontend/delivery.py)."""

import math

import numpy as np
import pytest

from nrmpc_ros.frontend.delivery import DelaySpread, DeliveryGaps, SlidingMax, StampLags


def test_delivery_gaps_are_a_sliding_maximum_of_silences_and_ages():
    gaps = DeliveryGaps(window_s=10.0)
    assert gaps.largest(0.0) == 0.0
    gaps.delivered(0.0, 0.0)
    gaps.delivered(0.0, -0.4)  # a message 0.4 s old when it came: its input was silent that long
    assert gaps.largest(0.0) == pytest.approx(0.4)
    for t in np.arange(0.1, 3.0, 0.1):
        gaps.delivered(t, t)
    gaps.delivered(5.0, 5.0)  # 2.1 s of silence
    assert gaps.largest(5.0) == pytest.approx(2.1) and gaps.largest(14.9) == pytest.approx(2.1)
    assert gaps.largest(15.1) == 0.0, "forgotten after window_s of the other input's stamps"


def test_the_sliding_maximum_forgets_what_left_its_window():
    m = SlidingMax(window_s=2.0)
    assert m.largest(0.0, default=-1.0) == -1.0
    for at, v in [(0.0, 5.0), (1.0, 3.0), (2.5, 4.0), (3.0, 1.0)]:
        m.add(at, v)
    assert m.largest(1.9) == 5.0 and m.largest(2.1) == 4.0 and m.largest(4.6) == 1.0 and m.largest(5.1) == 0.0


def test_the_delay_spread_does_not_see_clock_offsets_and_measures_bursts():
    steady, bursty = DelaySpread(60.0), DelaySpread(60.0)
    rng = np.random.default_rng(0)
    for k in range(100):
        stamp = 1e9 + 0.1 * k  # stamps on another clock than the arrivals
        steady.add(10.0 + 0.1 * k + 0.05 + rng.uniform(0, 0.003), stamp)
        bursty.add(10.0 + 2.0 * np.ceil(0.1 * k / 2.0) + 0.05, stamp)
    assert steady.spread(20.0) < 0.004 and bursty.spread(20.0) == pytest.approx(1.9)
    assert DelaySpread(60.0).spread(0.0) == 0.0


@pytest.mark.parametrize("rate", [0.5, 2.0, 5.0])
def test_a_recording_played_at_another_speed_spreads_its_delays_by_its_bursts_only(rate):
    """A bag played at ``rate`` times its speed: its stamps advance ``rate`` s per s of arrival, a trend of the
    delays that is no burst. A steady camera keeps the spread of its jitter; a driver that buffered 2 s of stamps
    at a time keeps its bursts (2 / rate s of arrivals); the first burst alone (its frames arriving together)
    spreads by its stamps' span."""
    rng = np.random.default_rng(1)
    steady, bursty, first = DelaySpread(60.0), DelaySpread(60.0), DelaySpread(60.0)
    for k in range(200):
        stamp = 1.7e9 + 0.1 * k
        steady.add(10.0 + 0.1 * k / rate + rng.uniform(0, 0.003), stamp)
        bursty.add(10.0 + 2.0 * np.ceil(0.1 * k / 2.0) / rate + 0.05, stamp)
        if k < 20:
            first.add(10.0 + 2.0 / rate + 0.001 * k, stamp)
    now = 10.0 + 20.0 / rate
    assert steady.spread_about_rate(now) < 0.004
    assert bursty.spread_about_rate(now) == pytest.approx(2.0 / rate, rel=0.1)
    assert first.spread_about_rate(now) == pytest.approx(1.9, abs=0.05)
    assert steady.spread(now) == pytest.approx(abs(20.0 / rate - 20.0), abs=0.2), "as they are: the trend included"


def test_stamp_lags_see_one_input_fall_behind_not_all_of_them():
    """One input delivering 2 s behind the others lags by 2 s; all of them late together lag by nothing."""
    lags, newest = StampLags(3, 60.0), [-math.inf] * 3
    for k in range(40):
        stamp = 0.1 * k
        for i, s in ((0, stamp), (1, stamp), (2, stamp - 2.0)):  # input 2 comes 2 s behind
            lags.delivered(i, s, newest)
            newest[i] = max(newest[i], s)
    assert lags.largest(2, newest) == pytest.approx(2.0) and lags.largest(0, newest) < 0.11
    assert StampLags(2, 60.0).largest(0, [-math.inf] * 2) == 0.0
