"""ImuBuffer: averaged accelerometer -> gravity (docs/CONVENTIONS.md, Gravity measurements), NaN, gaps, age."""

import math
from dataclasses import replace

import numpy as np
import pytest

from nrmpc_ros.core import gravity_from_accelerometer
from nrmpc_ros.core.rig import ImuMount
from nrmpc_ros.core.so3 import angle_between, exp_so3
from nrmpc_ros.frontend.imu import ImuBuffer, ImuConfig, ImuGravityRefusal, ImuRefusal, ImuReject, describe_gaps


def fill(buf, rng, g_imu, t0=0.0, t1=1.0, rate=200.0, noise=0.05, gyro=None):
    for t in np.arange(t0, t1, 1.0 / rate):
        a = -g_imu + rng.normal(scale=noise, size=3)
        w = rng.normal(scale=0.002, size=3) if gyro is None else gyro
        assert buf.add(t, a, w) is None


def test_body_mount_average(cross_rig, rng):
    buf = ImuBuffer(cross_rig)
    g = 9.81 * np.array([0.3, -0.2, -0.93]) / np.linalg.norm([0.3, -0.2, -0.93])
    fill(buf, rng, g)
    res, why = buf.gravity(0.2, 0.8)
    assert why is None
    assert res.num_samples == 121
    assert math.degrees(angle_between(res.gravity, g)) < 0.1
    assert np.linalg.norm(res.gravity) == pytest.approx(9.81)
    assert res.accel_std == pytest.approx(0.05, rel=0.2)  # per-axis spread of the samples: their noise


def test_rotated_mount_and_camera_mount(cross_rig, rng):
    R_mount_imu = exp_so3(np.array([0.3, -0.5, 1.0]))
    rig = replace(cross_rig, imu=ImuMount(mount="body", rotation=R_mount_imu))
    g_body = np.array([0.0, 0.0, -9.81])
    g_imu = R_mount_imu.T @ g_body
    buf = ImuBuffer(rig)
    fill(buf, rng, g_imu, noise=0.0)
    res, _ = buf.gravity(0.0, 1.0)
    np.testing.assert_allclose(res.gravity, g_body, atol=1e-9)
    # IMU in a camera that bends: same as the core's conversion of the mean reading
    rig_cam = replace(cross_rig, imu=ImuMount(mount="cam1", rotation=np.eye(3)))
    buf = ImuBuffer(rig_cam)
    fill(buf, rng, np.array([0.5, 9.7, 1.0]))
    res, _ = buf.gravity(0.0, 1.0)
    np.testing.assert_allclose(res.gravity, gravity_from_accelerometer(rig_cam, res.accel_mean), atol=1e-12)


def test_nan_out_of_order_and_shape_are_counted_not_raised(cross_rig, rng):
    buf = ImuBuffer(cross_rig)
    fill(buf, rng, np.array([0, 0, -9.81]), 0.0, 0.5)
    assert buf.add(0.6, [np.nan, 0, 9.8], [0, 0, 0]) is ImuReject.NOT_FINITE
    assert buf.add(0.61, [0, 0, 9.8], [0, np.inf, 0]) is ImuReject.NOT_FINITE
    assert buf.add(0.1, [0, 0, 9.8], [0, 0, 0]) is ImuReject.OUT_OF_ORDER
    assert buf.add(0.62, [0, 9.8], [0, 0, 0]) is ImuReject.WRONG_SHAPE
    assert buf.stats[ImuReject.NOT_FINITE] == 2
    assert buf.stats[ImuReject.OUT_OF_ORDER] == 1
    assert buf.stats["samples"] == 100
    res, why = buf.gravity(0.0, 0.5)
    assert why is None and np.all(np.isfinite(res.gravity))


def test_gaps_are_counted_and_reported(cross_rig, rng):
    buf = ImuBuffer(cross_rig, ImuConfig())
    g = np.array([0, 0, -9.81])
    fill(buf, rng, g, 0.0, 0.4)
    fill(buf, rng, g, 0.7, 1.0)
    assert buf.stats["gaps"] == 1
    res, why = buf.gravity(0.0, 1.0)
    assert why is None and len(res.gaps) == 1
    assert res.gaps[0][0] == pytest.approx(0.395) and res.gaps[0][1] == pytest.approx(0.7)
    res, _ = buf.gravity(0.75, 1.0)
    assert res.gaps == []


def test_the_longest_gap_is_told(cross_rig, rng):
    """The replay's summary and /diagnostics say how many gaps the stream had and the longest, however old."""
    buf = ImuBuffer(cross_rig, ImuConfig(capacity_s=1.0))
    g = np.array([0, 0, -9.81])
    assert describe_gaps(buf) == ""
    fill(buf, rng, g, 0.0, 0.4)
    fill(buf, rng, g, 0.9, 1.2)  # 0.5 s missing
    fill(buf, rng, g, 1.3, 3.0)  # 0.1 s missing; both gaps leave the history kept
    text = describe_gaps(buf)
    assert buf.gaps == [] and text.startswith("2 gaps") and "the longest 0.505 s from 0.395 s" in text


@pytest.mark.parametrize("rate", [50.0, 100.0, 1000.0])
def test_gaps_ages_and_pads_follow_the_measured_rate(cross_rig, rng, rate):
    """A gap is gap_periods sample periods whatever the rate: 8 missing samples are a gap at 1000 Hz and at
    50 Hz, a late sample of 1.5 periods is not; the max age and a snapshot's pad are never below the rate's."""
    buf = ImuBuffer(cross_rig)
    g = np.array([0, 0, -9.81])
    fill(buf, rng, g, 0.0, 1.0, rate=rate)
    assert buf.period_s == pytest.approx(1.0 / rate)
    fill(buf, rng, g, 1.0 + 8.0 / rate, 1.5, rate=rate)  # 8 samples missing
    fill(buf, rng, g, 1.5 + 1.5 / rate, 2.0, rate=rate)  # one late sample
    assert buf.stats["gaps"] == 1
    assert buf.max_age_s >= buf.config.gap_periods / rate and buf.max_age_s >= buf.config.max_age_s
    res, why = buf.gravity(2.0 - 1.0 / rate, 2.0 - 1.0 / rate)  # one frame: the pad holds min_samples samples
    assert why is None and res.num_samples >= buf.config.min_samples


def test_max_age(cross_rig, rng):
    buf = ImuBuffer(cross_rig, ImuConfig(max_age_s=0.1))
    fill(buf, rng, np.array([0, 0, -9.81]), 0.0, 1.0)
    assert buf.has_recent(1.05) and not buf.has_recent(1.5)
    res, why = buf.gravity(0.8, 1.5)
    assert res is None and why.rule is ImuRefusal.STALE and "older than the view" in str(why)
    res, why = buf.gravity(3.0, 3.5)
    assert res is None and why.rule is ImuRefusal.FEW_SAMPLES and "IMU samples in the window" in str(why)
    assert ImuBuffer(cross_rig).gravity(0.0, 1.0) == (None, ImuGravityRefusal(ImuRefusal.NO_SAMPLES))


def test_rig_without_imu_block(cross_rig, rng):
    buf = ImuBuffer(replace(cross_rig, imu=None))
    fill(buf, rng, np.array([0, 0, -9.81]), 0.0, 0.2)
    assert buf.gravity(0.0, 0.2) == (None, ImuGravityRefusal(ImuRefusal.NO_IMU_BLOCK))


def test_history_is_trimmed(cross_rig, rng):
    buf = ImuBuffer(cross_rig, ImuConfig(capacity_s=1.0))
    fill(buf, rng, np.array([0, 0, -9.81]), 0.0, 5.0)
    assert len(buf) <= 200 * 1.0 + 2
    t, _, _ = buf.window(0.0, 10.0)
    assert t[0] >= 3.99 - 1e-9


def test_long_stream_window_matches_every_kept_sample(cross_rig, rng):
    """Many block moves, trims and compactions of the buffer: windows hold exactly the samples kept, in order."""
    buf = ImuBuffer(cross_rig, ImuConfig(capacity_s=2.0))
    ts = np.cumsum(rng.uniform(0.002, 0.008, 6000))
    ts[3000:] += 0.5  # one gap, later trimmed away with its samples
    acc = rng.normal(size=(len(ts), 3))
    gyr = rng.normal(size=(len(ts), 3))
    for k, t in enumerate(ts):
        assert buf.add(t, acc[k], gyr[k]) is None
        if k % 997 == 0 or k == 3001:  # reads in between (consolidation of a partial block)
            t0 = t - 1.5
            got_t, got_a, got_w = buf.window(t0, t)
            sel = (ts[:k + 1] >= t0) & (ts[:k + 1] <= t)
            np.testing.assert_array_equal(got_t, ts[:k + 1][sel])
            np.testing.assert_array_equal(got_a, acc[:k + 1][sel])
            np.testing.assert_array_equal(got_w, gyr[:k + 1][sel])
            if k == 3001:
                assert len(buf.gravity(t0, t)[0].gaps) == 1
    kept = ts >= ts[-1] - 2.0
    assert len(buf) == kept.sum()
    np.testing.assert_array_equal(buf.window(0.0, ts[-1])[0], ts[kept])
    assert buf.stats["gaps"] == 1 and buf.gaps == []  # the gap is older than the history now
    t, a, _ = buf.window(ts[-1] - 0.1, ts[-1])
    a[:] = 0.0  # windows are copies: the buffer keeps its samples
    assert np.all(buf.window(ts[-1] - 0.1, ts[-1])[1] != 0.0)


def test_sample_containers(cross_rig):
    """Any container of three numbers is a sample; other sizes are rejected as wrong shape; no gyro reads zero."""
    buf = ImuBuffer(cross_rig)
    ok = [(0.1, 0.2, 9.8), [0.1, 0.2, 9.8], np.array([0.1, 0.2, 9.8]), np.array([[0.1, 0.2, 9.8]]),
          np.array([[0.1], [0.2], [9.8]]), np.array([0, 0, 10], dtype=np.int32), [[0.1], [0.2], [9.8]]]
    for k, a in enumerate(ok):
        assert buf.add(0.01 * k, a, np.zeros(3) if k % 2 else None) is None
    _, a, w = buf.window(0.0, 1.0)
    np.testing.assert_array_equal(a[:-2], [[0.1, 0.2, 9.8]] * 5)
    np.testing.assert_array_equal(a[-2], [0.0, 0.0, 10.0])
    assert np.all(w == 0.0)
    for bad in ([0.0, 9.8], np.zeros(4), np.zeros((2, 3)), 9.8):
        assert buf.add(1.0, bad) is ImuReject.WRONG_SHAPE
    assert buf.add(1.0, [0, 0, 9.8], [0, 0]) is ImuReject.WRONG_SHAPE
    assert buf.stats[ImuReject.WRONG_SHAPE] == 5 and buf.stats["samples"] == len(ok)


def test_a_mean_over_a_fraction_of_a_swing_carries_the_swing_in_its_std(cross_rig, rng):
    """An IMU in a camera on a bar ringing at 1.5 Hz, its tip swinging by 0.1 rad: over 0.1 s (a sixth of a
    period) the samples may all lie on one side of the swing, and their spread does not show how far the mean is
    from the rest. The mean's std takes the swing's angle (the gyro's largest rate over the period before, over
    the angular frequency) times gravity: the mean lies within 2 of its stds of the rest reading wherever the
    span falls in the swing."""
    rig = replace(cross_rig, imu=ImuMount(mount="cam1", rotation=np.eye(3)))
    buf = ImuBuffer(rig, ringing_hz=1.5)
    rest = np.array([0.5, 9.7, 1.0])
    omega = 2.0 * math.pi * 1.5
    axis = np.array([1.0, 0.0, 0.0])
    t = np.arange(0.0, 4.0, 1.0 / 200.0)
    angle = 0.1 * np.exp(-0.28 * t) * np.sin(omega * t)
    rate = 0.1 * np.exp(-0.28 * t) * (omega * np.cos(omega * t) - 0.28 * np.sin(omega * t))
    for k in range(len(t)):
        a = exp_so3(angle[k] * axis).T @ rest + rng.normal(scale=0.02, size=3)
        assert buf.add(t[k], a, rate[k] * axis + rng.normal(scale=0.002, size=3)) is None
    misses = []
    for t1 in np.arange(1.0, 3.9, 0.05):
        res, why = buf.gravity(t1 - 0.1, t1)
        assert why is None
        misses.append(float(np.abs(res.accel_mean - rest).max() / res.accel_mean_std))
    assert max(misses) <= 2.0
