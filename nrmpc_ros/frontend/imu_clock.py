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
read from; without :data:`MIN_MOVES` moves of the gyro inside the frames (at the
lag found), or with a correlation below ``MIN_CORRELATION``, no offset is
reported.
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
"""The spread of the bent cameras' peak is read finely over this many frame periods either side of it (and coarsely
over the whole range, :func:`_bent_grid_step`): the bars' response lags the body by tens of ms for bars of a few
Hz (see :class:`ImuClockEstimator`), about one frame period of cameras at 10-30 Hz, with half a period to spare."""


FAR_GRID_FRACTION = 0.25
"""Grid of the far search (:meth:`ImuClockEstimator.far_offset`) as a fraction of the median frame interval: the
correlation's peak is as wide as a move's ramps, several frames, so four lags per frame sample it; the peak is
then refined to :data:`LAG_TOLERANCE_S` between its grid neighbours."""

FAR_GRID_MOVE_FRACTION = 0.1
"""... or a tenth of the median move's duration where that is coarser (fast cameras): the correlation's peak is
wider than a move's ramps, which take a good part of the move, so a tenth samples it; a 60 Hz camera's quarter
frame over lags of 10 s either way would be 5000 lags, each a pass over every frame."""

FAR_MIN_MOVING_SHARE = 0.5
"""A far lag is scored only while the IMU's samples cover at least this share of the moving frames shifted by it:
a correlation of the few moves left at the span's ends is a chance one."""

RESAMPLES = 1000
"""Resamples of the recording's moves (each move with the still frames around it) that test the far peak against
its rivals: the Bayesian bootstrap (Rubin 1981), each resample the moves weighted by a flat Dirichlet draw, so a
recording of a few moves is not judged on the draws that leave its telling moves out altogether."""

CONFIDENCE = 0.95
"""The far peak is the clock's when it beats every rival peak at once in this share of the resamples (a one-sided
5 % test, each rival on the frames both lags cover): a regular motion (moves of one length at one period)
correlates almost as well one period off, and only the moves' own differences (axes, sizes) tell the lags apart
(identical moves: 10-50 %). The peak has first beaten every lag in correlation, lag 0 included."""

LAG_RESAMPLES = 200
"""Resamples of the recording's moves (the Bayesian bootstrap, as :data:`RESAMPLES`) whose peak lags give the
offset's standard deviation: the frames of one move share its shape and its ringing, so the spread over frames
would be far too small; 200 resamples know the std to 5 %."""

IMAGE_TIME_FRAMES = 0.1
"""What a frame interval's image motion does not tell of its own time, as a share of the frame period, in every
offset's std: exposure, a rolling shutter's readout and stamp jitter spread an image over part of its period
that no stamp says, and the motion per interval is a mean over it. Rendered recordings (exact bars, the offset
0) read offsets of 0.01-0.09 of a period at 5-30 Hz beyond their spread over the moves."""

BENT_SPREAD_LAGS = 100
"""Lags either side of the bent cameras' peak on which the spread of the peak is read: a hundredth of the
searched span (:data:`FRAME_LAGS` frame periods) resolves a std of a few percent of it."""

SIGNIFICANT_STDS = 2.0
"""An offset is reported as one (:attr:`ClockOffset.significant`) beyond this many of its standard deviations
from zero: slow, smooth moves correlate almost alike over tens of ms of lag, and the peak's place among them says
nothing about the clocks."""

GYRO_MOVE_SIGMAS = 5.0
"""A frame interval holds a move of the gyro when its mean rate stands this many standard deviations (from the
median absolute deviation over the frames) above the median: moves are counted, so a still frame must not pass
by chance (5 sigma: 3e-7 of normal noise, none in a recording), while a move stands hundreds of sigmas out."""

MIN_MOVES = 3
"""Moves the far search needs, and the near one inside the frames: a move and its return (the same axis back)
can line up at a wrong lag by chance, a third move about another axis cannot."""

MOVES_SHOWN_QUANTILE = 0.9
"""The gyro's moves are on camera where the images' median rate over the frames the gyro shows moving exceeds
this quantile of their rate over the frames it shows still. The stills' ringing after a stop stays below it
(except on bars that ring as fast as the rig turns: 1.5 Hz bars, 2 cameras on one bar, no verdict); with an IMU
clock seconds off, the images' own moves fall among the gyro's still frames, more than a tenth of them in a
recording of moves and holds, and the quantile is a move's rate."""

MAX_RIVALS = 8
"""Local maxima outside the peak's lobe that the resamples test it against: the strongest ones."""


@dataclass(frozen=True)
class ClockOffset:
    """The IMU clock offset found (s, to add to the IMU's stamps), the correlation at its peak, frames used, the
    offset's standard deviation (s) and the moves.

    The std is the spread of the peak over resampled moves (:data:`LAG_RESAMPLES`), the images' own timing
    (:data:`IMAGE_TIME_FRAMES`) and, on a rig whose bars bend where their modelled response did not explain the
    images better than the body's turn alone (no IMU in the rig file, bars it describes otherwise than they
    ring), the slowest bar's response time
    1 / (2 pi f): the images turn with the bars, which lead the body while they follow its acceleration and lag it
    while they ring, by up to that time, and a peak within it tells the clocks apart no better."""

    offset_s: float
    correlation: float
    frames: int
    std_s: float
    moves: int

    @property
    def significant(self) -> bool:
        """Whether the offset stands out of its spread (:data:`SIGNIFICANT_STDS`): a smaller one is no evidence
        that the clocks differ, and no advice to shift them."""
        return abs(self.offset_s) > SIGNIFICANT_STDS * self.std_s


@dataclass(frozen=True)
class FarClockOffset:
    """The IMU clock offset of the far search (s, to add to the IMU's stamps): the correlation of the cameras'
    image motion with its prediction at the peak, the best rival's outside the peak's lobe (-1: none), the share
    of resamples of the moves in which the peak beat every rival, and the moves (runs of moving frames) used."""

    offset_s: float
    correlation: float
    rival_correlation: float
    confidence: float
    moves: int

    @property
    def unique(self) -> bool:
        """Whether the moves single the lag out (:data:`CONFIDENCE`) with the shared motion explaining the images
        (:data:`MIN_CORRELATION`)."""
        return self.confidence >= CONFIDENCE and self.correlation >= MIN_CORRELATION


class ImuClockEstimator:
    """Collects the IMU and the images' motion per camera and frame set; :meth:`estimate` gives the offset.

    With a ``rig`` whose bars bend, the images move with the bent cameras, which lag the body by the bars'
    response: the gyro's rate alone would read that lag as a clock offset (tens of ms for bars of a few Hz).
    The estimate is then refined against each camera's predicted rotation over each frame interval, the
    body's (the gyro integrated) plus the change of its bar's bend (:class:`~nrmpc_ros.core.bar_state.
    BarPropagator` on the shifted IMU stream), across the camera's optical axis (the rotation the image
    shows as motion), over every lag of the range: the images of ringing bars move twice per period of the bars,
    and their correlation with the prediction peaks that often, so the peak next to the body's lag need not be the
    clock's (cameras that record only the holds see nothing but ringing, and a lag of a few tens of ms lines the
    gyro's stops up with it).
    """

    def __init__(self, rig=None):
        self.rig = rig
        self._imu: deque = deque(maxlen=KEEP_IMU_SAMPLES)  # (t, ax, ay, az, wx, wy, wz)
        self._frames: deque = deque(maxlen=KEEP_FRAMES)  # (t_prev, t, rate of each camera rad/s (NaN: none),
        # signed (x, y) motion of each camera rad/s (NaN: none))
        self._added = 0  # samples and frames added: the last estimate holds while no more came
        self._estimated: tuple = (-1, None)

    def add_imu(self, t: float, gyro, accel=(0.0, 0.0, 0.0)) -> None:
        (ax, ay, az), (wx, wy, wz) = accel, gyro
        self._imu.append((float(t), float(ax), float(ay), float(az), float(wx), float(wy), float(wz)))
        self._added += 1

    def add_frame(self, t_prev: float, t: float, image_rates, image_shifts=None) -> None:
        """Frame interval [t_prev, t] over which camera i's image moved by image_rates[i] (rad/s; NaN: unknown);
        optionally the image's signed motion image_shifts[i] = (x, y) (the tracks' median shift over the focal
        length and the interval, rad/s; NaN: unknown), which tells the turns' axes and senses apart."""
        r = np.asarray(image_rates, dtype=float).reshape(-1)
        shifts = np.full((len(r), 2), np.nan) if image_shifts is None else \
            np.asarray(image_shifts, dtype=float).reshape(len(r), 2)
        if t > t_prev and np.isfinite(r).any():
            self._frames.append((float(t_prev), float(t), r, shifts))
            self._added += 1

    def _collected(self) -> tuple:
        """(IMU rows sorted by stamp (N, 7), their stamps, frame starts (F,), ends (F,), image rates (F, M), signed
        motion (F, M, 2))."""
        imu = np.array(self._imu)
        imu = imu[np.argsort(imu[:, 0], kind="stable")]
        frames = list(self._frames)
        return (imu, imu[:, 0], np.array([f[0] for f in frames]), np.array([f[1] for f in frames]),
                np.array([f[2] for f in frames]), np.array([f[3] for f in frames]))

    def estimate(self) -> ClockOffset | None:
        """The lag within :data:`MAX_LAG_S` (module docstring), or None; computed again only once samples or
        frames were added (a replay asks for it to apply it and again to report it)."""
        if self._estimated[0] != self._added:
            self._estimated = (self._added, self._estimate())
        return self._estimated[1]

    def _estimate(self) -> ClockOffset | None:
        if len(self._imu) < MIN_IMU_SAMPLES or len(self._frames) < MIN_MOVING_FRAMES:
            return None
        imu, t, a, b, y, _ = self._collected()
        inside = (a - MAX_LAG_S >= t[0]) & (b + MAX_LAG_S <= t[-1])
        a, b, y = a[inside], b[inside], y[inside]
        med = np.nanmedian(y, axis=1) if len(y) else np.zeros(0)
        ok = np.isfinite(med)
        moving = med[ok] > np.median(med[ok]) + MOVE_MADS * _mad(med[ok]) if ok.any() else np.zeros(0, bool)
        if ok.sum() < MIN_MOVING_FRAMES or np.count_nonzero(moving) < MIN_MOVING_FRAMES:
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
        bent = self._rotations(imu)[1] if self.rig is not None and self.rig.imu is not None else None
        pred, meas = x[:, :, None], m_[:, None]  # the rates lined up at each lag, for the lag's spread
        bars_unexplained = self.rig is not None and self.rig.is_flexible
        if bent is not None:
            from scipy.optimize import minimize_scalar

            axis, span = self.rig.rotations[:, :, 2], FRAME_LAGS * np.median(b - a)
            # every lag of the range: the images' ringing makes the bent cameras' correlation peak again every half
            # period of the bars, so the peak near the body's lag need not be the clock's
            step = _bent_grid_step(self.rig, float(np.median(b - a)))
            grid = np.arange(-MAX_LAG_S, MAX_LAG_S + step / 2, step)
            k = int(np.argmax([_camera_correlation(bent, t, a, b, y, axis, d) for d in grid]))
            res = minimize_scalar(lambda d: -_camera_correlation(bent, t, a, b, y, axis, d), method="bounded",
                                  bounds=(grid[k] - step, grid[k] + step), options={"xatol": LAG_TOLERANCE_S})
            if -float(res.fun) > best:  # the bent cameras explain the images better than the body alone
                lag, best, bars_unexplained = float(res.x), -float(res.fun), False
                # the spread over the whole range (a rival peak the resamples prefer is part of it), finely near
                lags = np.union1d(grid, np.arange(lag - span, lag + span, max(LAG_STEP_S, span / BENT_SPREAD_LAGS)))

                def pred(d):
                    return _across_rates(_interp_rows(b_ + d, t, bent) - _interp_rows(a_ + d, t, bent), axis, b_ - a_)
                meas = y[ok]
        if best < MIN_CORRELATION:
            return None
        segment, moves = _move_segments(_gyro_moving(t, integral, a_, b_, lag))
        if min(moves, _move_segments(_gyro_moving(t, integral, a_, b_, 0.0))[1]) < MIN_MOVES:
            return None
        spread = math.hypot(_lag_spread(lags, pred, meas, segment, moves),
                            IMAGE_TIME_FRAMES * float(np.median(b_ - a_)))
        if bars_unexplained:  # the bars' response, not modelled, moves the peak by up to their response time
            from ..core.dynamics import bar_natural_frequencies

            spread = math.hypot(spread, 1.0 / (2.0 * math.pi * float(np.min(bar_natural_frequencies(self.rig)))))
        return ClockOffset(offset_s=-float(lag), correlation=best, frames=int(len(a)), std_s=spread, moves=moves)

    def far_offset(self, max_offset_s: float) -> FarClockOffset | None:
        """The IMU clock offset searched over lags of up to ``max_offset_s`` either way (an IMU stamped by another
        clock), from each camera's signed image motion (x and y; where the frames carry none, its rate across the
        optical axis) against the motion the IMU predicts in that camera: the moves' axes and senses tell moves of
        the same speed apart, which the rates' magnitudes alone hardly do (0.75-0.85 one hold-and-move period off
        against 0.76-0.99 at the right lag on regular motion; signed, 0.13-0.29 against 0.73-0.88). The
        prediction is the body's turn (the gyro integrated) and, on a rig whose bars bend, also each bar's change
        of bend (:class:`~nrmpc_ros.core.bar_state.BarPropagator` over the samples once, read at the shifted
        stamps): whichever correlates better at its peak (a rig file's bars that do not ring as the images do
        predict worse than the body alone). The correlation's sums are kept move by move, so resampling the moves
        (:data:`RESAMPLES`, a seeded generator) tests the peak against its rivals without recomputing a lag: the
        misfit each move adds at a rival lag beyond the peak's, summed over the resampled moves, must be
        positive.
        The bars' fine lag (ms) is left to :meth:`estimate`. None without a rig file's IMU mount, or without
        :data:`MIN_MOVING_FRAMES` moving frames in :data:`MIN_MOVES` moves and :data:`MIN_IMU_SAMPLES`
        samples."""
        rig = self.rig
        if rig is None or rig.imu is None or len(self._imu) < MIN_IMU_SAMPLES or len(self._frames) < MIN_MOVING_FRAMES:
            return None
        imu, t, a, b, y, shifts = self._collected()
        med = np.nanmedian(y, axis=1)
        ok = np.isfinite(med)
        a, b, y, shifts, med = a[ok], b[ok], y[ok], shifts[ok], med[ok]
        moving = med > np.median(med) + MOVE_MADS * _mad(med) if len(med) else np.zeros(0, bool)
        if moving.sum() < MIN_MOVING_FRAMES:
            return None
        segment, moves = _move_segments(moving)
        if moves < MIN_MOVES:
            return None
        signed = np.count_nonzero(np.isfinite(shifts).all(axis=2).any(axis=1) & moving) >= MIN_MOVING_FRAMES
        if signed:  # each camera's signed motion, two channels per camera
            y = shifts.reshape(len(shifts), -1)
        body, bent = self._rotations(imu)
        series = {"body": body} if bent is None else {"body": body, "bent": bent}
        axis, to_camera = rig.rotations[:, :, 2], np.swapaxes(rig.rotations, -1, -2)

        def predicted(turn, dt):
            """The image motion the cameras' rotations ``turn`` (K, M or 1, 3; body frame) over ``dt`` (K,) give:
            signed (K, 2M; a camera turned by theta about its own y axis sees the scene shift by -theta in x, about
            its x axis by +theta in y) or across the optical axes (K, M)."""
            if not signed:
                return _across_rates(turn, axis, dt)
            cam = np.einsum("mij,kmj->kmi", to_camera, np.broadcast_to(turn, (len(turn), len(axis), 3)))
            return np.stack([-cam[..., 1], cam[..., 0]], axis=2).reshape(len(turn), -1) / dt[:, None]

        def covered(lag: float) -> np.ndarray:
            return (a + lag >= t[0]) & (b + lag <= t[-1])

        def sums(rotation, lag: float, inside=None) -> np.ndarray | None:
            """(moves, 6) sums n, x, y, xx, yy, xy of predicted against measured rates at ``lag`` over the frames
            ``inside`` (default: those the samples cover at that lag), or None where the samples cover too few of
            the moving frames."""
            inside = covered(lag) if inside is None else inside
            if np.count_nonzero(inside & moving) < FAR_MIN_MOVING_SHARE * np.count_nonzero(moving):
                return None
            turn = _interp_rows(b[inside] + lag, t, rotation) - _interp_rows(a[inside] + lag, t, rotation)
            x = predicted(turn, (b - a)[inside])
            yy = y[inside]
            use = np.isfinite(yy)
            x, yy = np.where(use, x, 0.0), np.where(use, yy, 0.0)
            cols = np.stack([use.sum(1), x.sum(1), yy.sum(1), (x * x).sum(1), (yy * yy).sum(1), (x * yy).sum(1)], 1)
            out = np.zeros((moves, 6))
            np.add.at(out, segment[inside], cols)
            return out

        def scan(rotation, lags):
            stats = [sums(rotation, float(lag)) for lag in lags]
            return stats, np.array([_from_sums(s.sum(0)) if s is not None else -np.inf for s in stats])

        durations = [b[segment == i][moving[segment == i]].max() - a[segment == i][moving[segment == i]].min()
                     for i in range(moves)]
        step = max(FAR_GRID_FRACTION * float(np.median(b - a)), FAR_GRID_MOVE_FRACTION * float(np.median(durations)))
        lags = np.arange(-max_offset_s, max_offset_s + step / 2, step)
        scans = {name: scan(rotation, lags) for name, rotation in series.items()}
        name = max(scans, key=lambda n: np.max(scans[n][1]))
        stats, corr = scans[name]
        k = int(np.argmax(corr))
        if not np.isfinite(corr[k]):
            return None
        lo, hi = k, k  # the peak's lobe: down to half its correlation either way
        while lo > 0 and corr[lo - 1] > corr[k] / 2:
            lo -= 1
        while hi < len(corr) - 1 and corr[hi + 1] > corr[k] / 2:
            hi += 1
        peaks = [i for i in range(len(corr)) if (i < lo or i > hi) and np.isfinite(corr[i])
                 and corr[i] >= corr[max(i - 1, 0)] and corr[i] >= corr[min(i + 1, len(corr) - 1)]]
        rivals = sorted(peaks, key=lambda i: -corr[i])[:MAX_RIVALS]
        confidence = 1.0
        if rivals:  # each move's misfit at a rival lag less at the peak (the frames both lags cover), resampled
            weights = np.random.default_rng(0).dirichlet(np.ones(moves), size=RESAMPLES)  # (B, moves)
            gain = []
            for i in rivals:
                both = covered(float(lags[k])) & covered(float(lags[i]))
                at_peak, at_rival = sums(series[name], float(lags[k]), both), sums(series[name], float(lags[i]), both)
                if at_peak is not None and at_rival is not None:
                    gain.append(weights @ (_misfits(at_rival) - _misfits(at_peak)))
            confidence = float(np.mean(np.min(gain, axis=0) > 0)) if gain else 1.0
        from scipy.optimize import minimize_scalar

        def neg(lag):
            st = sums(series[name], float(lag))
            return -_from_sums(st.sum(0)) if st is not None else 1.0

        res = minimize_scalar(neg, method="bounded", bounds=(lags[k] - step, lags[k] + step),
                              options={"xatol": LAG_TOLERANCE_S})
        lag, best = (float(res.x), -float(res.fun)) if -float(res.fun) >= corr[k] else (float(lags[k]), float(corr[k]))
        return FarClockOffset(offset_s=-lag, correlation=best,
                              rival_correlation=float(corr[rivals[0]]) if rivals else -1.0,
                              confidence=confidence, moves=moves)

    def moving_rates(self) -> tuple | None:
        """What the frames the gyro shows moving (:data:`GYRO_MOVE_SIGMAS`) say of its size, its stamps as they
        are: each camera's image rate (F, M; rad/s, NaN: none), the rate the body's turn (the gyro integrated)
        predicts across that camera's optical axis (F, M), each frame's move (F,) and the number of moves. None
        without a rig file's IMU mount, without :data:`MIN_MOVING_FRAMES` such frames in :data:`MIN_MOVES` moves,
        or where the images do not move where the gyro does (:data:`MOVES_SHOWN_QUANTILE`): moves the frames do
        not show at the gyro's stamps (an IMU clock seconds off) would read the holds' images against the moves'
        rates."""
        rig = self.rig
        if rig is None or rig.imu is None or len(self._imu) < MIN_IMU_SAMPLES or len(self._frames) < MIN_MOVING_FRAMES:
            return None
        imu, t, a, b, y, _ = self._collected()
        inside = (a >= t[0]) & (b <= t[-1]) & np.isfinite(y).any(axis=1)
        a, b, y = a[inside], b[inside], y[inside]
        if not len(a):
            return None
        w = np.linalg.norm(imu[:, 4:7], axis=1)
        integral = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
        moving = _gyro_moving(t, integral, a, b, 0.0)
        segment, moves = _move_segments(moving)
        if np.count_nonzero(moving) < MIN_MOVING_FRAMES or moves < MIN_MOVES:
            return None
        body = _body_turn(rig, imu)
        turn = (_interp_rows(b, t, body) - _interp_rows(a, t, body))[:, None, :]
        pred = _across_rates(turn, rig.rotations[:, :, 2], b - a)
        med = np.nanmedian(y, axis=1)
        if not np.median(med[moving]) > np.quantile(med[~moving], MOVES_SHOWN_QUANTILE, method="linear"):
            return None  # the images do not move where the gyro does
        return y[moving], pred[moving], segment[moving], moves

    def _rotations(self, imu) -> tuple:
        """Each camera's rotation since the first sample at every IMU sample, body frame: the body's turn (the
        gyro integrated; (N, 1, 3)) and, on a rig whose bars bend, with each bar's bend added ((N, M, 3); the bars
        driven by the samples as stamped, :class:`~nrmpc_ros.core.bar_state.BarPropagator`), else None. A lag
        reads both at shifted stamps: the bars' response to the IMU does not depend on the clock it is read in.
        An IMU inside a camera on a flexible bar reads its own tip's motion: the propagator turns its readings
        into the body's through that bar's model (:mod:`~nrmpc_ros.core.tip_imu`); driven by the raw readings
        the bars rang as nothing does, and their prediction, scanned over seconds of lags, found chance peaks in
        that ringing (a false offset of 4.7 s). The body's turn here is the tip gyro's, bending rate included
        (the rates are the body's about, not exactly)."""
        rig = self.rig
        t = imu[:, 0]
        body = _body_turn(rig, imu)
        if not rig.is_flexible:
            return body[:, None, :], None
        from ..core.bar_state import BarPropagator
        from ..core.deformation import bend_rotation_vectors

        prop = BarPropagator(rig, history_s=math.inf)
        for row in imu.tolist():
            prop.add_imu(row[0], row[1:4], row[4:7])
        x = prop.loads_at(t)
        if x is None:
            return body[:, None, :], None
        M = rig.num_cameras
        phi = bend_rotation_vectors(rig, x.reshape(-1, 3)).reshape(len(t), M, M, 3)[:, np.arange(M), np.arange(M)]
        return body[:, None, :], body[:, None, :] + phi


def _camera_correlation(rotation, t, a, b, y, axis, lag: float) -> float:
    """Correlation of the images' rates ``y`` (F, M) over the frame intervals [a, b] with each camera's rate across
    its optical axis ``axis`` from its ``rotation`` at the IMU's stamps ``t`` (:meth:`ImuClockEstimator.
    _rotations`), the IMU lagging by ``lag``."""
    turn = _interp_rows(b + lag, t, rotation) - _interp_rows(a + lag, t, rotation)
    pred = _across_rates(turn, axis, b - a)
    ok = np.isfinite(y)
    return float(_correlation(pred[ok][None], y[ok])[0])


def _lag_spread(lags, pred, meas, segment, moves: int) -> float:
    """Standard deviation (s) of the peak lag of the correlation of the predicted rates ``pred`` (L lags, F frames,
    K channels; or a function of the lag giving (F, K)) with the measured ``meas`` (F, K; NaN: none) over resamples
    of the moves (each frame's move ``segment``), from the moves' sums."""
    use = np.isfinite(meas)
    meas = np.where(use, meas, 0.0)
    onehot = np.eye(moves)[segment]  # (F, moves)
    fixed = np.stack([use.sum(1) @ onehot, meas.sum(1) @ onehot, (meas * meas).sum(1) @ onehot])  # (3, moves)
    per_move = np.empty((len(lags), moves, 6))
    per_move[:, :, 0], per_move[:, :, 2], per_move[:, :, 4] = fixed
    for i, d in enumerate(lags):  # lags, not frames: each a pass over the frames
        p = np.where(use, pred(d) if callable(pred) else pred[i], 0.0)
        per_move[i, :, 1], per_move[i, :, 3], per_move[i, :, 5] = \
            p.sum(1) @ onehot, (p * p).sum(1) @ onehot, (p * meas).sum(1) @ onehot
    weights = np.random.default_rng(0).dirichlet(np.ones(moves), size=LAG_RESAMPLES) * moves
    peaks = lags[np.argmax(_from_sums(np.einsum("bm,lmk->blk", weights, per_move)), axis=1)]
    return float(np.std(peaks))


def _bent_grid_step(rig, frame_s: float) -> float:
    """Grid (s) of the bent cameras' lag search: an eighth of the shorter of a frame interval and half the fastest
    bar's period (the images' rate peaks twice per period of a ringing bar), so that no peak falls between two
    lags; never finer than :data:`LAG_STEP_S`."""
    from ..core.dynamics import bar_natural_frequencies

    f = bar_natural_frequencies(rig)
    f = f[np.isfinite(f)]
    half_period = 0.5 / float(f.max()) if len(f) else math.inf
    return max(LAG_STEP_S, min(frame_s, half_period) / 8.0)


def _gyro_moving(t, integral, a, b, lag: float) -> np.ndarray:
    """Whether the gyro moves inside each frame interval [a, b] read at ``lag``: its mean rate over the interval
    (from the rate's ``integral`` at the IMU's stamps ``t``) stands :data:`GYRO_MOVE_SIGMAS` above the median.
    Images that move while the gyro holds still (bars ringing after a stop, in recordings whose cameras skip the
    moves) correlate with the ends of the gyro's moves shifted into them: a lag is read only from moves the frames
    show both as stamped and at the lag (a true lag of a fraction of a move leaves the moves inside the frames
    either way)."""
    x = (np.interp(b + lag, t, integral) - np.interp(a + lag, t, integral)) / (b - a)
    return x > np.median(x) + GYRO_MOVE_SIGMAS * 1.4826 * _mad(x) if len(x) else np.zeros(0, bool)


def _across_rates(rot, axis, dt):
    """(F, M) image rates (rad/s): the small rotations ``rot`` (F, M or 1, 3) of the cameras over intervals ``dt``
    (F,), across each camera's optical axis ``axis`` (M, 3; the part an image shows as motion)."""
    across = rot - np.sum(rot * axis[None], axis=2, keepdims=True) * axis[None]
    return np.linalg.norm(across, axis=2) / dt[:, None]


def _body_turn(rig, imu) -> np.ndarray:
    """The body's rotation vector since the first of the IMU rows ``imu`` (N, 7) at each (N, 3): the gyro's
    body-frame rate (an IMU in a camera: about, not exactly) integrated by the trapezoid rule."""
    t = imu[:, 0]
    g = imu[:, 4:7] @ _imu_to_body(rig).T
    return np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(t)[:, None], axis=0)])


def _imu_to_body(rig) -> np.ndarray:
    """The IMU's axes in the body: its mount's rotation, through its camera's unbent rotation for an IMU inside a
    camera (that camera turns with its bar as well: the rates are the body's about, not exactly)."""
    mount = rig.imu
    if mount.mount == "body":
        return mount.rotation
    return rig.rotations[rig.camera_index(mount.mount)] @ mount.rotation


def _interp_rows(q, t, v):
    """``v`` (N, ..., 3) sampled at ``t`` (N,), linearly interpolated at ``q`` (K,): (K, ..., 3)."""
    k = np.clip(np.searchsorted(t, q, side="right") - 1, 0, len(t) - 2)
    w = ((q - t[k]) / np.maximum(t[k + 1] - t[k], 1e-300)).reshape((-1,) + (1,) * (v.ndim - 1))
    return v[k] * (1.0 - w) + v[k + 1] * w


def _move_segments(moving):
    """Each frame's move (0..n-1) for ``moving`` (F,) bool in time order: a move's run of moving frames with the
    still frames up to halfway to the next move's; and n."""
    starts = np.flatnonzero(moving & ~np.r_[False, moving[:-1]])
    ends = np.flatnonzero(moving & ~np.r_[moving[1:], False])
    bounds = (ends[:-1] + starts[1:] + 1) // 2  # first frame of each later move's segment
    return np.searchsorted(bounds, np.arange(len(moving)), side="right"), len(starts)


def _misfits(s) -> np.ndarray:
    """Each move's squared residual (moves,) of the line y = alpha x + beta fitted to all moves at once, from the
    moves' sums (moves, 6) n, x, y, xx, yy, xy: one gain for the whole recording, so a lag that lines one move
    up with another move's shape is not refitted move by move."""
    n, x, y, xx, yy, xy = s.sum(0)
    vx = xx - x * x / max(n, 1.0)
    alpha = (xy - x * y / max(n, 1.0)) / vx if vx > 0 else 0.0
    beta = (y - alpha * x) / max(n, 1.0)
    n, x, y, xx, yy, xy = s.T
    return yy - 2 * alpha * xy - 2 * beta * y + alpha * alpha * xx + 2 * alpha * beta * x + beta * beta * n


def _from_sums(s):
    """Pearson correlation from sums (..., 6) n, x, y, xx, yy, xy."""
    n, x, y, xx, yy, xy = np.moveaxis(np.asarray(s, float), -1, 0)
    n = np.maximum(n, 1.0)
    cov = xy - x * y / n
    var = np.maximum(xx - x * x / n, 0.0) * np.maximum(yy - y * y / n, 0.0)
    return cov / np.maximum(np.sqrt(var), 1e-300)


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


__all__ = ["ClockOffset", "FarClockOffset", "ImuClockEstimator", "MAX_LAG_S", "MIN_CORRELATION"]
