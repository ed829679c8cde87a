"""Zero-velocity (stillness) detection on IMU samples: a windowed chi-square test sized by the IMU's rate and noise.

The rig is *still* over a window of n samples when its angular rate and its
specific force are constant up to sensor noise. The test statistic is the
SHOE detector of Skog et al. ("Zero-velocity detection -- an algorithm
evaluation", IEEE TBME 2010), written so that its threshold follows from
the noise instead of being tuned:

    T = sum_j |w_j - b|^2 / s_w^2                                  angular rate minus the gyro bias b
      + sum_j |a_j - mean(a)|^2 / s_a^2                              the accelerometer's spread in the window
      + (|mean(a)| - n_a)^2 / (s_a^2 / n + s_n^2)                   its magnitude against the still norm n_a

with s_w, s_a the per-axis, per-sample noise (rad/s, m/s^2; never below the
configured floors, so a noise-free simulated IMU still works). Using the
accelerometer's own still norm n_a (estimated from the data) instead of the
nominal |g| keeps a scale error of the accelerometer from reading as motion.
The still norm is not one number, though: an accelerometer bias b makes
|-g + b| differ between attitudes by up to 2 |b| (and a scale error adds to
that), and that mismatch does not average away with more samples. s_n, the
spread of the still norm across attitudes, enters the magnitude term as a
variance of its own: without it the term grows as n (|b| / s_a)^2, so the
faster the IMU the more holds at some attitude read as motion (a 1 kHz IMU
with a 0.05 m/s^2 bias split every hold into dozens). s_n comes from the
data (the robust spread of the norms of the windows whose spread and rates
pass) and is never below ``accel_norm_floor_m_s2``.
The gyro bias is the median rate of the quietest windows; a creep is as quiet
as a still rig, so windows through which the accelerometer's direction turns
(:func:`_turning`: a creep about any axis but the vertical) have no vote.
For a still rig with white Gaussian noise T is chi-square with
nu = 3n + 3(n - 1) + 1 = 6n - 2 degrees of freedom, and a window is still
when T < chi2.isf(significance, nu): ``significance`` is the false-alarm
probability per window. :func:`still_statistic` returns T over that
threshold (< 1: still).

Windows are centred on each sample and ``window_s`` long in time (widened to
hold ``min_window_samples`` samples on slow IMUs), so non-uniform sampling
just changes n and nu per sample. Near the edge of the data (the newest
samples of an online stream, either side of a gap) a window slides inward so
that it keeps its full length: a window cut in half would hold half the
samples, too few to test on a slow IMU. A step between samples longer than
``gap_periods`` sample periods is a gap: no window and no still run spans
it. NaN/inf samples are skipped. Every sum is a difference of cumulative sums:
the cost is linear in the number of samples, with no loop over samples.

Detection limit: a constant rotation at rate r adds about n r^2 / s_w^2 to T,
so it is detected (on average) when r > s_w sqrt((gamma - nu) / n), gamma the
threshold. At 200 Hz, a 0.1 s window (n = 21), significance 1e-5 and
s_w = 0.002 rad/s this is 1.9 s_w = 0.0039 rad/s (0.22 deg/s): a creep of
0.5 deg/s is motion, one of 0.01 deg/s passes as still. The limit falls only
as n^(-1/4) with longer windows. A slow translation at constant velocity is
invisible to any IMU test (zero acceleration, zero rate).

False alarms: sliding windows overlap, so a still rig sees several times
``significance / window_s`` of them per second; each splits a still run.
Measured with known noise at 100-400 Hz: about 5 per 1000 s of stillness at
significance 1e-4, about 1 at 1e-5 (the default), none at 1e-6.

An IMU on a flexible bar (the rig file mounts it in a camera) rings with
that bar after every stop: its gyro and accelerometer carry a decaying
oscillation at the bar's natural frequency while the body stands still, for
seconds on a lightly damped bar, far above the sensor noise. Such a ringing is
not a motion of the rig. With ``mount_ringing_hz`` set (the pipeline sets it
from the rig file: :func:`for_rig`) each window is at least one period of that
frequency long and every axis fits, besides its constant, an oscillation at it
decaying at the bar's damping ratio, whose amplitude changes besides linearly
across the window (e cos, e sin, tau e cos, tau e sin: a damping and a
frequency a few percent off, to first order); T sums the residuals of that fit
and nu loses the 24 fitted parameters. The mount's turn, and its static bend
under the load, are taken out first (:class:`.mount_ringing.MountTurn`). A constant rate or
a ramp is nearly orthogonal to one period of an oscillation, so a creep or a
move stays a motion. The fit's windowed sums are differences of cumulative
sums too (the oscillation's phase is taken from the first sample's stamp).

Noise: :func:`estimate_noise` takes sensor_msgs/Imu covariances when they
are valid (``[0] == -1`` or all zeros mean unknown), read as per-sample
variances, each raised to the white noise the samples show (from the
differences of paired neighbouring samples, which a smooth motion hardly
changes) where a driver claims less; otherwise it estimates the noise from
the data. A MEMS IMU low-pass filters its output, so neighbouring samples
share their noise: its autocorrelation, measured from the still samples,
turns each window's null distribution into the scaled chi-square of the
same mean and variance (:mod:`.noise_correlation`), white noise giving back
chi-square(6n - 2). The data estimate
assumes the rig is still during part of the recording (more than
``noise_quantile`` of the time): the windowed variances of still windows
follow s^2 chi2(k) / k, so the ``noise_quantile`` quantile of the windowed
sum of squares divided by chi2.ppf(noise_quantile, k) is an unbiased
estimate of s^2. The gyro bias and the still norm of the accelerometer come
from the same quietest windows (their median): a constant slow rotation
looks like gyro bias, so the still windows must be the majority of the
quietest ones, and the bias is bounded by ``max_gyro_bias_rad_s`` (a
physical bound of MEMS gyros: an uncalibrated consumer part's zero-rate
offset is specified within 20 deg/s; at the earlier 3 deg/s bound a gyro 3.4
deg/s off had every window read as motion and no hold), so that a faster
steady turn stays a motion; a slower one the whole recording long reads as
bias, and the images, which do move, refuse its frames. A rig that never holds still makes the
quietest *motion* look like noise: the estimate is too large and motion
passes as still. Give the covariances (or a known :class:`ImuNoise`) then.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from ..config import check, option
from ..core.loss import MAD_TO_STD
from ..errors import InputError
from .imu import ImuBuffer, ImuReject
from .mount_ringing import RINGING_PARAMETERS, MountBar, MountTurn, mount_bar, mount_ringing_hz, ringing_moments
from .noise_correlation import (
    autocorrelation,
    mean_variance_factor,
    per_value,
    periodic,
    spread_null,
    statistic_null,
    vibration_period,
)

# A window on a ringing mount spans at least this many periods of its ringing to be tested (a hair less than
# one: a window of one period holds samples over one period less one sample's spacing, plus stamp jitter).
RINGING_SPAN_PERIODS = 0.95
# A covariance's noise below 1/CLAIM_REFUTED of the white noise the samples show is refuted (that estimate
# scatters by a few percent): the source is then the white noise (the noise used is the larger either way).
CLAIM_REFUTED = 1.25
# The noise's autocorrelation is measured over this many windows' lags: a vibration down to a quarter of a
# window's frequency (2.5 Hz at 0.1 s) shows its return, and so is told from a filter's decay.
VIBRATION_WINDOWS = 4


@dataclass
class ZuptConfig:
    """Settings of the stillness test; times in seconds."""

    window_s: float = option(0.1, "sliding window of the IMU stillness test, centred on each sample (s)", lo=0.0,
                             hi=10.0, lo_open=True)
    min_window_samples: int = option(8, "the window is widened to hold at least this many samples (slow IMUs)",
                                     lo=2, hi=10000)
    significance: float = option(1e-5, "false-alarm probability per window of a still rig (chi-square threshold)",
                                 lo=0.0, hi=0.5, lo_open=True)
    gyro_floor_rad_s: float = option(1e-4, "the gyro noise used is never below this (rad/s)", lo=0.0, hi=1.0,
                                     lo_open=True)
    accel_floor_m_s2: float = option(1e-3, "the accelerometer noise used is never below this (m/s^2)", lo=0.0,
                                     hi=10.0, lo_open=True)
    min_still_s: float = option(0.0, "shortest run of still samples reported as still (s); never shorter than "
                                "one window: a shorter run is the turning point of a move", lo=0.0, hi=60.0)
    gap_periods: float = option(5.0, "a step longer than this many sample periods is a gap: it breaks windows "
                                "and still runs", lo=1.0, hi=1000.0)
    noise_quantile: float = option(0.1, "the noise estimated from the data comes from this quantile of the "
                                   "windows (the rig must be still longer than that)", lo=0.0, hi=1.0,
                                   lo_open=True)
    noise_min_s: float = option(1.0, "the noise estimate from the data needs this much IMU data (s)", lo=0.0,
                                hi=3600.0, lo_open=True)
    noise_refresh_s: float = option(10.0, "the noise is estimated again after this much new data (s)", lo=0.0,
                                    hi=3600.0, lo_open=True)
    accel_norm_floor_m_s2: float = option(0.02, "the still norm of the accelerometer differs between attitudes by "
                                          "its bias and scale error; the spread used is the data's, never below "
                                          "this (m/s^2: a calibrated MEMS accelerometer's residual bias)", lo=0.0,
                                          hi=10.0, lo_open=True)
    mount_ringing_hz: float | None = option(None, "the IMU's mount rings at this frequency (Hz): the stillness "
                                            "test takes an oscillation at it as no motion; None: the natural "
                                            "frequency of the flexible bar the rig file mounts the IMU on (none on "
                                            "the body); 0: none", lo=0.0, hi=1000.0, nullable=True)
    use_covariance: bool = option(True, "take the noise the sensor_msgs/Imu covariances claim (raised to the "
                                  "white noise the samples show); false: estimate it from the samples alone "
                                  "(a driver whose covariances claim too little of a low-pass filtered IMU)")
    max_gyro_bias_rad_s: float = option(0.35, "the gyro bias estimated from the data is at most this (rad/s: an "
                                        "uncalibrated consumer MEMS gyro's zero-rate offset is specified within "
                                        "20 deg/s, 1-5 deg/s typical): a faster steady turn is motion, not bias",
                                        lo=0.0, hi=10.0)
    gyro_bias_stability_rad_s: float = option(
        5.2e-4, "how far the gyro's bias may stray over a recording from the one estimated from its still windows "
        "(rad/s; a MEMS gyro's in-run instability and a few degrees of warming: 0.03 deg/s): a hold whose mean "
        "rate stands out of it and the noise turned steadily (:mod:`.steady_turn`)", lo=0.0, hi=1.0, lo_open=True)

    # the bar the IMU rides on: its damping and static bend (:func:`.mount_ringing.mount_bar`); set from the rig
    # file by :func:`for_rig`, not an option
    mount_bar: MountBar | None = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        check(self, "zupt config")
        if self.mount_bar is not None and not isinstance(self.mount_bar, MountBar):
            raise InputError("zupt config", "is set from the rig file, not in a config", "mount_bar")


class NoiseSource(str, Enum):
    """Where the stillness test's noise comes from."""

    DATA = "data"  # the quietest windows of the samples
    COVARIANCE = "covariance"  # the sensor_msgs/Imu covariances
    WHITE_NOISE = "white noise"  # the samples' white noise, where it is above what the covariances claim
    VIBRATION = "vibration"  # the quietest windows' spread, where their samples vibrate (a periodic correlation)


@dataclass
class ImuNoise:
    """Noise of one IMU, per axis and per sample at its sampling period."""

    accel_sigma: float  # m/s^2
    gyro_sigma: float  # rad/s
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) rad/s, estimated from the data
    source: NoiseSource = NoiseSource.DATA
    accel_norm: float = math.nan  # m/s^2, |specific force| at rest; nan: no magnitude term in the test
    period_s: float = math.nan  # median sample period; nan: taken from the samples tested
    accel_norm_sigma: float = 0.0  # m/s^2, spread of the still norm across attitudes (bias, scale error)
    claimed: tuple | None = None  # (accel, gyro) sigmas the message covariances claim; None: none given
    white: tuple | None = None  # (accel, gyro) white noise of the samples (paired differences); None: unknown
    # normalised autocorrelation of the accelerometer's and the gyro's noise at lags 0, 1, ... samples (a MEMS
    # IMU's low-pass filter makes neighbouring samples alike); [1.0]: white
    accel_correlation: np.ndarray = field(default_factory=lambda: np.ones(1))
    gyro_correlation: np.ndarray = field(default_factory=lambda: np.ones(1))
    quietest: tuple | None = None  # (accel, gyro) noise the quietest windows show (the "data" estimate); None: unknown


def describe_noise(noise: ImuNoise, cfg: ZuptConfig) -> str:
    """One line on the noise the stillness test uses: per sample, where it comes from, what the covariances
    claimed where the samples refute it, and how far the noise of neighbouring samples correlates."""
    used = (max(noise.accel_sigma, cfg.accel_floor_m_s2), max(noise.gyro_sigma, cfg.gyro_floor_rad_s))
    text = f"noise {used[0]:.3g} m/s^2 and {used[1]:.3g} rad/s per sample (from the {noise.source.value}"
    if noise.source is NoiseSource.WHITE_NOISE and noise.claimed is not None:
        ratio = max(u / c if c > 0 else math.inf for u, c in zip(used, noise.claimed))
        text += (f": the Imu messages' covariances claim {noise.claimed[0]:.3g} m/s^2 and {noise.claimed[1]:.3g} "
                 f"rad/s, up to {ratio:.3g}x less than the samples show; tested with the claim, still windows read "
                 f"as motion")
    elif noise.source is NoiseSource.VIBRATION:
        periods = [vibration_period(rho) for rho in (noise.accel_correlation, noise.gyro_correlation)]
        period = next((p for p in periods if p is not None), None)  # samples
        known = period is not None and math.isfinite(noise.period_s)
        at = f" at about {1.0 / (period * noise.period_s):.3g} Hz as sampled" if known else ""
        claim = (f"; the Imu messages' covariances claim {noise.claimed[0]:.3g} m/s^2 and {noise.claimed[1]:.3g} "
                 f"rad/s" if noise.claimed is not None else "")
        text += (f" the quietest windows show: their samples vibrate{at}, a motor's vibration taken as noise, "
                 f"which a window's mean averages out{claim}")
    elif noise.source is NoiseSource.COVARIANCE and noise.quietest is not None:
        ratio = max(q / u for q, u in zip(noise.quietest, used))
        if ratio > CLAIM_REFUTED:  # smooth motion or correlated noise: the data cannot tell which
            text += (f"; the quietest windows show up to {ratio:.3g}x more: if the rig held still at times, the "
                     f"covariances claim too little (zupt.use_covariance: false takes the samples' noise)")
    text += ")"
    lags = max(len(noise.accel_correlation), len(noise.gyro_correlation)) - 1
    if lags > 0:
        span = f" ({1e3 * lags * noise.period_s:.3g} ms)" if math.isfinite(noise.period_s) else ""
        cause = "the vibration" if noise.source is NoiseSource.VIBRATION else "an IMU's low-pass filter"
        text += (f"; neighbouring samples' noise correlated over {lags} samples{span}, as {cause} makes it: taken into "
                 f"the test")
    return text


def _valid_samples(t, accel, gyro, source: str):
    """(t, accel, gyro) of the finite samples and their indices; InputError for wrong shapes or unordered stamps."""
    t = np.asarray(t, dtype=float).reshape(-1)
    accel = np.asarray(accel, dtype=float)
    gyro = np.asarray(gyro, dtype=float)
    for name, x in (("accel", accel), ("gyro", gyro)):
        if x.shape != (len(t), 3):
            raise InputError(source, f"{name} has shape {x.shape}, expected ({len(t)}, 3) like the stamps", name)
    idx = np.flatnonzero(np.isfinite(t) & np.isfinite(accel).all(axis=1) & np.isfinite(gyro).all(axis=1))
    t = t[idx]
    back = np.flatnonzero(np.diff(t) < 0)
    if len(back):
        k = idx[back[0] + 1]
        raise InputError(source, f"stamps go backwards at sample {k} ({t[back[0] + 1]:.6f} s after "
                                 f"{t[back[0]]:.6f} s); sort the samples by stamp", "t")
    return t, accel[idx], gyro[idx], idx


def _period(t: np.ndarray, noise: ImuNoise | None = None) -> float:
    if noise is not None and math.isfinite(noise.period_s) and noise.period_s > 0:
        return float(noise.period_s)
    dt = np.diff(t)
    dt = dt[dt > 0]
    return float(np.median(dt)) if len(dt) else math.nan


def for_rig(cfg: ZuptConfig, rig) -> ZuptConfig:
    """``cfg`` with ``mount_ringing_hz`` resolved from the rig file: the natural frequency of the flexible bar
    the IMU rides on (0 for an IMU on the body or a rigid mount); a value given in ``cfg`` is kept. The bar's
    damping and static bend (``mount_bar``) come from the rig file too."""
    hz = mount_ringing_hz(rig) if cfg.mount_ringing_hz is None else cfg.mount_ringing_hz
    return dataclasses.replace(cfg, mount_ringing_hz=hz, mount_bar=cfg.mount_bar or mount_bar(rig))


def _ringing_hz(cfg: ZuptConfig) -> float:
    f = cfg.mount_ringing_hz
    return float(f) if f is not None and f > 0 else 0.0


def ringing_damping(cfg: ZuptConfig) -> float:
    """The damping ratio at which the IMU's mount's ringing decays (0: not known, or no ringing mount)."""
    return cfg.mount_bar.damping if cfg.mount_bar is not None else 0.0


def _min_samples(cfg: ZuptConfig) -> int:
    """Samples a window needs: ``min_window_samples``, and with a ringing mount twice the oscillation's
    parameters per axis more, so that each fit keeps degrees of freedom to test."""
    return cfg.min_window_samples + (2 * RINGING_PARAMETERS if _ringing_hz(cfg) else 0)


def _testable(t: np.ndarray, i0: np.ndarray, i1: np.ndarray, period: float, cfg: ZuptConfig) -> np.ndarray:
    """The windows that can be tested: at least :func:`_min_samples` samples, and on a ringing mount a period of
    its ringing (a shorter span cannot tell the oscillation from the constant: the fit's constant, and with it
    the still norm, can be anything). At the start of a stream, or between gaps, the samples span less: those
    verdicts are "unknown", not "moving"."""
    n = i1 - i0
    ok = n >= _min_samples(cfg)
    f = _ringing_hz(cfg)
    if f and len(t):
        step = period if math.isfinite(period) else 0.0
        span = t[np.clip(i1 - 1, 0, len(t) - 1)] - t[np.clip(i0, 0, len(t) - 1)] + step
        ok &= span >= RINGING_SPAN_PERIODS / f
    return ok


def window_length(cfg: ZuptConfig, period: float) -> float:
    """``window_s``, widened on slow IMUs to an odd number of sample periods that holds ``min_window_samples``:
    a centred window of k + 1/2 periods either side holds 2k + 1 samples with its edges half a period from any
    sample, so stamp jitter and rounding do not drop one (a window of exactly m periods would hold m + 1, m or
    m - 1 samples depending on rounding). With a ringing mount, at least one period of its ringing."""
    f = _ringing_hz(cfg)
    least = max(cfg.window_s, 1.0 / f) if f else cfg.window_s
    if not math.isfinite(period):
        return least
    return max(least, (2 * math.ceil((_min_samples(cfg) - 1) / 2) + 1) * period)


def _gap_starts(t: np.ndarray, period: float, cfg: ZuptConfig) -> np.ndarray:
    """Per sample: True where it starts a gap-free segment (the first sample, and each after a step longer than
    ``gap_periods`` sample periods)."""
    brk = np.ones(len(t), dtype=bool)
    if len(t) > 1:
        brk[1:] = np.diff(t) > cfg.gap_periods * period
    return brk


def _windows(t: np.ndarray, period: float, cfg: ZuptConfig):
    """Index ranges [i0, i1) of each sample's centred window, clipped at gaps, and the gap flags.

    ``brk[j]`` is True when sample j starts a new gap-free segment (always for j = 0).
    """
    half = 0.5 * window_length(cfg, period)
    brk = _gap_starts(t, period, cfg)
    seg = np.cumsum(brk) - 1
    starts = np.flatnonzero(brk)
    ends = np.append(starts[1:], len(t))
    if len(t) == 0:
        return starts, ends, brk
    # near a segment's edge (the newest samples online, a gap) the window slides inward to keep its full length:
    # a window cut in half holds half the samples, which on a slow IMU is too few to test at all
    first, last = t[starts[seg]], t[ends[seg] - 1]
    lo = np.minimum(np.maximum(t - half, first), np.maximum(last - 2.0 * half, first))
    i0 = np.maximum(np.searchsorted(t, lo, side="left"), starts[seg])
    i1 = np.minimum(np.searchsorted(t, lo + 2.0 * half, side="right"), ends[seg])
    # a link that loses samples (one or two at a time, shorter than a gap) leaves some windows short of the
    # samples a test needs: such a window spans as many samples as it needs about its own (within its segment),
    # not an untestable verdict that cuts the still run around it (5 % lost in 30 ms bursts at 50 Hz: 7 % of the
    # windows, every hold cut into two or three)
    m = _min_samples(cfg)
    short = np.flatnonzero(i1 - i0 < m)
    if len(short):
        s0, s1 = starts[seg[short]], ends[seg[short]]
        first_i = np.clip(short - (m - 1) // 2, s0, np.maximum(s1 - m, s0))
        i0[short] = np.minimum(i0[short], first_i)
        i1[short] = np.minimum(np.maximum(i1[short], first_i + m), s1)
    return i0, i1, brk


def _moments(x: np.ndarray, i0: np.ndarray, i1: np.ndarray, shift: np.ndarray):
    """Window mean of x, sum of |x - mean|^2 and sum of |x - shift|^2 over [i0, i1), by cumulative sums.

    Subtracting ``shift`` (a typical value) before summing keeps the differences of
    large cumulative sums accurate.
    """
    d = x - shift
    c1 = np.zeros((len(x) + 1, 3))
    np.cumsum(d, axis=0, out=c1[1:])
    c2 = np.zeros(len(x) + 1)
    np.cumsum(np.einsum("ij,ij->i", d, d), out=c2[1:])
    n = np.maximum(i1 - i0, 1)[:, None]
    mean_d = (c1[i1] - c1[i0]) / n
    ss_shift = c2[i1] - c2[i0]
    ss_mean = np.maximum(ss_shift - n[:, 0] * np.einsum("ij,ij->i", mean_d, mean_d), 0.0)
    return mean_d + shift, ss_mean, ss_shift


def _window_moments(x, t, i0, i1, shift, cfg: ZuptConfig):
    """:func:`_moments`, or :func:`.mount_ringing.ringing_moments` on a ringing mount; and the parameters fitted
    per axis besides the constant."""
    f = _ringing_hz(cfg)
    if f:
        return ringing_moments(x, t, i0, i1, shift, f, ringing_damping(cfg)), RINGING_PARAMETERS
    return _moments(x, i0, i1, shift), 0


def _ringing_moments(a, w, t, i0, i1, shift, gyro_bias, cfg: ZuptConfig):
    """The accelerometer's and the gyro's :func:`_window_moments` (the gyro's about ``gyro_bias``) and the
    parameters fitted per axis besides the constant; on a ringing mount with the mount's turn taken out of
    both (:class:`.mount_ringing.MountTurn`: gravity turned with the tip, and the rate of a swing not in one
    plane, are not oscillations at the mount's frequency alone)."""
    f = _ringing_hz(cfg)
    if f:
        turn = MountTurn(t, w, gyro_bias, i0, i1, f, a, cfg.mount_bar)
        return turn.accel_moments(a, shift), turn.gyro_moments(w), RINGING_PARAMETERS
    return _moments(a, i0, i1, shift), _moments(w, i0, i1, gyro_bias), 0


def _sigma_from_covariance(cov, source: str, name: str) -> float | None:
    """sqrt of the mean diagonal of a row-major 3x3 covariance; None when it says 'unknown'."""
    if cov is None:
        return None
    c = np.asarray(cov, dtype=float).reshape(-1)
    if c.size != 9:
        raise InputError(source, f"{name} covariance has {c.size} entries, expected 9 (row-major 3x3)", name)
    if not np.isfinite(c).all() or c[0] == -1.0 or not np.any(c):
        return None
    d = c[[0, 4, 8]]
    if np.any(d <= 0):
        return None
    return float(math.sqrt(d.mean()))


def estimate_noise(t, accel, gyro, cfg: ZuptConfig | None = None, covariance=None,
                   source: str = "IMU samples") -> ImuNoise:
    """Per-sample noise, gyro bias and still norm of an IMU from its samples (and its message covariances).

    ``covariance`` is None or (linear_acceleration_covariance, angular_velocity_covariance)
    as in sensor_msgs/Imu (9 numbers each, m^2/s^4 and rad^2/s^2). When both are
    valid the sigmas come from them (source "covariance"), each raised to the white noise the samples show where
    that is larger (source "white noise": a driver's covariance is a claim, often a datasheet's noise density
    taken for a per-sample std, and a test with too little noise sees every still window move); otherwise from
    the quietest windows of the data (source "data"), which needs ``cfg.noise_min_s`` of samples. The gyro bias
    and still norm always come from the data.
    Raises :class:`InputError` naming ``source`` when there is too little data.
    """
    cfg = cfg or ZuptConfig()
    t, a, w, _ = _valid_samples(t, accel, gyro, source)
    cov_a, cov_w = covariance if covariance is not None else (None, None)
    s_a = _sigma_from_covariance(cov_a, source, "linear_acceleration")
    s_w = _sigma_from_covariance(cov_w, source, "angular_velocity")
    from_cov = cfg.use_covariance and s_a is not None and s_w is not None
    span = float(t[-1] - t[0]) if len(t) else 0.0
    if len(t) < cfg.min_window_samples or (not from_cov and span < cfg.noise_min_s):
        need = (f"{cfg.min_window_samples} samples" if from_cov
                else f"{cfg.noise_min_s} s of samples (or valid message covariances)")
        raise InputError(source, f"{len(t)} valid IMU samples over {span:.3f} s: the noise estimate needs {need}")
    period = _period(t)
    i0, i1, _ = _windows(t, period, cfg)
    n = i1 - i0
    ok = _testable(t, i0, i1, period, cfg)
    if not ok.any():
        ring = f" over a period of the mount's ringing ({1.0 / _ringing_hz(cfg):.3f} s)" if _ringing_hz(cfg) else ""
        raise InputError(source, f"no {_min_samples(cfg)} samples in a row{ring} without a gap (longer than "
                                 f"{cfg.gap_periods:g} sample periods of {period:.4f} s): cannot estimate the noise")
    (mean_w, ssw, _), extra = _window_moments(w, t, i0, i1, np.median(w, axis=0), cfg)
    (mean_a, ssa, _), _ = _window_moments(a, t, i0, i1, np.median(a, axis=0), cfg)
    white_null = (np.ones(1), np.ones(1))
    var_a, var_w, quiet = _quantile_variances(ssa[ok], ssw[ok], n[ok], extra, white_null, cfg)
    if not extra:  # (on a ringing mount the accelerometer's direction swings with the bar)
        smooth = _smooth(ssa, ssw, n, ok, var_a, var_w)
        turning = _turning(t, a, smooth, var_a, period)
        kept, calm = quiet & ~turning[ok], (smooth & ~turning)[ok]
        # the quietest windows that do not turn; where hardly any are left, every smooth one that does not
        quiet = kept if kept.sum() >= min(_min_samples(cfg), calm.sum()) and kept.any() else \
            calm if calm.any() else quiet
    if extra:
        bias = np.median(mean_w[ok][quiet], axis=0)
    else:  # the densest of the calm windows' mean rates (not the quiet ones' median: creeps pull it)
        pool = calm if calm.any() else quiet
        bias = _bias_mode(mean_w[ok][pool], max(var_w, cfg.gyro_floor_rad_s ** 2) / n[ok][pool])
    size = float(np.linalg.norm(bias))
    if size > cfg.max_gyro_bias_rad_s:  # a rig turning steadily the whole time is moving, whatever its rate
        bias = bias * (cfg.max_gyro_bias_rad_s / size)
    if extra:  # on a ringing mount, the mount's turn (with this bias) taken out
        (mean_a, ssa, _), (_, ssw, _), _ = _ringing_moments(a, w, t, i0, i1, np.median(a, axis=0), bias, cfg)
        var_a, var_w, quiet = _quantile_variances(ssa[ok], ssw[ok], n[ok], extra, white_null, cfg)
    norm = float(np.median(np.linalg.norm(mean_a[ok][quiet], axis=1)))
    white = _white_noise(t, a, w, i0, i1, cfg)

    def noise_of(var_a, var_w, correlation):
        if from_cov:
            sa, sw = max(s_a, white[0]), max(s_w, white[1])
            refuted = sa > CLAIM_REFUTED * s_a or sw > CLAIM_REFUTED * s_w
            src = NoiseSource.WHITE_NOISE if refuted else NoiseSource.COVARIANCE
            shaken = [periodic(rho) for rho in correlation]
            if any(shaken):  # a motor's vibration: neither claimed nor, slower than the samples, in their steps
                sa = max(sa, math.sqrt(max(var_a, 0.0))) if shaken[0] else sa
                sw = max(sw, math.sqrt(max(var_w, 0.0))) if shaken[1] else sw
                src = NoiseSource.VIBRATION
        else:
            sa, sw = (math.sqrt(v) if v > 0 else 0.0 for v in (var_a, var_w))  # nan: a degenerate spread
            src = NoiseSource.DATA
        quietest = tuple(math.sqrt(v) if v > 0 else 0.0 for v in (var_a, var_w))
        noise = ImuNoise(sa, sw, bias, src, norm, period, 0.0, (s_a, s_w) if from_cov else None, white,
                         *correlation, quietest)
        return dataclasses.replace(noise, accel_norm_sigma=_norm_spread(t, w - bias, mean_a, ssa, i0, i1, ok,
                                                                        noise, cfg))

    # How the noise of neighbouring samples correlates (a MEMS IMU's low-pass filter) comes first from the
    # quietest windows' samples, then from every sample the test with it calls still (the quietest windows
    # alone are biased towards smooth noise); with it the windows' spreads follow another, wider distribution,
    # so the variances are read again from their quantile. On a ringing mount the samples' correlation is the
    # ringing's, which the windows fit out: the noise is taken as white there.
    if extra:
        return noise_of(var_a, var_w, white_null)
    cover = np.zeros(len(t) + 1, dtype=np.int64)
    np.add.at(cover, i0[ok][quiet], 1)
    np.add.at(cover, i1[ok][quiet], -1)
    cover = np.cumsum(cover[:-1]) > 0
    # lags over a window's samples tell a filter's correlation; a vibration slower than a window (an engine at
    # idle, an alias) returns only after it: VIBRATION_WINDOWS windows' worth are measured
    lags = VIBRATION_WINDOWS * int(np.max(n[ok]))
    # a sensor whose samples show less than its floor holds no noise to correlate (a simulated one): white
    noisy = (var_a >= cfg.accel_floor_m_s2 ** 2, var_w >= cfg.gyro_floor_rad_s ** 2)

    def correlation_of(mask):
        return tuple(autocorrelation(x, mask, lags) if keep else white_null[0] for x, keep in zip((a, w), noisy))

    correlation = correlation_of(cover)
    if len(correlation[0]) == len(correlation[1]) == 1:
        return noise_of(var_a, var_w, white_null)
    var_a, var_w, _ = _quantile_variances(ssa[ok], ssw[ok], n[ok], extra, correlation, cfg)
    noise = noise_of(var_a, var_w, correlation)
    still = _statistic(t, a, w, noise, cfg)[0] < 1.0
    if still.sum() > cover.sum():
        correlation = correlation_of(still)
        var_a, var_w, _ = _quantile_variances(ssa[ok], ssw[ok], n[ok], extra, correlation, cfg)
        noise = noise_of(var_a, var_w, correlation)
    return _bias_through_vibration(noise, t, a, w, cfg)


CREEP_RAD_S = math.radians(0.2)
"""The slowest creep the accelerometer is to tell from a still rig (:func:`_turning`): 0.2 deg/s, a hold that turns
by a few tenths of a degree over its settled part."""

TURN_SIGMAS = 5.0
"""The accelerometer's direction turned between two blocks of samples where it moved by more than this many stds
of their means' difference (white noise: 4 in 10^6 pairs of a still rig, which then only lose their vote on the
bias)."""

TURN_SPAN_S = (0.25, 2.0)
"""The shortest and longest block (s) :func:`_turning` compares: at least a few dozen samples, at most the length
of a short hold."""


def turn_span_s(accel_sigma: float, rate_hz: float, gravity: float) -> float:
    """The length (s) of each of two adjacent blocks of samples whose mean directions tell a creep of
    :data:`CREEP_RAD_S` by TURN_SIGMAS of their noise: their centres S apart see it turn by CREEP_RAD_S S, their
    difference's std is accel_sigma sqrt(2 / (rate S)) / gravity, so S^(3/2) = TURN_SIGMAS accel_sigma
    sqrt(2 / rate) / (gravity CREEP_RAD_S); within :data:`TURN_SPAN_S`. 0.45 s at 200 Hz and 0.02 m/s^2 per
    sample, 0.7 s at 50 Hz, 0.8 s at 400 Hz and 0.065 m/s^2: the shorter the blocks, the nearer a still part
    next to a creep keeps its vote."""
    if not (accel_sigma > 0 and rate_hz > 0 and gravity > 0):
        return TURN_SPAN_S[1]
    span = (TURN_SIGMAS * accel_sigma * math.sqrt(2.0 / rate_hz) / (gravity * CREEP_RAD_S)) ** (2.0 / 3.0)
    return min(max(span, TURN_SPAN_S[0]), TURN_SPAN_S[1])


def _smooth(ssa, ssw, n, ok, var_a: float, var_w: float) -> np.ndarray:
    """Per window: both sensors' spreads within twice the noise's variance (a move's are tens of times that): a
    still rig, or one that creeps."""
    dof = np.maximum(3 * (n - 1), 1)
    return ok & (ssa < 2.0 * dof * var_a) & (ssw < 2.0 * dof * var_w)


def _turning(t, a, smooth, var_a: float, period: float) -> np.ndarray:
    """Per window: whether the body turns through it while the gyro and the accelerometer are smooth (a creep).
    A creep is as quiet as a still rig (a steady turn has no spread), and where more of the data crept than
    stood still the quiet windows' median rate is the creep's: the gyro's bias comes out as that rate, and every
    still window after reads as a turn. The accelerometer tells them apart where the turn is not about the
    vertical: the mean directions of its samples over a block and over the block after (one segment, every
    window in both smooth; each :func:`turn_span_s` long, from the IMU's rate and noise) differ by more than
    TURN_SIGMAS of their noise, which falls as the root of the samples; the windows about the blocks' boundary,
    half a block either side, are turning (the whole outer block at either end of a run of such pairs: the
    newest samples are tested by no later pair). ``smooth``: per window, :func:`_smooth`."""
    N = len(t)
    out = np.zeros(N, dtype=bool)
    if N < 2 or not var_a > 0 or not (math.isfinite(period) and period > 0):
        return out
    if not smooth.any():
        return out
    gravity = float(np.median(np.linalg.norm(a[smooth], axis=1)))
    # each block S long, or half the smooth run it lies in where that is shorter (a creep shorter than two blocks
    # is told by its two halves: a faster one, 0.2 deg/s times (S / its half)^(3/2), but a creep hold lasts as
    # long as a still one, and a lone creep longer than the still holds so far outnumbers their windows)
    idx = np.arange(N)
    edge = np.flatnonzero(np.diff(np.r_[0, smooth.astype(np.int8), 0]))
    starts, ends = edge[::2], edge[1::2]  # the smooth runs [start, end)
    run_len = t[ends - 1] - t[starts] if len(starts) else np.zeros(0)
    mark = np.zeros(N + 1)
    np.add.at(mark, starts, run_len)
    np.add.at(mark, ends, -run_len)
    length = np.cumsum(mark[:N])  # each sample's smooth run's length (0 outside one)
    span = np.clip(np.minimum(turn_span_s(math.sqrt(var_a), 1.0 / period, gravity), 0.5 * length),
                   TURN_SPAN_S[0], TURN_SPAN_S[1])
    # block [t_i, t_i + S) and the next, by cumulative sums over the samples (windows are the samples' own)
    mid = np.searchsorted(t, t + span, side="left")
    end = np.searchsorted(t, t + 2.0 * span, side="left")
    full = (end < N) & (t[np.minimum(end, N - 1)] - t <= 2.0 * span + 2.0 * period)
    rough = np.concatenate([[0], np.cumsum(~smooth)])
    steady = full & (rough[end] - rough[idx] == 0) & (mid - idx >= 2) & (end - mid >= 2)
    if not steady.any():
        return out
    i = np.flatnonzero(steady)
    ca = np.concatenate([np.zeros((1, 3)), np.cumsum(a - a[0], axis=0)])
    n_a, n_b = mid[i] - i, end[i] - mid[i]
    mean_a = (ca[mid[i]] - ca[i]) / n_a[:, None] + a[0]
    mean_b = (ca[end[i]] - ca[mid[i]]) / n_b[:, None] + a[0]
    norm_a, norm_b = np.linalg.norm(mean_a, axis=1), np.linalg.norm(mean_b, axis=1)
    moved = np.linalg.norm(np.cross(mean_a / norm_a[:, None], mean_b / norm_b[:, None]), axis=1)
    sigma = np.sqrt(var_a * (1.0 / n_a + 1.0 / n_b)) / np.sqrt(norm_a * norm_b)
    turned = i[moved > TURN_SIGMAS * sigma]
    if len(turned):  # the windows within half a block of each turning pair's boundary; at the ends of a run of
        # pairs (the data's newest samples, a gap, a move) the whole outer block, which no later pair tests
        # (to the smooth run's ends: the same windows a later pair would have tested, had there been one)
        first = np.r_[True, ~steady[:-1]][turned]
        last = np.r_[~steady[1:], True][turned]
        rough_at = np.flatnonzero(~smooth)
        run_start = np.r_[-1, rough_at][np.searchsorted(rough_at, turned, side="left")] + 1
        run_end = np.r_[rough_at, N][np.searchsorted(rough_at, end[turned], side="left")]
        lo = np.where(first, run_start, np.searchsorted(t, t[mid[turned]] - 0.5 * span[turned], side="left"))
        hi = np.where(last, run_end, np.searchsorted(t, t[mid[turned]] + 0.5 * span[turned], side="left"))
        mark = np.zeros(N + 1, dtype=np.int64)
        np.add.at(mark, lo, 1)
        np.add.at(mark, hi, -1)
        out = np.cumsum(mark[:N]) > 0
    return out


BIAS_MODE_CHI2 = 16.3
"""A window's mean rate lies within this chi-square (3 degrees of freedom, at 1 - 1e-3) of the gyro's bias in its
std when the rig stood still through it (:func:`_bias_mode`)."""

MEDIAN_CHI2_3 = 2.366
"""The median of chi-square with 3 degrees of freedom: half of the still windows' mean rates lie within it of the
bias."""

BIAS_CANDIDATES = 256
"""The windows' mean rates tried as the centre of the still windows' cluster (:func:`_bias_mode`; evenly spread)."""

BIAS_POOL = 4096
"""The windows (evenly spread) whose mean rates :func:`_bias_mode` counts about each candidate."""


def _bias_mode(means: np.ndarray, var_mean: np.ndarray) -> np.ndarray:
    """The gyro's bias from windows' mean rates (K, 3) and each one's variance per axis (K,): the densest of them
    (the median of those within :data:`MEDIAN_CHI2_3` of the mean rate that gathers most there), then the median
    of those within :data:`BIAS_MODE_CHI2` of it. Still windows share the bias; a creeping hold's windows read it
    plus their creep, each hold its own way, so where a creep lasts as long as a still hold the still holds
    together still gather most (a median of the windows is pulled by a share of every creep: a third of the
    holds creeping at 0.5 deg/s under a 50 Hz gyro put it 0.17-0.6 deg/s off, and the still holds after read as
    turns)."""
    if len(means) == 0:
        return np.zeros(3)
    # neighbouring windows share most of their samples: every few of them tell the clusters as well
    pool = np.arange(0, len(means), max(len(means) // BIAS_POOL, 1))
    m, v = means[pool], var_mean[pool]
    c = m[::max(len(m) // BIAS_CANDIDATES, 1)]
    d2 = (np.sum(c ** 2, axis=1)[:, None] + np.sum(m ** 2, axis=1)[None, :] - 2.0 * c @ m.T) / v[None, :]  # (C, K)
    near = d2 <= MEDIAN_CHI2_3  # the densest: a wider ball about a point between two clusters gathers both
    b = np.median(m[near[int(np.argmax(near.sum(axis=1)))]], axis=0)
    inside = np.sum((means - b) ** 2, axis=1) / var_mean <= BIAS_MODE_CHI2
    return np.median(means[inside], axis=0) if inside.any() else b


def _bias_through_vibration(noise: ImuNoise, t, a, w, cfg: ZuptConfig) -> ImuNoise:
    """Where the gyro vibrates (its correlation periodic), a window's mean holds part of a period of its
    rocking and the quietest windows catch it at one phase: the bias is then the mean rate over the samples the
    test calls still, whole periods of it, less two windows at either end of each still run (the slow ends of a
    move pass for still under a vibration's noise)."""
    if not periodic(noise.gyro_correlation):
        return noise
    from scipy.ndimage import binary_erosion  # imported where used

    still = _statistic(t, a, w, noise, cfg)[0] < 1.0
    edge = int(round(2.0 * window_length(cfg, noise.period_s) / noise.period_s)) if noise.period_s > 0 else 0
    inner = binary_erosion(still, np.ones(2 * edge + 1, bool)) if edge else still
    if inner.sum() < len(noise.gyro_correlation):
        return noise
    bias = w[inner].mean(axis=0)
    size = float(np.linalg.norm(bias))
    if size > cfg.max_gyro_bias_rad_s:
        bias = bias * (cfg.max_gyro_bias_rad_s / size)
    return dataclasses.replace(noise, gyro_bias=bias)


def _quantile_variances(ssa, ssw, n, extra: int, correlation, cfg: ZuptConfig):
    """(accelerometer variance, gyro variance, the quietest windows) from the windows' sums of squares about
    their fit: each sum over its null distribution's ``noise_quantile`` quantile is an unbiased s^2 at that
    quantile of still windows (:func:`spread_null`); the quietest are those of both sensors' lowest scores."""
    from scipy.special import gammaincinv  # a chi-square quantile; imported where used (0.3-0.5 s)
    q = cfg.noise_quantile
    out = []
    for ss, rho in ((ssa, correlation[0]), (ssw, correlation[1])):
        c, nu = spread_null(n, extra, rho)
        r = ss / (c * per_value(lambda k: 2.0 * gammaincinv(0.5 * k, q), nu))  # chi2.ppf(q, nu)
        out.append((r, float(np.quantile(r, q))))
    (ra, var_a), (rw, var_w) = out
    score = rw / max(var_w, cfg.gyro_floor_rad_s ** 2) + ra / max(var_a, cfg.accel_floor_m_s2 ** 2)
    return var_a, var_w, score <= np.quantile(score, q)


def _white_noise(t, a, w, i0, i1, cfg: ZuptConfig) -> tuple:
    """(accel, gyro) per-sample white noise from the differences of neighbouring samples: a smooth motion (a
    move, a steady turn) barely changes from one sample to the next, so unlike the samples' own spread this
    holds where the rig is never still. The samples are paired (0 with 1, 2 with 3, ...), so the differences
    are independent; per window their mean (a steady change of rate or force) is taken out, and on a ringing
    mount their ringing (an oscillation at the same frequency) with it; the sum of squares about that fit is
    2 s^2 chi2(m), m its degrees of freedom over the 3 axes, and the ``noise_quantile`` quantile of
    S / (2 chi2.ppf(q, m)) is s^2, as in :func:`estimate_noise`. 0 where no window holds enough pairs."""
    n = len(t) // 2
    if n < 2:
        return 0.0, 0.0
    mid = 0.5 * (t[0:2 * n:2] + t[1:2 * n:2])
    p0, p1 = (i0 + 1) // 2, np.maximum(i1 // 2, (i0 + 1) // 2)  # the pairs inside each window
    (_, ss_w, _), extra = _window_moments(w[1:2 * n:2] - w[0:2 * n:2], mid, p0, p1, np.zeros(3), cfg)
    (_, ss_a, _), _ = _window_moments(a[1:2 * n:2] - a[0:2 * n:2], mid, p0, p1, np.zeros(3), cfg)
    m = 3 * (p1 - p0 - 1 - extra)
    good = m >= 6
    if not good.any():
        return 0.0, 0.0
    from scipy.special import gammaincinv  # a chi-square quantile; imported where used (0.3-0.5 s)
    q = cfg.noise_quantile
    scale = 0.5 / per_value(lambda k: 2.0 * gammaincinv(0.5 * k, q), m[good])
    return (math.sqrt(float(np.quantile(ss_a[good] * scale, q))),
            math.sqrt(float(np.quantile(ss_w[good] * scale, q))))


def _norm_spread(t, w_unbiased, mean_a, ssa, i0, i1, ok, noise: ImuNoise, cfg: ZuptConfig) -> float:
    """Spread of the still norm across attitudes (m/s^2): the robust standard deviation (1.4826 MAD) of the
    window-mean norms of the windows whose accelerometer spread and angular rates pass the test, less their
    noise, never below ``accel_norm_floor_m_s2``."""
    s_w, s_a = max(noise.gyro_sigma, cfg.gyro_floor_rad_s), max(noise.accel_sigma, cfg.accel_floor_m_s2)
    (_, _, ssw), extra = _window_moments(w_unbiased, t, i0, i1, np.zeros(3), cfg)
    n = np.maximum(i1 - i0, 2)
    stat = ssw / s_w ** 2 + ssa / s_a ** 2
    from scipy.special import chdtri  # a chi-square quantile; imported where used (0.3-0.5 s)
    passed = ok.copy()
    rho = (noise.accel_correlation, noise.gyro_correlation)
    if ok.any():
        c, nu, _ = statistic_null(n[ok], extra, *rho, with_norm=False)
        passed[ok] = stat[ok] < c * per_value(lambda k: chdtri(k, cfg.significance), nu)
    if passed.sum() < 2:
        return cfg.accel_norm_floor_m_s2
    norms = np.linalg.norm(mean_a[passed], axis=1)
    robust = MAD_TO_STD * float(np.median(np.abs(norms - np.median(norms))))
    _, _, mean_factor = statistic_null(n[passed], extra, *rho, with_norm=False)
    excess = robust ** 2 - float(np.median(s_a ** 2 * mean_factor))
    return max(math.sqrt(max(excess, 0.0)), cfg.accel_norm_floor_m_s2)


def _statistic(t, a, w, noise: ImuNoise, cfg: ZuptConfig):
    """T / threshold per (valid) sample (nan where the window is too short) and the gap flags."""
    period = _period(t, noise)
    i0, i1, brk = _windows(t, period, cfg)
    n = i1 - i0
    s_w = max(float(noise.gyro_sigma), cfg.gyro_floor_rad_s)
    s_a = max(float(noise.accel_sigma), cfg.accel_floor_m_s2)
    bias = np.asarray(noise.gyro_bias, dtype=float).reshape(3)
    (mean_a, ssa, _), (mean_w, _, ssw), extra = _ringing_moments(a, w, t, i0, i1, np.median(a, axis=0) if len(a)
                                                                 else np.zeros(3), bias, cfg)
    stat = ssw / s_w ** 2 + ssa / s_a ** 2
    ok = _testable(t, i0, i1, period, cfg)
    out = np.full(len(t), np.nan)
    if ok.any():
        with_norm = math.isfinite(noise.accel_norm)
        c, nu, mean_factor = statistic_null(n[ok], extra, noise.accel_correlation, noise.gyro_correlation, with_norm)
        stat = stat[ok]
        if with_norm:
            spread = max(float(noise.accel_norm_sigma), cfg.accel_norm_floor_m_s2)
            stat = stat + (np.linalg.norm(mean_a[ok], axis=1) - noise.accel_norm) ** 2 / (
                s_a ** 2 * mean_factor + spread ** 2)
        from scipy.special import chdtri  # a chi-square quantile; imported where used (0.3-0.5 s)
        out[ok] = stat / (c * per_value(lambda k: chdtri(k, cfg.significance), nu))  # c chi2.isf(significance, nu)
        if not extra:  # (on a ringing mount the window's mean rate holds part of a period of the swing)
            out[ok] = np.maximum(out[ok], _mean_rate_statistic(mean_w[ok] - bias, n[ok], s_w, noise, cfg))
    return out, brk


def _mean_rate_statistic(rate: np.ndarray, n: np.ndarray, s_w: float, noise: ImuNoise, cfg: ZuptConfig):
    """Per window: its mean rate less the bias (K, 3), n samples, against what a still rig's mean holds (the
    noise's s_w^2 times the correlated mean's factor over n, and the bias's stability), over its chi-square(3)
    threshold at the test's significance. The sum of squares weighs a slow turn's rate as one part among the
    noise's 3 n; a vibration makes that noise large, and the ends of a move at a degree a second pass under it,
    while its sine averages out of the window's mean: the mean alone sees the turn (docs/PIPELINE.md, "Holds")."""
    from scipy.special import chdtri  # imported where used

    factor = per_value(lambda k: np.array([mean_variance_factor(noise.gyro_correlation, int(v)) for v in k]), n)
    var = s_w ** 2 * factor / np.maximum(n, 1) + cfg.gyro_bias_stability_rad_s ** 2
    return np.einsum("ij,ij->i", rate, rate) / var / float(chdtri(3, cfg.significance))


def still_statistic(t, accel, gyro, noise: ImuNoise, cfg: ZuptConfig | None = None,
                    source: str = "IMU samples") -> np.ndarray:
    """Per sample: the windowed test statistic over its chi-square threshold (< 1: still; nan: skipped sample
    or too few samples in its window)."""
    cfg = cfg or ZuptConfig()
    tv, a, w, idx = _valid_samples(t, accel, gyro, source)
    out = np.full(len(np.asarray(t).reshape(-1)), np.nan)
    if len(tv):
        out[idx] = _statistic(tv, a, w, noise, cfg)[0]
    return out


def still_mask(t, accel, gyro, noise: ImuNoise, cfg: ZuptConfig | None = None,
               source: str = "IMU samples") -> np.ndarray:
    """Per sample: True where the window around it passes the stillness test (False for skipped samples)."""
    with np.errstate(invalid="ignore"):
        return still_statistic(t, accel, gyro, noise, cfg, source) < 1.0


def _min_run(cfg: ZuptConfig, period: float) -> float:
    """Shortest still run (s): ``min_still_s``, at least one window (whose length follows the IMU's rate), not
    the period a ringing mount's windows span: every sample of a run passed a window that long, so a run
    shorter than it is no turning point of a move (which such a window would hold)."""
    return max(cfg.min_still_s, window_length(dataclasses.replace(cfg, mount_ringing_hz=0.0), period))


def _runs(t: np.ndarray, still: np.ndarray, brk: np.ndarray, min_still_s: float):
    """First and last indices of the runs of still samples (broken at gaps) lasting at least min_still_s."""
    prev = np.zeros(len(t), dtype=bool)
    prev[1:] = still[:-1] & ~brk[1:]
    nxt = np.zeros(len(t), dtype=bool)
    nxt[:-1] = still[1:] & ~brk[1:]
    starts = np.flatnonzero(still & ~prev)
    ends = np.flatnonzero(still & ~nxt)
    keep = t[ends] - t[starts] >= min_still_s
    return starts[keep], ends[keep]


def still_runs(t, still, cfg: ZuptConfig | None = None) -> tuple:
    """(first, last) sample indices of the runs of ``still`` samples at stamps ``t``, broken at gaps, as the
    stillness test's own runs (of any length)."""
    cfg = cfg or ZuptConfig()
    t = np.asarray(t, dtype=float).reshape(-1)
    return _runs(t, np.asarray(still, dtype=bool), _gap_starts(t, _period(t), cfg), 0.0)


def still_intervals(t, accel, gyro, noise: ImuNoise, cfg: ZuptConfig | None = None,
                    source: str = "IMU samples") -> list:
    """[(t0, t1), ...]: stamps of the first and last sample of each still run at least one window (and
    ``min_still_s``) long."""
    cfg = cfg or ZuptConfig()
    tv, a, w, _ = _valid_samples(t, accel, gyro, source)
    if not len(tv):
        return []
    stat, brk = _statistic(tv, a, w, noise, cfg)
    with np.errstate(invalid="ignore"):
        starts, ends = _runs(tv, stat < 1.0, brk, _min_run(cfg, _period(tv, noise)))
    return [(float(tv[i]), float(tv[j])) for i, j in zip(starts, ends)]


IMAGES_STILL_WINDOWS = 10
"""Stillness-test windows' worth of frames the images must hold still for, while every window reads as motion
with the noise the covariances claim and the quietest windows show more than the claim, before the claim is
dropped for the samples' own noise (:meth:`ZuptDetector.distrust_covariance`): with the right noise ten still
windows in a row false-alarm once in 10^50."""


def claim_disputed(noise: ImuNoise | None) -> bool:
    """Whether the noise in use is the covariances' claim (raised to the white noise or not) while the quietest
    windows show more than :data:`CLAIM_REFUTED` times it: correlated noise the claim leaves out, or smooth
    motion; the images tell which."""
    if noise is None or noise.quietest is None or noise.claimed is None:
        return False
    if noise.source not in (NoiseSource.COVARIANCE, NoiseSource.WHITE_NOISE):
        return False
    used = (max(noise.accel_sigma, 1e-12), max(noise.gyro_sigma, 1e-12))
    return max(q / u for q, u in zip(noise.quietest, used)) > CLAIM_REFUTED


class ZuptDetector:
    """Online stillness detector over an :class:`~nrmpc_ros.frontend.imu.ImuBuffer`.

    :meth:`add` only appends to the buffer (a preallocated block, no numpy per
    sample). Queries test the buffered history; the verdicts of samples whose
    whole window has arrived are cached, so a query recomputes only the newest
    window_s of samples. ``noise`` is fixed when given; otherwise it is
    estimated from the buffer (with ``covariance`` as in :func:`estimate_noise`)
    once ``noise_min_s`` of samples have arrived (with valid covariances: once
    a window's samples have) and again whenever the data has doubled since,
    at most ``noise_refresh_s`` apart; until then the queries answer None. The
    gyro bias and the still norm always come from the data: estimated from the
    first few windows they are off by several times what a window of a fast
    IMU resolves (their error enters T as n (db / s_w)^2), so an estimate from
    little data is soon replaced.
    """

    def __init__(self, config: ZuptConfig | None = None, noise: ImuNoise | None = None, covariance=None,
                 buffer: ImuBuffer | None = None):
        self.config = config or ZuptConfig()
        self.buffer = buffer if buffer is not None else ImuBuffer()
        self._fixed = noise is not None
        self._noise = noise
        self._noise_stamp = -math.inf  # newest sample stamp at the last noise estimate
        self._noise_span = 0.0  # the span of the samples that estimate used (s)
        self._covariance = covariance
        self.covariance_distrusted = False  # the images refuted the claimed noise: estimated from the data since
        self._cache_t = np.empty(0)  # stamps and statistics of the samples whose window is complete
        self._cache_stat = np.empty(0)
        self._cache_noise = None

    def add(self, t: float, accel, gyro, covariance=None) -> ImuReject | None:
        """Store one sample; None, or why it was rejected (NaN, out of order, wrong shape; counted by the buffer).

        ``covariance`` (linear_acceleration_covariance, angular_velocity_covariance) of the message: the first
        that says something (see :func:`estimate_noise`) fixes the noise from then on.
        """
        if covariance is not None and self._covariance is None and not self._fixed and not self.covariance_distrusted:
            try:
                ok = all(_sigma_from_covariance(c, self.buffer.source, n) is not None
                         for c, n in zip(covariance, ("linear_acceleration", "angular_velocity")))
            except InputError:
                ok = False
            if ok:
                self._covariance = covariance
                self._noise = None  # estimated again, now from the covariances
        return self.buffer.add(t, accel, gyro)

    def distrust_covariance(self) -> bool:
        """Estimate the noise from the samples alone from now on (as ``use_covariance: false``): the images held
        still where the noise the messages' covariances claim read every window as motion (a low-pass filtered
        IMU whose driver claims its white noise). False where the noise is fixed or not from the covariances."""
        if self._fixed or self._covariance is None:
            return False
        self._covariance, self.covariance_distrusted, self._noise = None, True, None
        return True

    @property
    def noise_in_use(self) -> ImuNoise | None:
        """The noise of the latest estimate, as it is (no new estimate: for reports from another thread)."""
        return self._noise

    @property
    def noise(self) -> ImuNoise | None:
        """The noise in use; None while too few samples have arrived to estimate it."""
        newest = self.buffer.last_stamp
        refresh = min(self.config.noise_refresh_s, max(self._noise_span, self.config.window_s))  # data doubled
        if not self._fixed and (self._noise is None or newest - self._noise_stamp >= refresh):
            t, a, w = self.buffer.window(-math.inf, math.inf)
            try:
                self._noise = estimate_noise(t, a, w, self.config, self._covariance, self.buffer.source)
                self._noise_stamp, self._noise_span = newest, float(t[-1] - t[0])
            except InputError:
                pass
        return self._noise

    def _verdicts(self):
        """(stamps, still flags, gap flags, unknown flags: too few samples in the window to tell) of the buffered
        samples, or None without noise or samples."""
        noise = self.noise
        t, a, w = self.buffer.window(-math.inf, math.inf)
        if noise is None or not len(t):
            return None
        if noise is not self._cache_noise:
            self._cache_t, self._cache_stat, self._cache_noise = np.empty(0), np.empty(0), noise
        k = int(np.searchsorted(self._cache_t, t[0]))  # samples trimmed from the buffer
        ct, cs = self._cache_t[k:], self._cache_stat[k:]
        done = ct[-1] if len(ct) else -math.inf
        win = window_length(self.config, _period(t, noise))
        i = int(np.searchsorted(t, done - win))  # one window of context before the first new verdict
        stat, _ = _statistic(t[i:], a[i:], w[i:], noise, self.config)
        new_stat = stat[len(ct) - i:]
        new_t = t[len(ct):]
        settled = new_t <= t[-1] - 0.5 * win
        self._cache_t, self._cache_stat = np.append(ct, new_t[settled]), np.append(cs, new_stat[settled])
        stat = np.append(cs, new_stat)
        brk = np.ones(len(t), dtype=bool)
        brk[1:] = np.diff(t) > self.config.gap_periods * _period(t, noise)
        with np.errstate(invalid="ignore"):
            return t, stat < 1.0, brk, np.isnan(stat)

    def _run_of(self, t0: float, t1: float, any_length: bool = False):
        """(stamps, i, j, run, young): samples i..j lie in [t0, t1] (j the newest); ``run`` = (first, last)
        indices of the still run holding j (None if j is not in one); ``young`` (False where i..j lie in one still
        run): the stream began, or resumed
        after a gap, less than a still run's length before sample j, and no sample since (nor in i..j) shows a
        move (each is still, or has too few samples around it to tell): what the rig did before is unknown (it
        may have stood still for long), so a run too short yet is no evidence of a move. None without noise,
        or when no sample lies in [t0, t1]. ``any_length``: runs of any length count (not only those a window
        long)."""
        v = self._verdicts()
        if v is None:
            return None
        t, still, brk, unknown = v
        i = int(np.searchsorted(t, t0, side="left"))
        j = int(np.searchsorted(t, t1, side="right")) - 1
        period = _period(t, self._noise)
        if j < i:  # no sample inside (an IMU slower than the cameras): the nearest sample within a gap answers
            gap = self.config.gap_periods * period
            after, before = i < len(t) and t[i] - t1 <= gap, j >= 0 and t0 - t[j] <= gap
            if not (after or before):
                return None
            i = j = i if after else j
        min_run = _min_run(self.config, period)
        starts, ends = _runs(t, still, brk, 0.0 if any_length else min_run)
        k = int(np.searchsorted(starts, j, side="right")) - 1
        run = (int(starts[k]), int(ends[k])) if k >= 0 and ends[k] >= j else None
        young = False
        if run is None or run[0] > i:  # (only asked where the samples are not all in one still run)
            b = int(np.flatnonzero(brk[: j + 1])[-1])  # the stream's start or the last gap (brk[0] is set)
            young = t[j] - t[b] < min_run and bool(np.all(still[min(i, b): j + 1] | unknown[min(i, b): j + 1]))
        return t, i, j, run, young

    @property
    def window_s(self) -> float:
        """The stillness window in use (s): ``window_s`` widened by the IMU's rate and a ringing mount."""
        noise = self.noise
        return window_length(self.config, noise.period_s if noise is not None else math.nan)

    def decided(self, t: float) -> bool:
        """Whether the stillness of an instant ``t`` is decided: the newest sample lies half a stillness window
        (and a sample period) after it, so the window centred on it is complete (the IMU's rate sets how long
        that is: 0.05 s at 200 Hz and more, 0.09 s at 50 Hz)."""
        noise = self.noise
        period = noise.period_s if noise is not None else math.nan
        if not (math.isfinite(period) and period > 0):
            return False
        return self.buffer.last_stamp >= t + 0.5 * window_length(self.config, period) + period

    def is_still(self, t0: float, t1: float) -> bool | None:
        """True when every sample in [t0, t1] lies in one still run (at least one window long).

        Without a sample inside [t0, t1] (an IMU slower than the cameras), the nearest sample within a gap of
        the interval answers. None when there is none, the noise is not known yet, or the samples are still
        in a run too young to tell that began with the stream or after a gap in it (the rig may have stood
        still before: the stream's first window is no move).
        """
        r = self._run_of(t0, t1)
        if r is None:
            return None
        _, i, _, run, young = r
        if run is not None and run[0] <= i:
            return True
        return None if young else False

    def still_run(self, t: float, any_length: bool = False) -> tuple | None:
        """(first, last) stamps of the still run holding ``t`` (its newest sample at most a gap before ``t``) as
        far as the samples so far show it (its last sample the newest one while the rig is still at rest);
        None when ``t`` is not in one. ``any_length``: also a run shorter than a window so far (a stop moments
        ago, whose samples since are still: a provisional answer, which the samples to come confirm or not)."""
        r = self._run_of(-math.inf, t, any_length)
        if r is None or r[3] is None:
            return None
        ts, _, j, (first, last), _ = r
        if t - ts[j] > self.config.gap_periods * _period(ts, self._noise):
            return None
        return float(ts[first]), float(ts[last])

    def leading_run(self, t: float) -> tuple | None:
        """(first, last) stamps of the still run that holds an instant ``t`` (:meth:`still_run`), or of one that
        starts less than half a stillness window (and a sample period) after it, with ``first`` the stop found
        sample by sample: a run of the windowed test starts half a window after the stop (its first window is the
        first whole one after it), so a snapshot taken sooner is still when every sample from it to the run
        reads still on its own (its rate within the test's significance of the bias and its specific force of
        the run's mean: chi-square with 6 degrees of freedom per sample); the stop is the first of the quiet
        samples that lead into the run. At 50 Hz half a window is 0.09 s: without this, a snapshot 0.05 s after
        every stop was taken for a move. On an IMU that rides a ringing bar its samples ring after a stop, and no
        sample alone reads still: there the run's first window answers, which spans half a window before the
        run's first stamp and fits rest and the mount's ringing over all of it. An instant it covers (or one
        with no sample between it and that window) is still, and the window's start is the stop as the test
        resolves it. Its window lasts a period of the ringing at least: on a 1.5 Hz bar the run begins 0.33 s
        after the stop, and a snapshot 0.3 s after each stop was taken for a move. None otherwise."""
        run = self.still_run(t)
        if run is not None:
            return run
        noise = self.noise
        if noise is None:
            return None
        period = noise.period_s if math.isfinite(noise.period_s) else _period(self.buffer.window(-math.inf,
                                                                                                  math.inf)[0])
        half = 0.5 * window_length(self.config, period)
        lead = half + period
        run = self.still_run(t + lead)
        if run is None or not t < run[0] <= t + lead:
            return None
        if _ringing_hz(self.config) > 0.0:
            return min(run[0] - half, t), run[1]
        ts, a, w = self.buffer.window(t - lead, run[1])
        in_run = ts >= run[0]
        s_w = max(float(noise.gyro_sigma), self.config.gyro_floor_rad_s)
        s_a = max(float(noise.accel_sigma), self.config.accel_floor_m_s2)
        T = np.sum((w - np.asarray(noise.gyro_bias, float)) ** 2, axis=1) / s_w ** 2 + \
            np.sum((a - a[in_run].mean(axis=0)) ** 2, axis=1) / s_a ** 2
        from scipy.special import chdtri  # a chi-square quantile; imported where used (0.3-0.5 s)

        moved = np.flatnonzero((T >= float(chdtri(6, self.config.significance))) & ~in_run)
        if len(moved) and ts[moved[-1]] >= t:
            return None  # a sample between the instant and the run reads a motion
        first = moved[-1] + 1 if len(moved) else 0
        return min(float(ts[first]), t), run[1]

    def still_since(self, t: float, any_length: bool = False) -> float | None:
        """Stamp of the first sample of the still run holding ``t`` (:meth:`still_run`); None when ``t`` is not
        in one."""
        run = self.still_run(t, any_length)
        return None if run is None else run[0]


__all__ = ["ImuNoise", "NoiseSource", "ZuptConfig", "ZuptDetector", "describe_noise",
           "estimate_noise", "for_rig", "still_intervals", "still_mask", "still_runs", "still_statistic",
           "window_length"]
