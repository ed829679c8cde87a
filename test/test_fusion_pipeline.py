"""Fused gravity in the Pipeline (rendered frames) and in nrmpc replay / compare (sample bag)."""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.core.fusion import sphere_log
from nrmpc_ros.core.so3 import angle_between, exp_so3, rotation_angle, tangent_basis
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.evaluation import CSV_HEADER, read_csv
from nrmpc_ros.frontend.pipeline import FrameSet, Pipeline, PipelineConfig
from nrmpc_ros.render import Renderer, make_scene
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "bags" / "sample"
RIG = ROOT / "config" / "sample_cross4.yaml"
GW = np.array([0.0, 0.0, -9.81])


def attitude(az_deg, tilt_deg, yaw_deg):
    az, t = math.radians(az_deg), math.radians(tilt_deg)
    return exp_so3(np.array([0, 0, math.radians(yaw_deg)])) @ exp_so3(t * np.array([math.cos(az), math.sin(az), 0]))


# 8 attitudes, 14-35 deg tilt, about 15-25 deg apart: every static view pairs with the previous one
ATTITUDES = [attitude(40 * k, 14 + 3 * k, (-1) ** k * 4) for k in range(8)]


@pytest.fixture(scope="module")
def rig():
    return make_rig(RigSpec(num_cameras=4, layout="cross", EI=0.2, focal=235.0, resolution=(320, 240)))


@pytest.fixture(scope="module")
def frames(rig):
    """Two noisy rendered frame sets per attitude: [(stamp, R_world_body, images)]."""
    rng = np.random.default_rng(7)
    r = Renderer(rig, make_scene(0))
    out, t = [], 100.0
    for k, R in enumerate(ATTITUDES):
        p = np.array([0.02 * k, -0.015 * k, 0.01 * (k % 2)])
        imgs = r.render_rig(R, p, R.T @ GW)
        t += 1.0 if k else 0.0
        for _ in range(2):
            t += 0.5
            out.append((t, R, [np.clip(im + rng.normal(scale=1.0, size=im.shape), 0, 255).astype(np.uint8)
                               for im in imgs]))
    return out


def run(rig, frames, method, config=None):
    pipe = Pipeline(rig, config or PipelineConfig(), method=method)
    ests = [e for st, _, imgs in frames for e in pipe.add_frames(FrameSet(st, imgs))]
    att = {st: R for st, R, _ in frames}
    return pipe, ests, att


def gravity_errors(ests, att):
    """(raw, fused) gravity errors (deg) against the true gravity in each estimate's current body frame."""
    truth = [att[e.stamp].T @ GW for e in ests]
    raw = np.degrees([angle_between(e.gravity, g) for e, g in zip(ests, truth)])
    fused = np.degrees([angle_between(e.gravity_fused, g) for e, g in zip(ests, truth)])
    return raw, fused


def test_fused_gravity_vision_only(rig, frames):
    pipe, ests, att = run(rig, frames, "6pt-bending")
    assert len(ests) >= 6
    for e in ests:
        assert e.gravity_fused is not None and np.linalg.norm(e.gravity_fused) == pytest.approx(9.81)
        C = e.cov_gravity_fused
        assert C.shape == (3, 3) and np.allclose(C, C.T)
        assert np.linalg.norm(C @ e.gravity_fused) < 1e-9 * np.linalg.norm(C) * 9.81  # tangent to the sphere
        assert np.linalg.eigvalsh(C)[1] > 0
        assert math.isfinite(e.gravity_fused_sigma_deg) and e.gravity_fused_sigma_deg > 0
    counts = [e.fused_count + e.fused_rejected for e in ests]
    assert counts == list(range(1, len(ests) + 1))  # one chain: every estimate fused or rejected
    assert ests[-1].fused_count >= len(ests) - 1
    # the uncertainty shrinks as estimates accumulate
    assert ests[-1].gravity_fused_sigma_deg < 0.7 * ests[0].gravity_fused_sigma_deg
    raw, fused = gravity_errors(ests, att)
    assert fused[0] == pytest.approx(raw[0], abs=1e-6)  # the first fused estimate is the first estimate
    assert np.median(fused) <= np.median(raw)
    assert np.mean(fused[len(fused) // 2:]) <= np.mean(raw[len(raw) // 2:])
    assert fused[-1] <= np.median(raw)


def test_fused_state_is_the_weighted_mean_carried_into_the_current_body_frame(rig, frames):
    """Without process noise or gating the fused gravity is the information-weighted mean of all estimates,
    each carried into the current body frame by the chained estimated rotations (recomputed here in a batch)."""
    cfg = PipelineConfig.from_dict({"fusion": {"process_sigma_deg": 0.0, "gate": 1e12}})
    _, ests, att = run(rig, frames, "6pt-bending", cfg)
    orient = {ests[0].ref_stamp: np.eye(3)}  # body frames of the views in the first one
    for e in ests:
        assert math.degrees(rotation_angle((att[e.ref_stamp].T @ att[e.stamp]).T @ e.R)) < 0.5
        orient[e.stamp] = orient[e.ref_stamp] @ e.R
    for k, e in enumerate(ests):
        n = e.gravity_fused / np.linalg.norm(e.gravity_fused)
        B = tangent_basis(n) / 9.81
        info, rhs = np.zeros((2, 2)), np.zeros(2)
        for p in ests[: k + 1]:
            A = orient[e.stamp].T @ orient[p.stamp]  # body frame of p -> body frame of e
            g = A @ p.gravity
            W = np.linalg.inv(B.T @ A @ p.cov_gravity @ A.T @ B)
            info += W
            rhs += W @ sphere_log(n, g / np.linalg.norm(g))
        offset = math.degrees(np.linalg.norm(np.linalg.solve(info, rhs)))
        assert offset < 0.02, (k, offset)  # rotation covariance and linearisation only
        sigma = math.degrees(math.sqrt(np.linalg.eigvalsh(np.linalg.inv(info)).max() * cfg.fusion.cov_scale))
        assert e.gravity_fused_sigma_deg == pytest.approx(sigma, rel=0.1)


def test_fusion_config_validation():
    cfg = PipelineConfig.from_dict({"fusion": {"cov_scale": 4, "gate": 9.2, "max_rejections": 2}})
    assert cfg.fusion.cov_scale == 4 and cfg.fusion.gate == 9.2 and cfg.fusion.max_rejections == 2
    with pytest.raises(InputError, match="fusion.cov_scale"):
        PipelineConfig.from_dict({"fusion": {"cov_scale": -1}})
    with pytest.raises(InputError, match="fusion.gtae"):
        PipelineConfig.from_dict({"fusion": {"gtae": 3}})


@pytest.mark.skipif(not (BAG / "metadata.yaml").exists(), reason="sample bag not present")
def test_replay_and_compare_report_fused_gravity(tmp_path, capsys):
    out = tmp_path / "vision.csv"
    assert main(["replay", str(BAG), "--rig", str(RIG), "--method", "6pt-bending", "--out", str(out),
                 "--no-progress", "--quiet"]) == 0
    with open(out) as f:
        header = next(csv.reader(f))
    assert header[:15] == CSV_HEADER and {"gfx", "gfy", "gfz", "gravity_fused_sigma_deg"} <= set(header)
    rows = read_csv(out)
    assert rows and all(r.gravity_fused is not None and abs(np.linalg.norm(r.gravity_fused) - 9.81) < 1e-6
                        for r in rows)
    capsys.readouterr()
    assert main(["compare", str(out), "--bag", str(BAG), "--rig", str(RIG), "--json", str(tmp_path / "s.json"),
                 "--plot", str(tmp_path / "g.png"), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "fused gravity vs ground truth" in text and "6pt-bending    fused" in text
    stats = json.loads((tmp_path / "s.json").read_text())["6pt-bending"]
    raw, fused = stats["gravity_vs_gt_deg"], stats["fused_vs_gt_deg"]
    assert raw["n"] == fused["n"] == len(rows)
    # the target: fused vision-only gravity at least 2x better (median) than the per-pair estimates
    assert fused["median"] <= 0.5 * raw["median"]
    assert (tmp_path / "g.png").read_bytes()[:4] == b"\x89PNG"


def test_pair_contradicting_the_fused_gravity_is_settled_in_its_basin():
    """Two cameras on one bar: the pair's estimate in the reversed-bending basin (as good a fit) is re-estimated
    from a fused gravity of three views and replaced; a pair that agrees is left alone."""
    from nrmpc_ros.core import estimate
    from nrmpc_ros.frontend.pipeline import _View
    from nrmpc_ros.sim.synthetic import Scenario, make_problem

    pb = make_problem(Scenario(rig=RigSpec(num_cameras=2, layout="line", EI=1.0), num_points=200, pixel_noise=0.5),
                      seed=11)
    u = pb.rig.positions[0] / np.linalg.norm(pb.rig.positions[0])
    pipe = Pipeline(pb.rig, PipelineConfig(), method="6pt-bending")
    opts = pipe.estimator_options
    wrong = estimate(pb.rig, pb.matches, seed=0, options=opts, gravity_hint=2.0 * (u @ pb.gravity) * u - pb.gravity)
    right = estimate(pb.rig, pb.matches, seed=0, options=opts)
    assert angle_between(wrong.gravity, pb.gravity) > math.radians(60)
    ref = _View(stamp=1.0, images=[], tracks=[], imu=None)
    assert pipe._settle_basin(ref, pb.matches, wrong) is wrong  # nothing fused yet: nothing to settle with
    for _ in range(3):
        pipe.fusion.update(pb.gravity, np.eye(3) * 0.1**2)  # view 1's body frame
    pipe._orient, pipe._fused_stamp = {1.0: np.eye(3)}, 1.0
    assert pipe._settle_basin(ref, pb.matches, right) is right
    settled = pipe._settle_basin(ref, pb.matches, wrong)
    assert settled.info["gravity_hint"] and angle_between(settled.gravity, pb.gravity) < math.radians(3)
    assert rotation_angle(settled.R.T @ pb.R) < math.radians(0.2)
    assert pipe.stats.hinted_pairs == pipe.stats.hinted_kept == 1
