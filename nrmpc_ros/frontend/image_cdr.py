"""Serialized sensor_msgs/Image and CompressedImage (CDR) -> views of the message, its pixels left in place.

The node takes its camera messages serialized, as it takes the IMU's (docs/ARCHITECTURE.md, "The node's two
workers"): a message rclpy converts into its Python object has every byte of its image copied once more into
a Python array, about a millisecond for a 640x480 colour image, the cost of decoding a JPEG of it. Read here,
the header fields come from their CDR offsets and ``data`` is a numpy view into the buffer the subscription
filled; :func:`~nrmpc_ros.frontend.images.decode_image` reads the views as it reads messages.

A message this reader cannot take apart (too short, lengths beyond its end, a CDR representation other than
plain CDR, which rosbags' reference deserializer then reads if it can) becomes an :class:`Unreadable` with
the reason: the feeder drops and counts it as an image it cannot decode.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass

import numpy as np

CDR_HEADER = 4  # representation identifier (2 bytes) and options (2 bytes); alignment counts from its end
PLAIN_CDR = {b"\x00\x00": ">", b"\x00\x01": "<"}  # representation identifier -> byte order
TYPENAMES = {False: "sensor_msgs/msg/Image", True: "sensor_msgs/msg/CompressedImage"}


@dataclass(frozen=True)
class Stamp:
    sec: int
    nanosec: int


@dataclass(frozen=True)
class Header:
    stamp: Stamp
    frame_id: str


@dataclass(frozen=True)
class ImageView:
    """A sensor_msgs/Image; ``data`` a uint8 view into the serialized message."""

    header: Header
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: np.ndarray


@dataclass(frozen=True)
class CompressedImageView:
    """A sensor_msgs/CompressedImage; ``data`` a uint8 view into the serialized message."""

    header: Header
    format: str
    data: np.ndarray


@dataclass(frozen=True)
class Unreadable:
    """A serialized image message that could not be read, and why; its stamp is unknown (0)."""

    header: Header
    problem: str


UNKNOWN_HEADER = Header(Stamp(0, 0), "")


class _Cursor:
    """Reads CDR fields in order from a buffer; IndexError past its end."""

    def __init__(self, buf: memoryview, order: str):
        self.buf, self.pos = buf, CDR_HEADER
        self.u32 = struct.Struct(order + "I")
        self.i32 = struct.Struct(order + "i")

    def _align(self, n: int) -> None:
        self.pos += -(self.pos - CDR_HEADER) % n

    def _need(self, n: int) -> None:
        if self.pos + n > len(self.buf):
            raise IndexError(f"a field at byte {self.pos} needs {n} bytes, the message has {len(self.buf)}")

    def _scalar(self, fmt: struct.Struct) -> int:
        self._align(fmt.size)
        self._need(fmt.size)
        (v,) = fmt.unpack_from(self.buf, self.pos)
        self.pos += fmt.size
        return v

    def uint32(self) -> int:
        return self._scalar(self.u32)

    def int32(self) -> int:
        return self._scalar(self.i32)

    def uint8(self) -> int:
        self._need(1)
        self.pos += 1
        return self.buf[self.pos - 1]

    def bytes_(self) -> memoryview:
        n = self.uint32()
        self._need(n)
        self.pos += n
        return self.buf[self.pos - n:self.pos]

    def string(self) -> str:
        raw = self.bytes_()  # CDR strings carry their terminating NUL in their length
        return bytes(raw[:-1] if len(raw) and raw[-1] == 0 else raw).decode("utf-8", "replace")

    def header(self) -> Header:
        sec, nanosec = self.int32(), self.uint32()
        return Header(Stamp(sec, nanosec), self.string())


def read_image(raw, compressed: bool) -> ImageView | CompressedImageView | Unreadable:
    """One serialized Image (``compressed`` False) or CompressedImage message (bytes-like) -> its view."""
    buf = memoryview(raw).cast("B")
    order = PLAIN_CDR.get(bytes(buf[:2]))
    if order is None:
        return _reference(buf, compressed)
    cur = _Cursor(buf, order)
    try:
        header = cur.header()
        if compressed:
            fmt = cur.string()
            return CompressedImageView(header, fmt, np.frombuffer(cur.bytes_(), np.uint8))
        height, width, encoding = cur.uint32(), cur.uint32(), cur.string()
        is_bigendian, step = cur.uint8(), cur.uint32()
        return ImageView(header, height, width, encoding, is_bigendian, step, np.frombuffer(cur.bytes_(), np.uint8))
    except IndexError as exc:
        return Unreadable(UNKNOWN_HEADER, f"truncated serialized {TYPENAMES[compressed]}: {exc}")


@functools.cache
def _typestore():
    from rosbags.typesys import Stores, get_typestore  # the reference CDR implementation (0.2 s to load)

    return get_typestore(Stores.ROS2_JAZZY)


def _reference(buf: memoryview, compressed: bool):
    """A representation other than plain CDR: rosbags' deserializer, where it reads it."""
    try:
        msg = _typestore().deserialize_cdr(bytes(buf), TYPENAMES[compressed])
    except Exception as exc:  # noqa: BLE001 - any failure of the reference means: not readable
        rep = bytes(buf[:2]).hex() or "none"
        return Unreadable(UNKNOWN_HEADER, f"serialized {TYPENAMES[compressed]} in representation 0x{rep} that "
                                          f"neither plain CDR nor the reference deserializer reads "
                                          f"({type(exc).__name__})")
    st = msg.header.stamp
    header = Header(Stamp(int(st.sec), int(st.nanosec)), str(msg.header.frame_id))
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if compressed:
        return CompressedImageView(header, str(msg.format), data)
    return ImageView(header, int(msg.height), int(msg.width), str(msg.encoding), int(msg.is_bigendian),
                     int(msg.step), data)


__all__ = ["CompressedImageView", "ImageView", "Unreadable", "read_image"]
