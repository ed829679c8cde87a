"""Holds: the intervals in which the rig is still, measured from their settled frames (docs/PIPELINE.md, "Holds").

A :class:`HoldRecorder` collects, camera by camera, the track positions of
every frame of one hold (tracked from the hold's anchor frame, see
:class:`~nrmpc_ros.frontend.tracking.KltTracker`). :meth:`HoldRecorder.measure`
then keeps only the settled part:

- the bars ring after the rig stops: the settled part starts at least
  ``settle_periods`` periods of the slowest bar (sqrt(3 EI / (m L^3)) / (2 pi),
  from the rig file) after the hold started, and
- every camera's image offset from the hold's rest position (the median over
  the later frames of the median track displacement from the anchor) is at
  most ``max(settle_px, settle_noise x its frame-to-frame noise)``; the
  longest run of such frames is the settled part;
- bars that still ring when the hold ends (lightly damped bars, short holds)
  give no such frames: then the settled part is the last frames spanning a
  whole number of periods of the slowest bar, over which the ringing averages
  out (``Hold.ringing``; such a hold is measured when it ends, as the ringing
  decays).

Each track's positions over the settled frames are averaged: the hold's
measurement noise falls with the number of frames. A hold with one frame (a
snapshot) is settled when the IMU says the rig was still for the settle time
before it, and taken as settled without an IMU.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..config import check, option
from ..core.dynamics import bar_natural_frequencies
from ..core.rig import Rig


@dataclass
class HoldConfig:
    """When frames belong to a hold, and which of them are settled (pixels of each camera's image)."""

    still_step_px: float = option(0.3, "without an IMU a hold starts when the median image motion between two "
                                  "frames is at most this (px)", lo=0.0, hi=100.0, lo_open=True)
    hold_radius_deg: float = option(3.0, "without an IMU a hold lasts while the image stays within this angle of "
                                    "the hold's first frame (deg, through each camera's focal length): ringing "
                                    "bars oscillate inside it, the moves between holds leave it", lo=0.0, hi=90.0,
                                    lo_open=True)
    settle_px: float = option(0.2, "a frame is settled when its image offset from the hold's rest position is "
                              "below this (px) or below settle_noise times the offset's noise; what remains of "
                              "the ringing averages out over the settled frames", lo=0.0, hi=100.0, lo_open=True)
    settle_noise: float = option(4.0, "see settle_px (in units of the offset's frame-to-frame noise)", lo=0.0,
                                 hi=1000.0, lo_open=True)
    settle_periods: float = option(2.0, "the settled part starts at least this many periods of the slowest bar "
                                   "after the hold starts", lo=0.0, hi=1000.0)
    lone_gap_s: float = option(1.0, "a frame with no other frame within this (s), or lone_periods frame periods, "
                               "is a snapshot: a hold of its own", lo=0.0, hi=3600.0, lo_open=True)
    lone_periods: float = option(3.0, "see lone_gap_s", lo=0.0, hi=1000.0)
    measure_s: float = option(2.0, "a hold is estimated once its settled part lasts this long (s), or when it "
                              "ends", lo=0.0, hi=3600.0, lo_open=True)
    min_settled_frames: int = option(3, "frames in a row a settled part needs (fewer when the hold has fewer)",
                                     lo=1, hi=100000)
    min_track_share: float = option(0.5, "a track is averaged when it is in this share of the settled frames",
                                    lo=0.0, hi=1.0, lo_open=True)
    min_tracks: int = option(8, "tracks a camera needs in a hold to contribute", lo=1, hi=100000)

    def __post_init__(self):
        check(self, "hold config")


def slowest_bar_period(rig: Rig) -> float:
    """Period (s) of the slowest flexible bar of the rig; 0 for a rigid rig."""
    f = bar_natural_frequencies(rig)
    f = f[np.isfinite(f) & (f > 0)]
    return float(1.0 / f.min()) if len(f) else 0.0


@dataclass
class CameraHold:
    """One camera's measurement of a hold: its tracks' averaged positions (px) and what they cost."""

    ids: np.ndarray  # (n,) track ids of the camera's tracker
    uv: np.ndarray  # (n, 2) averaged over the settled frames
    anchor_uv: np.ndarray  # (n, 2) in the anchor frame (where descriptors are taken)
    frames: int  # settled frames with this camera
    noise_px: float  # std of one frame's track position (px), NaN with a single frame


@dataclass
class Hold:
    """A measured hold (times in seconds)."""

    start: float  # the rig stopped (IMU still onset, or the first frame of the hold)
    end: float  # last frame of the hold
    settled_start: float
    settled_end: float
    stamp: float  # a frame inside the settled part: the hold's estimates carry it
    frames: int  # frames of the hold
    settled_frames: int
    residual_px: float  # RMS offset of the settled frames from the rest position (largest camera)
    cameras: list  # CameraHold or None, rig camera order
    snapshot: bool = False  # a single frame
    anchor_images: list = field(default_factory=list)  # per camera: the anchor frame (descriptors)
    ringing: bool = False  # the bars still rang at the end: averaged over whole periods of the slowest bar

    @property
    def settle_s(self) -> float:
        """How long after the stop the settled part began."""
        return self.settled_start - self.start

    @property
    def noise_px(self) -> float:
        """Median over cameras of one frame's position noise (px)."""
        v = [c.noise_px for c in self.cameras if c is not None and math.isfinite(c.noise_px)]
        return float(np.median(v)) if v else math.nan

    @property
    def averaged_noise_px(self) -> float:
        """The same for the averaged positions: noise_px / sqrt(settled frames)."""
        v = [c.noise_px / math.sqrt(c.frames) for c in self.cameras
             if c is not None and math.isfinite(c.noise_px) and c.frames > 0]
        return float(np.median(v)) if v else math.nan


class HoldRecorder:
    """The frames of the hold being recorded: per frame its stamp and every camera's (ids, uv)."""

    def __init__(self, start: float, anchors: list, anchor_images: list, snapshot: bool = False):
        """anchors: per camera (ids, uv) of the anchor frame or None; start: when the rig stopped."""
        self.start = float(start)
        self.anchors = anchors
        self.anchor_images = anchor_images
        self.snapshot = snapshot
        self.stamps: list = []
        self.positions: list = []  # per frame: list of (ids, uv) or None per camera
        self.measured = False  # estimated already (a long hold is measured once, before it ends)

    def add(self, stamp: float, positions: list) -> None:
        self.stamps.append(float(stamp))
        self.positions.append(positions)

    def __len__(self) -> int:
        return len(self.stamps)

    def _camera_tracks(self, i: int):
        """(anchor ids (n,), anchor uv (n, 2), X (F, n, 2) with NaN where a frame lacks the track)."""
        a_ids, a_uv = self.anchors[i]
        F = len(self.stamps)
        X = np.full((F, len(a_ids), 2), np.nan)
        for f, pos in enumerate(self.positions):  # frames, not points: the points of a frame go at once
            if pos is None or pos[i] is None:
                continue
            ids, uv = pos[i]
            _, ia, ib = np.intersect1d(a_ids, ids, assume_unique=True, return_indices=True)
            X[f, ia] = uv[ib]
        return a_ids, a_uv, X

    def measure(self, cfg: HoldConfig, bar_period_s: float, imu_still_since: float | None = None):
        """(Hold, "") of the settled frames, or (None, why not)."""
        with warnings.catch_warnings():  # frames without a camera, tracks lost: all-NaN medians are expected
            warnings.simplefilter("ignore", RuntimeWarning)
            return self._measure(cfg, bar_period_s, imu_still_since)

    def _measure(self, cfg: HoldConfig, bar_period_s: float, imu_still_since: float | None):
        F = len(self.stamps)
        if F == 0:
            return None, "no frames"
        t = np.array(self.stamps)
        M = len(self.anchors)
        cams = [i for i in range(M) if self.anchors[i] is not None and len(self.anchors[i][0]) >= cfg.min_tracks]
        if not cams:
            return None, "no camera had enough tracks"
        start = self.start if imu_still_since is None else min(self.start, imu_still_since)
        settle_after = start + cfg.settle_periods * bar_period_s
        tracks = {i: self._camera_tracks(i) for i in cams}
        ringing = False
        if F == 1:
            if imu_still_since is not None and t[0] < settle_after:
                return None, (f"snapshot {t[0] - start:.2f} s after the stop, before the bars settle "
                              f"({cfg.settle_periods:g} periods of {bar_period_s:.3f} s)")
            settled = np.ones(1, bool)
            residual = 0.0
        else:
            shifts = [tracks[i][2] - tracks[i][1][None] for i in cams]  # (F, n, 2) per camera
            offsets = np.stack([np.nanmedian(d, axis=1) for d in shifts], axis=1)  # (F, cams, 2)
            late = t >= settle_after
            if not late.any():
                return None, (f"ended {t[-1] - start:.2f} s after the stop, before the bars settle "
                              f"({cfg.settle_periods:g} periods of {bar_period_s:.3f} s)")
            rest = np.nanmedian(offsets[late], axis=0)  # (cams, 2)
            thr = max(cfg.settle_px, cfg.settle_noise * _offset_noise(shifts, offsets))
            dev = np.nanmax(np.linalg.norm(offsets - rest[None], axis=2), axis=1)
            settled = late & (dev <= thr)
            need = min(cfg.min_settled_frames, int(late.sum()))
            if settled.any():
                settled = _longest_run(settled)
            if settled.sum() < need:
                settled = _whole_periods(t, late, bar_period_s, need)
                if settled is None:
                    return None, (f"never settled: image offset from the rest position {np.nanmin(dev[late]):.3f} "
                                  f"px at best, threshold {thr:.3f} px, and less than one bar period "
                                  f"({bar_period_s:.3f} s) of {need} frames or more to average the ringing over")
                ringing = True
            residual = float(np.sqrt(np.nanmean(dev[settled] ** 2)))
        idx = np.flatnonzero(settled)
        cam_holds = [None] * M
        for i in cams:
            a_ids, a_uv, X = tracks[i]
            Xs = X[idx]
            present = np.isfinite(Xs[:, :, 0])
            frames = int(np.count_nonzero(present.any(axis=1)))
            if frames == 0:
                continue
            keep = present.sum(axis=0) >= max(1, cfg.min_track_share * frames)
            if keep.sum() < cfg.min_tracks:
                continue
            mean = np.nanmean(Xs[:, keep], axis=0)
            n = present[:, keep].sum(axis=0)
            dev2 = np.nansum((Xs[:, keep] - mean[None]) ** 2, axis=(0, 2))
            dof = 2 * (n - 1)
            noise = math.sqrt(float(dev2.sum() / dof.sum())) if dof.sum() > 0 else math.nan
            cam_holds[i] = CameraHold(a_ids[keep], mean, a_uv[keep], frames, noise)
        if all(c is None for c in cam_holds):
            return None, f"fewer than {cfg.min_tracks} tracks lasted through the settled frames in every camera"
        mid = idx[len(idx) // 2]
        return Hold(start=start, end=float(t[-1]), settled_start=float(t[idx[0]]), settled_end=float(t[idx[-1]]),
                    stamp=float(t[mid]), frames=F, settled_frames=len(idx), residual_px=residual,
                    cameras=cam_holds, snapshot=F == 1, anchor_images=self.anchor_images, ringing=ringing), ""

    def settled_duration(self, cfg: HoldConfig, bar_period_s: float, imu_still_since: float | None = None) -> float:
        """How long the settled part lasts so far (s); 0 when nothing is settled yet."""
        if len(self.stamps) < 2:
            return 0.0
        hold, _ = self.measure(cfg, bar_period_s, imu_still_since)
        if hold is None or hold.ringing:  # ringing decays: such a hold is measured when it ends
            return 0.0
        return hold.settled_end - hold.settled_start


def _offset_noise(shifts: list, offsets: np.ndarray) -> float:
    """Noise (px) of a frame's image offset: the tracks' spread about their frame's median shift (measurement
    noise, whatever the rig does), over the square root of their number (the offset is their median)."""
    out = []
    for i, d in enumerate(shifts):
        r = np.linalg.norm(d - offsets[:, i, None, :], axis=2)  # (F, n)
        n = np.count_nonzero(np.isfinite(r), axis=1)
        ok = n > 0
        if ok.any():
            spread = 1.4826 * np.nanmedian(r[ok], axis=1) / math.sqrt(2.0)  # per axis, per frame
            out.append(float(np.median(1.2533 * spread / np.sqrt(n[ok]))))
    return max(out) if out else 0.0


def _whole_periods(t: np.ndarray, late: np.ndarray, period_s: float, need: int) -> np.ndarray | None:
    """The last frames of a hold that span a whole number of periods of the slowest bar (as a mask of the
    frames), or None when the late frames span less than one period or hold fewer than ``need``.

    Bars that still ring when the hold ends oscillate about their rest position; the mean over whole periods
    of the oscillation is that rest position (up to the decay within the window and the sampling), so the
    averaged tracks measure the settled hold.
    """
    if not period_s > 0:
        return None
    tl = t[late]
    dt = float(np.median(np.diff(tl))) if len(tl) > 1 else 0.0
    periods = math.floor((tl[-1] - tl[0] + dt) / period_s + 1e-9)
    if periods < 1:
        return None
    window = late & (t > tl[-1] + dt - periods * period_s - 1e-9 * max(dt, 1.0))
    return window if window.sum() >= need else None


def _longest_run(mask: np.ndarray) -> np.ndarray:
    """The longest run of True in mask (the first when tied), as a mask."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    k = int(np.argmax(ends - starts))
    out = np.zeros(len(mask), bool)
    out[starts[k]:ends[k]] = True
    return out


__all__ = ["CameraHold", "Hold", "HoldConfig", "HoldRecorder", "slowest_bar_period"]
