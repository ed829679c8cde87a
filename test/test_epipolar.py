"""One camera's essential matrix: inliers of a rigid motion with outliers, bearings behind or beside the camera."""

import cv2
import numpy as np

from nrmpc_ros.core.epipolar import MIN_BEARING_Z, essential_matrix, in_front
from nrmpc_ros.core.so3 import exp_so3, rotation_angle


def _pairs(rng, n=200, outliers=0.2, noise_rad=0.5 / 400):
    P = rng.uniform([-2.0, -2.0, 3.0], [2.0, 2.0, 8.0], size=(n, 3))
    R, t = exp_so3(np.array([0.02, 0.05, -0.03])), np.array([0.3, 0.05, 0.02])  # view 2 -> view 1
    f1 = P / np.linalg.norm(P, axis=1, keepdims=True)
    f2 = (P - t) @ R
    f2 = f2 / np.linalg.norm(f2, axis=1, keepdims=True) + rng.normal(scale=noise_rad, size=(n, 3))
    bad = rng.random(n) < outliers
    f2[bad] = rng.normal(size=(bad.sum(), 3)) * [0.3, 0.3, 0.0] + [0.0, 0.0, 1.0]
    return f1, f2 / np.linalg.norm(f2, axis=1, keepdims=True), ~bad, R


def test_the_essential_matrix_separates_inliers_and_holds_the_rotation(rng):
    cv2.setRNGSeed(0)
    f1, f2, good, R = _pairs(rng)
    E, ok, x1, x2 = essential_matrix(f1, f2, 2.0 / 400)
    assert E.shape == (3, 3) and ok.shape == (len(f1),)
    assert ok[good].mean() > 0.95 and ok[~good].mean() < 0.1
    _, Rcv, _, _ = cv2.recoverPose(E, x1[ok], x2[ok], np.eye(3))
    assert rotation_angle(Rcv.T.T @ R) < 0.01  # OpenCV's x2 = Rcv x1 + t: its transpose maps view 2 into view 1


def test_bearings_too_far_off_axis_are_not_used():
    z = np.array([1.0, MIN_BEARING_Z, 2 * MIN_BEARING_Z, -0.5])
    f = np.stack([np.sqrt(1 - z ** 2), np.zeros(4), z], axis=1)
    assert in_front(f, f).tolist() == [True, False, True, False]
    assert not in_front(f[:1], f[3:]).any()
