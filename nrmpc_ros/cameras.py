"""Camera models of the rig file: pixels <-> unit bearings (docs/CONVENTIONS.md (Files)), through OpenCV.

``pinhole`` is OpenCV's radial-tangential model (k1 k2 p1 p2 [k3]);
``equidistant`` is OpenCV's fisheye model (k1 k2 k3 k4). Bearings follow the
OpenCV camera frame (x right, y down, z forward).
"""

from __future__ import annotations

import cv2
import numpy as np

from .core.rig import Camera
from .errors import InputError


def camera_matrix(cam: Camera) -> np.ndarray:
    fx, fy, cx, cy = cam.intrinsics
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _dist(cam: Camera) -> np.ndarray:
    n = 4 if cam.model == "equidistant" else max(len(cam.distortion), 4)
    d = np.zeros(n)
    d[: len(cam.distortion)] = cam.distortion
    return d


def pixels_to_bearings(cam: Camera, uv) -> np.ndarray:
    """Unit bearings (N, 3) of pixel coordinates uv (N, 2)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    if len(uv) == 0:
        return np.zeros((0, 3))
    K, d = camera_matrix(cam), _dist(cam)
    if cam.model == "equidistant":
        xy = cv2.fisheye.undistortPoints(uv, K, d)
    else:
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        xy = cv2.undistortPoints(uv, K, d, None, None, None, crit) if np.any(d) else cv2.undistortPoints(uv, K, None)
    xy = xy.reshape(-1, 2)
    f = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    return f / np.linalg.norm(f, axis=1, keepdims=True)


def bearings_to_pixels(cam: Camera, f) -> np.ndarray:
    """Pixel coordinates (N, 2) of bearings f (N, 3) in front of the camera (z > 0); NaN behind."""
    f = np.asarray(f, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(f), 2), np.nan)
    front = f[:, 2] > 1e-9
    if not front.any():
        return out
    K, d = camera_matrix(cam), _dist(cam)
    if cam.model != "equidistant" and not np.any(d):
        # OpenCV's model without distortion is K (x / z, y / z, 1): the same in numpy, without projectPoints'
        # Jacobians (always computed in the binding), several times faster on the patch grids
        fx, fy, cx, cy = cam.intrinsics
        p = f[front]
        out[front, 0] = fx * (p[:, 0] / p[:, 2]) + cx
        out[front, 1] = fy * (p[:, 1] / p[:, 2]) + cy
        return out
    pts = f[front].reshape(-1, 1, 3)
    rvec = tvec = np.zeros(3)
    if cam.model == "equidistant":
        uv, _ = cv2.fisheye.projectPoints(pts, rvec, tvec, K, d)
    else:
        uv, _ = cv2.projectPoints(pts, rvec, tvec, K, d)
    out[front] = uv.reshape(-1, 2)
    return out


def check_image_size(cam: Camera, width: int, height: int, source: str) -> None:
    """Raise a clear error when an image does not have the rig file's resolution."""
    if (int(width), int(height)) != tuple(cam.resolution):
        raise InputError(source, f"image is {width}x{height} but the rig file says {cam.resolution[0]}x"
                         f"{cam.resolution[1]} for camera {cam.name!r}", "resolution")
