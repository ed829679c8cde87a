"""nrmpc replay and nrmpc compare end to end: CSV columns and conventions, the batch solution, bad input."""

import math

import numpy as np
import pytest
import yaml
from recordings import recording

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.cli.main import main
from nrmpc_ros.core.so3 import angle_between, rotation_angle
from nrmpc_ros.frontend.estimates_csv import CSV_EXTRA, CSV_HEADER, read_csv
from nrmpc_ros.frontend.reference import read_reference


@pytest.fixture(scope="module")
def bag(recordings_dir):
    path, rig_file, _ = recording(recordings_dir, "cross4", "stream-smooth")
    return path, rig_file


@pytest.fixture(scope="module")
def replays(bag, tmp_path_factory):
    path, rig_file = bag
    d = tmp_path_factory.mktemp("replay")
    out = {}
    for name, extra in (("auto", []), ("vision", ["--no-imu"])):
        csv_path = d / f"{name}.csv"
        assert main(["replay", str(path), "--rig", str(rig_file), "--out", str(csv_path), "--batch",
                     str(d / f"{name}.batch.csv"), "--no-progress", *extra]) == 0
        out[name] = (csv_path, d / f"{name}.batch.csv")
    return out


@pytest.mark.slow
def test_csv_format(replays):
    csv_path, _ = replays["auto"]
    header = csv_path.read_text().splitlines()[0].split(",")
    assert header == CSV_HEADER + CSV_EXTRA
    rows = read_csv(csv_path)
    assert len(rows) == 3 and {r.method for r in rows} == {"4pt-bending"}
    # the origin's row comes with the second hold's, paired with it (docs/PIPELINE.md, "The origin's estimate")
    assert rows[0].origin[0] == rows[0].stamp and rows[0].ref_stamp == rows[1].stamp
    for r in rows:
        assert (r.stamp > r.ref_stamp or r is rows[0]) and r.gravity is not None
        assert abs(np.linalg.norm(r.gravity) - 9.81) < 1e-6
        assert float(r.extra["settled_frames"]) >= 3 and float(r.extra["gravity_sigma_deg"]) > 0
        assert r.origin is not None and r.origin[0] <= r.ref_stamp
    vision = read_csv(replays["vision"][0])
    assert {r.method for r in vision} == {"6pt-bending"}


@pytest.mark.slow
def test_conventions_against_ground_truth_directly(bag, replays):
    """(R, t) maps the current hold into the reference hold, gravity is in the current body frame, and the pose
    in the origin chains the relative poses (docs/CONVENTIONS.md, "Frames")."""
    path, _ = bag
    with BagReader(path) as b:
        ref = read_reference(b, "/imu/data")

    def pose(stamp):
        i = int(np.argmin(np.abs(ref.pose_t - stamp)))
        return ref.pose_R[i], ref.pose_p[i]

    rows = read_csv(replays["auto"][0])
    for r in rows:
        (R1, p1), (R2, p2) = pose(r.ref_stamp), pose(r.stamp)
        assert math.degrees(rotation_angle((R1.T @ R2).T @ r.R)) < 0.5
        assert math.degrees(angle_between(r.t, R1.T @ (p2 - p1))) < 10.0
        assert math.degrees(angle_between(r.gravity, R2.T @ np.array([0, 0, -9.81]))) < 1.0
        s0, R0, t0 = r.origin
        Ro, po = pose(s0)
        assert math.degrees(rotation_angle((Ro.T @ R2).T @ R0)) < 0.5


@pytest.mark.slow
def test_batch_solution(replays):
    """The batch CSV holds every hold after the first, relative to the one before, from one joint solve."""
    rows, batch = read_csv(replays["auto"][0])[1:], read_csv(replays["auto"][1])  # (the first: the origin's)
    assert [r.stamp for r in batch] == [r.stamp for r in rows]
    for a, b in zip(rows, batch):
        assert math.degrees(angle_between(a.gravity, b.gravity)) < 1.0


@pytest.mark.slow
def test_replay_summary_and_compare(bag, replays, tmp_path, capsys):
    path, rig_file = bag
    assert main(["compare", str(replays["auto"][0]), "--bag", str(path), "--rig", str(rig_file), "--plot",
                 str(tmp_path / "g.png")]) == 0
    text = capsys.readouterr().out
    assert "gravity vs ground truth" in text and "gravity vs IMU" in text and "relative rotation" in text
    assert "with an estimate (after the first): 2/2" in text and "outside every hold: 0" in text
    png = (tmp_path / "g.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000


@pytest.mark.slow
def test_missing_topic_and_wrong_size(bag, tmp_path, capsys):
    path, rig_file = bag
    rig = yaml.safe_load(rig_file.read_text())
    rig["cameras"][2]["image_topic"] = "/cam9/image_raw"
    bad = tmp_path / "rig.yaml"
    bad.write_text(yaml.safe_dump(rig))
    assert main(["replay", str(path), "--rig", str(bad), "--out", str(tmp_path / "x.csv"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "/cam9/image_raw" in err and "/cam0/image_raw" in err
    rig = yaml.safe_load(rig_file.read_text())
    rig["cameras"][1]["resolution"] = [400, 240]  # another aspect ratio: no resize recovers it
    bad.write_text(yaml.safe_dump(rig))
    assert main(["replay", str(path), "--rig", str(bad), "--out", str(tmp_path / "y.csv"), "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert "/cam1/image_raw" in captured.err and "320x240" in captured.err
    assert "/cam1/image_raw: wrong image size" in captured.out  # dropped at the input, counted by topic


def test_replay_creates_the_output_folder(tmp_path):
    """The README's main command writes to out/ in a fresh clone, where out/ does not exist yet."""
    from nrmpc_ros.frontend.estimates_csv import CsvWriter

    out = tmp_path / "new" / "dir" / "x.csv"
    w = CsvWriter(out)
    w.close()
    assert out.read_text().startswith(",".join(CSV_HEADER))


@pytest.mark.slow
def test_covariances_that_claim_too_little_are_said_and_overruled(recordings_dir, tmp_path, capsys):
    """A driver's covariances claiming a fifth of the IMU's noise: the replay says so with both numbers and
    finds every hold (with the claim alone, none)."""
    path, rig_file, _ = recording(recordings_dir, "cross4", "imu-claims-little")
    assert main(["replay", str(path), "--rig", str(rig_file), "--out", str(tmp_path / "x.csv"), "--no-progress"]) == 0
    text = capsys.readouterr().out
    line = next(ln for ln in text.splitlines() if ln.startswith("IMU stillness test:"))
    assert "from the white noise" in line and "covariances claim 0.004 m/s^2 and 0.0004 rad/s" in line
    assert "with an estimate (after the first): 2/2" in text


@pytest.mark.slow
def test_a_low_pass_filtered_imu_whose_driver_claims_a_fifth_of_its_noise_loses_no_hold(tmp_path, capsys):
    """An IMU that low-pass filters at 20 Hz and whose messages' covariances claim a fifth of its noise: the claim
    read every window as motion (0 holds) and the filter hides the noise from the samples' steps. The images held
    still where the IMU read motion, so the claim is dropped for the samples' own noise, and said."""
    out, rig = tmp_path / "dlpf", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(out), "--save-rig", str(rig), "--resolution", "320x240", "--supersample",
                 "1", "--cameras", "3", "--views", "6", "--bar-hz", "4", "--damping", "0.05", "--imu-rate", "400",
                 "--imu-lowpass-hz", "20", "--imu-covariance-scale", "0.2", "--seed", "22", "--no-progress"]) == 0
    assert main(["replay", str(out), "--rig", str(rig), "--out", str(tmp_path / "x.csv"), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "with an estimate (after the first): 5/5" in text, text
    assert any(ln.startswith("IMU covariances: not used") for ln in text.splitlines()), text
    medians = [float(ln.split("median")[1].split()[0]) for ln in text.splitlines()
               if ln.strip().startswith("gravity vs ground truth")]
    assert medians and max(medians) < 0.2


@pytest.mark.slow
def test_a_rig_file_whose_rotations_are_off_by_its_stated_std(bag, tmp_path, capsys):
    """Each camera's rotation in the rig file off by 0.2 deg per axis, and rotation_std_deg saying so: the replay
    estimates the rest rotations' errors, says how far each came out, and its gravities lie closer to the ground
    truth than with the same rig file taken as exact."""
    from nrmpc_ros.core import load_rig, save_rig

    path, rig_file = bag
    off = load_rig(rig_file).with_rotation_errors(0.2, np.random.default_rng(3))
    save_rig(off, tmp_path / "stated.yaml")
    d = yaml.safe_load((tmp_path / "stated.yaml").read_text())
    for cam in d["cameras"]:
        del cam["rotation_std_deg"]
    (tmp_path / "exact.yaml").write_text(yaml.safe_dump(d))
    errors = {}
    for name in ("exact", "stated"):
        csv_path = tmp_path / f"{name}.csv"
        assert main(["replay", str(path), "--rig", str(tmp_path / f"{name}.yaml"), "--out", str(csv_path),
                     "--no-progress", "--quiet"]) == 0
        text = capsys.readouterr().out
        lines = [ln for ln in text.splitlines() if ln.startswith("rig file's rest rotations")]
        assert len(lines) == (name == "stated")
        if lines:
            assert all(f"{c.name} " in lines[0] and "(0.2)" in lines[0] for c in off.cameras)
        errors[name] = float(next(ln for ln in text.splitlines() if "gravity vs ground truth" in ln)
                             .split("median")[1].split()[0])
    assert errors["stated"] < errors["exact"], errors
