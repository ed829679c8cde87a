"""The IMU's clock against the cameras': the lag that best lines the gyro's rate up with the images' motion.

While the rig turns, the image of every camera moves by about f |omega_perp| dt
pixels per frame; the tracks' median motion per frame (over the cameras, in
radians: motion / focal length / frame interval) is therefore a copy of the
gyro's rate |omega| averaged over each frame interval. The offset is the lag
delta that maximises the correlation between the images' rate at frame k and
the gyro's rate averaged over [t_{k-1} + delta, t_k + delta] (the gyro's rate
integrated once, then read at the shifted bounds: exact for any lag, so the
lag is found to well below a frame period). A gyro stamped late by d peaks at
delta = d; the clock offset to add to the IMU's stamps (``imu_time_offset_s``)
is -d. Holds add nothing (neither moves) and moves give the edges the lag is
read from; without moves, or with a correlation below ``MIN_CORRELATION``, no
offset is reported.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

MAX_LAG_S = 0.25
"""Lags searched (s, either way). A clock offset is a stamping or transport delay of a few frame periods at most
(a 30 Hz camera's period is 33 ms); stamps further off are a configuration error (another clock), not a lag, and
a wider window would only let a periodic move alias into a false peak."""

LAG_STEP_S = 0.0005
"""Grid of the lag search (s): half the period of a 1 kHz IMU, the finest stream this front end serves, so the
grid does not round the lag coarser than the IMU resolves it; the peak is refined by a parabola through its
neighbours (:func:`_parabola`)."""

LAG_TOLERANCE_S = 1e-4
"""The bent cameras' refinement stops when the lag is known to this (s): a fifth of :data:`LAG_STEP_S`, below what
the parabola through the grid resolves."""

MIN_CORRELATION = 0.5
"""Below this correlation the images and the gyro do not tell the same motion (no estimate). Two rates that share
a move correlate near 1 at the right lag; 0.5 means the shared motion explains only a quarter of the images'
variance (r^2), the rest being tracking noise and ringing: a lag read from that is not the clock's."""

MIN_MOVING_FRAMES = 10
"""Frames whose image motion stands above the ringing's (:data:`MOVE_MADS`) before an offset is looked for: the
correlation of fewer frames is dominated by the noise of each (its std is about 1/sqrt(n - 3))."""

MIN_IMU_SAMPLES = 10
"""IMU samples needed before an offset is looked for: enough to integrate the gyro over a move at all."""

MOVE_MADS = 3.0
"""A frame moves when the images' median rate is this many median absolute deviations above the median over the
frames (unscaled MADs: about 2 standard deviations of normal noise), the frames of holds, which ring, below."""

KEEP_IMU_SAMPLES = 60_000
"""The newest IMU samples kept: 1 min at 1 kHz, 5 min at 200 Hz; enough moves for the correlation, a bounded
memory and search cost."""

KEEP_FRAMES = 5_000
"""The newest frame intervals kept: over 2 min at 30 Hz, so the frames cover at least the IMU samples kept at
1 kHz."""

FRAME_LAGS = 1.5
"""The bent cameras' refinement searches this many frame periods around the gyro's lag: the bars' response lags
the body by tens of ms for bars of a few Hz (see :class:`ImuClockEstimator`), about one frame period of cameras at
10-30 Hz, searched with half a period to spare."""


@dataclass(frozen=True)
class ClockOffset:
    """The IMU clock offset found (s, to add to the IMU's stamps), the correlation at its peak, frames used."""

    offset_s: float
    correlation: float
    frames: int


class ImuClockEstimator:
    """Collects the IMU and the images' motion per camera and frame set; :meth:`estimate` gives the offset.

    With a ``rig`` whose bars bend, the images move with the bent cameras, which lag the body by the bars'
    response: the gyro's rate alone would read that lag as a clock offset (tens of ms for bars of a few Hz).
    The estimate is then refined against each camera's predicted rotation over each frame interval, the
    body's (the gyro integrated) plus the change of its bar's bend (:class:`~nrmpc_ros.core.bar_state.
    BarPropagator` on the shifted IMU stream), across the camera's optical axis (the rotation the image
    shows as motion).
    """

    def __init__(self, rig=None):
        self.rig = rig
        self._imu: deque = deque(maxlen=KEEP_IMU_SAMPLES)  # (t, ax, ay, az, wx, wy, wz)
        self._frames: deque = deque(maxlen=KEEP_FRAMES)  # (t_prev, t, rate of each camera rad/s (NaN: none))

    def add_imu(self, t: float, gyro, accel=(0.0, 0.0, 0.0)) -> None:
        (ax, ay, az), (wx, wy, wz) = accel, gyro
        self._imu.append((float(t), float(ax), float(ay), float(az), float(wx), float(wy), float(wz)))

    def add_frame(self, t_prev: float, t: float, image_rates) -> None:
        """Frame interval [t_prev, t] over which camera i's image moved by image_rates[i] (rad/s; NaN: unknown)."""
        r = np.asarray(image_rates, dtype=float).reshape(-1)
        if t > t_prev and np.isfinite(r).any():
            self._frames.append((float(t_prev), float(t), r))

    def estimate(self) -> ClockOffset | None:
        if len(self._imu) < MIN_IMU_SAMPLES or len(self._frames) < MIN_MOVING_FRAMES:
            return None
        imu = np.array(self._imu)
        imu = imu[np.argsort(imu[:, 0], kind="stable")]
        t = imu[:, 0]
        a = np.array([f[0] for f in self._frames])
        b = np.array([f[1] for f in self._frames])
        y = np.array([f[2] for f in self._frames])  # (F, M)
        inside = (a - MAX_LAG_S >= t[0]) & (b + MAX_LAG_S <= t[-1])
        a, b, y = a[inside], b[inside], y[inside]
        med = np.nanmedian(y, axis=1) if len(y) else np.zeros(0)
        ok = np.isfinite(med)
        moving = np.count_nonzero(med[ok] > np.median(med[ok]) + MOVE_MADS * _mad(med[ok])) if ok.any() else 0
        if ok.sum() < MIN_MOVING_FRAMES or moving < MIN_MOVING_FRAMES:
            return None  # no move the images and the gyro could both show
        # The gyro's rate integrated once: its mean over any shifted interval, for every lag at once.
        w = np.linalg.norm(imu[:, 4:7], axis=1)
        integral = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
        lags = np.arange(-MAX_LAG_S, MAX_LAG_S + LAG_STEP_S / 2, LAG_STEP_S)
        a_, b_, m_ = a[ok], b[ok], med[ok]
        x = (np.interp(b_[None] + lags[:, None], t, integral) - np.interp(a_[None] + lags[:, None], t, integral)) \
            / (b_ - a_)[None]
        corr = _correlation(x, m_)
        k = int(np.argmax(corr))
        lag = _parabola(lags, corr, k)
        best = float(corr[k])
        if self.rig is not None and self.rig.is_flexible and self.rig.imu is not None:
            from scipy.optimize import minimize_scalar

            res = minimize_scalar(lambda d: -self._camera_correlation(imu, a, b, y, d), method="bounded",
                                  bounds=(lag - FRAME_LAGS * np.median(b - a), lag + FRAME_LAGS * np.median(b - a)),
                                  options={"xatol": LAG_TOLERANCE_S})
            lag, best = float(res.x), -float(res.fun)
        if best < MIN_CORRELATION:
            return None
        return ClockOffset(offset_s=-float(lag), correlation=best, frames=int(len(a)))

    def _camera_correlation(self, imu, a, b, y, lag: float) -> float:
        """Correlation of the images' rates with each bent camera's predicted rate, the IMU lagging by ``lag``."""
        from ..core.bar_state import BarPropagator
        from ..core.deformation import bend_rotation_vectors

        rig = self.rig
        prop = BarPropagator(rig, imu_time_offset_s=-lag, history_s=math.inf)
        for row in imu.tolist():
            prop.add_imu(row[0], row[1:4], row[4:7])
        q = np.concatenate([a, b])
        x = prop.loads_at(q)
        if x is None:
            return -1.0
        M = rig.num_cameras
        phi = bend_rotation_vectors(rig, x.reshape(-1, 3)).reshape(len(q), M, M, 3)[:, np.arange(M), np.arange(M)]
        t = imu[:, 0] - lag
        g = imu[:, 4:7] @ rig.imu.rotation.T  # body-frame rate (an IMU in a camera: about, not exactly)
        cum = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(t)[:, None], axis=0)])
        turn = np.stack([np.interp(b, t, cum[:, j]) - np.interp(a, t, cum[:, j]) for j in range(3)], axis=1)
        rot = turn[:, None, :] + phi[len(a):] - phi[:len(a)]  # (F, M, 3) small rotations over the intervals
        axis = rig.rotations[:, :, 2]  # optical axes in the body
        across = rot - np.sum(rot * axis[None], axis=2, keepdims=True) * axis[None]
        pred = np.linalg.norm(across, axis=2) / (b - a)[:, None]
        ok = np.isfinite(y)
        return float(_correlation(pred[ok][None], y[ok])[0])


def _correlation(x, y):
    """Pearson correlation of each row of x (L, F) with y (F,)."""
    xc = x - x.mean(axis=1, keepdims=True)
    yc = y - y.mean()
    return (xc @ yc) / np.maximum(np.linalg.norm(xc, axis=1) * np.linalg.norm(yc), 1e-300)


def _parabola(lags, corr, k) -> float:
    """The peak's lag refined by a parabola through it and its neighbours."""
    lag = float(lags[k])
    if 0 < k < len(lags) - 1:
        c0, c1, c2 = corr[k - 1:k + 2]
        den = c0 - 2 * c1 + c2
        if den < 0:
            lag += 0.5 * (lags[1] - lags[0]) * (c0 - c2) / den
    return lag


def _mad(v) -> float:
    return float(np.median(np.abs(v - np.median(v))))


__all__ = ["ClockOffset", "ImuClockEstimator", "MAX_LAG_S", "MIN_CORRELATION"]
