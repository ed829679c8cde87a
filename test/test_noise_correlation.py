"""Correlated noise: its measured autocorrelation and the moments of the stillness test's sums under it."""

import numpy as np
import pytest

from nrmpc_ros.frontend.noise_correlation import (
    autocorrelation,
    mean_variance_factor,
    periodic,
    quadratic_moments,
    spread_null,
    statistic_null,
    vibration_period,
)


def ar1(rng, n, phi):
    """Unit-variance AR(1) noise (3 axes): autocorrelation phi^k."""
    e = rng.normal(size=(n, 3)) * np.sqrt(1 - phi ** 2)
    x = np.empty_like(e)
    x[0] = rng.normal(size=3)
    for k in range(1, n):  # a test's reference signal, not a hot path
        x[k] = phi * x[k - 1] + e[k]
    return x


@pytest.mark.parametrize("n", [2, 8, 21, 101])
def test_white_noise_gives_the_chi_square_back(n):
    (e0, v0), (ec, vc), s1 = quadratic_moments(np.ones(1), n)
    assert (e0, v0, ec, vc, s1) == pytest.approx((n, 2 * n, n - 1, 2 * (n - 1), n))
    c, nu = spread_null(np.array([n]), 0, np.ones(1))
    assert (c[0], nu[0]) == pytest.approx((1.0, 3 * (n - 1)))
    c, nu, mean = statistic_null(np.array([n]), 0, np.ones(1), np.ones(1), with_norm=True)
    assert (c[0], nu[0], mean[0]) == pytest.approx((1.0, 6 * n - 2, 1.0 / n))


def test_the_moments_are_those_of_the_correlation_matrix():
    """tr R, 2 tr R^2, tr CR, 2 tr CRCR and 1'R1 against the matrices themselves."""
    rho = np.array([1.0, 0.8, 0.5, 0.2, -0.05])
    n = 9
    R = np.array([[rho[abs(i - j)] if abs(i - j) < len(rho) else 0.0 for j in range(n)] for i in range(n)])
    C = np.eye(n) - np.ones((n, n)) / n
    (e0, v0), (ec, vc), s1 = quadratic_moments(rho, n)
    assert (e0, v0) == pytest.approx((np.trace(R), 2 * np.trace(R @ R)))
    assert (ec, vc) == pytest.approx((np.trace(C @ R), 2 * np.trace(C @ R @ C @ R)))
    assert s1 == pytest.approx(R.sum()) and mean_variance_factor(rho, n) == pytest.approx(R.sum() / n)


def test_the_sum_about_the_mean_of_correlated_noise_follows_its_scaled_chi_square(rng):
    """Windows of 21 samples of AR(1) noise (phi 0.7): the 10 %, 50 % and 99 % quantiles of their sums of squares
    about the mean match c chi2(nu) within a few percent (further out the true tail is a little heavier: 6 % at
    1e-4); the white-noise chi-square is far narrower."""
    from scipy.stats import chi2

    n, x = 21, ar1(rng, 21 * 4000, 0.7)
    w = x.reshape(-1, n, 3)
    ss = ((w - w.mean(axis=1, keepdims=True)) ** 2).sum(axis=(1, 2))
    c, nu = spread_null(np.array([n]), 0, 0.7 ** np.arange(n))
    for q in (0.1, 0.5, 0.99):
        assert np.quantile(ss, q) == pytest.approx(c[0] * chi2.ppf(q, nu[0]), rel=0.06)
    white = chi2.ppf(0.99, 3 * (n - 1)) / chi2.ppf(0.1, 3 * (n - 1))  # the spread white noise would have
    assert np.quantile(ss, 0.99) / np.quantile(ss, 0.1) > 1.3 * white


def test_the_autocorrelation_of_still_runs(rng):
    """AR(1) noise in runs of 60 samples between moves: its measured autocorrelation is phi^k where that stands
    out of the noise, and ends where it does not; white noise reads as white (the runs' own means added back)."""
    x = ar1(rng, 30000, 0.6)
    cover = (np.arange(len(x)) // 60) % 3 != 2  # two thirds of the samples, in runs of 120
    x[~cover] += 50.0 * rng.normal(size=(int((~cover).sum()), 3))  # the moves: ignored
    rho = autocorrelation(x, cover, 40)
    assert 4 <= len(rho) <= 20
    np.testing.assert_allclose(rho[:4], 0.6 ** np.arange(4), atol=0.03)
    assert len(autocorrelation(rng.normal(size=(30000, 3)), cover, 40)) <= 2


def test_the_mean_of_correlated_noise_varies_as_its_correlation_says(rng):
    n, x = 50, ar1(rng, 50 * 3000, 0.8)
    means = x.reshape(-1, n, 3).mean(axis=1)
    measured = float(np.var(means)) * n
    assert mean_variance_factor(0.8 ** np.arange(n), n) == pytest.approx(measured, rel=0.1)
    assert mean_variance_factor(np.ones(1), n) == 1.0


@pytest.mark.parametrize("rate, hz", [(50.0, 20.0), (100.0, 30.0), (100.0, 95.0), (200.0, 45.0), (1000.0, 35.0),
                                      (1000.0, 150.0)])
def test_a_vibrations_autocorrelation_is_kept_whole_and_is_a_covariance(rng, rate, hz):
    """A motor's sine (aliased where the IMU is slower than twice it) under white noise: its correlation is not
    cut at a zero crossing, its period as sampled is found, and the variance of a window's mean it gives is
    positive at every length and at least what the windows show (a cut cosine made it negative)."""
    t = np.arange(40000) / rate
    x = np.sin(2 * np.pi * hz * t[:, None] + rng.uniform(0, 2 * np.pi, 3)) + 0.1 * rng.normal(size=(len(t), 3))
    cover = (np.arange(len(t)) // 400) % 4 != 3
    rho = autocorrelation(x, cover, 100)
    assert periodic(rho) and len(rho) == 100
    alias = abs(hz - rate * round(hz / rate))
    assert abs(vibration_period(rho) - rate / alias) <= 1.0
    factors = np.array([mean_variance_factor(rho, n) for n in range(2, 101)])
    assert np.all(factors > 0)
    c = np.concatenate([np.zeros((1, 3)), np.cumsum(x, axis=0)])
    for n in (8, 20, 50, 200, 400):  # within the lags measured, and a hold's mean beyond them
        means = (c[n:] - c[:-n]) / n  # every window of n samples, wherever it starts on the sine
        assert mean_variance_factor(rho, n) >= 0.8 * float(np.var(means)) * n / float(np.var(x))
    assert mean_variance_factor(rho, 400) < 0.5  # the vibration averages out over a hold


@pytest.mark.parametrize("cutoff, rate", [(5.0, 50.0), (20.0, 200.0), (20.0, 400.0), (40.0, 1000.0), (100.0, 1000.0)])
def test_a_low_pass_filters_correlation_is_no_vibration(rng, cutoff, rate):
    """A MEMS IMU's 2nd-order Butterworth filter: its correlation decays (undershooting by a few hundredths) and
    is cut where the data cannot tell it from 0, as before."""
    from scipy.signal import butter, sosfilt

    x = sosfilt(butter(2, cutoff, fs=rate, output="sos"), rng.normal(size=(40000, 3)), axis=0)
    rho = autocorrelation(x, np.ones(len(x), bool), 100)
    assert not periodic(rho) and vibration_period(rho) is None
    assert 3 <= len(rho) <= 30


def test_a_correlation_cut_at_a_zero_crossing_never_gives_a_negative_variance():
    """A cosine cut where it first crosses 0 is no covariance: its sums over long windows went negative (a
    steady-turn test took the square root of one); the mean's variance is never below that of one sample
    over n."""
    cut = np.cos(2 * np.pi * 0.15 * np.arange(4))
    for n in (5, 20, 100, 1000):
        assert mean_variance_factor(cut, n) >= 1.0 / n
        assert quadratic_moments(cut, n)[2] >= 1.0
