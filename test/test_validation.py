"""Bad flags, settings files, topics and files: each is one error naming the flag, the file and key, or the topic.

Flags out of range are refused while the command line is parsed (argparse's ``argument --x: ...``, exit 2);
everything else is an InputError the command line prints as ``nrmpc <cmd>: error: ...`` (exit 2).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from badbags import copy_bag, retype
from recordings import recording

from nrmpc_ros.cli.main import main
from nrmpc_ros.core import save_matches
from nrmpc_ros.core.matches import Matches
from nrmpc_ros.frontend.estimates_csv import read_csv


def _run(argv, capsys):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.fixture(scope="module")
def bag(recordings_dir):
    path, rig, _ = recording(recordings_dir, "cross4", "stream-smooth")
    return path, rig


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "--out", str(d), "--points", "200"]) == 0
    return d / "rig.yaml", d / "pair_000.npz"


@pytest.mark.slow
@pytest.mark.parametrize("flag, value", [
    ("--sync-tolerance", "-1"), ("--sync-tolerance", "nan"), ("--sync-tolerance", "inf"), ("--queue-size", "0"),
    ("--seed", "-1"),
])
def test_replay_flags_out_of_range(bag, tmp_path, capsys, flag, value):
    path, rig = bag
    code, _, err = _run(["replay", path, "--rig", rig, "--out", tmp_path / "x.csv", flag, value], capsys)
    assert code == 2 and f"argument {flag}: must be" in err and repr(value) in err
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize("argv, flag", [
    (["solve", "--rig", "{rig}", "--method", "6pt-bending", "--seed", "-1", "{matches}"], "--seed"),
    (["calibrate-bars", "--rig", "{rig}", "--matches", "{matches}", "--out", "{d}/c.yaml", "--gravity-sigma", "0"],
     "--gravity-sigma"),
    (["calibrate-bars", "--rig", "{rig}", "--matches", "{matches}", "--out", "{d}/c.yaml", "--gravity-sigma", "-0.1"],
     "--gravity-sigma"),
])
def test_other_flags_out_of_range(sim, tmp_path, capsys, argv, flag):
    rig, matches = sim
    code, _, err = _run([a.format(rig=rig, matches=matches, d=tmp_path) for a in argv], capsys)
    assert code == 2 and f"argument {flag}: must be" in err


@pytest.mark.slow
def test_imu_topic_that_is_an_image_topic(bag, tmp_path, capsys):
    path, rig = bag
    code, _, err = _run(["replay", path, "--rig", rig, "--out", tmp_path / "x.csv", "--imu-topic",
                         "/cam0/image_raw"], capsys)
    assert code == 2 and "error: --imu-topic: " in err and "sensor_msgs/msg/Image" in err and "Imu" in err


@pytest.mark.slow
def test_imu_topic_of_the_wrong_type(bag, tmp_path, capsys):
    """The rig file's IMU topic carries geometry_msgs/Vector3Stamped: the error names the rig file's imu.topic."""
    path, rig = bag
    bad = retype(copy_bag(path, tmp_path / "bag"), "/imu/data", "geometry_msgs/msg/Vector3Stamped")
    code, _, err = _run(["replay", bad, "--rig", rig, "--out", tmp_path / "x.csv", "--no-progress"], capsys)
    assert code == 2 and f"{rig}: field 'imu.topic'" in err and "Vector3Stamped" in err
    code, _, err = _run(["compare", tmp_path / "x.csv", "--bag", bad], capsys)
    assert code == 2 and str(tmp_path / "x.csv") in err  # no CSV was written by the failed replay


@pytest.mark.slow
def test_ground_truth_of_another_type_is_ignored_with_a_warning(bag, tmp_path, capsys):
    """Ground truth is optional: a /ground_truth/gravity of type std_msgs/String is warned about and left out;
    the estimates are written as without it and compared with the IMU and the pose."""
    path, rig = bag
    bad = retype(copy_bag(path, tmp_path / "bag"), "/ground_truth/gravity", "std_msgs/msg/String")
    code, out, err = _run(["replay", bad, "--rig", rig, "--out", tmp_path / "x.csv", "--no-progress", "--quiet"],
                          capsys)
    assert code == 0, err
    assert "/ground_truth/gravity carries std_msgs/msg/String" in err and "ignored" in err
    assert len(read_csv(tmp_path / "x.csv")) == 3 and "gravity vs IMU" in out and "gravity vs ground truth" not in out


@pytest.mark.slow
def test_camera_info_topics(bag, tmp_path, capsys):
    path, rig = bag
    d = yaml.safe_load(rig.read_text())
    d["cameras"][1]["info_topic"] = d["cameras"][1]["image_topic"]
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(d))
    code, _, err = _run(["replay", path, "--rig", tmp_path / "a.yaml", "--out", tmp_path / "x.csv"], capsys)
    assert code == 2 and str(tmp_path / "a.yaml") in err and "info_topic" in err
    d = yaml.safe_load(rig.read_text())
    d["cameras"][0]["info_topic"] = "/ground_truth/pose"
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(d))
    code, _, err = _run(["replay", path, "--rig", tmp_path / "b.yaml", "--out", tmp_path / "x.csv"], capsys)
    assert code == 2 and f"{tmp_path / 'b.yaml'}: field 'cameras[0].info_topic'" in err
    assert "geometry_msgs/msg/PoseStamped" in err and "CameraInfo" in err


@pytest.mark.slow
@pytest.mark.parametrize("text, key", [
    ("tracking: 5\n", "tracking"),
    ("min_matches: forty\n", "min_matches"),
    ("tracking: {min_matches_per_camera: forty}\n", "tracking.min_matches_per_camera"),
    ("seed: abc\n", "seed"),
    ("tracking: {num_features: 1000000000}\n", "tracking.num_features"),
    ("tracking: {max_tracks: 1000000000}\n", "tracking.max_tracks"),
    ("imu_gravity_floor_deg: " + "9" * 400 + "\n", "imu_gravity_floor_deg"),
    ("sequence: {gravity_bias_sigma: abc}\n", "sequence.gravity_bias_sigma"),
    ("window: yes\n", "window"),
])
def test_replay_config_errors_name_the_file_and_key(bag, tmp_path, capsys, text, key):
    path, rig = bag
    cfg = tmp_path / "settings.yaml"
    cfg.write_text(text)
    code, _, err = _run(["replay", path, "--rig", rig, "--config", cfg, "--out", tmp_path / "x.csv"], capsys)
    assert code == 2 and f"error: {cfg}: field '{key}': " in err, err
    assert "config:" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.parametrize("payload, fragment", [
    (b"tracking: [\n", "not valid YAML"), (b"\x00\x01binary", "binary"), (b"[1, 2]\n", "must be a mapping"),
    ("tracking: {mode: caf\u00e9}\n".encode("latin-1"), "Latin-1"),
])
def test_replay_config_file_that_is_not_a_settings_mapping(bag, tmp_path, capsys, payload, fragment):
    path, rig = bag
    cfg = tmp_path / "settings.yaml"
    cfg.write_bytes(payload)
    code, _, err = _run(["replay", path, "--rig", rig, "--config", cfg, "--out", tmp_path / "x.csv"], capsys)
    assert code == 2 and f"error: {cfg}: " in err and fragment in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_compare_bad_csv_and_window(bag, tmp_path, capsys):
    path, rig = bag
    binary = tmp_path / "b.csv"
    binary.write_bytes(b"PK\x03\x04" + bytes(range(256)))
    code, _, err = _run(["compare", binary, "--bag", path], capsys)
    assert code == 2 and f"{binary}: estimates CSV is binary" in err
    good = tmp_path / "good.csv"
    assert main(["replay", str(path), "--rig", str(rig), "--out", str(good), "--no-progress", "--quiet"]) == 0
    capsys.readouterr()
    code, _, err = _run(["compare", good, "--bag", path, "--imu-window", "-1"], capsys)
    assert code == 2 and "argument --imu-window: must be" in err
    text = good.read_text()
    (tmp_path / "cut.csv").write_text(text[: len(text.splitlines()[0]) + 40])
    code, _, err = _run(["compare", tmp_path / "cut.csv", "--bag", path], capsys)
    assert code == 2 and "line 2: " in err and "columns" in err
    code, _, err = _run(["compare", good, "--bag", path, "--quiet", "--json", tmp_path / "s.json"], capsys)
    assert code == 0, err
    json.loads((tmp_path / "s.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-standard JSON {c}"))


def test_solve_failure_says_why(sim, tmp_path, capsys):
    rig, matches = sim
    with np.load(matches) as z:
        few = Matches(z["f1"][:5], z["f2"][:5], z["cam"][:5], g1_cam=z["g1_cam"], g2_cam=z["g2_cam"],
                      g_cam_index=int(z["g_cam_index"]))
    save_matches(few, tmp_path / "few.npz")
    for method in ("6pt-bending", "4pt-bending", "6pt-nonbending"):
        code, out, err = _run(["solve", "--rig", rig, "--method", method, tmp_path / "few.npz"], capsys)
        result = json.loads(out)
        assert code == 0 and result["success"] is False, err
        assert result["reason"] and result["reason"] != "no reason recorded"


@pytest.mark.parametrize("command", ["solve", "solve-sequence"])
def test_a_text_file_as_npz_gets_no_advice_to_load_it_unsafely(sim, tmp_path, capsys, command):
    rig, _ = sim
    text = tmp_path / "notes.npz"
    text.write_text("view,cam,track\n0,0,1\n")
    code, _, err = _run([command, "--rig", rig, "--method", "6pt-bending", text], capsys)
    assert code == 2 and f"{text}: not a readable .npz archive: it is text" in err
    assert "allow_pickle" not in err and "pickle" not in err
