"""Pose of a new view of the rig from landmarks already known: generalized absolute pose with the bars bent.

A sequence whose gravity g_0 and landmarks (in view 0's frame) are already
estimated places its next view by resection instead of a two-view estimate:
the view's cameras are bent under its gravity g_k = R_k^T g_0
(docs/CONVENTIONS.md, "Bending" and "Sequences"), which depends on the pose
sought, so the pose is solved at the bending of a guess (the view it is
linked to), the bending is updated at the pose found and the pose is
re-solved once from there. The solver is PoseLib's generalized absolute pose
(minimal gP3P in LO-RANSAC, then a robust refinement), on bearings as
normalised image points of unit-focal pinhole cameras.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import poselib

from .deformation import deformed_extrinsics
from .epipolar import MIN_BEARING_Z  # bearings further off axis are left out (normalised coordinates)
from .rig import Rig

BENDING_UPDATES = 5  # re-bendings at the pose found (each moves the pose by the bending change: a few suffice)
MIN_SAMPLES = 20  # RANSAC samples at least (the stopping rule ends it early at a high inlier ratio)
_UNIT_CAMERA = {"model": "SIMPLE_PINHOLE", "width": 0, "height": 0, "params": [1.0, 0.0, 0.0]}


@dataclass
class Resection:
    """View pose p_0 = R p + t (view -> view 0) and the inlier mask over the given observations."""

    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


def _camera_poses(rig: Rig, g_body):
    """PoseLib extrinsics (body -> camera) of the rig's cameras bent under body-frame gravity g_body (or
    straight for None)."""
    if g_body is None:
        w, W = rig.positions, rig.rotations
    else:
        w, W = deformed_extrinsics(rig, g_body)
    out = []
    for i in range(rig.num_cameras):
        p = poselib.CameraPose()
        p.R = W[i].T
        p.t = -W[i].T @ w[i]
        out.append(p)
    return out


def _rig_pose(R, t):
    """PoseLib pose (view 0 -> body) of the body pose p_0 = R p + t."""
    p = poselib.CameraPose()
    p.R = np.asarray(R).T
    p.t = -np.asarray(R).T @ np.asarray(t)
    return p


def resect_view(rig: Rig, points, f, cam, R_guess, t_guess, gravity0=None, threshold_rad: float = 1e-3,
                max_iterations: int = 1000, seed: int = 0) -> Resection | None:
    """Pose of a view from bearings f (n, 3) of cameras cam (n,) at known landmarks points (n, 3) (view 0's
    frame).

    ``R_guess``/``t_guess``: a rough pose (the view's link), whose gravity R_guess^T g_0 bends the cameras
    for the first solve; ``gravity0`` None solves with the rig straight. ``threshold_rad``: inlier angle.
    Returns None with fewer than four usable observations or when no pose explains four of them.
    """
    f = np.asarray(f, float)
    cam = np.asarray(cam, np.int64)
    points = np.asarray(points, float)
    use = (f[:, 2] > MIN_BEARING_Z) & np.all(np.isfinite(points), axis=1)
    if np.count_nonzero(use) < 4:
        return None
    x = f[:, :2] / np.where(use, f[:, 2], 1.0)[:, None]
    cams = range(rig.num_cameras)
    sel = [np.flatnonzero(use & (cam == i)) for i in cams]
    p2d = [x[s] for s in sel]
    p3d = [points[s] for s in sel]
    units = [_UNIT_CAMERA] * rig.num_cameras
    ransac = {"max_reproj_error": float(threshold_rad), "max_iterations": int(max_iterations),
              "min_iterations": MIN_SAMPLES, "seed": int(seed)}
    bundle = {"loss_type": "HUBER", "loss_scale": float(threshold_rad) / 2.0}
    g0 = None if gravity0 is None else np.asarray(gravity0, float)
    ext = _camera_poses(rig, None if g0 is None else np.asarray(R_guess).T @ g0)
    pose, info = poselib.estimate_generalized_absolute_pose(p2d, p3d, ext, units, ransac, bundle,
                                                            initial_pose=_rig_pose(R_guess, t_guess))
    if int(info.get("num_inliers", 0)) < 4:
        return None
    for _ in range(BENDING_UPDATES if g0 is not None else 0):  # bend the cameras at the pose found, refine
        R_before = pose.R
        ext = _camera_poses(rig, pose.R @ g0)
        pose, _ = poselib.refine_generalized_absolute_pose(p2d, p3d, pose, ext, units, bundle)
        if np.linalg.norm(pose.R - R_before) < 1e-9:
            break
    ext = _camera_poses(rig, None if g0 is None else pose.R @ g0)
    R = pose.R.T
    t = -R @ pose.t
    inliers = np.zeros(len(f), bool)
    for i, s in zip(cams, sel):
        if len(s):
            Xc = p3d[i] @ (ext[i].R @ pose.R).T + (ext[i].R @ pose.t + ext[i].t)
            d = Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
            inliers[s] = (Xc[:, 2] > 0) & (np.linalg.norm(d - f[s], axis=1) < threshold_rad)
    return Resection(R, t, inliers)


__all__ = ["Resection", "resect_view"]
