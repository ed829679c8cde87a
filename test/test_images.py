"""decode_image: raw encodings (step, endianness, 16 bit, Bayer, YUV), CompressedImage, clear errors."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.images import decode_image, resize_to, scale_to, stamp_seconds, to_uint8


def raw(arr, encoding, step=None, bigendian=False):
    """A sensor_msgs/Image-like object holding arr (H, W[, C]); rows padded to ``step`` bytes."""
    a = np.ascontiguousarray(arr)
    if a.dtype == np.uint16:
        a = a.astype(">u2" if bigendian else "<u2")
    h = a.shape[0]
    row = a.reshape(h, -1).view(np.uint8)
    step = step or row.shape[1]
    buf = np.zeros((h, step), np.uint8)
    buf[:, : row.shape[1]] = row
    return SimpleNamespace(height=h, width=a.shape[1], encoding=encoding, is_bigendian=int(bigendian), step=step,
                           data=buf.ravel())


@pytest.fixture
def colour(rng):
    return rng.integers(0, 256, size=(6, 7, 3), dtype=np.uint8)


def test_mono8_with_row_padding(rng):
    img = rng.integers(0, 256, size=(5, 9), dtype=np.uint8)
    out = decode_image(raw(img, "mono8", step=16), "/cam0/image_raw")
    assert out.dtype == np.uint8 and out.shape == (5, 9)
    np.testing.assert_array_equal(out, img)


@pytest.mark.parametrize("enc,code", [("bgr8", cv2.COLOR_BGR2GRAY), ("rgb8", cv2.COLOR_RGB2GRAY)])
def test_colour_encodings(colour, enc, code):
    out = decode_image(raw(colour, enc, step=7 * 3 + 3), "/c")
    np.testing.assert_array_equal(out, cv2.cvtColor(colour, code))


def test_rgb_and_bgr_differ_as_expected(colour):
    bgr = decode_image(raw(colour, "bgr8"), "/c")
    rgb = decode_image(raw(colour[:, :, ::-1], "rgb8"), "/c")
    np.testing.assert_array_equal(bgr, rgb)


@pytest.mark.parametrize("enc", ["bgra8", "rgba8"])
def test_four_channels(rng, enc):
    img = rng.integers(0, 256, size=(4, 5, 4), dtype=np.uint8)
    code = cv2.COLOR_BGRA2GRAY if enc == "bgra8" else cv2.COLOR_RGBA2GRAY
    np.testing.assert_array_equal(decode_image(raw(img, enc), "/c"), cv2.cvtColor(img, code))


@pytest.mark.parametrize("bigendian", [False, True])
@pytest.mark.parametrize("enc", ["mono16", "16UC1"])
def test_16_bit_scaled_to_8_bit(rng, bigendian, enc):
    img = rng.integers(0, 65536, size=(4, 6), dtype=np.uint16)
    img[0, 0] = 65535
    out = decode_image(raw(img, enc, step=6 * 2 + 4, bigendian=bigendian), "/c")
    np.testing.assert_array_equal(out, (img >> 8).astype(np.uint8))


def test_12_bit_data_in_16_bit_container_stays_visible(rng):
    img = rng.integers(0, 4096, size=(4, 6), dtype=np.uint16)
    img[0, 0] = 4095
    out = decode_image(raw(img, "mono16"), "/c")
    np.testing.assert_array_equal(out, (img >> 4).astype(np.uint8))
    assert out.max() == 255
    np.testing.assert_array_equal(to_uint8(img, depth_bits=16), (img >> 8).astype(np.uint8))


@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_compressed(rng, ext):
    img = cv2.GaussianBlur(rng.integers(0, 256, size=(32, 40), dtype=np.uint8), (5, 5), 2)
    ok, buf = cv2.imencode(ext, img)
    assert ok
    out = decode_image(SimpleNamespace(format=ext[1:], data=buf.ravel()), "/c/compressed")
    assert out.shape == img.shape and out.dtype == np.uint8
    assert np.abs(out.astype(int) - img).max() <= (0 if ext == ".png" else 12)


def test_compressed_colour_becomes_grey(colour):
    ok, buf = cv2.imencode(".png", colour)
    out = decode_image(SimpleNamespace(format="png", data=bytes(buf.ravel())), "/c")
    np.testing.assert_array_equal(out, cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))


def test_rosbags_message_objects(rng):
    ts = get_typestore(Stores.ROS2_JAZZY)
    Image = ts.types["sensor_msgs/msg/Image"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    img = rng.integers(0, 256, size=(3, 4), dtype=np.uint8)
    msg = Image(header=Header(stamp=Time(sec=12, nanosec=500_000_000), frame_id="cam0"), height=3, width=4,
                encoding="mono8", is_bigendian=0, step=4, data=img.ravel())
    raw_bytes = ts.serialize_cdr(msg, "sensor_msgs/msg/Image")
    back = ts.deserialize_cdr(raw_bytes, "sensor_msgs/msg/Image")
    np.testing.assert_array_equal(decode_image(back, "/cam0/image_raw"), img)
    assert stamp_seconds(back) == pytest.approx(12.5)


def smooth_colour(h=48, w=64):
    """A BGR image whose channels differ strongly and vary smoothly (demosaicing is then exact to a few levels):
    red rises left to right, blue top to bottom, green is their mean."""
    yy, xx = np.mgrid[0:h, 0:w]
    r, b = 40 + 180 * xx / w, 30 + 200 * yy / h
    return np.dstack([b, (r + b) / 2, r])


def through_cfa(bgr, pattern):
    """A colour image seen through the colour filter array ``pattern`` (top-left 2x2 cell, e.g. "rggb")."""
    out = np.empty(bgr.shape[:2], bgr.dtype)
    for k, c in enumerate(pattern):
        out[k // 2::2, k % 2::2] = bgr[k // 2::2, k % 2::2, "bgr".index(c)]
    return out


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
@pytest.mark.parametrize("bits", [8, 16])
def test_bayer_patterns_demosaic_to_the_scenes_grey(pattern, bits):
    colour = smooth_colour()
    grey = cv2.cvtColor(np.rint(colour).astype(np.uint8), cv2.COLOR_BGR2GRAY).astype(int)
    scale = 16 if bits == 16 else 1  # 12 significant bits in 16, as machine-vision cameras send
    mosaic = np.rint(through_cfa(colour, pattern) * scale).astype(np.uint16 if bits == 16 else np.uint8)
    out = decode_image(raw(mosaic, f"bayer_{pattern}{bits}", step=64 * bits // 8 + 8), "/c")
    inner = (slice(2, -2), slice(2, -2))
    assert out.shape == grey.shape and out.dtype == np.uint8
    assert np.abs(out[inner].astype(int) - grey[inner]).max() <= 3
    # read with another pattern, the same bytes give another grey: the pattern is honoured
    other = {"rggb": "bggr", "bggr": "rggb", "gbrg": "rggb", "grbg": "bggr"}[pattern]
    wrong = decode_image(raw(mosaic, f"bayer_{other}{bits}"), "/c")
    assert np.abs(wrong[inner].astype(int) - grey[inner]).max() > 10


@pytest.mark.parametrize("enc,y_at", [("uyvy", 1), ("yuv422", 1), ("yuyv", 0), ("yuv422_yuy2", 0)])
def test_packed_yuv_gives_its_luma(rng, enc, y_at):
    luma = rng.integers(0, 256, size=(5, 6), dtype=np.uint8)
    packed = rng.integers(0, 256, size=(5, 12), dtype=np.uint8)  # chroma of a colourful scene
    packed[:, y_at::2] = luma
    out = decode_image(_with_width(raw(packed, enc, step=16), 6), "/c")
    np.testing.assert_array_equal(out, luma)


@pytest.mark.parametrize("enc,chroma_rows", [("nv21", 3), ("nv24", 10)])
def test_semi_planar_yuv_gives_its_luma_plane(rng, enc, chroma_rows):
    luma = rng.integers(0, 256, size=(5, 6), dtype=np.uint8)
    planes = np.concatenate([luma, rng.integers(0, 256, size=(chroma_rows, 6), dtype=np.uint8)])
    msg = raw(planes, enc)
    msg.height = 5
    np.testing.assert_array_equal(decode_image(msg, "/c"), luma)
    msg.data = msg.data[:5 * 6 + 2]  # the luma plane, but not the chroma the encoding says follows
    with pytest.raises(InputError, match=r"/c: field 'data'.*chroma"):
        decode_image(msg, "/c")


def _with_width(msg, width):
    msg.width = width
    return msg


@pytest.mark.parametrize("enc,code", [("bgr16", cv2.COLOR_BGR2GRAY), ("rgb16", cv2.COLOR_RGB2GRAY),
                                      ("8UC3", cv2.COLOR_BGR2GRAY)])
def test_more_colour_encodings(rng, enc, code):
    colour = rng.integers(0, 256, size=(4, 5, 3), dtype=np.uint8)
    arr = colour.astype(np.uint16) * 257 if enc.endswith("16") else colour
    out = decode_image(raw(arr, enc), "/c").astype(int)
    assert np.abs(out - cv2.cvtColor(colour, code)).max() <= (1 if enc.endswith("16") else 0)  # 16 bit: rounding


def test_unsupported_encoding_names_topic():
    msg = raw(np.zeros((2, 2), np.float32).view(np.uint8), "32FC1")
    with pytest.raises(InputError, match=r"/cam3/image_raw.*encoding.*32FC1"):
        decode_image(msg, "/cam3/image_raw")


def test_short_data_and_bad_step():
    msg = raw(np.zeros((4, 4), np.uint8), "mono8")
    msg.data = msg.data[:10]
    with pytest.raises(InputError, match=r"/cam1/image_raw: field 'data'"):
        decode_image(msg, "/cam1/image_raw")
    msg = raw(np.zeros((4, 4), np.uint8), "mono8")
    msg.step = 3
    with pytest.raises(InputError, match="step"):
        decode_image(msg, "/cam1/image_raw")


def test_undecodable_compressed():
    with pytest.raises(InputError, match="/cam0/compressed.*cannot decode"):
        decode_image(SimpleNamespace(format="jpeg", data=b"not a jpeg"), "/cam0/compressed")


def test_a_binned_image_resized_to_the_full_sensor_keeps_its_pixel_centres():
    """2x2 binning: binned pixel j covers full pixels 2j and 2j + 1, its centre at 2j + 1/2. A bright dot
    at binned (x, y) lands at full (2x + 1/2, 2y + 1/2) after resizing back; another aspect ratio or a factor
    beyond 8 is no resize."""
    small = np.zeros((60, 80), np.uint8)
    cv2.circle(small, (30, 20), 3, 255, -1)
    assert scale_to(small, (160, 120)) == 2.0 and scale_to(small, (40, 30)) == 0.5
    assert scale_to(small, (160, 160)) is None and scale_to(small, (800, 600)) is None
    big = resize_to(small, (160, 120)).astype(float)
    ys, xs = np.mgrid[:120, :160]
    centre = (float((xs * big).sum() / big.sum()), float((ys * big).sum() / big.sum()))
    assert centre == pytest.approx((2 * 30 + 0.5, 2 * 20 + 0.5), abs=0.05)
    back = resize_to(big.astype(np.uint8), (80, 60)).astype(float)
    ys, xs = np.mgrid[:60, :80]
    assert (float((xs * back).sum() / back.sum()), float((ys * back).sum() / back.sum())) == pytest.approx(
        (30.0, 20.0), abs=0.05)
