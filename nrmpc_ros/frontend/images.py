"""sensor_msgs/Image and CompressedImage -> 2-D uint8 grey images (rosbags and rclpy objects alike).

Message buffers are read where they are (``np.frombuffer``: a mono8 image with rows of its own width is a view
of the message, not a copy); each image is decoded once, by the feeder (docs/PIPELINE.md, "Performance notes").
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..errors import InputError
from .image_cdr import Unreadable

# Packed encodings: encoding -> (channels, dtype, cv2 conversion to grey or None). 8UC3/8UC4 are read as BGR(A),
# as cv_bridge does.
_PACKED = {
    "mono8": (1, np.uint8, None),
    "8uc1": (1, np.uint8, None),
    "bgr8": (3, np.uint8, cv2.COLOR_BGR2GRAY),
    "8uc3": (3, np.uint8, cv2.COLOR_BGR2GRAY),
    "rgb8": (3, np.uint8, cv2.COLOR_RGB2GRAY),
    "bgra8": (4, np.uint8, cv2.COLOR_BGRA2GRAY),
    "8uc4": (4, np.uint8, cv2.COLOR_BGRA2GRAY),
    "rgba8": (4, np.uint8, cv2.COLOR_RGBA2GRAY),
    "mono16": (1, np.uint16, None),
    "16uc1": (1, np.uint16, None),
    "bgr16": (3, np.uint16, cv2.COLOR_BGR2GRAY),
    "rgb16": (3, np.uint16, cv2.COLOR_RGB2GRAY),
    "bgra16": (4, np.uint16, cv2.COLOR_BGRA2GRAY),
    "rgba16": (4, np.uint16, cv2.COLOR_RGBA2GRAY),
}
# Colour filter arrays as machine-vision drivers publish them (sensor_msgs/image_encodings.h: the pattern of the
# top-left 2x2 cell), demosaiced straight to grey. OpenCV names a pattern by the second row's second and third
# pixels, so ROS rggb is OpenCV's BG (cv_bridge's mapping).
_BAYER = {
    "rggb": cv2.COLOR_BayerBG2GRAY,
    "bggr": cv2.COLOR_BayerRG2GRAY,
    "gbrg": cv2.COLOR_BayerGR2GRAY,
    "grbg": cv2.COLOR_BayerGB2GRAY,
}
for _cfa, _code in _BAYER.items():
    _PACKED[f"bayer_{_cfa}8"] = (1, np.uint8, _code)
    _PACKED[f"bayer_{_cfa}16"] = (1, np.uint16, _code)
# Luma-chroma encodings of USB and embedded cameras: the grey image is the luma plane, read in place (no colour
# conversion). Packed 4:2:2: encoding -> byte offset of Y in each 2-byte pixel; semi-planar: encoding -> bytes of
# chroma per byte of luma after the luma plane.
_YUV_PACKED = {"uyvy": 1, "yuv422": 1, "yuyv": 0, "yuv422_yuy2": 0}
_YUV_PLANAR = {"nv21": 0.5, "nv24": 2.0}
SUPPORTED_ENCODINGS = ("mono8", "8UC1", "bgr8", "rgb8", "bgra8", "rgba8", "8UC3", "8UC4", "mono16", "16UC1",
                       "bgr16", "rgb16", "bgra16", "rgba16", *(f"bayer_{c}{b}" for b in (8, 16) for c in _BAYER),
                       *_YUV_PACKED, *_YUV_PLANAR)


def _bytes(data) -> np.ndarray:
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    try:
        return np.frombuffer(data, np.uint8)  # bytes, bytearray, memoryview, array.array
    except TypeError:
        return np.asarray(data, dtype=np.uint8).reshape(-1)  # a list of ints


def to_uint8(img16: np.ndarray, depth_bits: int | None = None) -> np.ndarray:
    """16-bit grey -> 8 bit by a right shift of (depth_bits - 8).

    ``depth_bits=None`` takes the smallest of 8, 10, 12, 14, 16 bits that holds
    the image's maximum (10/12-bit sensors packed in 16 bits stay visible).
    """
    if depth_bits is None:
        top = int(img16.max()) if img16.size else 0
        depth_bits = next(b for b in (8, 10, 12, 14, 16) if top < (1 << b))
    shift = max(0, int(depth_bits) - 8)
    return np.minimum(img16 >> shift, 255).astype(np.uint8)


def _rows(msg, source: str, row: int, extra_rows: float = 0.0) -> np.ndarray:
    """The message's ``height`` rows of ``row`` bytes each, ``step`` apart (a view of its buffer); the buffer must
    also hold ``extra_rows`` more rows of ``step`` bytes (a chroma plane)."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise InputError(source, f"empty image ({w}x{h})", "width")
    if step < row:
        raise InputError(source, f"step {step} is smaller than width * bytes per pixel = {row}", "step")
    buf = _bytes(msg.data)
    need = step * (h - 1) + row + math.ceil(step * extra_rows)
    if buf.size < need:
        raise InputError(source, f"data holds {buf.size} bytes but {h} rows of step {step} "
                                 f"{'and the chroma plane ' if extra_rows else ''}need {need}", "data")
    return np.lib.stride_tricks.as_strided(buf, shape=(h, row), strides=(step, 1))


def decode_raw(msg, source: str, depth_bits: int | None = None) -> np.ndarray:
    """A sensor_msgs/Image -> (height, width) uint8 grey, honouring step and is_bigendian: packed grey and colour
    (8 and 16 bit), Bayer patterns (demosaiced), and YUV (its luma plane)."""
    enc = str(msg.encoding)
    key = enc.lower()
    h, w = int(msg.height), int(msg.width)
    if key in _YUV_PACKED:
        rows = _rows(msg, source, 2 * w)
        return np.ascontiguousarray(rows[:, _YUV_PACKED[key]::2])
    if key in _YUV_PLANAR:
        return np.ascontiguousarray(_rows(msg, source, w, h * _YUV_PLANAR[key]))
    spec = _PACKED.get(key)
    if spec is None:
        raise InputError(source, f"unsupported image encoding {enc!r} (supported: {', '.join(SUPPORTED_ENCODINGS)})",
                         "encoding")
    ch, dtype, conv = spec
    rows = _rows(msg, source, w * ch * np.dtype(dtype).itemsize)
    if dtype == np.uint8:
        img = np.ascontiguousarray(rows).reshape(h, w, ch) if ch > 1 else np.ascontiguousarray(rows)
        return cv2.cvtColor(img, conv) if conv is not None else img
    order = ">" if bool(msg.is_bigendian) else "<"
    img = np.ascontiguousarray(rows).view(np.dtype(f"{order}u2")).reshape(h, w, ch).astype(np.uint16)
    img = img[:, :, 0] if ch == 1 else img
    return to_uint8(cv2.cvtColor(img, conv) if conv is not None else img, depth_bits)


JPEG_MAGIC = b"\xff\xd8"


def decode_compressed(msg, source: str) -> np.ndarray:
    """A sensor_msgs/CompressedImage (jpeg, png, ...) -> 2-D uint8; the message's buffer is read in place.

    A JPEG is decoded straight to grey (libjpeg then skips the colour planes); other formats as they are (a
    16-bit PNG keeps its depth for :func:`to_uint8`)."""
    buf = _bytes(msg.data)
    jpeg = buf[:2].tobytes() == JPEG_MAGIC
    img = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE if jpeg else cv2.IMREAD_UNCHANGED) if buf.size else None
    if img is None:
        raise InputError(source, f"cannot decode compressed image (format {str(msg.format)!r}, {buf.size} bytes)",
                         "data")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    if img.dtype == np.uint16:
        img = to_uint8(img)
    elif img.dtype != np.uint8:
        raise InputError(source, f"compressed image decodes to unsupported dtype {img.dtype}", "data")
    return img


def decode_image(msg, source: str, depth_bits: int | None = None) -> np.ndarray:
    """Image or CompressedImage message (or a view of one, :mod:`~nrmpc_ros.frontend.image_cdr`) -> 2-D uint8
    grey image; InputError naming ``source`` otherwise."""
    if isinstance(msg, Unreadable):
        raise InputError(source, msg.problem)
    if hasattr(msg, "encoding"):
        return decode_raw(msg, source, depth_bits)
    if hasattr(msg, "format"):
        return decode_compressed(msg, source)
    raise InputError(source, f"not a sensor_msgs/Image or CompressedImage ({type(msg).__name__})")


RESIZE_RANGE = (0.125, 8.0)
"""Scales from a stream's images to the rig file's size that are resized: binning or a driver's resize by up to 8
either way; beyond it the images are another camera's."""


def scale_to(img: np.ndarray, size: tuple) -> float | None:
    """The one factor that takes ``img`` to ``size`` (width, height) pixel for pixel, where both sides scale
    alike (within a pixel of the smaller image) and by a factor in :data:`RESIZE_RANGE`; None otherwise (another
    aspect ratio: a crop or another camera, no resize recovers it)."""
    h, w = img.shape[:2]
    sx, sy = size[0] / w, size[1] / h
    if abs(sx - sy) * min(w, h) > max(sx, sy) or not RESIZE_RANGE[0] <= sx <= RESIZE_RANGE[1]:
        return None
    return sx


def resize_to(img: np.ndarray, size: tuple) -> np.ndarray:
    """``img`` resampled to ``size`` (width, height), pixel centres kept (x_rig = s (x + 1/2) - 1/2: what 2x2
    binning does to the full sensor's pixels, so a rig file calibrated at full size stays exact): averaging when
    it shrinks, bilinear when it grows."""
    grow = size[0] > img.shape[1]
    return cv2.resize(img, size, interpolation=cv2.INTER_LINEAR if grow else cv2.INTER_AREA)


def ros_seconds(sec, nanosec) -> float:
    """A ROS stamp (sec, nanosec) in seconds (float); every reader of stamps computes them so, bit for bit."""
    return float(sec) + 1e-9 * float(nanosec)


def stamp_seconds(msg) -> float:
    """header.stamp of a message (rclpy, rosbags or ROS 1) in seconds (float)."""
    st = msg.header.stamp
    return ros_seconds(st.sec, getattr(st, "nanosec", getattr(st, "nsec", 0)))
