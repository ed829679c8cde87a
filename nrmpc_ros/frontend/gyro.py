"""The body's rotation between two holds from the gyro: what bridges a break in the landmarks.

When no landmark links a hold to the holds before it, the gyro still saw the
move. Its rate, corrected by its mean over the earlier hold's still part
(the bias, while the body does not turn), is integrated over the move into
the rotation between the two holds' body frames, with a standard deviation
from the samples' own noise (docs/PIPELINE.md, "Bridging a break").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.rig import ImuMount
from ..core.so3 import exp_so3, rotation_angle
from .imu import ImuBuffer

ACCELERATION_SPAN_S = 0.05  # the angular acceleration that bounds a gap's unknown turn is read over this span (s):
# long enough that the gyro's noise (0.002 rad/s per sample) adds little (0.06 rad/s^2), short against a move


@dataclass(frozen=True)
class GyroRotation:
    """The rotation of the body between two holds: ``R`` maps the later hold's body frame into the earlier
    one's (p_before = R p_after); ``sigma_rad`` its angular std; the gyro samples integrated; and the angle the
    rates turn as read, not wrapped at pi (rad: the rates taken for deg/s turn by this times one degree), which
    the images' turn between the holds measures the gyro's unit by (docs/INPUTS.md, units)."""

    R: np.ndarray
    sigma_rad: float
    samples: int
    read_angle_rad: float = math.nan


def ordered_product(Rs: np.ndarray) -> np.ndarray:
    """R_0 R_1 ... R_{n-1} of a stack (n, 3, 3), multiplied pairwise in order (log2 n array products)."""
    Rs = np.asarray(Rs, float)
    while len(Rs) > 1:
        if len(Rs) % 2:
            Rs = np.concatenate([Rs, np.eye(3)[None]])
        Rs = Rs[0::2] @ Rs[1::2]
    return Rs[0] if len(Rs) else np.eye(3)


def rotation_between(buffer: ImuBuffer, mount: ImuMount, still: tuple, move: tuple,
                     max_age_s: float, scale_error: float) -> GyroRotation | None:
    """The body's rotation over ``move`` = (t0, t1) (from the end of one hold to the next), bias-corrected
    with the mean rate over ``still`` = (t0, t1) (the earlier hold's still part). None with an IMU inside a
    camera (it turns with its bar), fewer than two samples in either span, no gyro (every rate exactly 0:
    a message without angular velocity), or the move's samples more than ``max_age_s`` from its ends.

    The std adds the samples' angle random walk (their rate noise while still), the bias's own std over the
    move and ``scale_error`` (the gyro's scale-factor error, a share) of the angle travelled (the integral of
    the rate's magnitude: a move that turns one way and back, or about several axes, travels more than its net
    rotation, and the scale error of each part need not cancel).

    A gap in the samples (:attr:`~.imu.ImuBuffer.gaps`: a link that lost them) is bridged by the mean of the
    rates either side, with what the rate may have done meanwhile as extra noise (:func:`_gap_variance`: the
    rates either side, and the largest angular acceleration the samples show). A short gap in a slow move costs
    nothing; a long one in a fast move leaves a turn whose std says how little is known.
    """
    if mount.mount != "body":
        return None
    ts, _, ws = buffer.window(*still)
    t, _, w = buffer.window(*move)
    if len(ts) < 2 or len(t) < 2 or not np.any(w) or t[0] - move[0] > max_age_s or move[1] - t[-1] > max_age_s:
        return None
    bias = ws.mean(axis=0)
    sigma_w = float(np.sqrt(np.mean(np.var(ws, axis=0))))  # one sample's rate noise (rad/s) while still
    dt = np.diff(t)
    rates = w[:-1] - bias
    gap = _gap_steps(t, buffer.gaps)
    rates[gap] = 0.5 * (w[:-1][gap] + w[1:][gap]) - bias  # across a gap: the mean of the rates either side
    steps = rates * dt[:, None]
    R_imu = ordered_product(exp_so3(steps))
    T = float(t[-1] - t[0])
    regular = dt[~gap]
    travelled = float(np.sum(np.linalg.norm(steps, axis=1)))
    sigma = math.sqrt(sigma_w ** 2 * float(np.sum(regular)) * (float(np.mean(regular)) if len(regular) else 0.0)
                      + (sigma_w / math.sqrt(len(ws)) * T) ** 2 + (scale_error * travelled) ** 2
                      + _gap_variance(t, w, gap))
    M = mount.rotation  # IMU -> body
    degree = math.radians(1.0)
    read = float(rotation_angle(ordered_product(exp_so3(steps * degree)))) / degree
    return GyroRotation(M @ R_imu @ M.T, sigma, len(t), read)




def _gap_steps(t: np.ndarray, gaps: list) -> np.ndarray:
    """Per step between consecutive samples t (n,): whether it spans one of the buffer's gaps (n - 1,)."""
    out = np.zeros(max(len(t) - 1, 0), dtype=bool)
    for before, after in gaps:
        k = int(np.searchsorted(t, before))
        if k + 1 < len(t) and t[k] == before and t[k + 1] == after:
            out[k] = True
    return out


def _gap_variance(t: np.ndarray, w: np.ndarray, gap: np.ndarray) -> float:
    """The variance (rad^2) of the turn over the gaps among the steps of samples (t, w), bridged by the mean of
    the rates either side. Per gap of tau s: the rate may have gone anywhere between those two rates (tau dw)^2
    / 12, and away from both and back at the largest angular acceleration alpha the samples show (over
    :data:`ACCELERATION_SPAN_S`, or 5 sample periods if longer), a turn of up to alpha tau^2 / 4 taken as two
    stds: (alpha tau^2 / 8)^2."""
    if not gap.any():
        return 0.0
    h = max(ACCELERATION_SPAN_S, 5.0 * float(np.median(np.diff(t))))
    j = np.searchsorted(t, t + h, side="right") - 1  # the latest sample within h of each (itself before a gap)
    alpha = float(np.max(np.linalg.norm(w[j] - w, axis=1))) / h
    total = 0.0
    for k in np.flatnonzero(gap):
        tau = float(t[k + 1] - t[k])
        across = float(np.linalg.norm(w[k + 1] - w[k]))
        total += (tau * across) ** 2 / 12.0 + (alpha * tau * tau / 8.0) ** 2
    return total


def gyro_turn(buffer: ImuBuffer, mount: ImuMount, t0: float, t1: float, time_offset_s: float = 0.0,
              max_gap_s: float | None = None) -> np.ndarray | None:
    """The rotation of the frame the IMU is mounted in (the body, or the camera it sits in: it turns with that
    camera's bar) from frame time ``t1`` into frame time ``t0`` (p_t0 = R p_t1, in that frame) from the gyro's
    rate, integrated piecewise-constant over [t0, t1] (each sample's rate held until the next, the newest one's
    up to ``t1``: a frame set reaches the pipeline once the samples before its stamp are in); the IMU's stamps
    plus ``time_offset_s`` are the cameras' clock. None with no gyro (every rate exactly 0), or without a sample
    at or before ``t0`` and one within ``max_gap_s`` (default one sample period, at least 5 ms) of ``t1``: the
    samples do not cover the interval.

    No bias is subtracted: a MEMS gyro's bias (below 0.01 rad/s) turns a camera by less than 0.2 px over a
    frame interval of 1/30 s at 500 px focal length, a fraction of Lucas-Kanade's reach of a quarter window
    (docs/PIPELINE.md, "Performance notes")."""
    if not t1 > t0:
        return None
    gap = max(buffer.period_s if buffer.period_s == buffer.period_s else 0.0, 0.005) \
        if max_gap_s is None else max_gap_s
    a, b = t0 - time_offset_s, t1 - time_offset_s
    t, _, w = buffer.window(a - gap, b + gap)
    if len(t) < 2 or t[0] > a or t[-1] < b - gap or not np.any(w):
        return None
    # the time each sample's rate holds within [a, b]
    dt = np.clip(np.r_[t[1:], b], a, b) - np.clip(t, a, b)
    R_imu = ordered_product(exp_so3(w * dt[:, None]))
    M = mount.rotation  # IMU -> its mount's frame
    return M @ R_imu @ M.T


def camera_turns(R_body: np.ndarray, W0: np.ndarray, W1: np.ndarray) -> np.ndarray:
    """Each camera's rotation between two frame times, f_t1 = R f_t0 (bearings in the camera frame): (M, 3, 3)
    from the body's rotation ``R_body`` (p_t0 = R_body p_t1) and the cameras' bent rotations (camera -> body)
    ``W0`` and ``W1`` (M, 3, 3) at the two times: R = W1^T R_body^T W0."""
    return np.swapaxes(W1, -1, -2) @ R_body.T @ W0


class CameraTurns:
    """Each camera's rotation from one image to its next, from the gyro and the bars: the start of every KLT
    track's search (docs/PIPELINE.md, "Performance notes").

    ``extrinsics`` (:class:`~.extrinsics.FrameExtrinsics`, None without an IMU) names the rig; ``buffer``/
    ``mount`` the gyro; ``bars`` (a :class:`~nrmpc_ros.core.bar_state.BarPropagator` the pipeline feeds every
    IMU sample as it came, no bias subtracted; None: none) the bars' state. :meth:`advance` answers per frame
    set with candidates of each camera's turn: the body's turn seen through the camera's canonical rotation
    and, with ``bars``, through its bent rotations at its two images (the change of the bars' bending: a bar
    that rings turns its camera by tens of pixels between frames while the body is still). The tracker starts
    from the candidate that predicted its tracks best so far (a rig file whose bars do not behave as modelled
    does not mislead it). The bars' state here is its own, driven by the samples alone: not the one whose
    accelerometer bias the estimation stage corrects, so the tracks (and every estimate) do not depend on when
    that stage ran, and the node gives the replay's estimates (the bias moves the static bending, which
    cancels in the change). An IMU inside a camera turns with that camera: its gyro gives that camera's turn, and
    the body's is that turn taken through the camera's rotation at its two images (canonical, or bent as the
    bars' state has it: the IMU's own bar ringing is then taken out; a camera module with an IMU on a bar that
    rings by tens of pixels a frame lost its tracks at every frame of a hold without any prediction). None for
    every camera without an IMU, for a camera's first image, or while the gyro's samples do not cover the
    interval: the trackers then predict from the images alone."""

    def __init__(self, buffer: ImuBuffer, mount: ImuMount | None, extrinsics, num_cameras: int,
                 time_offset_s: float = 0.0, bars=None):
        self.buffer, self.mount, self.extrinsics = buffer, mount, extrinsics
        self.bars = bars if bars is not None and not np.all(bars.rigid) else None
        self.num_cameras = int(num_cameras)
        self.time_offset_s = float(time_offset_s)
        self._stamp = np.full(self.num_cameras, np.nan)  # each camera's previous image (frame set stamp)
        self._taken = np.full(self.num_cameras, np.nan)  # and its own stamp (the bars ring between the two)

    def advance(self, stamp: float, present=None, max_interval_s: float = math.inf, taken=None) -> list:
        """The candidate rotations of each camera (f_now = R f_last) since its previous image, (K, 3, 3), or
        None each; ``present`` (M,) bool: the cameras with an image in this frame set (default all); ``taken``
        (M,): each camera's own image stamp (default the set's; the bars' bending is taken there). None too for
        a camera whose previous image is more than ``max_interval_s`` old: across the gap between two streams
        or snapshots the tracks are not followed but linked by descriptors (a whole move's translation leaves
        the turn's prediction far off, and a wrong KLT link is worse than none)."""
        out = [None] * self.num_cameras
        if self.mount is None or self.extrinsics is None:
            return out
        cams = np.arange(self.num_cameras) if present is None else np.flatnonzero(np.asarray(present, bool))
        now = np.array([float(stamp) if taken is None or taken[i] is None else float(taken[i])
                        for i in range(self.num_cameras)])
        W = self.extrinsics.rig.rotations
        j = None if self.mount.mount == "body" else self.extrinsics.rig.camera_index(self.mount.mount)
        turn = {}  # the IMU mount's turn since each distinct previous stamp
        use = []
        for i in cams:
            t0 = float(self._stamp[i])
            if not stamp - t0 <= max_interval_s:  # (NaN: the camera's first image)
                continue
            if t0 not in turn:
                turn[t0] = gyro_turn(self.buffer, self.mount, t0, stamp, self.time_offset_s)
            if turn.get(t0) is not None:
                use.append(i)
        bent = bent_mount = None
        if use and self.bars is not None and self.bars.ready:
            idx = np.asarray(use)
            q = np.concatenate([self._taken[idx], now[idx]])
            got = self.bars.extrinsics_at(q, np.concatenate([idx, idx]))
            if got is not None:
                bent = dict(zip(use, zip(got[1][: len(idx)], got[1][len(idx):])))
            if got is not None and j is not None:  # the IMU's camera bent at the ends of the gyro's intervals
                ends = np.array([*(self._stamp[i] for i in use), stamp])
                at = self.bars.extrinsics_at(ends, np.full(len(ends), j))
                bent_mount = None if at is None else {float(self._stamp[i]): (at[1][k], at[1][-1])
                                                      for k, i in enumerate(use)}
        for i in use:
            t0 = float(self._stamp[i])
            R = turn[t0] if j is None else W[j] @ turn[t0] @ W[j].T  # the body's turn, canonically
            turns = [camera_turns(R, W[i], W[i])]
            if self.bars is not None:  # and through the bent rotations (the canonical again until the bars know)
                if bent_mount is not None:
                    Wj0, Wj1 = bent_mount[t0]
                    R = Wj0 @ turn[t0] @ Wj1.T  # the IMU camera's turn taken through its bent rotations
                turns.append(camera_turns(R, *bent[i]) if bent is not None else turns[0])
            out[i] = np.stack(turns)
        self._stamp[cams] = stamp
        self._taken[cams] = now[cams]
        return out


__all__ = ["CameraTurns", "GyroRotation", "camera_turns", "gyro_turn", "ordered_product",
           "rotation_between"]
