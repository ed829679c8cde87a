"""Views of a flat random texture by a pinhole camera that only rotates (a homography): exact correspondences."""

import cv2
import numpy as np

from nrmpc_ros.core.rig import Camera

W, H, F = 640, 480, 470.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])
CAM = Camera(name="cam0", model="pinhole", intrinsics=(F, F, (W - 1) / 2, (H - 1) / 2), distortion=(),
             resolution=(W, H), position=np.zeros(3), rotation=np.eye(3))


def make_texture(seed: int = 7) -> np.ndarray:
    """A large multi-scale random texture (plenty of corners, nothing repetitive)."""
    rng = np.random.default_rng(seed)
    size = (1400, 1800)
    img = np.zeros(size, np.float32)
    for sigma, weight in ((1.0, 0.6), (3.0, 1.0), (9.0, 1.5)):
        img += weight * cv2.GaussianBlur(rng.normal(size=size).astype(np.float32), (0, 0), sigma) * sigma
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def view(texture, R):
    """Image of a camera rotated by R (camera -> reference) looking at the texture (pure rotation: a homography)."""
    # texture pixel (x, y) <-> reference-camera ray K^-1 (x - ox, y - oy, 1), texture centred on the optical axis
    oy, ox = (texture.shape[0] - H) / 2, (texture.shape[1] - W) / 2
    T = np.array([[1, 0, ox], [0, 1, oy], [0, 0, 1.0]])
    Hm = T @ K @ R @ np.linalg.inv(K)  # current pixel -> texture pixel
    return cv2.warpPerspective(texture, Hm, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)


def project(R_a, R_b, uv_a):
    """Where pixels of view a land in view b (both pure rotations of the reference camera)."""
    Hab = K @ R_b.T @ R_a @ np.linalg.inv(K)
    p = np.c_[uv_a, np.ones(len(uv_a))] @ Hab.T
    return p[:, :2] / p[:, 2:]
