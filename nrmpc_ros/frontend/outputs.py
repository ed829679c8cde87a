"""What the node publishes for one hold estimate, in numbers and frame names (docs/CONVENTIONS.md, "Frames").

- **Origin pose** (``~/pose``): the hold in the sequence's origin frame, the
  first hold's body frame turned level once gravity is known (z up, against
  gravity; the first hold's heading kept): R_A0 = R_level(g_0), with g_0 the
  joint gravity in the first hold's body frame. Without gravity
  (6pt-nonbending, a rigid rig) the origin frame is the first hold's body
  frame itself. The 6x6 covariance is in ROS's order and frame: position
  (x, y, z) then small rotations about the x, y, z axes of the origin frame
  (the estimate's rotation errors are body-frame right perturbations,
  turned into the origin frame by the hold's orientation). The uncertainty
  of the levelling itself is not included.
- **Relative pose** (``~/relative_pose``): the hold in the body frame of the
  hold it was paired with (p_ref = R p + t), whose frame is named
  :func:`hold_frame` (body frame, sequence, hold index).
- **Gravity**: the joint gravity in this hold's body frame (m/s^2) and its
  3x3 covariance; **attitude**: roll and pitch of the body from it (yaw
  unobservable: variance ``YAW_VARIANCE``).
- **Camera poses**: every camera's bent extrinsics at that gravity,
  ``deformed_extrinsics(rig, g)``: position (m) and orientation
  (camera -> body) in the body frame; canonical ones without gravity.
- **Camera poses at every frame set** (with an IMU): the bars' state driven
  by the IMU (:mod:`.extrinsics`) gives each camera's pose at its image
  stamp: TF body -> camera at every frame set, ``~/camera_poses`` at most
  ``camera_poses_rate_hz`` times per second (:func:`frame_pose_fields`).
"""

from __future__ import annotations

import importlib
import re
from dataclasses import dataclass

import numpy as np

from ..core.attitude import leveling_rotation, roll_pitch_from_gravity, tangent_covariance
from ..core.deformation import deformed_extrinsics
from ..core.rig import Rig
from ..core.so3 import matrix_to_quat_xyzw
from .extrinsics import CameraPoses
from .pipeline import HoldEstimate

# What the node publishes, by the keys of message_fields: message type and topic.
OUTPUTS = {"ref": ("std_msgs/msg/Header", "~/relative_pose_reference"),
           "rel": ("geometry_msgs/msg/PoseStamped", "~/relative_pose"),
           "pose": ("geometry_msgs/msg/PoseWithCovarianceStamped", "~/pose"),
           "g": ("geometry_msgs/msg/Vector3Stamped", "~/gravity"),
           "gcov": ("geometry_msgs/msg/AccelWithCovarianceStamped", "~/gravity_covariance"),
           "att": ("sensor_msgs/msg/Imu", "~/attitude"), "cams": ("geometry_msgs/msg/PoseArray", "~/camera_poses"),
           "tf": ("tf2_msgs/msg/TFMessage", "/tf")}
YAW_VARIANCE = 1e6  # rad^2: gravity says nothing about the heading
UNKNOWN_VARIANCE = 1e6  # diagonal of a covariance the estimate does not give (m^2 or rad^2)


@dataclass(frozen=True)
class FrameNames:
    """TF frame names: the rig's body frame, the sequence origin, the cameras' optical frames."""

    body: str
    origin: str
    cameras: tuple


def hold_frame(body: str, sequence: int, hold: int | None, stamp: float) -> str:
    """Name of the body frame at one hold: ``<body>_s<sequence>_h<hold>`` (``_t<stamp ns>`` if the index is
    not known)."""
    return f"{body}_s{sequence}_h{hold}" if hold is not None else f"{body}_s{sequence}_t{int(round(stamp * 1e9))}"


@dataclass
class HoldOutput:
    """Everything published for one hold (quaternions x, y, z, w; metres; m/s^2)."""

    estimate: HoldEstimate
    reference_frame: str  # the reference hold's body frame (frame_id of the relative pose)
    relative_q: np.ndarray
    relative_t: np.ndarray
    origin_q: np.ndarray  # the hold's pose in the (levelled) origin frame
    origin_t: np.ndarray
    origin_covariance: np.ndarray  # (6, 6), ROS order, origin frame
    levelled: bool  # the origin frame is level (gravity known)
    gravity: np.ndarray | None
    gravity_covariance: np.ndarray | None  # (3, 3) m^2/s^4
    attitude_q: np.ndarray | None  # the body's roll and pitch (yaw 0) as orientation in its level frame
    attitude_covariance: np.ndarray | None  # (3, 3) rad^2 about x, y, z
    camera_positions: np.ndarray  # (M, 3) in the body frame
    camera_q: np.ndarray  # (M, 4) camera -> body


def _finite_or_unknown(cov, n: int) -> np.ndarray:
    cov = None if cov is None else np.asarray(cov, dtype=float)
    if cov is None or cov.shape != (n, n) or not np.all(np.isfinite(cov)):
        return UNKNOWN_VARIANCE * np.eye(n)
    return cov


def origin_pose(est: HoldEstimate):
    """(R_A0, R_Ak, t_Ak, levelled): the levelling rotation and the hold's pose in the levelled origin frame."""
    R0k = np.asarray(est.R_origin, dtype=float)
    t0k = np.asarray(est.t_origin, dtype=float).reshape(3)
    if est.gravity is None:
        return np.eye(3), R0k, t0k, False
    R_A0 = leveling_rotation(R0k @ np.asarray(est.gravity, dtype=float))
    return R_A0, R_A0 @ R0k, R_A0 @ t0k, True


def ros_pose_covariance(cov_pose, R_A0: np.ndarray, R_Ak: np.ndarray) -> np.ndarray:
    """ROS (position, rotation about the parent's axes) covariance from (body rotation, origin translation)."""
    C = _finite_or_unknown(cov_pose, 6)
    J = np.zeros((6, 6))
    J[:3, 3:] = R_A0  # position in the levelled origin frame from t in the origin
    J[3:, :3] = R_Ak  # Exp(dr_A) R = R Exp(dr_b): dr_A = R dr_b
    out = J @ C @ J.T
    return 0.5 * (out + out.T)


def attitude(gravity, cov_gravity):
    """(quaternion, 3x3 covariance about x, y, z) of the body's roll and pitch from its gravity."""
    g = np.asarray(gravity, dtype=float)
    cov_t = tangent_covariance(g, _finite_or_unknown(cov_gravity, 3))
    _, _, q, cov_rp = roll_pitch_from_gravity(g, cov_t)
    cov = np.zeros((3, 3))
    cov[:2, :2] = cov_rp
    cov[2, 2] = YAW_VARIANCE
    return q, cov


def hold_output(est: HoldEstimate, rig: Rig, names: FrameNames, reference_hold: int | None) -> HoldOutput:
    """The messages' contents for ``est``; ``reference_hold`` is the index of its reference hold (None: unknown)."""
    R_A0, R_Ak, t_Ak, levelled = origin_pose(est)
    g = None if est.gravity is None else np.asarray(est.gravity, dtype=float).reshape(3)
    w, W = deformed_extrinsics(rig, g if g is not None else np.zeros(3))
    att_q, att_cov = attitude(g, est.cov_gravity) if g is not None else (None, None)
    return HoldOutput(
        estimate=est, reference_frame=hold_frame(names.body, est.sequence, reference_hold, est.ref_stamp),
        relative_q=matrix_to_quat_xyzw(np.asarray(est.R, dtype=float)),
        relative_t=np.asarray(est.t, dtype=float).reshape(3),
        origin_q=matrix_to_quat_xyzw(R_Ak), origin_t=t_Ak,
        origin_covariance=ros_pose_covariance(est.cov_pose, R_A0, R_Ak), levelled=levelled,
        gravity=g, gravity_covariance=None if g is None else _finite_or_unknown(est.cov_gravity, 3),
        attitude_q=att_q, attitude_covariance=att_cov,
        camera_positions=np.asarray(w), camera_q=matrix_to_quat_xyzw(np.asarray(W)))


def _floats(values) -> list:
    return [float(v) for v in np.asarray(values, dtype=float).ravel()]


def _pose(t, q) -> dict:
    x, y, z = _floats(t)
    qx, qy, qz, qw = _floats(q)
    return {"position": {"x": x, "y": y, "z": z}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def message_fields(out: HoldOutput, names: FrameNames, ros_stamp) -> dict:
    """The messages of one hold as nested field values, by output: "ref" (std_msgs/Header), "rel"
    (PoseStamped), "pose" (PoseWithCovarianceStamped), "g" (Vector3Stamped), "gcov" (AccelWithCovarianceStamped),
    "att" (sensor_msgs/Imu), "cams" (PoseArray), "tf" (tf2_msgs/TFMessage). ``ros_stamp(seconds)`` gives the
    (sec, nanosec) of a stamp as received. Published in this order: the reference before the relative pose."""
    e = out.estimate

    def header(stamp: float, frame: str) -> dict:
        sec, nsec = ros_stamp(stamp)
        return {"stamp": {"sec": int(sec), "nanosec": int(nsec)}, "frame_id": frame}

    body = header(e.stamp, names.body)
    msgs = {"ref": header(e.ref_stamp, out.reference_frame),
            "rel": {"header": header(e.stamp, out.reference_frame), "pose": _pose(out.relative_t, out.relative_q)},
            "pose": {"header": header(e.stamp, names.origin),
                     "pose": {"pose": _pose(out.origin_t, out.origin_q), "covariance": _floats(out.origin_covariance)}}}
    if out.gravity is not None:
        gx, gy, gz = _floats(out.gravity)
        cov = np.diag([0.0, 0.0, 0.0] + [UNKNOWN_VARIANCE] * 3)  # angular acceleration: not estimated
        cov[:3, :3] = out.gravity_covariance
        qx, qy, qz, qw = _floats(out.attitude_q)
        not_provided = [-1.0] + [0.0] * 8  # sensor_msgs/Imu: element 0 = -1
        msgs["g"] = {"header": body, "vector": {"x": gx, "y": gy, "z": gz}}
        msgs["gcov"] = {"header": body, "accel": {"accel": {"linear": {"x": gx, "y": gy, "z": gz}},
                                                  "covariance": _floats(cov)}}
        msgs["att"] = {"header": body, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
                       "orientation_covariance": _floats(out.attitude_covariance),
                       "angular_velocity_covariance": not_provided, "linear_acceleration_covariance": not_provided}
    cams = [_pose(t, q) for t, q in zip(out.camera_positions, out.camera_q)]
    msgs["cams"] = {"header": body, "poses": cams}
    msgs["tf"] = {"transforms": [{"header": body, "child_frame_id": name,
                                  "transform": {"translation": c["position"], "rotation": c["orientation"]}}
                                 for name, c in zip(names.cameras, cams)]}
    return msgs


@dataclass
class FramePosesOutput:
    """The cameras' poses of one frame set, from the IMU-driven bars (docs/CONVENTIONS.md, "The rig in motion"):
    TF body -> each camera present, at its image stamp; ``camera_poses``: also ``~/camera_poses`` (every camera,
    rig order, at the set's first stamp), when the set is complete and the rate allows it."""

    poses: CameraPoses
    camera_poses: bool


def frame_pose_fields(out: FramePosesOutput, names: FrameNames, ros_stamp) -> dict:
    """Messages of one frame set's camera poses, by output: "tf" (tf2_msgs/TFMessage) and, when
    ``out.camera_poses``, "cams" (PoseArray); ``ros_stamp`` as in :func:`message_fields`."""
    p = out.poses
    q = matrix_to_quat_xyzw(p.rotations).reshape(-1, 4)
    cams = [_pose(t, qi) for t, qi in zip(p.positions, q)]

    def header(stamp: float) -> dict:
        sec, nsec = ros_stamp(float(stamp))
        return {"stamp": {"sec": int(sec), "nanosec": int(nsec)}, "frame_id": names.body}

    msgs = {"tf": {"transforms": [{"header": header(t), "child_frame_id": names.cameras[int(i)],
                                   "transform": {"translation": c["position"], "rotation": c["orientation"]}}
                                  for t, i, c in zip(p.stamps, p.cameras, cams)]}}
    if out.camera_poses:
        msgs["cams"] = {"header": header(p.stamps[0]), "poses": cams}
    return msgs


def fill_message(msg, fields: dict):
    """Set a ROS message's fields from nested values (as :func:`message_fields` gives them); a list of mappings
    becomes a sequence of sub-messages of the field's type."""
    for key, value in fields.items():
        if isinstance(value, dict):
            fill_message(getattr(msg, key), value)
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            pkg, name = re.search(r"(\w+)/(\w+)", msg.get_fields_and_field_types()[key]).groups()  # sequence<p/T, N>
            cls = getattr(importlib.import_module(f"{pkg}.msg"), name)
            setattr(msg, key, [fill_message(cls(), v) for v in value])
        else:
            setattr(msg, key, value)
    return msg


__all__ = ["OUTPUTS", "FrameNames", "FramePosesOutput", "HoldOutput", "UNKNOWN_VARIANCE", "YAW_VARIANCE", "attitude",
           "fill_message", "frame_pose_fields",
           "hold_frame", "hold_output", "message_fields", "origin_pose", "ros_pose_covariance"]
