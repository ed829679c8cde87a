"""Matching a stamp to a bag's reference samples: nearest within the tolerance, the earlier on a tie."""

import numpy as np

from nrmpc_ros.frontend.reference import STAMP_TOLERANCE_S, nearest_stamp


def test_nearest_stamp_within_the_tolerance():
    ts = np.array([1.0, 1.5, 2.0])
    assert nearest_stamp(ts, 1.49) == 1
    assert nearest_stamp(ts, 1.75) is None  # 0.25 s from both neighbours
    assert nearest_stamp(ts, 1.75, tol=0.3) == 1  # a tie goes to the earlier sample
    assert nearest_stamp(ts, 0.99) == 0 and nearest_stamp(ts, 2.0 + STAMP_TOLERANCE_S / 2) == 2
    assert nearest_stamp(ts, 2.0 + 2 * STAMP_TOLERANCE_S) is None
    assert nearest_stamp(np.array([5.0]), 5.01) == 0
    assert nearest_stamp(np.zeros(0), 1.0) is None
