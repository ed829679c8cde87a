"""IMU buffer: the accelerometer averaged over a hold -> body-frame gravity (docs/CONVENTIONS.md, Gravity
measurements).

Samples are kept in time order for ``capacity_s`` seconds. NaN/inf samples and
samples older than the newest one are rejected and counted. The IMU's sample
period is measured from the stream (:attr:`ImuBuffer.period_s`, the median step
of recent samples): every age and window here is in those periods, so one
setting serves IMUs from 50 to 1000 Hz. Steps longer than ``gap_periods``
periods are gaps, counted and reported by :meth:`ImuBuffer.gravity` when they
fall inside the window. Nothing here raises on bad samples.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from ..config import check, option
from ..core.deformation import gravity_from_accelerometer
from ..core.rig import Rig
from ..errors import InputError
from .mount_ringing import mean_under_ringing

INITIAL_ROWS = 1024
"""Rows of the sample array at the start (grown by doubling): a second of a 1 kHz IMU, five of a 200 Hz one."""

PENDING_BLOCK = 256
"""Samples appended one at a time (a tuple each) before they move as one block into the array: the numpy calls of
a consolidation are shared by this many samples; every read consolidates first, so the block size never delays a
hold's samples."""

PERIOD_SAMPLES = 16
"""Samples that measure the IMU's period before the first block is full: the gap test (``gap_periods`` periods)
needs the period from the start, and :data:`PERIOD_MIN_STEPS` steps of the first samples give it."""

PERIOD_MIN_STEPS = 8
"""Fewest steps whose median is taken as the sample period: a median of 8 steps is unmoved by up to 3 outlying
ones (a gap, or the long and the short step around a late sample)."""

PERIOD_WINDOW = PENDING_BLOCK
"""The period is the median step of the newest samples: the block just added and up to this many before it."""


@dataclass
class ImuConfig:
    """IMU samples: how long they are kept and when a hold's averaged accelerometer is usable."""

    max_age_s: float = option(0.1, "a hold uses the IMU only when its newest sample in the hold is at most this "
                              "far from the hold's end (s), and never less than gap_periods sample periods",
                              lo=0.0, hi=60.0, lo_open=True)
    capacity_s: float = option(60.0, "IMU history kept (s)", lo=1.0, hi=3600.0)
    gap_periods: float = option(5.0, "a step between samples longer than this many sample periods (measured from "
                                "the stream) is a gap", lo=1.0, hi=1000.0)
    pad_s: float = option(0.05, "a hold of one frame uses the samples of this long a window before it (s), and "
                          "never fewer than min_samples sample periods", lo=0.0, hi=60.0, lo_open=True)
    min_samples: int = option(3, "samples a hold's averaged accelerometer needs", lo=1, hi=100000)
    gyro_scale_error: float = option(0.01, "the gyro's scale-factor error (a share of the angle travelled; MEMS "
                                     "datasheets: 0.1-3 %): the least std of the rotation it measures between "
                                     "two holds", lo=0.0, hi=0.5)

    def __post_init__(self):
        check(self, "imu config")


class ImuReject(Enum):
    """Why :meth:`ImuBuffer.add` rejected a sample; the value is the phrase shown."""

    WRONG_SHAPE = "wrong shape"
    NOT_FINITE = "NaN or inf"
    OUT_OF_ORDER = "out of order"


class ImuRefusal(Enum):
    """Why :meth:`ImuBuffer.gravity` gives no gravity for a window; the value is the phrase shown."""

    NO_IMU_BLOCK = "the rig file has no imu block"
    NO_SAMPLES = "no IMU samples"
    FEW_SAMPLES = "too few IMU samples in the window"
    STALE = "newest IMU sample older than the view"
    BAD_MEAN = "averaged accelerometer not usable"
    REFUTED = "the images refute it (pair test)"
    DOUBTED = "not testable while an earlier one stands refuted"
    PENDING = "the first after holds without one: waits for the next hold's test"
    UNUSABLE = "refuted on consecutive holds: the IMU's gravity is not used (its rotation or clock)"
    AXES_OFF = "the turns between holds put the IMU's axes off the rig file's: its gravity is not used"
    TURN_REFUTED = "the images' turn from the hold before refutes the gyro's (the IMU's axes?)"
    NO_GRAVITY = "the accelerometer reads no gravity at rest (taken out by a fused driver?)"


@dataclass(frozen=True)
class ImuGravityRefusal:
    """No gravity from a window: the rule (counted by the pipeline) and the numbers behind it (shown)."""

    rule: ImuRefusal
    detail: str = ""

    def __str__(self) -> str:
        return self.detail or self.rule.value


@dataclass
class ImuGravity:
    """Gravity (body frame, m/s^2) from the averaged accelerometer of one window."""

    gravity: np.ndarray
    accel_mean: np.ndarray
    num_samples: int
    t0: float
    t1: float
    accel_std: float  # m/s^2, std of the samples (all axes; about the mount's fitted ringing where it rings)
    # m/s^2, std of accel_mean per axis: accel_std over the root of the samples, or, on a ringing mount seen
    # for less than a period, the ringing the mean keeps
    accel_mean_std: float
    gyro_max: float  # rad/s
    gaps: list = field(default_factory=list)  # (start, end) of gaps inside the window


_ZERO3 = (0.0, 0.0, 0.0)


def _vec3(v) -> tuple | None:
    """(x, y, z) as floats from anything holding exactly three numbers (sequence or array of any shape), else None."""
    if isinstance(v, np.ndarray):
        if v.size != 3:
            return None
        v = v.ravel().tolist()
    try:
        x, y, z = v
        return float(x), float(y), float(z)
    except (TypeError, ValueError):
        a = np.asarray(v, dtype=float).reshape(-1)
        return tuple(a.tolist()) if a.shape == (3,) else None


def describe_gaps(buffer: ImuBuffer) -> str:
    """One line on the stream's gaps (steps beyond ``gap_periods`` sample periods), empty without one: how many,
    and the longest. No stillness window, still run, hold gravity or gyro turn spans a gap, so the frames of
    a gap are judged by the images alone (a user sees why holds there lack the IMU's gravity)."""
    n = buffer.stats["gaps"]
    if not n:
        return ""
    a, b = buffer.longest_gap
    return (f"{n} gap{'s' if n > 1 else ''} of more than {buffer.config.gap_periods:g} sample periods "
            f"({1e3 * buffer.period_s:.3g} ms), the longest {b - a:.3g} s from {a:.3f} s: nothing of the IMU "
            f"spans a gap (the images alone judge its frames)")


class ImuBuffer:
    """Time-ordered accelerometer + gyro samples of one IMU.

    :meth:`add` only checks a sample and appends a tuple of floats (no numpy
    per sample); pending samples move in blocks into a preallocated array of
    rows (t, ax, ay, az, wx, wy, wz) whose live part ``[_i0, _n)`` is trimmed
    by moving ``_i0`` and compacted (or grown) only when the end is reached.
    """

    def __init__(self, rig: Rig | None = None, config: ImuConfig | None = None, ringing_hz: float = 0.0,
                 ringing_damping: float = 0.0):
        self.rig = rig  # None: a bare sample store (no gravity, e.g. for the stillness detector)
        self.config = config or ImuConfig()
        # the IMU's mount rings at this frequency (Hz; 0: it does not), decaying at this damping ratio: a hold's
        # mean takes the oscillation out
        self.ringing_hz, self.ringing_damping = float(ringing_hz), float(ringing_damping)
        self.source = rig.imu.topic if rig is not None and rig.imu is not None else "imu"
        self._buf = np.empty((INITIAL_ROWS, 7))
        self._i0 = self._n = 0  # live rows of _buf
        self._pending: list = []  # (t, ax, ay, az, wx, wy, wz) appended since the last consolidation
        self._gaps: list = []
        self.longest_gap = (math.nan, math.nan)  # (last sample before, first after) of the longest gap so far
        self.stats = Counter()  # "samples", "gaps" and an ImuReject per rejected sample
        self.last_stamp = -math.inf
        self.period_s = math.nan  # median sample period of the stream (s), measured at each consolidation

    def add(self, stamp: float, accel, gyro=None) -> ImuReject | None:
        """Store one sample; returns None, or the reason it was rejected (also counted in ``stats``, by reason)."""
        stamp = float(stamp)
        a = _vec3(accel)
        w = _ZERO3 if gyro is None else _vec3(gyro)
        reason = None
        if a is None or w is None:
            reason = ImuReject.WRONG_SHAPE
        elif not (math.isfinite(stamp) and all(map(math.isfinite, a + w))):
            reason = ImuReject.NOT_FINITE
        elif stamp <= self.last_stamp:
            reason = ImuReject.OUT_OF_ORDER
        if reason:
            self.stats[reason] += 1
            return reason
        if self.last_stamp > -math.inf and stamp - self.last_stamp > self.config.gap_periods * self.period_s:
            self.stats["gaps"] += 1
            self._gaps.append((self.last_stamp, stamp))
            if not stamp - self.last_stamp <= self.longest_gap[1] - self.longest_gap[0]:  # (NaN: the first)
                self.longest_gap = (self.last_stamp, stamp)
        self.last_stamp = stamp
        self.stats["samples"] += 1
        self._pending.append((stamp, *a, *w))
        n = len(self._pending)
        if n >= PENDING_BLOCK or (self.period_s != self.period_s and n >= PERIOD_SAMPLES):
            self._consolidate()  # (the first samples give the period the gap test needs)
        return None

    def _consolidate(self) -> None:
        """Move the pending samples into the array and drop samples older than ``capacity_s``."""
        keep_from = self.last_stamp - self.config.capacity_s
        if self._pending:
            block = np.array(self._pending, dtype=float)
            self._pending.clear()
            live = self._buf[max(self._i0, self._n - PERIOD_WINDOW):self._n, 0]
            steps = np.diff(np.concatenate([live, block[:, 0]]))
            if len(steps) >= PERIOD_MIN_STEPS:  # the median step of the newest samples
                self.period_s = float(np.median(steps))
            self._i0 += int(np.searchsorted(self._buf[self._i0:self._n, 0], keep_from))
            if self._n + len(block) > len(self._buf):  # compact to the front, growing when over half full
                live = self._n - self._i0
                size = max(len(self._buf), 2 * (live + len(block)))
                buf = self._buf if size == len(self._buf) else np.empty((size, 7))
                buf[:live] = self._buf[self._i0:self._n]
                self._buf, self._i0, self._n = buf, 0, live
            self._buf[self._n:self._n + len(block)] = block
            self._n += len(block)
        self._i0 += int(np.searchsorted(self._buf[self._i0:self._n, 0], keep_from))
        if self._gaps and self._gaps[0][1] < keep_from:
            self._gaps = [g for g in self._gaps if g[1] >= keep_from]

    @property
    def _t(self) -> np.ndarray:
        """Stamps of the consolidated samples (a view)."""
        return self._buf[self._i0:self._n, 0]

    def __len__(self) -> int:
        self._consolidate()
        return self._n - self._i0

    @property
    def gaps(self) -> list[tuple[float, float]]:
        """The input gaps longer than ``gap_periods`` sample periods as (last stamp before, first stamp after),
        oldest first; a gap is forgotten once the sample after it leaves the history kept (``stats["gaps"]``
        still counts it)."""
        self._consolidate()
        return list(self._gaps)

    def window(self, t0: float, t1: float):
        """Samples (t, accel, gyro) with t0 <= t <= t1 (copies)."""
        self._consolidate()
        t = self._t
        i = self._i0 + int(np.searchsorted(t, t0, side="left"))
        j = self._i0 + int(np.searchsorted(t, t1, side="right"))
        rows = self._buf[i:j].copy()
        return rows[:, 0], rows[:, 1:4], rows[:, 4:7]

    def _periods(self, n: float) -> float:
        """n sample periods (s); 0 while the period is not known."""
        return n * self.period_s if self.period_s > 0 else 0.0

    @property
    def max_age_s(self) -> float:
        """How old the newest sample may be (s): ``max_age_s``, at least ``gap_periods`` sample periods."""
        return max(self.config.max_age_s, self._periods(self.config.gap_periods))

    @property
    def pad_s(self) -> float:
        """The window before a one-frame hold (s): ``pad_s``, at least ``min_samples`` sample periods."""
        return max(self.config.pad_s, self._periods(self.config.min_samples))

    def has_recent(self, stamp: float) -> bool:
        """True when a sample lies within :attr:`max_age_s` of ``stamp``."""
        age = self.max_age_s
        t, _, _ = self.window(stamp - age, stamp + age)
        return len(t) > 0

    def _swing_m_s2(self, t1: float, g: float) -> float:
        """How far a mean over less than a period of a ringing mount may be off its rest (m/s^2): gravity ``g``
        turned by the swing's angle, its largest rate over the period before ``t1`` (the gyro, less its median
        over the span of ten periods before, a bias) over the ringing's angular frequency. The samples' spread
        over a fraction of a swing does not show it: they may all lie on one side."""
        period = 1.0 / self.ringing_hz
        tw, _, ww = self.window(t1 - 10.0 * period, t1)
        recent = ww[tw >= t1 - period]
        if not len(recent):
            return 0.0
        rate = np.linalg.norm(recent - np.median(ww, axis=0), axis=1)
        return g * float(rate.max()) / (2.0 * math.pi * self.ringing_hz)

    def gravity(self, t0: float, t1: float):
        """(ImuGravity, None) from samples in [t0, t1] (at least pad_s long), or (None, ImuGravityRefusal)."""
        cfg = self.config
        if self.rig is None or self.rig.imu is None:
            return None, ImuGravityRefusal(ImuRefusal.NO_IMU_BLOCK)
        t, a, w = self.window(min(t0, t1 - self.pad_s), t1)
        if len(t) < cfg.min_samples:
            ts = self._t
            if len(ts) == 0:
                return None, ImuGravityRefusal(ImuRefusal.NO_SAMPLES)
            dt = t1 - ts[np.searchsorted(ts, t1, side="right") - 1] if ts[0] <= t1 else math.nan
            return None, ImuGravityRefusal(ImuRefusal.FEW_SAMPLES, f"{len(t)} IMU samples in the window (need "
                                           f"{cfg.min_samples}; newest is {dt:.3f} s old)")
        if t1 - t[-1] > self.max_age_s:
            return None, ImuGravityRefusal(ImuRefusal.STALE, f"newest IMU sample is {t1 - t[-1]:.3f} s older than "
                                           f"the view (max age {self.max_age_s:.3f} s)")
        mean, mean_std, spread = mean_under_ringing(t, a, self.ringing_hz, w, damping=self.ringing_damping)
        if self.ringing_hz > 0 and t[-1] - t[0] < 1.0 / self.ringing_hz:
            mean_std = math.hypot(mean_std, self._swing_m_s2(t[-1], float(np.linalg.norm(mean))))
        try:
            g = gravity_from_accelerometer(self.rig, mean)
        except InputError as exc:
            return None, ImuGravityRefusal(ImuRefusal.BAD_MEAN, str(exc))
        gaps = [gp for gp in self._gaps if gp[1] > t[0] and gp[0] < t1]
        return ImuGravity(g, mean, len(t), float(t[0]), float(t1), spread, mean_std,
                          float(np.max(np.linalg.norm(w, axis=1))), gaps), None
