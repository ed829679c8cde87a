"""A view's gravity under the accelerometer tilt's two priors, calibrated or not, weighed by the data's evidence
(docs/PIPELINE.md, "Calibrated or not: the tilt's two priors")."""

import math

import numpy as np
import pytest

from nrmpc_ros.core.tilt_mixture import CalibrationOdds, mixed_gravity, prior_sigma_rad

NARROW = math.radians(0.3)
WIDE = math.radians(4.6)


def _model(rng, imu_rad: float, vision_rad: float, norm_rad: float):
    """A linear-Gaussian stand-in of one view's joint solve: unknowns x = (g (2, the gravity direction's tangent
    part), b (3, the tilt)); the IMU reads g + b[:2] (noise ``imu_rad``), the images g (``vision_rad``), the norms
    b[2] (``norm_rad``); g under a wide proper prior both priors of b share. (J, noise std per row, g's prior)."""
    J = np.zeros((5, 5))
    J[0:2, 0:2] = np.eye(2)
    J[0:2, 2:4] = np.eye(2)
    J[2:4, 0:2] = np.eye(2)
    J[4, 4] = 1.0
    return J, np.array([imu_rad] * 2 + [vision_rad] * 2 + [norm_rad]), 1.0


def _posterior(J, s, g_prior, y, sigma):
    """Exact posterior (mean, covariance) of x and log p(y) under b ~ N(0, sigma^2 I)."""
    prior = np.diag([g_prior ** 2] * 2 + [sigma ** 2] * 3)
    S = J @ prior @ J.T + np.diag(s ** 2)
    H = J.T @ np.diag(s ** -2) @ J + np.linalg.inv(prior)
    cov = np.linalg.inv(H)
    mean = cov @ J.T @ (y / s ** 2)
    log_p = -0.5 * float(y @ np.linalg.solve(S, y)) - 0.5 * float(np.linalg.slogdet(S)[1])
    return mean, cov, log_p


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("true_tilt_deg", [0.2, 1.5, 4.0])
@pytest.mark.parametrize("log_odds", [0.0, 2.0, -2.0])
def test_the_mixture_is_the_exact_posterior_of_a_linear_gaussian_solve(seed, true_tilt_deg, log_odds):
    """Fed the wide prior's solution and covariance of a linear-Gaussian problem, the mixture's mean and covariance
    of the view's gravity are those of the exact two-component posterior, weights from the exact evidences."""
    rng = np.random.default_rng(seed)
    J, s, gp = _model(rng, math.radians(0.05), math.radians(0.8), math.radians(0.5))
    x_true = np.concatenate([rng.normal(scale=0.3, size=2), math.radians(true_tilt_deg) * rng.normal(size=3) /
                             math.sqrt(3)])
    y = J @ x_true + rng.normal(size=5) * s
    wide_mean, wide_cov, log_wide = _posterior(J, s, gp, y, WIDE)
    narrow_mean, narrow_cov, log_narrow = _posterior(J, s, gp, y, NARROW)
    mixed = mixed_gravity(wide_mean[2:], wide_cov, WIDE, CalibrationOdds(NARROW, log_odds))
    w = 1.0 / (1.0 + math.exp(-(log_odds + log_narrow - log_wide)))
    mean = w * narrow_mean[:2] + (1 - w) * wide_mean[:2]
    cov = w * (narrow_cov[:2, :2] + np.outer(narrow_mean[:2] - mean, narrow_mean[:2] - mean)) + \
        (1 - w) * (wide_cov[:2, :2] + np.outer(wide_mean[:2] - mean, wide_mean[:2] - mean))
    assert mixed.calibrated_weight == pytest.approx(w, abs=1e-9)
    assert np.allclose(wide_mean[:2] + mixed.shift, mean, atol=1e-9)
    assert np.allclose(mixed.covariance, cov, rtol=1e-6, atol=1e-14)


def _view(rng, true_tilt_rad: float, vision_rad: float):
    J, s, gp = _model(rng, math.radians(0.05), vision_rad, math.inf)
    J, s = J[:4], s[:4]  # the norms resolve nothing here: the images alone tell the tilt
    x_true = np.concatenate([rng.normal(scale=0.3, size=2), [true_tilt_rad, 0.0, 0.0]])
    y = J @ x_true + rng.normal(size=4) * s
    mean, cov, _ = _posterior(J, s, gp, y, WIDE)
    return x_true, mean, cov


def test_images_that_agree_with_a_calibrated_imu_leave_its_gravity_its_calibrated_std():
    """Loose images (1 deg) and an IMU tilted 0.2 deg: the wide prior alone gives the images' gravity (about 1 deg
    off); the mixture mostly trusts the calibrated prior: over many draws its errors are below the wide prior's
    and near the IMU's own, within 2 of its std in at least 90 %."""
    rng = np.random.default_rng(7)
    wide_err, mixed_err, z = [], [], []
    for _ in range(400):
        x, mean, cov = _view(rng, math.radians(0.2) * rng.choice([-1, 1]), math.radians(1.0))
        m = mixed_gravity(mean[2:], cov, WIDE, CalibrationOdds(NARROW, 0.0))
        g = mean[:2] + m.shift
        wide_err.append(np.linalg.norm(mean[:2] - x[:2]))
        mixed_err.append(np.linalg.norm(g - x[:2]))
        e = g - x[:2]
        z.append(math.sqrt(float(e @ np.linalg.solve(m.covariance, e)) / 2.0))
    assert np.median(mixed_err) < 0.5 * np.median(wide_err)
    assert math.degrees(np.median(mixed_err)) < 0.35
    assert np.mean(np.array(z) < 2.0) > 0.9


def test_images_that_refute_a_calibrated_imu_keep_the_wide_prior():
    """Sharp images (0.05 deg) and a chip tilted 3 deg: the calibrated prior's evidence is nil, the mixture is
    the wide prior's solution."""
    rng = np.random.default_rng(3)
    x, mean, cov = _view(rng, math.radians(3.0), math.radians(0.05))
    m = mixed_gravity(mean[2:], cov, WIDE, CalibrationOdds(NARROW, 0.0))
    assert m.calibrated_weight < 1e-6
    assert np.allclose(m.shift, 0.0, atol=1e-9)
    assert np.allclose(m.covariance, cov[:2, :2], rtol=1e-6)


def test_nothing_changes_where_there_is_no_second_prior():
    """A calibrated prior no tighter than the wide one, or a covariance that is not finite: no mixture."""
    rng = np.random.default_rng(0)
    _, mean, cov = _view(rng, 0.0, math.radians(1.0))
    assert mixed_gravity(mean[2:], cov, WIDE, CalibrationOdds(WIDE, 0.0)) is None
    bad = cov.copy()
    bad[0, 0] = np.inf
    assert mixed_gravity(mean[2:], bad, WIDE, CalibrationOdds(NARROW, 0.0)) is None


def test_a_hold_no_images_tell_takes_the_two_priors_as_the_norms_weigh_them():
    """Without images the tilt's std is the mixture's: the wide prior's at odds that favour it, the calibrated
    one's at odds that favour that, the root of the mean of their variances at even odds; one prior without
    odds."""
    assert prior_sigma_rad(WIDE, None) == WIDE
    assert prior_sigma_rad(WIDE, CalibrationOdds(NARROW, -30.0)) == pytest.approx(WIDE)
    assert prior_sigma_rad(WIDE, CalibrationOdds(NARROW, 30.0)) == pytest.approx(NARROW, rel=1e-6)
    even = math.sqrt((NARROW ** 2 + WIDE ** 2) / 2)
    assert prior_sigma_rad(WIDE, CalibrationOdds(NARROW, 0.0)) == pytest.approx(even)


@pytest.mark.slow
def test_loose_images_no_longer_make_a_calibrated_imu_worse(tmp_path):
    """A recording drawn at random (``bench_holds.py --random``, seed 311): three cameras, a third of the holds
    creeping, a calibrated accelerometer (0.05 m/s^2) at 50 Hz inside a ringing camera, holds turned about one
    axis (the norms leave one component of the tilt open). Under the wide prior alone `auto` was 2.7x the IMU
    alone (0.85 deg, the images' gravity); with the two priors weighed it is below the IMU alone, and every
    gravity within 2 of its std."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "bench_holds", Path(__file__).resolve().parents[1] / "scripts" / "bench_holds.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    (r,) = bench.run_cell((tmp_path, "random", None, ["auto"], None, 1, 311))
    assert r["covered"] == r["still_holds"] - 1
    assert r["gravity_deg"] < r["imu_only_deg"], (r["gravity_deg"], r["imu_only_deg"])
    assert r["within2"] == 1.0
