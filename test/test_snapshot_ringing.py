"""A snapshot's ringing predicted from the IMU-driven bars and removed from its bearings; the prediction's error."""

import dataclasses
import math

import numpy as np
import pytest

from nrmpc_ros.cameras import bearings_to_pixels
from nrmpc_ros.core.bar_state import BarPropagator, bent_extrinsics_at_loads
from nrmpc_ros.core.dynamics import bar_natural_frequencies
from nrmpc_ros.core.so3 import angle_between
from nrmpc_ros.frontend.snapshot_ringing import correct_pixels, correction_rotations, predict, residual_px, uncertainty
from nrmpc_ros.render.bagmaker import BagOptions, imu_readings
from nrmpc_ros.render.bars import CameraLoads
from nrmpc_ros.render.sequence import MotionOptions, make_trajectory
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

DELAY_S = 0.4  # the snapshot after the stop: a 2.9 Hz bar at damping 0.03 still rings at 80 % of its stop


def _rig(damping=0.03):
    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.3, mass=0.1, bar_length=0.3, focal=235.0,
                           resolution=(320, 240)))
    return dataclasses.replace(rig, cameras=tuple(dataclasses.replace(c, damping=damping) for c in rig.cameras))


def _ringing_snapshot(rig, bias_ms2: float, seed: int = 4, accel_noise: float = 0.0, gyro_noise: float = 0.0):
    """An IMU at 1 kHz (noise-free unless given, with a constant accelerometer bias) through abrupt moves, and
    the propagated bars at a snapshot DELAY_S after the second stop: (prediction, true loads (M, 3), still
    loads (M, 3))."""
    motion = MotionOptions(views=3, hold_seconds=2.0, rate=10, imu_rate=1000, move_seconds=0.6,
                           move_profile="min-jerk", max_step=35, min_step=25)
    traj = make_trajectory(np.random.default_rng(seed), motion)
    loads = CameraLoads(rig, traj)
    t_snap = int(traj.hold_start[2]) + int(DELAY_S * 1e9)
    imu_t = np.arange(traj.start_ns, t_snap + 1, 1_000_000, dtype=np.int64)
    opts = BagOptions(motion=motion, imu_noise=accel_noise, gyro_noise=gyro_noise, imu_bias=bias_ms2, gyro_bias=0.0)
    accel, gyro = imu_readings(rig, traj, imu_t, np.random.default_rng(seed), opts, loads)
    prop = BarPropagator(rig, history_s=5.0)
    for k in range(len(imu_t)):
        prop.add_imu(imu_t[k] * 1e-9, accel[k], gyro[k])
    t = t_snap * 1e-9
    M = rig.num_cameras
    p = predict(prop, np.full(M, t), np.arange(M), t - 0.3, t, traj.hold_start[2] * 1e-9)
    return p, loads.at(np.array([t_snap]))[0], loads.quasi_static(np.array([t_snap]))[0]


@pytest.mark.parametrize("bias, tol_rad", [(0.0, 2e-6), (0.05, 1e-5)])
def test_corrected_bearings_match_the_static_model_at_the_true_gravity(bias, tol_rad):
    """Every camera's bearings of the snapshot, turned by the predicted ringing, are those of the static model
    at the still rig's true load (its gravity); uncorrected they are off by the ringing (> 1e-3 rad). The
    accelerometer's bias cancels to first order: what is left is half the commutator of its bend (0.015 rad
    per m/s^2 times 0.05) and the ringing's, about 4e-6 rad."""
    rig = _rig()
    p, x_true, still = _ringing_snapshot(rig, bias)
    assert p is not None and p.elapsed_s == pytest.approx(DELAY_S)
    _, W_true = bent_extrinsics_at_loads(rig, x_true)  # the cameras as the ringing bars hold them
    _, W_static = bent_extrinsics_at_loads(rig, still)  # the static model at the true gravity
    rng = np.random.default_rng(0)
    R = correction_rotations(rig, p)
    for i, cam in enumerate(rig.cameras):
        f_static = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), np.ones(50)])
        f_static /= np.linalg.norm(f_static, axis=1, keepdims=True)
        d = f_static @ W_static[i].T  # body-frame directions of far points
        f_seen = d @ W_true[i]  # their bearings in the ringing camera
        before = angle_between(f_seen, f_static)
        after = angle_between(f_seen @ R[i].T, f_static)
        assert before.min() > 1e-3, before.min()
        assert after.max() < tol_rad, after.max()
        uv_seen, uv_true = bearings_to_pixels(cam, f_seen), bearings_to_pixels(cam, f_static)
        assert np.linalg.norm(uv_seen - uv_true, axis=1).min() > 0.2
        assert np.linalg.norm(correct_pixels(cam, uv_seen, R[i]) - uv_true, axis=1).max() < 2 * cam.focal_px * tol_rad


def test_the_predicted_envelope_is_the_bars_free_ringing_about_the_still_load_with_a_noisy_imu():
    """With a MEMS-grade IMU at 1 kHz the envelope is the true bars' (|x - l| and x' / w about the still load,
    within the noise they pass), not the amplitude about one IMU step's load line, which carries the noise's
    slope over one period (|s| / w: about 1.5 m/s^2 here, the envelope itself 0.1-0.5 m/s^2)."""
    rig = _rig()
    p, x_true, still = _ringing_snapshot(rig, 0.0, accel_noise=0.02, gyro_noise=0.002)
    w = 2 * math.pi * bar_natural_frequencies(rig)
    loads = p.ringing.real + p.still_load  # Re(Z) is the load's offset from the still one
    assert np.allclose(loads, p.load, atol=1e-9)
    envelope = np.linalg.norm(np.abs(p.ringing), axis=1)
    quiet, _, _ = _ringing_snapshot(rig, 0.0)  # the same moves, a noise-free IMU
    truth = np.linalg.norm(np.abs(quiet.ringing), axis=1)
    assert np.all(truth > 0.05)
    h, zeta = 1e-3, 0.03  # the noise the bars pass (per axis: accelerometer, and the gyro's differenced)
    lever = np.linalg.norm(rig.positions, axis=1)
    sigma = np.hypot(0.02 * np.sqrt(h * w / (4 * zeta)), lever * 0.002 * np.sqrt(h * w**3 / (4 * zeta)))
    assert np.all(np.abs(envelope - truth) < 0.1 * truth + 5 * sigma), (envelope, truth, sigma)


def test_the_prediction_error_grows_with_the_time_since_the_stop_and_the_damping_uncertainty():
    """The residual: the envelope times w t s_zeta, 2 pi t s_f and w s_t; the IMU noise through the bar alone
    when the bars are known exactly; zero for a noise-free IMU and exact bars."""
    rig = _rig()
    p, _, _ = _ringing_snapshot(rig, 0.0)
    zeta = np.full(3, 0.03)
    exact = uncertainty(rig, 0.0, 0.0, 0.0, 0.0, 0.0)  # no IMU period: the stamps exact too
    assert np.all(residual_px(rig, zeta, p, exact) == 0.0)
    u_dir, cd, _ = rig.bar_coefficients  # the translation, not removed, over the depth of the points
    perp = p.deflection - np.sum(p.deflection * u_dir, axis=1, keepdims=True) * u_dir
    assert residual_px(rig, zeta, p, exact, depth_m=2.0) == pytest.approx(235.0 * cd * np.linalg.norm(perp, axis=1) / 2)
    u = uncertainty(rig, 0.2, 0.03, 0.0, 0.0, 0.001)
    assert u.damping_std.tolist() == pytest.approx([0.006] * 3)
    assert u.clock_std_s == pytest.approx(0.001 / math.sqrt(12))
    r = residual_px(rig, zeta, p, u)
    later = residual_px(rig, zeta, dataclasses.replace(p, elapsed_s=2 * p.elapsed_s), u)
    assert np.all(r > 0) and np.all(later > 1.9 * r * 0.99)
    unknown = dataclasses.replace(rig, cameras=tuple(dataclasses.replace(c, damping=None) for c in rig.cameras))
    assert np.all(residual_px(rig, zeta, p, uncertainty(unknown, 0.2, 0.03, 0.0, 0.0, 0.001)) > 4 * r)
    f = bar_natural_frequencies(rig)
    calibrated = dataclasses.replace(rig, cameras=tuple(dataclasses.replace(
        c, damping_std=0.0003, frequency_hz=1.001 * fi, frequency_std_hz=0.0005 * fi) for c, fi in zip(rig.cameras, f)))
    assert bar_natural_frequencies(calibrated) == pytest.approx(1.001 * f)  # the identified frequency is used
    uc = uncertainty(calibrated, 0.2, 0.03, 0.01, 0.0, 0.001)
    assert uc.damping_std.tolist() == [0.0003] * 3  # the rig file's stds, not the defaults
    assert uc.frequency_rel_std == pytest.approx(np.full(3, 0.0005 / 1.001))
    assert np.all(residual_px(rig, zeta, p, uc) < 0.5 * r)
    noisy = uncertainty(rig, 0.0, 0.0, 0.0, 0.02, 0.005)
    n = np.sqrt(residual_px(rig, zeta, p, noisy) ** 2 - residual_px(rig, zeta, p, uncertainty(
        rig, 0.0, 0.0, 0.0, 0.0, 0.005)) ** 2)  # the stamps' half period alone taken out
    px_per_load = 235.0 * np.linalg.norm(rig.bar_derivatives[1], ord=2, axis=(1, 2))
    w = 2 * math.pi * bar_natural_frequencies(rig)  # sigma sqrt(h w / (4 zeta)) on each of two transverse axes
    expected = math.sqrt(2) * px_per_load * 0.02 * np.sqrt(0.005 * w / (4 * 0.03))
    assert n == pytest.approx(expected, rel=0.05)
    gyro = uncertainty(rig, 0.0, 0.0, 0.0, 0.0, 0.005, gyro_sigma=0.002)
    n_gyro = np.sqrt(residual_px(rig, zeta, p, gyro) ** 2 - residual_px(rig, zeta, p, uncertainty(
        rig, 0.0, 0.0, 0.0, 0.0, 0.005)) ** 2)  # the gyro's noise differenced into alpha at the tip's lever
    lever = np.linalg.norm(rig.positions, axis=1)
    assert n_gyro == pytest.approx(math.sqrt(2) * px_per_load * lever * 0.002 * np.sqrt(0.005 * w**3 / (4 * 0.03)),
                                   rel=0.05)
