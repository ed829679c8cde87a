"""Correspondence error between two holds on rendered views with known geometry (docs/RESULTS.md).

One camera (pinhole or equidistant fisheye) sees the textured room (:mod:`nrmpc_ros.render.scene`) from a
reference pose, then orbits a point on the far wall by the viewpoint change (deg, with a roll of a third of
it about the optical axis) to a second pose, through frames one degree apart as a rig's move is filmed.
The ray caster knows the 3D point behind every reference position, so its projection through the second
camera is the true position of the same landmark there. Two ways to find it are compared:

- ``tracks``: the front end's own (:class:`~nrmpc_ros.frontend.tracking.KltTracker`): corners refined at
  the reference hold's anchor, followed through the move, refined again at the second hold's anchor;
- ``aligned``: the reference patch aligned in the second hold (:mod:`nrmpc_ros.frontend.patch_align`),
  starting from the tracks' positions and the affine warp of the neighbouring links.

Rendering is noise free: the error of each landmark is its bias (the part averaging over a hold's frames
cannot remove); ``noise`` adds Gaussian grey-level noise to both images.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..cameras import bearings_to_pixels, pixels_to_bearings
from ..core.rig import Camera, Rig
from ..frontend.patch_align import PatchAlignConfig, align, neighbour_affine, reference_patches, tangent_frames
from ..frontend.tracking import KltTracker, TrackingConfig
from ..render.raycast import Renderer, cast_rays
from ..render.scene import make_scene

MODELS = ("pinhole", "equidistant")
FIXATION = np.array([3.4, 0.3, -0.2])  # a point on the far wall (world frame, m)
START = np.array([0.3, 0.0, 0.3])  # the reference camera centre


def camera(model: str, width: int = 320) -> Camera:
    """A camera ``width`` px wide (4:3): pinhole with 60 deg of horizontal field, or an equidistant fisheye
    of about 120 deg with a little distortion (as the benchmarks' rigs)."""
    h = width * 3 // 4
    s = width / 320
    if model == "pinhole":
        return Camera(name="cam", model="pinhole", intrinsics=(235.0 * s, 235.0 * s, (width - 1) / 2, (h - 1) / 2),
                      distortion=(), resolution=(width, h), position=np.zeros(3), rotation=np.eye(3))
    if model == "equidistant":
        return Camera(name="fish", model="equidistant", intrinsics=(150.0 * s, 150.0 * s, (width - 1) / 2,
                                                                     (h - 1) / 2),
                      distortion=(0.02, -0.01, 0.003, -0.001), resolution=(width, h), position=np.zeros(3),
                      rotation=np.eye(3))
    raise ValueError(f"camera model must be one of {MODELS}, got {model!r}")


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def pose(angle_deg: float) -> tuple:
    """(R_world_cam, centre) of the camera orbiting FIXATION by ``angle_deg`` about the vertical, looking at it,
    rolled by a third of the angle about its optical axis."""
    a = np.radians(angle_deg)
    c = FIXATION + _rot([0, 0, 1], a) @ (START - FIXATION)
    z = FIXATION - c
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1)
    return R @ _rot([0, 0, 1], a / 3), c


@dataclass
class PairResult:
    """Errors (N, 2) (px) of the landmarks both holds see, per method; ``aligned_ok`` which alignments
    succeeded (the others count as failures, not in the errors)."""

    model: str
    angle_deg: float
    tracks: np.ndarray
    aligned: np.ndarray
    aligned_ok: np.ndarray
    align_time_s: float


def render_pair(model: str, angle_deg: float, width: int = 320, seed: int = 0, noise: float = 0.0,
                step_deg: float = 1.0, supersample: int = 2):
    """Images along the move (first = reference hold, last = second hold), camera, scene and poses
    (``supersample`` rays per pixel side, as :class:`~nrmpc_ros.render.bagmaker.BagOptions`)."""
    cam = camera(model, width)
    scene = make_scene(seed=seed)
    ren = Renderer(Rig(cameras=(cam,)), scene, supersample=supersample)
    steps = max(1, int(np.ceil(abs(angle_deg) / step_deg)))
    poses = [pose(angle_deg * k / steps) for k in range(steps + 1)]
    rng = np.random.default_rng(seed)
    images = []
    for R, c in poses:
        img = ren.render_camera(0, R, c)
        if noise > 0:
            img = img + rng.normal(scale=noise, size=img.shape)
        images.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return images, cam, scene, poses


def true_positions(cam: Camera, scene, pose_ref, pose_cur, uv_ref) -> tuple:
    """Projections (N, 2) in the second view of the 3D points behind pixels uv_ref of the reference view, and
    whether the second view sees them (not occluded, in the image)."""
    R0, c0 = pose_ref
    R1, c1 = pose_cur
    d = pixels_to_bearings(cam, uv_ref) @ R0.T
    t, _ = cast_rays(scene, c0, d)
    X = c0 + t.astype(np.float64)[:, None] * d
    v = X - c1
    dist = np.linalg.norm(v, axis=1)
    t1, _ = cast_rays(scene, c1, v / dist[:, None])
    uv = bearings_to_pixels(cam, v @ R1)
    w, h = cam.resolution
    seen = (np.abs(t1 - dist) < 1e-3 * dist) & np.all(np.isfinite(uv), axis=1)
    seen &= (uv[:, 0] > 0) & (uv[:, 1] > 0) & (uv[:, 0] < w - 1) & (uv[:, 1] < h - 1)
    return uv, seen


def compare(model: str, angle_deg: float, width: int = 320, seed: int = 0, noise: float = 0.0,
            tracking: TrackingConfig | None = None, align_cfg: PatchAlignConfig | None = None,
            supersample: int = 2) -> PairResult:
    """Correspondence errors of both methods for one camera model and viewpoint change."""
    images, cam, scene, poses = render_pair(model, angle_deg, width, seed, noise, supersample=supersample)
    cfg = tracking or TrackingConfig()
    acfg = align_cfg or PatchAlignConfig()
    trk = KltTracker(cfg)
    trk.track(images[0])
    trk.start_hold()
    ids0, uv0 = trk.positions()
    trk.end_hold()
    for img in images[1:]:
        trk.track(img)
    trk.start_hold()
    ids1, uv1 = trk.positions()
    _, i0, i1 = np.intersect1d(ids0, ids1, return_indices=True)
    uv_ref, uv_trk = uv0[i0], uv1[i1]
    truth, seen = true_positions(cam, scene, poses[0], poses[-1], uv_ref)
    uv_ref, uv_trk, truth = uv_ref[seen], uv_trk[seen], truth[seen]
    t0 = time.perf_counter()
    ref = reference_patches(cam, images[0], uv_ref, acfg)
    tf0, tf1 = tangent_frames(cam, uv_ref), tangent_frames(cam, uv_trk)
    A0 = neighbour_affine(tf0.f, tf1.f, tf0, tf1, acfg.neighbours) @ ref.affine
    res = align(cam, images[-1], ref, uv_trk, A0, acfg)
    dt = time.perf_counter() - t0
    return PairResult(model, float(angle_deg), uv_trk - truth, res.uv - truth, res.ok, dt)


def summary(err: np.ndarray) -> dict:
    """Median and 90th percentile of the error's length, length of the mean error (px), count."""
    e = np.asarray(err, float).reshape(-1, 2)
    if len(e) == 0:
        return {"n": 0, "median_px": np.nan, "p90_px": np.nan, "mean_px": np.nan}
    r = np.linalg.norm(e, axis=1)
    return {"n": len(e), "median_px": float(np.median(r)), "p90_px": float(np.percentile(r, 90)),
            "mean_px": float(np.linalg.norm(e.mean(axis=0)))}


__all__ = ["MODELS", "PairResult", "camera", "compare", "pose", "render_pair", "summary", "true_positions"]
