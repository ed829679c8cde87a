"""Static-window detection: which frames show the rig at rest, one representative view per window.

A window starts at a frame and grows while the image motion since its first
frame (median KLT displacement, all cameras) stays below ``max_motion_px``
and the IMU, when there is one, says the rig is still. A window is confirmed
(its representative view is the frame that confirms it) once it holds
``min_static_frames`` frames spanning ``min_static_duration_s``. A frame that
comes more than ``snapshot_gap_s`` after the previous one (a bag of static
snapshots) is a window of its own, confirmed at once unless the IMU says the
rig is moving (the very first frame needs the IMU's word for that). Each
window yields at most one view.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class StaticConfig:
    max_motion_px: float = 1.0  # median image motion since the window's first frame
    min_static_frames: int = 2
    min_static_duration_s: float = 0.0
    snapshot_gap_s: float = 2.5  # frames further apart than this are static snapshots
    min_tracks: int = 15  # fewer tracks surviving since the window's start: the image moved too much to tell


@dataclass
class Window:
    start: float
    frames: int = 1
    snapshot: bool = False
    confirmed: bool = False


class StaticDetector:
    """Feed one decision per frame; returns True for the frame that confirms a static window."""

    def __init__(self, cfg: StaticConfig | None = None):
        self.cfg = cfg or StaticConfig()
        self.window: Window | None = None
        self.last_stamp = None

    def update(self, stamp: float, motion_px: float, tracks: int, imu_still: bool | None) -> tuple:
        """(new_window, confirmed): whether the frame starts a window (re-anchor tracks) and confirms one."""
        cfg = self.cfg
        first = self.last_stamp is None
        gap = float("inf") if first else stamp - self.last_stamp
        self.last_stamp = stamp
        still = motion_px <= cfg.max_motion_px and tracks >= cfg.min_tracks and imu_still is not False
        new = self.window is None or gap > cfg.snapshot_gap_s or not still
        if new:
            self.window = Window(start=stamp, snapshot=gap > cfg.snapshot_gap_s)
        else:
            self.window.frames += 1
        w = self.window
        if w.confirmed:
            return new, False
        if w.snapshot and (imu_still is True or (imu_still is None and not first)):
            w.confirmed = True
        elif w.frames >= cfg.min_static_frames and stamp - w.start >= cfg.min_static_duration_s:
            w.confirmed = True
        return new, w.confirmed
