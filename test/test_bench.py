"""``nrmpc bench``: PoseLib conventions, input validation and the report (no timing asserts)."""

import json
import math

import numpy as np
import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.core import pose_errors
from nrmpc_ros.core.matches import Matches
from nrmpc_ros.experiments.bench import POSELIB, poselib_inputs, run_bench, run_poselib
from nrmpc_ros.sim.synthetic import RigSpec, Scenario, make_problem, make_rig


def test_poselib_rigid_pipeline_in_our_conventions():
    """On a rigid rig without noise PoseLib's answer, converted, is the ground truth (docs/CONVENTIONS.md (Frames))."""
    sc = Scenario(rig=RigSpec(EI=math.inf), num_points=200, pixel_noise=0.0, outlier_fraction=0.0)
    for seed in range(3):
        p = make_problem(sc, seed)
        R, t, dt = run_poselib(p.rig, p.matches, threshold_px=1.0, seed=seed)
        err = pose_errors(R, t, p.R, p.t)
        assert err["rotation"] < 1e-6 and err["translation"] < 1e-5 and dt > 0


def test_poselib_inputs_are_validated_before_calling_it():
    """PoseLib 2.0.5 never returns on one camera pair or pairs with < 5 matches: we must refuse first."""
    rig = make_rig(RigSpec())
    rng = np.random.default_rng(0)
    f = rng.normal(size=(40, 3))
    f[:, 2] = np.abs(f[:, 2]) + 1.0
    one_camera = Matches(f, f, np.zeros(40, dtype=int))
    with pytest.raises(ValueError):
        poselib_inputs(rig, one_camera)
    few = Matches(f[:8], f[:8], np.array([0, 0, 0, 0, 1, 1, 1, 1]))
    with pytest.raises(ValueError):
        poselib_inputs(rig, few)
    assert run_poselib(rig, one_camera, 1.0) == (None, None, 0.0)
    pairs, ext1, cams1, _, _ = poselib_inputs(rig, Matches(f, f, np.arange(40) % 4))
    assert len(pairs) == 4 and len(ext1) == len(cams1) == 4
    assert np.allclose(ext1[1].R, rig.rotations[1].T)


def test_run_bench_report():
    sc = Scenario(num_points=200)
    res = run_bench(runs=2, seed=0, scenario=sc, progress=False)
    m = res["methods"]
    assert list(m) == ["6pt-nonbending", "6pt-bending", "4pt-bending", POSELIB]
    assert m[POSELIB]["time_ratio_poselib"] == 1.0
    assert m["4pt-bending"]["success_rate"] == 1.0
    assert m["4pt-bending"]["gravity_over_crlb"] < 5  # near-efficient
    assert m["6pt-nonbending"]["median_gravity"] is None and m[POSELIB]["gravity_over_crlb"] is None
    assert 0 < res["crlb_rad"]["gravity"]["median"] < res["crlb_rad"]["gravity"]["rms"]


def test_cli_json_and_errors(capsys):
    assert main(["bench", "--runs", "1", "--points", "150", "--methods", "4pt-bending", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res["methods"]) == {"4pt-bending", POSELIB}
    assert main(["bench", "--runs", "1", "--points", "150", "--methods", "4pt-bending", "--no-poselib"]) == 0
    assert "4pt-bending" in capsys.readouterr().out
    assert main(["bench", "--methods", "9pt"]) == 2
    assert main(["bench", "--runs", "0"]) == 2
    assert main(["bench", "--gravity-frame", "none"]) == 2


@pytest.mark.parametrize("cameras, parallel", [(2, True), (3, False), (4, False)])
def test_cli_cameras_picks_the_rig(capsys, cameras, parallel):
    """--cameras 2 is two cameras on one straight bar (parallel bars, the weak case), 3 a ring, 4 the cross;
    6pt-bending and PoseLib run on the same problems and the time ratio is reported."""
    assert main(["bench", "--cameras", str(cameras), "--runs", "1", "--points", "200", "--methods", "6pt-bending",
                 "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    rig = make_rig(Scenario.from_dict(res["scenario"]).rig)
    u = rig.positions / np.linalg.norm(rig.positions, axis=1, keepdims=True)
    assert rig.num_cameras == cameras and bool(np.all(np.abs(u @ u[0]) > 1 - 1e-9)) == parallel
    m = res["methods"]
    assert set(m) == {"6pt-bending", POSELIB} and m["6pt-bending"]["success_rate"] == 1.0
    assert m["6pt-bending"]["time_ratio_poselib"] > 0
