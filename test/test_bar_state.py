"""Bar state propagated from IMU samples: exact steps, ringing, rotational loads, gaps, queries."""

import dataclasses
import math

import numpy as np
import pytest

from nrmpc_ros.core.bar_state import BarPropagator, bent_extrinsics_at_loads
from nrmpc_ros.core.deformation import deformed_extrinsics
from nrmpc_ros.core.dynamics import UNKNOWN_DAMPING_RATIO, DampedResponse, bar_natural_frequencies
from nrmpc_ros.core.rig import Rig
from nrmpc_ros.sim.synthetic import RigSpec, make_rig


def _rig(damping=(0.03, 0.05, 0.04), EI=0.3):
    rig = make_rig(RigSpec(num_cameras=len(damping), layout="ring", EI=EI, mass=0.1, bar_length=0.3))
    cams = tuple(dataclasses.replace(c, damping=z) for c, z in zip(rig.cameras, damping))
    return dataclasses.replace(rig, cameras=cams)


def _feed(prop, t, f, w=None):
    w = np.zeros_like(f) if w is None else w
    for k in range(len(t)):
        prop.add_imu(t[k], f[k], w[k])


def test_a_load_step_rings_at_the_natural_frequency_and_decays_at_the_damping():
    rig = _rig()
    prop = BarPropagator(rig, history_s=10.0)
    eps = 1e-7  # the step: the load goes from 0 to 1 m/s^2 (x) between two samples eps apart
    t = np.concatenate([[0.0, 0.5, 0.5 + eps], 0.5 + eps + np.arange(1, 4001) * 1e-3])
    f = np.zeros((len(t), 3))
    f[2:, 0] = -1.0  # specific force -load
    _feed(prop, t, f)
    q = 0.5 + np.linspace(0.0, 3.9, 200)
    x = prop.loads_at(q)[:, :, 0]
    for i, (fr, z) in enumerate(zip(bar_natural_frequencies(rig), (0.03, 0.05, 0.04))):
        w = 2 * math.pi * fr
        wd = w * math.sqrt(1 - z * z)
        tt = q - 0.5
        expected = 1.0 - np.exp(-z * w * tt) * (np.cos(wd * tt) + z * w / wd * np.sin(wd * tt))
        assert np.abs(x[:, i] - expected).max() < 10 * w * eps
    assert np.allclose(prop.loads_at([0.25])[0], 0.0, atol=1e-15), "at rest before the step"
    assert prop.stats.too_old == 0
    short = BarPropagator(rig, history_s=1.0)
    _feed(short, t, f)
    short.loads_at([0.6, 4.0])
    assert short.stats.too_old == 1


def test_the_steps_are_exact_for_a_load_linear_between_samples():
    """Uneven IMU steps, a load with kinks at the samples: the closed form of DampedResponse to 1e-11."""
    rng = np.random.default_rng(3)
    rig = _rig()
    t = np.cumsum(rng.uniform(0.002, 0.008, size=200))
    f = rng.normal(size=(len(t), 3)) + [0.0, 0.0, 9.81]
    prop = BarPropagator(rig)
    _feed(prop, t, f)
    q = np.sort(rng.uniform(t[-100], t[-1], size=50))
    ref = DampedResponse(t, -f, bar_natural_frequencies(rig), [0.03, 0.05, 0.04]).at(q)[0]
    assert np.abs(prop.loads_at(q) - ref).max() < 1e-11


def test_a_pure_spin_loads_each_bar_with_its_centripetal_term():
    rig = _rig()
    spin = np.array([0.0, 0.0, 2.0])  # rad/s about the body z axis, constant
    t = np.arange(500) * 0.005
    f = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    prop = BarPropagator(rig)
    _feed(prop, t, f, np.tile(spin, (len(t), 1)))
    x = prop.loads_at(np.linspace(0.1, 2.4, 9))
    v = rig.positions
    expected = np.array([0.0, 0.0, -9.81]) - np.cross(spin, np.cross(spin, v))  # g - omega x (omega x v)
    assert np.allclose(x, expected[None], atol=1e-10)
    assert np.allclose(expected[:, :2], 4.0 * v[:, :2]), "outwards, |omega|^2 times the lever"
    w, W = prop.extrinsics_at([1.0])
    w0, W0 = bent_extrinsics_at_loads(rig, expected)
    assert np.allclose(w[0], w0) and np.allclose(W[0], W0)


def test_bent_extrinsics_at_one_load_for_all_is_the_static_model():
    rig = _rig()
    g = np.array([0.3, -1.2, -9.7])
    w, W = bent_extrinsics_at_loads(rig, np.tile(g, (3, 1)))
    w0, W0 = deformed_extrinsics(rig, g)
    assert np.allclose(w, w0, atol=1e-15) and np.allclose(W, W0, atol=1e-15)


def test_an_imu_gap_holds_the_load_and_a_long_one_restarts_at_rest():
    rig = _rig()
    prop = BarPropagator(rig)
    t = np.concatenate([np.arange(100) * 0.005, 0.495 + 0.04 + np.arange(100) * 0.005])  # 8 periods missing
    f = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    f[100:, 0] = -2.0
    _feed(prop, t, f)
    prop.flush()
    assert prop.stats.gaps_held == 1 and prop.stats.reinitialised == 0
    assert np.allclose(prop.loads_at([0.52])[0], [0.0, 0.0, -9.81]), "the last load, held over the gap"
    t2 = t[-1] + 1.0 + np.arange(50) * 0.005  # a gap longer than the slowest bar's period
    _feed(prop, t2, np.tile([-1.0, 0.0, 9.81], (50, 1)))
    prop.flush()
    assert prop.stats.gaps_held == 2 and prop.stats.reinitialised == 1
    assert np.allclose(prop.loads_at([t2[10]])[0], [1.0, 0.0, -9.81], atol=1e-12), "at rest after a long gap"


@pytest.mark.parametrize("rate_hz", [50.0, 200.0, 1000.0])
def test_a_still_rig_with_a_noisy_imu_starts_at_rest_and_stays_within_the_noise_the_bar_passes(rate_hz):
    """The first sample's angular acceleration is the gyro's noise differenced over one IMU period (sqrt(2)
    sigma_w / h: 1.1 m/s^2 at the 0.3 m lever for 0.002 rad/s at 1 kHz); a bar started at rest there would
    ring at that for seconds. At rest at the specific force it stays within the noise the running bar
    filters: per axis sigma_a sqrt(h w / (4 zeta)) from the accelerometer and |v| sigma_w sqrt(h w^3 /
    (4 zeta)) from the gyro's differenced noise."""
    rig = _rig()
    rng = np.random.default_rng(int(rate_hz))
    h, sa, sw = 1.0 / rate_hz, 0.02, 0.002
    t = np.arange(int(3.0 * rate_hz)) * h
    f = np.array([1.0, -2.0, 9.5]) + rng.normal(scale=sa, size=(len(t), 3))
    prop = BarPropagator(rig, history_s=10.0)
    _feed(prop, t, f, rng.normal(scale=sw, size=(len(t), 3)))
    w = 2 * math.pi * bar_natural_frequencies(rig)
    zeta = np.array([0.03, 0.05, 0.04])
    lever = np.linalg.norm(rig.positions, axis=1)
    sigma = np.hypot(sa * np.sqrt(h * w / (4 * zeta)), lever * sw * np.sqrt(h * w**3 / (4 * zeta)))
    q = np.linspace(t[1], t[-1], 300)
    dev = np.abs(prop.loads_at(q) + np.array([1.0, -2.0, 9.5]))  # the load is minus the specific force
    # (plus the first sample's own accelerometer noise, the load the bar starts at rest at)
    assert np.all(dev.max(axis=(0, 2)) < 5.0 * sigma + 3.0 * sa), dev.max(axis=(0, 2)) / sigma


def test_queries_beyond_the_newest_sample_hold_the_last_load_and_the_clock_offset_applies():
    rig = _rig()
    t = np.arange(200) * 0.005
    f = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    f[100:, 1] = 1.5
    late = BarPropagator(rig, imu_time_offset_s=0.25)
    _feed(late, t, f)
    ref = BarPropagator(rig)
    _feed(ref, t + 0.25, f)
    q = np.linspace(0.3, 1.2, 11)
    assert np.allclose(late.loads_at(q), ref.loads_at(q), atol=1e-12)
    # Beyond the newest sample (t = 0.995 + 0.25) the load stays; the ringing goes on from the state there.
    more = BarPropagator(rig, imu_time_offset_s=0.25)
    _feed(more, np.arange(400) * 0.005, np.concatenate([f, np.tile(f[-1], (200, 1))]))
    q = np.array([1.3, 1.5, 1.9])
    assert np.allclose(late.loads_at(q), more.loads_at(q), atol=1e-12)
    assert late.stats.extrapolated == 3


def test_unknown_damping_takes_the_documented_default():
    rig = _rig(damping=(None, 0.05, None))
    assert BarPropagator(rig).zeta.tolist() == [UNKNOWN_DAMPING_RATIO, 0.05, UNKNOWN_DAMPING_RATIO]
    assert BarPropagator(rig, damping=0.07).zeta.tolist() == [0.07, 0.05, 0.07]
    assert not BarPropagator(rig).ready
    assert BarPropagator(rig).loads_at([0.0]) is None


def test_an_imu_in_a_camera_is_moved_to_the_body():
    """A still rig: an IMU inside camera 1 reads gravity in the bent camera frame; the bars carry gravity."""
    rig = _rig(EI=3.0)
    g = np.array([0.5, -1.0, -9.7])
    w, W = deformed_extrinsics(rig, g)
    imu = dataclasses.replace(rig.imu, mount=rig.cameras[1].name, rotation=np.eye(3))
    rig_cam = Rig(cameras=rig.cameras, imu=imu)
    prop = BarPropagator(rig_cam)
    t = np.arange(300) * 0.005
    _feed(prop, t, np.tile(-W[1].T @ g, (len(t), 1)))
    x = prop.loads_at([1.0])[0]
    assert np.abs(x - g).max() < 0.02 * np.linalg.norm(g)  # first W_1 from the canonical V_1, then the bent one
    x_late = prop.loads_at([t[-1]])[0]
    assert np.abs(x_late - g).max() < 1e-3


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_and_out_of_order_samples_are_rejected_and_counted(bad):
    prop = BarPropagator(_rig())
    prop.add_imu(0.0, [0, 0, 9.81], [0, 0, 0])
    prop.add_imu(0.005, [bad, 0, 9.81], [0, 0, 0])
    prop.add_imu(-1.0, [0, 0, 9.81], [0, 0, 0])
    assert prop.stats.rejected == 2


def test_noise_free_imu_predicts_the_rendered_extrinsics_at_every_image():
    """The truth a rendered bag carries (render.bars on the trajectory) against the propagator fed the bag's IMU
    readings without noise or bias at 2 kHz: < 1e-6 rad and 1e-7 m at every frame, moving or ringing.
    min-jerk moves: the acceleration has no step between two IMU samples (a step would be smeared over one)."""
    from nrmpc_ros.core.rig import ImuMount
    from nrmpc_ros.core.so3 import exp_so3, rotation_angle
    from nrmpc_ros.render.bagmaker import BagOptions, imu_readings
    from nrmpc_ros.render.bars import CameraLoads
    from nrmpc_ros.render.sequence import MotionOptions, make_trajectory

    rig = _rig(damping=(0.02, 0.04, 0.06))
    rig = dataclasses.replace(rig, imu=ImuMount(rotation=exp_so3(np.array([0.2, -0.1, 0.4]))))
    motion = MotionOptions(views=3, hold_seconds=1.0, rate=15, imu_rate=2000, move_seconds=0.8,
                           move_profile="min-jerk", max_step=30, min_step=20)
    traj = make_trajectory(np.random.default_rng(5), motion)
    loads = CameraLoads(rig, traj)
    assert loads.ringing and loads.zeta.tolist() == [0.02, 0.04, 0.06]
    imu_t = np.arange(traj.start_ns, traj.end_ns, 500_000, dtype=np.int64)
    opts = BagOptions(motion=motion, imu_noise=0.0, gyro_noise=0.0, imu_bias=0.0, gyro_bias=0.0)
    accel, gyro = imu_readings(rig, traj, imu_t, np.random.default_rng(0), opts, loads)
    prop = BarPropagator(rig, history_s=100.0)
    frame_t, view = traj.frame_times("stream")
    truth_w, truth_W = bent_extrinsics_at_loads(rig, loads.at(frame_t))
    for k in range(len(imu_t)):
        prop.add_imu(imu_t[k] * 1e-9, accel[k], gyro[k])
    w, W = prop.extrinsics_at(frame_t * 1e-9)
    err = rotation_angle(np.swapaxes(W, -1, -2) @ truth_W)
    moved = rotation_angle(np.swapaxes(truth_W, -1, -2) @ rig.rotations[None])
    assert (view < 0).sum() > 20 and moved.max() > 0.01, "the bars bend and ring through the moves"
    assert err.max() < 1e-6, err.max()
    assert np.abs(w - truth_w).max() < 1e-7


@pytest.mark.parametrize("imu_rate, noisy, median_deg, p90_deg", [(2000, False, 0.15, 0.4), (200, True, 0.2, 0.5),
                                                                 (50, True, 1.5, 3.5)])
def test_an_imu_on_a_bar_as_soft_as_the_others_predicts_the_rendered_extrinsics(imu_rate, noisy, median_deg,
                                                                                 p90_deg):
    """The IMU inside camera 1, whose 2.9 Hz bar is as soft as the others (all alike: the tip's ringing, read as
    the body's load, would drive them at resonance). Its readings are turned into the body's motion through
    the bar's model (core.tip_imu): median 2.8 deg off without that (noise-free, 2 kHz), 0.075 with it."""
    from nrmpc_ros.core.rig import ImuMount
    from nrmpc_ros.core.so3 import exp_so3, rotation_angle
    from nrmpc_ros.render.bagmaker import BagOptions, imu_readings
    from nrmpc_ros.render.bars import CameraLoads
    from nrmpc_ros.render.sequence import MotionOptions, make_trajectory

    rig = _rig(damping=(0.02, 0.04, 0.06))
    rig = dataclasses.replace(rig, imu=ImuMount(mount=rig.cameras[1].name,
                                                rotation=exp_so3(np.array([0.2, -0.1, 0.4]))))
    motion = MotionOptions(views=4, hold_seconds=1.5, rate=15, imu_rate=imu_rate, move_seconds=0.8,
                           move_profile="min-jerk", max_step=30, min_step=20)
    traj = make_trajectory(np.random.default_rng(5), motion)
    loads = CameraLoads(rig, traj)
    imu_t = np.arange(traj.start_ns, traj.end_ns, round(1e9 / imu_rate), dtype=np.int64)
    opts = BagOptions(motion=motion, imu_noise=0.02 * noisy, gyro_noise=0.002 * noisy, imu_bias=0.0, gyro_bias=0.0)
    accel, gyro = imu_readings(rig, traj, imu_t, np.random.default_rng(0), opts, loads)
    prop = BarPropagator(rig, history_s=100.0)
    for k in range(len(imu_t)):
        prop.add_imu(imu_t[k] * 1e-9, accel[k], gyro[k])
    frame_t, _ = traj.frame_times("stream")
    _, truth_W = bent_extrinsics_at_loads(rig, loads.at(frame_t))
    _, W = prop.extrinsics_at(frame_t * 1e-9)
    err = np.degrees(rotation_angle(np.swapaxes(W, -1, -2) @ truth_W))
    bend = np.degrees(rotation_angle(np.swapaxes(truth_W, -1, -2) @ rig.rotations[None]))
    assert np.median(bend) > 5.0, "the bars bend by degrees"
    assert np.median(err) < median_deg and np.percentile(err, 90) < p90_deg, (np.median(err), np.percentile(err, 90))


@pytest.mark.parametrize("mount", ["body", "camera"])
def test_a_shifted_specific_force_is_as_if_the_samples_had_always_carried_it(mount):
    """Shifting the specific force after the samples gives the state a propagation of the shifted samples
    gives from the start (the loads are linear in the samples): no ringing from the shift. With an IMU in a camera
    its filters' states are shifted too (no step for the next samples); the shift's own bend of the tip turns the
    reading, which is second order and left out."""
    rig = _rig()
    if mount == "camera":
        from nrmpc_ros.core.rig import ImuMount

        rig = dataclasses.replace(rig, imu=ImuMount(mount=rig.cameras[1].name))
    rng = np.random.default_rng(5)
    t = 10.0 + np.arange(600) * 0.005
    f = np.array([0.3, -0.2, 9.8]) + 0.8 * np.sin(np.outer(t, [2.0, 3.0, 5.0]))
    w = 0.4 * np.cos(np.outer(t, [1.0, 2.0, 3.0]))
    d = rng.normal(scale=0.05, size=3)
    shifted, later = BarPropagator(rig), BarPropagator(rig)
    _feed(shifted, t, f + d, w)
    _feed(later, t[:400], f[:400], w[:400])
    later.shift_specific_force(d)
    _feed(later, t[400:], f[400:] + d, w[400:])
    q = np.linspace(t[-1] - 1.5, t[-1] + 0.2, 50)
    # an IMU in a camera: the shift also turns the tip's bend, which turns the reading, by c_r |f| of the shift
    tol = 1e-9 if mount == "body" else 2.0 * rig.bar_coefficients[2][1] * np.linalg.norm(f[0]) * np.linalg.norm(d)
    assert np.abs(later.loads_at(q) - shifted.loads_at(q)).max() < tol
