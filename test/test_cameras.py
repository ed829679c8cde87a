"""Pixels <-> bearings for the rig file's camera models (OpenCV radtan and fisheye)."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from nrmpc_ros.cameras import bearings_to_pixels, camera_matrix, check_image_size, pixels_to_bearings
from nrmpc_ros.errors import InputError


@pytest.fixture
def pinhole(cross_rig):
    return cross_rig.cameras[0]


@pytest.mark.parametrize(
    "model, distortion",
    [("pinhole", ()), ("pinhole", (-0.2, 0.05, 0.001, -0.001)), ("pinhole", (-0.25, 0.08, 0.0, 0.0, -0.01)),
     ("equidistant", (0.1, -0.02, 0.01, 0.0))],
)
def test_round_trip(pinhole, model, distortion):
    cam = replace(pinhole, model=model, distortion=distortion)
    uv = np.random.default_rng(0).uniform([0, 0], [639, 479], size=(200, 2))
    f = pixels_to_bearings(cam, uv)
    assert np.allclose(np.linalg.norm(f, axis=1), 1.0) and np.all(f[:, 2] > 0)
    assert np.abs(bearings_to_pixels(cam, f) - uv).max() < 1e-6


def test_a_distortion_free_pinhole_projects_as_opencv(pinhole):
    """Without distortion the projection is computed in numpy: OpenCV's values, NaN behind the camera."""
    cam = replace(pinhole, model="pinhole", distortion=())
    f = np.random.default_rng(1).normal(size=(500, 3))
    uv = bearings_to_pixels(cam, f)
    front = f[:, 2] > 1e-9
    ref, _ = cv2.projectPoints(f[front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera_matrix(cam), np.zeros(4))
    np.testing.assert_allclose(uv[front], ref.reshape(-1, 2), rtol=1e-12, atol=1e-9)
    assert np.all(np.isnan(uv[~front]))


def test_principal_point_and_focal(pinhole):
    fx, fy, cx, cy = pinhole.intrinsics
    f = pixels_to_bearings(pinhole, [[cx, cy], [cx + fx, cy]])
    assert np.allclose(f[0], [0, 0, 1])
    assert np.isclose(np.degrees(np.arccos(f[1, 2])), 45.0)  # one focal length off-centre: 45 deg


def test_fisheye_wide_angles(pinhole):
    cam = replace(pinhole, model="equidistant", intrinsics=(200.0, 200.0, 319.5, 239.5), distortion=(0, 0, 0, 0))
    theta = np.radians([10.0, 45.0, 80.0])
    f = np.stack([np.sin(theta), np.zeros(3), np.cos(theta)], axis=1)
    uv = bearings_to_pixels(cam, f)
    assert np.allclose(uv[:, 0] - 319.5, 200.0 * theta)  # equidistant: r = f theta
    assert np.allclose(pixels_to_bearings(cam, uv), f, atol=1e-9)
    assert np.all(np.isnan(bearings_to_pixels(cam, [[0.0, 0.0, -1.0]])))  # behind the camera


def test_image_size_check_names_the_camera(pinhole):
    check_image_size(pinhole, 640, 480, "/cam0/image_raw")
    with pytest.raises(InputError, match="/cam0/image_raw.*320x240.*640x480"):
        check_image_size(pinhole, 320, 240, "/cam0/image_raw")
