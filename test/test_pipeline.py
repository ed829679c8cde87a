"""Pipeline on rendered frames in memory: holds found in a stream, 4pt/6pt estimates per hold, bad input."""

import math
from dataclasses import replace

import numpy as np
import pytest

from nrmpc_ros.core.so3 import angle_between, exp_so3, log_so3, rotation_angle
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.pipeline import FrameSet, Pipeline, PipelineConfig
from nrmpc_ros.render import Renderer, make_scene
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

GW = np.array([0.0, 0.0, -9.81])
RATE_HZ = 10.0
HOLD_S = 1.5
MOVE_S = 0.6


def tilt(az_deg, tilt_deg, yaw_deg=0.0):
    az, t = math.radians(az_deg), math.radians(tilt_deg)
    return exp_so3(np.array([0, 0, math.radians(yaw_deg)])) @ exp_so3(t * np.array([math.cos(az), math.sin(az), 0]))


ATTITUDES = [tilt(0, 15), tilt(50, 25, 8), tilt(110, 18, -4), tilt(170, 28, 6), tilt(230, 16, 0)]  # 22-28 deg apart


def make_stream(rig, seed=0):
    """A 10 Hz stream through holds (1.5 s) and moves (0.6 s, cosine profile) of the rig, bars bending
    quasi-statically: [(stamp, R_world_body, p_world_body, images)], and 200 Hz IMU samples
    [(stamp, specific force, angular rate)] in the body frame (the rig's IMU sits at the body centre)."""
    rng = np.random.default_rng(seed)
    r = Renderer(rig, make_scene(0))
    poses = [(R, np.array([0.03 * k, -0.02 * k, 0.01 * (k % 2)])) for k, R in enumerate(ATTITUDES)]
    dt = 1.0 / RATE_HZ
    timeline = []  # (t0, t1, from pose, to pose)
    t = 100.0
    for k, pose in enumerate(poses):
        if k:
            timeline.append((t, t + MOVE_S, poses[k - 1], pose))
            t += MOVE_S
        timeline.append((t, t + HOLD_S, pose, pose))
        t += HOLD_S

    def pose_at(s):
        for t0, t1, (R0, p0), (R1, p1) in timeline:
            if s <= t1 + 1e-9:
                u = 0.5 - 0.5 * math.cos(math.pi * min(max((s - t0) / (t1 - t0), 0.0), 1.0))
                w = log_so3(R1 @ R0.T)
                rate = w * (0.5 * math.pi * math.sin(math.pi * (s - t0) / (t1 - t0)) / (t1 - t0))
                return exp_so3(w * u) @ R0, p0 + (p1 - p0) * u, rate
        R, p = timeline[-1][3]
        return R, p, np.zeros(3)

    still = {}
    frames = []
    for st in np.arange(100.0 + dt, t, dt):
        R, p, w = pose_at(st)
        key = (round(float(R[0, 0]), 12), round(float(R[1, 2]), 12)) if not np.any(w) else None
        if key is None or key not in still:
            imgs = r.render_rig(R, p, R.T @ GW)
            if key is not None:
                still[key] = imgs
        else:
            imgs = still[key]
        noisy = [np.clip(im + rng.normal(scale=1.0, size=im.shape), 0, 255).astype(np.uint8) for im in imgs]
        frames.append((float(st), R, p, noisy))
    imu = []
    for ti in np.arange(100.0, t, 0.005):
        R, _, w = pose_at(ti)
        imu.append((float(ti), -(R.T @ GW) + rng.normal(scale=0.02, size=3),
                    R.T @ w + rng.normal(scale=0.002, size=3)))
    return frames, imu


@pytest.fixture(scope="module")
def rig3():
    return make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.3, mass=0.15, bar_length=0.3, focal=235.0,
                            resolution=(320, 240)))


@pytest.fixture(scope="module")
def stream(rig3):
    return make_stream(rig3)


def run(rig, frames, imu=(), method="auto", config=None, bad=None, drop=None):
    """Frames and IMU samples through one pipeline in stamp order; returns (pipeline, estimates)."""
    pipe = Pipeline(rig, config or PipelineConfig(), method=method)
    imu = list(imu)
    ests, k = [], 0
    for st, _, _, imgs in frames:
        while k < len(imu) and imu[k][0] <= st:
            pipe.add_imu(*imu[k])
            k += 1
        if bad and st in bad:
            with pytest.raises(InputError) as err:
                pipe.add_frames(FrameSet(st, bad[st](imgs)))
            bad[st] = str(err.value)
        if drop:
            imgs = drop(st, imgs)
        ests += pipe.add_frames(FrameSet(st, imgs))
    return pipe, ests + pipe.flush()


def errors(frames, e):
    """(rotation, gravity, translation direction) errors of a hold estimate against the truth (deg)."""
    pose = {st: (R, p) for st, R, p, _ in frames}
    (R1, p1), (R2, p2) = pose[e.ref_stamp], pose[e.stamp]
    rot = math.degrees(rotation_angle((R1.T @ R2).T @ e.R))
    grav = math.degrees(angle_between(e.gravity, R2.T @ GW)) if e.gravity is not None else math.nan
    tdir = math.degrees(angle_between(e.t, R1.T @ (p2 - p1)))
    return rot, grav, tdir


def test_holds_of_a_stream_with_imu_use_4pt(rig3, stream):
    frames, imu = stream
    pipe, ests = run(rig3, frames, imu)
    assert pipe.stats.holds == len(ATTITUDES)
    assert len(ests) == len(ATTITUDES) - 1
    assert {e.method for e in ests} == {"4pt-bending"}
    assert len({e.hold_index for e in ests}) == len(ests) and all(e.sequence == 0 for e in ests)
    for e in ests:
        rot, grav, tdir = errors(frames, e)
        assert rot < 0.3 and grav < 0.5 and tdir < 10.0, (rot, grav, tdir)
        assert e.imu_gravity is not None and e.gravity_sigma_deg > 0
        assert e.hold.settled_frames >= 3


def test_without_imu_auto_runs_6pt_bending(rig3, stream):
    frames, _ = stream
    pipe, ests = run(rig3, frames)
    assert len(ests) == len(ATTITUDES) - 1 and {e.method for e in ests} == {"6pt-bending"}
    for e in ests:
        rot, grav, _ = errors(frames, e)
        assert rot < 0.5 and grav < max(3.0 * e.gravity_sigma_deg, 0.5), (rot, grav, e.gravity_sigma_deg)
        assert e.imu_gravity is None
    sigmas = [e.gravity_sigma_deg for e in ests]
    assert sigmas[-1] < sigmas[0] < 3.0  # the joint estimate sharpens as holds come in


def test_nonbending_reports_no_gravity(rig3, stream):
    frames, imu = stream
    _, ests = run(rig3, frames, imu, method="6pt-nonbending")
    assert ests and all(e.gravity is None and e.method == "6pt-nonbending" for e in ests)


def test_forced_4pt_without_imu_is_counted(rig3, stream):
    frames, _ = stream
    pipe, ests = run(rig3, frames, method="4pt-bending")
    assert ests == []
    assert pipe.stats.holds == len(ATTITUDES)
    assert pipe.stats.dropped["hold without IMU gravity (4pt-bending forced)"] == len(ATTITUDES)


def test_a_camera_missing_from_some_frame_sets(rig3, stream):
    frames, imu = stream
    stamps = [st for st, *_ in frames]
    gone = set(stamps[1::4])

    def drop(st, imgs):
        return [None if (i == 1 and st in gone) else im for i, im in enumerate(imgs)]

    _, ests = run(rig3, frames, imu, drop=drop)
    assert len(ests) == len(ATTITUDES) - 1
    for e in ests:
        rot, grav, _ = errors(frames, e)
        assert rot < 0.3 and grav < 0.5


def test_bad_frames_raise_and_pipeline_keeps_working(rig3, stream):
    frames, imu = stream
    _, clean = run(rig3, frames, imu)
    stamps = [st for st, *_ in frames]
    bad = {
        stamps[3]: lambda imgs: [imgs[0], imgs[1][:-2], imgs[2]],  # wrong size
        stamps[9]: lambda imgs: imgs[:2],  # wrong number of images
        stamps[30]: lambda imgs: [imgs[0], imgs[1].astype(np.float32), imgs[2]],  # wrong dtype
        stamps[40]: lambda imgs: [None, None, None],  # nothing at all
    }
    noisy_imu = list(imu) + [(stamps[5] - 0.0001, [np.nan, 0, 9.8], [0, 0, 0])]
    noisy_imu.sort(key=lambda s: s[0])
    pipe, ests = run(rig3, frames, noisy_imu, bad=bad)
    assert "/cam1/image_raw" in bad[stamps[3]] and "resolution" in bad[stamps[3]]
    assert "2 images" in bad[stamps[9]] and "3 cameras" in bad[stamps[9]]
    assert "/cam1/image_raw" in bad[stamps[30]] and "uint8" in bad[stamps[30]]
    assert "no camera" in bad[stamps[40]]
    assert pipe.stats.dropped["imu sample: NaN or inf"] == 1
    assert [e.stamp for e in ests] == [e.stamp for e in clean]
    for a, b in zip(ests, clean):
        np.testing.assert_allclose(a.R, b.R, atol=1e-4)


def test_out_of_order_frames_and_bad_options(rig3, stream):
    frames, _ = stream
    pipe = Pipeline(rig3)
    pipe.add_frames(FrameSet(frames[1][0], frames[1][3]))
    assert pipe.add_frames(FrameSet(frames[0][0], frames[0][3])) == []
    assert pipe.stats.dropped["frame set out of order"] == 1
    with pytest.raises(InputError, match="method"):
        Pipeline(rig3, method="8pt")
    with pytest.raises(InputError, match="tracking.max_trakcs"):
        PipelineConfig.from_dict({"tracking": {"max_trakcs": 1}})
    with pytest.raises(InputError, match="unknown option"):
        PipelineConfig.from_dict({"min_matchez": 1})
    cfg = PipelineConfig.from_dict({"tracking": {"descriptor": "sift"}, "imu": {"max_age_s": 0.2}, "seed": 3})
    assert cfg.tracking.descriptor == "sift" and cfg.imu.max_age_s == 0.2 and cfg.seed == 3


def test_rig_without_imu_block_ignores_samples(rig3, stream):
    frames, imu = stream
    pipe, ests = run(replace(rig3, imu=None), frames[:40], imu)
    assert ests and all(e.method == "6pt-bending" for e in ests)
    assert pipe.stats.dropped["imu sample ignored: rig file has no imu block"] > 0


def test_a_recording_without_any_hold_says_why(rig3, stream):
    """An IMU that never stops turning: every frame set is counted as not at rest and the report gives the
    IMU's noise the stillness test used; without the IMU the image motion is named with its numbers."""
    frames, _ = stream
    rng = np.random.default_rng(5)
    t0, t1 = frames[0][0] - 1.0, frames[30][0]
    spinning = [(float(t), [0.0, 0.0, 9.81] + rng.normal(scale=0.02, size=3), [0.0, 0.0, 0.5])
                for t in np.arange(t0, t1, 0.005)]
    pipe, ests = run(rig3, frames[:30], spinning)
    assert ests == [] and pipe.stats.holds == 0
    report = pipe.no_hold_report()
    assert report.startswith("no hold found in 30 frame sets")
    assert "29 frame sets not at rest: the IMU says the rig moved" in report  # every one after the first
    assert "IMU stillness test: noise" in report and "m/s^2" in report
    pipe, _ = run(rig3, [f for f in frames if 101.55 < f[0] < 102.15])  # no IMU, the first move only
    report = pipe.no_hold_report()
    assert "0.3 px between two frames" in report and "the images alone decided" in report
    assert "before the bars settle (2 periods of 0.421 s)" in report, report  # a start too short to be a hold
