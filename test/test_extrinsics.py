"""Cameras' extrinsics at every frame set: from the pipeline (IMU-driven bars), in replay --extrinsics."""

import csv
import dataclasses

import numpy as np
import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.core.bar_state import BarPropagator
from nrmpc_ros.core.deformation import deformed_extrinsics
from nrmpc_ros.core.so3 import exp_so3, quat_xyzw_to_matrix, rotation_angle
from nrmpc_ros.frontend.drops import Drop
from nrmpc_ros.frontend.extrinsics import EXTRINSICS_HEADER, ExtrinsicsCsv, ExtrinsicsSource, hold_poses
from nrmpc_ros.frontend.pipeline import FrameSet, Pipeline
from nrmpc_ros.frontend.runner import PipelineRunner
from nrmpc_ros.sim.synthetic import RigSpec, make_rig


def _rig(imu=True):
    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.3, mass=0.1, bar_length=0.3, resolution=(64, 48)),
                   imu=imu)
    return dataclasses.replace(rig, cameras=tuple(dataclasses.replace(c, damping=0.03) for c in rig.cameras))


def _samples(n=400, seed=1):
    rng = np.random.default_rng(seed)
    t = 100.0 + np.arange(n) * 0.005
    accel = np.array([0.0, 0.0, 9.81]) + 0.5 * np.sin(np.outer(t, [3.0, 5.0, 7.0])) + rng.normal(0, 0.01, (n, 3))
    gyro = 0.3 * np.cos(np.outer(t, [2.0, 1.0, 4.0]))
    return t, accel, gyro


def test_the_pipeline_answers_each_camera_at_its_image_stamp():
    rig = _rig()
    pipe = Pipeline(rig)
    ref = BarPropagator(rig)
    t, accel, gyro = _samples()
    for k in range(len(t)):
        pipe.add_imu(t[k], accel[k], gyro[k])
        ref.add_imu(t[k], accel[k], gyro[k])
    images = [np.zeros((48, 64), np.uint8), None, np.zeros((48, 64), np.uint8)]
    stamps = [101.0, None, 101.013]
    poses = pipe.camera_poses(FrameSet(101.005, images, stamps))
    assert poses.source is ExtrinsicsSource.IMU and poses.cameras.tolist() == [0, 2]
    assert poses.stamps.tolist() == [101.0, 101.013]
    w, W = ref.extrinsics_at([101.0, 101.013])
    assert np.allclose(poses.positions, w[[0, 1], [0, 2]], atol=1e-15)
    assert np.allclose(poses.rotations, W[[0, 1], [0, 2]], atol=1e-15)
    assert Pipeline(_rig(imu=False)).camera_poses(FrameSet(101.0, images)) is None, "no IMU: nothing between holds"


def test_the_imu_clock_offset_of_the_pipeline_config_moves_the_samples():
    from nrmpc_ros.frontend.pipeline import PipelineConfig

    rig = _rig()
    late = Pipeline(rig, PipelineConfig(imu_time_offset_s=0.02))
    ref = Pipeline(rig)
    t, accel, gyro = _samples()
    for k in range(len(t)):
        late.add_imu(t[k], accel[k], gyro[k])
        ref.add_imu(t[k] + 0.02, accel[k], gyro[k])
    fs = FrameSet(101.0, [np.zeros((48, 64), np.uint8)] * 3)
    assert np.allclose(late.camera_poses(fs).rotations, ref.camera_poses(fs).rotations, atol=1e-14)


def test_the_runner_hands_the_poses_of_every_frame_set_over():
    rig = _rig()
    got = []
    runner = PipelineRunner(rig, on_poses=got.append)
    t, accel, gyro = _samples()
    from nrmpc_ros.frontend.work import Work, WorkKind

    for k in range(len(t)):
        runner.run(Work(WorkKind.IMU, t[k], (accel[k], gyro[k])))
    rng = np.random.default_rng(0)
    for s in (101.0, 101.1):
        runner.run(Work(WorkKind.FRAMES, s, (FrameSet(s, [rng.integers(0, 255, (48, 64), dtype=np.uint8)] * 3), 0.0)))
    assert len(got) == 2 and runner.poses_sets == 2 and got[1].stamps.tolist() == [101.1] * 3


def test_the_csv_rows_and_the_static_poses_of_a_hold(tmp_path):
    rig = _rig()
    g = np.array([0.5, 1.0, -9.7])
    poses = hold_poses(rig, 12.5, g)
    w, W = deformed_extrinsics(rig, g)
    assert poses.source is ExtrinsicsSource.HOLD and np.allclose(poses.positions, w) and np.allclose(poses.rotations, W)
    out = tmp_path / "x.csv"
    with ExtrinsicsCsv(out, rig) as xs:
        xs.write(poses)
        assert not out.exists(), "written atomically: the file appears at the end"
    rows = list(csv.reader(out.open()))
    assert rows[0] == EXTRINSICS_HEADER and len(rows) == 4
    assert rows[2][1] == rig.cameras[1].name and rows[2][-1] == "hold"
    q = np.array([float(v) for v in rows[2][5:9]])
    assert rotation_angle(quat_xyzw_to_matrix(q).T @ W[1]) < 1e-8
    with pytest.raises(RuntimeError):
        with ExtrinsicsCsv(tmp_path / "y.csv", rig) as xs:
            raise RuntimeError("the run failed")
    assert not (tmp_path / "y.csv").exists()


def _gt_extrinsics(bag_path):
    from nrmpc_ros.bag.reader import BagReader

    out = {}
    with BagReader(bag_path) as bag:
        topics = [t for t in bag.topics if t.startswith("/ground_truth/extrinsics/")]
        for topic, _, msg in bag.messages(topics):
            s = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            o, p = msg.pose.orientation, msg.pose.position
            out[(round(s, 6), topic.rsplit("/", 1)[1])] = (np.array([p.x, p.y, p.z]),
                                                            quat_xyzw_to_matrix([o.x, o.y, o.z, o.w]))
    return out


@pytest.mark.slow
def test_replay_extrinsics_match_the_rendered_truth_with_a_noise_free_imu(tmp_path, capsys):
    """make-bag (ringing bars, rotating moves, noise-free IMU at 2 kHz, min-jerk moves: no acceleration step
    between two samples) then replay --extrinsics: every image's camera pose within 1e-6 rad and 1e-6 m of the
    bag's /ground_truth/extrinsics; without the IMU, one row per camera and hold."""
    rig_path, bag = tmp_path / "rig.yaml", tmp_path / "b"
    assert main(["make-bag", "--cameras", "2", "--layout", "line", "--resolution", "160x120", "--views", "3",
                 "--hold-seconds", "1", "--rate", "10", "--imu-rate", "2000", "--capture", "stream",
                 "--move-seconds", "0.8", "--move-profile", "min-jerk", "--damping", "0.04", "--imu-noise", "0",
                 "--gyro-noise", "0", "--imu-bias", "0", "--gyro-bias", "0", "--max-step", "20", "--save-rig",
                 str(rig_path), "--no-progress", "--out", str(bag)]) == 0
    out = tmp_path / "x.csv"
    config = tmp_path / "c.yaml"
    config.write_text("imu_bias_sigma_deg: 0\n")  # the IMU is declared unbiased: no bias from the holds' gravity
    online = tmp_path / "causal.csv"
    assert main(["replay", str(bag), "--rig", str(rig_path), "--out", str(tmp_path / "e.csv"), "--extrinsics",
                 str(out), "--extrinsics-causal", str(online), "--config", str(config), "--no-progress",
                 "--quiet"]) == 0
    truth = _gt_extrinsics(bag)
    causal_rows = list(csv.DictReader(online.open()))
    causal = [(r["stamp"], r["camera"]) for r in causal_rows]
    assert len(causal) >= len(truth) - 2  # from the 2nd IMU sample on
    smoothed_rows = list(csv.DictReader(out.open()))
    assert [(r["stamp"], r["camera"]) for r in smoothed_rows] == causal  # one row per image and camera
    assert {r["source"] for r in causal_rows} == {"imu"} and {r["source"] for r in smoothed_rows} == {"smoothed"}
    rows = causal_rows + smoothed_rows
    rot, pos = [], []
    for r in rows:
        p, R = truth[(round(float(r["stamp"]), 6), r["camera"])]
        q = [float(r[k]) for k in ("qx", "qy", "qz", "qw")]
        rot.append(rotation_angle(R.T @ quat_xyzw_to_matrix(q)))
        pos.append(np.linalg.norm(p - [float(r[k]) for k in ("px", "py", "pz")]))
    assert max(rot) < 1e-6 and max(pos) < 1e-6
    alone = tmp_path / "alone.csv"  # --extrinsics without --extrinsics-causal: the same rows
    assert main(["replay", str(bag), "--rig", str(rig_path), "--out", str(tmp_path / "e2.csv"), "--extrinsics",
                 str(alone), "--config", str(config), "--no-progress", "--quiet"]) == 0
    assert list(csv.DictReader(alone.open())) == smoothed_rows
    capsys.readouterr()
    assert main(["replay", str(bag), "--rig", str(rig_path), "--no-imu", "--out", str(tmp_path / "f.csv"),
                 "--extrinsics", str(tmp_path / "y.csv"), "--no-progress", "--quiet"]) == 0
    assert "only the static extrinsics of holds are available" in capsys.readouterr().out
    held = list(csv.DictReader((tmp_path / "y.csv").open()))
    assert {r["source"] for r in held} <= {"hold"} and len(held) % 2 == 0


def test_the_accelerometer_bias_is_taken_from_the_holds_gravity():
    """A still rig, an accelerometer with a constant bias: after holds at two attitudes whose gravity vision gives,
    the bias is known and the bars carry the true gravity again."""
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics

    rig = _rig()
    bias = np.array([0.03, -0.02, 0.04])  # IMU frame
    fx = FrameExtrinsics(rig)
    R_bi = rig.imu.rotation
    t = 0.0
    for g in (np.array([0.0, 1.0, -9.76]), np.array([1.2, -0.5, -9.72]), np.array([-0.8, 0.3, -9.77])):
        accel = -R_bi.T @ g + bias
        for _ in range(200):
            fx.add_imu(t, accel, (0.0, 0.0, 0.0))
            t += 0.005
        fx.observe_hold(accel, g, 1e-4 * (np.eye(3) - np.outer(g, g) / (g @ g)))  # vision: tangent std 0.01
    assert np.allclose(fx.bias, bias, atol=1e-12)
    for _ in range(4000):  # 20 s: the step the correction makes has rung out
        fx.add_imu(t, accel, (0.0, 0.0, 0.0))
        t += 0.005
    assert np.allclose(fx.bars.loads_at([t - 0.01])[0], g, atol=1e-4)


def test_the_bias_from_a_hold_weighs_by_its_gravitys_covariance_against_the_prior():
    """A hold whose gravity is as uncertain as the prior bias moves the bias half way; a tight one nearly all
    the way; a declared unbiased accelerometer (prior 0) learns nothing."""
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics

    rig = _rig()
    bias, g = np.array([0.03, -0.02, 0.0]), np.array([0.0, 0.0, -9.81])  # tangent to gravity: what vision sees
    accel = -rig.imu.rotation.T @ g + bias
    tangent = np.eye(3) - np.outer(g, g) / (g @ g)
    for std, share in ((0.05, 0.5), (0.005, 1 / (1 + 0.01))):
        fx = FrameExtrinsics(rig, bias_prior_ms2=0.05)
        fx.observe_hold(accel, g, std ** 2 * tangent)
        assert np.allclose(fx.bias, share * bias, atol=1e-12)
    fx = FrameExtrinsics(rig, bias_prior_ms2=0.0)
    fx.observe_hold(accel, g, 1e-6 * tangent)
    assert np.all(fx.bias == 0)
    fx = FrameExtrinsics(rig, bias_prior_ms2=0.05)
    fx.observe_hold(accel, g, np.full((3, 3), np.inf))
    assert np.all(fx.bias == 0), "a gravity of unknown covariance tells nothing"


def test_an_imu_on_a_flexible_bar_is_warned_about():
    from nrmpc_ros.core.rig import ImuMount
    from nrmpc_ros.frontend.extrinsics import imu_mount_warning

    rig = _rig()
    assert imu_mount_warning(rig) is None
    on_bar = dataclasses.replace(rig, imu=ImuMount(mount=rig.cameras[1].name))
    assert rig.cameras[1].name in imu_mount_warning(on_bar)
    rigid = dataclasses.replace(on_bar, cameras=tuple(dataclasses.replace(c, EI=float("inf")) if i == 1 else c
                                                      for i, c in enumerate(rig.cameras)))
    assert imu_mount_warning(rigid) is None


def test_imu_samples_in_any_container_of_three_numbers_reach_the_bars():
    pipe = Pipeline(_rig())
    for k in range(5):
        pipe.add_imu(1.0 + 0.005 * k, np.array([[0.0, 0.0, 9.81]]), [[0.0], [0.0], [0.1]])
    pipe.add_imu(2.0, [0, 0], [0, 0, 0])  # refused by the IMU checks, counted there
    pipe.extrinsics.bars.flush()
    assert pipe.extrinsics.bars.stats.samples == 5 and pipe.stats.dropped[Drop.IMU_SAMPLE_WRONG_SHAPE] == 1


def _still_holds(rig, bias, K, rng, vision_std_ms2=0.035, accel_noise_ms2=0.02, samples=1000):
    """K still holds at random attitudes (tilts of ~20 deg): each one's mean accelerometer (IMU frame) with its
    noise, and its gravity from vision (body frame) off by vision_std_ms2 across gravity, with that covariance."""
    from nrmpc_ros.core.so3 import exp_so3

    G = rig.gravity_magnitude
    out = []
    for _ in range(K):
        g = exp_so3(rng.normal(scale=0.35, size=3)) @ np.array([0.0, 0.0, -G])
        P = np.eye(3) - np.outer(g, g) / (g @ g)
        accel = -rig.imu.rotation.T @ g + bias + rng.normal(scale=accel_noise_ms2 / np.sqrt(samples), size=3)
        seen = g + P @ rng.normal(scale=vision_std_ms2, size=3)
        out.append((accel, G * seen / np.linalg.norm(seen), vision_std_ms2 ** 2 * P))
    return out


def test_the_online_bias_converges_from_the_first_hold_and_its_std_covers_the_error():
    """A recording of still holds with a known accelerometer bias: the first hold (no vision gravity yet) gives
    the bias along gravity from the gravity's magnitude, every later one all of it; the posterior's covariance
    covers the error at every step and the estimate ends within a few mm/s^2."""
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics

    rng = np.random.default_rng(11)
    rig = _rig()
    bias = 0.05 * np.array([0.3, -0.5, -0.81])  # IMU frame, |b| = 0.05 m/s^2
    prior, floor = 9.81 * np.radians(0.3), 9.81 * np.radians(0.05)
    fx = FrameExtrinsics(rig, bias_prior_ms2=prior, floor_ms2=floor)
    for k, (accel, g, cov) in enumerate(_still_holds(rig, bias, 8, rng)):
        fx.observe_still(k, accel, 0.02, 1000)
        if k == 0:
            est = fx.bias_estimate
            down = -accel / np.linalg.norm(accel)  # the first hold: along gravity known, across it the prior's
            assert abs(down @ (est.bias_ms2 - bias)) < 3 * floor and est.holds == 1 and est.with_gravity == 0
            assert np.sqrt(down @ est.cov_ms2 @ down) < 1.5 * floor
            assert np.allclose(np.linalg.eigvalsh(est.cov_ms2)[1:], prior ** 2, rtol=0.05)
        else:
            fx.observe_hold(accel, g, cov, key=k, accel_std_ms2=0.02, num_samples=1000)
        est = fx.bias_estimate
        err = est.bias_ms2 - bias
        assert err @ np.linalg.solve(est.cov_ms2, err) < 16.3  # chi-square(3) at 0.999
        assert np.array_equal(fx.bias, est.bias_ms2)
    assert est.holds == 8 and est.with_gravity == 7
    assert np.linalg.norm(err) < 0.012 and np.all(est.std_ms2 < 0.015)


def test_the_bias_std_is_a_faithful_promise():
    """Over many recordings whose bias is drawn from the prior, the posterior's Mahalanobis error is chi-square
    with 3 degrees of freedom (mean 3; 95 % of the components within 2 std)."""
    from nrmpc_ros.frontend.extrinsics import AccelBias

    rng = np.random.default_rng(12)
    rig, prior = _rig(), 0.05
    d2, z = [], []
    for _ in range(300):
        bias = rng.normal(scale=prior, size=3)
        est = AccelBias(rig.gravity_magnitude, prior)
        for k, (accel, g, cov) in enumerate(_still_holds(rig, bias, 4, rng)):
            est.observe_still(k, accel, 0.02 ** 2 / 1000)
            if k:  # vision gravity (IMU at the body: its frame is rig.imu.rotation)
                R = rig.imu.rotation.T
                est.observe_gravity(k, accel, R @ g, R @ cov @ R.T, 0.02 ** 2 / 1000)
        err = est.estimate.bias_ms2 - bias
        d2.append(err @ np.linalg.solve(est.estimate.cov_ms2, err))
        z.extend(err / est.estimate.std_ms2)
    assert 2.6 < np.mean(d2) < 3.4
    assert 0.92 < np.mean(np.abs(z) < 2.0) < 0.98


def test_a_bias_correction_does_not_set_the_modelled_bars_ringing():
    """The bars settled under a biased accelerometer: once a hold gives the bias they carry the true gravity at
    once (their state moved as if the samples had always been corrected), not after the correction rang out."""
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics

    rig = _rig()
    bias, g = np.array([0.03, -0.02, 0.04]), np.array([1.2, -0.5, -9.72])
    fx = FrameExtrinsics(rig, bias_prior_ms2=None, floor_ms2=1e-6)
    accel = -rig.imu.rotation.T @ g + bias
    for k in range(4000):  # 20 s still: the bars rest at the biased load
        fx.add_imu(100.0 + 0.005 * k, accel, (0.0, 0.0, 0.0))
    t = 100.0 + 0.005 * 3999
    assert np.linalg.norm(fx.bars.loads_at([t])[0] - g, axis=1).min() > 0.03
    fx.observe_hold(accel, g, key="hold")
    assert np.allclose(fx.bias, bias, atol=1e-9)
    assert np.allclose(fx.bars.loads_at([t])[0], g, atol=1e-6)
    for k in range(4000, 4040):
        fx.add_imu(100.0 + 0.005 * k, accel, (0.0, 0.0, 0.0))
    assert np.allclose(fx.bars.loads_at([100.0 + 0.005 * 4039])[0], g, atol=1e-6)


def test_holds_of_one_sequence_share_their_gravity_error_and_the_std_says_so():
    """The holds of a sequence get their gravity from one joint estimate: the newest hold's, turned by the
    relative rotations, so one error is shared by all. Marginalised, the bias's posterior is chi-square over
    many recordings (bias drawn from the prior); the attitudes' spread separates the bias from that error, so
    the estimate is better than the vision gravity's std across gravity."""
    from nrmpc_ros.core.so3 import exp_so3
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics

    rng = np.random.default_rng(13)
    rig, prior, vision = _rig(), 0.05, 0.035
    G = rig.gravity_magnitude
    R_bi = rig.imu.rotation
    d2, err_norm = [], []
    for _ in range(200):
        bias = rng.normal(scale=prior, size=3)
        Q = [exp_so3(rng.normal(scale=0.35, size=3)) for _ in range(5)]  # body -> world per hold
        g = [q.T @ np.array([0.0, 0.0, -G]) for q in Q]
        fx = FrameExtrinsics(rig, bias_prior_ms2=prior, floor_ms2=0.0)
        for k, gk in enumerate(g):
            fx.observe_still(k, -R_bi.T @ gk + bias + rng.normal(scale=0.02 / np.sqrt(1000), size=3), 0.02, 1000)
        P = np.eye(3) - np.outer(g[-1], g[-1]) / G ** 2
        seen = g[-1] + P @ rng.normal(scale=vision, size=3)
        turns = [(k, Q[k].T @ Q[-1]) for k in range(5)]  # the newest hold's body frame into hold k's
        fx.observe_sequence(0, G * seen / np.linalg.norm(seen), vision ** 2 * P, turns)
        est = fx.bias_estimate
        assert est.holds == 5 and est.with_gravity == 5
        err = est.bias_ms2 - bias
        d2.append(err @ np.linalg.solve(est.cov_ms2, err))
        err_norm.append(np.linalg.norm(err))
    assert 2.6 < np.mean(d2) < 3.4
    assert np.median(err_norm) < 0.5 * vision


def test_a_sequence_that_has_not_found_gravity_tells_the_bias_nothing():
    """Vision alone on a young sequence may publish a gravity with a std of thousands of degrees (a finite
    covariance of 1e13 (m/s^2)^2): the bias stays where the still holds and the prior put it, with no error."""
    from nrmpc_ros.core.so3 import exp_so3
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics

    rng = np.random.default_rng(5)
    rig = _rig()
    G = rig.gravity_magnitude
    Q = [exp_so3(rng.normal(scale=0.35, size=3)) for _ in range(3)]
    g = [q.T @ np.array([0.0, 0.0, -G]) for q in Q]
    fx = FrameExtrinsics(rig, bias_prior_ms2=0.05, floor_ms2=0.0)
    for k, gk in enumerate(g):
        fx.observe_still(k, -rig.imu.rotation.T @ gk + rng.normal(scale=1e-3, size=3), 0.02, 1000)
    before = fx.bias_estimate
    P = np.eye(3) - np.outer(g[-1], g[-1]) / G ** 2
    fx.observe_sequence(0, g[-1], 1e13 * P, [(k, Q[k].T @ Q[-1]) for k in range(3)])
    after = fx.bias_estimate
    np.testing.assert_allclose(after.bias_ms2, before.bias_ms2)
    assert after.with_gravity == before.with_gravity == 0


def test_the_smoothed_poses_are_the_recording_again_with_the_final_bias_from_the_start():
    """Offline: every answered frame set once more, the bars driven by all samples minus the final bias; the
    causal answers before the bias was known differ from them, those after agree."""
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics

    rig = _rig()
    t, accel, gyro = _samples(n=5000)
    bias = np.array([0.04, -0.03, 0.02])
    fx = FrameExtrinsics(rig, bias_prior_ms2=None, floor_ms2=1e-6, keep_samples=True)
    causal = []
    for k in range(len(t)):
        fx.add_imu(t[k], accel[k] + bias, gyro[k])
        if k % 13 == 12:
            causal.append(fx.at(t[k] - 0.01))
        if k == 2500:
            fx.observe_hold(accel[k] + bias, -rig.imu.rotation @ accel[k], key="hold")  # a hold that gives b
    assert np.allclose(fx.bias, bias)
    smooth = list(fx.smoothed())
    assert len(smooth) == len(causal) and all(p.source is ExtrinsicsSource.SMOOTHED for p in smooth)
    ref = BarPropagator(rig, history_s=60.0)  # the whole recording at once
    for k in range(len(t)):
        ref.add_imu(t[k], accel[k], gyro[k])
    for c, s in zip(causal, smooth):
        assert np.array_equal(c.stamps, s.stamps) and np.array_equal(c.cameras, s.cameras)
        w, W = ref.extrinsics_at(s.stamps, s.cameras)
        assert np.abs(s.rotations - W).max() < 1e-9 and np.abs(s.positions - w).max() < 1e-12
    before = [np.abs(c.rotations - s.rotations).max() for c, s in zip(causal, smooth) if c.stamps[0] < t[2500]]
    after = [np.abs(c.rotations - s.rotations).max() for c, s in zip(causal, smooth) if c.stamps[0] > t[2501]]
    assert min(before) > 1e-5 and max(after) < 1e-9


def test_the_cameras_rest_turns_turn_the_published_rotations():
    """Where the joint estimate found the cameras' rest turns (a rig file's rotations off by their calibration),
    every published camera rotation, at a frame set or a hold, is the bent rotation times its camera's turn;
    the positions stay."""
    from nrmpc_ros.frontend.extrinsics import FrameExtrinsics

    rig = _rig()
    fx = FrameExtrinsics(rig)
    for k in range(50):
        fx.add_imu(0.005 * k, -rig.imu.rotation.T @ np.array([0.0, 0.0, -9.81]), (0.0, 0.0, 0.0))
    plain = fx.at(0.2)
    turns = exp_so3(np.radians(0.1) * np.random.default_rng(5).normal(size=(rig.num_cameras, 3)))
    fx.rest_turns = turns
    turned = fx.at(0.2, present=[i != 1 for i in range(rig.num_cameras)])
    cams = turned.cameras
    assert 1 not in cams and np.allclose(turned.rotations, plain.rotations[cams] @ turns[cams])
    assert np.array_equal(turned.positions, plain.positions[cams])
    from nrmpc_ros.frontend.extrinsics import hold_poses

    g = np.array([0.5, -0.3, -9.79])
    held, held_turned = hold_poses(rig, 3.0, g), hold_poses(rig, 3.0, g, turns)
    assert np.allclose(held_turned.rotations, held.rotations @ turns)
    assert np.array_equal(held_turned.positions, held.positions)
