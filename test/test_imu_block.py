"""IMU blocks: serialized sensor_msgs/Imu decoded at once give the numbers of the messages themselves."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from nrmpc_ros.frontend.imu_block import ImuDecoder

STORE = get_typestore(Stores.ROS2_JAZZY)
T = STORE.types


def message(rng, k: int, frame_id: str):
    v3 = [T["geometry_msgs/msg/Vector3"](*rng.normal(size=3)) for _ in range(2)]
    q = rng.normal(size=4)
    return T["sensor_msgs/msg/Imu"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](1_700_000_000 + k // 7,
                                                                                int(rng.integers(0, 10**9))),
                                        frame_id=frame_id),
        orientation=T["geometry_msgs/msg/Quaternion"](*(q / np.linalg.norm(q))),
        orientation_covariance=rng.normal(size=9), angular_velocity=v3[0],
        angular_velocity_covariance=rng.normal(size=9), linear_acceleration=v3[1],
        linear_acceleration_covariance=rng.normal(size=9))


@pytest.mark.parametrize("little_endian", [True, False])
def test_decoded_blocks_hold_the_numbers_of_the_messages(little_endian):
    rng = np.random.default_rng(7)
    msgs = [message(rng, k, "imu_link"[: k % 9]) for k in range(60)]  # every alignment of the doubles
    raws = [STORE.serialize_cdr(m, "sensor_msgs/msg/Imu", little_endian=little_endian) for m in msgs]
    decoder = ImuDecoder()
    got = decoder.decode(raws)
    want = {"stamps": [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in msgs],
            "accel": [[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in msgs],
            "gyro": [[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in msgs],
            "accel_cov": [m.linear_acceleration_covariance for m in msgs],
            "gyro_cov": [m.angular_velocity_covariance for m in msgs]}
    for name, values in want.items():
        assert np.array_equal(getattr(got, name), np.array(values)), name
    assert len(got) == 60 and got.accel[3].tolist() == [msgs[3].linear_acceleration.x,
                                                         msgs[3].linear_acceleration.y,
                                                         msgs[3].linear_acceleration.z]
    assert got.stamps[5] == msgs[5].header.stamp.sec + 1e-9 * msgs[5].header.stamp.nanosec
    one = decoder.decode(raws[10:11])
    assert np.array_equal(one.gyro, got.gyro[10:11]) and one.accel_cov.shape == (1, 9)


def test_a_message_that_is_not_an_imu_message_is_an_error_not_numbers():
    raw = bytes(STORE.serialize_cdr(message(np.random.default_rng(1), 0, "imu"), "sensor_msgs/msg/Imu"))
    with pytest.raises(Exception):  # noqa: B017 - the reference deserializer's own error
        ImuDecoder().decode([raw[:-16]])
