"""Noise whose neighbouring samples are correlated: its autocorrelation, and the null distribution of the
stillness test's sums of squares under it (docs/PIPELINE.md, Holds).

A MEMS IMU low-pass filters its output (a digital filter at 5-250 Hz on a 50-1000 Hz stream), so neighbouring
samples share their noise. A window's sum of squares of such noise is no chi-square of as many degrees of
freedom as it has samples: for n samples with correlation matrix R the sum about a known value has mean tr R
and variance 2 tr R^2, the sum about the window's mean tr CR and 2 tr CRCR (C the centring matrix), and the mean
varies as 1'R1 / n^2 times the per-sample variance. The scaled chi-square c chi2(nu) of the same mean and
variance (Satterthwaite) stands in for the distribution; white noise gives c = 1 and the usual degrees of
freedom back.
"""

from __future__ import annotations

import math

import numpy as np

AUTOCORRELATION_SAMPLES = 1 << 18  # the noise's autocorrelation comes from the newest this many samples at most
VIBRATION_RETURN = 0.3
"""The correlation a vibration's autocorrelation swings to either side of 0 (its share of the power, at least
this): a 2nd-order low-pass filter's undershoots by a few hundredths."""


def per_value(fn, dof: np.ndarray) -> np.ndarray:
    """fn(dof) evaluated once per distinct number of degrees of freedom."""
    u, inv = np.unique(dof, return_inverse=True)
    return fn(u)[inv]


def autocorrelation(x: np.ndarray, cover: np.ndarray, lags: int) -> np.ndarray:
    """Normalised autocorrelation at lags 0..``lags`` - 1 samples of the samples x (N, 3) where ``cover`` is
    True (the still windows'), each run of them about its own mean, the axes pooled, from the newest
    ``AUTOCORRELATION_SAMPLES`` at most (by FFT), at most half as many lags as there are such samples. It ends
    before the first lag whose estimate lies within two standard errors of 0: lags the data cannot tell from
    white count as uncorrelated; unless it is a vibration's (:func:`periodic`), then all ``lags`` are kept.
    [1.0]: white."""
    x, cover = x[-AUTOCORRELATION_SAMPLES:], cover[-AUTOCORRELATION_SAMPLES:]
    lags = min(lags, int(cover.sum()) // 2)  # few samples yet (a recording's first second): the first lags
    if lags < 2:
        return np.ones(1)
    run = np.cumsum(np.concatenate([[True], cover[1:] != cover[:-1]]))
    sums = np.zeros((run.max() + 1, 3))
    np.add.at(sums, run, x)
    counts = np.bincount(run, minlength=run.max() + 1)[:, None]
    z = (x - sums[run] / counts[run]) * cover[:, None]
    size = 1 << int(math.ceil(math.log2(2 * len(z))))
    power = np.abs(np.fft.rfft(z, size, axis=0)) ** 2
    acov = np.fft.irfft(power.sum(axis=1), size)[:lags]
    pairs = np.fft.irfft(np.abs(np.fft.rfft(cover.astype(float), size)) ** 2, size)[:lags]
    pairs = np.maximum(np.rint(pairs), 1.0)
    if not acov[0] > 0:
        return np.ones(1)
    # a run of L samples about its own mean owes each lagged product -s^2 / L (for white noise): added back, so
    # that many short runs do not read as a negative correlation
    starts = np.flatnonzero(np.concatenate([[True], run[1:] != run[:-1]]))
    length = np.diff(np.append(starts, len(run)))[cover[starts]].astype(float)
    owed = (np.maximum(length[:, None] - np.arange(lags)[None, :], 0.0) / length[:, None]).sum(axis=0)
    var = acov[0] / pairs[0] / (1.0 - owed[0] / pairs[0])
    rho = (acov / pairs + var * owed / pairs) / var
    if periodic(rho):
        # a vibration's sine, not a filter's decay: every lag is kept, each over all the samples (the biased
        # estimate: a covariance, so no window's mean or spread gets a negative variance from a cosine cut at
        # a zero crossing)
        return rho * (pairs / pairs[0])
    quiet = np.abs(rho[1:]) < 2.0 / np.sqrt(3.0 * pairs[1:])  # within two standard errors of 0
    end = 1 + (int(np.argmax(quiet)) if quiet.any() else len(rho) - 1)
    return rho[:end].copy()


def periodic(correlation: np.ndarray) -> bool:
    """Whether an autocorrelation (lags in samples, from :func:`autocorrelation`) is a vibration's: after its
    first minimum below -:data:`VIBRATION_RETURN` it comes back above +:data:`VIBRATION_RETURN`. A low-pass
    filter's decays and undershoots a little at most; a motor's sine returns to its own share of the power."""
    rho = np.asarray(correlation, dtype=float)
    below = np.flatnonzero(rho < -VIBRATION_RETURN)
    return bool(len(below)) and bool(np.any(rho[below[0]:] > VIBRATION_RETURN))


def vibration_period(correlation: np.ndarray) -> float | None:
    """A vibration's period as sampled (samples; aliased where the samples are slower than twice its frequency):
    four times its autocorrelation's first zero crossing, interpolated between lags; None where the correlation
    is no vibration's (:func:`periodic`)."""
    if not periodic(correlation):
        return None
    rho = np.asarray(correlation, dtype=float)
    k = int(np.argmax(rho < 0.0))
    return max(4.0 * (k - 1 + float(rho[k - 1] / (rho[k - 1] - rho[k]))), 2.0)


def quadratic_moments(rho: np.ndarray, n: int) -> tuple:
    """For n consecutive samples of unit-variance Gaussian noise with autocorrelation ``rho`` (lags in
    samples, R its correlation matrix): the mean and variance of the sum of squares about 0 (tr R, 2 tr R^2),
    of the sum of squares about the samples' mean (C the centring matrix: tr CR, 2 tr CRCR), and 1'R1 (n^2
    times the variance of the mean)."""
    r = np.zeros(n)
    k = min(len(rho), n)
    r[:k] = rho[:k]
    weight = n - np.arange(n)  # pairs at each lag
    tr_r2 = float(weight[0] + 2.0 * np.sum(weight[1:] * r[1:] ** 2))
    s1 = max(float(weight[0] + 2.0 * np.sum(weight[1:] * r[1:])), 1.0)  # as in mean_variance_factor
    if k > 1:
        row_sums = np.convolve(np.concatenate([r[:0:-1], r]), np.ones(n), mode="valid")  # R 1
        r1_sq = float(row_sums @ row_sums)
    else:
        r1_sq = float(n)
    return (float(n), 2.0 * tr_r2), (n - s1 / n, 2.0 * (tr_r2 - 2.0 * r1_sq / n + s1 ** 2 / n ** 2)), s1


def mean_variance_factor(correlation: np.ndarray, n: int) -> float:
    """The variance of the mean of n consecutive samples of noise with autocorrelation ``correlation`` (lags
    in samples) over its white-noise value s^2 / n: 1'R1 / n, above 1 where a low-pass filter makes
    neighbouring samples alike, below 1 where it alternates (a vibration's sine, bounded by its envelope over
    windows longer than its measured lags), and never below 1 / n (a mean no surer than that of one sample over
    n): an autocorrelation cut at the first lag the data cannot tell from 0 is no covariance, and a vibration's
    cut cosine would otherwise make the variance negative."""
    period = vibration_period(correlation) if n > len(correlation) else None
    if period is not None:
        # a vibration's sine averages out over a window longer than the lags measured: its mean over n samples
        # is at most sqrt(2) its rms / (n sin(pi / P)) (a geometric sum; P its period in samples), the rest of
        # the power white. Its share of the power is the cosine's amplitude, the largest correlation at a lag.
        share = min(float(np.max(np.abs(np.asarray(correlation, dtype=float)[1:]))), 1.0)
        return max(1.0 - share + share * 2.0 / (n * math.sin(math.pi / period) ** 2), 1.0 / n)
    rho = np.asarray(correlation, dtype=float)[1:max(int(n), 1)]
    if not len(rho):
        return 1.0
    return max(1.0 + 2.0 * float(np.sum((1.0 - np.arange(1, len(rho) + 1) / n) * rho)), 1.0 / max(int(n), 1))


def spread_null(n: np.ndarray, extra: int, rho: np.ndarray) -> tuple:
    """(c, nu) per window: the sum of squares about a window's fit (3 axes, n samples, ``extra`` parameters
    fitted per axis besides the constant) of still noise with autocorrelation ``rho`` is about s^2 c chi2(nu)
    (Satterthwaite: the scaled chi-square of its mean and variance; c = 1, nu = 3 (n - 1 - extra) for white
    noise). A fitted ringing removes its share of the centred sum's mean and variance."""
    def per_n(m):
        out = []
        for v in m:
            _, (e, var), _ = quadratic_moments(rho, int(v))
            if not (e > 0 and var > 0):  # a correlation near 1 throughout: no noise in the window to speak of
                e, var = v - 1.0, 2.0 * (v - 1.0)
            keep = (v - 1 - extra) / (v - 1)
            out.append((var / (2.0 * e), 6.0 * keep * e ** 2 / var))
        return np.array(out)
    cn = per_value(per_n, np.asarray(n))
    return cn[..., 0], cn[..., 1]


def statistic_null(n: np.ndarray, extra: int, accel_correlation: np.ndarray, gyro_correlation: np.ndarray,
              with_norm: bool) -> tuple:
    """(c, nu, mean factor) per window of the stillness statistic T of still noise: T is about c chi2(nu)
    (Satterthwaite over the gyro's sum about its bias, the accelerometer's about its fit, and the magnitude
    term; c = 1, nu = 6n - 3 - 6 extra (+1) for white noise), and the variance of the accelerometer's window
    mean is s_a^2 times the mean factor (1/n for white noise)."""
    def per_n(m):
        out = []
        for v in m:
            v = int(v)
            (e_g, var_g), _, _ = quadratic_moments(gyro_correlation, v)
            _, (e_a, var_a), s1 = quadratic_moments(accel_correlation, v)
            keep_g, keep_a = (v - extra) / v, (v - 1 - extra) / (v - 1)
            if not (e_a > 0 and var_a > 0):  # as in spread_null
                e_a, var_a = v - 1.0, 2.0 * (v - 1.0)
            e = 3.0 * (keep_g * e_g + keep_a * e_a) + (1.0 if with_norm else 0.0)
            var = 3.0 * (keep_g * var_g + keep_a * var_a) + (2.0 if with_norm else 0.0)
            out.append((var / (2.0 * e), 2.0 * e ** 2 / var, s1 / v ** 2))
        return np.array(out)
    cn = per_value(per_n, np.asarray(n))
    return cn[..., 0], cn[..., 1], cn[..., 2]


__all__ = ["AUTOCORRELATION_SAMPLES", "VIBRATION_RETURN", "autocorrelation", "mean_variance_factor", "per_value",
           "periodic", "quadratic_moments", "spread_null", "statistic_null", "vibration_period"]
