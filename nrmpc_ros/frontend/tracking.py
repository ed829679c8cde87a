"""Per-camera correspondences between a reference view and the current view.

Two ways, one config (:class:`TrackingConfig`):

- KLT: :class:`KltTracker` follows corners frame to frame through the motion
  (pyramidal Lucas-Kanade with a forward-backward check). Each track remembers
  where it was in the reference view and at the start of the current static
  window, which also measures image motion for static detection.
- Descriptors: ORB (default) or SIFT features of the two static views, ratio
  test + mutual best match; for static-only bags where views are 5-30 deg apart.

Both are spread over the image with grid bucketing and verified per camera
with an essential-matrix RANSAC on undistorted bearings (valid for pinhole and
fisheye models, and exact for each camera even when its bar bends).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import NamedTuple

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..cameras import pixels_to_bearings
from ..core.rig import Camera
from ..errors import InputError

MODES = ("auto", "klt", "descriptors")
DESCRIPTORS = ("orb", "sift")
CORNER_DETECTORS = ("fast", "gftt")
ORB_SCORES = ("harris", "fast")
RANSAC_METHODS = ("usac", "ransac")


@dataclass
class TrackingConfig:
    """Feature tracking and matching; pixel values refer to the camera's own image."""

    mode: str = "auto"  # auto: KLT tracks when enough survive from the reference view, else descriptors
    grid_rows: int = 6
    grid_cols: int = 8
    max_tracks: int = 150  # KLT tracks per camera
    replenish_fraction: float = 0.7  # detect new corners when fewer tracks than this fraction remain
    min_distance_px: float = 8.0
    corner_detector: str = "fast"  # new KLT corners: fast (FAST, strongest per grid cell) | gftt (Shi-Tomasi)
    fast_threshold: int = 12  # FAST intensity threshold (grey levels)
    corner_quality: float = 0.003  # goodFeaturesToTrack qualityLevel (corner_detector gftt)
    klt_window: int = 15
    klt_levels: int = 3
    fb_threshold_px: float = 0.7  # forward-backward round-trip error
    probe_tracks: int = 24  # after a still frame, follow this many tracks first (0: always track all) ...
    still_px: float = 0.25  # ... and when they moved at most this (median, px) skip the rest: the image is unchanged
    seed_from_features: bool = True  # tracks starting afresh (a jump): seed them with the view's ORB keypoints
    descriptor: str = "orb"  # orb | sift
    num_features: int = 300  # descriptor features detected per camera image
    orb_levels: int = 1  # ORB pyramid levels (scale factor 1.2): views differ by rotation, hardly by scale
    orb_score: str = "harris"  # ORB keypoint ranking: harris | fast
    ratio: float = 0.8  # Lowe ratio test
    subpixel: bool = False  # refine ORB keypoints with cornerSubPix (~1 ms per image; no gain on the bags)
    ransac: str = "usac"  # essential-matrix verification: usac (OpenCV USAC, SPRT + local optimisation) | ransac
    ransac_threshold_px: float = 1.0  # essential-matrix verification (Sampson distance)
    ransac_confidence: float = 0.999
    min_matches_per_camera: int = 12  # fewer verified matches: the camera contributes nothing
    max_matches_per_camera: int = 120  # bucketed cap handed to the estimator ...
    max_matches_total: int = 480  # ... raised to max_matches_total / cameras for rigs with few cameras
    min_klt_matches: int = 200  # auto: fewer verified KLT matches (or < half the cap) -> also try descriptors

    def __post_init__(self):
        for name, allowed in (("mode", MODES), ("corner_detector", CORNER_DETECTORS), ("ransac", RANSAC_METHODS),
                              ("orb_score", ORB_SCORES), ("descriptor", DESCRIPTORS)):
            value = getattr(self, name)
            if value not in allowed:
                raise InputError("tracking config", f"{name} must be one of {', '.join(allowed)}, got {value!r}", name)
        for name in ("grid_rows", "grid_cols", "max_tracks", "num_features", "max_matches_per_camera", "orb_levels"):
            if int(getattr(self, name)) < 1:
                raise InputError("tracking config", "must be >= 1", name)
        if not 0 < self.ratio <= 1:
            raise InputError("tracking config", f"must be in (0, 1], got {self.ratio}", "ratio")

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "tracking config") -> TrackingConfig:
        d = dict(d or {})
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise InputError(source, f"unknown option (allowed: {', '.join(sorted(names))})", unknown[0])
        return cls(**d)


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
        fb_px: float | None = None):
    """Forward-backward LK: tracked points and a validity mask (window, levels, threshold default to the config's)."""
    if len(p0) == 0:
        return p0.copy(), np.zeros(0, bool)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.03)
    w = int(cfg.klt_window if window is None else window)
    win, levels = (w, w), int(cfg.klt_levels if levels is None else levels)
    p0 = np.ascontiguousarray(p0, np.float32)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, None, winSize=win, maxLevel=levels, criteria=crit)
    h, w = img1.shape
    ok = st1.ravel() == 1
    ok &= (p1[:, 0] >= 0) & (p1[:, 1] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] <= h - 1)
    idx = np.flatnonzero(ok)
    if len(idx):  # backward check only for what the forward pass kept
        p0b, st2, _ = cv2.calcOpticalFlowPyrLK(img1, img0, np.ascontiguousarray(p1[idx]), None, winSize=win,
                                               maxLevel=levels, criteria=crit)
        fb = cfg.fb_threshold_px if fb_px is None else fb_px
        good = (st2.ravel() == 1) & (np.linalg.norm(p0b - p0[idx], axis=1) < fb)
        ok[idx[~good]] = False
    return p1, ok


PATCH_MARGIN_PX = 4  # the still check's patches reach this far beyond the LK window


def _lk_patches(img0, img1, p0: np.ndarray, window: int, criteria):
    """Single-level LK of a few points ``p0`` (N, 2) float32 on patches around them: (motions (N, 2), status (N,)).

    The patches (the window plus ``PATCH_MARGIN_PX`` on each side, shifted
    inside the image) of both images are stacked into two narrow mosaics, so
    LK computes image derivatives on those only, not on the whole images (for
    24 points a twentieth of a VGA image). Motions within the margin come out
    as on the full images; larger ones come out wrong, but not small.
    """
    half = window // 2 + PATCH_MARGIN_PX
    size = 2 * half + 1
    h, w = img0.shape
    if h < size or w < size:
        p1, st, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, None, winSize=(window, window), maxLevel=0,
                                             criteria=criteria)
        return p1 - p0, st.ravel() == 1
    o = np.clip(np.floor(p0).astype(np.int64) - half, 0, [w - size, h - size])  # patch corners (x, y)
    m0 = sliding_window_view(img0, (size, size))[o[:, 1], o[:, 0]].reshape(-1, size)
    m1 = sliding_window_view(img1, (size, size))[o[:, 1], o[:, 0]].reshape(-1, size)
    q = p0 - o.astype(np.float32)
    q[:, 1] += size * np.arange(len(q), dtype=np.float32)  # patch k starts at mosaic row k * size
    q1, st, _ = cv2.calcOpticalFlowPyrLK(m0, m1, q, None, winSize=(window, window), maxLevel=0, criteria=criteria)
    return q1 - q, st.ravel() == 1


PROBE_SCALE = 4  # the probe's forward-backward check of a frame that moved runs on images up to 4x smaller ...
PROBE_MIN_WIDTH = 160  # ... and at least this wide
PROBE_FB_PX = 0.1  # its forward-backward threshold (px of the small image)


class Snapshot(NamedTuple):
    """Tracks of a view's frame: ids, positions (N, 2) and, when they were seeded from them, its features."""

    ids: np.ndarray
    uv: np.ndarray
    features: Features | None = None


class KltTracker:
    """KLT tracks of one camera with persistent ids; a :class:`Snapshot` of a view pairs it with later frames.

    ``uv`` are the track positions in ``prev``, the last frame tracked in
    full. After a still frame, a new frame first tracks ``probe_tracks``
    spread tracks: when they moved at most ``still_px`` the image is taken as
    unchanged and nothing else is done (``prev`` and ``uv`` stay: the frames
    of a static window cost one small LK); when most of them are lost (a jump
    between static snapshots) all tracks are dropped without tracking them
    and new corners are detected; otherwise all tracks are followed.

    Tracks that start afresh (first frame, or lost) are seeded with the
    frame's descriptor keypoints when ``seed_from_features`` (ORB, mode not
    ``klt``): the features are kept with the frame while it stays ``prev``
    and go into the snapshot, so a static view after a jump (the static-only
    bags) detects corners once for both tracking and matching.
    """

    def __init__(self, cfg: TrackingConfig):
        self.cfg = cfg
        self.prev = None
        self.uv = np.zeros((0, 2), np.float32)
        self.ids = np.zeros(0, np.int64)
        self.anchor_uv = np.zeros((0, 2), np.float32)  # NaN: born after the anchor
        self._next_id = 0
        self._still = False  # the last frame moved at most still_px: probe the next one first
        self._fresh = False  # corners were detected in prev (since it became prev)
        self._probe_motion = 0.0  # median motion (px) of the probe of the last frame skipped as unchanged
        self.features: Features | None = None  # descriptor features of prev when the tracks were seeded from them
        self._small_prev = None  # (prev, prev reduced PROBE_SCALE times) for the probe's jump check
        self._probe_uv = None  # (uv, its probe tracks): the probe is spread again when uv changes
        self.skipped = 0  # frames taken as unchanged (probe only)
        self.lost = 0  # frames where the probe lost the tracks (all dropped, not tracked)

    def _replenish(self, img, force=False):
        n = len(self.uv)
        if n >= self.cfg.max_tracks or (not force and n >= self.cfg.replenish_fraction * self.cfg.max_tracks):
            return
        mask = None
        if n:
            mask = np.full(img.shape, 255, np.uint8)
            r = max(1, int(self.cfg.min_distance_px))
            for u, v in self.uv.astype(int):
                cv2.circle(mask, (int(u), int(v)), r, 0, -1)
        cfg = self.cfg
        if n == 0 and cfg.seed_from_features and cfg.descriptor == "orb" and cfg.mode != "klt":
            self.features = f = detect_features(img, cfg)
            new = f.uv[spread_corners(f.uv, f.score, (img.shape[1], img.shape[0]), cfg, cfg.max_tracks)]
            new = new.astype(np.float32).reshape(-1, 2)
        else:
            new = detect_corners(img, cfg, cfg.max_tracks - n, mask)
        self._fresh = True  # corners of this frame were just detected: a snapshot needs no new search
        self.uv = np.concatenate([self.uv, new])
        self.ids = np.concatenate([self.ids, self._next_id + np.arange(len(new))])
        self._next_id += len(new)
        self.anchor_uv = np.concatenate([self.anchor_uv, np.full((len(new), 2), np.nan, np.float32)])

    def _probe(self, img) -> str:
        """'still' (image unchanged), 'lost' (tracks cannot follow) or 'moved', from a few spread tracks.

        Still: forward LK at full resolution, single level, on patches around
        the tracks only (:func:`_lk_patches`, ~0.15 ms) finds them within
        ``still_px``. Otherwise the same tracks go through a
        pyramidal forward-backward LK on images ``PROBE_SCALE`` times smaller
        (it follows motions of 100+ px for a third of the cost at full
        resolution): when fewer than a quarter survive, the tracks are lost (a
        jump between static snapshots) and the costly LK of all tracks is
        skipped.
        """
        if self._probe_uv is None or self._probe_uv[0] is not self.uv:  # the tracks changed: spread a new probe
            sel = bucket(self.uv, (img.shape[1], img.shape[0]), self.cfg.grid_rows, self.cfg.grid_cols,
                         int(self.cfg.probe_tracks))
            self._probe_uv = (self.uv, np.ascontiguousarray(self.uv[sel], np.float32))
        p0 = self._probe_uv[1]
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 10, 0.01)
        motion, st = _lk_patches(self.prev, img, p0, int(self.cfg.klt_window), crit)
        d = np.linalg.norm(motion, axis=1)[st]
        if len(d) >= 0.75 * len(p0) and float(np.median(d)) <= self.cfg.still_px:
            self._probe_motion = float(np.median(d))
            return "still"
        scale = max(1, min(PROBE_SCALE, img.shape[1] // PROBE_MIN_WIDTH))
        small = self._small(img, scale)
        if self._small_prev is None or self._small_prev[0] is not self.prev:
            self._small_prev = (self.prev, self._small(self.prev, scale))
        _, ok = _lk(self._small_prev[1], small, p0 / scale, self.cfg, window=9, levels=2, fb_px=PROBE_FB_PX)
        self._small_prev = (img, small)  # img becomes prev unless it is skipped as still (it is not)
        return "lost" if ok.sum() < 0.25 * len(p0) else "moved"

    @staticmethod
    def _small(img, scale: int):
        """``img`` reduced ``scale`` times by area averaging, by halvings where possible (INTER_AREA's fast case)."""
        size = (img.shape[1] // scale, img.shape[0] // scale)
        while scale % 2 == 0:
            img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
            scale //= 2
        return img if scale == 1 else cv2.resize(img, size, interpolation=cv2.INTER_AREA)

    def track(self, img: np.ndarray) -> None:
        """Follow the tracks into ``img`` (dropping failures) and top them up with new corners."""
        probe = self.prev is not None and self._still and self.cfg.probe_tracks > 0 and len(self.uv) >= 8
        state = self._probe(img) if probe else "moved"
        if state == "still":
            self.skipped += 1
            return
        self._fresh = False
        self._probe_motion = 0.0
        self.features = None  # prev changes
        if self.prev is not None and len(self.uv) and state != "lost":
            p1, ok = _lk(self.prev, img, self.uv, self.cfg)
            step = np.linalg.norm(p1[ok] - self.uv[ok], axis=1)
            self._still = bool(len(step)) and float(np.median(step)) <= self.cfg.still_px
            self.uv, self.ids, self.anchor_uv = p1[ok], self.ids[ok], self.anchor_uv[ok]
        else:  # first frame, or the tracks were lost: start afresh, probe the next frame first
            if state == "lost":
                self.lost += 1
            self.uv, self.ids, self.anchor_uv = self.uv[:0], self.ids[:0], self.anchor_uv[:0]
            self._still = True
        self.prev = img
        self._replenish(img)

    def set_anchor(self) -> None:
        """Image motion is measured from the current frame on (start of a static window)."""
        self.anchor_uv = self.uv.copy()
        self._probe_motion = 0.0

    def anchor_motion(self):
        """(median displacement in px since the anchor, number of tracks alive since the anchor)."""
        ok = np.isfinite(self.anchor_uv[:, 0])
        if not ok.any():
            return np.inf, 0
        motion = float(np.median(np.linalg.norm(self.uv[ok] - self.anchor_uv[ok], axis=1)))
        return motion + self._probe_motion, int(ok.sum())

    def snapshot(self) -> Snapshot:
        """Tracks of the current frame, topped up to max_tracks first (for a view that may become a reference)."""
        if self.prev is not None and not self._fresh:
            self._replenish(self.prev, force=True)
        return Snapshot(self.ids.copy(), self.uv.astype(np.float64), self.features)

    def pairs_since(self, snap: Snapshot):
        """(uv in the snapshot's frame, uv now) of tracks alive since ``snap``."""
        ids, uv = snap[0], snap[1]
        _, i_old, i_now = np.intersect1d(ids, self.ids, assume_unique=True, return_indices=True)
        return uv[i_old], self.uv[i_now].astype(np.float64)


# ---------------------------------------------------------------------------
# Descriptors
# ---------------------------------------------------------------------------

@dataclass
class Features:
    """Keypoints (N, 2), descriptors (N, D) and keypoint scores (N,) of one image."""

    uv: np.ndarray
    desc: np.ndarray | None
    score: np.ndarray | None = None


def _detector(cfg: TrackingConfig):
    """The OpenCV feature detector of ``cfg``."""
    n = int(cfg.num_features)
    if cfg.descriptor == "sift":
        return cv2.SIFT_create(nfeatures=2 * n)
    score = cv2.ORB_HARRIS_SCORE if cfg.orb_score == "harris" else cv2.ORB_FAST_SCORE
    return cv2.ORB_create(nfeatures=2 * n, nlevels=int(cfg.orb_levels), fastThreshold=10, scoreType=score)


def detect_features(img: np.ndarray, cfg: TrackingConfig) -> Features:
    """Grid-bucketed ORB or SIFT features (strongest per cell), optionally refined to sub-pixel."""
    n = int(cfg.num_features)
    det = _detector(cfg)
    kps = det.detect(img, None)
    if not kps:
        return Features(np.zeros((0, 2)), None)
    uv = cv2.KeyPoint_convert(kps).reshape(-1, 2)
    resp = np.fromiter((k.response for k in kps), float, len(kps))
    keep = bucket(uv, (img.shape[1], img.shape[0]), cfg.grid_rows, cfg.grid_cols, n,
                  order=np.argsort(-resp, kind="stable"))
    kps, desc = det.compute(img, list(map(kps.__getitem__, keep.tolist())))
    if desc is None or not kps:
        return Features(np.zeros((0, 2)), None)
    uv = cv2.KeyPoint_convert(kps).reshape(-1, 2).astype(np.float64)
    resp = np.fromiter((k.response for k in kps), float, len(kps))
    if cfg.subpixel and cfg.descriptor == "orb":
        level0 = np.fromiter((k.octave == 0 for k in kps), bool, len(kps))
        if level0.any():
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)
            p = uv[level0].astype(np.float32).reshape(-1, 1, 2)
            ref = cv2.cornerSubPix(img, p, (3, 3), (-1, -1), crit).reshape(-1, 2)
            moved = np.linalg.norm(ref - uv[level0], axis=1) < 1.5
            sub = uv[level0]
            sub[moved] = ref[moved]
            uv[level0] = sub
    return Features(uv, desc, resp)


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

def verify_pairs(cam: Camera, uv1: np.ndarray, uv2: np.ndarray, cfg: TrackingConfig, cap: int | None = None):
    """Bearings (f1, f2) and indices of pairs consistent with one essential matrix (RANSAC), at most ``cap``.

    The kept pairs are spread over the image by grid bucketing; ``cap``
    defaults to ``cfg.max_matches_per_camera``.
    """
    uv1 = np.asarray(uv1, float).reshape(-1, 2)
    uv2 = np.asarray(uv2, float).reshape(-1, 2)
    empty = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64))
    if len(uv1) < max(8, cfg.min_matches_per_camera):
        return empty
    f1 = pixels_to_bearings(cam, uv1)
    f2 = pixels_to_bearings(cam, uv2)
    front = (f1[:, 2] > 0.1) & (f2[:, 2] > 0.1)  # normalised coordinates need z > 0 (up to ~84 deg off axis)
    idx = np.flatnonzero(front)
    if len(idx) < max(8, cfg.min_matches_per_camera):
        return empty
    x1 = f1[idx, :2] / f1[idx, 2:]
    x2 = f2[idx, :2] / f2[idx, 2:]
    thr = cfg.ransac_threshold_px / cam.focal_px
    method = cv2.USAC_DEFAULT if cfg.ransac == "usac" else cv2.RANSAC
    E, mask = cv2.findEssentialMat(x1, x2, np.eye(3), method=method, prob=cfg.ransac_confidence, threshold=thr)
    if E is None or mask is None:
        return empty
    idx = idx[mask.ravel()[: len(idx)] > 0]
    if len(idx) < cfg.min_matches_per_camera:
        return empty
    cap = int(cfg.max_matches_per_camera if cap is None else cap)
    idx = idx[bucket(uv2[idx], cam.resolution, cfg.grid_rows, cfg.grid_cols, cap)]
    return f1[idx], f2[idx], idx
