"""Rendered synthetic bags of a bending rig (issue 4; topics of SPEC section 11).

For every camera frame the images are rendered with the BENT extrinsics
(SPEC section 3) at the load of that instant: gravity in the body frame,
``g_B = R_world_body^T (0, 0, -|g|)`` while still (minus the body's
acceleration during moves, quasi-static). The IMU (200 Hz by default)
reads the specific force ``a = -g`` in its own frame when still (SPEC
section 4, through the rig's ``imu`` mount) plus white noise and a constant
bias, and the body angular velocity during moves. Ground truth
``/ground_truth/pose`` (body in world, world z up) and
``/ground_truth/gravity`` (gravity in the body frame) are stamped like the
images. Deterministic for a seed.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field

import numpy as np

from ..bag.writer import ENCODINGS, BagWriter
from ..core.deformation import deformed_extrinsics
from ..core.rig import ImuMount, Rig
from ..core.so3 import normalize
from ..errors import InputError
from .raycast import Renderer
from .scene import contains, make_scene
from .sequence import MotionOptions, Trajectory, make_trajectory

POSE_TOPIC = "/ground_truth/pose"
GRAVITY_TOPIC = "/ground_truth/gravity"
WORLD_FRAME = "world"
IMU_FRAME = "imu"


@dataclass
class BagOptions:
    """Everything besides the rig that defines a rendered bag."""

    motion: MotionOptions = field(default_factory=MotionOptions)
    seed: int = 0
    encoding: str = "mono8"
    storage: str = "sqlite3"
    image_noise: float = 1.0  # grey levels, std of Gaussian pixel noise
    imu_noise: float = 0.02  # m/s^2, accelerometer white noise std per sample
    gyro_noise: float = 0.002  # rad/s
    imu_bias: float = 0.05  # m/s^2, norm of the constant accelerometer bias (random direction)
    gyro_bias: float = 0.002  # rad/s, norm of the constant gyro bias

    def validate(self) -> None:
        if self.encoding not in ENCODINGS:
            raise InputError("--encoding", f"unsupported {self.encoding!r} (supported: {', '.join(ENCODINGS)})")
        for name in ("image_noise", "imu_noise", "gyro_noise", "imu_bias", "gyro_bias"):
            if not getattr(self, name) >= 0:
                raise InputError(f"--{name.replace('_', '-')}", f"must be >= 0, got {getattr(self, name)}")
        try:
            self.motion.validate()
        except ValueError as exc:
            raise InputError("make-bag options", str(exc)) from None


def imu_readings(rig: Rig, traj: Trajectory, t_ns, rng: np.random.Generator, opts: BagOptions):
    """Accelerometer (N, 3) and gyro (N, 3) in the IMU frame at times t_ns, with noise and constant bias.

    Specific force a = R^T (acc_world - g_world) in the body frame; an IMU at
    the body centre reads R_body_imu^T a, one inside camera i reads
    R_cam_imu^T W_i(g)^T a with the camera bent by the load (SPEC section 4).
    """
    imu = rig.imu or ImuMount()
    R, _, omega, acc = traj.state(t_ns)
    load = traj.load_body(R, acc)  # g - a_world in body = -(specific force)
    f_body = -load
    if imu.mount == "body":
        mount_R = np.broadcast_to(np.eye(3), (len(R), 3, 3))
    else:
        _, W = deformed_extrinsics(rig, load)  # (N, M, 3, 3)
        mount_R = W[:, rig.camera_index(imu.mount)]
    to_imu = np.einsum("ji,njk->nik", imu.rotation, np.swapaxes(mount_R, 1, 2))  # body -> IMU
    accel = np.einsum("nij,nj->ni", to_imu, f_body)
    gyro = np.einsum("nij,nj->ni", to_imu, omega)
    accel_bias = opts.imu_bias * normalize(rng.normal(size=3))
    gyro_bias = opts.gyro_bias * normalize(rng.normal(size=3))
    accel = accel + accel_bias + rng.normal(scale=opts.imu_noise, size=accel.shape)
    gyro = gyro + gyro_bias + rng.normal(scale=opts.gyro_noise, size=gyro.shape)
    return accel, gyro


def _check_inside(rig: Rig, traj: Trajectory, scene) -> None:
    """Every (bent) camera must stay inside the room and outside the boxes."""
    t = np.arange(traj.start_ns, traj.end_ns, traj.period_ns // 2 or 1, dtype=np.int64)
    R, p, _, acc = traj.state(t)
    w, _ = deformed_extrinsics(rig, traj.load_body(R, acc))
    centres = np.einsum("nij,nmj->nmi", R, w) + p[:, None, :]
    if not np.all(contains(scene, centres.reshape(-1, 3))):
        raise InputError(rig.source, "a camera leaves the rendered room (bars too long or too bent); "
                                     "use shorter bars or a smaller --max-translation", "position")


def make_bag(rig: Rig, out, opts: BagOptions, progress: bool = True) -> dict:
    """Render and write a bag; returns a summary (counts, duration, trajectory)."""
    from tqdm import tqdm

    opts.validate()
    ss = np.random.SeedSequence(int(opts.seed))
    rng_traj, rng_imu, rng_img = (np.random.default_rng(s) for s in ss.spawn(3))
    scene = make_scene(int(opts.seed))
    traj = make_trajectory(rng_traj, opts.motion, rig.gravity_magnitude)
    _check_inside(rig, traj, scene)
    renderer = Renderer(rig, scene)
    frame_t, frame_view = traj.frame_times(opts.motion.motion)
    imu_period = int(round(1e9 / opts.motion.imu_rate))
    imu_t = np.arange(traj.start_ns, traj.end_ns, imu_period, dtype=np.int64)
    accel, gyro = imu_readings(rig, traj, imu_t, rng_imu, opts)
    R, p, _, acc = traj.state(frame_t)
    g_true = traj.gravity_body(R)
    load = traj.load_body(R, acc)
    imu_topic = (rig.imu or ImuMount()).topic
    cached_view, cached = None, None
    j = 0  # next IMU sample
    writer = BagWriter(out, opts.storage)  # refuses an existing path, so removing it on failure is safe
    try:
        with writer as bag:
            bar = tqdm(total=len(frame_t), unit="frame", desc="make-bag", disable=not progress, leave=False)
            for n, (t, view) in enumerate(zip(frame_t, frame_view)):
                while j < len(imu_t) and imu_t[j] <= t:
                    bag.write(imu_topic, bag.imu_msg(int(imu_t[j]), IMU_FRAME, accel[j], gyro[j], opts.imu_noise,
                                                     opts.gyro_noise), int(imu_t[j]))
                    j += 1
                if view >= 0 and view == cached_view:
                    images = cached  # still: same view, fresh noise below
                else:
                    images = renderer.render_rig(R[n], p[n], load[n])
                    cached_view, cached = (int(view), images) if view >= 0 else (None, None)
                t = int(t)
                for cam, img in zip(rig.cameras, images):
                    noisy = img + rng_img.normal(scale=opts.image_noise, size=img.shape) if opts.image_noise else img
                    u8 = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
                    bag.write(cam.image_topic, bag.image_msg(u8, t, cam.name, opts.encoding), t)
                    bag.write(cam.info_topic, bag.camera_info_msg(cam, t), t)
                bag.write(POSE_TOPIC, bag.pose_msg(t, WORLD_FRAME, R[n], p[n]), t)
                bag.write(GRAVITY_TOPIC, bag.vector_msg(t, rig.body_frame, g_true[n]), t)
                bar.update(1)
            for k in range(j, len(imu_t)):
                bag.write(imu_topic, bag.imu_msg(int(imu_t[k]), IMU_FRAME, accel[k], gyro[k], opts.imu_noise,
                                                 opts.gyro_noise), int(imu_t[k]))
            bar.close()
            counts = dict(bag.counts)
    except BaseException:
        shutil.rmtree(writer.path, ignore_errors=True)  # no half-written bag left behind
        raise
    return {
        "frames": int(len(frame_t)), "views": int(len(traj.R)), "counts": counts,
        "duration_s": (traj.end_ns - traj.start_ns) * 1e-9, "trajectory": traj,
    }
