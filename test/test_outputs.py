"""What the node publishes for a hold: levelled origin pose with ROS covariance, relative pose and its reference
frame, gravity, attitude, bent camera poses, and the message fields."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from nrmpc_ros.core import load_rig
from nrmpc_ros.core.deformation import deformed_extrinsics
from nrmpc_ros.core.so3 import exp_so3, quat_xyzw_to_matrix
from nrmpc_ros.frontend.outputs import (
    YAW_VARIANCE,
    FrameNames,
    hold_frame,
    hold_output,
    message_fields,
    ros_pose_covariance,
)
from nrmpc_ros.frontend.pipeline import HoldEstimate

ROOT = Path(__file__).resolve().parents[1]
NAMES = FrameNames("base_link", "base_link_origin", ("cam0_optical", "cam1_optical", "cam2_optical", "cam3_optical"))


@pytest.fixture
def rig():
    return load_rig(ROOT / "config" / "sample_cross4.yaml")


def estimate(rng, gravity=True, **kw) -> HoldEstimate:
    """A hold 3 of sequence 2: the origin tilted in the world, the hold rotated and moved from it."""
    R_w0 = exp_so3(np.array([0.3, -0.2, 1.0]))  # the origin's body in the world (yaw 1 rad)
    R_0k = exp_so3(rng.normal(scale=0.3, size=3))
    g_k = (R_w0 @ R_0k).T @ np.array([0.0, 0.0, -9.81])
    A = rng.normal(size=(6, 6))
    d = dict(stamp=103.5, ref_stamp=101.5, method="6pt-bending", R=exp_so3(rng.normal(scale=0.2, size=3)),
             t=rng.normal(size=3), gravity=g_k if gravity else None, gravity_sigma_deg=0.2,
             cov_gravity=1e-4 * np.eye(3) if gravity else None, num_inliers=100, num_observations=120, time_ms=5.0,
             origin_stamp=100.0, R_origin=R_0k, t_origin=rng.normal(size=3), cov_pose=1e-4 * (A @ A.T), sequence=2,
             hold_index=3, hold=None, links=Counter())
    d.update(kw)
    return HoldEstimate(**d), R_w0


def test_the_origin_frame_is_level_with_the_first_holds_heading(rig):
    est, R_w0 = estimate(np.random.default_rng(0))
    out = hold_output(est, rig, NAMES, reference_hold=1)
    assert out.levelled
    R_Ak = quat_xyzw_to_matrix(out.origin_q)
    assert np.allclose(R_Ak @ est.gravity, [0, 0, -9.81], atol=1e-9), "z up in the origin frame"
    # the levelled origin differs from the world only by a yaw, so it is the world frame turned about z
    R_wA = R_w0 @ (R_Ak @ est.R_origin.T).T
    assert np.allclose(R_wA[2], [0, 0, 1], atol=1e-9) and np.allclose(R_wA[:, 2], [0, 0, 1], atol=1e-9)
    assert np.allclose(out.origin_t, (R_Ak @ est.R_origin.T) @ est.t_origin)
    assert np.allclose(quat_xyzw_to_matrix(out.relative_q), est.R) and np.allclose(out.relative_t, est.t)
    assert out.reference_frame == "base_link_s2_h1"


def test_without_gravity_the_origin_is_the_first_holds_body_frame(rig):
    est, _ = estimate(np.random.default_rng(1), gravity=False)
    out = hold_output(est, rig, NAMES, reference_hold=None)
    assert not out.levelled and np.allclose(quat_xyzw_to_matrix(out.origin_q), est.R_origin)
    assert out.gravity is None and out.attitude_q is None
    assert out.reference_frame == hold_frame("base_link", 2, None, 101.5) == "base_link_s2_t101500000000"
    w, W = deformed_extrinsics(rig, np.zeros(3))
    assert np.allclose(out.camera_positions, rig.positions) and np.allclose(w, rig.positions)
    assert "g" not in message_fields(out, NAMES, lambda s: (int(s), 0))


def test_ros_pose_covariance_follows_the_perturbations():
    """Sample body-frame rotation and origin translation errors, push them through the poses, compare."""
    rng = np.random.default_rng(2)
    A = rng.normal(size=(6, 6))
    C = 1e-4 * (A @ A.T)
    R_A0, R_0k = exp_so3(np.array([0.1, 0.2, 0.0])), exp_so3(rng.normal(size=3))
    R_Ak = R_A0 @ R_0k
    x = rng.multivariate_normal(np.zeros(6), C, size=20000)
    dp = x[:, 3:] @ R_A0.T  # position errors in the origin frame A
    dtheta = x[:, :3] @ R_Ak.T  # Exp(dtheta) R_Ak = R_Ak Exp(dr)
    emp = np.cov(np.hstack([dp, dtheta]).T)
    assert np.allclose(ros_pose_covariance(C, R_A0, R_Ak), emp, atol=0.05 * C.max())
    # unknown covariances are a large variance, never NaN
    assert np.all(np.isfinite(ros_pose_covariance(np.full((6, 6), np.nan), R_A0, R_Ak)))


def test_camera_poses_are_the_bent_extrinsics_at_the_gravity(rig):
    est, _ = estimate(np.random.default_rng(3))
    out = hold_output(est, rig, NAMES, 1)
    w, W = deformed_extrinsics(rig, est.gravity)
    assert np.allclose(out.camera_positions, w, atol=1e-12)
    assert np.allclose(quat_xyzw_to_matrix(out.camera_q), W, atol=1e-12)
    assert not np.allclose(w, rig.positions, atol=1e-3), "the bars bend"


def test_attitude_levels_the_body_and_leaves_yaw_unknown(rig):
    est, _ = estimate(np.random.default_rng(4))
    out = hold_output(est, rig, NAMES, 1)
    R = quat_xyzw_to_matrix(out.attitude_q)
    assert np.allclose(R @ est.gravity, [0, 0, -9.81], atol=1e-9)
    sigma = np.sqrt(1e-4) / 9.81  # rad, the gravity direction's std
    assert np.allclose(np.diag(out.attitude_covariance)[:2], sigma**2, rtol=0.6)
    assert out.attitude_covariance[2, 2] == YAW_VARIANCE


def test_message_fields_carry_frames_stamps_and_numbers(rig):
    est, _ = estimate(np.random.default_rng(5))
    out = hold_output(est, rig, NAMES, 1)
    msgs = message_fields(out, NAMES, lambda s: (int(s), int(round((s - int(s)) * 1e9))))
    assert msgs["ref"] == {"stamp": {"sec": 101, "nanosec": 500000000}, "frame_id": "base_link_s2_h1"}
    assert msgs["rel"]["header"]["frame_id"] == "base_link_s2_h1" and msgs["rel"]["header"]["stamp"]["sec"] == 103
    assert msgs["pose"]["header"]["frame_id"] == "base_link_origin" and len(msgs["pose"]["pose"]["covariance"]) == 36
    for key in ("g", "gcov", "att", "cams"):
        assert msgs[key]["header"]["frame_id"] == "base_link", key
    assert msgs["g"]["vector"] == dict(zip("xyz", map(float, est.gravity)))
    cov = np.array(msgs["gcov"]["accel"]["covariance"]).reshape(6, 6)
    assert np.allclose(cov[:3, :3], est.cov_gravity) and np.all(cov[3:, 3:].diagonal() > 1e5)
    assert msgs["att"]["angular_velocity_covariance"][0] == -1.0
    assert [t["child_frame_id"] for t in msgs["tf"]["transforms"]] == list(NAMES.cameras)
    assert all(isinstance(v, float) for v in msgs["cams"]["poses"][0]["position"].values())
