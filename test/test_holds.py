"""Holds: settled part after ringing and before motion, averaged positions and their noise, snapshots."""

import math

import numpy as np
import pytest

from nrmpc_ros.config import from_mapping
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.holds import HoldConfig, HoldRecorder, slowest_bar_period
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

RATE = 10.0


def record(offsets, noise=0.02, cams=2, n=40, seed=0, missing=()):
    """A recorder whose frames move every track of camera c by offsets[f] (F, 2) (same for all cameras) plus
    Gaussian noise; frames in ``missing`` lack camera 1."""
    rng = np.random.default_rng(seed)
    ids = np.arange(n)
    base = rng.uniform(20, 300, size=(n, 2))
    anchors = [(ids, base.copy()) for _ in range(cams)]
    rec = HoldRecorder(0.0, anchors, [None] * cams)
    for f, o in enumerate(offsets):
        pos = []
        for c in range(cams):
            if c == 1 and f in missing:
                pos.append(None)
            else:
                pos.append((ids, base + o + rng.normal(scale=noise, size=base.shape)))
        rec.add(f / RATE, pos)
    return rec, base


def test_a_still_hold_is_averaged():
    F = 30
    rec, base = record(np.zeros((F, 2)), noise=0.05)
    hold, why = rec.measure(HoldConfig(), bar_period_s=0.0)
    assert hold is not None, why
    assert hold.settled_frames == F and hold.settle_s == 0.0
    for ch in hold.cameras:
        assert ch.frames == F
        assert ch.noise_px == pytest.approx(0.05, rel=0.15)
        assert np.abs(ch.uv - base).max() < 5 * 0.05 / math.sqrt(F)
    assert hold.averaged_noise_px == pytest.approx(hold.noise_px / math.sqrt(F), rel=1e-9)
    assert hold.settled_start <= hold.stamp <= hold.settled_end


def test_ringing_is_waited_out():
    """A decaying oscillation of the image: the settled part starts once its amplitude is below the threshold
    (and at least two bar periods after the stop)."""
    f_bar, zeta, amp = 2.0, 0.1, 3.0
    t = np.arange(60) / RATE
    env = amp * np.exp(-zeta * 2 * math.pi * f_bar * t)
    offsets = np.stack([env * np.cos(2 * math.pi * f_bar * t + 0.3), 0.5 * env * np.sin(2 * math.pi * f_bar * t)], 1)
    rec, _ = record(offsets, noise=0.01)
    cfg = HoldConfig(settle_px=0.1)
    hold, why = rec.measure(cfg, bar_period_s=1.0 / f_bar)
    assert hold is not None, why
    dev = np.linalg.norm(offsets, axis=1)  # the rest position is the origin here
    k = int(round(hold.settle_s * RATE))
    assert np.all(dev[k:] <= cfg.settle_px + 0.02)  # every frame of the settled part within the threshold ...
    assert dev[k - 1] > cfg.settle_px - 0.02  # ... and the frame before it not
    implied = math.log(amp / cfg.settle_px) / (zeta * 2 * math.pi * f_bar)  # the envelope's own settling time
    assert hold.settle_s <= implied + 1.0 / RATE
    assert hold.residual_px <= cfg.settle_px
    assert hold.settled_end == pytest.approx(t[-1])


def test_ringing_that_outlasts_the_hold_is_averaged_over_whole_periods():
    """Lightly damped bars still ring when the hold ends: the last frames spanning whole bar periods average the
    oscillation out, far better than any single frame."""
    f_bar, zeta, amp = 2.5, 0.01, 2.0
    t = np.arange(50) / RATE
    env = amp * np.exp(-zeta * 2 * math.pi * f_bar * t)
    offsets = np.stack([env * np.cos(2 * math.pi * f_bar * t + 0.4), 0.6 * env * np.sin(2 * math.pi * f_bar * t)], 1)
    rec, base = record(offsets, noise=0.01)
    hold, why = rec.measure(HoldConfig(), bar_period_s=1.0 / f_bar)
    assert hold is not None and hold.ringing, why
    span = hold.settled_frames / RATE
    assert span == pytest.approx(round(span * f_bar) / f_bar, abs=1e-9) and span * f_bar >= 4  # whole periods
    assert hold.settled_end == pytest.approx(t[-1])
    err = max(np.abs(ch.uv - base).max() for ch in hold.cameras)
    assert err < 0.05 * np.linalg.norm(offsets[-1])  # the ringing at the end is ~1.5 px
    cfg = HoldConfig()
    assert rec.settled_duration(cfg, 1.0 / f_bar) == 0.0  # measured when the hold ends, not early
    short, why = record(offsets[:11], noise=0.01)[0].measure(cfg, bar_period_s=1.0 / f_bar)
    assert short is None and "bar period" in why  # less than one period after the settle time: no hold


def test_settle_waits_for_two_bar_periods():
    rec, _ = record(np.zeros((30, 2)))
    hold, _ = rec.measure(HoldConfig(settle_periods=2.0), bar_period_s=0.7)
    assert hold.settle_s == pytest.approx(1.4, abs=1.0 / RATE)
    hold, why = rec.measure(HoldConfig(settle_periods=2.0), bar_period_s=2.0)  # the hold is shorter than that
    assert hold is None and "before the bars settle" in why


def test_the_start_of_a_move_is_left_out():
    """The last frames creep away as the next move starts: the settled part ends before them."""
    offsets = np.zeros((30, 2))
    offsets[25:, 0] = 0.05 * np.arange(1, 6) ** 3  # a smooth start: 0.05, 0.4, 1.35, ... px
    rec, _ = record(offsets, noise=0.01)
    hold, _ = rec.measure(HoldConfig(settle_px=0.1), bar_period_s=0.0)
    assert hold.settled_end <= 25 / RATE
    assert hold.settled_frames >= 24


def test_missing_frames_of_a_camera():
    rec, _ = record(np.zeros((20, 2)), missing={3, 4, 11})
    hold, _ = rec.measure(HoldConfig(), bar_period_s=0.0)
    assert hold.settled_frames == 20
    assert hold.cameras[0].frames == 20 and hold.cameras[1].frames == 17


def test_a_hold_that_never_settles_says_why():
    t = np.arange(30) / RATE
    offsets = np.stack([2.0 * np.sin(2 * math.pi * 3.3 * t), np.zeros_like(t)], 1)  # vibration that never stops
    rec, _ = record(offsets, noise=0.01)
    hold, why = rec.measure(HoldConfig(), bar_period_s=0.0)
    assert hold is None and "never settled" in why and "px" in why


def test_snapshots():
    rec, base = record(np.zeros((1, 2)))
    hold, _ = rec.measure(HoldConfig(), bar_period_s=0.5)  # no IMU: taken as settled
    assert hold is not None and hold.snapshot and hold.settled_frames == 1
    assert math.isnan(hold.noise_px)
    hold, why = rec.measure(HoldConfig(), bar_period_s=0.5, imu_still_since=-0.4)  # still for 0.4 s < 2 periods
    assert hold is None and "before the bars settle" in why
    hold, _ = rec.measure(HoldConfig(), bar_period_s=0.5, imu_still_since=-3.0)
    assert hold is not None and hold.settle_s == pytest.approx(3.0)


def test_too_few_tracks():
    rec, _ = record(np.zeros((5, 2)), n=5)
    hold, why = rec.measure(HoldConfig(min_tracks=8), bar_period_s=0.0)
    assert hold is None and "tracks" in why


def test_slowest_bar_period():
    rig = make_rig(RigSpec(num_cameras=2, layout="line", EI=1.0, mass=0.15, bar_length=0.3))
    f = math.sqrt(3 * 1.0 / (0.15 * 0.3**3)) / (2 * math.pi)
    assert slowest_bar_period(rig) == pytest.approx(1 / f)
    assert slowest_bar_period(rig.as_rigid()) == 0.0


def test_config_errors():
    with pytest.raises(InputError, match="holds.settle_px"):
        from_mapping(HoldConfig, {"settle_px": -1}, prefix="holds.")
    with pytest.raises(InputError, match="min_tracks"):
        HoldConfig(min_tracks=0)
