"""`nrmpc solve` round trip (docs/CONVENTIONS.md (Files)) on files written from the generator."""

import json
import subprocess
import sys

import numpy as np

from nrmpc_ros.cli.main import main
from nrmpc_ros.core import pose_errors, save_matches, save_rig
from nrmpc_ros.sim.synthetic import Scenario, make_problem


def _write(tmp_path, seeds):
    paths = []
    for seed in seeds:
        pb = make_problem(Scenario(), seed=seed)
        save_matches(pb.matches, tmp_path / f"pair{seed}.npz")
        paths.append((str(tmp_path / f"pair{seed}.npz"), pb))
    save_rig(pb.rig, tmp_path / "rig.yaml")
    return tmp_path / "rig.yaml", paths


def test_solve_prints_one_result_per_file_in_order(tmp_path, capsys):
    rig, paths = _write(tmp_path, [0, 1])
    assert main(["solve", "--rig", str(rig), "--method", "4pt-bending", *[p for p, _ in paths]]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2
    for line, (path, pb) in zip(lines, paths):
        r = json.loads(line)
        assert r["matches"] == path and r["method"] == "4pt-bending" and r["success"]
        assert set(r) >= {"R", "t", "gravity", "num_inliers", "inliers", "time_s"}
        e = pose_errors(np.array(r["R"]), np.array(r["t"]), pb.R, pb.t, np.array(r["gravity"]), pb.gravity)
        assert e["rotation"] < 1e-3 and e["gravity"] < 1e-2


def test_solve_out_file_and_nonbending_null_gravity(tmp_path, capsys):
    rig, paths = _write(tmp_path, [2])
    out = tmp_path / "res.jsonl"
    assert main(["solve", "--rig", str(rig), "--method", "6pt-nonbending", "--out", str(out), paths[0][0]]) == 0
    assert capsys.readouterr().out == ""
    r = json.loads(out.read_text())
    assert r["gravity"] is None


def test_solve_bad_inputs_exit_2_with_clear_message(tmp_path):
    rig, paths = _write(tmp_path, [3])
    bad = tmp_path / "bad.npz"
    np.savez(bad, f1=np.ones((4, 2)), f2=np.ones((4, 3)), cam=np.zeros(4, int))
    proc = subprocess.run([sys.executable, "-m", "nrmpc_ros.cli.main", "solve", "--rig", str(rig), "--method",
                           "6pt-bending", str(bad)], capture_output=True, text=True)
    assert proc.returncode == 2 and str(bad) in proc.stderr and "'f1'" in proc.stderr
    assert "Traceback" not in proc.stderr
    nograv = make_problem(Scenario(gravity_frame="none"), seed=0).matches
    save_matches(nograv, tmp_path / "ng.npz")
    proc = subprocess.run([sys.executable, "-m", "nrmpc_ros.cli.main", "solve", "--rig", str(rig), "--method",
                           "4pt-bending", str(tmp_path / "ng.npz")], capture_output=True, text=True)
    assert proc.returncode == 2 and "needs gravity" in proc.stderr
