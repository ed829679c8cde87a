"""The accelerometer's tilt from the still holds' norms: the prior of the joint estimate's tilt follows what the
norms show, and an uncalibrated accelerometer's gravities keep their stds (docs/PIPELINE.md, "The accelerometer's
tilt")."""

import math

import numpy as np
import pytest

from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.frontend.accel_tilt import UNCALIBRATED_TILT_DEG, AccelTiltEvidence, describe_tilt

G = 9.81
CALIBRATED = math.radians(0.3)
WIDE = math.radians(UNCALIBRATED_TILT_DEG)
FLOOR = math.radians(0.05)


def _holds(seed: int, bias_ms2: float, n: int = 8, min_tilt_deg: float = 10.0, max_tilt_deg: float = 40.0,
           scales=(1.0, 1.0, 1.0), noise_ms2: float = 0.002):
    """Mean accelerometers (sensor frame) of ``n`` still holds tilted ``min_tilt_deg``-``max_tilt_deg`` about
    random horizontal axes, with a bias of norm ``bias_ms2`` in a random direction, per-axis ``scales`` and
    averaged noise; each hold's true tilt of its direction (rad), and the bias's size over gravity (rad)."""
    rng = np.random.default_rng(seed)
    b = rng.normal(size=3)
    b *= bias_ms2 / np.linalg.norm(b)
    means, tilts = [], []
    for _ in range(n):
        ax = np.append(rng.normal(size=2), 0.0)
        R = exp_so3(ax / np.linalg.norm(ax) * math.radians(rng.uniform(min_tilt_deg, max_tilt_deg)))
        up = R.T @ np.array([0.0, 0.0, G])  # the reading at rest without errors
        a = np.asarray(scales) * up + b + rng.normal(scale=noise_ms2, size=3)
        means.append(a)
        tilts.append(math.acos(np.clip(a @ up / np.linalg.norm(a) / G, -1, 1)))
    return means, np.array(tilts), bias_ms2 / G


def _evidence(means, noise_ms2: float = 0.002, calibrated=CALIBRATED, wide=WIDE):
    tilt = AccelTiltEvidence(calibrated, wide, FLOOR)
    for a in means:
        tilt.observe_still(a, noise_ms2 ** 2)
    return tilt


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("bias_ms2", [0.2, 0.6, 1.0])
def test_a_bias_is_measured_and_the_prior_covers_the_tilt_it_gives(seed, bias_ms2):
    """A bias of 20-100 mg (1.2-5.8 deg at most): the norms measure its size over gravity within 15 %, and the
    prior's std is at least the tilt of every hold within 1.5 stds (a prior of 0.3 deg held them at up to 19)."""
    means, tilts, most = _holds(seed, bias_ms2)
    ev = _evidence(means).evidence
    assert ev.holds == 8
    assert abs(ev.tilt_rad - most) < 0.15 * most
    assert np.all(tilts < 1.5 * ev.prior_sigma_rad)


@pytest.mark.parametrize("seed", range(6))
def test_a_calibrated_accelerometer_keeps_a_tight_prior_once_the_holds_span_attitudes(seed):
    """A bias of 5 mg (0.3 deg): after holds at several attitudes the prior is within twice the calibrated one."""
    ev = _evidence(_holds(seed, 0.05)[0]).evidence
    assert ev.prior_sigma_rad < 2 * CALIBRATED


def test_before_the_holds_span_attitudes_the_prior_is_the_uncalibrated_one():
    """One hold, or holds at one attitude: the norm tells nothing across gravity, the prior is as wide as an
    uncalibrated accelerometer's tilt; holds at several attitudes narrow it."""
    assert AccelTiltEvidence(CALIBRATED, WIDE).evidence.prior_sigma_rad >= WIDE
    same, _ = _holds(0, 0.05, n=5, min_tilt_deg=20.0, max_tilt_deg=20.0)[:2]
    same = [same[0] + np.random.default_rng(k).normal(scale=0.002, size=3) for k in range(5)]
    assert _evidence(same).evidence.prior_sigma_rad > 0.9 * WIDE
    assert _evidence(_holds(0, 0.05, n=5)[0]).evidence.prior_sigma_rad < 0.3 * WIDE


def test_the_evidence_does_not_depend_on_the_unit():
    """An accelerometer in g (a driver's unit, scaled later) gives the same evidence: the fit reads norms relative
    to their median."""
    means = _holds(3, 0.6)[0]
    in_ms2 = _evidence(means).evidence
    in_g = _evidence([a / 9.80665 for a in means], noise_ms2=0.002 / 9.80665).evidence
    assert in_g.tilt_rad == pytest.approx(in_ms2.tilt_rad, rel=1e-6)
    assert in_g.prior_sigma_rad == pytest.approx(in_ms2.prior_sigma_rad, rel=1e-6)


def test_unequal_axis_scales_widen_the_prior():
    """Axes 2 % apart in scale (an uncalibrated chip's) vary the norm with attitude and tilt the direction alike:
    the prior widens beyond the calibrated one, to cover the tilt they give."""
    means, tilts, _ = _holds(4, 0.0, scales=(1.02, 0.99, 1.0))
    ev = _evidence(means).evidence
    assert ev.prior_sigma_rad > 2 * CALIBRATED and np.all(tilts < 1.5 * ev.prior_sigma_rad)


def test_a_calibrated_prior_no_narrower_than_the_uncalibrated_one_is_kept_and_the_tilt_said():
    """imu_bias_max_deg at or below imu_bias_sigma_deg: the user's word for a calibrated accelerometer stands
    (the prior is the calibrated one), and a tilt the norms show is said, with what to change."""
    means = _holds(1, 0.6)[0]
    kept = _evidence(means, wide=0.0)
    assert kept.evidence.prior_sigma_rad == CALIBRATED and not kept.graded
    said = describe_tilt(kept)
    assert said is not None and "raise imu_bias_max_deg" in said
    graded = _evidence(means)
    assert "estimated with a prior of" in describe_tilt(graded)
    assert describe_tilt(_evidence(_holds(1, 0.05)[0])) is None  # nothing beyond the calibrated tilt


def test_a_chip_nobody_calibrated_carries_the_tilt_its_axes_scales_may_give():
    """Norms that show a 60 mg bias: the chip is uncalibrated, so each attitude's gravity carries the tilt that
    axes' scales within 2 % may give it (their spread over many such chips, 0.4 deg at 30 deg of tilt; none at a
    level hold, where gravity lies along one axis); a calibrated chip's, or one whose calibrated prior the user
    keeps, carries none."""
    tilt = _evidence(_holds(2, 0.6)[0])
    assert tilt.shows_bias
    up = np.array([0.0, math.sin(math.radians(30.0)), math.cos(math.radians(30.0))])
    rng = np.random.default_rng(5)
    s = rng.uniform(-0.02, 0.02, size=(20000, 3))
    turned = (1.0 + s) * up  # each chip's reading of the same gravity
    angles = np.arccos(np.clip(turned @ up / np.linalg.norm(turned, axis=1), -1.0, 1.0))
    assert tilt.scale_tilt_rad(G * up) == pytest.approx(math.sqrt(np.mean(angles ** 2)), rel=0.05)
    assert math.degrees(tilt.scale_tilt_rad(G * up)) == pytest.approx(0.4, abs=0.02)
    assert tilt.scale_tilt_rad(np.array([0.0, 0.0, G])) == 0.0
    assert _evidence(_holds(2, 0.05)[0]).scale_tilt_rad(G * up) == 0.0
    assert _evidence(_holds(2, 0.6)[0], wide=0.0).scale_tilt_rad(G * up) == 0.0


@pytest.mark.parametrize("seed", range(4))
def test_the_norms_weigh_calibrated_against_uncalibrated(seed):
    """The odds the joint estimate's two priors of the tilt get (:mod:`nrmpc_ros.core.tilt_mixture`): even
    before a hold; a calibrated chip's norms at several attitudes favour the calibrated prior (the tilt they
    show fits it), more so than holds at one attitude do; a 60 mg bias all but rules the calibrated prior out
    (the norms show it); the user's calibrated word keeps one prior."""
    before = AccelTiltEvidence(CALIBRATED, WIDE).calibration_odds()
    assert before.log_odds == 0.0 and before.calibrated_sigma_rad == pytest.approx(CALIBRATED)
    spread = _evidence(_holds(seed, 0.05)[0]).calibration_odds()
    assert spread.log_odds > 2.0
    assert CALIBRATED <= spread.calibrated_sigma_rad < 2 * CALIBRATED
    assert spread.calibrated_sigma_rad == CALIBRATED
    same = _holds(seed, 0.05, n=8, min_tilt_deg=20.0, max_tilt_deg=20.0)[0]
    same = [same[0] + np.random.default_rng(k).normal(scale=0.002, size=3) for k in range(8)]
    assert _evidence(same).calibration_odds().log_odds < spread.log_odds
    biased = _evidence(_holds(seed, 0.6)[0])
    assert biased.shows_bias and biased.calibration_odds().log_odds < -10.0
    assert _evidence(_holds(seed, 0.05)[0], wide=0.0).calibration_odds() is None


def test_a_few_holds_scattered_beyond_their_noise_show_no_bias_on_a_calibrated_chip():
    """Five holds of a 2 mg chip whose averaged noise is twice what the samples' spread claims: the fitted tilt
    is anything within the wide prior along the holds' mean direction (the old rule, the fitted tilt beyond twice
    the calibrated prior, took 18 of 40 such chips for uncalibrated), but the norms' evidence does not favour an
    uncalibrated chip: none is. A 30 mg bias on the same five holds is shown in most draws, a 60 mg one in all
    but one."""
    def shown(bias_ms2):
        return sum(_evidence(_holds(seed, bias_ms2, n=5, noise_ms2=0.008)[0], noise_ms2=0.004).shows_bias
                   for seed in range(40))

    assert shown(0.02) == 0
    assert shown(0.3) >= 20 and shown(0.6) >= 38


def test_holds_that_tell_nothing_are_skipped():
    """A mean that is not finite, zero, or a variance that is not finite: not a hold."""
    tilt = AccelTiltEvidence(CALIBRATED, WIDE)
    for a, v in [((np.nan, 0.0, 9.8), 0.0), ((0.0, 0.0, 0.0), 0.0), ((0.0, 0.0, 9.8), math.inf)]:
        assert tilt.observe_still(a, v).holds == 0


def _z_scores(bag, csv_path) -> np.ndarray:
    """Each estimate's gravity error against the recording's /ground_truth/gravity over its own std."""
    import csv

    from nrmpc_ros.bag.reader import BagReader
    from nrmpc_ros.frontend.reference import nearest_stamp, read_reference

    with BagReader(bag) as b:
        truth = read_reference(b)
    z = []
    for row in csv.DictReader(open(csv_path)):
        g = truth.grav_g[nearest_stamp(truth.grav_t, float(row["stamp"]))]
        e = np.array([float(row[k]) for k in ("gx", "gy", "gz")])
        err = math.degrees(math.acos(np.clip(g @ e / np.linalg.norm(g) / np.linalg.norm(e), -1, 1)))
        z.append(err / float(row["gravity_sigma_deg"]))
    return np.array(z)


@pytest.mark.slow
def test_replay_of_an_uncalibrated_accelerometer_keeps_every_gravity_within_its_std(tmp_path, capsys):
    """An accelerometer 80 mg off (4.7 deg at most; the IMU alone about 4 deg off): replay says the bias the norms
    show, and the bias vector to calibrate out (the bars' estimate under the same graded prior: 0.8 m/s^2 within
    0.02, where the calibrated prior shrank it to 0.77), weighs a calibrated chip's prior at nearly nothing, and
    estimates every hold within 3 of its std of the truth. The calibrated prior kept (imu_bias_max_deg: 0) leaves
    estimates several stds off: what the evidence repairs."""
    from nrmpc_ros.cli.main import main

    bag, rig = tmp_path / "biased", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(bag), "--save-rig", str(rig), "--resolution", "240x180", "--supersample",
                 "1", "--cameras", "4", "--views", "6", "--imu-bias", "0.8", "--seed", "21", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["replay", str(bag), "--rig", str(rig), "--out", str(tmp_path / "x.csv"), "--no-progress"]) == 0
    text = capsys.readouterr().out
    said = [ln for ln in text.splitlines() if ln.startswith("IMU bias:")]
    assert len(said) == 1 and "estimated with a prior of" in said[0], text
    assert abs(float(said[0].split("up to ")[1].split()[0]) - math.degrees(math.atan(0.8 / 9.81))) < 0.7
    vector = said[0].split("the bias reads [")[1].split("]")[0]
    assert abs(np.linalg.norm(np.array(vector.split(), dtype=float)) - 0.8) < 0.02, said[0]
    z = _z_scores(bag, tmp_path / "x.csv")
    assert len(z) == 6 and np.all(z < 3.0), z  # every hold (the first one's with the second's)
    weighed = [ln for ln in text.splitlines() if ln.startswith("IMU calibration:")]
    assert len(weighed) == 1 and float(weighed[0].split("weighed ")[1].split()[0]) < 0.05, weighed
    (tmp_path / "kept.yaml").write_text("imu_bias_max_deg: 0\n")
    assert main(["replay", str(bag), "--rig", str(rig), "--out", str(tmp_path / "y.csv"), "--no-progress",
                 "--config", str(tmp_path / "kept.yaml")]) == 0
    kept = capsys.readouterr().out
    assert "raise imu_bias_max_deg" in kept and "IMU calibration:" not in kept  # one prior: nothing weighed
    assert np.sum(_z_scores(bag, tmp_path / "y.csv") > 3.0) >= 2
