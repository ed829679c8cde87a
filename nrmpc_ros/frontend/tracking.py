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

from ..config import check, option
from ..core.rig import Camera

MODES = ("auto", "klt", "descriptors")
DESCRIPTORS = ("orb", "sift")
CORNER_DETECTORS = ("fast", "gftt")
RANSAC_METHODS = ("usac", "ransac")


@dataclass
class TrackingConfig:
    """Feature tracking and matching; pixel values refer to the camera's own image."""

    mode: str = option("auto", "how holds are linked: auto (KLT identity and, where too few tracks survived a "
                       "move, descriptors), klt (identity only), descriptors (every hold matched afresh)",
                       choices=MODES)
    grid_rows: int = option(6, "rows of the bucketing grid that spreads corners over the image", lo=1, hi=100)
    grid_cols: int = option(8, "columns of the bucketing grid", lo=1, hi=100)
    max_tracks: int = option(150, "KLT tracks per camera", lo=8, hi=5000)
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
    lost_fraction: float = option(0.25, "fewer tracks than this share survive a frame: they are lost (a jump) "
                                  "and start afresh", lo=0.0, hi=1.0, lo_open=True)
    corner_window_px: int = option(11, "sub-pixel corner search window at a hold's anchor (px)", lo=3, hi=31)
    corner_refinement_px: float = option(3.0, "a track the sub-pixel corner search moves further than this "
                                         "(px) keeps its position; 0 turns the search off", lo=0.0, hi=10.0)
    descriptor: str = option("orb", "descriptors that link holds without surviving tracks: orb or sift",
                             choices=DESCRIPTORS)
    ratio: float = option(0.8, "Lowe's ratio test of descriptor matches", lo=0.0, hi=1.0, lo_open=True)
    ransac: str = option("usac", "essential-matrix verification: usac (OpenCV USAC) or ransac",
                         choices=RANSAC_METHODS)
    ransac_threshold_px: float = option(1.0, "essential-matrix verification threshold (Sampson distance, px)",
                                        lo=0.0, hi=20.0, lo_open=True)
    ransac_confidence: float = option(0.999, "essential-matrix RANSAC confidence", lo=0.5, hi=1.0, lo_open=True)
    min_matches_per_camera: int = option(12, "fewer verified links between two holds: the camera links nothing",
                                         lo=8, hi=10000)
    min_klt_links: int = option(40, "fewer verified KLT links of a camera to its previous hold: descriptors too",
                                lo=0, hi=10000)

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
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)
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


class TrackStep(NamedTuple):
    """What one frame did to a camera's tracks: median motion since the previous frame (px, NaN when unknown),
    tracks alive, whether the tracks were lost (a jump: too few survived, all were dropped) and, inside a
    hold, the median offset from the hold's anchor frame (px, NaN outside a hold)."""

    motion_px: float
    tracks: int
    lost: bool
    offset_px: float = math.nan


class KltTracker:
    """KLT tracks of one camera with persistent ids.

    Between holds the tracks follow the image frame to frame (pyramidal
    Lucas-Kanade with a forward-backward check); when fewer than
    ``lost_fraction`` of them survive (a jump, e.g. between snapshots) all are
    dropped and new corners are detected, with new ids. Inside a hold
    (:meth:`start_hold`) every frame is tracked from the hold's anchor frame,
    the template, starting from the previous positions:
    positions of one hold never drift from frame to frame, so averaging them
    reduces the noise. No corners are added during a hold.
    """

    def __init__(self, cfg: TrackingConfig):
        self.cfg = cfg
        self.prev = None  # last image
        self.uv = np.zeros((0, 2), np.float32)
        self.ids = np.zeros(0, np.int64)
        self._next_id = 0
        self._anchor = None  # (image, uv, ids) of the hold's first frame
        self.lost = 0  # frames where the tracks were lost and started afresh

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
        self.uv = np.concatenate([self.uv, new])
        self.ids = np.concatenate([self.ids, self._next_id + np.arange(len(new))])
        self._next_id += len(new)

    def track(self, img: np.ndarray) -> TrackStep:
        """Follow the tracks into ``img``; outside a hold, top them up with new corners."""
        lost = False
        motion = offset = math.nan
        if self.prev is not None and len(self.uv):
            if self._anchor is not None:
                a_img, a_uv, a_ids = self._anchor
                keep = np.isin(a_ids, self.ids)
                p1, ok = _lk(a_img, img, a_uv[keep], self.cfg, guess=self.uv)
                if ok.any():
                    offset = float(np.median(np.linalg.norm(p1[ok] - a_uv[keep][ok], axis=1)))
            else:
                p1, ok = _lk(self.prev, img, self.uv, self.cfg)
            if ok.any():
                motion = float(np.median(np.linalg.norm(p1[ok] - self.uv[ok], axis=1)))
            if ok.sum() < self.cfg.lost_fraction * len(self.uv):
                lost = True
                self.lost += 1
                self.uv, self.ids = self.uv[:0], self.ids[:0]
                self._anchor = None
            else:
                self.uv, self.ids = p1[ok], self.ids[ok]
        self.prev = img
        if self._anchor is None:
            self._replenish(img)
        return TrackStep(motion, len(self.uv), lost, offset)

    def start_hold(self) -> None:
        """The current frame becomes the anchor (template) of a hold.

        Each track moves to the sub-pixel corner under it (cornerSubPix): a track that came through a move
        carries the small errors of every frame it was followed in, and a new one sits on the detector's
        integer pixel; the corner itself is where the same point is found again in every hold.
        """
        if self.prev is None:
            return
        if len(self.uv) and self.cfg.corner_refinement_px > 0:
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.001)
            half = int(self.cfg.corner_window_px) // 2
            ref = cv2.cornerSubPix(self.prev, self.uv.reshape(-1, 1, 2).copy(), (half, half), (-1, -1), crit)
            ref = ref.reshape(-1, 2)
            moved = np.linalg.norm(ref - self.uv, axis=1)
            ok = moved <= self.cfg.corner_refinement_px  # else no corner near it: it keeps its position
            self.uv = np.where(ok[:, None], ref, self.uv).astype(np.float32)
        self._anchor = (self.prev, self.uv.copy(), self.ids.copy())

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
    front = (f1[:, 2] > 0.1) & (f2[:, 2] > 0.1)  # normalised coordinates need z > 0 (up to ~84 deg off axis)
    idx = np.flatnonzero(front)
    if len(idx) < max(8, cfg.min_matches_per_camera):
        return ok
    x1 = f1[idx, :2] / f1[idx, 2:]
    x2 = f2[idx, :2] / f2[idx, 2:]
    thr = cfg.ransac_threshold_px / cam.focal_px
    method = cv2.USAC_DEFAULT if cfg.ransac == "usac" else cv2.RANSAC
    E, mask = cv2.findEssentialMat(x1, x2, np.eye(3), method=method, prob=cfg.ransac_confidence, threshold=thr)
    if E is None or mask is None:
        return ok
    ok[idx[mask.ravel()[: len(idx)] > 0]] = True
    if ok.sum() < cfg.min_matches_per_camera:
        ok[:] = False
    return ok
