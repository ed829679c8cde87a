"""nrmpc calibrate-bars on rendered bags with known EI (bag path: frontend.replay.collect_sequences)."""

import numpy as np
import pytest
import yaml

from nrmpc_ros.cli.main import main
from nrmpc_ros.core import load_rig, save_rig
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.replay import collect_sequences
from nrmpc_ros.sim.synthetic import RigSpec, make_rig


def small_rig(ei):
    """4-camera cross on 0.4 m bars (tip mass 0.1 kg), QVGA cameras to keep rendering fast; IMU at the centre."""
    return make_rig(RigSpec(num_cameras=4, layout="cross", EI=ei, mass=0.1, focal=235.0, resolution=(320, 240)))


def render(tmp, name, ei, seed):
    """A bag of 8 holds (2 s, 6 frames each: the bars settle within two periods) of the rig with the given EI;
    returns (bag, rig file)."""
    rig_file = tmp / f"{name}_truth.yaml"
    save_rig(small_rig(ei), rig_file)
    bag = tmp / name
    assert main(["make-bag", "--rig", str(rig_file), "--views", "8", "--hold-seconds", "2.0", "--rate", "3",
                 "--seed", str(seed), "--out", str(bag), "--no-progress"]) == 0
    return bag, rig_file


def off_by(tmp, name, ei):
    path = tmp / f"{name}_wrong.yaml"
    save_rig(small_rig(ei), path, header=f"EI set to {ei} (wrong)")
    return path


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("calbags")
    return {"bending": render(tmp, "bending", 0.2, 1), "stiff": render(tmp, "stiff", 1e5, 3), "tmp": tmp}


@pytest.mark.slow
def test_bending_rig_compliance_recovered_from_a_rig_file_off_by_two(bags, capsys):
    bag, truth_file = bags["bending"]
    tmp = bags["tmp"]
    wrong = off_by(tmp, "bending", 0.4)
    out = tmp / "bending_cal.yaml"
    assert main(["calibrate-bars", str(bag), "--rig", str(wrong), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "not observable" not in text
    truth, cal = load_rig(truth_file), load_rig(out)
    ratio = cal.compliance / truth.compliance
    assert np.all(np.abs(ratio - 1.0) < 0.05), ratio
    std = np.array([float(line.split("+-")[1].split()[0]) for line in text.splitlines() if "+-" in line])
    assert np.all(np.abs(cal.compliance - truth.compliance) < 4 * std)  # the stds cover the errors
    assert f"from bag {bag}" in out.read_text()


@pytest.mark.slow
def test_stiff_rig_reported_not_observable(bags, capsys):
    bag, _ = bags["stiff"]
    tmp = bags["tmp"]
    wrong = off_by(tmp, "stiff", 2e5)
    out = tmp / "stiff_cal.yaml"
    assert main(["calibrate-bars", str(bag), "--rig", str(wrong), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.count("not observable") >= 4  # every bar, not a made-up number
    assert "EI 0." not in text
    np.testing.assert_allclose([c.EI for c in load_rig(out).cameras], 2e5, rtol=1e-9)  # left as in the file


@pytest.mark.slow
def test_collect_sequences_returns_holds_with_imu_gravity(bags):
    bag, truth_file = bags["bending"]
    stats = {}
    seqs = collect_sequences(bag, load_rig(truth_file), stats=stats)
    assert sum(s.tracks.num_views for s in seqs) >= 7  # of the 8 holds
    for s in seqs:
        tr = s.tracks
        assert tr.g_meas is not None and np.all(np.isfinite(tr.g_meas))
        np.testing.assert_allclose(np.linalg.norm(tr.g_meas, axis=1), 9.81, rtol=0.01)
        assert len(np.unique(tr.cam)) >= 2 and np.all(s.measured_sigma > 0)
        assert s.R.shape == (tr.num_views, 3, 3) and s.gravity.shape == (3,)


@pytest.mark.slow
def test_bag_or_rig_without_imu_is_a_clear_error(bags, tmp_path):
    bag, truth_file = bags["bending"]
    d = yaml.safe_load(truth_file.read_text())
    d["imu"]["topic"] = "/imu/missing"
    other = tmp_path / "other_topic.yaml"
    other.write_text(yaml.safe_dump(d))
    with pytest.raises(InputError) as err:
        collect_sequences(bag, load_rig(other))
    assert str(bag) in str(err.value) and "/imu/missing" in str(err.value) and "/imu/data" in str(err.value)
    del d["imu"]
    no_imu = tmp_path / "no_imu.yaml"
    no_imu.write_text(yaml.safe_dump(d))
    assert main(["calibrate-bars", str(bag), "--rig", str(no_imu), "--out", str(tmp_path / "x.yaml")]) == 2
    assert not (tmp_path / "x.yaml").exists()
