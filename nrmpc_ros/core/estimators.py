"""The three estimators (docs/CONVENTIONS.md, Estimators): 6pt-nonbending, 6pt-bending, 4pt-bending.

Each is RANSAC (ours, with a PoseLib minimal solver) followed by the robust
bundle adjustment of :mod:`.bundle`. ``estimate`` is the stable entry point.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.random import default_rng  # imported here, not lazily at the first estimate (~15 ms)

from ..config import check, from_mapping, option
from ..errors import EstimationError, InputError
from .bundle import gravity_covariance, largest_sigma, refine_two_view, two_view_priors
from .deformation import deformed_extrinsics, rays
from .gravity_init import (
    camera_rotations,
    gravity_rotation_hypotheses,
    hinted_hypothesis,
    start_translation,
)
from .loss import msac_score
from .matches import Matches
from .minimal import UprightFrames, solve_6pt
from .ransac import RansacOptions, ransac
from .residuals import two_view_angular_errors
from .rig import Rig
from .so3 import angle_between, fibonacci_sphere, normalize

METHODS = ("6pt-nonbending", "6pt-bending", "4pt-bending")


MINIMAL_SAMPLE = {"6pt-nonbending": 6, "6pt-bending": 6, "4pt-bending": 4}  # correspondences each solver needs


def pair_method(method: str, has_gravity: bool) -> str:
    """The estimator for one pair of a sequence estimated with ``method``: 4pt-bending needs gravity measured in
    both views, and a pair without it falls back to 6pt-bending (vision only); other methods are kept."""
    return "6pt-bending" if method == "4pt-bending" and not has_gravity else method

INLIER_CHANGE_SHARE = 0.01  # the refinement is repeated while the inlier set changes by more than this share
SCORE_POINTS = 50  # correspondences scoring the full pose of each gravity hypothesis (parallel bars)
START_TOL = 1e-3  # relative cost decrease that ends a start's bundle adjustment (starts are only compared)
# A start takes its pose from the camera rotations (rotation) and least squares (translation) when that pose
# explains this share of the correspondences at the loose threshold; otherwise a 6-point RANSAC on the bent
# Plucker lines gives it (each gen_relpose_6pt call costs ~1 ms), which may stop after START_MIN_SAMPLES samples
# once the inlier ratio says it can: it only has to give the start's translation and inliers
START_FIT_SHARE = 0.5
START_MIN_SAMPLES = 2
WEAK_START_MIN_SAMPLES = 5  # ... but on parallel bars the basins are close and the starts' models decide them
# On parallel bars a start in a wrong basin can explain as many correspondences as the right one: the search
# stops at a start that explains the data only once this many starts have been refined
WEAK_MIN_STARTS = 2
CAMERA_THRESHOLD_FACTOR = 3.0  # the cameras' own epipolar geometry accepts errors up to this times threshold_px


@dataclass
class EstimatorOptions:
    """Tuning of the estimators. Thresholds are in pixels, turned into angles with the rig's mean focal length."""

    loose_threshold_px: float = option(20.0, "6-point RANSAC with canonical extrinsics (px; bending is a model "
                                       "error there)", lo=0.0, hi=1e4, lo_open=True)
    threshold_px: float = option(2.0, "inliers under the bending model: 4-point RANSAC, final inliers (px)",
                                 lo=0.0, hi=1e4, lo_open=True)
    confidence: float = option(0.999, "RANSAC confidence", lo=0.5, hi=1.0, lo_open=True)
    max_iterations_6pt: int = option(150, "6-point RANSAC samples at most", lo=1, hi=1000000)
    max_iterations_4pt: int = option(1000, "4-point RANSAC samples at most", lo=1, hi=1000000)
    patience_6pt: int = option(30, "stop once the best 6-point model has not improved for this many samples",
                               lo=1, hi=1000000)
    start_iterations_6pt: int = option(12, "6-point samples per gravity start in 6pt-bending", lo=1, hi=1000000)
    start_ba_iterations: int = option(6, "bundle-adjustment iterations that compare gravity starts", lo=1,
                                      hi=10000)
    weak_geometry_starts: int = option(6, "gravity starts when all observing cameras sit on parallel bars", lo=1,
                                       hi=1000)
    patience_4pt: int = option(200, "stop once the best 4-point model has not improved for this many samples",
                               lo=1, hi=1000000)
    gravity_hypotheses: int = option(200, "gravity directions scored cheaply in 6pt-bending before refining",
                                     lo=6, hi=100000)
    gravity_refine_starts: int = option(3, "best distinct gravity hypotheses refined by bundle adjustment", lo=1,
                                        hi=1000)
    gravity_prior_sigma: float = option(0.005, "4pt-bending: std of the measured gravity's prior (rad); inf "
                                        "drops the prior", lo=0.0, lo_open=True)
    huber_k: float = option(3.0, "Huber threshold on the 2-D residual norm (robust sigmas)", lo=0.0, hi=1e3,
                            lo_open=True)
    max_ba_iterations: int = option(30, "bundle-adjustment iterations per refinement", lo=1, hi=10000)
    subset_size: int = option(150, "correspondences used while comparing gravity starts", lo=8, hi=10000000)
    final_refinement: bool = option(True, "6pt-bending: robust refinement on all correspondences after the best "
                                    "start (off where a joint adjustment over a sequence follows)")
    stop_at_explaining_start: bool = option(True, "6pt-bending: stop at the first gravity start that explains the "
                                            "correspondences within threshold_px (off: every start refined, its "
                                            "basin a candidate: where a joint cost chooses among them)")

    def __post_init__(self) -> None:
        check(self, "estimator options")

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "estimator options") -> EstimatorOptions:
        return from_mapping(cls, d, source)


_ARRAY_FIELDS = frozenset({"measured_gravity", "cov_rotation", "cov_translation", "cov_gravity_tangent",
                           "cov_gravity"})


@dataclass(eq=False)
class EstimateInfo:
    """Diagnostics of one :class:`Estimate` (docs/CONVENTIONS.md, Python API): why it failed, how the search
    went, and the covariances of the final bundle adjustment.

    A field holds its default (None, no hint, no candidates) where the method did not record it: each
    method fills only what it measures (the gravity fields stay None for ``6pt-nonbending``). Covariances
    are the final bundle adjustment's: rotation (rad^2, 3x3, tangent space), translation (m^2, 3x3),
    gravity's two tangent directions (rad^2, 2x2) and gravity itself (m^2/s^4, 3x3, rank 2). ``eq=False``:
    instances compare by identity (arrays have no single truth value).
    """

    reason: str | None = None  # why there is no pose (success False)
    ransac_iterations: int | None = None  # minimal samples drawn, all RANSAC stages together
    stage1_inliers: int | None = None  # inliers of the first RANSAC (rigid 6-point, or 4-point on measured gravity)
    cameras_with_rotation: int | None = None  # 6pt-bending: cameras whose own epipolar geometry gave a rotation
    camera_inliers: int | None = None  # ... and the correspondences it accepted (None: fewer than two such cameras)
    gravity_hint: bool = False  # 6pt-bending started from a given gravity_hint only
    gravity_starts: int | None = None  # 6pt-bending: gravity starts refined
    mirrored_start: bool | None = None  # parallel bars: whether a mirrored or reversed start won (None: not tried)
    gravity_candidates: tuple[np.ndarray, ...] = ()  # refined gravity of every start, best MSAC score first
    candidate_poses: tuple[np.ndarray, ...] = ()  # ... and its pose [R | t] (3, 4): a basin is gravity and pose
    msac_score_rad2: float | None = None  # 6pt-bending: MSAC score of all correspondences at the threshold
    measured_gravity: np.ndarray | None = None  # 4pt-bending: (2, 3) measured gravity, each view's body frame
    gravity_unobservable: str | None = None  # why there is no gravity although the method estimates one
    sigma_rad: float | None = None  # robust noise scale of the final bundle adjustment (rad)
    ba_iterations: int | None = None  # its iterations
    cov_rotation: np.ndarray | None = None  # (3, 3)
    cov_translation: np.ndarray | None = None  # (3, 3)
    cov_gravity_tangent: np.ndarray | None = None  # (2, 2)
    cov_gravity: np.ndarray | None = None  # (3, 3)
    gravity_sigma_rad: float | None = None  # largest angular std of gravity

    def _recorded(self) -> Iterator[tuple[str, Any]]:
        """(name, value) of the fields not at their default."""
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None or (type(value) in (bool, tuple) and value == f.default):
                continue
            yield f.name, value

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: arrays as nested lists, fields at their default left out (what was recorded)."""
        out = {}
        for name, value in self._recorded():
            if isinstance(value, tuple):
                value = [np.asarray(v).tolist() for v in value]
            elif isinstance(value, np.ndarray):
                value = value.tolist()
            out[name] = value
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EstimateInfo:
        """The inverse of :meth:`as_dict`: lists become float arrays again; unknown keys are an error."""
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise KeyError(f"not estimate diagnostics: {', '.join(unknown)}")
        values = dict(d)
        for name, value in d.items():
            if name in ("gravity_candidates", "candidate_poses"):
                values[name] = tuple(np.asarray(v, dtype=float) for v in value)
            elif name in _ARRAY_FIELDS and value is not None:
                values[name] = np.asarray(value, dtype=float)
        return cls(**values)


@dataclass
class Estimate:
    """Result of :func:`estimate`: (R, t) maps view 2 into view 1; gravity in view 1's body frame (m/s^2)."""

    method: str
    success: bool
    R: np.ndarray | None = None
    t: np.ndarray | None = None
    gravity: np.ndarray | None = None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    time_s: float = 0.0
    info: EstimateInfo = field(default_factory=EstimateInfo)

    @property
    def num_inliers(self) -> int:
        """Number of inlier correspondences."""
        return int(len(self.inliers))

    @property
    def gravity2(self) -> np.ndarray | None:
        """Gravity in view 2's body frame, g' = R^T g."""
        if self.gravity is None or self.R is None:
            return None
        return self.R.T @ self.gravity

    def to_json(self, matches_path: str | None = None) -> dict[str, Any]:
        """The result object of docs/CONVENTIONS.md (Python API); a failed estimate also says why (``reason``)."""
        out = {
            "matches": matches_path,
            "method": self.method,
            "success": bool(self.success),
            "R": None if self.R is None else self.R.tolist(),
            "t": None if self.t is None else self.t.tolist(),
            "gravity": None if self.gravity is None else self.gravity.tolist(),
            "num_inliers": self.num_inliers,
            "inliers": [int(i) for i in self.inliers],
            "time_s": self.time_s,
        }
        if not self.success:
            out["reason"] = "no reason recorded" if self.info.reason is None else str(self.info.reason)
        return out


# ---------------------------------------------------------------------------
# RANSAC problems
# ---------------------------------------------------------------------------

Pose = tuple[np.ndarray, np.ndarray]  # (R, t): view 2 into view 1


class _RayProblem:
    """Rays of both views fixed (extrinsics at given gravity); errors are angular (rad)."""

    def __init__(self, o1: np.ndarray, d1: np.ndarray, o2: np.ndarray, d2: np.ndarray):
        self.o1, self.d1, self.o2, self.d2 = o1, d1, o2, d2
        self.num_data = len(o1)

    def errors(self, models: list[Pose], idx: np.ndarray | None = None) -> np.ndarray:
        """Angular errors (rad) of the correspondences (all, or idx) under each model: (len(models), n)."""
        R = np.array([m[0] for m in models])
        t = np.array([m[1] for m in models])
        if idx is None:
            return two_view_angular_errors(self.o1, self.d1, self.o2, self.d2, R, t)
        return two_view_angular_errors(self.o1[idx], self.d1[idx], self.o2[idx], self.d2[idx], R, t)


class SixPointProblem(_RayProblem):
    """RANSAC problem of the generalized 6-point relative pose on fixed rays."""

    sample_size = 6

    def generate(self, s: np.ndarray) -> list[Pose]:
        return solve_6pt(self.o1[s], self.d1[s], self.o2[s], self.d2[s])


class UprightFourPointProblem(_RayProblem):
    """RANSAC problem of the upright 4-point relative pose: rays and measured gravity g1, g2 (body frames)."""

    sample_size = 4

    def __init__(self, o1: np.ndarray, d1: np.ndarray, o2: np.ndarray, d2: np.ndarray, g1: np.ndarray,
                 g2: np.ndarray):
        super().__init__(o1, d1, o2, d2)
        self.frames = UprightFrames(g1, g2)

    def generate(self, s: np.ndarray) -> list[Pose]:
        return self.frames.solve(self.o1[s], self.d1[s], self.o2[s], self.d2[s])


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------

def _thresholds(rig: Rig, opts: EstimatorOptions):
    focal = float(np.mean([c.focal_px for c in rig.cameras]))
    return opts.loose_threshold_px / focal, opts.threshold_px / focal


def _bending_errors(rig, m: Matches, R, t, g):
    """Angular errors of all correspondences under the bending model at (R, t, g)."""
    o1, d1 = rays(rig, m.f1, m.cam, g)
    o2, d2 = rays(rig, m.f2, m.cam, None if g is None else R.T @ g)
    return two_view_angular_errors(o1, d1, o2, d2, R, t)


def _subset(rng, idx, k):
    return idx if len(idx) <= k else np.sort(rng.choice(idx, size=k, replace=False))


def _ransac_6pt(rig_rays: Rig, m: Matches, threshold, opts, rng, g=None, max_iterations=None, min_iterations=5):
    """6-point RANSAC on rays of rig_rays; g=None canonical, else (g1, g2) bends each view."""
    g1, g2 = (None, None) if g is None else g
    o1, d1 = rays(rig_rays, m.f1, m.cam, g1)
    o2, d2 = rays(rig_rays, m.f2, m.cam, g2)
    cap = int(opts.max_iterations_6pt if max_iterations is None else max_iterations)
    ro = RansacOptions(threshold=threshold, confidence=opts.confidence, max_iterations=cap,
                       min_iterations=min(int(min_iterations), cap),
                       patience=min(int(opts.patience_6pt), cap), local_optimization=False)
    return ransac(SixPointProblem(o1, d1, o2, d2), ro, rng, groups=m.cam)


def _refine_loop(rig, m, R, t, g, threshold, opts, prior=None, optimize_gravity=True, inliers=None):
    """Bundle adjustment on the inliers, re-score all correspondences, repeat while the inlier set grows.

    Returns (R, t, g, inliers, BundleResult or None, MSAC score of all correspondences at threshold, rad^2).
    """
    err = None
    if inliers is None:
        err = _bending_errors(rig, m, R, t, g)
        inliers = err < threshold
    res = None
    for _ in range(3):
        idx = np.flatnonzero(inliers)
        if len(idx) < 6:
            break
        res = refine_two_view(rig, m.f1[idx], m.f2[idx], m.cam[idx], R, t, g, optimize_gravity=optimize_gravity,
                              prior=prior, max_iter=int(opts.max_ba_iterations), huber_k=opts.huber_k)
        R, t = res.R, res.t
        g = res.g if optimize_gravity else g
        err = _bending_errors(rig, m, R, t, g)
        new_inliers = err < threshold
        changed = int(np.count_nonzero(new_inliers != inliers))
        inliers = new_inliers
        if changed <= max(2, INLIER_CHANGE_SHARE * inliers.sum()):
            break
    if err is None:
        err = _bending_errors(rig, m, R, t, g)
    return R, t, g, inliers, res, msac_score(err, threshold)


def _record_pose(info: EstimateInfo, res, optimize_gravity: bool) -> EstimateInfo:
    """Put the final bundle adjustment's noise scale, iterations and covariances (if any) into info."""
    if res is None:
        return info
    cov = np.array(res.covariance, dtype=float)
    info.sigma_rad, info.ba_iterations = float(res.sigma_rad), int(res.iterations)
    info.cov_rotation, info.cov_translation = cov[0:3, 0:3], cov[3:6, 3:6]
    if optimize_gravity and res.g is not None:
        cg = cov[6:8, 6:8]
        info.cov_gravity_tangent, info.cov_gravity = cg, np.asarray(gravity_covariance(res.g, cg), dtype=float)
        info.gravity_sigma_rad = largest_sigma(cg)
    return info


RIGID_REASON = "the rig has no flexible bar (every EI is inf or mass 0), so gravity is unobservable from vision"


# ---------------------------------------------------------------------------
# methods
# ---------------------------------------------------------------------------

def _six_point_nonbending(rig, m, opts, rng):
    loose, _ = _thresholds(rig, opts)
    rigid = rig.as_rigid()
    rr = _ransac_6pt(rigid, m, loose, opts, rng)
    if rr is None:
        return None
    R, t = rr.model
    R, t, _, inliers, res, _ = _refine_loop(rigid, m, R, t, None, loose, opts, optimize_gravity=False,
                                         inliers=rr.inliers)
    return R, t, None, inliers, _record_pose(EstimateInfo(ransac_iterations=int(rr.iterations)), res, False)


def score_gravity_hypotheses(rig: Rig, m: Matches, idx: np.ndarray, R: np.ndarray, t: np.ndarray,
                             hypotheses: np.ndarray, threshold: float) -> np.ndarray:
    """MSAC cost of each gravity hypothesis (K, 3) on correspondences idx at fixed (R, t)."""
    f1, f2, cam = m.f1[idx], m.f2[idx], m.cam[idx]
    w1, W1 = deformed_extrinsics(rig, hypotheses)
    w2, W2 = deformed_extrinsics(rig, hypotheses @ R)  # rows R^T g_k
    o1, d1 = w1[:, cam], np.einsum("knij,nj->kni", W1[:, cam], f1)
    o2, d2 = w2[:, cam], np.einsum("knij,nj->kni", W2[:, cam], f2)
    err = two_view_angular_errors(o1, d1, o2, d2, R, t)
    return msac_score(err, threshold, axis=1)


def _starts_from_rigid_fit(rig, m, opts, rng, loose, info: EstimateInfo, gravity_hint=None):
    """The paper's route: 6-point RANSAC with canonical extrinsics, then gravity hypotheses scored at that pose
    (or only the gravity_hint); the RANSAC's samples and inliers go into info."""
    rr = _ransac_6pt(rig.as_rigid(), m, loose, opts, rng)
    if rr is None:
        return []
    R0, t0 = rr.model
    idx = _subset(rng, np.flatnonzero(rr.inliers), int(opts.subset_size))
    info.ransac_iterations, info.stage1_inliers = int(rr.iterations), int(rr.num_inliers)
    if gravity_hint is not None:
        return [(R0, t0, gravity_hint, idx)]
    hyp = rig.gravity_magnitude * fibonacci_sphere(int(opts.gravity_hypotheses))
    costs = score_gravity_hypotheses(rig, m, idx, R0, t0, hyp, loose)
    starts = []
    for k in np.argsort(costs):
        if all(angle_between(hyp[k], s[2]) > 0.5 for s in starts):
            starts.append((R0, t0, hyp[k], idx))
        if len(starts) >= int(opts.gravity_refine_starts):
            break
    return starts


def _starts_from_camera_rotations(rig, m, opts, rng, loose, tight, num_starts, weak_geometry=False,
                                  gravity_hint=None):
    """Starts (R, t, g, idx) from per-camera rotations (see :mod:`.gravity_init`), and the mask of the
    correspondences the cameras' own epipolar geometry accepts.

    Each gravity hypothesis comes with the body rotation the cameras agree on
    when the bars bend under it (a weighted mean over the cameras, so the
    bas-relief ambiguity of one narrow camera averages out); the translation
    is then linear (least squares on the bent Plücker lines of the accepted
    correspondences, its sign checked). Only where that pose explains fewer
    than START_FIT_SHARE of them at the loose threshold does a 6-point RANSAC
    on the bent lines give (R, t) and inliers jointly over all cameras. With
    weak_geometry (parallel bars) the gravity grid is ranked by full-pose
    scores. With a gravity_hint (view 1), the only start is the hint and its
    rotation.
    """
    cams, Rc, counts, cam_inl = camera_rotations(m, rig.num_cameras, CAMERA_THRESHOLD_FACTOR * tight,
                                                 seed=int(rng.integers(1 << 30)))
    info = EstimateInfo(cameras_with_rotation=int(len(cams)), camera_inliers=int(cam_inl.sum()), ransac_iterations=0)
    if len(cams) < 2:
        return [], info, cam_inl
    if gravity_hint is not None:
        hypotheses = hinted_hypothesis(rig, cams, Rc, counts, gravity_hint)
    else:
        scoring = None
        if weak_geometry:  # the camera rotations barely tell gravity apart: rank by the full pose (translations too)
            scoring = (m, _subset(rng, np.flatnonzero(cam_inl), SCORE_POINTS), 3.0 * tight)
        hypotheses = gravity_rotation_hypotheses(rig, cams, Rc, counts, int(opts.gravity_hypotheses), num_starts,
                                                 scoring=scoring)

    accepted = np.flatnonzero(cam_inl)

    def starts():  # lazily: the caller may stop once a start explains the data
        for g0, R0, _ in hypotheses:
            idx = _subset(rng, accepted, int(opts.subset_size))
            t0, err = start_translation(rig, m, idx, R0, g0, loose)
            if np.mean(err < loose) >= START_FIT_SHARE:  # the rotations' pose is good enough: no RANSAC
                yield R0, t0, g0, idx
                continue
            rr = _ransac_6pt(rig, m, loose, opts, rng, g=(g0, R0.T @ g0), max_iterations=opts.start_iterations_6pt,
                             min_iterations=WEAK_START_MIN_SAMPLES if weak_geometry else START_MIN_SAMPLES)
            info.ransac_iterations += 0 if rr is None else int(rr.iterations)
            if rr is not None and rr.num_inliers >= 12:
                yield (*rr.model, g0, _subset(rng, np.flatnonzero(rr.inliers), int(opts.subset_size)))
            else:
                yield R0, t0, g0, idx

    return starts(), info, cam_inl


def _start_score(rig, m: Matches, res, threshold) -> tuple:
    """MSAC score of a refined start over all correspondences at the tight threshold, and its inlier mask.

    Starts are refined on different subsets (each start's own RANSAC
    inliers), so their bundle-adjustment costs are not comparable: a wrong
    start with fewer inliers has a smaller sum. This score is.
    """
    err = _bending_errors(rig, m, res.R, res.t, res.g)
    return msac_score(err, threshold), err < threshold


def _start_refinement(rig, m: Matches, idx, R, t, g, tight, opts):
    """Short bundle adjustment of one start on correspondences idx at a fixed sigma; (result, score, inlier mask)."""
    res = refine_two_view(rig, m.f1[idx], m.f2[idx], m.cam[idx], R, t, g, max_iter=int(opts.start_ba_iterations),
                          huber_k=opts.huber_k, sigma_rad=tight / 2.0, tol=START_TOL)
    return (res, *_start_score(rig, m, res, tight))


def _explains(rig: Rig, opts: EstimatorOptions, inliers, accepted) -> bool:
    """Whether a start's inliers (bending model, tight threshold) hold every correspondence that the cameras'
    own epipolar geometry accepts, but for the outliers that test lets through: an outlier falls within
    CAMERA_THRESHOLD_FACTOR * threshold_px of its epipolar line with about the chance of that band's share of
    the image, so a start may miss two plus that share of the correspondences the test rejects."""
    band = 2.0 * CAMERA_THRESHOLD_FACTOR * opts.threshold_px / min(min(c.resolution) for c in rig.cameras)
    missed = np.count_nonzero(accepted & ~inliers)
    return missed <= 2 + band * np.count_nonzero(~accepted)


def _common_bar_axis(rig, m: Matches, min_share: float = 0.9):
    """The bar axis shared by the cameras holding min_share of the correspondences, if they are all parallel."""
    counts = np.bincount(m.cam, minlength=rig.num_cameras).astype(float)
    order = np.argsort(-counts)
    keep = order[: int(np.searchsorted(np.cumsum(counts[order]), min_share * counts.sum()) + 1)]
    u, _, cr = rig.bar_coefficients
    keep = keep[cr[keep] > 0]
    if len(keep) == 0 or np.any(np.abs(u[keep] @ u[keep[0]]) < 0.99):
        return None
    return u[keep[0]]


def _six_point_bending(rig, m, opts, rng, gravity_hint=None):
    loose, tight = _thresholds(rig, opts)
    if not rig.is_flexible:
        rr = _ransac_6pt(rig, m, loose, opts, rng)
        if rr is None:
            return None
        R, t, _, inliers, res, _ = _refine_loop(rig, m, *rr.model, None, tight, opts, optimize_gravity=False)
        info = EstimateInfo(ransac_iterations=int(rr.iterations), gravity_unobservable=RIGID_REASON)
        return R, t, None, inliers, _record_pose(info, res, False)
    axis = _common_bar_axis(rig, m)
    # parallel bars observe gravity weakly (paper, section 3.3): search wider there
    num_starts = int(opts.gravity_refine_starts if axis is None else max(opts.gravity_refine_starts,
                                                                          opts.weak_geometry_starts))
    starts, info, camera_inl = _starts_from_camera_rotations(rig, m, opts, rng, loose, tight, num_starts,
                                                             weak_geometry=axis is not None,
                                                             gravity_hint=gravity_hint)
    if gravity_hint is not None:
        info.gravity_hint = True
        axis = None  # stay in the hint's basin: no mirrored or reversed starts
    if info.cameras_with_rotation < 2:
        starts = _starts_from_rigid_fit(rig, m, opts, rng, loose, info, gravity_hint)
        info.camera_inliers = None  # of fewer than two cameras: no yardstick for the starts
    best = best_score = best_idx = best_inliers = None
    info.gravity_starts = 0
    candidates = []  # (MSAC score, refined start): the basins this pair leaves open
    accepted = camera_inl if info.cameras_with_rotation >= 2 else None
    min_starts = 1 if axis is None else WEAK_MIN_STARTS

    def refine(start) -> None:  # one start refined: a candidate, and the best so far where it scores lowest
        nonlocal best, best_score, best_idx, best_inliers
        R0, t0, g0, idx = start
        res, score, inliers = _start_refinement(rig, m, idx, R0, t0, g0, tight, opts)
        info.gravity_starts += 1
        candidates.append((score, res))
        if best is None or score < best_score:
            best, best_score, best_idx, best_inliers = res, score, idx, inliers

    explained = False
    for start in starts:
        refine(start)
        if opts.stop_at_explaining_start and accepted is not None and info.gravity_starts >= min_starts \
                and _explains(rig, opts, best_inliers, accepted):
            explained = True
            break  # explains the correspondences the cameras' own epipolar geometry accepts: the right basin
    if best is not None and not explained and gravity_hint is None and accepted is not None and \
            np.count_nonzero(best_inliers) < len(m):
        # Correspondences the best start leaves out may be outliers, or the cameras' own rotations (each from a
        # camera's few matches alone, and so the yardstick of what they accept) misled every start: the paper's
        # route, one rigid fit over every camera's matches, gives further starts, and the score decides (three
        # cameras with 8-19 links each: the cameras' starts explained 36 of 44 links 124 deg off; a rigid start
        # 43, and the adjustment all 44).
        for start in _starts_from_rigid_fit(rig, m, opts, rng, loose, EstimateInfo()):
            refine(start)
    if best is None:
        return None
    if axis is not None:
        # All observing cameras sit on parallel bars: mirroring gravity's axial component leaves view 1's
        # bending unchanged, and on rendered two-camera bags the bending reversed (perpendicular part
        # flipped) can fit as well; both are second basins (paper, section 3.3, degenerate cases).
        # Refine from them too and keep the best.
        ga = (axis @ best.g) * axis  # axial part; flipping it, or the rest (bars bent the other way):
        info.mirrored_start = False
        for g_m in (best.g - 2.0 * ga, 2.0 * ga - best.g):
            mirrored, score, inliers = _start_refinement(rig, m, best_idx, best.R, best.t, g_m, tight, opts)
            candidates.append((score, mirrored))
            if score < best_score:
                best, best_score, best_inliers, info.mirrored_start = mirrored, score, inliers, True
    ranked = [c for _, c in sorted(candidates, key=lambda c: c[0]) if c.g is not None]
    info.gravity_candidates = tuple(c.g for c in ranked)
    info.candidate_poses = tuple(np.column_stack([c.R, c.t]) for c in ranked)
    if not opts.final_refinement:
        info.msac_score_rad2 = float(best_score)
        return best.R, best.t, best.g, best_inliers, _record_pose(info, best, True)
    if axis is not None:
        # on parallel bars the adjustment creeps along the weakly observed gravity direction: the winner is
        # first settled on its subset, at its own noise scale, where iterations are cheap
        best = refine_two_view(rig, m.f1[best_idx], m.f2[best_idx], m.cam[best_idx], best.R, best.t, best.g,
                               max_iter=int(opts.max_ba_iterations), huber_k=opts.huber_k)
        best_inliers = _start_score(rig, m, best, tight)[1]
    R, t, g, inliers, res, info.msac_score_rad2 = _refine_loop(rig, m, best.R, best.t, best.g, tight, opts,
                                                                inliers=best_inliers)
    return R, t, g, inliers, _record_pose(info, res, True)


def _require_gravity(m: Matches) -> None:
    if not m.has_gravity:
        raise EstimationError(f"{m.source}: 4pt-bending needs gravity measurements in both views "
                              "(g1/g2 or g1_cam/g2_cam); use 6pt-bending for vision only")


def _four_point_bending(rig, m, opts, rng):
    _require_gravity(m)
    g1m, g2m = m.body_gravity(rig)
    _, tight = _thresholds(rig, opts)
    o1, d1 = rays(rig, m.f1, m.cam, g1m)
    o2, d2 = rays(rig, m.f2, m.cam, g2m)
    ro = RansacOptions(threshold=tight, confidence=opts.confidence, max_iterations=int(opts.max_iterations_4pt),
                       patience=int(opts.patience_4pt), local_optimization=False)
    rr = ransac(UprightFourPointProblem(o1, d1, o2, d2, g1m, g2m), ro, rng, groups=m.cam)
    if rr is None:
        return None
    R, t = rr.model
    info = EstimateInfo(ransac_iterations=int(rr.iterations), stage1_inliers=int(rr.num_inliers),
                        measured_gravity=np.array([g1m, g2m], dtype=float))
    flexible = rig.is_flexible
    prior = None
    if flexible and math.isfinite(opts.gravity_prior_sigma):
        prior = two_view_priors(g1m, g2m, float(opts.gravity_prior_sigma))
    R, t, g, inliers, res, _ = _refine_loop(rig, m, R, t, g1m, tight, opts, prior=prior, optimize_gravity=flexible,
                                         inliers=rr.inliers)
    _record_pose(info, res, flexible)
    if not flexible:
        info.gravity_unobservable = RIGID_REASON
        g = None
    return R, t, g, inliers, info


_METHODS = {
    "6pt-nonbending": _six_point_nonbending,
    "6pt-bending": _six_point_bending,
    "4pt-bending": _four_point_bending,
}


def estimate(rig: Rig, matches: Matches, method: str = "6pt-bending", seed: int = 0,
             options: EstimatorOptions | dict | None = None, *,
             gravity_hint: np.ndarray | Sequence[float] | None = None) -> Estimate:
    """Relative pose (R, t) and, for the bending methods, gravity from two views (docs/CONVENTIONS.md (Estimators)).

    ``seed`` makes RANSAC deterministic. Raises EstimationError / InputError for
    an unknown method, 4pt-bending without gravity measurements, or matches
    that do not fit the rig. A run that cannot produce a pose returns
    ``success=False`` with the reason in ``info.reason`` (:class:`EstimateInfo`).

    ``gravity_hint`` (6pt-bending only; view 1's body frame, m/s^2): gravity
    known roughly from elsewhere, e.g. fused from earlier views. The search
    then starts from it alone and stays in its basin, which settles the
    two-fold ambiguity of parallel bars (paper, section 3.3) by history; the
    result is still a vision-only estimate. ``info.msac_score_rad2`` (MSAC
    score over all correspondences at the inlier threshold) lets a caller
    compare it with the unhinted estimate.
    """
    if method not in _METHODS:
        raise EstimationError(f"unknown method {method!r} (choose one of {', '.join(METHODS)})")
    if gravity_hint is not None:
        if method != "6pt-bending":
            raise EstimationError(f"gravity_hint applies to 6pt-bending only, not {method}")
        gravity_hint = np.asarray(gravity_hint, dtype=float).reshape(-1)
        if gravity_hint.shape != (3,) or not np.all(np.isfinite(gravity_hint)) or not np.any(gravity_hint):
            raise InputError("estimate()", f"must be a finite, non-zero 3-vector, got {gravity_hint.tolist()}",
                             "gravity_hint")
    opts = options if isinstance(options, EstimatorOptions) else EstimatorOptions.from_dict(options)
    matches.check_rig(rig)
    t_start = time.perf_counter()
    need = 4 if method == "4pt-bending" else 6
    if method == "4pt-bending":
        _require_gravity(matches)
    cams_seen = int(np.count_nonzero(np.bincount(matches.cam)))
    if len(matches) < need + 2 or cams_seen < 2:
        return Estimate(method=method, success=False, time_s=time.perf_counter() - t_start,
                        info=EstimateInfo(reason=f"needs at least {need + 2} correspondences seen by at least 2 "
                                                 f"cameras, got {len(matches)} from {cams_seen} camera(s)"))
    rng = default_rng(seed)
    hint = {} if gravity_hint is None else {"gravity_hint": gravity_hint}
    out = _METHODS[method](rig, matches, opts, rng, **hint)
    elapsed = time.perf_counter() - t_start
    if out is None:
        return Estimate(method=method, success=False, time_s=elapsed,
                        info=EstimateInfo(reason="no minimal sample gave a valid pose"))
    R, t, g, inliers, info = out
    if g is not None:
        g = rig.gravity_magnitude * normalize(g)
    return Estimate(method=method, success=True, R=R, t=t, gravity=g, inliers=np.flatnonzero(inliers),
                    time_s=elapsed, info=info)


__all__ = ["METHODS", "RIGID_REASON", "Estimate", "EstimateInfo", "EstimatorOptions", "estimate", "pair_method"]
