"""Resection of a view of the bent rig on known landmarks (core.resection.resect_view)."""

import math

import numpy as np

from nrmpc_ros.core.resection import resect_view
from nrmpc_ros.core.so3 import rotation_angle
from nrmpc_ros.sim.sequence import SequenceScenario, make_sequence
from nrmpc_ros.sim.synthetic import RigSpec

RING3 = RigSpec(num_cameras=3, layout="ring", EI=1.3)


def _view(p, k):
    tr = p.tracks
    m = tr.view == k
    return p.points[tr.track[m]], tr.f[m], tr.cam[m], m


def test_noise_free_pose_is_exact_with_the_bending():
    p = make_sequence(SequenceScenario(rig=RING3, num_views=4, pixel_noise=0.0, outlier_fraction=0.0), seed=3)
    X, f, cam, _ = _view(p, 3)
    g0 = p.gravity[0]
    res = resect_view(p.rig, X, f, cam, p.R[2], p.t[2], g0, threshold_rad=2.0 / 470.0, seed=0)
    assert rotation_angle(p.R[3].T @ res.R) < 1e-8 and np.linalg.norm(res.t - p.t[3]) < 1e-7
    assert res.inliers.all()
    # the straight rig cannot explain the bent cameras' bearings as well
    straight = resect_view(p.rig, X, f, cam, p.R[2], p.t[2], None, threshold_rad=2.0 / 470.0, seed=0)
    assert rotation_angle(p.R[3].T @ straight.R) > 100 * rotation_angle(p.R[3].T @ res.R)


def test_outliers_are_rejected_and_too_few_points_give_none():
    p = make_sequence(SequenceScenario(rig=RING3, num_views=4, pixel_noise=0.3, outlier_fraction=0.1), seed=5)
    X, f, cam, m = _view(p, 2)
    res = resect_view(p.rig, X, f, cam, p.R[1], p.t[1], p.gravity[0], threshold_rad=2.0 / 470.0, seed=1)
    assert math.degrees(rotation_angle(p.R[2].T @ res.R)) < 0.05 and np.linalg.norm(res.t - p.t[2]) < 0.01
    truth = p.inlier_mask[m]
    assert np.mean(res.inliers[~truth]) < 0.05 and np.mean(res.inliers[truth]) > 0.9
    assert resect_view(p.rig, X[:3], f[:3], cam[:3], p.R[1], p.t[1], p.gravity[0]) is None
