"""Without an IMU: whether a camera's image rings about a rest that stays put (docs/PIPELINE.md, "Holds").

The images alone must tell a hold from a move when no IMU is there. On soft, lightly damped bars the image of a
rig at rest swings by tens of pixels between frames for seconds after a stop, so "the image barely moved between
two frames" finds no hold at all. What tells ringing from a move is its shape: ringing swings the image about a
rest position at the bar's frequency, with an envelope that only decays; a move carries the image away.

Each camera's image path (the sum of its tracks' median shifts, frame to frame, at the image's own stamps) is
fitted over its last ``WINDOW_PERIODS`` bar periods (at least ``MIN_WINDOW_FRAMES`` frames) by the damped response
(:mod:`.ringing`: rest plus a decaying oscillation) at the best of a grid of frequencies about the bar's and of
damping ratios (no refinement: it runs every frame). The share of the path's spread the fit leaves is what
decides: ringing leaves a few percent of it (the stamps' jitter times the ringing's speed: at most about 30 %
for an 8 Hz bar seen at 15 Hz with +-8 ms stamps), while a steady move, an acceleration or the end of a move
within the window leaves at least 40 % (the first harmonic of a sawtooth carries 61 % of its variance, so a
period's fit leaves about 60 % of a ramp). ``RINGING_SHARE`` lies between. A bar that rings faster than half
the camera's rate is seen at its alias (its distance to the nearest multiple of the rate): the grid keeps only
the frequencies whose alias makes at least a cycle over the window (:func:`.ringing.resolvable_bands`), as the
lowest one does unaliased; an alias near zero fits a slow move as well as any ringing, and a camera whose grid
has none left is not judged. Right after a stop the window
still holds the end of the move, and the share falls through the bound as the move leaves the window: a hold
that began there is kept while the share stays within ``KEPT_SHARE`` (hysteresis; a move that starts from rest
passes it within a few frames).
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np

from .ringing import ZETA_GRID, best_on_grid, in_bands, resolvable_bands

WINDOW_PERIODS = 1.25  # at least one period at the lowest frequency of the grid (FREQ_SPAN[0])
MIN_WINDOW_FRAMES = 8  # three parameters per image axis, and as many frames again to judge the fit by
FREQ_SPAN = (0.8, 1.25)  # the grid's frequencies, relative to the rig file's (its bars may be off by that much)
FREQ_STEPS = 9
RINGING_SHARE = 0.35  # largest residual RMS, as a share of the path's RMS spread, that ringing leaves
KEPT_SHARE = 0.5  # ... and that an open hold's ringing may leave before it is taken for a move


class PathVerdict(NamedTuple):
    """Whether an image's recent path rings about a rest (None: not known), the rest (px, None when not
    known), and the share of the path's spread the damped response leaves (NaN when not known)."""

    rings: bool | None
    rest: np.ndarray | None
    share: float = math.nan
    since: float = math.nan  # the window's first image (s)

    def kept(self) -> bool | None:
        """Whether an open hold's ringing goes on (the looser bound, KEPT_SHARE; None: not known)."""
        return None if self.rings is None else bool(self.share <= KEPT_SHARE)


class RingingWatch:
    """Each camera's recent image path, and whether it rings about a fixed rest (module docstring).

    ``freqs_hz`` (M,): each camera's bar frequency (inf or 0: a rigid camera, never ringing); ``zeta``: the bars'
    damping ratio (added to the grid's)."""

    def __init__(self, freqs_hz, zeta: float):
        self.freqs_hz = np.asarray(freqs_hz, float)
        zetas = set(ZETA_GRID)
        if 0.0 < zeta < 1.0:
            zetas.add(float(zeta))
        self.zetas = np.array(sorted(zetas))
        self._paths = [deque() for _ in self.freqs_hz]  # per camera: (taken, x, y) of each image

    def _window_s(self, i: int) -> float:
        f = self.freqs_hz[i]
        return WINDOW_PERIODS / f if math.isfinite(f) and f > 0 else 0.0

    def add(self, i: int, taken: float, shift_px, lost: bool) -> None:
        """Camera i's image at ``taken`` moved its tracks by ``shift_px`` (2,) (median) since its last one;
        ``lost``: its tracks were lost (the path starts again)."""
        path = self._paths[i]
        if lost or not np.all(np.isfinite(shift_px)):
            path.clear()
        if path and taken <= path[-1][0]:
            return
        x, y = (path[-1][1] + float(shift_px[0]), path[-1][2] + float(shift_px[1])) if path else (0.0, 0.0)
        path.append((float(taken), x, y))
        keep = self._window_s(i)
        while len(path) > MIN_WINDOW_FRAMES and path[1][0] <= taken - keep:
            path.popleft()

    def reset(self) -> None:
        """Every path starts again (a gap in the stream)."""
        for path in self._paths:
            path.clear()

    def judge(self, i: int) -> PathVerdict:
        """Whether camera i's image rings about a rest over the last window (module docstring), and that rest
        (px, in the camera's path); ``rings`` None when the window is not covered yet or the camera's bar is
        rigid."""
        path, window = self._paths[i], self._window_s(i)
        if not window or len(path) < MIN_WINDOW_FRAMES or path[-1][0] - path[0][0] < window - 1e-9:
            return PathVerdict(None, None)
        a = np.array(path)
        tau, xy = a[:, 0] - a[0, 0], a[:, 1:]
        freqs = self.freqs_hz[i] * np.geomspace(FREQ_SPAN[0], FREQ_SPAN[1], FREQ_STEPS)
        freqs = freqs[in_bands(freqs, resolvable_bands([(tau, xy)], float(freqs[0]), float(freqs[-1])))]
        if not len(freqs):
            return PathVerdict(None, None)  # every frequency aliases to a slow swing (module docstring)
        spread = math.sqrt(float(np.mean((xy - xy.mean(axis=0)) ** 2)))
        if spread <= 0.0:
            return PathVerdict(None, None)
        rms, rest = best_on_grid(tau, xy, freqs, self.zetas)
        return PathVerdict(bool(rms <= RINGING_SHARE * spread), rest, rms / spread, float(a[0, 0]))


__all__ = ["RINGING_SHARE", "KEPT_SHARE", "PathVerdict", "RingingWatch"]
