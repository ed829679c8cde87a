"""The body's rotation between two holds from the gyro (frontend.gyro): bias-corrected integration over the
move, its std covering the error, the IMU's mount, and no rotation without gyro samples."""

import math

import numpy as np
import pytest

from nrmpc_ros.core.rig import ImuMount
from nrmpc_ros.core.so3 import exp_so3, rotation_angle
from nrmpc_ros.frontend.gyro import camera_turns, gyro_turn, ordered_product, rotation_between
from nrmpc_ros.frontend.imu import ImuBuffer

RATE_HZ = 200.0
AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
TURN = math.radians(25.0)


def samples(rng, bias, noise, gyro=True):
    """1 s still, a 1.5 s cosine-profile turn of TURN about AXIS (IMU frame), 1 s still: (buffer, truth)."""
    buf = ImuBuffer()
    for t in np.arange(0.0, 3.5, 1.0 / RATE_HZ):
        u = min(max((t - 1.0) / 1.5, 0.0), 1.0)
        rate = TURN * 0.5 * math.pi * math.sin(math.pi * u) / 1.5 if 0.0 < u < 1.0 else 0.0
        w = rate * AXIS + bias + rng.normal(scale=noise, size=3) if gyro else None
        buf.add(t, [0.0, 0.0, 9.81], w)
    return buf, exp_so3(TURN * AXIS)


def test_ordered_product_keeps_the_order(rng):
    Rs = exp_so3(rng.normal(size=(9, 3)))
    R = np.eye(3)
    for x in Rs:
        R = R @ x
    assert np.allclose(ordered_product(Rs), R) and np.allclose(ordered_product(Rs[:0]), np.eye(3))


@pytest.mark.parametrize("seed", range(5))
def test_the_turn_between_two_holds_is_found_within_its_std(seed):
    rng = np.random.default_rng(seed)
    buf, truth = samples(rng, bias=np.array([0.004, -0.003, 0.002]), noise=0.002)
    turn = rotation_between(buf, ImuMount(), (0.1, 0.99), (0.99, 2.6), max_age_s=0.1, scale_error=0.01)
    err = rotation_angle(truth.T @ turn.R)
    assert err < 3 * turn.sigma_rad and turn.sigma_rad < math.radians(1.0), (math.degrees(err), turn.sigma_rad)
    assert turn.sigma_rad >= 0.01 * TURN  # the scale error bounds it from below
    # the bias (0.005 rad/s) over the 1.6 s move would leave about 0.5 deg: the correction removed it
    assert err < math.radians(0.3)


@pytest.mark.parametrize("scale", [1.0, 180.0 / math.pi])
def test_the_angle_as_read_is_not_wrapped(scale):
    """The angle the rates turn as read: the turn's 25 deg for a gyro in rad/s, 57 times that (1432 deg, wrapped
    it would be 8 deg) for the same rates in deg/s: what the images' turn measures the unit by."""
    rng = np.random.default_rng(3)
    buf, _ = samples(rng, bias=np.zeros(3), noise=0.0)
    scaled = ImuBuffer()
    t, a, w = buf.window(0.0, 3.5)
    for ti, ai, wi in zip(t, a, w):
        scaled.add(float(ti), ai, scale * wi)
    turn = rotation_between(scaled, ImuMount(), (0.1, 0.99), (0.99, 2.6), max_age_s=0.1, scale_error=0.01)
    assert turn.read_angle_rad == pytest.approx(scale * TURN, rel=1e-3)


def test_the_imu_mount_turns_the_rotation_into_the_body_frame(rng):
    buf, truth = samples(rng, bias=np.zeros(3), noise=1e-4)
    M = exp_so3(np.array([0.0, 0.0, math.pi / 2]))  # IMU -> body
    turn = rotation_between(buf, ImuMount(rotation=M), (0.1, 0.99), (0.99, 2.6), max_age_s=0.1, scale_error=0.01)
    assert rotation_angle((M @ truth @ M.T).T @ turn.R) < math.radians(0.05)


def test_no_rotation_without_gyro_samples_or_inside_a_camera(rng):
    buf, _ = samples(rng, bias=np.zeros(3), noise=0.002, gyro=False)
    assert rotation_between(buf, ImuMount(), (0.1, 0.99), (0.99, 2.6), max_age_s=0.1, scale_error=0.01) is None
    buf, _ = samples(rng, bias=np.zeros(3), noise=0.002)
    inside = ImuMount(mount="cam0")
    assert rotation_between(buf, inside, (0.1, 0.99), (0.99, 2.6), max_age_s=0.1, scale_error=0.01) is None
    # the samples end early
    assert rotation_between(buf, ImuMount(), (0.1, 0.99), (0.99, 5.0), max_age_s=0.1, scale_error=0.01) is None


def test_a_move_there_and_back_carries_the_scale_error_of_the_way_travelled(rng):
    """25 deg about the axis and back: the net rotation is none, found as such, and its std still holds the
    scale-factor error of the 50 deg travelled (which would not cancel about two different axes)."""
    buf = ImuBuffer()
    for t in np.arange(0.0, 5.0, 1.0 / RATE_HZ):
        u = min(max((t - 1.0) / 1.5, 0.0), 2.0)
        rate = TURN * 0.5 * math.pi * math.sin(math.pi * u) / 1.5 if 0.0 < u < 2.0 else 0.0  # + then -
        buf.add(t, [0.0, 0.0, 9.81], rate * AXIS + rng.normal(scale=0.002, size=3))
    turn = rotation_between(buf, ImuMount(), (0.1, 0.99), (0.99, 4.1), max_age_s=0.1, scale_error=0.01)
    assert rotation_angle(turn.R) < 3.0 * turn.sigma_rad and rotation_angle(turn.R) < math.radians(0.1)
    assert turn.sigma_rad >= 0.01 * 2.0 * TURN * 0.99


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("lost", [(1.2, 1.23), (1.6, 1.9), (1.1, 2.2)], ids=["30 ms", "0.3 s", "1.1 s"])
def test_a_gap_in_the_moves_samples_is_bridged_with_what_the_rate_may_have_done(seed, lost):
    """A stretch of the move's samples lost (a link that dropped them): the turn is bridged by the mean of the
    rates either side, its std grown by what the rate may have done meanwhile (the move's own changes over as
    long). The truth stays within 3 of the std; a 30 ms gap costs little (the std within 1.5 times the one
    without the gap), and a 1.1 s gap of a 1.5 s move leaves a std that covers what it does not know."""
    rng = np.random.default_rng(seed)
    full, truth = samples(rng, bias=np.array([0.004, -0.003, 0.002]), noise=0.002)
    whole = rotation_between(full, ImuMount(), (0.1, 0.99), (0.99, 2.6), max_age_s=0.1, scale_error=0.01)
    t, a, w = full.window(0.0, 3.5)
    buf = ImuBuffer()
    for k in np.flatnonzero((t < lost[0]) | (t > lost[1])):
        buf.add(t[k], a[k], w[k])
    assert buf.gaps
    turn = rotation_between(buf, ImuMount(), (0.1, 0.99), (0.99, 2.6), max_age_s=0.1, scale_error=0.01)
    err = rotation_angle(truth.T @ turn.R)
    assert err < 3 * turn.sigma_rad, (math.degrees(err), math.degrees(turn.sigma_rad))
    assert turn.sigma_rad >= whole.sigma_rad
    if lost[1] - lost[0] < 0.05:
        assert turn.sigma_rad < 1.5 * whole.sigma_rad
    # the still part's gaps play no part
    still_gap = ImuBuffer()
    for k in np.flatnonzero((t < 0.3) | (t > 0.6)):
        still_gap.add(t[k], a[k], w[k])
    other = rotation_between(still_gap, ImuMount(), (0.7, 0.99), (0.99, 2.6), max_age_s=0.1, scale_error=0.01)
    assert other is not None and still_gap.gaps


def test_gyro_turn_between_frames_integrates_the_rate_over_the_interval(rng):
    """Piecewise-constant integration over [t0, t1] (interior of the cosine turn, frame times off the sample
    grid) matches the truth; None where the samples do not cover the interval or inside a camera."""
    buf, _ = samples(rng, bias=np.zeros(3), noise=0.0)

    def angle(t):  # the cosine profile's angle turned by time t
        u = min(max((t - 1.0) / 1.5, 0.0), 1.0)
        return TURN * 0.5 * (1.0 - math.cos(math.pi * u))

    for t0 in (1.3013, 1.8421, 2.2007):
        t1 = t0 + 1.0 / 30.0
        R = gyro_turn(buf, ImuMount(), t0, t1)
        truth = exp_so3((angle(t1) - angle(t0)) * AXIS)
        # a held rate errs by about half a sample's change of angle per step: far below 1e-4 rad here
        assert rotation_angle(truth.T @ R) < 1e-4
    assert gyro_turn(buf, ImuMount(), 3.3, 3.6) is None  # the samples end more than a period before t1
    # the newest sample's rate holds up to t1 when it is less than a sample period old
    last = 1.0 + 1.5 * 0.4  # inside the turn, the frame stamp just after a sample
    t_last = buf.window(0.0, last)[0][-1]
    assert last - t_last < 1.0 / RATE_HZ
    R = gyro_turn(ImuBufferUpTo(buf, t_last), ImuMount(), last - 1.0 / 30.0, last)
    assert R is not None and rotation_angle(exp_so3((angle(last) - angle(last - 1.0 / 30.0)) * AXIS).T @ R) < 1e-3
    # an IMU inside a camera: the turn of that camera's frame, the same integral through the mount's rotation
    in_camera = gyro_turn(buf, ImuMount(mount="cam0"), 1.3, 1.4)
    assert in_camera is not None and rotation_angle(gyro_turn(buf, ImuMount(), 1.3, 1.4).T @ in_camera) < 1e-12
    M = exp_so3(np.array([0.0, 0.0, math.pi / 2]))  # IMU -> body
    R = gyro_turn(buf, ImuMount(rotation=M), 1.3, 1.4)
    assert rotation_angle((M @ gyro_turn(buf, ImuMount(), 1.3, 1.4) @ M.T).T @ R) < 1e-12


class ImuBufferUpTo:
    """The samples of a buffer up to a stamp (those after it have not arrived yet)."""

    def __init__(self, buf, t_end):
        self.buf, self.t_end, self.period_s = buf, t_end, buf.period_s

    def window(self, t0, t1):
        return self.buf.window(t0, min(t1, self.t_end))


def test_camera_turns_compose_the_body_turn_with_the_bending(rng):
    """A world direction seen by each camera at t0 and t1: f1 = R f0 with R from camera_turns."""
    R_body = exp_so3(rng.normal(size=3) * 0.1)  # p_t0 = R_body p_t1
    W0, W1 = exp_so3(rng.normal(size=(4, 3))), exp_so3(rng.normal(size=(4, 3)))  # camera -> body
    d0 = rng.normal(size=3)  # a direction in the body frame at t0
    f0 = np.einsum("mji,j->mi", W0, d0)
    f1 = np.einsum("mji,j->mi", W1, R_body.T @ d0)
    np.testing.assert_allclose(np.einsum("mij,mj->mi", camera_turns(R_body, W0, W1), f0), f1, atol=1e-12)


@pytest.mark.parametrize("imu_rate", [50.0, 1000.0])
def test_camera_turns_follow_the_bars_ringing_through_a_hold(imu_rate):
    """Soft bars (1.5 Hz, damping 0.03) ring for seconds after every stop: between two frames a camera turns by
    up to degrees while the body is still. The bars' candidate (the bars' state driven by the raw samples, a
    biased accelerometer and gyro included) predicts each camera's turn between its images to a small share of it; the
    gyro's alone misses the ringing. The truth is the renderer's own integration of the bars along the
    trajectory, not the samples."""
    from nrmpc_ros.core.bar_state import BarPropagator
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics
    from nrmpc_ros.frontend.gyro import CameraTurns
    from nrmpc_ros.render.bagmaker import BagOptions, imu_readings
    from nrmpc_ros.render.bars import CameraLoads, bent_extrinsics
    from nrmpc_ros.render.sequence import MotionOptions, make_trajectory
    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.2))
    rng = np.random.default_rng(5)
    traj = make_trajectory(rng, MotionOptions(views=3, rate=10.0, imu_rate=imu_rate, capture="stream"))
    loads = CameraLoads(rig, traj, damping=0.03)
    imu_t = np.arange(traj.start_ns, traj.end_ns, int(round(1e9 / imu_rate)), dtype=np.int64)
    accel, gyro = imu_readings(rig, traj, imu_t, rng, BagOptions(imu_noise=0.0, gyro_noise=0.0, imu_bias=0.05,
                                                                 gyro_bias=0.002), loads)
    buf, bars = ImuBuffer(), BarPropagator(rig, damping=0.03)  # as a rig file that gives bar.damping
    turns = CameraTurns(buf, rig.imu, FrameExtrinsics(rig), rig.num_cameras, bars=bars)
    frames, view = traj.frame_times("stream")
    R_true, _, _, _ = traj.state(frames)
    _, W_true = bent_extrinsics(rig, loads.at(frames))
    j, err_bars, err_gyro, ringing = 0, [], [], []
    for k, t_ns in enumerate(frames):
        while j < len(imu_t) and imu_t[j] <= t_ns:  # the samples up to the frame are in
            buf.add(imu_t[j] * 1e-9, accel[j], gyro[j])
            bars.add_imu(imu_t[j] * 1e-9, accel[j], gyro[j])
            j += 1
        out = turns.advance(t_ns * 1e-9, taken=[t_ns * 1e-9] * rig.num_cameras)
        if k == 0:
            assert all(o is None for o in out)
            continue
        if view[k] < 0 or view[k - 1] != view[k]:
            continue  # inside holds: the body is still, only the bars turn the cameras
        truth = camera_turns(R_true[k - 1].T @ R_true[k], W_true[k - 1], W_true[k])
        for i, cands in enumerate(out):
            assert cands.shape == (2, 3, 3)
            ringing.append(rotation_angle(truth[i]))
            err_gyro.append(rotation_angle(truth[i].T @ cands[0]))
            err_bars.append(rotation_angle(truth[i].T @ cands[1]))
    ringing, err_gyro, err_bars = (np.degrees(x) for x in (ringing, err_gyro, err_bars))
    big = ringing > 0.5
    assert big.sum() >= 10, ringing.max()
    # a few per cent of the turn; the load held linear between samples smears the stop's acceleration jump over
    # one IMU period (20 ms at 50 Hz): up to a fifth there, a fraction of a pixel for KLT's start
    share = err_bars[big] / ringing[big]
    assert np.median(share) <= 0.05 and share.max() <= 0.2, (np.median(share), share.max())
    assert np.median(err_gyro[big] / ringing[big]) > 0.9


def test_an_imu_inside_a_camera_predicts_that_cameras_turn_and_through_the_bars_the_others_in_moves():
    """The IMU inside the second camera, on a soft bar (damping 0.03), 200 Hz: its gyro is that camera's own turn
    (a few per cent of it off, in holds where only the bar turns it and through the moves), and the body's turn
    it implies, taken through the bent rotations, starts the other cameras through the moves within a third of
    their turn. Before, an IMU inside a camera gave no candidate at all."""
    from nrmpc_ros.core.bar_state import BarPropagator
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics
    from nrmpc_ros.frontend.gyro import CameraTurns
    from nrmpc_ros.render.bagmaker import BagOptions, imu_readings
    from nrmpc_ros.render.bars import CameraLoads, bent_extrinsics
    from nrmpc_ros.render.sequence import MotionOptions, make_trajectory
    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.2)).with_imu_in("cam1")
    rng = np.random.default_rng(5)
    traj = make_trajectory(rng, MotionOptions(views=3, rate=10.0, imu_rate=200.0, capture="stream"))
    loads = CameraLoads(rig, traj, damping=0.03)
    imu_t = np.arange(traj.start_ns, traj.end_ns, int(round(1e9 / 200.0)), dtype=np.int64)
    accel, gyro = imu_readings(rig, traj, imu_t, rng, BagOptions(imu_noise=0.0, gyro_noise=0.0, imu_bias=0.05,
                                                                 gyro_bias=0.002), loads)
    buf, bars = ImuBuffer(), BarPropagator(rig, damping=0.03)
    turns = CameraTurns(buf, rig.imu, FrameExtrinsics(rig), rig.num_cameras, bars=bars)
    frames, view = traj.frame_times("stream")
    R_true, _, _, _ = traj.state(frames)
    _, W_true = bent_extrinsics(rig, loads.at(frames))
    j, rows = 0, []
    for k, t_ns in enumerate(frames):
        while j < len(imu_t) and imu_t[j] <= t_ns:
            buf.add(imu_t[j] * 1e-9, accel[j], gyro[j])
            bars.add_imu(imu_t[j] * 1e-9, accel[j], gyro[j])
            j += 1
        out = turns.advance(t_ns * 1e-9, taken=[t_ns * 1e-9] * rig.num_cameras)
        if k == 0:
            continue
        truth = camera_turns(R_true[k - 1].T @ R_true[k], W_true[k - 1], W_true[k])
        in_hold = view[k] >= 0 and view[k - 1] == view[k]
        for i, cands in enumerate(out):
            assert cands is not None and cands.shape == (2, 3, 3)
            rows.append((in_hold, i, rotation_angle(truth[i]), rotation_angle(truth[i].T @ cands[1])))
    hold, cam, turn, err = (np.array(c) for c in zip(*rows))
    share = err / np.maximum(turn, 1e-12)
    for still in (True, False):
        assert np.median(share[(cam == 1) & (hold == still)]) <= 0.1
    assert np.median(share[(cam != 1) & ~hold]) <= 0.35
