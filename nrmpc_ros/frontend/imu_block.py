"""IMU samples in blocks: sensor_msgs/Imu messages as arrays, decoded from their serialized (CDR) form at once.

A 1 kHz IMU delivers a message every millisecond. Turned into Python message
objects one by one (header, quaternion, three vectors, three covariance
arrays each) a message costs about 0.15 ms before any of its numbers is
used: 15 % of a core for the conversion alone. The node therefore takes the
IMU's messages serialized and decodes the ones waiting as one block
(docs/ARCHITECTURE.md, "The node's two workers").

The serialized form of ``sensor_msgs/msg/Imu`` is fixed by the message
definition and the CDR encoding (XCDR1, as rmw implementations write it): a
4-byte encapsulation header naming the byte order, then, aligned to their
size from the start of the payload, the stamp (int32 sec, uint32 nanosec),
the frame id (uint32 length with its terminating null, then the
characters) and 37 float64: orientation (4), its covariance (9), angular
velocity (3), its covariance (9), linear acceleration (3), its covariance
(9). Messages of one length and byte order share a layout and are read
with the same offsets. The first message of every layout is also
deserialized by rosbags' CDR implementation, and a layout whose numbers
differ from it (or that is not the one above) is decoded message by
message by rosbags from then on: the unpacking is an accelerator, the
library stays the reference.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from .images import ros_seconds, stamp_seconds

IMU_TYPE = "sensor_msgs/msg/Imu"
CDR_HEADER = 4  # encapsulation: 2 bytes representation id (byte 1: 1 little endian, 0 big), 2 bytes options
NUM_DOUBLES = 37
GYRO, GYRO_COV, ACCEL, ACCEL_COV = slice(13, 16), slice(16, 25), slice(25, 28), slice(28, 37)


@dataclass
class ImuBlock:
    """IMU samples in arrival order: stamps (n,) s, specific force ``accel`` (n, 3) m/s^2 and angular rate
    ``gyro`` (n, 3) rad/s in the IMU frame, and the messages' covariances (n, 9) each (row-major 3x3)."""

    stamps: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    accel_cov: np.ndarray
    gyro_cov: np.ndarray

    def __len__(self) -> int:
        return len(self.stamps)

    def part(self, start: int, stop: int) -> ImuBlock:
        """Samples ``start`` to ``stop`` (exclusive), as views."""
        k = slice(start, stop)
        return ImuBlock(self.stamps[k], self.accel[k], self.gyro[k], self.accel_cov[k], self.gyro_cov[k])

    @classmethod
    def _from_rows(cls, stamps, doubles) -> ImuBlock:
        return cls(stamps, doubles[:, ACCEL], doubles[:, GYRO], doubles[:, ACCEL_COV], doubles[:, GYRO_COV])


def _row(m) -> list:
    """[stamp s, the 37 doubles] of a deserialized message."""
    q, w, a = m.orientation, m.angular_velocity, m.linear_acceleration
    return [stamp_seconds(m), q.x, q.y, q.z, q.w, *np.asarray(m.orientation_covariance, float).ravel(),
            w.x, w.y, w.z, *np.asarray(m.angular_velocity_covariance, float).ravel(),
            a.x, a.y, a.z, *np.asarray(m.linear_acceleration_covariance, float).ravel()]


def _layout_size(frame_id_length: int) -> int:
    """Serialized size of an Imu message whose frame id (with its null) has ``frame_id_length`` bytes."""
    doubles_at = (12 + frame_id_length + 7) // 8 * 8
    return CDR_HEADER + doubles_at + 8 * NUM_DOUBLES


@dataclass(frozen=True)
class _Layout:
    """How messages of one size and byte order are read: the stamp and the doubles unpacked at their offsets,
    or ``reference`` (a function of the message) for a layout the unpacking does not read right."""

    stamp: struct.Struct | None
    doubles: struct.Struct | None
    reference: object

    def read(self, raw) -> list:
        """[stamp s, the 37 doubles] of one message."""
        if self.reference is not None:
            return self.reference(raw)
        sec, nsec = self.stamp.unpack_from(raw, CDR_HEADER)
        return [ros_seconds(sec, nsec), *self.doubles.unpack_from(raw, len(raw) - 8 * NUM_DOUBLES)]


class ImuDecoder:
    """Serialized sensor_msgs/Imu messages -> :class:`ImuBlock` (module docstring). Keeps which layouts were
    checked against the reference deserializer (an input's property, not an estimate)."""

    def __init__(self):
        self._typestore = None  # the reference, loaded with the first layout to check (0.2 s: not at start-up)
        self._layouts: dict = {}  # (size, byte order) -> its _Layout

    def decode(self, raws: list) -> ImuBlock:
        """The samples of ``raws`` (serialized messages, bytes-like) in their order."""
        rows = [self._layout(raw).read(raw) for raw in raws]
        arr = np.array(rows, dtype=float).reshape(len(rows), 1 + NUM_DOUBLES)
        return ImuBlock._from_rows(arr[:, 0], arr[:, 1:])

    def _layout(self, raw) -> _Layout:
        key = (len(raw), bytes(raw[:2]))
        layout = self._layouts.get(key)
        if layout is None:
            layout = self._layouts[key] = self._check(key[0], key[1], raw)
        return layout

    def _check(self, size: int, rep: bytes, first) -> _Layout:
        """The layout of messages of ``size`` bytes in byte order ``rep``, checked on ``first`` against the
        reference; the reference itself where the array reading does not give its numbers."""
        reference = _Layout(None, None, self._reference)
        if rep not in (b"\x00\x01", b"\x00\x00") or size < CDR_HEADER + 12:
            return reference
        order = "<" if rep[1] == 1 else ">"
        (length,) = struct.unpack_from(f"{order}I", first, CDR_HEADER + 8)
        if _layout_size(length) != size:
            return reference
        fast = _Layout(struct.Struct(f"{order}iI"), struct.Struct(f"{order}{NUM_DOUBLES}d"), None)
        ours, theirs = np.array(fast.read(first)), np.array(self._reference(first))
        return fast if np.array_equal(ours, theirs, equal_nan=True) else reference

    def _reference(self, raw) -> list:
        if self._typestore is None:
            from rosbags.typesys import Stores, get_typestore  # the reference CDR implementation
            self._typestore = get_typestore(Stores.ROS2_JAZZY)
        return _row(self._typestore.deserialize_cdr(bytes(raw), IMU_TYPE))


__all__ = ["ImuBlock", "ImuDecoder"]
