"""sensor_msgs/CameraInfo against the rig file: what differs, with numbers (the rig file stays the source of truth).

One check for the node (the first CameraInfo of each camera) and ``nrmpc replay``
(the first of each camera in the bag). A CameraInfo of an uncalibrated camera
(K all zero, as drivers publish without a calibration) says nothing about the
intrinsics and is not reported. Pixel quantities are compared to
``PIXEL_TOLERANCE``, distortion coefficients to ``DISTORTION_TOLERANCE``.
"""

from __future__ import annotations

import numpy as np

from ..core.rig import Camera

PIXEL_TOLERANCE = 0.5  # px: focal lengths and principal point
DISTORTION_TOLERANCE = 1e-4  # unitless coefficients
# ROS distortion_model names that describe each rig camera model
MODELS = {"pinhole": ("plumb_bob", "rational_polynomial"), "equidistant": ("equidistant", "fisheye")}


def camera_info_mismatch(cam: Camera, msg, rig_source: str = "") -> str | None:
    """What ``msg`` (a sensor_msgs/CameraInfo, rclpy or rosbags) says differently from ``cam`` of the rig file
    ``rig_source``; None if it agrees."""
    problems = []
    size = (int(msg.width), int(msg.height))
    if size != (0, 0) and size != tuple(cam.resolution):
        problems.append(f"resolution {size[0]}x{size[1]}, the rig file {cam.resolution[0]}x{cam.resolution[1]}")
    K = np.asarray(msg.k, dtype=float).reshape(3, 3)
    if np.any(K):
        got = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
        want = np.asarray(cam.intrinsics, dtype=float)
        if np.max(np.abs(got - want)) > PIXEL_TOLERANCE:
            problems.append("intrinsics fx fy cx cy " + " ".join(f"{v:.2f}" for v in got) + ", the rig file "
                            + " ".join(f"{v:.2f}" for v in want))
        model = str(msg.distortion_model)
        if model and model not in MODELS.get(cam.model, ()):
            problems.append(f"distortion model {model!r}, the rig file {cam.model!r} "
                            f"({' or '.join(MODELS.get(cam.model, ()))})")
        else:
            d = np.asarray(msg.d, dtype=float).reshape(-1)
            n = max(len(d), len(cam.distortion))
            got_d, want_d = np.zeros(n), np.zeros(n)
            got_d[:len(d)], want_d[:len(cam.distortion)] = d, cam.distortion
            if n and np.max(np.abs(got_d - want_d)) > DISTORTION_TOLERANCE:
                problems.append(f"distortion [{', '.join(f'{v:.5g}' for v in got_d)}], the rig file "
                                f"[{', '.join(f'{v:.5g}' for v in want_d)}]")
    if not problems:
        return None
    where = f"the rig file {rig_source}" if rig_source else "the rig file"
    return f"CameraInfo of camera {cam.name!r} disagrees with {where}: " + "; ".join(problems) + \
        " (using the rig file)"


__all__ = ["DISTORTION_TOLERANCE", "MODELS", "PIXEL_TOLERANCE", "camera_info_mismatch"]
