import json
import math
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest

from nrmpc_ros.core import METHODS, EstimateInfo, estimate, pose_errors
from nrmpc_ros.core.estimators import pair_method
from nrmpc_ros.core.so3 import angle_between, exp_so3
from nrmpc_ros.errors import EstimationError, InputError
from nrmpc_ros.sim.synthetic import RigSpec, Scenario, make_problem


def _run(method, scenario, seed):
    pb = make_problem(scenario, seed=seed)
    est = estimate(pb.rig, pb.matches, method=method, seed=seed)
    return pb, est, pose_errors(est.R, est.t, pb.R, pb.t, est.gravity, pb.gravity)


NOISE_FREE = dict(pixel_noise=0.0, outlier_fraction=0.0, gravity_noise_px=0.0)


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_stiff_rig_all_methods_exact(method):
    # EI = 10 still tilts the tips by 8 mrad: exact for the bending model, not for a rigid one
    ei = 1e7 if method == "6pt-nonbending" else 10.0
    sc = Scenario(rig=RigSpec(EI=ei), **NOISE_FREE)
    for seed in range(3):
        _, est, e = _run(method, sc, seed)
        assert est.success
        assert e["rotation"] < 1e-6 and e["translation"] < 1e-6, (seed, e)
        if method == "6pt-nonbending":
            assert est.gravity is None
        else:
            assert e["gravity"] < 1e-6, (seed, e)


@pytest.mark.parametrize("method", ["6pt-bending", "4pt-bending"])
def test_noise_free_bending_rig_exact(method):
    sc = Scenario(**NOISE_FREE)  # EI = 0.1: the tips rotate by ~45 deg under gravity
    for seed in range(3):
        _, est, e = _run(method, sc, seed)
        assert e["rotation"] < 1e-6 and e["translation"] < 1e-6 and e["gravity"] < 1e-6, (seed, e)
        assert np.isclose(np.linalg.norm(est.gravity), 9.81)


def test_nonbending_visibly_fails_on_a_bending_rig():
    sc = Scenario(**NOISE_FREE)
    rot = [_run("6pt-nonbending", sc, seed)[2]["rotation"] for seed in range(3)]
    assert min(rot) > 1e-3


@pytest.mark.parametrize("method", METHODS)
def test_forty_percent_outliers(method):
    ei = 10.0 if method == "6pt-nonbending" else 0.1
    sc = Scenario(rig=RigSpec(EI=ei), outlier_fraction=0.4, pixel_noise=0.1)
    pb, est, e = _run(method, sc, seed=11)
    assert e["success"] and e["rotation"] < 5e-3, e
    if method != "6pt-nonbending":
        assert e["gravity"] < 0.02, e
    found = np.zeros(len(pb.matches), dtype=bool)
    found[est.inliers] = True
    assert found[pb.inlier_mask].mean() > 0.95 and found[~pb.inlier_mask].mean() < 0.02


def test_info_reports_covariances():
    _, est, e = _run("4pt-bending", Scenario(), seed=5)
    cg = est.info.cov_gravity
    assert cg.shape == (3, 3) and np.all(np.isfinite(cg))
    assert 0 < est.info.gravity_sigma_rad < 0.01
    assert est.info.cov_rotation.shape == (3, 3)
    json = est.to_json("x.npz")
    assert json["matches"] == "x.npz" and len(json["gravity"]) == 3 and json["num_inliers"] == est.num_inliers


def _symmetric_psd(c: np.ndarray) -> bool:
    scale = max(1.0, float(np.abs(c).max()))
    return np.allclose(c, c.T, rtol=0, atol=1e-12 * scale) and np.linalg.eigvalsh(c).min() >= -1e-12 * scale


@pytest.mark.parametrize("method", METHODS)
def test_info_fields_are_typed_and_covariances_symmetric_psd(method):
    """A real estimate's diagnostics are typed: covariances are float arrays of their shapes, symmetric
    positive semi-definite, gravity's 3x3 one of rank 2 (nothing along gravity); counts are ints."""
    ei = 10.0 if method == "6pt-nonbending" else 0.1
    _, est, e = _run(method, Scenario(rig=RigSpec(EI=ei)), seed=5)
    info = est.info
    assert est.success and e["success"] and isinstance(info, EstimateInfo) and info.reason is None
    shapes = {"cov_rotation": (3, 3), "cov_translation": (3, 3)}
    if method == "6pt-nonbending":
        assert info.cov_gravity is None and info.cov_gravity_tangent is None and info.gravity_sigma_rad is None
    else:
        shapes.update(cov_gravity_tangent=(2, 2), cov_gravity=(3, 3))
        g = est.gravity / np.linalg.norm(est.gravity)
        assert np.linalg.norm(info.cov_gravity @ g) < 1e-6 * np.abs(info.cov_gravity).max()
        assert isinstance(info.gravity_sigma_rad, float) and info.gravity_sigma_rad > 0
    for name, shape in shapes.items():
        c = getattr(info, name)
        assert isinstance(c, np.ndarray) and c.dtype == float and c.shape == shape, name
        assert np.all(np.isfinite(c)) and _symmetric_psd(c), name
    assert type(info.ransac_iterations) is int and type(info.ba_iterations) is int
    assert type(info.sigma_rad) is float and info.sigma_rad > 0
    if method == "6pt-bending":
        assert type(info.gravity_starts) is int and type(info.cameras_with_rotation) is int
        assert type(info.msac_score_rad2) is float and isinstance(info.gravity_candidates, tuple)
        assert len(info.gravity_candidates) >= 1 and all(c.shape == (3,) for c in info.gravity_candidates)
        assert len(info.candidate_poses) == len(info.gravity_candidates)
        assert all(P.shape == (3, 4) for P in info.candidate_poses)
    if method == "4pt-bending":
        assert info.measured_gravity.shape == (2, 3) and type(info.stage1_inliers) is int


def test_info_as_dict_is_json_ready_and_round_trips():
    """as_dict() holds what was recorded (defaults left out) as plain JSON values; from_dict() inverts it."""
    pb = make_problem(Scenario(), seed=5)
    for method in METHODS:
        info = estimate(pb.rig, pb.matches, method=method, seed=0).info
        d = info.as_dict()
        back = EstimateInfo.from_dict(json.loads(json.dumps(d)))
        assert back.as_dict() == d and "reason" not in d and "cov_rotation" in d
        for f in fields(EstimateInfo):
            a, b = getattr(info, f.name), getattr(back, f.name)
            if f.name in ("gravity_candidates", "candidate_poses"):
                assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
            elif isinstance(a, np.ndarray):
                assert isinstance(b, np.ndarray) and np.array_equal(a, b), f.name
            else:
                assert a == b, f.name
    assert EstimateInfo().as_dict() == {}
    assert EstimateInfo(reason="why", mirrored_start=False).as_dict() == {"reason": "why", "mirrored_start": False}
    with pytest.raises(KeyError, match="covariance"):
        EstimateInfo.from_dict({"covariance": 1.0})


def test_rigid_rig_reports_no_gravity():
    sc = Scenario(rig=RigSpec(EI=math.inf))
    for method in ("6pt-bending", "4pt-bending"):
        _, est, e = _run(method, sc, seed=2)
        assert est.success and est.gravity is None and "unobservable" in est.info.gravity_unobservable
        assert e["rotation"] < 5e-3


def test_four_point_needs_gravity_and_bad_inputs():
    pb = make_problem(Scenario(gravity_frame="none"), seed=0)
    with pytest.raises(EstimationError, match="4pt-bending needs gravity"):
        estimate(pb.rig, pb.matches, method="4pt-bending")
    with pytest.raises(EstimationError, match="unknown method"):
        estimate(pb.rig, pb.matches, method="5pt")
    with pytest.raises(InputError, match="unknown option"):
        estimate(pb.rig, pb.matches, options={"treshold_px": 3})
    few = pb.matches.subset(np.arange(5))
    est = estimate(pb.rig, few, method="6pt-bending")
    assert not est.success and "at least" in est.info.reason


def test_same_seed_same_result():
    pb = make_problem(Scenario(), seed=9)
    a = estimate(pb.rig, pb.matches, method="6pt-bending", seed=3)
    b = estimate(pb.rig, pb.matches, method="6pt-bending", seed=3)
    assert np.array_equal(a.R, b.R) and np.array_equal(a.inliers, b.inliers)


# Two cameras on one bar (EI = 1): the bending reversed fits this pair about as well as the truth (seed 11).
AMBIGUOUS_LINE = Scenario(rig=RigSpec(num_cameras=2, layout="line", EI=1.0), num_points=200, pixel_noise=0.5)


def _reversed_bending(rig, g):
    """Gravity with the part across the (common) bar axis flipped: the bars bend the other way."""
    u = rig.positions[0] / np.linalg.norm(rig.positions[0])
    return 2.0 * (u @ g) * u - g


def test_gravity_hint_keeps_its_basin_and_is_checked():
    pb = make_problem(AMBIGUOUS_LINE, seed=11)
    own = estimate(pb.rig, pb.matches, method="6pt-bending")
    near = estimate(pb.rig, pb.matches, method="6pt-bending", gravity_hint=exp_so3([0.03, 0.0, 0.02]) @ pb.gravity)
    far = estimate(pb.rig, pb.matches, method="6pt-bending", gravity_hint=_reversed_bending(pb.rig, pb.gravity))
    err = {k: pose_errors(e.R, e.t, pb.R, pb.t, e.gravity, pb.gravity) for k, e in (("near", near), ("far", far))}
    assert near.info.gravity_hint and far.info.gravity_hint and not own.info.gravity_hint
    assert err["near"]["gravity"] < math.radians(3) and err["near"]["rotation"] < math.radians(0.2)
    assert err["far"]["gravity"] > math.radians(60)  # stayed in the hint's (wrong) basin ...
    sigma2 = own.info.sigma_rad ** 2  # ... which fits the correspondences about as well (paper, section 3.3)
    assert abs(far.info.msac_score_rad2 - near.info.msac_score_rad2) / sigma2 < 9.21
    with pytest.raises(EstimationError, match="6pt-bending only"):
        estimate(pb.rig, pb.matches, method="4pt-bending", gravity_hint=pb.gravity)
    for bad in ([0.0, 0.0, 0.0], [np.nan, 0.0, -9.8], [1.0, 2.0]):
        with pytest.raises(InputError, match="gravity_hint"):
            estimate(pb.rig, pb.matches, method="6pt-bending", gravity_hint=bad)


def test_gravity_hint_on_the_rigid_fit_route(monkeypatch):
    """With fewer than two cameras with their own rotation the starts come from a rigid 6-point fit; a hint is
    then the only gravity start there."""
    import nrmpc_ros.core.estimators as estimators

    def no_camera_rotations(m, num_cameras, threshold_rad, seed=0):
        return np.zeros(0, int), np.zeros((0, 3, 3)), np.zeros(0), np.zeros(len(m), bool)

    monkeypatch.setattr(estimators, "camera_rotations", no_camera_rotations)
    pb = make_problem(Scenario(), seed=3)
    plain = estimate(pb.rig, pb.matches, method="6pt-bending")
    hinted = estimate(pb.rig, pb.matches, method="6pt-bending", gravity_hint=exp_so3([0.02, 0.0, 0.0]) @ pb.gravity)
    assert plain.info.gravity_starts > 1 and hinted.info.gravity_starts == 1 and hinted.info.gravity_hint
    assert pose_errors(hinted.R, hinted.t, pb.R, pb.t, hinted.gravity, pb.gravity)["gravity"] < 1e-3


def test_parallel_bars_report_both_basins_among_the_candidates():
    """On one bar the search refines at least two grid starts plus the mirrored and reversed ones, and its
    gravity candidates (best first) hold the truth's basin and the second basin that a start from the bending
    reversed ends in, which fits this pair about as well (seed 11): the basins a sequence estimator compares."""
    pb = make_problem(AMBIGUOUS_LINE, seed=11)
    own = estimate(pb.rig, pb.matches, method="6pt-bending")
    far = estimate(pb.rig, pb.matches, method="6pt-bending", gravity_hint=_reversed_bending(pb.rig, pb.gravity))
    cands = own.info.gravity_candidates
    assert own.info.gravity_starts >= 2 and len(cands) == own.info.gravity_starts + 2
    assert angle_between(cands[0], pb.gravity) < math.radians(3)
    assert min(angle_between(c, far.gravity) for c in cands) < math.radians(2)
    assert angle_between(far.gravity, pb.gravity) > math.radians(60)


@pytest.mark.parametrize("outliers", [0.05, 0.4])
def test_one_start_explains_a_cross_rig(outliers):
    """Four cameras observe gravity well: the first start, posed from the camera rotations without a RANSAC,
    explains every correspondence the cameras' epipolar geometry accepts (up to the outliers that the
    epipolar test lets through), so the search stops there."""
    sc = Scenario(outlier_fraction=outliers, pixel_noise=0.1)
    for seed in range(4):
        pb, est, e = _run("6pt-bending", sc, seed)
        assert est.info.gravity_starts == 1 and est.info.ransac_iterations == 0, (seed, est.info.as_dict())
        assert len(est.info.gravity_candidates) == 1
        assert e["gravity"] < 2e-3 and e["rotation"] < 1e-3, (seed, e)


def test_noise_free_parallel_bars_exact():
    """Two cameras on one bar (the weak case) without noise: exact pose and gravity."""
    sc = Scenario(rig=RigSpec(num_cameras=2, layout="line"), **NOISE_FREE)
    for seed in range(3):
        _, est, e = _run("6pt-bending", sc, seed)
        assert e["rotation"] < 1e-9 and e["translation"] < 1e-9 and e["gravity"] < 1e-9, (seed, e)


def test_a_pair_without_measured_gravity_falls_back_to_vision_only():
    """One rule for every sequence orchestrator: 4pt-bending needs gravity in both views, else 6pt-bending."""
    assert pair_method("4pt-bending", True) == "4pt-bending"
    assert pair_method("4pt-bending", False) == "6pt-bending"
    assert [pair_method(m, False) for m in ("6pt-bending", "6pt-nonbending")] == ["6pt-bending", "6pt-nonbending"]


def test_a_pair_whose_cameras_have_few_links_each_is_started_from_a_rigid_fit_too():
    """A pair recorded on three cameras on 1.5, 8 and 1.5 Hz bars (a rendered bag), linked by descriptors across
    a creeping hold: 44 links, 8-19 per camera. Each camera's own rotation, from its few links, put every
    gravity start in a basin that explains 36 of them, 124 deg from the truth; the rigid fit over every
    camera's links starts the basin that explains all 44. The pair's options are a sequence's (every start
    refined, no final refinement)."""
    from nrmpc_ros.core import load_rig
    from nrmpc_ros.core.matches import load_matches
    from nrmpc_ros.core.sequence_steps import SequenceOptions

    data = Path(__file__).parent / "data"
    rig = load_rig(data / "ring3_mixed.yaml")
    m = load_matches(data / "ring3_mixed_pair.npz", rig)  # g1: the truth in view 1's body frame
    est = estimate(rig, replace(m, g1=None, g2=None), "6pt-bending", seed=1,
                   options=SequenceOptions().pair_estimator())
    assert len(est.inliers) == len(m) == 44
    assert math.degrees(angle_between(est.gravity, m.g1)) < 1.0
