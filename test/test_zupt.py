"""Zero-velocity detection: still rigs, creep, vibration, holds between moves, rates, noise sources, gaps, online."""

import dataclasses
import math

import numpy as np
import pytest

from nrmpc_ros.core.deformation import bend_rotation_vectors
from nrmpc_ros.core.dynamics import bar_damping_ratios, bar_natural_frequencies
from nrmpc_ros.core.rig import ImuMount
from nrmpc_ros.core.so3 import exp_so3, right_jacobian, skew
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.imu import ImuReject
from nrmpc_ros.frontend.mount_ringing import MountBar, static_bend
from nrmpc_ros.frontend.noise_correlation import mean_variance_factor
from nrmpc_ros.frontend.steady_turn import steady_turn
from nrmpc_ros.frontend.zupt import (
    ImuNoise,
    NoiseSource,
    ZuptConfig,
    ZuptDetector,
    claim_disputed,
    describe_noise,
    estimate_noise,
    for_rig,
    still_intervals,
    still_mask,
    still_statistic,
)

BIAS = np.array([0.003, -0.002, 0.001])  # rad/s
AXIS = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])


def trace(rng, rate, plan, accel_sigma=0.02, gyro_sigma=0.002, bias=BIAS):
    """IMU samples of a rig that holds and moves: plan = [("hold" | "move", seconds), ...].

    A move turns the rig about a fixed axis (rate 0.6 sin^2 rad/s) while it
    translates back and forth (1 m/s^2 sin); the accelerometer reads the specific
    force in the turned body frame. Returns t, accel, gyro and the true holds.
    """
    t = np.arange(0.0, sum(d for _, d in plan), 1.0 / rate)
    w, lin, holds, t0 = np.zeros((len(t), 3)), np.zeros((len(t), 3)), [], 0.0
    for kind, d in plan:
        m = (t >= t0) & (t < t0 + d)
        tau = (t[m] - t0) / d
        if kind == "move":
            w[m] = 0.6 * np.sin(np.pi * tau)[:, None] ** 2 * AXIS
            lin[m] = np.sin(2 * np.pi * tau)[:, None] * np.array([1.0, 0.4, 0.0])
        else:
            holds.append((t0, t0 + d))
        t0 += d
    rate_norm = np.linalg.norm(w, axis=1)
    angle = np.concatenate([[0.0], np.cumsum(0.5 * (rate_norm[1:] + rate_norm[:-1]) * np.diff(t))])
    R = exp_so3(angle[:, None] * AXIS)  # body -> world
    accel = np.einsum("nji,nj->ni", R, lin + np.array([0.0, 0.0, 9.81]))
    accel = accel + rng.normal(scale=accel_sigma, size=accel.shape)
    gyro = w + bias + rng.normal(scale=gyro_sigma, size=w.shape)
    return t, accel, gyro, holds


def still_trace(rng, rate=200.0, seconds=10.0, accel_sigma=0.02, gyro_sigma=0.002):
    t = np.arange(0.0, seconds, 1.0 / rate)
    accel = np.array([0.2, -0.1, 9.8]) + rng.normal(scale=accel_sigma, size=(len(t), 3))
    gyro = BIAS + rng.normal(scale=gyro_sigma, size=(len(t), 3))
    return t, accel, gyro


def test_still_rig_with_noise_and_bias_is_still(rng):
    t, a, w = still_trace(rng, seconds=20.0)
    noise = estimate_noise(t, a, w)
    assert noise.source == "data"
    assert noise.accel_sigma == pytest.approx(0.02, rel=0.1)
    assert noise.gyro_sigma == pytest.approx(0.002, rel=0.1)
    assert np.abs(noise.gyro_bias - BIAS).max() < 3e-4
    assert noise.accel_norm == pytest.approx(np.linalg.norm([0.2, -0.1, 9.8]), abs=0.01)
    assert noise.period_s == pytest.approx(0.005)
    assert still_intervals(t, a, w, noise) == [(t[0], t[-1])]
    assert still_mask(t, a, w, noise).all()


@pytest.mark.parametrize("deg_s, still", [(0.5, False), (0.01, True)])
def test_slow_creep(rng, deg_s, still):
    """7 s still, then a constant rotation: 0.5 deg/s is motion, 0.01 deg/s is below the detection limit.

    A constant rate looks like gyro bias; the bias estimate follows the majority of the quietest windows,
    here the still part.
    """
    t, a, w = still_trace(rng)
    w[t >= 7.0] += math.radians(deg_s) * np.array([0.0, 0.0, 1.0])
    noise = estimate_noise(t, a, w)
    iv = still_intervals(t, a, w, noise)
    if still:
        assert iv == [(t[0], t[-1])]
    else:
        assert np.abs(noise.gyro_bias - BIAS).max() < 3e-4
        assert len(iv) == 1 and iv[0][0] == t[0] and abs(iv[0][1] - 7.0) < 0.1
        assert not still_mask(t, a, w, noise)[t > 7.1].any()


def test_vibration_is_not_still(rng):
    t, a, w = still_trace(rng)
    vib = (t > 4.0) & (t < 6.0)
    a[vib, 0] += 0.3 * np.sin(2 * np.pi * 20.0 * t[vib])  # 20 Hz, 0.3 m/s^2
    noise = estimate_noise(t, a, w)
    iv = still_intervals(t, a, w, noise)
    assert len(iv) == 2 and abs(iv[0][1] - 4.0) < 0.1 and abs(iv[1][0] - 6.0) < 0.1
    assert not still_mask(t, a, w, noise)[(t > 4.05) & (t < 5.95)].any()


@pytest.mark.parametrize("rate", [100.0, 400.0])
def test_holds_between_moves(rng, rate):
    plan = [("hold", 3.0), ("move", 1.5), ("hold", 2.0), ("move", 1.0), ("hold", 0.15), ("move", 1.0), ("hold", 3.0)]
    t, a, w, holds = trace(rng, rate, plan)
    cfg = ZuptConfig()
    noise = estimate_noise(t, a, w, cfg)
    iv = still_intervals(t, a, w, noise, cfg)
    # a still run is a hold less one window (the windows around its ends see the moves), and lasts one window at
    # least: the 0.15 s pause is too short to report
    expected = [h for h in holds if h[1] - h[0] >= 2 * cfg.window_s]
    assert len(iv) == len(expected) == 3
    for (f0, f1), (h0, h1) in zip(iv, expected):
        assert h0 - 1.0 / rate <= f0 <= h0 + cfg.window_s
        assert h1 - cfg.window_s <= f1 <= h1
    stat = still_statistic(t, a, w, noise, cfg)
    assert stat.shape == t.shape and np.nanmax(stat) > 100  # moves are far above the threshold


@pytest.mark.parametrize("bias_deg_s", [3.4, 17.0])
def test_an_uncalibrated_gyros_bias_of_degrees_per_second_is_bias_not_motion(rng, bias_deg_s):
    """A consumer MEMS gyro's zero-rate offset is specified within 20 deg/s: at 3.4 deg/s (beyond the earlier
    3 deg/s bound) every window read as motion and no hold was found. The holds are found as with a calibrated
    gyro, and the bias is the gyro's."""
    plan = [("hold", 3.0), ("move", 1.5), ("hold", 2.0), ("move", 1.0), ("hold", 3.0)]
    bias = math.radians(bias_deg_s) * np.array([0.6, -0.48, 0.64])
    t, a, w, holds = trace(rng, 200.0, plan, bias=bias)
    noise = estimate_noise(t, a, w)
    assert np.abs(noise.gyro_bias - bias).max() < 3e-4
    iv = still_intervals(t, a, w, noise)
    assert len(iv) == len(holds) == 3
    for (f0, f1), (h0, h1) in zip(iv, holds):
        assert h0 - 0.005 <= f0 <= h0 + ZuptConfig().window_s and h1 - ZuptConfig().window_s <= f1 <= h1


def test_single_still_sample_between_moves_is_no_interval(rng):
    t, a, w, _ = trace(rng, 200.0, [("move", 1.0), ("move", 1.0)], accel_sigma=0.0, gyro_sigma=0.0, bias=np.zeros(3))
    k = int(np.argmin(np.abs(t - 1.0)))  # between the moves the rate is zero for one sample
    noise = ImuNoise(0.02, 0.002, np.zeros(3), "covariance", 9.81, 0.005)
    assert np.linalg.norm(w[k]) < 1e-12
    assert still_intervals(t, a, w, noise) == []
    assert not still_mask(t, a, w, noise)[k]


def test_noise_free_imu_uses_the_floors(rng):
    plan = [("hold", 2.0), ("move", 1.0), ("hold", 2.0)]
    t, a, w, holds = trace(rng, 200.0, plan, accel_sigma=0.0, gyro_sigma=0.0, bias=np.zeros(3))
    noise = estimate_noise(t, a, w)
    assert noise.accel_sigma < 1e-6 and noise.gyro_sigma < 1e-6
    iv = still_intervals(t, a, w, noise)
    assert len(iv) == 2 and iv[0][1] < 2.0 and iv[1][0] > 3.0


def vibrating_trace(rng, rate, hz, rms):
    """:func:`trace` of three holds and two moves under a motor's vibration of ``rms`` m/s^2 at ``hz``: on each
    accelerometer axis a sine of its own amplitude and phase, and the gyro's rocking with it (a pivot 0.2 m away)."""
    t, a, w, holds = trace(rng, rate, [("hold", 3.0), ("move", 1.0), ("hold", 3.0), ("move", 1.2), ("hold", 3.0)])
    shake = np.sqrt(2.0) * rms * np.array([0.6, 0.5, 0.62]) / np.linalg.norm([0.6, 0.5, 0.62])
    a = a + shake * np.sin(2 * np.pi * hz * t[:, None] + np.array([0.3, 1.9, 4.0]))
    w = w + shake / (0.2 * 2 * np.pi * hz) * np.sin(2 * np.pi * hz * t[:, None] + np.array([2.1, 0.4, 5.0]))
    return t, a, w, holds


@pytest.mark.parametrize("rate, hz, rms", [(50.0, 20.0, 0.3), (100.0, 30.0, 0.5), (200.0, 45.0, 1.5),
                                           (200.0, 120.0, 2.0), (1000.0, 35.0, 1.0), (1000.0, 150.0, 3.0),
                                           (100.0, 8.0, 0.5), (200.0, 12.0, 0.5), (100.0, 95.0, 0.5)])
def test_a_motors_vibration_the_covariances_do_not_claim_is_noise_not_motion(rng, rate, hz, rms):
    """A motor running all along (an engine, idling propellers) shakes the accelerometer by tenths to whole
    m/s^2 at tens to hundreds of Hz; the Imu messages' covariances claim the sensor's noise alone, and where the
    vibration is slow beside the samples their steps do not show it either. The quietest windows' samples
    vibrate (a periodic correlation): their spread is taken as noise, and the holds are found whole. A
    vibration slower than a window (an engine at idle, 8-12 Hz; 95 Hz read at 100 Hz, aliased to 5) returns
    within four windows' lags, and the gyro's bias is its mean over the still samples, not the quietest
    windows' means (which catch its rocking at one phase)."""
    t, a, w, holds = vibrating_trace(rng, rate, hz, rms)
    cov_a, cov_w = (np.eye(3) * 0.02 ** 2).ravel(), (np.eye(3) * 0.002 ** 2).ravel()
    noise = estimate_noise(t, a, w, covariance=(cov_a, cov_w))
    assert noise.source is NoiseSource.VIBRATION and noise.claimed == (0.02, 0.002)
    assert np.abs(noise.gyro_bias - BIAS).max() < 1e-3  # the rocking at no one phase
    assert "vibrate at" in describe_noise(noise, ZuptConfig())
    found = still_intervals(t, a, w, noise)
    assert len(found) == len(holds)
    for (f0, f1), (h0, h1) in zip(found, holds):  # a move's first and last 0.25 s turn slower than the rocking
        assert h0 - 0.25 <= f0 < h0 + 0.3 and h1 - 0.3 < f1 <= h1 + 0.25
    quiet = estimate_noise(*still_trace(rng, rate=rate), covariance=(cov_a, cov_w))
    assert quiet.source is NoiseSource.COVARIANCE  # no vibration: the claim stands


@pytest.mark.parametrize("rate, hz, rms", [(50.0, 20.0, 0.3), (200.0, 45.0, 1.5), (400.0, 45.0, 1.5),
                                           (200.0, 12.0, 0.5), (1000.0, 35.0, 1.0)])
def test_under_a_vibration_a_still_run_ends_where_the_move_starts(rate, hz, rms):
    """A vibration's rocking makes the gyro's noise per sample degrees a second: the windows' sum of squares
    takes a move's first and last tenths of a second (turning at a degree a second) for noise, and the still
    run they join turns through its span, so the steady-turn test refuses the hold (a snapshot 0.8 s after its
    stop: 6 of 7 holds lost). The rocking's sine averages out of a window's mean rate, which sees those ends: each
    run ends within 0.08 s of its hold, and no run turns."""
    rng = np.random.default_rng(3)
    t, a, w, holds = vibrating_trace(rng, rate, hz, rms)
    cov_a, cov_w = (np.eye(3) * 0.02 ** 2).ravel(), (np.eye(3) * 0.002 ** 2).ravel()
    noise = estimate_noise(t, a, w, covariance=(cov_a, cov_w))
    found = still_intervals(t, a, w, noise)
    assert len(found) == len(holds)
    for (f0, f1), (h0, h1) in zip(found, holds):
        assert h0 - 0.08 <= f0 and f1 <= h1 + 0.08
        inside = (t >= f0) & (t <= f1)
        assert not steady_turn(t[inside], w[inside], noise, ZuptConfig()).turning


def test_noise_from_covariance_or_data(rng):
    t, a, w, holds = trace(rng, 200.0, [("hold", 3.0), ("move", 1.0), ("hold", 3.0)])
    cov_a, cov_w = (np.eye(3) * 0.02 ** 2).ravel(), (np.eye(3) * 0.002 ** 2).ravel()
    from_cov = estimate_noise(t, a, w, covariance=(cov_a, cov_w))
    assert from_cov.source == "covariance" and from_cov.claimed == (0.02, 0.002)
    # the claim stands, raised at most to the white noise the samples show (a few percent of scatter)
    assert 0.02 <= from_cov.accel_sigma < 0.022 and 0.002 <= from_cov.gyro_sigma < 0.0022
    assert np.abs(from_cov.gyro_bias - BIAS).max() < 3e-4  # the bias always comes from the data
    from_data = estimate_noise(t, a, w)
    assert from_data.source == "data"
    assert from_data.gyro_sigma == pytest.approx(0.002, rel=0.15)
    unknown = np.zeros(9)
    unknown[0] = -1.0
    for cov in [(unknown, cov_w), (cov_a, np.zeros(9)), None]:  # unknown covariances: estimated from the data
        assert estimate_noise(t, a, w, covariance=cov).source == "data"
    a_cov = still_intervals(t, a, w, from_cov)
    a_data = still_intervals(t, a, w, from_data)
    assert len(a_cov) == len(a_data) == 2
    assert np.allclose(a_cov, a_data, atol=0.05)
    with pytest.raises(InputError, match="angular_velocity"):
        estimate_noise(t, a, w, covariance=(cov_a, np.ones(4)))


def test_gap_breaks_a_still_run_and_nan_samples_are_skipped(rng):
    t, a, w = still_trace(rng, seconds=6.0)
    keep = (t < 2.0) | (t > 2.5)  # half a second without samples
    t, a, w = t[keep], a[keep], w[keep]
    a[700] = np.nan  # one unusable sample: skipped, not a gap
    noise = estimate_noise(t, a, w)
    iv = still_intervals(t, a, w, noise)
    assert len(iv) == 2
    assert iv[0] == (t[0], t[t < 2.0][-1]) and iv[1] == (t[t > 2.5][0], t[-1])
    mask = still_mask(t, a, w, noise)
    assert not mask[700] and mask[699] and mask[701]
    assert np.isnan(still_statistic(t, a, w, noise)[700])


@pytest.mark.parametrize("rate", [50.0, 200.0, 1000.0])
def test_samples_a_link_loses_do_not_cut_a_hold(rate):
    """A serial or USB link that loses 5 % of the samples, one or two at a time (shorter than a gap): the windows
    they fall in hold fewer samples than a test needs (at 50 Hz most windows have just enough). Such a window
    spans as many samples as it needs about its own, so every hold stays one still run (at 50 Hz the lost
    samples cut each hold into two or three, and each piece was estimated with a few frames' ringing)."""
    rng = np.random.default_rng(8)
    t, a, w, holds = trace(rng, rate, [("hold", 3.0), ("move", 1.0), ("hold", 3.0), ("move", 1.0), ("hold", 3.0)])
    lost = np.zeros(len(t), bool)
    starts = rng.choice(len(t) - 2, size=int(0.035 * len(t)), replace=False)
    lost[starts] = True
    lost[starts[rng.random(len(starts)) < 0.5] + 1] = True  # some bursts of two
    t, a, w = t[~lost], a[~lost], w[~lost]
    noise = estimate_noise(t, a, w)
    found = still_intervals(t, a, w, noise)
    assert len(found) == len(holds), found
    for (f0, f1), (h0, h1) in zip(found, holds):
        assert h0 - 0.1 <= f0 < h0 + 0.2 and h1 - 0.2 < f1 <= h1 + 0.1


def test_non_uniform_sampling(rng):
    t, a, w, holds = trace(rng, 200.0, [("hold", 3.0), ("move", 1.0), ("hold", 3.0)])
    t = t + rng.uniform(-0.4, 0.4, len(t)) * 0.005  # +-40 % of a period, order kept
    noise = estimate_noise(t, a, w)
    iv = still_intervals(t, a, w, noise)
    assert len(iv) == 2 and abs(iv[0][1] - 3.0) < 0.1 and abs(iv[1][0] - 4.0) < 0.1


def test_bad_input_is_one_clear_error(rng):
    t, a, w = still_trace(rng, seconds=2.0)
    with pytest.raises(InputError, match="/imu: .*need"):
        estimate_noise(t[:50], a[:50], w[:50], source="/imu")
    with pytest.raises(InputError, match="field 'accel'"):
        estimate_noise(t, a[:, :2], w)
    with pytest.raises(InputError, match="field 'gap_periods': must be >= 1"):
        ZuptConfig(min_window_samples=4, gap_periods=0.5)
    t2 = t.copy()
    t2[10] = t2[5]
    with pytest.raises(InputError, match="field 't'.*backwards at sample 10"):
        still_mask(t2, a, w, ImuNoise(0.02, 0.002))


def test_online_detector_matches_the_offline_test(rng):
    plan = [("hold", 3.0), ("move", 1.0), ("hold", 2.0), ("move", 1.0), ("hold", 2.0)]
    t, a, w, holds = trace(rng, 200.0, plan)
    det = ZuptDetector()
    assert det.is_still(0.0, 1.0) is None and det.still_since(1.0) is None
    since = {}
    for k in range(len(t)):
        assert det.add(t[k], a[k], w[k]) is None
        if k % 25 == 0 and det.noise is not None:  # queried while the samples arrive (cache of settled windows)
            since[k] = det.still_since(t[k])
    assert det.noise.source == "data"
    assert det.add(t[-1], a[-1], w[-1]) is ImuReject.OUT_OF_ORDER
    noise = det.noise
    offline = still_intervals(t, a, w, noise)
    assert len(offline) == 3
    for h0, h1 in offline:
        assert det.still_since(h1) == h0
        assert det.still_since(0.5 * (h0 + h1)) == h0
        assert det.is_still(h0, h1) is True
        assert det.is_still(h0 - 0.2, h1) is bool(h0 == t[0])  # before the first sample nothing says it moved
    assert det.is_still(3.3, 3.6) is False and det.still_since(3.5) is None
    assert det.is_still(100.0, 101.0) is None
    # online answers agree with the offline runs known up to that sample (within a window: the online noise
    # estimate in use then was from less data)
    for k, s in since.items():
        run = [h0 for h0, h1 in offline if h0 <= t[k] <= h1 + 0.1]
        if s is not None:
            assert run and abs(s - run[0]) <= ZuptConfig().window_s
    assert sum(s is not None for s in since.values()) > 0.6 * len(since)


def test_online_detector_with_known_noise(rng):
    t, a, w = still_trace(rng, seconds=1.0)
    noise = ImuNoise(0.02, 0.002, BIAS, "covariance", float(np.linalg.norm([0.2, -0.1, 9.8])), 0.005)
    det = ZuptDetector(noise=noise)
    for k in range(len(t)):
        det.add(t[k], a[k], w[k])
    assert det.noise is noise
    assert det.is_still(0.1, 0.9) is True
    assert det.still_since(0.9) == t[0]
    det.add(1.0, a[0] + np.array([1.0, 0.0, 0.0]), w[0])  # a jolt: the newest sample is not still
    assert det.is_still(0.1, 1.0) is False


@pytest.mark.parametrize("imu_rate", [50.0, 100.0, 200.0, 500.0, 1000.0])
@pytest.mark.parametrize("camera_rate, phase", [(5.0, 0.37), (10.0, 0.0), (60.0, 0.61)])
def test_online_stillness_between_frames_at_every_rate(rng, imu_rate, camera_rate, phase):
    """The pipeline asks the online detector, frame by frame, whether the rig was still since the previous frame:
    inside a hold every answer is yes (also for the newest samples, and with no IMU sample between two frames of
    a camera faster than the IMU), during a move every answer is no, at IMU rates 50-1000 Hz and cameras 5-60 Hz
    of any phase."""
    plan = [("hold", 3.0), ("move", 1.0), ("hold", 2.0), ("move", 1.0), ("hold", 2.0)]
    t, a, w, holds = trace(rng, imu_rate, plan)
    det = ZuptDetector(noise=estimate_noise(t, a, w))
    frames = np.arange(phase / camera_rate, t[-1], 1.0 / camera_rate)
    win = max(ZuptConfig().window_s, ZuptConfig().min_window_samples / imu_rate)
    k, answers = 0, []
    for f0, f1 in zip(frames[:-1], frames[1:]):
        while k < len(t) and t[k] <= f1:  # the samples up to the frame have arrived (merged by stamp)
            det.add(t[k], a[k], w[k])
            k += 1
        answers.append((f0, f1, det.is_still(f0, f1), det.still_since(f1)))
    margin = 2 * win
    for h0, h1 in holds:
        inside = [(s, since) for f0, f1, s, since in answers if h0 + margin <= f0 and f1 <= h1]
        assert inside and all(s is True for s, _ in inside)
        assert all(abs(since - h0) <= win for _, since in inside)
    moving = [s for f0, f1, s, _ in answers if any(m0 + 0.1 <= f0 and f1 <= m1 - 0.1 for m0, m1 in ((3.0, 4.0),
                                                                                                    (6.0, 7.0)))]
    assert moving and not any(moving)


@pytest.mark.parametrize("imu_rate", [50.0, 200.0, 1000.0])
def test_the_still_run_of_a_hold_spans_the_hold_and_a_move_has_none(rng, imu_rate):
    """still_run of any instant of a hold: its first and last still samples, at the hold's ends within a window
    (before and after the instant: a snapshot's run goes on after its image); none inside a move; while the
    rig still rests, the run ends at the newest sample."""
    plan = [("hold", 3.0), ("move", 1.0), ("hold", 2.0), ("move", 1.0), ("hold", 2.0)]
    t, a, w, holds = trace(rng, imu_rate, plan)
    det = ZuptDetector(noise=estimate_noise(t, a, w))
    win = max(ZuptConfig().window_s, ZuptConfig().min_window_samples / imu_rate)
    for k in range(len(t)):
        det.add(t[k], a[k], w[k])
    for h0, h1 in holds[:-1]:
        for at in (h0 + 0.3, 0.5 * (h0 + h1), h1 - 0.3):
            first, last = det.still_run(at)
            assert abs(first - h0) <= win and abs(last - h1) <= win, (at, first, last, h0, h1)
    assert det.still_run(3.5) is None and det.still_run(6.5) is None
    assert det.still_run(holds[-1][0] + 1.0)[1] == t[-1]


@pytest.mark.parametrize("imu_rate", [50.0, 100.0, 200.0, 1000.0])
def test_a_snapshot_sooner_after_the_stop_than_half_a_window_is_still_sample_by_sample(rng, imu_rate):
    """A still run of the windowed test starts half a window after the stop (0.09 s at 50 Hz): an instant 0.02-0.05
    s after the stop lies before it, and every sample since reads still on its own, so it leads into that run,
    which starts at the stop found sample by sample. An instant inside the move, or 0.05 s before the stop, does
    not (its samples read the move)."""
    plan = [("hold", 3.0), ("move", 1.0), ("hold", 2.0), ("move", 1.0), ("hold", 2.0)]
    t, a, w, holds = trace(rng, imu_rate, plan)
    det = ZuptDetector(noise=estimate_noise(t, a, w))
    for k in range(len(t)):
        det.add(t[k], a[k], w[k])
    for h0, h1 in holds[1:]:
        for after in (0.02, 0.05):
            first, last = det.leading_run(h0 + after)
            assert h0 - 0.06 <= first <= h0 + after and abs(last - h1) <= 0.1, (after, first, h0)
        assert det.leading_run(h0 - 0.05) is None and det.leading_run(h0 - 0.5) is None
    if imu_rate == 50.0:  # the windowed test alone takes both instants for the move
        assert det.is_still(holds[1][0] + 0.02, holds[1][0] + 0.02) is False


@pytest.mark.parametrize("imu_rate", [50.0, 200.0, 1000.0])
def test_an_instant_moments_after_a_stop_is_decided_half_a_window_later_in_a_run_of_any_length(rng, imu_rate):
    """0.15 s after a stop (less than a stillness window and its shortest run at 50 Hz, 0.18 s, past the half
    window the test cannot tell from the move): undecided until the samples reach half a window beyond it;
    then it lies in a still run (``any_length``: also one not yet a window long) starting within a window of
    the stop."""
    plan = [("hold", 2.0), ("move", 1.0), ("hold", 2.0)]
    t, a, w, holds = trace(rng, imu_rate, plan)
    det = ZuptDetector(noise=estimate_noise(t, a, w))
    cfg = ZuptConfig()
    half = 0.5 * max(cfg.window_s, (2 * math.ceil((cfg.min_window_samples - 1) / 2) + 1) / imu_rate)
    stop = holds[1][0]
    at = stop + 0.15
    seen = []
    for k in range(len(t)):
        det.add(t[k], a[k], w[k])
        seen.append(det.decided(at))
        if seen[-1]:
            break
    assert t[k] >= at + half and t[k] <= at + half + 2.0 / imu_rate, (t[k] - at, half)
    assert not any(seen[:-1])
    since = det.still_since(at, any_length=True)
    assert since is not None and stop <= since <= stop + 2 * half, (since - stop, half)


@pytest.mark.parametrize("rate", [50.0, 200.0, 1000.0])
def test_an_accelerometer_bias_does_not_split_holds_at_any_rate(rng, rate):
    """A biased accelerometer's still norm |-g + b| differs between attitudes; that mismatch does not average
    away with more samples, so it must not read as motion on a fast IMU (one still run per hold at 50-1000 Hz)."""
    plan = [("hold", 3.0), ("move", 1.5), ("hold", 3.0), ("move", 1.5), ("hold", 3.0), ("move", 1.5), ("hold", 3.0)]
    t, a, w, holds = trace(rng, rate, plan)
    a = a + np.array([0.08, -0.06, 0.05])  # m/s^2, body frame: the norms of the holds differ by ~0.05
    cfg = ZuptConfig()
    noise = estimate_noise(t, a, w, cfg)
    iv = still_intervals(t, a, w, noise, cfg)
    assert len(iv) == len(holds), iv
    for (f0, f1), (h0, h1) in zip(iv, holds):
        assert f1 - f0 >= h1 - h0 - 3 * max(cfg.window_s, cfg.min_window_samples / rate)


def test_a_steady_vertical_acceleration_without_rotation_is_motion(rng):
    """The magnitude term still sees a lift: 1 m/s^2 straight up for a second, no rotation, no change."""
    t, a, w = still_trace(rng, rate=200.0, seconds=6.0)
    lift = (t > 3.0) & (t < 4.0)
    a[lift] *= (9.8 + 1.0) / 9.8
    noise = estimate_noise(t[t < 3.0], a[t < 3.0], w[t < 3.0])
    still = still_mask(t, a, w, noise)
    assert not still[(t > 3.2) & (t < 3.8)].any() and still[t < 2.8].all()


@pytest.mark.parametrize("rate", [200.0, 1000.0])
def test_online_with_covariances_the_first_bias_estimate_is_soon_replaced(rng, rate):
    """With valid message covariances the online detector answers after one window of samples, its gyro bias from
    those few windows. That early bias is off by several times what a 1 kHz window resolves; kept for
    noise_refresh_s it read a still rig as moving. It is estimated again as the data doubles: every frame
    interval of a long hold is still, and the bias in use converges to the data's."""
    t, a, w = still_trace(rng, rate=rate, seconds=8.0)
    covariance = (np.diag([0.02**2] * 3).ravel(), np.diag([0.002**2] * 3).ravel())
    det = ZuptDetector(covariance=covariance)
    k, answers, first = 0, [], None
    for f0, f1 in zip(np.arange(0.0, 8.0, 1 / 60)[:-1], np.arange(0.0, 8.0, 1 / 60)[1:]):
        while k < len(t) and t[k] <= f1:
            det.add(t[k], a[k], w[k], covariance)
            k += 1
        if det.noise is not None and first is None:
            first = det.noise.gyro_bias.copy()
        if f0 >= 0.3:
            answers.append(det.is_still(f0, f1))
    assert det.noise.source == "covariance" and answers and all(s is True for s in answers)
    bias_std = 0.002 / math.sqrt(len(t))  # of the mean over all samples; the quietest windows' median is near it
    assert np.abs(det.noise.gyro_bias - BIAS).max() < 10 * bias_std < np.abs(first - BIAS).max()


@pytest.mark.parametrize("imu_rate", [50.0, 200.0, 1000.0])
def test_the_streams_first_window_and_one_after_a_gap_are_no_move(rng, imu_rate):
    """A recording that starts (or an IMU stream that resumes after a gap) while the rig rests: its first
    samples are still, but fewer than a still run needs. Nothing says the rig moved, so the answer is unknown
    (None: the images decide), not "moved": before, a hold at a recording's start was cut after its first
    frame and measured twice, a pair without any motion between. A young run after a move is "moved" as
    before, and the samples of a move are too."""
    plan = [("hold", 3.0), ("move", 1.0), ("hold", 3.0)]
    t, a, w, holds = trace(rng, imu_rate, plan)
    det = ZuptDetector(noise=ImuNoise(0.02, 0.002, BIAS, "covariance", 9.81, 1.0 / imu_rate))
    win = max(ZuptConfig().window_s, ZuptConfig().min_window_samples / imu_rate)
    first = [k for k in range(len(t)) if t[k] < 0.5 * win]
    for k in first:
        det.add(t[k], a[k], w[k])
    assert det.is_still(t[first[0]], t[first[-1]]) is None
    gap = 0.5  # no sample from 1.0 to 1.5 s: then the stream resumes, the rig still at rest
    for k in range(first[-1] + 1, len(t)):
        if 1.0 <= t[k] < 1.0 + gap:
            continue
        det.add(t[k], a[k], w[k])
        if t[k] >= 1.0 + gap and t[k] - (1.0 + gap) < 0.5 * win:
            assert det.is_still(1.0 + gap, t[k]) is None  # young after the gap
        if 3.0 + 0.2 <= t[k] < 4.0 - 0.2:
            assert det.is_still(t[k] - 0.05, t[k]) is False  # the move
        if 4.0 + 0.05 <= t[k] < 4.0 + 0.5 * win:
            assert det.is_still(t[k] - 0.02, t[k]) is False  # young after the move: it just stopped
    assert det.is_still(t[-1] - 0.5, t[-1]) is True


def ringing_trace(rng, rate, frequency_hz, zeta=0.03, creep_deg_s=0.0):
    """:func:`trace` of holds and moves read by an IMU that rides on a bar ringing at ``frequency_hz``: after
    every move its gyro and accelerometer carry a decaying oscillation (17 deg/s and 1 m/s^2 at first, each
    axis at its own phase), far above their noise for the whole hold; ``creep_deg_s`` turns the body slowly
    through the second hold (a motion)."""
    plan = [("hold", 3.0), ("move", 1.5), ("hold", 3.0), ("move", 1.0), ("hold", 3.0)]
    t, a, w, holds = trace(rng, rate, plan)
    omega = 2.0 * math.pi * frequency_hz
    for h0, h1 in holds[1:]:
        m = (t >= h0) & (t < h1)
        tau = t[m] - h0
        phase = rng.uniform(0.0, 2.0 * math.pi, size=6)
        env = np.exp(-zeta * omega * tau)[:, None]
        w[m] += 0.3 * env * np.sin(omega * tau[:, None] + phase[:3]) * rng.uniform(0.5, 1.0, 3)
        a[m] += 1.0 * env * np.sin(omega * tau[:, None] + phase[3:]) * rng.uniform(0.5, 1.0, 3)
    if creep_deg_s:
        h0, h1 = holds[1]
        w[(t >= h0) & (t < h1)] += math.radians(creep_deg_s) * AXIS
    return t, a, w, holds


@pytest.mark.parametrize("rate, frequency_hz", [(50.0, 1.5), (200.0, 4.0), (1000.0, 8.0), (100.0, 6.0)])
def test_an_imu_on_a_ringing_bar_finds_every_hold_whole(rng, rate, frequency_hz):
    """The ringing of the IMU's own bar is no motion: each hold is one still run from about a window after the
    stop to its end; without the bar's frequency the same samples lose most of every hold after a move."""
    t, a, w, holds = ringing_trace(rng, rate, frequency_hz)
    cfg = ZuptConfig(mount_ringing_hz=frequency_hz)
    noise = estimate_noise(t, a, w, cfg)
    assert noise.gyro_sigma == pytest.approx(0.002, rel=0.2)
    iv = still_intervals(t, a, w, noise, cfg)
    detector = ZuptDetector(cfg, noise=noise)
    win = detector.window_s if detector.add(t[0], a[0], w[0]) is None else math.nan
    assert win >= 1.0 / frequency_hz
    assert len(iv) == len(holds)
    for (f0, f1), (h0, h1) in zip(iv, holds):  # (a move's first 30 ms turn slower than the gyro's noise)
        assert h0 - 1.0 / rate <= f0 <= h0 + win and h1 - win <= f1 <= h1 + 0.03
    plain = ZuptConfig(mount_ringing_hz=0.0)
    iv0 = still_intervals(t, a, w, estimate_noise(t, a, w, plain), plain)
    found = sum(min(f1, h1) - max(f0, h0) for f0, f1 in iv0 for h0, h1 in holds[1:] if f1 > h0 and f0 < h1)
    assert found < 0.5 * sum(h1 - h0 for h0, h1 in holds[1:])


@pytest.mark.parametrize("rate, frequency_hz", [(50.0, 1.5), (1000.0, 8.0)])
def test_a_creep_under_a_ringing_bar_is_still_motion(rng, rate, frequency_hz):
    t, a, w, holds = ringing_trace(rng, rate, frequency_hz, creep_deg_s=2.0)
    cfg = ZuptConfig(mount_ringing_hz=frequency_hz)
    noise = estimate_noise(t, a, w, cfg)
    still = still_mask(t, a, w, noise, cfg)
    h0, h1 = holds[1]
    assert not still[(t > h0) & (t < h1)].any()
    assert still[(t > holds[2][0] + 1.0 / frequency_hz) & (t < holds[2][1] - 1.0 / frequency_hz)].all()


def test_the_mount_ringing_follows_the_rig_file(cross_rig):
    on_bar = dataclasses.replace(cross_rig, imu=ImuMount(mount=cross_rig.cameras[1].name))
    f = bar_natural_frequencies(cross_rig)[1]
    assert math.isfinite(f) and for_rig(ZuptConfig(), on_bar).mount_ringing_hz == pytest.approx(f)
    assert for_rig(ZuptConfig(), dataclasses.replace(cross_rig, imu=ImuMount())).mount_ringing_hz == 0.0
    assert for_rig(ZuptConfig(mount_ringing_hz=0.0), on_bar).mount_ringing_hz == 0.0


def swinging_trace(rng, rate, frequency_hz, swing_rad, zeta=0.03, creep_deg_s=0.0):
    """:func:`trace` read by an IMU at the tip of a bar (along x) that swings after every move: its tip turns by
    phi(t), up to ``swing_rad`` about y and 0.6 of it about z a quarter period later (a swing not in one plane),
    decaying at ``zeta``. The accelerometer reads the body's specific force and the tip's own acceleration (a
    0.3 m lever), turned by -phi; the gyro J_r(phi) phi' (what make-bag's IMU in a camera reads);
    ``creep_deg_s`` turns the body slowly through the second hold."""
    t, a, w, holds = trace(rng, rate, [("hold", 3.0), ("move", 1.5), ("hold", 3.0), ("move", 1.0), ("hold", 3.0)],
                           accel_sigma=0.0, gyro_sigma=0.0, bias=np.zeros(3))
    omega = 2.0 * math.pi * frequency_hz
    lever = np.array([0.3, 0.0, 0.0])
    for h0, h1 in holds[1:]:
        m = (t >= h0) & (t < h1)
        tau = t[m] - h0
        env, decay = swing_rad * np.exp(-zeta * omega * tau), -zeta * omega
        c, s = np.cos(omega * tau), np.sin(omega * tau + 0.4)
        dc, ds = -omega * np.sin(omega * tau), omega * np.cos(omega * tau + 0.4)
        ex, ey = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
        phi = env[:, None] * (np.outer(c, ex) + 0.6 * np.outer(s, ey))
        dphi = env[:, None] * (np.outer(decay * c + dc, ex) + 0.6 * np.outer(decay * s + ds, ey))
        ddphi = -omega ** 2 * phi  # to first order in the damping
        R = exp_so3(phi)
        a[m] = np.einsum("nji,nj->ni", R, a[m] + np.cross(ddphi, lever))
        w[m] = np.einsum("nij,nj->ni", right_jacobian(phi), dphi)
    if creep_deg_s:
        h0, h1 = holds[1]
        w[(t >= h0) & (t < h1)] += math.radians(creep_deg_s) * AXIS
    return t, a + rng.normal(scale=0.02, size=a.shape), w + BIAS + rng.normal(scale=0.002, size=w.shape), holds


@pytest.mark.parametrize("rate, frequency_hz, swing_rad", [(50.0, 1.5, 0.15), (200.0, 1.5, 0.15), (400.0, 2.0, 0.1),
                                                           (100.0, 4.0, 0.05)])
def test_an_imu_on_a_bar_swinging_by_tenths_of_a_radian_finds_every_hold_whole(rng, rate, frequency_hz, swing_rad):
    """A tip that turns by 0.15 rad reads gravity turned with it: to second order a constant and a second
    harmonic, 0.1 m/s^2 and more (five accelerometer noises), and a swing not in one plane puts one into the
    gyro too (the same stop swings a stiffer bar less, as 1 / f^2). With the mount's turn taken out each hold
    is one still run from about a window after the stop to its end; a creep of 2 deg/s under the same swing
    stays a motion."""
    t, a, w, holds = swinging_trace(rng, rate, frequency_hz, swing_rad)
    cfg = ZuptConfig(mount_ringing_hz=frequency_hz)
    noise = estimate_noise(t, a, w, cfg)
    assert noise.accel_sigma == pytest.approx(0.02, rel=0.2) and noise.gyro_sigma == pytest.approx(0.002, rel=0.2)
    iv = still_intervals(t, a, w, noise, cfg)
    win = ZuptDetector(cfg, noise=noise).window_s
    assert len(iv) == len(holds)
    for (f0, f1), (h0, h1) in zip(iv, holds):
        assert h0 - 1.0 / rate <= f0 <= h0 + win and h1 - win <= f1 <= h1 + 0.03
    t, a, w, holds = swinging_trace(rng, rate, frequency_hz, swing_rad, creep_deg_s=2.0)
    still = still_mask(t, a, w, estimate_noise(t, a, w, cfg), cfg)
    h0, h1 = holds[1]
    assert not still[(t > h0) & (t < h1)].any()


SOFT_BAR = MountBar(damping=0.03, compliance=-0.04 * skew(np.array([1.0, 0.0, 0.0])))  # 0.4 rad under 1 g


def bent_swinging_trace(rng, rate, frequency_hz, swing_rad, bar=SOFT_BAR, creep_deg_s=0.0):
    """:func:`trace` read by an IMU at the tip of a soft bar (along x) that rests bent by its load, psi_s = K f
    (0.4 rad under gravity), and swings about that bend after every move as :func:`swinging_trace`: the tip
    turns by psi = psi_s + r, its gyro reads exp(-psi) w + J_r(psi) psi' and its accelerometer exp(-psi) f (the
    physics of make-bag's IMU in a camera on a 1.5 Hz bar)."""
    t, f, w, holds = trace(rng, rate, [("hold", 3.0), ("move", 1.5), ("hold", 3.0), ("move", 1.0), ("hold", 3.0)],
                           accel_sigma=0.0, gyro_sigma=0.0, bias=np.zeros(3))
    omega = 2.0 * math.pi * frequency_hz
    psi = f @ bar.compliance.T  # quasi-static through the moves
    lever = np.array([0.3, 0.0, 0.0])
    for h0, h1 in holds[1:]:
        m = (t >= h0) & (t < h1)
        tau = t[m] - h0
        env = swing_rad * np.exp(-bar.damping * omega * tau)
        psi[m] += env[:, None] * (np.outer(np.cos(omega * tau), [0.0, 1.0, 0.0])
                                  + 0.6 * np.outer(np.sin(omega * tau + 0.4), [0.0, 0.0, 1.0]))
        f[m] += np.cross(-omega ** 2 * (psi[m] - psi[m].mean(axis=0)), lever)
    dpsi = np.gradient(psi, t, axis=0)
    if creep_deg_s:
        h0, h1 = holds[1]
        w[(t >= h0) & (t < h1)] += math.radians(creep_deg_s) * AXIS
    R = exp_so3(psi)
    a = np.einsum("nji,nj->ni", R, f)
    w = np.einsum("nji,nj->ni", R, w) + np.einsum("nij,nj->ni", right_jacobian(psi), dpsi)
    return t, a + rng.normal(scale=0.02, size=a.shape), w + BIAS + rng.normal(scale=0.002, size=w.shape), holds


@pytest.mark.parametrize("rate", [50.0, 200.0, 1000.0])
def test_a_swing_about_a_soft_bars_static_bend_finds_every_hold_whole(rng, rate):
    """A soft bar's tip rests bent by 0.4 rad and swings about that bend by 0.16 rad (86 deg/s): the gyro's
    J_r(psi_s + r) r' carries products of the bend with the swing, a second harmonic, and over one period a
    swing damped at 0.03 is 0.3 % off a linear change of amplitude: together several gyro noises. With the bar's
    static bend and damping (the rig file's, ``mount_bar``) each hold is one still run after the stop, at
    every rate; without them the fastest IMU loses most of the first hold after a move (its test sees n times
    the misfit over n times the noise), and a creep of 2 deg/s under the same swing stays a motion."""
    frequency_hz = 1.5
    t, a, w, holds = bent_swinging_trace(rng, rate, frequency_hz, 0.16)
    cfg = ZuptConfig(mount_ringing_hz=frequency_hz, mount_bar=SOFT_BAR)
    noise = estimate_noise(t, a, w, cfg)
    assert noise.gyro_sigma == pytest.approx(0.002, rel=0.2)
    iv = still_intervals(t, a, w, noise, cfg)
    win = ZuptDetector(cfg, noise=noise).window_s
    assert len(iv) == len(holds)
    for (f0, f1), (h0, h1) in zip(iv, holds):
        assert h0 - 1.0 / rate <= f0 <= h0 + win and h1 - win <= f1 <= h1 + 0.03
    if rate == 1000.0:
        bare = ZuptConfig(mount_ringing_hz=frequency_hz)
        still = still_mask(t, a, w, estimate_noise(t, a, w, bare), bare)
        h0, h1 = holds[1]
        assert np.mean(still[(t > h0 + win) & (t < h1)]) < 0.5
    t, a, w, holds = bent_swinging_trace(rng, rate, frequency_hz, 0.16, creep_deg_s=2.0)
    still = still_mask(t, a, w, estimate_noise(t, a, w, cfg), cfg)
    h0, h1 = holds[1]
    assert not still[(t > h0) & (t < h1)].any()


@pytest.mark.parametrize("rate", [50.0, 100.0, 1000.0])
def test_a_snapshot_before_a_ringing_mounts_first_window_ends_is_still_by_that_window(rng, rate):
    """On a 1.5 Hz bar the test's windows last a period (0.67 s), so a still run begins a third of a second after
    the stop and a snapshot 0.3 s after it lies before the run: its instant is still because the run's first
    window, which fits rest and the swing over all of its samples, covers it. An instant in the move, and one
    in a hold that creeps under the same swing, are not."""
    frequency_hz = 1.5
    cfg = ZuptConfig(mount_ringing_hz=frequency_hz, mount_bar=SOFT_BAR)
    t, a, w, holds = bent_swinging_trace(rng, rate, frequency_hz, 0.16)
    det = ZuptDetector(cfg, noise=estimate_noise(t, a, w, cfg))
    for k in range(len(t)):
        det.add(t[k], a[k], w[k])
    for h0, h1 in holds[1:]:
        snap = h0 + 0.3
        assert det.still_run(snap) is None  # the windowed run alone starts after the snapshot
        first, last = det.leading_run(snap)
        assert h0 - 1.0 / rate <= first <= snap and abs(last - h1) <= 0.4
        assert det.leading_run(h0 - 0.3) is None
    t, a, w, holds = bent_swinging_trace(rng, rate, frequency_hz, 0.16, creep_deg_s=2.0)
    det = ZuptDetector(cfg, noise=estimate_noise(t, a, w, cfg))
    for k in range(len(t)):
        det.add(t[k], a[k], w[k])
    assert det.leading_run(holds[1][0] + 0.3) is None


def test_the_mount_bar_follows_the_rig_file(cross_rig):
    """The damping and static bend of the bar the rig file mounts the IMU on; none for an IMU on the body. The
    static bend is the bar's bend under the load the IMU reads: K f turns the IMU's reading of gravity into the
    rotation the deformation model gives the camera under that gravity."""
    cam = cross_rig.cameras[1]
    on_bar = dataclasses.replace(cross_rig, imu=ImuMount(mount=cam.name))
    bar = for_rig(ZuptConfig(), on_bar).mount_bar
    assert bar is not None and bar.damping == pytest.approx(bar_damping_ratios(on_bar)[1])
    assert for_rig(ZuptConfig(), dataclasses.replace(cross_rig, imu=ImuMount())).mount_bar is None
    g = np.array([1.0, -2.0, -9.5])
    bent = exp_so3(bend_rotation_vectors(cross_rig, g, cams=[1])[0]) @ cross_rig.rotations[1]
    psi = static_bend(bar.compliance, (bent.T @ -g)[None])[0]  # what the IMU in the bent camera reads
    assert np.linalg.norm(psi) > 1e-3
    assert np.allclose(cross_rig.rotations[1] @ exp_so3(psi), bent, atol=1e-3 * np.linalg.norm(psi))


@pytest.mark.parametrize("rate, frequency_hz", [(50.0, 1.5), (200.0, 1.5), (400.0, 4.0)])
def test_a_ringing_mount_at_the_start_of_a_stream_is_unknown_until_a_period_then_still(rng, rate, frequency_hz):
    """A node that starts on a rig at rest, its IMU on a ringing bar (the messages' covariances known, so the
    noise needs no second of data): over less than one period of the ringing the fit cannot tell the
    oscillation from the constant (its still norm read 45 m/s^2 from 0.1 s), so the rig's stillness is unknown
    there, not a motion; from a period on it is still, and the still norm is the accelerometer's."""
    t, a, w = still_trace(rng, rate=rate, seconds=3.0)
    cov = (np.diag([0.02 ** 2] * 3).ravel(), np.diag([0.002 ** 2] * 3).ravel())
    det = ZuptDetector(ZuptConfig(mount_ringing_hz=frequency_hz))
    period = 1.0 / frequency_hz
    for k in range(len(t)):
        det.add(t[k], a[k], w[k], cov)
        if t[k] < 0.9 * period:
            assert det.is_still(t[0], t[k]) is not False
    assert det.is_still(0.0, 2.5) is True
    assert det.noise.accel_norm == pytest.approx(float(np.linalg.norm([0.2, -0.1, 9.8])), abs=0.01)


def test_a_ringing_mount_is_tested_alike_after_an_hour(rng):
    """The fit's sums are cumulative over the recording: an hour of samples (50 Hz) gives the last minute the
    statistic the last minute alone gives (the oscillation's phase, and its powers, stay small)."""
    t = np.arange(0.0, 3600.0, 0.02)
    a = np.array([0.2, -0.1, 9.8]) + rng.normal(scale=0.02, size=(len(t), 3))
    w = BIAS + rng.normal(scale=0.002, size=(len(t), 3))
    tail = t > 3540.0
    tau = t[tail] - 3540.0
    w[tail] += 0.2 * np.exp(-0.3 * tau)[:, None] * np.sin(2 * math.pi * 1.5 * tau[:, None] + np.array([0, 1, 2]))
    cfg = ZuptConfig(mount_ringing_hz=1.5)
    noise = ImuNoise(0.02, 0.002, BIAS, accel_norm=float(np.linalg.norm([0.2, -0.1, 9.8])), period_s=0.02)
    whole = still_statistic(t, a, w, noise, cfg)[tail]
    alone = still_statistic(t[tail], a[tail], w[tail], noise, cfg)
    inner = (t[tail] > 3541.0) & (t[tail] < 3599.0)  # the windows the end of the slice does not move
    assert np.nanmax(np.abs(whole[inner] - alone[inner])) < 1e-6 * np.nanmax(alone[inner])
    assert np.nanmax(alone[inner]) < 1.0


# -- an IMU's own low-pass filter, and covariances that claim too little ------------------------------------------


def lowpass(noise: np.ndarray, cutoff_hz: float, rate: float) -> np.ndarray:
    """Unit-std noise through a MEMS IMU's digital low-pass filter (2nd-order Butterworth), std kept at 1."""
    from scipy.signal import butter, sosfilt

    y = sosfilt(butter(2, cutoff_hz, fs=rate, output="sos"), noise, axis=0)
    return y / y[200:].std()


def filtered_trace(rng, rate, cutoff_hz, plan, accel_sigma=0.02, gyro_sigma=0.002, creep_deg_s=0.0):
    """:func:`trace` with the noise low-pass filtered (neighbouring samples correlated, the std per sample kept);
    ``creep_deg_s`` turns the body slowly through the second hold."""
    t, a, w, holds = trace(rng, rate, plan, accel_sigma=0.0, gyro_sigma=0.0)
    a = a + accel_sigma * lowpass(rng.normal(size=a.shape), cutoff_hz, rate)
    w = w + gyro_sigma * lowpass(rng.normal(size=w.shape), cutoff_hz, rate)
    if creep_deg_s:
        h0, h1 = holds[1]
        w[(t >= h0) & (t < h1)] += math.radians(creep_deg_s) * AXIS
    return t, a, w, holds


@pytest.mark.parametrize("rate, cutoff_hz", [(50.0, 10.0), (200.0, 40.0), (200.0, 10.0), (1000.0, 100.0),
                                             (1000.0, 20.0)])
def test_a_low_pass_filtered_imu_finds_every_hold_whole(rng, rate, cutoff_hz):
    """A MEMS IMU filters its output: neighbouring samples share their noise, so a window's spread follows a
    wider distribution than white noise gives. The test takes it from the noise's measured correlation: the
    noise per sample is estimated right, and each hold is one still run (tested as white noise, with the
    narrower distribution's quantile, the noise came out 10-30 % low and 13-97 % of a still minute at 1 kHz
    with a 10-100 Hz filter read as motion)."""
    plan = [("hold", 6.0), ("move", 1.0), ("hold", 6.0), ("move", 1.0), ("hold", 6.0)]
    t, a, w, holds = filtered_trace(rng, rate, cutoff_hz, plan)
    noise = estimate_noise(t, a, w)
    assert noise.accel_sigma == pytest.approx(0.02, rel=0.12) and noise.gyro_sigma == pytest.approx(0.002, rel=0.12)
    assert len(noise.accel_correlation) > 1 and noise.accel_correlation[1] > 0.3
    iv = still_intervals(t, a, w, noise)
    assert len(iv) == len(holds)
    for (f0, f1), (h0, h1) in zip(iv, holds):
        assert abs(f0 - h0) < 0.2 and abs(f1 - h1) < 0.2


@pytest.mark.parametrize("rate", [200.0, 1000.0])
def test_a_creep_under_filtered_noise_is_still_motion(rng, rate):
    """The correlated noise's wider null distribution does not let a slow turn through: 1 deg/s through a hold
    is motion at a 20 Hz filter."""
    plan = [("hold", 4.0), ("move", 1.0), ("hold", 4.0), ("move", 1.0), ("hold", 4.0)]
    t, a, w, holds = filtered_trace(rng, rate, 20.0, plan, creep_deg_s=1.0)
    noise = estimate_noise(t, a, w)
    h0, h1 = holds[1]
    assert not still_mask(t, a, w, noise)[(t > h0 + 0.1) & (t < h1 - 0.1)].any()


@pytest.mark.parametrize("claim", [0.1, 0.3, 0.7])
@pytest.mark.parametrize("rate", [50.0, 200.0, 1000.0])
def test_a_covariance_that_claims_too_little_noise_is_raised_to_the_samples_white_noise(rng, rate, claim):
    """A driver's covariance is a claim (often a datasheet's noise density taken for a per-sample std): one
    below the white noise the samples show is raised to it, and said so; with the claim alone every still
    window reads as motion."""
    t, a, w, holds = trace(rng, rate, [("hold", 4.0), ("move", 1.0), ("hold", 4.0), ("move", 1.0), ("hold", 4.0)])
    cov = ((np.eye(3) * (claim * 0.02) ** 2).ravel(), (np.eye(3) * (claim * 0.002) ** 2).ravel())
    noise = estimate_noise(t, a, w, covariance=cov)
    assert noise.source == NoiseSource.WHITE_NOISE
    assert noise.claimed == pytest.approx((claim * 0.02, claim * 0.002))
    assert noise.accel_sigma == pytest.approx(0.02, rel=0.1) and noise.gyro_sigma == pytest.approx(0.002, rel=0.1)
    iv = still_intervals(t, a, w, noise)
    assert len(iv) == len(holds)
    as_claimed = dataclasses.replace(noise, accel_sigma=claim * 0.02, gyro_sigma=claim * 0.002)
    h0, h1 = holds[1]
    assert still_mask(t, a, w, as_claimed)[(t > h0 + 0.2) & (t < h1 - 0.2)].mean() < (0.5 if claim < 0.5 else 0.9)


def test_a_generous_covariance_stands_and_the_white_noise_holds_where_the_rig_never_stops(rng):
    """A covariance claiming more noise than the samples show is kept (it only makes the test less sensitive).
    The white noise comes from differences of neighbouring samples, so a rig that never stops (where the
    quietest windows are motion) still shows its sensor's noise."""
    t, a, w, _ = trace(rng, 100.0, [("move", 2.0)] * 10)
    generous = ((np.eye(3) * 0.2 ** 2).ravel(), (np.eye(3) * 0.02 ** 2).ravel())
    noise = estimate_noise(t, a, w, covariance=generous)
    assert noise.source == NoiseSource.COVARIANCE and (noise.accel_sigma, noise.gyro_sigma) == (0.2, 0.02)
    assert noise.white == pytest.approx((0.02, 0.002), rel=0.1)
    assert estimate_noise(t, a, w).gyro_sigma > 1.5 * 0.002  # the quietest windows of a moving rig


@pytest.mark.parametrize("rate", [50.0, 200.0, 1000.0])
def test_white_noise_reads_as_white(rng, rate):
    """Between moves at 50-1000 Hz the still runs are short: each about its own mean owes every lagged product
    a little, which is added back, so white noise shows no correlation (uncorrected, 6-7 lags at 50-200 Hz)."""
    t, a, w, _ = trace(rng, rate, [("hold", 1.0), ("move", 0.5)] * 12)
    noise = estimate_noise(t, a, w)
    assert len(noise.accel_correlation) <= 2 and len(noise.gyro_correlation) <= 2
    assert np.abs(noise.accel_correlation[1:]).max(initial=0.0) < 0.1


def test_the_noise_is_described_with_its_source_claim_and_correlation(rng):
    t, a, w, _ = trace(rng, 200.0, [("hold", 4.0), ("move", 1.0), ("hold", 4.0)])
    small = ((np.eye(3) * 0.002 ** 2).ravel(), (np.eye(3) * 0.0002 ** 2).ravel())
    text = describe_noise(estimate_noise(t, a, w, covariance=small), ZuptConfig())
    assert text.startswith("noise 0.02") and "from the white noise" in text and "claim 0.002 m/s^2" in text
    ignored = estimate_noise(t, a, w, ZuptConfig(use_covariance=False), covariance=small)
    assert ignored.source == NoiseSource.DATA and ignored.claimed is None
    assert ignored.gyro_sigma == pytest.approx(0.002, rel=0.15)
    t, a, w, _ = filtered_trace(rng, 1000.0, 40.0, [("hold", 4.0), ("move", 1.0), ("hold", 4.0)])
    right = ((np.eye(3) * 0.02 ** 2).ravel(), (np.eye(3) * 0.002 ** 2).ravel())
    text = describe_noise(estimate_noise(t, a, w, covariance=right), ZuptConfig())
    assert "from the covariance)" in text and "correlated over" in text and "low-pass filter" in text
    # a filtered IMU's claim of a fifth: its white noise cannot refute it (the filter smooths neighbours alike),
    # the quietest windows can, and the line says what to do
    fifth = ((np.eye(3) * 0.004 ** 2).ravel(), (np.eye(3) * 0.0004 ** 2).ravel())
    text = describe_noise(estimate_noise(t, a, w, covariance=fifth), ZuptConfig())
    assert "the quietest windows show up to" in text and "zupt.use_covariance: false" in text


def test_the_mean_of_filtered_noise_varies_as_its_correlation_says(rng):
    """A low-pass filtered IMU's hold mean varies several times more than s^2 / n: the measured correlation
    gives that factor (the IMU gravity's std is the mean's), within the scatter of 300 means."""
    t, a, w, _ = filtered_trace(rng, 1000.0, 40.0, [("hold", 120.0)])
    noise = estimate_noise(t, a, w)
    n = 400
    means = a[: (len(a) // n) * n].reshape(-1, n, 3).mean(axis=1)
    measured = float(np.var(means - means.mean(axis=0))) / (0.02 ** 2 / n)
    factor = mean_variance_factor(noise.accel_correlation, n)
    assert factor > 4.0 and factor == pytest.approx(measured, rel=0.25)
    assert mean_variance_factor(np.ones(1), n) == 1.0


@pytest.mark.parametrize("scale, said, unit", [(1.0, False, False), (1.05, False, False), (1.0 / 9.81, True, True),
                                               (1.2, True, False)])
def test_an_accelerometer_off_gravitys_scale_is_said(rng, scale, said, unit):
    """A driver that publishes g instead of m/s^2 (REP 145) reads 1.0 at rest: directions stand, magnitudes are
    read ten times too small; said with the number, and not within a MEMS accelerometer's few percent."""
    from nrmpc_ros.frontend.imu_units import describe_accel_scale

    t, a, w = still_trace(rng)
    text = describe_accel_scale(estimate_noise(t, a * scale, w), 9.81)
    assert (text is not None) == said
    if said:
        assert f"{np.linalg.norm([0.2, -0.1, 9.8]) * scale:.3g}" in text and ("units of g" in text) == unit


def test_a_low_pass_filtered_imu_whose_covariances_claim_its_white_noise_is_disputed_and_can_be_dropped(rng):
    """A driver that claims its chip's white noise for a 20 Hz low-pass filtered 400 Hz stream: the claim reads
    every window as motion and the quietest windows show more than it (disputed: only the images can tell
    correlated noise from smooth motion). Dropped (what the pipeline does when the images held still), the noise
    comes from the samples and the holds are found; an honest claim is not disputed."""
    from scipy.signal import butter, sosfilt

    rate = 400.0
    t, a, w, holds = trace(rng, rate, [("hold", 3.0), ("move", 1.0), ("hold", 3.0), ("move", 1.0), ("hold", 3.0)],
                           accel_sigma=0.0, gyro_sigma=0.0)
    sos = butter(2, 20.0, fs=rate, output="sos")
    for x, sigma in ((a, 0.02), (w, 0.002)):
        n = sosfilt(sos, rng.normal(size=x.shape), axis=0)
        x += sigma * n / n.std(axis=0)
    claim = ((np.eye(3) * 0.004 ** 2).ravel(), (np.eye(3) * 0.0004 ** 2).ravel())
    z = ZuptDetector(ZuptConfig())
    for k in range(len(t)):
        z.add(t[k], a[k], w[k], covariance=claim)
    assert claim_disputed(z.noise) and not z.covariance_distrusted
    assert not any(z.is_still(h0 + 0.5, h1 - 0.5) for h0, h1 in holds)
    assert z.distrust_covariance() and z.covariance_distrusted and not z.distrust_covariance()
    assert z.noise.source is NoiseSource.DATA
    assert all(z.is_still(h0 + 0.5, h1 - 0.5) for h0, h1 in holds)
    z.add(t[-1] + 1.0 / rate, a[-1], w[-1], covariance=claim)  # later claims are not taken again
    assert z.noise.source is NoiseSource.DATA
    honest = ZuptDetector(ZuptConfig())
    t, a, w = still_trace(rng, rate=rate)
    for k in range(len(t)):
        honest.add(t[k], a[k], w[k], covariance=((np.eye(3) * 0.02 ** 2).ravel(), (np.eye(3) * 0.002 ** 2).ravel()))
    assert not claim_disputed(honest.noise)


@pytest.mark.parametrize("rate, creep_deg_s", [(50.0, 0.5), (200.0, 0.2), (200.0, 0.5), (1000.0, 0.2),
                                              (1000.0, 0.5)])
def test_a_creep_the_accelerometer_sees_turn_is_no_bias(rng, rate, creep_deg_s):
    """Still 1.5 s, then a creep about a horizontal axis for 5 s: the quiet windows are mostly the creep's (the
    bias came out as its rate), but the accelerometer's direction turns through it (0.2 deg/s: 5.5 of its stds
    over a second at 200 Hz; 50 Hz needs 0.35 deg/s), so they lose their vote on the gyro's bias: the noise
    estimated at the end of the creep has a bias well off the creep's rate, and a creep of 0.5 deg/s reads as
    motion."""
    axis = np.array([0.6, 0.8, 0.0])
    t = np.arange(0.0, 6.5, 1.0 / rate)
    crept = t >= 1.5
    angle = np.deg2rad(creep_deg_s) * np.clip(t - 1.5, 0.0, None)
    R = exp_so3(angle[:, None] * axis)  # body -> world
    accel = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, 9.81])) + rng.normal(scale=0.02, size=(len(t), 3))
    gyro = BIAS + np.where(crept[:, None], np.deg2rad(creep_deg_s) * axis, 0.0) + \
        rng.normal(scale=0.002, size=(len(t), 3))
    noise = estimate_noise(t, accel, gyro)
    assert np.linalg.norm(noise.gyro_bias - BIAS) < 0.4 * np.deg2rad(creep_deg_s)
    if creep_deg_s >= 0.5:  # (0.2 deg/s is about the windowed test's limit: the steady-turn test's to find)
        assert not still_mask(t, accel, gyro, noise)[(t > 4.0) & (t < 6.0)].any()


@pytest.mark.parametrize("rate, accel_sigma, gyro_sigma", [(50.0, 0.056, 0.0045), (200.0, 0.03, 0.003),
                                                         (1000.0, 0.1, 0.004)])
def test_creeps_that_together_outlast_the_still_hold_are_no_bias(rate, accel_sigma, gyro_sigma):
    """A still hold of 2.1 s, then two holds that each creep at 0.5 deg/s for 1.7 s, one about a level axis and
    one about the vertical (which the accelerometer does not see), moves between: the creeps' windows outnumber
    the still ones (their median was the creeps'). The still windows share the bias and each creep is a cluster
    of its own: the bias is the densest of the windows' mean rates, and the turn the accelerometer sees is told
    over a creep hold's two halves where it is shorter than two of the blocks the IMU's noise asks for (1.4 s
    at 50 Hz). (A lone creep about the vertical as long as every still hold so far is as dense: nothing the IMU
    reads tells them apart.)"""
    rng = np.random.default_rng(7)
    plan = [("still", 2.1, None), ("move", 1.0, AXIS), ("creep", 1.7, np.array([0.6, 0.8, 0.0])),
            ("move", 1.0, -AXIS), ("creep", 1.7, np.array([0.0, 0.0, 1.0])), ("move", 0.2, AXIS)]
    t = np.arange(0.0, sum(d for _, d, _ in plan), 1.0 / rate)
    w, t0 = np.zeros((len(t), 3)), 0.0
    for kind, d, axis in plan:
        m = (t >= t0) & (t < t0 + d)
        if kind == "move":
            w[m] = 0.6 * np.sin(np.pi * (t[m] - t0) / d)[:, None] ** 2 * axis
        elif kind == "creep":
            w[m] = np.deg2rad(0.5) * axis
        t0 += d
    R = [np.eye(3)]
    for k in range(1, len(t)):
        R.append(R[-1] @ exp_so3(0.5 * (w[k] + w[k - 1]) * (t[k] - t[k - 1])))
    accel = np.einsum("nji,j->ni", np.array(R), np.array([0.0, 0.0, 9.81])) + \
        rng.normal(scale=accel_sigma, size=(len(t), 3))
    gyro = w + BIAS + rng.normal(scale=gyro_sigma, size=(len(t), 3))
    noise = estimate_noise(t, accel, gyro)
    assert np.linalg.norm(noise.gyro_bias - BIAS) < 0.1 * np.deg2rad(0.5)


@pytest.mark.parametrize("rate, accel_sigma", [(50.0, 0.08), (400.0, 0.065), (1000.0, 0.1)])
def test_a_creep_under_a_noisy_accelerometer_is_no_bias(rng, rate, accel_sigma):
    """Still 1.5 s, then holds that creep at 0.5 deg/s for 4 s, still again: an accelerometer 3-5 times noisier
    than the project's (0.065 m/s^2 per sample at 400 Hz) hid the creep's turn from two windows a second apart,
    and the bias came out as the creep's rate. The blocks compared are as long as the IMU's rate and noise need,
    and every sample counts: the bias stays the still rig's, and the still part after reads as still."""
    axis = np.array([0.6, 0.8, 0.0])
    t = np.arange(0.0, 7.0, 1.0 / rate)
    crept = (t >= 1.5) & (t < 5.5)
    angle = np.deg2rad(0.5) * np.clip(np.minimum(t, 5.5) - 1.5, 0.0, None)
    R = exp_so3(angle[:, None] * axis)  # body -> world
    accel = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, 9.81])) + rng.normal(scale=accel_sigma, size=(len(t), 3))
    gyro = BIAS + np.where(crept[:, None], np.deg2rad(0.5) * axis, 0.0) + rng.normal(scale=0.002, size=(len(t), 3))
    early = t < 5.5
    noise = estimate_noise(t[early], accel[early], gyro[early])
    assert np.linalg.norm(noise.gyro_bias - BIAS) < 0.2 * np.deg2rad(0.5)
    assert still_mask(t, accel, gyro, noise)[t > 6.0].mean() > 0.9
