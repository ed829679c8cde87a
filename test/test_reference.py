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


def test_the_imu_as_read_is_shifted_scaled_turned_or_stamped_by_its_recording_times():
    from nrmpc_ros.frontend.feeder import FeederConfig
    from nrmpc_ros.frontend.reference import Reference

    ref = Reference(imu_t=np.zeros(3), imu_a=np.ones((3, 3)), imu_w=np.ones((3, 3)),
                    imu_arrival=np.array([10.0, 10.005, 10.01]))
    inputs = FeederConfig(imu_clock_offset_s=2.0, imu_gyro_scale=0.5, imu_accel_scale=3.0)
    shifted = ref.as_read(inputs)
    assert np.array_equal(shifted.imu_t, [2.0, 2.0, 2.0])
    assert np.all(shifted.imu_w == 0.5) and np.all(shifted.imu_a == 3)
    turned = ref.as_read(FeederConfig(imu_axes_turn_xyzw=[0.0, 0.0, 1.0, 0.0]))  # 180 deg about z
    assert np.allclose(turned.imu_a, [[-1.0, -1.0, 1.0]] * 3) and np.allclose(turned.imu_w, turned.imu_a)
    assert np.array_equal(ref.as_read(inputs, by_arrival=True).imu_t, ref.imu_arrival), "frozen stamps: arrival"
