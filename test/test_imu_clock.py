"""The IMU clock offset from the gyro's rate against the images' motion."""

import numpy as np
import pytest

from nrmpc_ros.frontend.imu_clock import ImuClockEstimator


def _rate(t):
    """|omega| of a rig holding still and turning in trapezoid moves of 1 s every 3 s (rad/s)."""
    phase = np.mod(t, 3.0)
    ramp = np.clip(phase / 0.25, 0, 1) * np.clip((1.0 - phase) / 0.25, 0, 1)
    return 0.6 * ramp * (phase < 1.0)


@pytest.mark.parametrize("late_s", [0.0, 0.0237, -0.061])
def test_the_lag_between_gyro_and_images_is_found_to_a_millisecond(late_s):
    rng = np.random.default_rng(4)
    est = ImuClockEstimator()
    t_imu = np.arange(0.0, 30.0, 0.005)
    for t in t_imu:  # the gyro stamped late_s after the truth
        est.add_imu(t + late_s, (_rate(t) + rng.normal(0, 0.002), rng.normal(0, 0.002), 0.0))
    frames = np.arange(0.5, 29.5, 1 / 15)
    fine = np.linspace(0, 1, 50)
    for a, b in zip(frames[:-1], frames[1:]):
        mean = _rate(a + (b - a) * fine).mean()
        est.add_frame(a, b, [mean * (1 + rng.normal(0, 0.05)) + abs(rng.normal(0, 0.003))])
    out = est.estimate()
    assert out is not None and out.correlation > 0.9
    assert out.offset_s == pytest.approx(-late_s, abs=1e-3)


def test_no_move_no_offset():
    est = ImuClockEstimator()
    rng = np.random.default_rng(0)
    for t in np.arange(0.0, 10.0, 0.005):
        est.add_imu(t, rng.normal(0, 0.002, 3))
    for a in np.arange(0.5, 9.5, 0.1):
        est.add_frame(a, a + 0.1, [abs(rng.normal(0, 0.001))])
    assert est.estimate() is None


def test_bent_cameras_lag_the_body_and_the_refinement_reads_the_clock_not_the_bars():
    """A rendered trajectory (no pixels): each camera's image rotates with the body AND its ringing bar. The
    gyro's rate alone reads the bars' lag as a clock offset; against the bent cameras the IMU's true lateness
    comes out to a millisecond."""
    import dataclasses

    from nrmpc_ros.core.bar_state import bent_extrinsics_at_loads
    from nrmpc_ros.core.so3 import log_so3
    from nrmpc_ros.render.bagmaker import BagOptions, imu_readings
    from nrmpc_ros.render.bars import CameraLoads
    from nrmpc_ros.render.sequence import MotionOptions, make_trajectory
    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.25, mass=0.1, bar_length=0.3))
    rig = dataclasses.replace(rig, cameras=tuple(dataclasses.replace(c, damping=0.04) for c in rig.cameras))
    motion = MotionOptions(views=5, hold_seconds=2.0, rate=15, imu_rate=200, move_profile="trapezoid",
                           min_step=15, max_step=30, speed=40.0)
    traj = make_trajectory(np.random.default_rng(2), motion)
    loads = CameraLoads(rig, traj)
    imu_t = np.arange(traj.start_ns, traj.end_ns, 5_000_000, dtype=np.int64)
    opts = BagOptions(motion=motion, imu_noise=0.0, gyro_noise=0.0, imu_bias=0.0, gyro_bias=0.0)
    accel, gyro = imu_readings(rig, traj, imu_t, np.random.default_rng(0), opts, loads)
    frames, _ = traj.frame_times("stream")
    R, _, _, _ = traj.state(frames)
    _, W = bent_extrinsics_at_loads(rig, loads.at(frames))
    cam = R[:, None] @ W  # (F, M, 3, 3) camera -> world
    turn = log_so3(np.swapaxes(cam[:-1], -1, -2) @ cam[1:])  # in each camera's frame
    across = np.linalg.norm(turn[..., :2], axis=-1) / (np.diff(frames) * 1e-9)[:, None]  # image motion, rad/s
    late = 0.018
    results = {}
    for name, r in (("gyro only", None), ("bent cameras", rig)):
        est = ImuClockEstimator(r)
        for k in range(len(imu_t)):
            est.add_imu(imu_t[k] * 1e-9 + late, gyro[k], accel[k])
        for k in range(len(frames) - 1):
            est.add_frame(frames[k] * 1e-9, frames[k + 1] * 1e-9, across[k])
        results[name] = est.estimate()
    assert results["bent cameras"].offset_s == pytest.approx(-late, abs=1e-3), results
    assert abs(results["gyro only"].offset_s + late) > 3e-3, "the bars' lag biases the gyro-only estimate"
