"""nrmpc replay + nrmpc compare end to end on the sample bag (bags/sample): counts, conventions, error bounds."""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.cli.main import main
from nrmpc_ros.core.so3 import angle_between, quat_xyzw_to_matrix, rotation_angle
from nrmpc_ros.frontend.evaluation import CSV_HEADER, evaluate, read_csv, read_reference

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "bags" / "sample"
RIG = ROOT / "config" / "sample_cross4.yaml"
pytestmark = pytest.mark.skipif(not (BAG / "metadata.yaml").exists() or not RIG.exists(),
                                reason="sample bag not present")


@pytest.fixture(scope="module")
def replays(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay")
    out = {}
    for name, extra in (("auto", []), ("vision", ["--no-imu"])):
        csv_path = d / f"{name}.csv"
        assert main(["replay", str(BAG), "--rig", str(RIG), "--out", str(csv_path), "--no-progress", *extra]) == 0
        out[name] = csv_path
    return out


@pytest.fixture(scope="module")
def reference():
    with BagReader(BAG) as bag:
        return read_reference(bag, "/imu/data"), sum(1 for _ in bag.messages(["/cam0/image_raw"]))


def test_csv_format(replays):
    with open(replays["auto"]) as f:
        rows = list(csv.reader(f))
    assert rows[0][:15] == CSV_HEADER
    for r in rows[1:]:
        assert float(r[0]) > float(r[1])  # stamp after ref_stamp
        q = np.array([float(x) for x in r[3:7]])
        assert abs(np.linalg.norm(q) - 1) < 1e-9
        assert r[2] == "4pt-bending" and all(x != "" for x in r[10:13])
        assert abs(np.linalg.norm([float(x) for x in r[10:13]]) - 9.81) < 1e-6
    with open(replays["vision"]) as f:
        assert {r["method"] for r in csv.DictReader(f)} == {"6pt-bending"}


def test_conventions_against_ground_truth_directly(replays):
    """Independent of the evaluation module: (q, t) is the current view in the reference view, g in the current."""
    rows = read_csv(replays["auto"])
    with BagReader(BAG) as bag:
        pose, grav = {}, {}
        for topic, _, m in bag.messages(["/ground_truth/pose", "/ground_truth/gravity"]):
            st = round(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, 6)
            if topic == "/ground_truth/pose":
                o, p = m.pose.orientation, m.pose.position
                pose[st] = (quat_xyzw_to_matrix([o.x, o.y, o.z, o.w]), np.array([p.x, p.y, p.z]))
            else:
                grav[st] = np.array([m.vector.x, m.vector.y, m.vector.z])
    for r in rows:
        (R1, p1), (R2, p2) = pose[round(r.ref_stamp, 6)], pose[round(r.stamp, 6)]
        assert math.degrees(rotation_angle((R1.T @ R2).T @ r.R)) < 0.5
        assert math.degrees(angle_between(r.t, R1.T @ (p2 - p1))) < 5.0
        assert math.degrees(angle_between(r.gravity, grav[round(r.stamp, 6)])) < 1.0


def check_bounds(csv_path, reference, grav_bound):
    ref, num_frames = reference
    rows = read_csv(csv_path)
    ev = evaluate(rows, ref)
    assert ev.holds == 9 and num_frames == 18
    assert ev.coverage >= 0.9  # static views (after the first) with an estimate
    method = rows[0].method
    assert ev.stats("gravity_vs_gt_deg", method)["median"] <= grav_bound
    assert ev.stats("rotation_deg", method)["median"] <= 0.5
    return ev


def test_4pt_bending_bounds(replays, reference):
    ev = check_bounds(replays["auto"], reference, 1.0)
    assert ev.stats("gravity_vs_imu_deg")["median"] <= 1.0
    assert ev.stats("imu_vs_gt_deg")["median"] < 0.5  # the IMU bias of the sample bag


def test_6pt_bending_bounds(replays, reference):
    check_bounds(replays["vision"], reference, 2.0)


def test_replay_summary_and_compare(replays, tmp_path, capsys):
    assert main(["compare", str(replays["auto"]), "--bag", str(BAG), "--rig", str(RIG), "--plot",
                 str(tmp_path / "g.png"), "--json", str(tmp_path / "s.json")]) == 0
    text = capsys.readouterr().out
    assert "gravity vs ground truth" in text and "gravity vs IMU" in text and "relative rotation" in text
    png = (tmp_path / "g.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["4pt-bending"]["gravity_vs_gt_deg"]["n"] == 8
    assert stats["attitudes_with_estimate"] == 8 and stats["static_attitudes"] == 9
    assert stats["4pt-bending"]["gravity_vs_gt_deg"]["median"] <= 1.0


def test_missing_topic_and_wrong_size(tmp_path, capsys):
    rig = yaml.safe_load(RIG.read_text())
    rig["cameras"][2]["image_topic"] = "/cam9/image_raw"
    bad = tmp_path / "rig.yaml"
    bad.write_text(yaml.safe_dump(rig))
    assert main(["replay", str(BAG), "--rig", str(bad), "--out", str(tmp_path / "x.csv"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "'/cam9/image_raw' not in the bag" in err and "/cam0/image_raw" in err
    rig = yaml.safe_load(RIG.read_text())
    rig["cameras"][1]["resolution"] = [320, 240]
    bad.write_text(yaml.safe_dump(rig))
    assert main(["replay", str(BAG), "--rig", str(bad), "--out", str(tmp_path / "y.csv"), "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert "/cam1/image_raw" in captured.err and "640x480" in captured.err
    assert "/cam1/image_raw: wrong image size 18" in captured.out  # dropped at the input, counted by topic
    assert read_csv(tmp_path / "y.csv") == []


def test_replay_creates_the_output_folder(tmp_path):
    """The README's main command writes to out/ in a fresh clone, where out/ does not exist yet."""
    from nrmpc_ros.frontend.evaluation import CsvWriter

    out = tmp_path / "new" / "dir" / "x.csv"
    w = CsvWriter(out)
    w.close()
    assert out.read_text().startswith("stamp,ref_stamp,method,qx,qy,qz,qw,tx,ty,tz,gx,gy,gz,num_inliers,time_ms")
