"""``nrmpc simulate``: files, determinism, scenario files, validation, the solve round trip, and sequences."""

import json

import numpy as np
import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.core import load_matches, load_rig, pose_errors
from nrmpc_ros.core.deformation import deformed_extrinsics
from nrmpc_ros.core.so3 import angle_between
from nrmpc_ros.core.tracks import load_tracks


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
    (["--sequence", "--points", "10"], "--points"),
    (["--sequence", "--gravity-frame", "body"], "--gravity-frame"),
    (["--views", "4"], "--views"),
    (["--no-gravity"], "--no-gravity"),
    (["--sequence", "--views", "1"], "num_views"),
    (["--sequence", "--track-views", "4", "3"], "max_track_views"),
    (["--sequence", "--outliers", "1.5"], "outlier_fraction"),
    (["--sequence", "--EI", "0"], "rig.EI"),
    (["--sequence", "--min-step", "100", "--max-step", "120", "--views", "2", "--tracks-per-camera", "5"],
     "max_step_deg"),
])
def test_bad_input_is_a_clear_error(tmp_path, capsys, args, field):
    try:
        code = main(["simulate", "--out", str(tmp_path / "x"), *args])
    except SystemExit as exc:  # a flag out of range is refused while parsing
        code = exc.code
    assert code == 2
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


def test_sequence_writes_rig_tracks_and_truth(tmp_path):
    out = _simulate(tmp_path, "--sequence", "--views", "4", "--tracks-per-camera", "25", "--count", "2", "--seed",
                    "3", "--noise", "0", "--outliers", "0.1", "--track-views", "2", "3", "--min-step", "3",
                    "--max-step", "10")
    rig = load_rig(out / "rig.yaml")
    assert rig.num_cameras == 4 and rig.is_flexible
    for k, seed in ((0, 3), (1, 4)):
        tr = load_tracks(out / f"seq_{k:03d}.npz")
        tr.check_rig(rig)
        truth = json.loads((out / f"seq_{k:03d}.truth.json").read_text())
        assert truth["seed"] == seed and truth["tracks"] == f"seq_{k:03d}.npz" and truth["num_views"] == 4
        assert truth["scenario"]["num_views"] == 4 and truth["scenario"]["max_track_views"] == 3
        R, t, g = (np.array(truth[key]) for key in ("R", "t", "gravity"))
        assert tr.num_views == 4 and np.array_equal(R[0], np.eye(3)) and np.allclose(g[0], truth["g0"])
        assert np.allclose(g, np.einsum("kba,b->ka", R, g[0]))
        assert tr.g_meas is not None and np.all(angle_between(tr.g_meas, g) < np.radians(3))
        outliers = np.array(truth["outliers"])
        assert len(outliers) == round(0.1 * len(tr))
        # noise-free inliers: each track's bearings meet in one point under the truth and the written rig
        inl = np.setdiff1d(np.arange(len(tr)), outliers)
        i1, i2 = tr.pair_indices(0, 1)
        both = np.isin(i1, inl) & np.isin(i2, inl)
        i1, i2 = i1[both], i2[both]
        w, W = deformed_extrinsics(rig, g)
        o1, d1 = w[0, tr.cam[i1]], np.einsum("nij,nj->ni", W[0, tr.cam[i1]], tr.f[i1])
        o2 = np.einsum("ij,nj->ni", R[1], w[1, tr.cam[i2]]) + t[1]
        d2 = np.einsum("ij,nj->ni", R[1], np.einsum("nij,nj->ni", W[1, tr.cam[i2]], tr.f[i2]))
        gap = np.abs(np.einsum("ni,ni->n", o2 - o1, np.cross(d1, d2))) / np.linalg.norm(np.cross(d1, d2), axis=1)
        assert len(gap) > 20 and gap.max() < 1e-6  # metres between the two rays of a landmark
    assert not np.array_equal(np.load(out / "seq_000.npz")["f"][:5], np.load(out / "seq_001.npz")["f"][:5])


def test_sequence_scenario_file_rig_file_and_no_gravity(tmp_path):
    base = _simulate(tmp_path, "--cameras", "3", "--points", "20", name="base")
    sc = tmp_path / "seq.yaml"
    sc.write_text(f"rig_file: {base / 'rig.yaml'}\nnum_views: 3\ntracks_per_camera: 15\npixel_noise: 0.0\n"
                  "seed: 9\ncount: 1\n")
    out = _simulate(tmp_path, "--sequence", "--scenario", str(sc), "--no-gravity", "--views", "2", "--prefix", "s")
    tr = load_tracks(out / "s_000.npz")
    truth = json.loads((out / "s_000.truth.json").read_text())
    assert tr.g_meas is None and tr.num_views == 2 and truth["seed"] == 9  # the flag wins over the file
    assert truth["scenario"]["tracks_per_camera"] == 15 and not truth["scenario"]["gravity_measured"]
    assert load_rig(out / "rig.yaml").num_cameras == 3 and set(np.unique(tr.cam)) == {0, 1, 2}


def test_sequence_scenario_file_takes_sequence_keys_only(tmp_path, capsys):
    sc = tmp_path / "bad.yaml"
    sc.write_text("num_views: 3\nnum_points: 100\n")
    assert main(["simulate", "--out", str(tmp_path / "x"), "--sequence", "--scenario", str(sc)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "'num_points'" in err
