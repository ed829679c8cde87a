"""``nrmpc simulate`` (issue 3): files, determinism, scenario files, validation, and the solve round trip."""

import json

import numpy as np
import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.core import load_matches, load_rig, pose_errors
from nrmpc_ros.core.so3 import angle_between


def _simulate(tmp_path, *extra, name="out"):
    out = tmp_path / name
    assert main(["simulate", "--out", str(out), *extra]) == 0
    return out


def test_writes_rig_matches_and_truth(tmp_path):
    out = _simulate(tmp_path, "--points", "200", "--count", "2", "--seed", "7", "--outliers", "0.1")
    rig = load_rig(out / "rig.yaml")
    assert rig.num_cameras == 4 and rig.is_flexible
    for k, seed in ((0, 7), (1, 8)):
        m = load_matches(out / f"pair_{k:03d}.npz", rig)
        truth = json.loads((out / f"pair_{k:03d}.truth.json").read_text())
        assert len(m) == 200 and truth["seed"] == seed
        assert len(truth["outliers"]) == 20
        R, g = np.array(truth["R"]), np.array(truth["gravity"])
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.allclose(np.array(truth["gravity2"]), R.T @ g)
        assert np.isclose(np.linalg.norm(g), rig.gravity_magnitude)
        assert m.g1_cam is not None and m.g_cam_index == 0  # gravity measured in camera 0 by default
    a = np.load(out / "pair_000.npz")
    b = np.load(out / "pair_001.npz")
    assert not np.allclose(a["f1"], b["f1"])  # different seeds, different problems


def test_deterministic_for_a_seed(tmp_path):
    o1 = _simulate(tmp_path, "--points", "60", "--seed", "3", name="a")
    o2 = _simulate(tmp_path, "--points", "60", "--seed", "3", name="b")
    a, b = np.load(o1 / "pair_000.npz"), np.load(o2 / "pair_000.npz")
    for key in a.files:
        assert np.array_equal(a[key], b[key])


def test_layouts_and_flags(tmp_path):
    out = _simulate(tmp_path, "--cameras", "3", "--looking", "forward", "--EI", "2.5", "--mass", "0.2",
                    "--bar-length", "0.3", "--points", "30", "--gravity-frame", "body")
    rig = load_rig(out / "rig.yaml")
    assert rig.num_cameras == 3  # ring by default for != 4 cameras
    assert np.allclose(np.linalg.norm(rig.positions, axis=1), 0.3)
    assert all(c.EI == 2.5 and c.mass == 0.2 for c in rig.cameras)
    assert np.allclose(rig.rotations[:, :, 2], [1, 0, 0])  # every optical axis along body +x
    m = load_matches(out / "pair_000.npz")
    assert m.g1 is not None and m.g1_cam is None
    out = _simulate(tmp_path, "--cameras", "2", "--layout", "line", "--EI", "inf", "--gravity-frame", "none",
                    "--points", "30", name="line")
    rig = load_rig(out / "rig.yaml")
    assert rig.num_cameras == 2 and not rig.is_flexible
    assert not load_matches(out / "pair_000.npz").has_gravity


def test_scenario_file_and_flag_override(tmp_path):
    sc = tmp_path / "sc.yaml"
    sc.write_text("rig: {num_cameras: 2, layout: line, EI: 1.0}\nnum_points: 40\npixel_noise: 0.0\n"
                  "outlier_fraction: 0.0\nseed: 5\ncount: 2\n")
    out = _simulate(tmp_path, "--scenario", str(sc), "--points", "50")
    truth = json.loads((out / "pair_001.truth.json").read_text())
    assert truth["seed"] == 6 and truth["scenario"]["num_points"] == 50
    assert truth["scenario"]["rig"]["EI"] == 1.0 and truth["scenario"]["rig"]["layout"] == "line"
    assert len(load_matches(out / "pair_000.npz")) == 50


def test_custom_rig(tmp_path):
    base = _simulate(tmp_path, "--cameras", "3", "--points", "20", name="base")
    out = _simulate(tmp_path, "--rig", str(base / "rig.yaml"), "--EI", "5", "--points", "30", name="custom")
    rig = load_rig(out / "rig.yaml")
    assert rig.num_cameras == 3 and all(c.EI == 5.0 for c in rig.cameras)
    assert np.load(out / "pair_000.npz")["cam"].max() == 2


@pytest.mark.parametrize("args, field", [
    (["--outliers", "1.0"], "outlier_fraction"),
    (["--noise", "-1"], "pixel_noise"),
    (["--cameras", "3", "--layout", "cross"], "rig"),
    (["--EI", "0"], "rig.EI"),
    (["--count", "0"], "--count"),
])
def test_bad_input_is_a_clear_error(tmp_path, capsys, args, field):
    assert main(["simulate", "--out", str(tmp_path / "x"), *args]) == 2
    assert field in capsys.readouterr().err


def test_bad_scenario_file(tmp_path, capsys):
    sc = tmp_path / "bad.yaml"
    sc.write_text("rig: {num_cameras: 4, colour: red}\n")
    assert main(["simulate", "--out", str(tmp_path / "x"), "--scenario", str(sc)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "rig.colour" in err
    assert main(["simulate", "--out", str(tmp_path / "x"), "--scenario", str(tmp_path / "missing.yaml")]) == 2
    base = _simulate(tmp_path, "--points", "20", name="base")
    assert main(["simulate", "--out", str(tmp_path / "x"), "--rig", str(base / "rig.yaml"), "--cameras", "2"]) == 2


def test_solve_round_trip(tmp_path, capsys):
    out = _simulate(tmp_path, "--points", "300", "--seed", "1")
    capsys.readouterr()
    assert main(["solve", "--rig", str(out / "rig.yaml"), "--method", "4pt-bending", str(out / "pair_000.npz")]) == 0
    res = json.loads(capsys.readouterr().out)
    truth = json.loads((out / "pair_000.truth.json").read_text())
    err = pose_errors(np.array(res["R"]), np.array(res["t"]), np.array(truth["R"]), np.array(truth["t"]))
    assert err["rotation"] < 1e-3 and err["translation"] < 1e-2
    assert angle_between(np.array(res["gravity"]), np.array(truth["gravity"])) < 1e-2
    outliers = set(truth["outliers"])
    assert len(outliers & set(res["inliers"])) <= 2
