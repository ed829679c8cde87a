"""Rendered synthetic bags of a bending rig, recorded the way real rigs are (topics of docs/CONVENTIONS.md (Bags)).

The rig holds still at a sequence of attitudes joined by moves
(:mod:`.sequence`); the cameras are triggered in one of the capture modes
``holds``, ``snapshot`` or ``stream``. For every trigger each camera is
rendered with its bent extrinsics at the load its bar carries at that
instant (:mod:`.bars`): the quasi-static load g_B - a_B (gravity minus the
body's acceleration, body frame), or, when the bars ring, its damped
response. Like software-synchronised USB cameras, each camera's header stamp
(and bag time) may be off the trigger by a random jitter, and each camera may
drop frames; the image content and the ground truth stay at the trigger
time, or, with a shutter time (``shutter_ms``), the image integrates the
scene from the trigger over it (motion blur: :class:`ShutterRenderer`).
Each camera may run at its own rate and phase (:mod:`.sequence`);
auto-exposure may drift: each camera's grey levels become gain(t) I + offset(t)
with a slow sinusoidal gain (1 +- ``exposure_drift``) and offset
(+- ``EXPOSURE_OFFSET_GREY`` x ``exposure_drift`` grey levels), each camera with its own periods near
``exposure_period_s`` and its own phases. The IMU (200 Hz by default,
throughout) reads the specific force (``a = -g`` when still, through the
rig's ``imu`` mount) plus white noise and a constant bias, and the body
angular velocity; its stamps may be off the cameras' clock by a constant
``imu_time_offset_ms``, or come from its own clock (``imu_clock_start_s``:
what that clock reads at the first frame); a camera may stamp with its own
clock too (``camera_clock_start_s``), and a driver may leave its messages'
stamps at 0 (``unstamped``). A camera driver may deliver its images late: each
image's bag time (when the recorder received it) may trail its stamp by
``camera_latency_ms`` and, with ``camera_burst_s``, come in bursts (a driver
or link that buffers, every image of a burst received together at the
burst's end; with ``camera_burst_stagger_ms`` topic by topic, camera i's
images i x that later), while the IMU's samples are received when taken (an
IMU stamped by another clock too: the recorder's clock is the cameras'). A
link may lose IMU samples in runs (``imu_loss``, ``imu_loss_burst_ms``:
:func:`lost_samples`). Ground truth ``/ground_truth/pose`` (body in world,
world z up), ``/ground_truth/gravity`` (gravity in the body frame) and
``/ground_truth/angular_velocity`` (body rate, rad/s, body frame: zero exactly
while the body is still, non-zero in a creeping hold or a move) is written at
every trigger instant, and ``/ground_truth/extrinsics/<camera>`` (the camera's bent pose
in the body frame at the trigger, stamped like the camera's image) with every image
(docs/CONVENTIONS.md, "The rig in motion"). Deterministic for a seed, with separate random streams
for the trajectory, the IMU, the image noise, the jitter, the drops, the
exposure, the IMU's stamps and its lost samples. Someone may walk through the
room (``walker_speed``: :class:`MovingScene`): a person-sized textured box
goes back and forth along a lane 1.2-1.5 m from the rig's start, through holds
and moves alike, so what a camera sees of it moves while the rig holds still.
"""

from __future__ import annotations

import heapq
import itertools
import math
import numbers
import shutil
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from ..bag.writer import COMPRESSED_FORMATS, DEFAULT_JPEG_QUALITY, ENCODINGS, STORAGES, BagWriter, image_topic_for
from ..core.bar_state import bent_extrinsics_at_loads
from ..core.deformation import bend_rotation_vectors
from ..core.dynamics import check_damping
from ..core.rig import ImuMount, Rig
from ..core.so3 import cross, exp_and_left_jacobian, normalize, rotation_angle
from ..errors import InputError, OptionError
from ..frontend.topics import bag_topic
from .bars import CameraLoads, bent_extrinsics
from .raycast import Renderer
from .scene import BOXES, WALKER, WALKER_LANE_X, Scene, contains, make_scene, walker_offset, with_box_moved
from .sequence import MotionOptions, Trajectory, make_trajectory

POSE_TOPIC = "/ground_truth/pose"
GRAVITY_TOPIC = "/ground_truth/gravity"
EXTRINSICS_TOPIC = "/ground_truth/extrinsics/{}"  # .format(camera name): the bent camera's pose in the body
ANGULAR_VELOCITY_TOPIC = "/ground_truth/angular_velocity"
GYRO_UNITS = {"rad/s": 1.0, "deg/s": math.pi / 180.0}  # unit -> its size in rad/s
ACCEL_UNITS = {"m/s^2": 1.0, "g": 9.80665}  # unit -> its size in m/s^2 (standard gravity, as drivers convert)
EXPOSURE_OFFSET_GREY = 40.0  # grey levels of offset drift per unit of exposure_drift
WORLD_FRAME = "world"
IMU_FRAME = "imu"
# A still camera is re-rendered only when its bar's load moved by more than this (m/s^2): for the bars of
# this project (c_r <= 0.1 rad per m/s^2, f <= 1000 px) that shifts the image by less than 1e-4 px.
CACHE_LOAD_TOLERANCE = 1e-6
WALKER_MAX_SPEED = 3.0  # m/s: a person running through the room
# A shutter's motion blur is rendered as the mean of instants this far apart along each pixel's path (px), at most
# BLUR_MAX_INSTANTS of them (a longer smear is sampled more sparsely; at 2 x 2 rays per pixel the mean of instants
# 1 px apart is the smear's integral within the noise)
BLUR_STEP_PX = 1.0
BLUR_MAX_INSTANTS = 24
BLUR_DEPTH_M = 1.0  # the nearest depth at which a camera's translation during the shutter counts toward its blur


def _real(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


_OWNER = "bag options"  # how OptionError names this module's options


@dataclass
class BagOptions:
    """Everything besides the rig that defines a rendered bag."""

    motion: MotionOptions = field(default_factory=MotionOptions)
    seed: int = 0
    encoding: str = "mono8"  # raw sensor_msgs/Image encodings, or png/jpeg (CompressedImage on <topic>/compressed)
    jpeg_quality: int = DEFAULT_JPEG_QUALITY
    storage: str = "sqlite3"
    image_noise: float = 1.0  # grey levels, std of Gaussian pixel noise
    imu_noise: float = 0.02  # m/s^2, accelerometer white noise std per sample
    gyro_noise: float = 0.002  # rad/s
    imu_lowpass_hz: float = 0.0  # the IMU's digital low-pass filter (a MEMS DLPF): a 2nd-order Butterworth at this
    # cut-off on its output (signal and noise; the output noise std stays imu_noise/gyro_noise); 0: none, white
    imu_covariance_scale: float = 1.0  # the Imu messages' covariances say this times the true noise std (a driver's
    # claim: 1 true, 0 all zeros = unknown, 0.1 a noise density taken for a per-sample std, 10 a generous constant)
    imu_bias: float = 0.05  # m/s^2, norm of the constant accelerometer bias (random direction)
    accel_scale_error: float = 0.0  # each accelerometer axis reads (1 + s) times the truth, s uniform in +-this (an
    # uncalibrated MEMS chip's sensitivity error: 0.01-0.03)
    gyro_bias: float = 0.002  # rad/s, norm of the constant gyro bias
    vibration: float = 0.0  # m/s^2 RMS of a motor's vibration the accelerometer reads all along (an engine or
    # idling propellers: 0.1-3), a sine at vibration_hz on each axis; the gyro reads the rocking it comes with
    vibration_hz: float = 60.0  # its frequency (an IMU sampling slower than twice it reads it aliased)
    imu_gravity_removed: bool = False  # the topic carries a fused driver's linear acceleration: the specific force
    # with gravity taken out (an AHRS's output, not the accelerometer's), ~0 at rest
    imu: bool = True  # write the IMU topic
    gyro_unit: str = "rad/s"  # the unit the Imu messages' angular_velocity (and its covariance) is written in:
    # "deg/s" is a driver that breaks REP 103
    accel_unit: str = "m/s^2"  # ... and linear_acceleration: "g" is a driver that breaks REP 103
    damping: float | None = None  # damping ratio of the bars' ringing; None: quasi-static bending
    jitter_ms: float = 0.0  # each camera's stamp is off the trigger by U(-jitter, +jitter) ms
    drop_rate: float = 0.0  # probability that a camera loses a frame
    supersample: int = 2  # rays per pixel side: a pixel integrates its area (1: point sampling, aliased)
    imu_time_offset_ms: float = 0.0  # IMU stamps = true sample time + this (a constant clock offset)
    imu_clock_start_s: float | None = None  # the IMU stamps with its own clock, reading this at the first frame
    # (a device counter since power-on, another epoch); None: the cameras' clock
    camera_clock_start_s: tuple | None = None  # per camera: its own clock's reading at the first frame, or None
    unstamped: tuple = ()  # inputs whose driver leaves header.stamp at 0: camera names, or "imu"
    # (the common clock); None: every camera on the common clock
    imu_stamp_jitter_ms: float = 0.0  # a driver that stamps each IMU sample when the host receives it: the
    # stamp trails the sample by U(0, this) ms, kept in arrival order (a serial or USB link; where this exceeds
    # the sample period, samples arrive in batches of nearly equal stamps)
    shutter_ms: float = 0.0  # each image integrates the scene over this long from its trigger (its stamp): motion
    # blur while the rig moves or its bars ring (0: an instant)
    imu_loss: float = 0.0  # share of the IMU's samples the recording lost (a USB or serial link, a busy recorder)
    imu_loss_burst_ms: float = 0.0  # mean length of a run of lost samples (ms; 0: samples lost one by one)
    exposure_drift: float = 0.0  # amplitude of each camera's slow gain change (0.2: gain 0.8-1.2)
    exposure_period_s: float = 20.0  # typical period of the exposure drift
    camera_latency_ms: float = 0.0  # each image is received (bag time) this long after its stamp
    camera_burst_s: float = 0.0  # images received in bursts: at the end of every such interval (0: one by one)
    camera_burst_stagger_ms: float = 0.0  # within a burst camera i's images are received i x this after its end:
    # a driver or link that delivers a burst topic by topic (0: the images of a burst in stamp order)
    walker_speed: float = 0.0  # m/s: a person-sized textured box walks back and forth through the room at this
    # speed, through holds and moves alike (0: nobody): what a camera sees of it moves while the rig holds still

    def validate(self) -> None:
        """One OptionError naming the field of the first bad option."""
        if not (isinstance(self.seed, numbers.Integral) and self.seed >= 0):
            raise OptionError(_OWNER, "seed", f"must be an integer >= 0, got {self.seed!r}")
        if self.storage not in STORAGES:
            raise OptionError(_OWNER, "storage", f"unknown storage {self.storage!r} (supported: {', '.join(STORAGES)})")
        if self.encoding not in ENCODINGS:
            raise OptionError(_OWNER, "encoding", f"unsupported {self.encoding!r} (supported: {', '.join(ENCODINGS)})")
        if not (isinstance(self.jpeg_quality, numbers.Integral) and 0 <= self.jpeg_quality <= 100):
            raise OptionError(_OWNER, "jpeg_quality", f"must be an integer in [0, 100], got {self.jpeg_quality!r}")
        if not (isinstance(self.supersample, numbers.Integral) and 1 <= self.supersample <= 8):
            raise OptionError(_OWNER, "supersample", f"must be an integer in [1, 8], got {self.supersample!r}")
        for name in ("image_noise", "imu_noise", "gyro_noise", "imu_bias", "gyro_bias", "jitter_ms",
                     "imu_covariance_scale", "imu_lowpass_hz", "accel_scale_error", "vibration"):
            value = getattr(self, name)
            if not (_real(value) and value >= 0):
                raise OptionError(_OWNER, name, f"must be a finite number >= 0, got {value!r}")
        if not self.accel_scale_error < 1.0:
            raise OptionError(_OWNER, "accel_scale_error", f"must be below 1 (an axis reading (1 + s) times the "
                              f"truth with s down to -S), got {self.accel_scale_error!r}")
        if not (_real(self.vibration_hz) and 0 < self.vibration_hz <= 1e4):
            raise OptionError(_OWNER, "vibration_hz", f"must be a finite number in (0, 10000] Hz, "
                              f"got {self.vibration_hz!r}")
        if not (_real(self.imu_time_offset_ms) and abs(self.imu_time_offset_ms) <= 1e4):
            raise OptionError(_OWNER, "imu_time_offset_ms", f"must be a finite number of ms within +-10000, "
                              f"got {self.imu_time_offset_ms!r}")
        if self.imu_clock_start_s is not None and not (_real(self.imu_clock_start_s)
                                                       and 0 <= self.imu_clock_start_s < 2.0**31):
            raise OptionError(_OWNER, "imu_clock_start_s", f"must be a finite number of s in [0, 2^31) (a ROS "
                              f"stamp's seconds), got {self.imu_clock_start_s!r}")
        if self.camera_clock_start_s is not None and not all(
                v is None or (_real(v) and 0 <= v < 2.0**31) for v in self.camera_clock_start_s):
            raise OptionError(_OWNER, "camera_clock_start_s", f"each must be empty or a finite number of s in [0, "
                              f"2^31), got {self.camera_clock_start_s!r}")
        if not (_real(self.exposure_drift) and 0 <= self.exposure_drift <= 0.5):
            raise OptionError(_OWNER, "exposure_drift", f"must be in [0, 0.5] (a gain change), "
                              f"got {self.exposure_drift!r}")
        if not (_real(self.exposure_period_s) and self.exposure_period_s > 0):
            raise OptionError(_OWNER, "exposure_period_s", f"must be a finite number > 0, "
                              f"got {self.exposure_period_s!r}")
        for name, top in (("camera_latency_ms", 10000), ("camera_burst_s", 10), ("camera_burst_stagger_ms", 1000),
                          ("imu_stamp_jitter_ms", 1000)):
            value = getattr(self, name)
            if not (_real(value) and 0 <= value <= top):
                raise OptionError(_OWNER, name, f"must be a finite number in [0, {top}], got {value!r}")
        if not (_real(self.shutter_ms) and 0 <= self.shutter_ms <= 1e3 / max(self.motion.camera_rates
                                                                             or (self.motion.rate,))):
            raise OptionError(_OWNER, "shutter_ms", f"must be a finite number of ms from 0 to the frame period, "
                              f"got {self.shutter_ms!r}")
        if not (_real(self.imu_loss) and 0 <= self.imu_loss <= 0.5):
            raise OptionError(_OWNER, "imu_loss", f"must be a share in [0, 0.5], got {self.imu_loss!r}")
        if not (_real(self.imu_loss_burst_ms) and 0 <= self.imu_loss_burst_ms <= 10000):
            raise OptionError(_OWNER, "imu_loss_burst_ms", f"must be a finite number in [0, 10000], "
                              f"got {self.imu_loss_burst_ms!r}")
        if not (_real(self.walker_speed) and 0 <= self.walker_speed <= WALKER_MAX_SPEED):
            raise OptionError(_OWNER, "walker_speed", f"must be a finite number of m/s in [0, {WALKER_MAX_SPEED:g}] "
                              f"(0: nobody walks), got {self.walker_speed!r}")
        if not (_real(self.drop_rate) and 0 <= self.drop_rate < 1):
            raise OptionError(_OWNER, "drop_rate", f"must be in [0, 1), got {self.drop_rate!r}")
        if self.damping is not None:
            check_damping(self.damping, _OWNER)
        for name, units in (("gyro_unit", GYRO_UNITS), ("accel_unit", ACCEL_UNITS)):
            if getattr(self, name) not in units:
                raise OptionError(_OWNER, name, f"unknown unit {getattr(self, name)!r} (supported: {', '.join(units)})")
        self.motion.validate()
        if self.imu_lowpass_hz and not self.imu_lowpass_hz < 0.5 * self.motion.imu_rate:
            raise OptionError(_OWNER, "imu_lowpass_hz", f"must be 0 (none) or below half the IMU rate "
                              f"({0.5 * self.motion.imu_rate:g} Hz), got {self.imu_lowpass_hz!r}")
        rate = max(self.motion.camera_rates or (self.motion.rate,))
        period_ms = 1e3 / rate
        if 2 * self.jitter_ms >= period_ms:
            raise OptionError(_OWNER, "jitter_ms", f"must be below half the frame period ({period_ms / 2:g} ms at "
                              f"rate {rate:g} Hz) so each camera's stamps stay in order, "
                              f"got {self.jitter_ms!r}")


def imu_readings(rig: Rig, traj: Trajectory, t_ns, rng: np.random.Generator, opts: BagOptions,
                 loads: CameraLoads | None = None):
    """Accelerometer (N, 3) and gyro (N, 3) in the IMU frame at times t_ns, with noise and constant bias.

    Specific force f = R^T (acc_world - g_world) = -u in the body frame (u the body's load); an IMU at the
    body centre reads R_body_imu^T f and the body rate. One inside camera i reads R_cam_imu^T W_i^T f_i with
    the camera bent by its bar's load (docs/CONVENTIONS.md, Gravity measurements), where f_i adds the lever arm
    of the bent camera
    position w_i: alpha x w_i + omega x (omega x w_i). When that bar rings (``loads`` with a damping ratio)
    the tip's own motion adds too: its acceleration c_d P_i x_i'' = P_i (l_i - x_i - 2 zeta / w x_i') (the
    bar's spring and damper force per unit tip mass, l_i its quasi-static load :meth:`CameraLoads.quasi_static`;
    P_i removes the axial part, which the bar carries rigidly), the Coriolis term 2 omega x w_i', and, on the
    gyro, the bending rate J_l(phi_i) phi_i'.
    Quasi-static bars have no motion of their own.
    """
    imu = rig.imu or ImuMount()
    R, _, omega, acc = traj.state(t_ns)
    load = traj.load_body(R, acc)  # u = g - a_world in body = -(specific force)
    f_body, w_body = -load, omega
    if imu.mount == "body":
        mount_R = np.broadcast_to(np.eye(3), (len(R), 3, 3))
    else:
        i = rig.camera_index(imu.mount)
        u_dir, c_d, _ = (c[i] for c in rig.bar_coefficients)
        if loads is not None and loads.ringing:
            x, v, li = loads.state(t_ns)
            xi, vi, li = x[:, i], v[:, i], li[:, i]
        else:
            li = load if loads is None else loads.quasi_static(t_ns)[:, i]
            xi, vi = li, np.zeros_like(li)
        w, _ = bent_extrinsics(rig, np.broadcast_to(xi[:, None], (len(xi), rig.num_cameras, 3)))
        alpha = traj.angular_acceleration(t_ns)
        f_body = f_body + cross(alpha, w[:, i]) + cross(omega, cross(omega, w[:, i]))
        E, J_l = exp_and_left_jacobian(bend_rotation_vectors(rig, xi, cams=[i])[:, 0])
        mount_R = E @ rig.rotations[i]
        if loads is not None and loads.ringing:
            def perp(y):
                return y - np.outer(y @ u_dir, u_dir)

            f_body = f_body + perp(li - xi - (2.0 * loads.zeta[i] / (2.0 * math.pi * loads.frequencies[i])) * vi)
            f_body = f_body + 2.0 * cross(omega, c_d * perp(vi))
            w_body = omega + np.einsum("nij,nj->ni", J_l, bend_rotation_vectors(rig, vi, cams=[i])[:, 0])
    to_imu = np.einsum("ji,njk->nik", imu.rotation, np.swapaxes(mount_R, 1, 2))  # body -> IMU
    if opts.imu_gravity_removed:  # a fused driver's linear acceleration: gravity added back to the specific force
        f_body = f_body + traj.gravity_body(R)
    accel = np.einsum("nij,nj->ni", to_imu, f_body)
    gyro = np.einsum("nij,nj->ni", to_imu, w_body)
    accel_bias = opts.imu_bias * normalize(rng.normal(size=3))
    gyro_bias = opts.gyro_bias * normalize(rng.normal(size=3))
    accel_noise = rng.normal(scale=opts.imu_noise, size=accel.shape)
    gyro_noise = rng.normal(scale=opts.gyro_noise, size=gyro.shape)
    if opts.accel_scale_error:  # drawn last: recordings without it keep their random streams
        accel = accel * (1.0 + opts.accel_scale_error * rng.uniform(-1.0, 1.0, size=3))
    if opts.vibration:  # drawn after the scale error, for the same reason
        accel_vib, gyro_vib = _vibration(np.asarray(t_ns), opts.vibration, opts.vibration_hz, rng)
        accel, gyro = accel + accel_vib, gyro + gyro_vib
    if opts.imu_lowpass_hz:
        accel, gyro = (_lowpass(x, opts.imu_lowpass_hz, opts.motion.imu_rate) for x in (accel, gyro))
        accel_noise, gyro_noise = (_lowpass(x, opts.imu_lowpass_hz, opts.motion.imu_rate, unit_noise=True)
                                   for x in (accel_noise, gyro_noise))
    return accel + accel_bias + accel_noise, gyro + gyro_bias + gyro_noise


VIBRATION_PIVOT_M = 0.2  # a vibration's rocking: the mount turns about a pivot this far away


def _vibration(t_ns: np.ndarray, rms: float, hz: float, rng: np.random.Generator) -> tuple:
    """Accelerometer and gyro readings (N, 3) of a motor's vibration at ``hz``, ``rms`` m/s^2 over the three
    axes: on each axis a sine of its own amplitude and phase, and the rocking that comes with it (angular
    acceleration rms / pivot, so a rate of that over 2 pi hz). Sampled at the IMU's stamps, so an IMU slower than
    twice ``hz`` reads it aliased, as one without an anti-aliasing filter does. The cameras move with it by
    micrometres and microradians (rms / (2 pi hz)^2): the images do not show it, and far above the bars'
    frequencies it does not excite them."""
    t = (t_ns - t_ns[0]) * 1e-9
    share = normalize(np.abs(rng.normal(size=3)) + 0.2)
    phases = rng.uniform(0.0, 2.0 * math.pi, size=(2, 3))
    omega = 2.0 * math.pi * hz
    amplitude = math.sqrt(2.0) * rms * share
    accel = amplitude * np.sin(omega * t[:, None] + phases[0])
    gyro = (amplitude / (VIBRATION_PIVOT_M * omega)) * np.sin(omega * t[:, None] + phases[1])
    return accel, gyro


def _lowpass(x: np.ndarray, cutoff_hz: float, rate_hz: float, unit_noise: bool = False) -> np.ndarray:
    """x (N, 3) through a MEMS IMU's digital low-pass filter: a causal 2nd-order Butterworth at ``cutoff_hz``
    sampled at ``rate_hz``, started at rest on the first sample (it delays the signal as the sensor does). With
    ``unit_noise`` scaled so that white noise keeps its std (the filter's noise gain divided out)."""
    from scipy.signal import butter, sosfilt, sosfilt_zi  # imported where used

    sos = butter(2, cutoff_hz, fs=rate_hz, output="sos")
    y = sosfilt(sos, x, axis=0, zi=sosfilt_zi(sos)[:, :, None] * x[0][None, None, :])[0]
    if unit_noise:
        impulse = sosfilt(sos, np.eye(1, 4096).ravel())
        y = y / math.sqrt(float(np.sum(impulse ** 2)))
    return y


class MovingScene:
    """The scene at an instant: the room's boxes stand still; the walker (its last box, with ``walker_speed``
    > 0) walks its lane (:func:`.scene.walker_offset`, time from the recording's start)."""

    def __init__(self, scene: Scene, walker_speed: float, start_ns: int):
        self.scene, self.speed, self.start_ns = scene, float(walker_speed), int(start_ns)
        self.walker = scene.num_boxes - 1 if self.speed > 0 else None

    @property
    def moves(self) -> bool:
        return self.walker is not None

    def at(self, t_ns: int) -> Scene:
        if self.walker is None:
            return self.scene
        return with_box_moved(self.scene, self.walker, walker_offset((int(t_ns) - self.start_ns) * 1e-9,
                                                                     self.speed)[0])

    def swept(self) -> Scene:
        """The scene with the walker's box stretched over its whole lane: where no camera may go."""
        if self.walker is None:
            return self.scene
        lo, hi = self.scene.lo.copy(), self.scene.hi.copy()
        lo[self.walker, 0] += WALKER_LANE_X[0]
        hi[self.walker, 0] += WALKER_LANE_X[1]
        return replace(self.scene, lo=lo, hi=hi)


def _check_inside(rig: Rig, traj: Trajectory, scene, loads: CameraLoads) -> None:
    """Every (bent) camera must stay inside the room and outside the boxes (and the walker's lane)."""
    t = np.arange(traj.start_ns, traj.end_ns, traj.period_ns // 2 or 1, dtype=np.int64)
    R, p, _, _ = traj.state(t)
    w, _ = bent_extrinsics(rig, loads.at(t))
    centres = np.einsum("nij,nmj->nmi", R, w) + p[:, None, :]
    if not np.all(contains(scene, centres.reshape(-1, 3))):
        raise InputError(rig.source, "a camera leaves the rendered room (bars too long or too bent); "
                                     "use shorter bars or a smaller --max-translation", "position")


def hold_intervals(traj: Trajectory, loads: CameraLoads) -> list:
    """One dict per hold: ``start``, ``end`` (s, the body stopped in between), ``settled`` (s, when the
    bars' ringing amplitude has fallen below 1e-3 of its value at the start of the hold; None without
    ringing; it may lie beyond ``end`` when the hold is too short) and ``creeping`` (the body turns slowly
    through the hold: it is not still)."""
    settled = loads.settle_times_ns()
    return [{"start": int(a) * 1e-9, "end": int(b) * 1e-9, "settled": None if settled is None else int(s) * 1e-9,
             "creeping": bool(c)}
            for a, b, s, c in zip(traj.hold_start, traj.hold_end,
                                  settled if settled is not None else traj.hold_start, traj.creeping)]


class ShutterRenderer:
    """Images integrated over the shutter time from each trigger: the mean of renders at instants spread over
    it, as many as the camera's image moves by (its turn and the shift of its centre during the shutter, in
    pixels, :data:`BLUR_STEP_PX` apart); one render at the shutter's middle when it moves by less."""

    def __init__(self, renderer, traj: Trajectory, loads: CameraLoads, shutter_ns: int, scenes: MovingScene):
        self.renderer, self.traj, self.loads, self.shutter_ns = renderer, traj, loads, int(shutter_ns)
        self.scenes = scenes
        self.instants = Counter()  # renders per image: how many images took how many instants

    def _poses(self, t_ns: np.ndarray) -> list:
        R, p, _, _ = self.traj.state(t_ns)
        cam_loads = self.loads.at(t_ns)
        return [self.renderer.camera_poses(R[k], p[k], cam_loads[k]) for k in range(len(t_ns))]

    def instant_count(self, i: int, t_ns: int) -> int:
        """How many instants camera i's image at trigger t_ns needs."""
        (Ra, ca), (Rb, cb) = self._poses(np.array([t_ns, t_ns + self.shutter_ns], dtype=np.int64))
        turn = rotation_angle(Ra[i].T @ Rb[i])
        focal = float(self.renderer.rig.cameras[i].intrinsics[0])
        blur_px = focal * (turn + np.linalg.norm(cb[i] - ca[i]) / BLUR_DEPTH_M)
        return int(min(BLUR_MAX_INSTANTS, max(1, math.ceil(blur_px / BLUR_STEP_PX))))

    def render(self, i: int, t_ns: int, count: int) -> np.ndarray:
        """Camera i's image exposed from t_ns for the shutter time, the mean of ``count`` instants."""
        ts = t_ns + np.rint((np.arange(count) + 0.5) / count * self.shutter_ns).astype(np.int64)
        img = None
        for t, (Rs, cs) in zip(ts, self._poses(ts)):
            one = self.renderer.render_camera(i, Rs[i], cs[i], scene=self.scenes.at(t))
            img = one if img is None else img + one
        self.instants[count] += 1
        return img / count


class _StillCache:
    """Images of still cameras, reused while the body stays in one hold and the camera's load is unchanged."""

    def __init__(self, num_cameras: int):
        self.view = [None] * num_cameras
        self.load = [None] * num_cameras
        self.image = [None] * num_cameras

    def get(self, i: int, view: int, load: np.ndarray):
        if view >= 0 and self.view[i] == view and np.max(np.abs(load - self.load[i])) <= CACHE_LOAD_TOLERANCE:
            return self.image[i]
        return None

    def put(self, i: int, view: int, load: np.ndarray, image: np.ndarray) -> None:
        self.view[i], self.load[i], self.image[i] = (view, load.copy(), image) if view >= 0 else (None, None, None)


class Exposure:
    """Each camera's slow auto-exposure drift: grey levels -> gain(t) I + offset(t) (see the module docstring)."""

    def __init__(self, num_cameras: int, opts: BagOptions, rng: np.random.Generator):
        self.amplitude = float(opts.exposure_drift)
        # per camera: periods of the gain and of the offset (0.7-1.3 x the typical one), and their phases
        self.periods = opts.exposure_period_s * rng.uniform(0.7, 1.3, size=(num_cameras, 2))
        self.phases = rng.uniform(0.0, 2.0 * math.pi, size=(num_cameras, 2))

    def gain_offset(self, i: int, t_s: float) -> tuple:
        """(gain, offset in grey levels) of camera i at t_s seconds from the start."""
        s = np.sin(2.0 * math.pi * t_s / self.periods[i] + self.phases[i])
        return 1.0 + self.amplitude * float(s[0]), EXPOSURE_OFFSET_GREY * self.amplitude * float(s[1])


def lost_samples(n: int, loss: float, burst_samples: float, rng: np.random.Generator) -> np.ndarray:
    """Which of ``n`` samples a link lost (n,) bool: runs of kept and of lost samples alternate, each of a
    geometric length, the lost ones ``burst_samples`` long on average (at least 1) and the kept ones as long as
    makes ``loss`` the share lost (a two-state Gilbert channel, drawn run by run)."""
    lost = np.zeros(n, dtype=bool)
    if loss <= 0 or n == 0:
        return lost
    mean_lost = max(1.0, float(burst_samples))
    mean_kept = mean_lost * (1.0 - loss) / loss
    runs = max(8, int(4 * n / (mean_lost + mean_kept)) + 8)
    while True:  # enough runs to cover n samples (almost always the first draw)
        kept = rng.geometric(min(1.0, 1.0 / mean_kept), size=runs)
        gone = rng.geometric(1.0 / mean_lost, size=runs)
        ends = np.cumsum(np.stack([kept, gone], axis=1).ravel())
        if ends[-1] >= n:
            break
        runs *= 2
    starts, stops = ends[0::2], ends[1::2]  # lost runs [start, stop)
    edges = np.zeros(n + 1, dtype=np.int64)
    np.add.at(edges, np.minimum(starts, n), 1)
    np.add.at(edges, np.minimum(stops, n), -1)
    lost[:] = np.cumsum(edges[:n]) > 0
    return lost


def make_bag(rig: Rig, out, opts: BagOptions, progress: bool = True) -> dict:
    """Render and write a bag into ``out`` (a new directory; nothing is written elsewhere).

    Returns a summary: ``frames`` (triggers), ``views`` (holds), ``counts`` (messages per topic),
    ``dropped`` (camera frames lost), ``duration_s``, ``holds`` (see :func:`hold_intervals`),
    ``bar_frequencies_hz`` (M,) and ``trajectory`` (the :class:`Trajectory`).
    """
    from tqdm import tqdm

    opts.validate()
    opts.motion.validate_cameras(rig.num_cameras)
    ss = np.random.SeedSequence(int(opts.seed))
    rng_traj, rng_imu, rng_img, rng_jitter, rng_drop, rng_exposure, rng_stamp, rng_loss = (
        np.random.default_rng(s) for s in ss.spawn(8))  # a seed's first streams as before later ones were added
    scene = make_scene(int(opts.seed), boxes=BOXES + ((WALKER,) if opts.walker_speed else ()))
    traj = make_trajectory(rng_traj, opts.motion, rig.gravity_magnitude)
    loads = CameraLoads(rig, traj, opts.damping)
    scenes = MovingScene(scene, opts.walker_speed, traj.start_ns)
    _check_inside(rig, traj, scenes.swept(), loads)
    renderer = Renderer(rig, scene, opts.supersample)
    shutter = (ShutterRenderer(renderer, traj, loads, int(round(opts.shutter_ms * 1e6)), scenes)
               if opts.shutter_ms else None)
    frame_t, frame_view, fires = traj.camera_triggers(opts.motion, rig.num_cameras)
    M = rig.num_cameras
    jitter_ns = np.rint(rng_jitter.uniform(-1.0, 1.0, size=(len(frame_t), M)) * opts.jitter_ms * 1e6).astype(np.int64)
    dropped = rng_drop.random(size=(len(frame_t), M)) < opts.drop_rate
    exposure = Exposure(M, opts, rng_exposure) if opts.exposure_drift else None
    imu_offset_ns = int(round(opts.imu_time_offset_ms * 1e6))
    if opts.imu_clock_start_s is not None:  # another clock: it reads imu_clock_start_s at the first frame
        imu_offset_ns += int(round(opts.imu_clock_start_s * 1e9)) - traj.start_ns
    latency_ns, burst_ns = int(round(opts.camera_latency_ms * 1e6)), int(round(opts.camera_burst_s * 1e9))
    clocks = opts.camera_clock_start_s or (None,) * M
    if len(clocks) != M:
        raise OptionError(_OWNER, "camera_clock_start_s", f"needs one entry per camera ({M}), got {len(clocks)}")
    camera_clock_ns = [0 if c is None else int(round(c * 1e9)) - traj.start_ns for c in clocks]
    names = [c.name for c in rig.cameras]
    unstamped = [False] * M
    for name in opts.unstamped:
        if name in names:
            unstamped[names.index(name)] = True
        elif name.isdigit() and int(name) < M:
            unstamped[int(name)] = True
        elif name != "imu":
            raise OptionError(_OWNER, "unstamped", f"{name!r} is neither a camera of the rig ({', '.join(names)}, "
                              f"or its index) nor imu")
    stagger_ns = int(round(opts.camera_burst_stagger_ms * 1e6))

    def received(stamp_ns: int, camera: int) -> int:
        """An image's bag time: its stamp, plus the driver's latency, at the end of its burst (camera by camera
        when staggered)."""
        t = stamp_ns + latency_ns
        if burst_ns <= 0:
            return t
        return traj.start_ns + -(-(t - traj.start_ns) // burst_ns) * burst_ns + camera * stagger_ns
    if opts.imu:
        imu_period = int(round(1e9 / opts.motion.imu_rate))
        imu_t = np.arange(traj.start_ns, traj.end_ns, imu_period, dtype=np.int64)
        accel, gyro = imu_readings(rig, traj, imu_t, rng_imu, opts, loads)
        accel, gyro = accel / ACCEL_UNITS[opts.accel_unit], gyro / GYRO_UNITS[opts.gyro_unit]
    else:
        imu_t = np.zeros(0, dtype=np.int64)
    imu_stamp = imu_t  # when each sample is stamped and received: when taken, or on a host that receives it late
    if opts.imu_stamp_jitter_ms:
        delay = rng_stamp.uniform(0.0, opts.imu_stamp_jitter_ms * 1e6, size=len(imu_t))
        imu_stamp = np.maximum.accumulate(imu_t + np.rint(delay).astype(np.int64))
    # samples the link lost: taken out after the readings, so every other sample reads as without the loss
    imu_lost = lost_samples(len(imu_t), opts.imu_loss, opts.imu_loss_burst_ms * 1e-3 * opts.motion.imu_rate, rng_loss)
    if imu_lost.any():
        kept = ~imu_lost
        imu_t, imu_stamp, accel, gyro = imu_t[kept], imu_stamp[kept], accel[kept], gyro[kept]
    R, p, omega, _ = traj.state(frame_t)
    g_true = traj.gravity_body(R)
    cam_loads = loads.at(frame_t)  # (F, M, 3)
    gt_w, gt_W = bent_extrinsics_at_loads(rig, cam_loads)  # each camera's pose in the body at each trigger
    creeping = traj.creeping
    imu_topic = bag_topic((rig.imu or ImuMount()).topic)  # a relative rig topic is recorded in the root namespace
    topics = [(image_topic_for(bag_topic(c.image_topic), opts.encoding), bag_topic(c.info_topic)) for c in rig.cameras]
    quality = {"jpeg_quality": opts.jpeg_quality} if opts.encoding in COMPRESSED_FORMATS else {}
    max_jitter_ns = int(np.max(np.abs(jitter_ns), initial=0))
    claimed = (opts.imu_covariance_scale * opts.imu_noise / ACCEL_UNITS[opts.accel_unit],
               opts.imu_covariance_scale * opts.gyro_noise / GYRO_UNITS[opts.gyro_unit])
    cache = _StillCache(M)
    j = 0  # next IMU sample
    pending: list = []  # heap of (bag time, order, topic, message): written in bag-time order, ties as pushed
    order = itertools.count()
    writer = BagWriter(out, opts.storage)  # refuses an existing path, so removing it on failure is safe
    try:
        with writer as bag:
            def push(ts, topic, msg):
                heapq.heappush(pending, (int(ts), next(order), topic, msg))

            def push_imu(k):
                """IMU sample k, received when stamped; its stamp carries the IMU clock's offset."""
                stamp = 0 if "imu" in opts.unstamped else int(imu_stamp[k]) + imu_offset_ns
                msg = bag.imu_msg(stamp, IMU_FRAME, accel[k], gyro[k], *claimed)
                push(int(imu_stamp[k]), imu_topic, msg)

            def flush(until_ns):
                while pending and pending[0][0] <= until_ns:
                    ts, _, topic, msg = heapq.heappop(pending)
                    bag.write(topic, msg, ts)

            bar = tqdm(total=len(frame_t), unit="frame", desc="make-bag", disable=not progress, leave=False)
            for n, (t, view) in enumerate(zip(frame_t, frame_view)):
                t, view = int(t), int(view)
                # IMU samples taken up to this trigger's latest camera stamp, received when taken (the recorder's
                # clock); their stamps carry the IMU clock's offset
                while j < len(imu_t) and imu_t[j] <= t + max_jitter_ns:
                    push_imu(j)
                    j += 1
                Rs, cs = renderer.camera_poses(R[n], p[n], cam_loads[n])
                # a creeping body, or a scene in which someone walks, is re-rendered every time
                key = view if view >= 0 and not creeping[view] and not scenes.moves else -1
                for i in np.flatnonzero(fires[n]):
                    cam = rig.cameras[i]
                    img = cache.get(i, key, cam_loads[n, i])
                    if img is None and not dropped[n, i]:
                        if shutter is None:
                            img = renderer.render_camera(i, Rs[i], cs[i], scene=scenes.at(t))
                        else:  # blurred where the image moves during the shutter
                            count = shutter.instant_count(i, t)
                            img = shutter.render(i, t, count)
                        cache.put(i, key if shutter is None or count == 1 else -1, cam_loads[n, i], img)
                    h, w = cam.resolution[1], cam.resolution[0]
                    noise = rng_img.normal(scale=opts.image_noise, size=(h, w)) if opts.image_noise else 0.0
                    if dropped[n, i]:
                        continue  # the noise was drawn anyway, so a drop changes no other image
                    if exposure is not None:
                        gain, offset = exposure.gain_offset(i, (t - traj.start_ns) * 1e-9)
                        img = gain * img + offset
                    u8 = np.clip(np.rint(img + noise), 0, 255).astype(np.uint8)
                    ts = t + int(jitter_ns[n, i])
                    own = 0 if unstamped[i] else ts + camera_clock_ns[i]  # the stamp of the camera's own clock
                    push(received(ts, i), topics[i][0], bag.image_msg(u8, own, cam.name, opts.encoding, **quality))
                    push(received(ts, i), topics[i][1], bag.camera_info_msg(cam, own))
                    push(ts, EXTRINSICS_TOPIC.format(cam.name),
                         bag.pose_msg(ts, rig.body_frame, gt_W[n, i], gt_w[n, i]))
                push(t, POSE_TOPIC, bag.pose_msg(t, WORLD_FRAME, R[n], p[n]))
                push(t, GRAVITY_TOPIC, bag.vector_msg(t, rig.body_frame, g_true[n]))
                push(t, ANGULAR_VELOCITY_TOPIC, bag.vector_msg(t, rig.body_frame, omega[n]))
                # later triggers stamp nothing before their earliest jittered stamp, later IMU samples nothing
                # before this trigger's latest one
                nxt = int(frame_t[n + 1]) - max_jitter_ns - 1 if n + 1 < len(frame_t) else t + max_jitter_ns
                flush(min(t + max_jitter_ns, nxt))
                bar.update(1)
            while j < len(imu_t):
                push_imu(j)
                j += 1
            flush(np.iinfo(np.int64).max)
            bar.close()
            counts = dict(bag.counts)
    except BaseException:
        shutil.rmtree(writer.path, ignore_errors=True)  # no half-written bag left behind
        raise
    return {
        "frames": int(len(frame_t)), "views": int(len(traj.R)), "counts": counts,
        "dropped": int((dropped & fires).sum()),
        "duration_s": (traj.end_ns - traj.start_ns) * 1e-9, "holds": hold_intervals(traj, loads),
        "bar_frequencies_hz": [float(f) for f in loads.frequencies], "trajectory": traj,
        "images": int((fires & ~dropped).sum()), "imu_lost": int(imu_lost.sum()),
        "blurred": 0 if shutter is None else int(sum(v for k, v in shutter.instants.items() if k > 1)),
    }
