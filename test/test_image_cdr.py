"""Serialized image messages read in place (nrmpc_ros.frontend.image_cdr) against reference serializers."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.image_cdr import CompressedImageView, ImageView, Unreadable, read_image
from nrmpc_ros.frontend.images import decode_image

TS = get_typestore(Stores.ROS2_JAZZY)
Image, CompressedImage = TS.types["sensor_msgs/msg/Image"], TS.types["sensor_msgs/msg/CompressedImage"]
Header, Time = TS.types["std_msgs/msg/Header"], TS.types["builtin_interfaces/msg/Time"]


def header(sec: int, nanosec: int, frame_id: str):
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def assert_header(view, sec, nanosec, frame_id):
    assert (view.header.stamp.sec, view.header.stamp.nanosec, view.header.frame_id) == (sec, nanosec, frame_id)


texts = st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=9)


@settings(max_examples=60, deadline=None)
@given(sec=st.integers(-2**31, 2**31 - 1), nanosec=st.integers(0, 999_999_999), frame_id=texts, encoding=texts,
       height=st.integers(0, 5), width=st.integers(0, 7), bigendian=st.integers(0, 1), little=st.booleans(),
       seed=st.integers(0, 2**16))
def test_raw_images_read_as_the_reference_wrote_them(sec, nanosec, frame_id, encoding, height, width, bigendian,
                                                     little, seed):
    """Every field at its place, whatever lengths the strings give the alignment, in either byte order."""
    data = np.random.default_rng(seed).integers(0, 256, height * width * 3, dtype=np.uint8)
    msg = Image(header=header(sec, nanosec, frame_id), height=height, width=width, encoding=encoding,
                is_bigendian=bigendian, step=width * 3, data=data)
    view = read_image(TS.serialize_cdr(msg, Image.__msgtype__, little_endian=little), compressed=False)
    assert isinstance(view, ImageView)
    assert_header(view, sec, nanosec, frame_id)
    assert (view.height, view.width, view.encoding, view.is_bigendian, view.step) == (height, width, encoding,
                                                                                      bigendian, width * 3)
    np.testing.assert_array_equal(view.data, data)


@settings(max_examples=40, deadline=None)
@given(frame_id=texts, fmt=texts, size=st.integers(0, 40), little=st.booleans())
def test_compressed_images_read_as_the_reference_wrote_them(frame_id, fmt, size, little):
    data = np.arange(size, dtype=np.uint8)
    msg = CompressedImage(header=header(7, 8, frame_id), format=fmt, data=data)
    view = read_image(TS.serialize_cdr(msg, CompressedImage.__msgtype__, little_endian=little), compressed=True)
    assert isinstance(view, CompressedImageView)
    assert_header(view, 7, 8, frame_id)
    assert view.format == fmt
    np.testing.assert_array_equal(view.data, data)


def test_the_pixels_are_a_view_of_the_buffer_not_a_copy():
    buf = bytearray(TS.serialize_cdr(Image(header=header(1, 2, "cam"), height=2, width=3, encoding="mono8",
                                           is_bigendian=0, step=3, data=np.arange(6, dtype=np.uint8)),
                                     Image.__msgtype__))
    view = read_image(buf, compressed=False)
    buf[-1] = 99
    assert view.data[-1] == 99
    np.testing.assert_array_equal(decode_image(view, "/cam"), [[0, 1, 2], [3, 4, 99]])


def test_rclpy_serialized_messages_read_as_rclpy_reads_them():
    """The node's own serializer: a colour image and a JPEG read in place as rclpy deserializes them."""
    serialization = pytest.importorskip("rclpy.serialization")
    msgs = pytest.importorskip("sensor_msgs.msg")
    img = np.random.default_rng(0).integers(0, 256, (4, 5, 3), dtype=np.uint8)
    m = msgs.Image(height=4, width=5, encoding="bgr8", step=15, data=img.tobytes())
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = 12, 345, "cam_0"
    view = read_image(serialization.serialize_message(m), compressed=False)
    assert_header(view, 12, 345, "cam_0")
    np.testing.assert_array_equal(decode_image(view, "/cam"), decode_image(m, "/cam"))
    c = msgs.CompressedImage(format="jpeg", data=bytes(range(30)))
    c.header.frame_id = "x" * 5
    cview = read_image(serialization.serialize_message(c), compressed=True)
    assert cview.format == "jpeg" and bytes(cview.data) == bytes(range(30))


@pytest.mark.parametrize("cut", [0, 3, 10, 20, 40])
def test_a_truncated_message_is_unreadable_and_its_decoding_names_the_topic(cut):
    raw = bytes(TS.serialize_cdr(Image(header=header(1, 2, "cam"), height=2, width=3, encoding="mono8",
                                       is_bigendian=0, step=3, data=np.arange(6, dtype=np.uint8)),
                                 Image.__msgtype__))[:cut]
    view = read_image(raw, compressed=False)
    assert isinstance(view, Unreadable)
    with pytest.raises(InputError, match="/cam0/image_raw"):
        decode_image(view, "/cam0/image_raw")


def test_an_unknown_representation_is_unreadable_with_its_identifier():
    view = read_image(b"\x00\x0b\x00\x00" + bytes(40), compressed=True)
    assert isinstance(view, Unreadable) and "0x000b" in view.problem
