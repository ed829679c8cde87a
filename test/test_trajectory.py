"""Hold trajectories in the sequence origin as TUM files: layout, ground truth in the same frame, and evo's APE on
them agreeing with the errors replay prints."""

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from recordings import recording

from nrmpc_ros.cli.main import main
from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.estimates_csv import EstimateRow, read_csv
from nrmpc_ros.frontend.reference import Reference
from nrmpc_ros.frontend.trajectory import (
    absolute_errors,
    ground_truth_trajectory,
    read_tum,
    sequence_paths,
    trajectories,
    write_tum,
)


def row(stamp, origin_stamp, R, t):
    return EstimateRow(stamp, stamp - 1.0, "6pt-bending", np.eye(3), np.zeros(3), None, 10, 1.0, {},
                       (origin_stamp, R, t))


def test_trajectories_split_by_sequence_origin_first():
    rng = np.random.default_rng(0)
    R = [exp_so3(rng.normal(size=3) * 0.3) for _ in range(4)]
    rows = [row(2.0, 1.0, R[0], [1, 0, 0]), row(3.0, 1.0, R[1], [2, 0, 0]), row(9.0, 8.0, R[2], [0, 1, 0]),
            row(3.0, 1.0, R[3], [2.5, 0, 0])]  # hold 3.0 estimated again: the last pose counts
    a, b = trajectories(rows)
    assert a.origin_stamp == 1.0 and list(a.stamps) == [1.0, 2.0, 3.0]
    np.testing.assert_allclose(a.R[0], np.eye(3)) and np.testing.assert_allclose(a.t[0], 0)
    np.testing.assert_allclose(a.R[2], R[3]) and np.testing.assert_allclose(a.t[2], [2.5, 0, 0])
    assert list(b.stamps) == [8.0, 9.0]
    assert [p.name for p in sequence_paths("/x/est.txt", 3)] == ["est.txt", "est_seq1.txt", "est_seq2.txt"]


def test_tum_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(1)
    R = np.array([np.eye(3)] + [exp_so3(rng.normal(size=3) * 0.4) for _ in range(4)])
    t = np.vstack([np.zeros(3), rng.normal(size=(4, 3))])
    ref = Reference(pose_t=np.arange(5.0), pose_R=R, pose_p=t)
    (traj,) = trajectories([row(float(k), 0.0, R[k], t[k]) for k in range(1, 5)])
    write_tum(tmp_path / "a.txt", traj)
    back = read_tum(tmp_path / "a.txt")
    np.testing.assert_allclose(back.t, traj.t, atol=1e-8) and np.testing.assert_allclose(back.R, traj.R, atol=1e-8)
    # The ground truth of a rig that starts elsewhere, seen from the origin hold, is the same trajectory.
    W = exp_so3(np.array([0.1, -0.2, 0.7]))
    moved = Reference(pose_t=ref.pose_t, pose_R=W @ R, pose_p=(W @ t.T).T + [5.0, 1.0, -2.0])
    gt = ground_truth_trajectory(traj, moved)
    err = absolute_errors(traj, gt)
    assert err["n"] == 5 and err["position_rmse_m"] < 1e-9 and err["rotation_rmse_deg"] < 1e-6
    shifted = trajectories([row(float(k), 0.0, R[k], t[k] + [0.03, 0, 0.04]) for k in range(1, 5)])[0]
    assert absolute_errors(shifted, gt)["position_rmse_m"] == pytest.approx(0.05 * np.sqrt(4 / 5))
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    with pytest.raises(InputError, match="line 1: expected 8"):
        read_tum(tmp_path / "bad.txt")


@pytest.fixture(scope="module")
def replayed(recordings_dir, tmp_path_factory):
    bag, rig_file, _ = recording(recordings_dir, "cross4", "stream-smooth")
    out = tmp_path_factory.mktemp("tum")
    return bag, rig_file, out


def _evo_rmse(tmp_path, *args) -> float:
    """RMSE printed by the evo_ape command installed beside this Python (its settings kept in tmp_path)."""
    exe = Path(sys.executable).with_name("evo_ape")
    env = {**os.environ, "HOME": str(tmp_path), "MPLBACKEND": "Agg"}
    res = subprocess.run([str(exe), "tum", *map(str, args)], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    return float(re.search(r"rmse\s+([0-9.eE+-]+)", res.stdout).group(1))


@pytest.mark.slow
def test_evo_ape_on_the_replay_tum_files_agrees_with_replay(replayed, capsys):
    bag, rig_file, out = replayed
    est, gt = out / "est.txt", out / "gt.txt"
    assert main(["replay", str(bag), "--rig", str(rig_file), "--out", str(out / "est.csv"), "--tum", str(est),
                 "--tum-gt", str(gt), "--no-progress", "--quiet"]) == 0
    text = capsys.readouterr().out
    m = re.search(r"\((\d+) holds, origin included\): position RMSE ([0-9.]+) m, rotation RMSE ([0-9.]+) deg", text)
    assert m, text
    n, pos, rot = int(m.group(1)), float(m.group(2)), float(m.group(3))
    assert n == 3 and 0 < pos < 0.05  # three holds of this recording
    assert _evo_rmse(out, gt, est) == pytest.approx(pos, abs=1e-4)
    assert _evo_rmse(out, gt, est, "--pose_relation", "angle_deg") == pytest.approx(rot, abs=1e-3)
    assert _evo_rmse(out, gt, est, "--align") <= pos + 1e-6  # alignment only lowers it
    # compare writes the same files from the CSV
    assert main(["compare", str(out / "est.csv"), "--bag", str(bag), "--rig", str(rig_file), "--quiet",
                 "--tum", str(out / "c.txt"), "--tum-gt", str(out / "cgt.txt")]) == 0
    assert (out / "c.txt").read_text() == est.read_text() and (out / "cgt.txt").read_text() == gt.read_text()
    (traj,) = trajectories(read_csv(out / "est.csv"))
    assert absolute_errors(traj, read_tum(gt))["position_rmse_m"] == pytest.approx(pos, abs=1e-4)


@pytest.mark.slow
def test_tum_gt_needs_tum_and_ground_truth(replayed, capsys):
    bag, rig_file, out = replayed
    assert main(["replay", str(bag), "--rig", str(rig_file), "--out", str(out / "x.csv"), "--tum-gt",
                 str(out / "g.txt")]) == 2
    assert "--tum-gt" in capsys.readouterr().err and not (out / "x.csv").exists()
