"""IMU buffer: accelerometer averaged over a static window -> body-frame gravity (SPEC section 4).

Samples are kept in time order for ``capacity_s`` seconds. NaN/inf samples and
samples older than the newest one are rejected and counted; gaps longer than
``gap_s`` are counted and reported by :meth:`ImuBuffer.gravity` when they fall
inside the window. Nothing here raises on bad samples.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..core.deformation import gravity_from_accelerometer
from ..core.rig import Rig
from ..errors import InputError


@dataclass
class ImuConfig:
    """IMU handling: a view uses the IMU only if a sample lies within ``max_age_s`` of its stamp."""

    max_age_s: float = 0.1  # newest usable sample at most this far from the view's stamp
    capacity_s: float = 60.0  # history kept
    gap_s: float = 0.05  # a jump between samples larger than this is a gap
    pad_s: float = 0.05  # a window shorter than this uses the samples of [t1 - pad_s, t1] (one-frame window)
    still_gyro: float = 0.05  # rad/s: max |gyro| of a still rig
    still_accel: float = 0.3  # m/s^2: max deviation of |accel| samples from their mean on a still rig
    min_samples: int = 3


@dataclass
class ImuGravity:
    """Gravity (body frame, m/s^2) from the averaged accelerometer of one window."""

    gravity: np.ndarray
    accel_mean: np.ndarray
    num_samples: int
    t0: float
    t1: float
    accel_std: float  # m/s^2, std of the samples (all axes)
    gyro_max: float  # rad/s
    gaps: list = field(default_factory=list)  # (start, end) of gaps inside the window


class ImuBuffer:
    """Time-ordered accelerometer + gyro samples of one IMU."""

    def __init__(self, rig: Rig, config: ImuConfig | None = None):
        self.rig = rig
        self.config = config or ImuConfig()
        self.source = rig.imu.topic if rig.imu is not None else "imu"
        self._t = np.zeros(0)
        self._a = np.zeros((0, 3))
        self._w = np.zeros((0, 3))
        self._pending: list = []  # (t, a, w) appended since the last consolidation
        self._gaps: list = []
        self.stats = Counter()
        self.last_stamp = -math.inf

    def add(self, stamp: float, accel, gyro=None) -> str | None:
        """Store one sample; returns None, or the reason it was rejected (also counted in ``stats``)."""
        a = np.asarray(accel, dtype=float).reshape(-1)
        w = np.zeros(3) if gyro is None else np.asarray(gyro, dtype=float).reshape(-1)
        stamp = float(stamp)
        reason = None
        if a.shape != (3,) or w.shape != (3,):
            reason = "wrong shape"
        elif not (math.isfinite(stamp) and np.all(np.isfinite(a)) and np.all(np.isfinite(w))):
            reason = "NaN or inf"
        elif stamp <= self.last_stamp:
            reason = "out of order"
        if reason:
            self.stats[f"rejected: {reason}"] += 1
            return reason
        if self.last_stamp > -math.inf and stamp - self.last_stamp > self.config.gap_s:
            self.stats["gaps"] += 1
            self._gaps.append((self.last_stamp, stamp))
        self.last_stamp = stamp
        self.stats["samples"] += 1
        self._pending.append((stamp, a, w))
        if len(self._pending) >= 256:
            self._consolidate()
        return None

    def _consolidate(self) -> None:
        if self._pending:
            t = np.array([p[0] for p in self._pending])
            a = np.array([p[1] for p in self._pending])
            w = np.array([p[2] for p in self._pending])
            self._pending = []
            self._t = np.concatenate([self._t, t])
            self._a = np.concatenate([self._a, a])
            self._w = np.concatenate([self._w, w])
        keep_from = self.last_stamp - self.config.capacity_s
        k = int(np.searchsorted(self._t, keep_from))
        if k:
            self._t, self._a, self._w = self._t[k:], self._a[k:], self._w[k:]
        self._gaps = [g for g in self._gaps if g[1] >= keep_from]

    def __len__(self) -> int:
        self._consolidate()
        return len(self._t)

    def window(self, t0: float, t1: float):
        """Samples (t, accel, gyro) with t0 <= t <= t1."""
        self._consolidate()
        i = int(np.searchsorted(self._t, t0, side="left"))
        j = int(np.searchsorted(self._t, t1, side="right"))
        return self._t[i:j], self._a[i:j], self._w[i:j]

    def has_recent(self, stamp: float) -> bool:
        """True when a sample lies within max_age_s of ``stamp``."""
        t, _, _ = self.window(stamp - self.config.max_age_s, stamp + self.config.max_age_s)
        return len(t) > 0

    def is_still(self, t0: float, t1: float) -> bool | None:
        """Gyro and accelerometer say the rig was still over [t0, t1]; None without samples there."""
        t, a, w = self.window(min(t0, t1 - self.config.pad_s), t1)
        if len(t) < 2:
            return None
        cfg = self.config
        if np.max(np.linalg.norm(w, axis=1)) > cfg.still_gyro:
            return False
        return bool(np.max(np.linalg.norm(a - a.mean(axis=0), axis=1)) <= cfg.still_accel)

    def gravity(self, t0: float, t1: float):
        """(ImuGravity, None) from samples in [t0, t1] (at least pad_s long), or (None, reason) without IMU."""
        cfg = self.config
        if self.rig.imu is None:
            return None, "the rig file has no imu block"
        t, a, w = self.window(min(t0, t1 - cfg.pad_s), t1)
        if len(t) < cfg.min_samples:
            self._consolidate()
            if len(self._t) == 0:
                return None, "no IMU samples"
            dt = t1 - self._t[np.searchsorted(self._t, t1, side="right") - 1] if self._t[0] <= t1 else math.nan
            return None, f"{len(t)} IMU samples in the window (need {cfg.min_samples}; newest is {dt:.3f} s old)"
        if t1 - t[-1] > cfg.max_age_s:
            return None, f"newest IMU sample is {t1 - t[-1]:.3f} s older than the view (max_age_s {cfg.max_age_s})"
        mean = a.mean(axis=0)
        try:
            g = gravity_from_accelerometer(self.rig, mean)
        except InputError as exc:
            return None, str(exc)
        gaps = [gp for gp in self._gaps if gp[1] > t[0] and gp[0] < t1]
        return ImuGravity(g, mean, len(t), float(t[0]), float(t1), float(a.std()),
                          float(np.max(np.linalg.norm(w, axis=1))), gaps), None
