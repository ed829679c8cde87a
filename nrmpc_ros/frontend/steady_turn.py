"""A hold the body turns through slowly: the gyro's mean rate over the hold against its bias and noise.

The windowed stillness test (:mod:`.zupt`) sums squared rates over a tenth of
a second, so it sees a constant rotation only above about twice the gyro's
per-sample noise (0.2 deg/s for a MEMS gyro at 200 Hz); a creep near that
limit flickers in and out of it and splits a hold into pieces, each of which
passed as still. Over a whole hold the matched test for a steady turn is the
mean rate: over n samples its noise falls as 1/sqrt(n), so a hold of a
second tells 0.02 deg/s from rest where the gyro's bias is known.

    r = mean(w) - b,   T = |r|^2 / (s_w^2 k / n + s_b^2 + s_r^2)

with b the gyro bias the stillness test estimated from the recording's
quietest windows, s_w its per-sample noise and k the variance factor of the
mean of n samples that a low-pass filter correlates
(:func:`.noise_correlation.mean_variance_factor`); s_b the bias's stability
over the recording (``ZuptConfig.gyro_bias_stability_rad_s``: an in-run bias
instability and a temperature drift, which no sample of the hold tells from a
turn); s_r, on an IMU that rides a ringing bar, what the bar's ringing leaves
in the mean (its turn between the hold's ends, at most the rate's oscillation
over the bar's angular frequency, over the span). For a still body T is
chi-square with 3 degrees of freedom, and the hold turns when T exceeds its
quantile at the stillness test's ``significance``. A hold the body turns
through is a motion: its images average attitudes, and no estimate is made
there (docs/PIPELINE.md, "Holds").

A creep the windowed test flickers on splits its hold into pieces of a tenth of
a second or so, each too short for the mean to tell. The span tested is
therefore the hold's, widened either way over every sample whose windowed
mean rate (the stillness test's window) stays below twice the windowed test's
detection limit (:func:`flicker_rate`): the whole creep, the pieces and the
windows between them, but not a move (whose rate is tens of times that; the
last hundredths of a second of a stop add a turn of a few millionths of a
radian).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .noise_correlation import mean_variance_factor
from .zupt import ImuNoise, ZuptConfig, window_length

MIN_SAMPLES = 4
"""Samples a hold's span needs to be tested: fewer leave the mean to one or two samples' noise."""


@dataclass(frozen=True)
class SteadyTurn:
    """The body's mean rate through a hold's span (rad/s, bias taken out), its standard deviation per axis
    (rad/s), the span (s) and samples, the test statistic T and its threshold."""

    rate_rad_s: float
    sigma_rad_s: float
    span_s: float
    samples: int
    statistic: float
    threshold: float

    @property
    def turning(self) -> bool:
        """Whether the body turned through the span beyond its noise at the test's significance."""
        return self.statistic > self.threshold

    def describe(self) -> str:
        return (f"{math.degrees(self.rate_rad_s):.3f} deg/s over {self.span_s:.2f} s ({self.samples} samples), "
                f"{math.sqrt(self.statistic / 3.0):.1f} of its std {math.degrees(self.sigma_rad_s):.3f} deg/s per axis")


def flicker_rate(noise: ImuNoise, cfg: ZuptConfig, period_s: float) -> float:
    """Twice the windowed stillness test's detection limit (rad/s): a constant rate r adds about n r^2 / s_w^2 to
    its statistic over n samples, so rates above s_w sqrt((gamma - nu) / n) read as motion in most windows (gamma
    its threshold, nu = 6 n - 2 its degrees of freedom; :mod:`.zupt`), and twice that in every one."""
    from scipy.special import chdtri  # a chi-square quantile; imported where used (0.3-0.5 s)

    n = int(round(window_length(cfg, period_s) / max(period_s, 1e-9))) + 1
    nu = 6.0 * n - 2.0
    s_w = max(float(noise.gyro_sigma), cfg.gyro_floor_rad_s)
    return 2.0 * s_w * math.sqrt(max(float(chdtri(nu, cfg.significance)) - nu, 1.0) / n)


def creep_span(t, gyro, noise: ImuNoise, cfg: ZuptConfig, t0: float, t1: float) -> tuple:
    """(t0, t1) widened either way over the samples (t (n,), gyro (n, 3)) whose windowed mean rate, bias taken
    out, stays below :func:`flicker_rate`: the stretch of a slow turn that the span [t0, t1] lies in."""
    t = np.asarray(t, float).reshape(-1)
    w = np.asarray(gyro, float).reshape(-1, 3) - np.asarray(noise.gyro_bias, float).reshape(3)
    if len(t) < MIN_SAMPLES:
        return t0, t1
    period = float(np.median(np.diff(t)))
    half = 0.5 * window_length(cfg, period)
    c = np.concatenate([np.zeros((1, 3)), np.cumsum(w, axis=0)])
    lo = np.searchsorted(t, t - half, side="left")
    hi = np.searchsorted(t, t + half, side="right")
    mean = (c[hi] - c[lo]) / np.maximum(hi - lo, 1)[:, None]
    slow = np.linalg.norm(mean, axis=1) < flicker_rate(noise, cfg, period)
    i0, i1 = int(np.searchsorted(t, t0, side="left")), int(np.searchsorted(t, t1, side="right")) - 1
    if i0 > i1 or not slow[i0:i1 + 1].all():
        return t0, t1
    fast = np.flatnonzero(~slow)
    before, after = fast[fast < i0], fast[fast > i1]
    a = before[-1] + 1 if len(before) else 0
    b = after[0] - 1 if len(after) else len(t) - 1
    return min(t0, float(t[a])), max(t1, float(t[b]))


def steady_turn(t, gyro, noise: ImuNoise, cfg: ZuptConfig, ringing_hz: float = 0.0) -> SteadyTurn | None:
    """The steady-turn test over the samples (t (n,), gyro (n, 3) rad/s, the IMU's axes) of one hold's span;
    None with fewer than :data:`MIN_SAMPLES`. ``ringing_hz``: the natural frequency of the bar the IMU rides on
    (0: on the body or a rigid camera)."""
    t = np.asarray(t, float).reshape(-1)
    w = np.asarray(gyro, float).reshape(-1, 3)
    ok = np.isfinite(t) & np.all(np.isfinite(w), axis=1)
    t, w = t[ok], w[ok]
    n = len(t)
    if n < MIN_SAMPLES:
        return None
    rate = w.mean(axis=0) - np.asarray(noise.gyro_bias, float).reshape(3)
    s_w = max(float(noise.gyro_sigma), cfg.gyro_floor_rad_s)
    var = s_w ** 2 * mean_variance_factor(noise.gyro_correlation, n) / n + cfg.gyro_bias_stability_rad_s ** 2
    span = float(t[-1] - t[0])
    if ringing_hz > 0.0 and span > 0.0:
        # the ringing's rate oscillates by up to sqrt(2) times its spread about the mean; its turn, that over
        # 2 pi f, differs between the span's ends by up to twice that
        spread = float(np.sqrt(np.mean(np.sum((w - w.mean(axis=0)) ** 2, axis=1)) / 3.0))
        var += (2.0 * math.sqrt(2.0) * spread / (2.0 * math.pi * ringing_hz * span)) ** 2
    from scipy.special import chdtri  # a chi-square quantile; imported where used (0.3-0.5 s)

    statistic = float(rate @ rate) / var
    return SteadyTurn(float(np.linalg.norm(rate)), math.sqrt(var), span, n, statistic,
                      float(chdtri(3, cfg.significance)))


__all__ = ["MIN_SAMPLES", "SteadyTurn", "creep_span", "flicker_rate", "steady_turn"]
