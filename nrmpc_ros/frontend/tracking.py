"""Image measurements of one camera: KLT tracks, descriptor features, and their verification.

- :class:`KltTracker` follows corners frame to frame through the moves and,
  inside a hold, from the hold's anchor frame (so a hold's positions can be
  averaged); ids persist while a corner is followed.
- Descriptors: ORB (default) or SIFT at the tracks' positions, matched with
  a ratio test and mutual best match, link holds whose tracks did not survive
  the move between them (snapshots, fast moves).
- :func:`verify_correspondences`: an essential-matrix RANSAC on undistorted
  bearings per camera (valid for pinhole and fisheye models, and exact for
  each camera even when its bar bends).

Grid bucketing spreads corners and features over the image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..cameras import bearings_to_pixels, pixels_to_bearings
from ..config import check, option
from ..core.epipolar import essential_matrix, in_front
from ..core.rig import Camera
from .exposure import NONE as NO_CHANGE
from .exposure import grid_quantiles, undo_exposure

MODES = ("auto", "klt", "descriptors")
DESCRIPTORS = ("orb", "sift")
CORNER_DETECTORS = ("fast", "gftt")
# pyramidal Lucas-Kanade stops after 20 iterations or a step below 0.01 px, OpenCV's defaults
LK_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)
# a corner's sub-pixel refinement: 30 iterations or a step below 0.001 px (it is found again in every hold)
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.001)
# inside a settled hold one frame is tracked per quarter bar period (an eighth of the measurement window
# without a bar period): the tracks follow the slowest ringing the hold's measurement still removes
SKIP_SPACING_PERIODS = 0.25
SKIP_SPACING_MEASURE = 0.125
DEVIATION_QUANTILE = 0.95  # a prediction's deviation: this quantile of the tracks' distances from it
DEVIATION_SMOOTHING = 0.25  # the deviation averaged over about the last 1 / this frames (exponentially)


@dataclass
class TrackingConfig:
    """Feature tracking and matching; pixel values refer to the camera's own image."""

    mode: str = option("auto", "how holds are linked: auto (KLT identity and, where too few tracks survived a "
                       "move, descriptors), klt (identity only), descriptors (every hold matched afresh)",
                       choices=MODES)
    grid_rows: int = option(6, "rows of the bucketing grid that spreads corners over the image", lo=1, hi=100)
    grid_cols: int = option(8, "columns of the bucketing grid", lo=1, hi=100)
    max_tracks: int = option(150, "KLT tracks per camera", lo=8, hi=5000)
    undo_exposure: bool = option(True, "inside a hold, a frame's gain and offset against the anchor's (auto-"
                                 "exposure) are undone before it is tracked (frontend/exposure.py)")
    replenish_fraction: float = option(0.7, "outside holds, new corners are detected when fewer tracks than "
                                       "this share of max_tracks remain", lo=0.0, hi=1.0)
    min_distance_px: float = option(8.0, "least distance between corners (px)", lo=1.0, hi=200.0)
    corner_detector: str = option("fast", "new corners: fast (FAST, strongest per cell) or gftt (Shi-Tomasi)",
                                  choices=CORNER_DETECTORS)
    fast_threshold: int = option(12, "FAST intensity threshold (grey levels)", lo=1, hi=255)
    corner_quality: float = option(0.003, "goodFeaturesToTrack qualityLevel (corner_detector gftt)", lo=0.0,
                                   hi=1.0, lo_open=True)
    klt_window: int = option(15, "Lucas-Kanade window side (px)", lo=5, hi=101)
    klt_levels: int = option(3, "Lucas-Kanade pyramid levels between holds", lo=0, hi=8)
    fb_threshold_px: float = option(0.7, "largest forward-backward round-trip error of a track (px)", lo=0.0,
                                    hi=10.0, lo_open=True)
    imu_prediction: bool = option(True, "with an IMU on the body, each frame's KLT search starts where the gyro's "
                                  "turn (and the bars' predicted bending, where it predicts better) takes the "
                                  "tracks; false: from the images alone (docs/PIPELINE.md, Performance notes)")
    lost_fraction: float = option(0.25, "fewer tracks than this share survive a frame: they are lost (a jump) "
                                  "and start afresh", lo=0.0, hi=1.0, lo_open=True)
    corner_window_px: int = option(11, "sub-pixel corner search window at a hold's anchor (px)", lo=3, hi=31)
    corner_refinement_px: float = option(3.0, "a track the sub-pixel corner search moves further than this "
                                         "(px) keeps its position; 0 turns the search off", lo=0.0, hi=10.0)
    descriptor: str = option("orb", "descriptors that link holds without surviving tracks: orb or sift",
                             choices=DESCRIPTORS)
    ratio: float = option(0.8, "Lowe's ratio test of descriptor matches", lo=0.0, hi=1.0, lo_open=True)
    ransac_threshold_px: float = option(1.0, "essential-matrix verification threshold (Sampson distance, px)",
                                        lo=0.0, hi=20.0, lo_open=True)
    ransac_confidence: float = option(0.999, "essential-matrix RANSAC confidence", lo=0.5, hi=1.0, lo_open=True)
    min_matches_per_camera: int = option(12, "fewer verified links between two holds: the camera links nothing",
                                         lo=8, hi=10000)
    min_klt_links: int = option(40, "fewer verified KLT links of a camera to its previous hold: descriptors too",
                                lo=0, hi=10000)
    link_store_holds: int = option(200, "holds per camera whose descriptors are kept to link a new hold to an "
                                   "older one (a return to an earlier view); 0: the previous hold only", lo=0,
                                   hi=100000)
    link_older_candidates: int = option(3, "older holds, most descriptor matches first, whose matches are "
                                        "verified per camera when the previous hold links few", lo=1, hi=100)

    def __post_init__(self):
        check(self, "tracking config")


# ---------------------------------------------------------------------------
# Bucketing and detection
# ---------------------------------------------------------------------------

def cell_ranks(uv: np.ndarray, size, rows: int, cols: int, order: np.ndarray | None = None) -> np.ndarray:
    """Rank (0 = best) of each point among the points of its grid cell, best first by ``order``."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    w, h = size
    cx = np.clip((uv[:, 0] * (cols / w)).astype(np.int64), 0, cols - 1)
    cy = np.clip((uv[:, 1] * (rows / h)).astype(np.int64), 0, rows - 1)
    cell = cy * cols + cx
    n = len(cell)
    srt = np.arange(n) if order is None else np.asarray(order, dtype=np.int64)
    srt = srt[np.argsort(cell[srt], kind="stable")]  # by cell, best first within a cell
    c = cell[srt]
    pos = np.arange(n)
    first = np.ones(n, bool)  # first point of its cell in srt
    np.not_equal(c[1:], c[:-1], out=first[1:])
    ranks = np.empty(n, np.int64)
    ranks[srt] = pos - np.maximum.accumulate(np.where(first, pos, 0))
    return ranks


def bucket(uv: np.ndarray, size, rows: int, cols: int, count: int, order: np.ndarray | None = None) -> np.ndarray:
    """Indices (ascending) of at most ``count`` points spread as evenly as possible over a rows x cols grid.

    Points are taken round-robin over the cells (best first by ``order``,
    default input order), so no cell gets more than its share while others
    have points left.
    """
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    n = len(uv)
    if n <= count:
        return np.arange(n)
    if order is None:
        key = np.arange(n)
    else:
        key = np.empty(n, np.int64)
        key[np.asarray(order)] = np.arange(n)
    key += n * cell_ranks(uv, size, rows, cols, order)  # (rank in its cell, position in order): unique
    return np.sort(np.argpartition(key, count - 1)[:count])


def spread_corners(pts: np.ndarray, score: np.ndarray, size, cfg: TrackingConfig, max_count: int) -> np.ndarray:
    """Indices of at most ``max_count`` of ``pts``: the strongest per ``min_distance_px`` cell, grid bucketed."""
    if len(pts) == 0 or max_count <= 0:
        return np.zeros(0, np.int64)
    d = max(1.0, float(cfg.min_distance_px))
    strongest = cell_ranks(pts, size, max(1, int(size[1] // d)), max(1, int(size[0] // d)),
                           np.argsort(-score, kind="stable")) == 0
    idx = np.flatnonzero(strongest)  # at most one corner per min_distance_px cell
    keep = bucket(pts[idx], size, cfg.grid_rows, cfg.grid_cols, max_count,
                  order=np.argsort(-score[idx], kind="stable"))
    return idx[keep]


def detect_corners(img: np.ndarray, cfg: TrackingConfig, max_count: int, mask=None) -> np.ndarray:
    """Corners (N, 2) float32 for KLT, at least ``min_distance_px`` apart, spread by grid bucketing.

    ``corner_detector: fast`` (default) takes FAST corners, the strongest per
    ``min_distance_px`` cell (about 10x cheaper than Shi-Tomasi on a VGA
    image); ``gftt`` takes Shi-Tomasi corners.
    """
    if max_count <= 0:
        return np.zeros((0, 2), np.float32)
    size = (img.shape[1], img.shape[0])
    if cfg.corner_detector == "gftt":
        pts = cv2.goodFeaturesToTrack(img, maxCorners=int(3 * max_count), qualityLevel=cfg.corner_quality,
                                      minDistance=cfg.min_distance_px, mask=mask, blockSize=5)
        if pts is None:
            return np.zeros((0, 2), np.float32)
        pts = pts.reshape(-1, 2)
        keep = bucket(pts, size, cfg.grid_rows, cfg.grid_cols, max_count)
        return pts[keep].astype(np.float32)
    kps = cv2.FastFeatureDetector_create(int(cfg.fast_threshold), True).detect(img, mask)
    if not kps:
        return np.zeros((0, 2), np.float32)
    pts = cv2.KeyPoint_convert(kps).reshape(-1, 2)
    resp = np.fromiter((k.response for k in kps), float, len(kps))
    return pts[spread_corners(pts, resp, size, cfg, max_count)]


def _lk(img0, img1, p0, cfg: TrackingConfig, window: int | None = None, levels: int | None = None,
        fb_px: float | None = None, guess: np.ndarray | None = None):
    """Forward-backward LK from img0 (points p0) into img1: tracked points and a validity mask (window, levels,
    threshold default to the config's; ``guess``: starting positions in img1)."""
    if len(p0) == 0:
        return np.asarray(p0, np.float32).copy(), np.zeros(0, bool)
    crit = LK_CRITERIA
    w = int(cfg.klt_window if window is None else window)
    win, levels = (w, w), int(cfg.klt_levels if levels is None else levels)
    p0 = np.ascontiguousarray(p0, np.float32)
    flags = 0
    p1 = None
    if guess is not None:
        p1 = np.ascontiguousarray(guess, np.float32).copy()
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, p1, winSize=win, maxLevel=levels, criteria=crit,
                                          flags=flags)
    h, w = img1.shape
    ok = st1.ravel() == 1
    ok &= (p1[:, 0] >= 0) & (p1[:, 1] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] <= h - 1)
    idx = np.flatnonzero(ok)
    if len(idx):  # backward check only for what the forward pass kept
        p0b, st2, _ = cv2.calcOpticalFlowPyrLK(img1, img0, np.ascontiguousarray(p1[idx]), p0[idx].copy(), winSize=win,
                                               maxLevel=levels, criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        fb = cfg.fb_threshold_px if fb_px is None else fb_px
        good = (st2.ravel() == 1) & (np.linalg.norm(p0b - p0[idx], axis=1) < fb)
        ok[idx[~good]] = False
    return p1, ok


def _median(x: np.ndarray) -> np.ndarray:
    """Median along the first axis by partial sort (np.median's overhead dominates for a few hundred values)."""
    n = len(x)
    if n % 2:
        return np.partition(x, n // 2, axis=0)[n // 2]
    part = np.partition(x, (n // 2 - 1, n // 2), axis=0)
    return 0.5 * (part[n // 2 - 1] + part[n // 2])


def _norm(d: np.ndarray) -> np.ndarray:
    """Lengths of the rows of an (N, 2) array."""
    return np.hypot(d[:, 0], d[:, 1])


def _levels_for(step_px: float, window: int, most: int) -> int:
    """Pyramid levels Lucas-Kanade needs for a displacement of ``step_px`` from its starting guess: one level
    converges within about a quarter of its window, each level above it doubles that reach."""
    reach = window / 4.0
    return int(min(most, max(0, math.ceil(math.log2(max(step_px, 1e-6) / reach)))))


def _lk_predicted(img0, img1, p0, guess, cfg: TrackingConfig, deviation_px: float,
                  stats: TrackerStats | None = None):
    """LK from ``img0`` (points ``p0``) into ``img1`` starting at the predicted positions ``guess``, with the
    pyramid levels that the measured deviation of the last frame's motion from its prediction,
    ``deviation_px``, needs (none in a still hold or a steady move) and no backward pass where the result is
    plain.

    Predictions: inside a hold the previous positions (tracked from the anchor), during a move the previous
    positions plus each track's last frame-to-frame motion. A track is doubtful when LK failed or it lies
    further from its prediction than half the round-trip tolerance (``fb_threshold_px``) beyond the common
    deviation of all tracks; a track that moved as predicted from its previous, already checked, position
    needs no round trip. Doubtful tracks go through the full forward-backward :func:`_lk` (all levels), so a
    frame where the rig starts or stops moving is tracked as before. Where :func:`_lk` would accept a track
    the same window converges to the same position, at a fraction of the cost: a small pyramid or none, and
    one pass instead of two. ``stats``: where the levels of the first pass and the tracks given the full pass
    are counted."""
    if len(p0) == 0 or not math.isfinite(deviation_px):
        if stats is not None:
            stats.levels += int(cfg.klt_levels)
            stats.full_pass_tracks += len(p0)
        return _lk(img0, img1, p0, cfg, guess=guess)
    w = int(cfg.klt_window)
    crit = LK_CRITERIA
    p0 = np.ascontiguousarray(p0, np.float32)
    guess = np.ascontiguousarray(guess, np.float32)
    levels = _levels_for(2.0 * deviation_px, w, int(cfg.klt_levels))  # twice the last: the motion may change
    p1, st, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, guess.copy(), winSize=(w, w), maxLevel=levels,
                                         criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    h, wd = img1.shape
    ok = (st.ravel() == 1) & (p1[:, 0] >= 0) & (p1[:, 1] >= 0) & (p1[:, 0] <= wd - 1) & (p1[:, 1] <= h - 1)
    off = p1 - guess
    common = _median(off[ok]) if ok.any() else np.zeros(2, np.float32)
    doubtful = ~ok | (_norm(off - common) > 0.5 * cfg.fb_threshold_px)
    idx = np.flatnonzero(doubtful)
    if stats is not None:
        stats.levels += levels
        stats.full_pass_tracks += len(idx)
    if len(idx):
        p1[idx], ok[idx] = _lk(img0, img1, p0[idx], cfg, guess=guess[idx])
    return p1, ok


def turn_pixels(cam: Camera, R: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Where the pixels ``uv`` (N, 2) of ``cam`` land when the camera turns by ``R`` (bearings f' = R f): the
    infinite homography K R K^-1 through the camera's own model (distortion, fisheye), exact for points far
    away and for a camera that only turns. NaN where a point turns behind the camera."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if len(uv) == 0:
        return uv.copy()
    if cam.model == "pinhole" and not any(cam.distortion):  # K R K^-1 directly
        fx, fy, cx, cy = cam.intrinsics
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        H = K @ np.asarray(R, float) @ np.linalg.inv(K)
        p = uv @ H[:, :2].T + H[:, 2]
        out = p[:, :2] / p[:, 2:]
        out[p[:, 2] <= 1e-9] = np.nan
        return out
    return bearings_to_pixels(cam, pixels_to_bearings(cam, uv) @ np.asarray(R, float).T)


class TrackStep(NamedTuple):
    """What one frame did to a camera's tracks: median motion since the previous frame (px, NaN when unknown),
    tracks alive, whether the tracks were lost (a jump: too few survived, all were dropped), inside a hold the
    median offset from the hold's anchor frame (px, NaN outside a hold), and the median shift of the tracks since
    the previous frame (x, y px; NaN when unknown): the image's path, whose shape tells ringing from a move."""

    motion_px: float
    tracks: int
    lost: bool
    offset_px: float = math.nan
    shift_px: tuple = (math.nan, math.nan)


@dataclass
class TrackerStats:
    """The work a tracker did: frames tracked, of which started from the camera's turn (the IMU), the pyramid
    levels of their first pass summed over frames, tracks that needed the full forward-backward pass, tracks
    alive after each frame (summed), tracks the frames dropped (failed or rejected) and frames where the
    tracks were lost (all dropped)."""

    frames: int = 0
    turn_frames: int = 0
    levels: int = 0
    full_pass_tracks: int = 0
    tracks: int = 0
    dropped_tracks: int = 0
    lost: int = 0
    exposure_frames: int = 0  # frames of a hold tracked after their exposure change was undone


@dataclass
class HoldThinning:
    """Which frames of a settled, still hold are tracked: work in proportion to what the frames still tell.

    A hold's landmark positions are averaged over its settled frames; the average's noise is one frame's
    noise ``sigma`` over the square root of the frames, and on top of it every correspondence carries a bias
    that no averaging removes (``floor_px``, :data:`~nrmpc_ros.core.sequence.CORRESPONDENCE_BIAS_FLOOR_PX`).
    Once the averaged noise is at most half that floor -- ``(2 sigma / floor_px)^2`` settled frames, sigma
    the per-frame noise the latest measured holds showed -- further frames lower the total
    ``sqrt(sigma^2 / N + floor_px^2)`` by less than 12 %. From then on, while the IMU says the rig is still (a
    cheap test on samples already there), a frame is tracked only when a quarter of the slowest bar's period
    (the settle test still samples any ringing four times a period; an eighth of ``measure_s`` for rigid
    bars) has passed since the last tracked one, so the settled part keeps growing in time and the images
    still check the hold (docs/PIPELINE.md, "Performance notes"). Without an IMU every frame is tracked (the
    images are the only stillness test then), and before the first hold has been measured (no noise known)."""

    floor_px: float
    skipped: int = 0  # frames not tracked

    def needed_frames(self, noise_px: float) -> int:
        """Settled frames whose average reaches half the floor at a per-frame noise of ``noise_px``."""
        return max(1, math.ceil((2.0 * noise_px / self.floor_px) ** 2))

    def skip(self, stamp: float, last_tracked: float, settled_frames: float, noise_px: float,
             bar_period_s: float, measure_s: float, imu_still) -> bool:
        """Whether the frame at ``stamp`` goes untracked: the settled part has ``settled_frames`` frames, one
        frame's noise is ``noise_px``, the last frame tracked was at ``last_tracked``; ``imu_still()`` (asked
        last: the rest is cheaper) says whether the IMU saw the rig still since the last frame."""
        if not math.isfinite(noise_px) or settled_frames < self.needed_frames(noise_px):
            return False
        spacing = SKIP_SPACING_PERIODS * bar_period_s if bar_period_s > 0 else SKIP_SPACING_MEASURE * measure_s
        if stamp - last_tracked >= spacing or not imu_still():
            return False
        self.skipped += 1
        return True


TURN_NEGLIGIBLE_PX = 0.01  # a turn that moves no pixel further than this leaves the predicted positions as they are


class KltTracker:
    """KLT tracks of one camera with persistent ids.

    Between holds the tracks follow the image frame to frame (pyramidal
    Lucas-Kanade with a forward-backward check); when fewer than
    ``lost_fraction`` of them survive (a jump, e.g. between snapshots) all are
    dropped and new corners are detected, with new ids. Inside a hold
    (:meth:`start_hold`) every frame is tracked from the hold's anchor frame,
    the template, starting from the previous positions:
    positions of one hold never drift from frame to frame, so averaging them
    reduces the noise. No corners are added during a hold. The work per frame
    follows the measured motion (:func:`_lk_predicted`): each frame starts from
    the predicted positions with the pyramid the measured prediction error needs
    and one pass; doubtful tracks get the full forward-backward pyramidal KLT
    (docs/PIPELINE.md, "Performance notes").

    Predicted positions: with the camera's turn since the last frame (``turn``
    of :meth:`track`: the gyro and the bars' bending, :func:`.gyro.camera_turns`)
    each track is turned by the infinite homography through the camera's model
    (:func:`turn_pixels`), plus, during a move, what the last turn did not
    explain of its last motion (the parallax of the rig's translation). Without
    a turn: still in a hold, moving on as in the last frame during a move.
    """

    def __init__(self, cfg: TrackingConfig, camera: Camera | None = None):
        self.cfg = cfg
        self.camera = camera  # its model turns the predicted positions (None: no turn is used)
        self.prev = None  # last image
        self.uv = np.zeros((0, 2), np.float32)
        self.ids = np.zeros(0, np.int64)
        self._next_id = 0
        self._anchor = None  # (image, uv, ids) of the hold's first frame
        self._anchor_levels = None  # its intensity quantiles (frontend/exposure.py)
        self._in_anchor = np.zeros(0, np.int64)  # index in the anchor of each track (inside a hold)
        self.lost = 0  # frames where the tracks were lost and started afresh
        self.flow = np.zeros((0, 2), np.float32)  # each track's motion between the last two frames (px)
        self.rest = None  # (K, N, 2) px of the last motion each candidate turn did not explain (None: no turn then)
        self.turn_deviation_px = np.zeros(0)  # (K,) running 95th-percentile deviation of each candidate turn (px)
        self.deviation_px = math.nan  # 95th percentile of the tracks' distance from their predicted position (px)
        self.stats = TrackerStats()

    @property
    def in_hold(self) -> bool:
        return self._anchor is not None

    def _replenish(self, img) -> None:
        n = len(self.uv)
        cfg = self.cfg
        if n >= cfg.replenish_fraction * cfg.max_tracks:
            return
        mask = None
        if n:
            mask = np.full(img.shape, 255, np.uint8)
            r = max(1, int(cfg.min_distance_px))
            for u, v in self.uv.astype(int):
                cv2.circle(mask, (int(u), int(v)), r, 0, -1)
        new = detect_corners(img, cfg, cfg.max_tracks - n, mask)
        flow = np.median(self.flow, axis=0) if len(self.flow) else np.zeros(2, np.float32)
        self.uv = np.concatenate([self.uv, new])
        self.ids = np.concatenate([self.ids, self._next_id + np.arange(len(new))])
        self.flow = np.concatenate([self.flow, np.broadcast_to(flow, new.shape)]).astype(np.float32)
        if self.rest is not None:
            rest = np.median(self.rest, axis=1) if self.rest.shape[1] else np.zeros((len(self.rest), 2))
            fill = np.broadcast_to(rest[:, None, :], (len(self.rest), len(new), 2))
            self.rest = np.concatenate([self.rest, fill], axis=1).astype(np.float32)
        self._next_id += len(new)

    def _turned(self, uv: np.ndarray, turn: np.ndarray | None) -> np.ndarray | None:
        """``uv`` turned by the camera's ``turn`` (float32; NaN rows keep their position), or None without one;
        ``uv`` itself when the turn moves no pixel by more than :data:`TURN_NEGLIGIBLE_PX`."""
        if turn is None or self.camera is None:
            return None
        turn = np.asarray(turn, float)
        sin_angle = 0.5 * math.sqrt((turn[2, 1] - turn[1, 2]) ** 2 + (turn[0, 2] - turn[2, 0]) ** 2
                                    + (turn[1, 0] - turn[0, 1]) ** 2)
        if sin_angle * self.camera.focal_px * 2.0 < TURN_NEGLIGIBLE_PX:  # (twice: off axis it moves further)
            return uv
        out = turn_pixels(self.camera, turn, uv)
        bad = ~np.isfinite(out).all(axis=1)
        out[bad] = uv[bad]
        return out.astype(np.float32)

    def _deviation(self, p1: np.ndarray, guess: np.ndarray, ok: np.ndarray) -> float:
        """The DEVIATION_QUANTILE of the distance of the tracked positions from a prediction (px; NaN: none
        tracked)."""
        n = int(ok.sum())
        if not n:
            return math.nan
        k = int(DEVIATION_QUANTILE * (n - 1))
        return float(np.partition(_norm(p1[ok] - guess[ok]), k)[k])

    def track(self, img: np.ndarray, turn: np.ndarray | None = None) -> TrackStep:
        """Follow the tracks into ``img``; outside a hold, top them up with new corners.

        ``turn``: the camera's rotation since the last frame (bearings f_now = turn f_last), (3, 3), or (K, 3,
        3) candidates of it (rival models of the camera's motion, e.g. with and without a predicted bending
        change). Each track's search starts where the candidate with the smallest running deviation from the
        tracked positions takes it (the first one while none has been measured): a model is used where it
        predicts what the images show."""
        lost = False
        motion = offset = math.nan
        shift = (math.nan, math.nan)
        st = self.stats
        st.frames += 1
        cands = None if turn is None or self.camera is None else np.asarray(turn, float).reshape(-1, 3, 3)
        if cands is not None and len(cands) != len(self.turn_deviation_px):
            self.turn_deviation_px = np.full(len(cands), math.nan)
            self.rest = None
        if self.prev is not None and len(self.uv):
            turned_all = None if cands is None else [self._turned(self.uv, R) for R in cands]
            best = 0
            if turned_all is not None and np.isfinite(self.turn_deviation_px).any():
                best = int(np.nanargmin(self.turn_deviation_px))
            turned = None if turned_all is None else turned_all[best]
            st.turn_frames += turned is not None
            in_hold = self._anchor is not None
            if in_hold:  # predicted: where they were (the rig is still), or where the turn took them
                a_img, a_uv = self._anchor[:2]
                a_uv = a_uv[self._in_anchor]  # the anchor's tracks still alive, in the order of self.uv
                guesses = None if turned_all is None else turned_all
                guess = self.uv if turned is None else turned
                seen = img
                if self.cfg.undo_exposure:
                    seen, change = undo_exposure(self._anchor_levels, img)
                    st.exposure_frames += change is not NO_CHANGE
                p1, ok = _lk_predicted(a_img, seen, a_uv, guess, self.cfg, self.deviation_px, st)
                if ok.any():
                    offset = float(_median(_norm(p1[ok] - a_uv[ok])))
            else:  # predicted: moving on as in the last frame, or turned plus the last motion's remainder
                guesses = None if turned_all is None else \
                    [t if self.rest is None else t + self.rest[j] for j, t in enumerate(turned_all)]
                guess = self.uv + self.flow if guesses is None else guesses[best]
                p1, ok = _lk_predicted(self.prev, img, self.uv, guess, self.cfg, self.deviation_px, st)
            self.deviation_px = self._deviation(p1, guess, ok)
            n_ok = int(ok.sum())
            st.dropped_tracks += len(ok) - n_ok
            if n_ok:
                moved = p1[ok] - self.uv[ok]
                motion = float(_median(_norm(moved)))
                shift = tuple(float(v) for v in _median(moved))
            if guesses is not None:  # each candidate's deviation, averaged over the last few frames
                dev = np.array([self._deviation(p1, g, ok) for g in guesses])
                old = self.turn_deviation_px
                a = DEVIATION_SMOOTHING
                self.turn_deviation_px = np.where(np.isfinite(old), (1.0 - a) * old + a * dev, dev)
            if n_ok < self.cfg.lost_fraction * len(self.uv):
                lost = True
                self.lost += 1
                st.lost += 1
                self.uv, self.ids, self.flow = self.uv[:0], self.ids[:0], self.flow[:0]
                self.rest = None
                self._anchor = None
            else:
                self.rest = None if turned_all is None or in_hold else \
                    np.stack([(p1 - t)[ok] for t in turned_all]).astype(np.float32)
                self.uv, self.ids, self.flow = p1[ok], self.ids[ok], p1[ok] - self.uv[ok]
                if self._anchor is not None:
                    self._in_anchor = self._in_anchor[ok]
        self.prev = img
        if self._anchor is None:
            self._replenish(img)
        st.tracks += len(self.uv)
        return TrackStep(motion, len(self.uv), lost, offset, shift)

    def start_hold(self, top_up: bool = False) -> None:
        """The current frame becomes the anchor (template) of a hold; ``top_up``: with new corners first, as
        between holds (a frame after a move that was tracked from the previous hold's anchor, a snapshot, may
        keep only part of its tracks).

        Each track moves to the sub-pixel corner under it (cornerSubPix): a track that came through a move
        carries the small errors of every frame it was followed in, and a new one sits on the detector's
        integer pixel; the corner itself is where the same point is found again in every hold.
        """
        if self.prev is None:
            return
        if top_up:
            self._replenish(self.prev)
        if len(self.uv) and self.cfg.corner_refinement_px > 0:
            crit = SUBPIX_CRITERIA
            half = int(self.cfg.corner_window_px) // 2
            ref = cv2.cornerSubPix(self.prev, self.uv.reshape(-1, 1, 2).copy(), (half, half), (-1, -1), crit)
            ref = ref.reshape(-1, 2)
            moved = np.linalg.norm(ref - self.uv, axis=1)
            ok = moved <= self.cfg.corner_refinement_px  # else no corner near it: it keeps its position
            self.uv = np.where(ok[:, None], ref, self.uv).astype(np.float32)
        self._anchor = (self.prev, self.uv.copy(), self.ids.copy())
        self._anchor_levels = grid_quantiles(self.prev) if self.cfg.undo_exposure else None
        self._in_anchor = np.arange(len(self.uv))

    def end_hold(self) -> None:
        self._anchor = None

    def positions(self) -> tuple:
        """(ids, uv (N, 2) float64) of the tracks in the last frame."""
        return self.ids.copy(), self.uv.astype(np.float64)


# ---------------------------------------------------------------------------
# Descriptors
# ---------------------------------------------------------------------------

@dataclass
class Features:
    """Keypoints (N, 2), descriptors (N, D) and keypoint scores (N,) of one image."""

    uv: np.ndarray
    desc: np.ndarray | None
    score: np.ndarray | None = None


ORIENTATION_RADIUS = 15  # px: the intensity-centroid patch of a feature's orientation (ORB's 31 px patch)
DESCRIPTOR_PAD_PX = 32  # the image is mirrored this far beyond its border before descriptors are computed


def _orientations(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Orientation (deg) of the patch around each point by its intensity centroid (as ORB orients keypoints)."""
    r = ORIENTATION_RADIUS
    size = 2 * r + 1
    pad = cv2.copyMakeBorder(img, r, r, r, r, cv2.BORDER_REFLECT_101).astype(np.float32)
    c = np.clip(np.rint(uv).astype(np.int64), 0, [img.shape[1] - 1, img.shape[0] - 1])
    patches = sliding_window_view(pad, (size, size))[c[:, 1], c[:, 0]]  # (N, size, size), centred on the points
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disc = (xx * xx + yy * yy <= r * r).astype(np.float32)
    m10 = np.einsum("nij,ij->n", patches, disc * xx)
    m01 = np.einsum("nij,ij->n", patches, disc * yy)
    return np.degrees(np.arctan2(m01, m10)) % 360.0


def describe(img: np.ndarray, uv: np.ndarray, cfg: TrackingConfig) -> tuple:
    """Descriptors of the patches at ``uv`` (N, 2): (desc (N, D) with rows of zeros where none, valid (N,)).

    ORB (or SIFT) of a patch oriented by its intensity centroid, so features rotated about the optical axis
    between two holds still match; points too close to the border have none.
    """
    uv = np.asarray(uv, float).reshape(-1, 2)
    if len(uv) == 0:
        return None, np.zeros(0, bool)
    ang = _orientations(img, uv)
    size = 31.0 if cfg.descriptor == "orb" else 16.0
    pad = DESCRIPTOR_PAD_PX  # mirrored border: a point near the edge still has a full patch
    padded = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_REFLECT_101)
    kps = [cv2.KeyPoint(float(x) + pad, float(y) + pad, size, float(a), 0, 0, int(k))
           for k, ((x, y), a) in enumerate(zip(uv.tolist(), ang.tolist()))]
    det = cv2.ORB_create(edgeThreshold=31, patchSize=31) if cfg.descriptor == "orb" else cv2.SIFT_create()
    kps, desc = det.compute(padded, kps)
    valid = np.zeros(len(uv), bool)
    if desc is None or not kps:
        return None, valid
    idx = np.fromiter((k.class_id for k in kps), np.int64, len(kps))
    out = np.zeros((len(uv), desc.shape[1]), desc.dtype)
    out[idx] = desc
    valid[idx] = True
    return out, valid


def match_features(a: Features, b: Features, cfg: TrackingConfig):
    """Index pairs (ia, ib): nearest neighbours passing the ratio test, each ``b`` feature used once (best kept)."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if a.desc is None or b.desc is None or len(a.uv) < 2 or len(b.uv) < 2:
        return empty
    norm, dtype = (cv2.NORM_L2, cv2.CV_32F) if cfg.descriptor == "sift" else (cv2.NORM_HAMMING, cv2.CV_32S)
    dist, nn = cv2.batchDistance(a.desc, b.desc, dtype, normType=norm, K=2)  # two nearest, as arrays
    ia = np.flatnonzero(dist[:, 0] < cfg.ratio * dist[:, 1])
    ib = nn[ia, 0].astype(np.int64)
    o = np.lexsort((dist[ia, 0], ib))  # by b index, best distance first
    ia, ib = ia[o], ib[o]
    first = np.ones(len(ib), bool)
    np.not_equal(ib[1:], ib[:-1], out=first[1:])
    return ia[first], ib[first]


# ---------------------------------------------------------------------------
# Verification
# ---------------------------------------------------------------------------

def verify_correspondences(cam: Camera, f1: np.ndarray, f2: np.ndarray, cfg: TrackingConfig) -> np.ndarray:
    """Inlier mask of bearing pairs (f1, f2) of one camera consistent with one essential matrix (RANSAC at
    ``ransac_threshold_px``); all False when there are too few to tell."""
    f1 = np.asarray(f1, float).reshape(-1, 3)
    f2 = np.asarray(f2, float).reshape(-1, 3)
    ok = np.zeros(len(f1), bool)
    idx = np.flatnonzero(in_front(f1, f2))
    if len(idx) < max(8, cfg.min_matches_per_camera):
        return ok
    found = essential_matrix(f1[idx], f2[idx], cfg.ransac_threshold_px / cam.focal_px, cfg.ransac_confidence)
    if found is None:
        return ok
    ok[idx[found[1]]] = True
    if ok.sum() < cfg.min_matches_per_camera:
        ok[:] = False
    return ok
