"""How inputs deliver: sliding maxima of silences and ages, and the spread of delays (frontend/delivery.py)."""

import numpy as np
import pytest

from nrmpc_ros.frontend.delivery import DelaySpread, DeliveryGaps, SlidingMax


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
