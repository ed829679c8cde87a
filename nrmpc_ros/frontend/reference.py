"""A bag's reference data: its IMU samples and ``/ground_truth/*``, and matching a stamp to them.

:func:`read_reference` loads them once for ``nrmpc replay``'s summary, ``nrmpc compare``, the report and the
benchmarks; :func:`nearest_stamp` is the one rule that pairs an estimate's stamp with a ground-truth sample.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.so3 import quat_xyzw_to_matrix
from .images import stamp_seconds
from .topics import IMU_TYPE, POSE_TYPE, VECTOR_TYPE, check_topic_type, same_type

GT_POSE_TOPIC = "/ground_truth/pose"
GT_GRAVITY_TOPIC = "/ground_truth/gravity"
STAMP_TOLERANCE_S = 0.02  # ground truth is matched to an estimate's stamp within this (cameras may jitter)


@dataclass
class Reference:
    """IMU samples and ground truth of a bag (arrays sorted by stamp, seconds)."""

    imu_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    imu_a: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    imu_w: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    pose_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pose_R: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))  # body -> world
    pose_p: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    grav_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    grav_g: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # gravity in the body frame
    imu_covariance: tuple | None = None  # the first IMU message's (linear_acceleration, angular_velocity) covariances
    imu_arrival: np.ndarray = field(default_factory=lambda: np.zeros(0))  # each sample's recording time (s)

    @property
    def has_imu(self) -> bool:
        return len(self.imu_t) > 0

    @property
    def has_pose(self) -> bool:
        return len(self.pose_t) > 0

    @property
    def has_gravity(self) -> bool:
        return len(self.grav_t) > 0

    def as_read(self, inputs, by_arrival: bool = False) -> Reference:
        """The IMU's samples as a pipeline read them with the input settings ``inputs`` (a
        :class:`~nrmpc_ros.frontend.feeder.FeederConfig`): in the cameras' clock (``imu_clock_offset_s`` added;
        with ``by_arrival``, stamped by their recording times: their own stamps froze) and in rad/s and m/s^2
        (``imu_gyro_scale``, ``imu_accel_scale``), in the axes the rig file's imu rotation reads
        (``imu_axes_turn_xyzw``)."""
        t = self.imu_arrival if by_arrival else self.imu_t + inputs.imu_clock_offset_s
        A, G = inputs.imu_reading()
        return replace(self, imu_t=t, imu_w=self.imu_w if G is None else self.imu_w @ G.T,
                       imu_a=self.imu_a if A is None else self.imu_a @ A.T)


def _vec(v) -> list:
    return [float(v.x), float(v.y), float(v.z)]


def _warn(msg: str) -> None:
    print(f"nrmpc: warning: {msg}", file=sys.stderr)


def read_reference(bag, imu_topic: str | None = "/imu/data", warn=_warn) -> Reference:
    """IMU (if ``imu_topic`` is in the bag) and /ground_truth/* (if present) of a :class:`BagReader`.

    The IMU topic must carry sensor_msgs/Imu (InputError naming the topic otherwise). Ground truth is
    optional: a ground-truth topic of another type than the one nrmpc make-bag writes is ignored with one
    ``warn`` each, and so are samples that are not finite (or a pose with a zero quaternion).
    """
    if imu_topic:
        check_topic_type(bag, imu_topic, IMU_TYPE, bag.source, "the IMU", imu_topic)
    topics = [t for t in (imu_topic, GT_POSE_TOPIC, GT_GRAVITY_TOPIC) if t and bag.has_topic(t)]
    for topic, expected in ((GT_POSE_TOPIC, POSE_TYPE), (GT_GRAVITY_TOPIC, VECTOR_TYPE)):
        if topic in topics and not same_type(bag.topics[topic][0], expected):
            warn(f"{bag.source}: ground truth {topic} carries {bag.topics[topic][0]}, not {expected}: ignored")
            topics.remove(topic)
    imu, pose, grav, imu_cov = [], [], [], None
    for topic, t_ns, msg in bag.messages(topics):
        st = stamp_seconds(msg)
        if topic == imu_topic:
            imu.append([st, *_vec(msg.linear_acceleration), *_vec(msg.angular_velocity), t_ns * 1e-9])
            if imu_cov is None:
                imu_cov = tuple(None if c is None else np.array(c, dtype=float) for c in (
                    getattr(msg, "linear_acceleration_covariance", None),
                    getattr(msg, "angular_velocity_covariance", None)))
        elif topic == GT_POSE_TOPIC:
            p, o = msg.pose.position, msg.pose.orientation
            pose.append([st, p.x, p.y, p.z, o.x, o.y, o.z, o.w])
        else:
            grav.append([st, *_vec(msg.vector)])
    ref = Reference(imu_covariance=imu_cov)
    if imu:
        a = np.array(imu, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        ok = np.all(np.isfinite(a), axis=1)
        ref.imu_t, ref.imu_a, ref.imu_w, ref.imu_arrival = a[ok, 0], a[ok, 1:4], a[ok, 4:7], a[ok, 7]
    if pose:
        a = np.array(pose, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        a = a[np.all(np.isfinite(a), axis=1) & (np.linalg.norm(a[:, 4:8], axis=1) > 1e-9)]
        ref.pose_t, ref.pose_p = a[:, 0], a[:, 1:4]
        ref.pose_R = np.array([quat_xyzw_to_matrix(q / np.linalg.norm(q)) for q in a[:, 4:8]]).reshape(-1, 3, 3)
    if grav:
        a = np.array(grav, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        a = a[np.all(np.isfinite(a), axis=1) & (np.linalg.norm(a[:, 1:4], axis=1) > 0)]
        ref.grav_t, ref.grav_g = a[:, 0], a[:, 1:4]
    return ref


def nearest_stamp(stamps: np.ndarray, t: float, tol: float = STAMP_TOLERANCE_S) -> int | None:
    """Index of the stamp in ``stamps`` (sorted) nearest to ``t`` (the earlier on a tie), None when it is
    farther than ``tol`` (s) or there is none."""
    n = len(stamps)
    if n == 0:
        return None
    i = int(np.clip(np.searchsorted(stamps, t), 1, n - 1)) if n > 1 else 0
    if n > 1 and abs(stamps[i - 1] - t) <= abs(stamps[i] - t):
        i -= 1
    return i if abs(stamps[i] - t) <= tol else None


__all__ = ["GT_GRAVITY_TOPIC", "GT_POSE_TOPIC", "STAMP_TOLERANCE_S", "Reference", "nearest_stamp", "read_reference"]
