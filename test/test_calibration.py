"""Bar self-calibration on synthetic pairs with known EI."""

import numpy as np
import pytest

from nrmpc_ros.calibration import calibrate_bars
from nrmpc_ros.cli.main import main
from nrmpc_ros.core import estimate, load_rig, pose_errors, save_matches, save_rig
from nrmpc_ros.errors import EstimationError
from nrmpc_ros.sim.synthetic import RigSpec, Scenario, make_problem, make_rig


def _pairs(ei, n=6, seed=0):
    sc = Scenario(rig=RigSpec(EI=ei), gravity_frame="body", gravity_noise_px=0.5, pixel_noise=0.3, num_points=300)
    return [make_problem(sc, seed=seed + s) for s in range(n)]


def test_recovers_compliance_from_a_rig_file_off_by_two():
    truth = make_rig(RigSpec(EI=0.3))
    wrong = truth.with_compliance(truth.compliance * 2.0)
    cal = calibrate_bars(wrong, [p.matches for p in _pairs(0.3)])
    assert cal.observable.all()
    assert np.all(np.abs(cal.compliance / truth.compliance - 1.0) < 0.10), cal.compliance
    assert np.all(cal.std < 0.05 * cal.compliance)
    calibrated = cal.calibrated_rig(wrong)
    assert np.allclose([c.EI for c in calibrated.cameras], 0.3, rtol=0.1)


def test_shared_scalar_and_rigid_rig_not_observable():
    truth = make_rig(RigSpec(EI=0.3))
    cal = calibrate_bars(truth.with_compliance(truth.compliance * 0.5), [p.matches for p in _pairs(0.3, 4)],
                         shared=True)
    assert len(cal.compliance) == 1 and abs(cal.compliance[0] / truth.compliance[0] - 1) < 0.1
    stiff = make_rig(RigSpec(EI=1e6))  # practically rigid
    cal = calibrate_bars(stiff, [p.matches for p in _pairs(1e6, 4)])
    assert not cal.observable.any()
    assert any("not observable" in n for n in cal.notes)
    assert np.allclose(cal.calibrated_rig(stiff).compliance, stiff.compliance)


def test_calibrated_rig_estimates_better_than_a_rig_off_by_two():
    truth = make_rig(RigSpec(EI=0.3))
    wrong = truth.with_compliance(truth.compliance * 2.0)
    cal = calibrate_bars(wrong, [p.matches for p in _pairs(0.3, 5)])
    calibrated = cal.calibrated_rig(wrong)
    errs = {"wrong": [], "calibrated": []}
    for pb in _pairs(0.3, 4, seed=100):
        for name, rig in (("wrong", wrong), ("calibrated", calibrated)):
            est = estimate(rig, pb.matches, method="6pt-bending", seed=0)
            errs[name].append(pose_errors(est.R, est.t, pb.R, pb.t, est.gravity, pb.gravity)["gravity"])
    assert np.median(errs["calibrated"]) < 0.2 * np.median(errs["wrong"])


def test_needs_gravity(tmp_path):
    pb = make_problem(Scenario(gravity_frame="none"), seed=0)
    with pytest.raises(EstimationError, match="gravity"):
        calibrate_bars(pb.rig, [pb.matches])


def test_cli_writes_calibrated_rig(tmp_path, capsys):
    truth = make_rig(RigSpec(EI=0.3))
    save_rig(truth.with_compliance(truth.compliance * 2.0), tmp_path / "rig.yaml")
    files = []
    for k, pb in enumerate(_pairs(0.3, 4)):
        save_matches(pb.matches, tmp_path / f"p{k}.npz")
        files.append(str(tmp_path / f"p{k}.npz"))
    out = tmp_path / "cal.yaml"
    assert main(["calibrate-bars", "--rig", str(tmp_path / "rig.yaml"), "--out", str(out), "--matches", *files]) == 0
    assert "compliance" in capsys.readouterr().out
    rig = load_rig(out)
    assert np.allclose([c.EI for c in rig.cameras], 0.3, rtol=0.1)
    assert "calibrated by nrmpc calibrate-bars" in out.read_text()


def test_sequences_of_holds_recover_every_bar_with_covering_stds():
    """calibrate_sequences (the bag path of calibrate-bars) on simulated sequences: started from a rig file with
    every EI twice the truth and the truth's poses perturbed, each bar comes back within its reported std, and
    the jackknife over holds gives its own std beside the formal one."""
    from nrmpc_ros.calibration import calibrate_sequences
    from nrmpc_ros.core.incremental import SequenceRecord
    from nrmpc_ros.core.so3 import exp_so3
    from nrmpc_ros.sim.sequence import SequenceScenario, make_sequence

    spec = RigSpec(num_cameras=3, layout="ring", EI=0.5, mass=0.1)
    records, rng = [], np.random.default_rng(7)
    for seed in range(2):
        p = make_sequence(SequenceScenario(rig=spec, num_views=8, pixel_noise=0.3, outlier_fraction=0.05), seed=seed)
        R = np.array([exp_so3(rng.normal(scale=0.002, size=3)) @ r for r in p.R])
        t = p.t + rng.normal(scale=0.002, size=p.t.shape)
        sigma = np.full(p.tracks.num_views, np.radians(0.3))
        records.append(SequenceRecord(p.tracks, R, t, p.gravity[0], sigma))
    truth = p.rig
    wrong = truth.with_compliance(truth.compliance / 2.0)
    cal = calibrate_sequences(wrong, records)
    assert cal.num_sequences == 2 and cal.num_views == 16
    assert np.all(cal.observable)
    k_true = np.array([truth.compliance[cal.groups == gi][0] for gi in range(len(cal.compliance))])
    err = cal.compliance - k_true
    assert np.all(np.abs(err) / k_true < 0.05), err
    assert np.all(np.abs(err) < 4 * cal.std)
    assert np.all(np.isfinite(cal.std_jackknife)) and np.all(cal.std >= cal.std_formal)
    assert np.all(cal.std == np.maximum(cal.std_formal, cal.std_jackknife))
