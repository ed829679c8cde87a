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
    assert out.significant == (late_s != 0.0), out  # advised only where the clocks differ


def test_no_move_no_offset():
    est = ImuClockEstimator()
    rng = np.random.default_rng(0)
    for t in np.arange(0.0, 10.0, 0.005):
        est.add_imu(t, rng.normal(0, 0.002, 3))
    for a in np.arange(0.5, 9.5, 0.1):
        est.add_frame(a, a + 0.1, [abs(rng.normal(0, 0.001))])
    assert est.estimate() is None


def test_images_ringing_after_moves_they_skipped_give_no_offset():
    """Cameras that record only the holds (the moves themselves skipped), the bars ringing after each stop: the
    images move while the gyro holds still, and the ends of the gyro's moves shifted into the first frames correlate
    with that ringing. No move lies inside the frames, so no offset is read (not one of -0.2 s)."""
    rng = np.random.default_rng(5)
    est = ImuClockEstimator()
    for t in np.arange(0.0, 30.0, 0.005):
        est.add_imu(t, (_rate(t) + rng.normal(0, 0.002), rng.normal(0, 0.002), 0.0))
    for a in np.arange(1.0, 29.0, 0.25):
        if np.mod(a, 3.0) >= 1.0:  # a hold's frames, the bars ringing down from each stop at 1 s of 3
            since_stop = np.mod(a, 3.0) - 1.0
            est.add_frame(a, a + 0.25, [0.2 * np.exp(-since_stop / 0.4) + abs(rng.normal(0, 0.001))])
    assert est.estimate() is None


def _rendered_rates(rig, late_s, seed=2, views=6, signed=False, noisy=True, estimator_rig=..., capture="stream",
                    gyro_unit=1.0):
    """A rendered trajectory's IMU (``noisy``: a MEMS-grade noise; its rates in units of ``gyro_unit`` rad/s),
    stamped ``late_s`` after the truth, and each
    bent camera's image rate across its optical axis per frame interval (no pixels), with ``signed`` also the
    image's signed motion (x, y): an estimator for ``estimator_rig`` (default ``rig``) fed with both. ``capture``:
    the frames of make-bag's capture mode (with "holds" an interval spans each move, as a pipeline passes it on)."""
    from nrmpc_ros.core.bar_state import bent_extrinsics_at_loads
    from nrmpc_ros.core.so3 import log_so3
    from nrmpc_ros.render.bagmaker import BagOptions, imu_readings
    from nrmpc_ros.render.bars import CameraLoads
    from nrmpc_ros.render.sequence import MotionOptions, make_trajectory

    motion = MotionOptions(views=views, hold_seconds=2.0, rate=15, imu_rate=200, move_profile="trapezoid",
                           min_step=15, max_step=30, speed=40.0)
    traj = make_trajectory(np.random.default_rng(seed), motion)
    loads = CameraLoads(rig, traj)
    imu_t = np.arange(traj.start_ns, traj.end_ns, 5_000_000, dtype=np.int64)
    opts = BagOptions(motion=motion, imu_noise=0.02 * noisy, gyro_noise=0.002 * noisy, imu_bias=0.0, gyro_bias=0.0)
    accel, gyro = imu_readings(rig, traj, imu_t, np.random.default_rng(0), opts, loads)
    frames, _ = traj.frame_times(capture)
    R, _, _, _ = traj.state(frames)
    _, W = bent_extrinsics_at_loads(rig, loads.at(frames))
    cam = R[:, None] @ W
    turn = log_so3(np.swapaxes(cam[:-1], -1, -2) @ cam[1:])
    dt = (np.diff(frames) * 1e-9)[:, None]
    across = np.linalg.norm(turn[..., :2], axis=-1) / dt
    shifts = np.stack([-turn[..., 1], turn[..., 0]], axis=-1) / dt[..., None]  # the scene's shift in each image
    est = ImuClockEstimator(rig if estimator_rig is ... else estimator_rig)
    for k in range(len(imu_t)):
        est.add_imu(imu_t[k] * 1e-9 + late_s, gyro[k] / gyro_unit, accel[k])
    for k in range(len(frames) - 1):
        est.add_frame(frames[k] * 1e-9, frames[k + 1] * 1e-9, across[k], shifts[k] if signed else None)
    return est


def _ring3():
    import dataclasses

    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.25, mass=0.1, bar_length=0.3))
    return dataclasses.replace(rig, cameras=tuple(dataclasses.replace(c, damping=0.04) for c in rig.cameras))


def test_bent_cameras_lag_the_body_and_the_refinement_reads_the_clock_not_the_bars():
    """A rendered trajectory (no pixels): each camera's image rotates with the body AND its ringing bar. The
    gyro's rate alone reads the bars' lag as a clock offset; against the bent cameras the IMU's true lateness
    comes out to a millisecond."""
    rig = _ring3()
    late = 0.018
    results = {name: _rendered_rates(rig, late, views=5, noisy=False, estimator_rig=r).estimate()
               for name, r in (("gyro only", None), ("bent cameras", rig))}
    assert results["bent cameras"].offset_s == pytest.approx(-late, abs=1e-3), results
    assert results["bent cameras"].significant, results  # 18 ms beyond two stds of a 15 Hz camera's timing
    assert abs(results["gyro only"].offset_s + late) > 3e-3, "the bars' lag biases the gyro-only estimate"


def test_bars_the_estimate_cannot_model_widen_the_offset_by_their_response_time():
    """The same rig known without its IMU's mount: the bars' response cannot be predicted, the images lead or lag
    the body by up to the slowest bar's response time, and an 18 ms lateness is no evidence within it."""
    import dataclasses

    from nrmpc_ros.core.dynamics import bar_natural_frequencies

    rig = _ring3()
    out = _rendered_rates(rig, 0.018, views=5, noisy=False, estimator_rig=dataclasses.replace(rig, imu=None)).estimate()
    response_s = 1.0 / (2 * np.pi * bar_natural_frequencies(rig).min())
    assert out is not None and out.std_s >= response_s and not out.significant


@pytest.mark.parametrize("seed", [2, 3])
def test_cameras_that_record_only_the_holds_read_no_lag_from_the_bars_ringing(seed):
    """Cameras that record the holds only, on ringing bars: the first frames of each hold move with the bars while
    the body holds still. Shifted a few tens of ms later, the ends of the gyro's moves line up with that ringing,
    and the bent cameras' correlation peaks again every half period of the bars: the clock is the best of all
    those peaks (here the truth, 0), not the one next to the body's."""
    rig = _ring3()
    out = _rendered_rates(rig, 0.0, seed=seed, views=6, capture="holds").estimate()
    assert out is not None and not out.significant and abs(out.offset_s) < 0.01, out


@pytest.mark.parametrize("signed", [False, True])
@pytest.mark.parametrize("late_s", [2.3, -4.1, 0.0])
def test_an_imu_clock_seconds_off_is_found_by_the_far_search(late_s, signed):
    """An IMU stamped seconds late or early: the far search finds the offset to a frame's fraction, singled out
    by the moves' axes (the gyro's rate magnitude alone correlates almost as well one hold-and-move later), from
    the images' motion across their axes or from their signed motion; the small-lag search cannot reach it."""
    from nrmpc_ros.frontend.imu_clock import MAX_LAG_S

    est = _rendered_rates(_ring3(), late_s, signed=signed)
    far = est.far_offset(10.0)
    assert far is not None and far.unique, far
    assert far.offset_s == pytest.approx(-late_s, abs=0.03)  # the bars' own lag is left to estimate()
    assert far.correlation > 0.9 and far.rival_correlation < far.correlation - 0.2
    near = est.estimate()
    if abs(late_s) > MAX_LAG_S:
        assert near is None or abs(near.offset_s + late_s) > 0.5


def test_identical_moves_leave_the_far_lag_open():
    """A rig that makes the same move about the same axis at a fixed period: every period's shift correlates as
    well, and the far search says the lag is not singled out rather than pick one."""
    import dataclasses

    est = ImuClockEstimator(dataclasses.replace(_ring3()))
    rng = np.random.default_rng(1)
    late = 3.0  # one period
    for t in np.arange(0.0, 40.0, 0.005):
        est.add_imu(t + late, (_rate(t) + rng.normal(0, 0.002), rng.normal(0, 0.002), 0.0))
    frames = np.arange(0.5, 39.5, 1 / 15)
    fine = np.linspace(0, 1, 50)
    for a, b in zip(frames[:-1], frames[1:]):
        mean = _rate(a + (b - a) * fine).mean()
        est.add_frame(a, b, [mean * (1 + rng.normal(0, 0.05)) + abs(rng.normal(0, 0.003))] * 3)
    far = est.far_offset(10.0)
    assert far is not None and not far.unique, far


@pytest.mark.parametrize("cameras, imu_camera, seed", [(3, 1, 2), (4, 2, 5), (6, 4, 2), (6, 4, 3)])
def test_an_imu_inside_a_camera_on_a_swinging_bar_finds_no_far_offset(cameras, imu_camera, seed):
    """An IMU inside a camera on a 1.5 Hz bar (damping 0.03) reads its tip's swing, not the body's specific
    force: bars driven by it ring as nothing does, and a scan of their prediction over seconds of lags finds
    chance peaks in the ringing (a whole second off here). The far search then reads the body's turn alone:
    with the stamps right its peak stays within a lag of zero."""
    import dataclasses
    import math

    from nrmpc_ros.frontend.imu_clock import MAX_LAG_S
    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    mass, length = 0.1, 0.3
    rig = make_rig(RigSpec(num_cameras=cameras, layout="ring", EI=(2 * math.pi * 1.5) ** 2 * mass * length ** 3 / 3,
                           mass=mass, bar_length=length))
    rig = dataclasses.replace(rig, cameras=tuple(dataclasses.replace(c, damping=0.03) for c in rig.cameras))
    rig = rig.with_imu_in(rig.cameras[imu_camera].name)
    far = _rendered_rates(rig, 0.0, seed=seed, signed=True).far_offset(10.0)
    assert far is None or abs(far.offset_s) <= MAX_LAG_S, far


def test_the_estimate_is_computed_again_only_once_samples_or_frames_came():
    """Replay asks for the lag to apply it and again to report it: the second answer is the first, unless the
    estimator received more since."""
    rng = np.random.default_rng(7)
    est = ImuClockEstimator()
    for t in np.arange(0.0, 30.0, 0.005):
        est.add_imu(t + 0.02, (_rate(t) + rng.normal(0, 0.002), rng.normal(0, 0.002), 0.0))
    frames = np.arange(0.5, 29.5, 1 / 15)
    for a, b in zip(frames[:-1], frames[1:]):
        est.add_frame(a, b, [_rate(a + (b - a) * np.linspace(0, 1, 50)).mean()])
    first = est.estimate()
    assert first is not None and est.estimate() is first
    est.add_imu(30.1, (0.0, 0.0, 0.0))
    again = est.estimate()
    assert again is not first and again.offset_s == pytest.approx(first.offset_s, abs=1e-3)
