"""The three estimators (docs/CONVENTIONS.md, Estimators): 6pt-nonbending, 6pt-bending, 4pt-bending.

Each is RANSAC (ours, with a PoseLib minimal solver) followed by the robust
bundle adjustment of :mod:`.bundle`. ``estimate`` is the stable entry point.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.random import default_rng  # imported here, not lazily at the first estimate (~15 ms)

from ..config import check, from_mapping, option
from ..errors import EstimationError, InputError
from .bundle import gravity_covariance, refine_two_view, two_view_priors
from .deformation import deformed_extrinsics, rays
from .gravity_init import (
    camera_rotations,
    gravity_rotation_hypotheses,
    hinted_hypothesis,
    start_translation,
)
from .matches import Matches
from .minimal import UprightFrames, solve_6pt
from .ransac import RansacOptions, ransac
from .residuals import two_view_angular_errors
from .rig import Rig
from .so3 import angle_between, fibonacci_sphere, normalize

METHODS = ("6pt-nonbending", "6pt-bending", "4pt-bending")
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

    def __post_init__(self):
        check(self, "estimator options")

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "estimator options") -> EstimatorOptions:
        return from_mapping(cls, d, source)


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
    info: dict = field(default_factory=dict)

    @property
    def num_inliers(self) -> int:
        return int(len(self.inliers))

    @property
    def gravity2(self) -> np.ndarray | None:
        """Gravity in view 2's body frame, g' = R^T g."""
        if self.gravity is None or self.R is None:
            return None
        return self.R.T @ self.gravity

    def to_json(self, matches_path: str | None = None) -> dict:
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
            out["reason"] = str(self.info.get("reason", "no reason recorded"))
        return out


# ---------------------------------------------------------------------------
# RANSAC problems
# ---------------------------------------------------------------------------

class _RayProblem:
    """Rays of both views fixed (extrinsics at given gravity); errors are angular (rad)."""

    def __init__(self, o1, d1, o2, d2):
        self.o1, self.d1, self.o2, self.d2 = o1, d1, o2, d2
        self.num_data = len(o1)

    def errors(self, models, idx=None):
        R = np.array([m[0] for m in models])
        t = np.array([m[1] for m in models])
        if idx is None:
            return two_view_angular_errors(self.o1, self.d1, self.o2, self.d2, R, t)
        return two_view_angular_errors(self.o1[idx], self.d1[idx], self.o2[idx], self.d2[idx], R, t)


class SixPointProblem(_RayProblem):
    sample_size = 6

    def generate(self, s):
        return solve_6pt(self.o1[s], self.d1[s], self.o2[s], self.d2[s])


class UprightFourPointProblem(_RayProblem):
    sample_size = 4

    def __init__(self, o1, d1, o2, d2, g1, g2):
        super().__init__(o1, d1, o2, d2)
        self.frames = UprightFrames(g1, g2)

    def generate(self, s):
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
    return R, t, g, inliers, res, float(np.minimum(err * err, threshold**2).sum())


def _pose_info(res, optimize_gravity):
    info = {}
    if res is None:
        return info
    cov = res.covariance
    info["sigma_rad"] = res.sigma_rad
    info["ba_iterations"] = res.iterations
    info["cov_rotation"] = cov[0:3, 0:3].tolist()
    info["cov_translation"] = cov[3:6, 3:6].tolist()
    if optimize_gravity and res.g is not None:
        cg = cov[6:8, 6:8]
        info["cov_gravity_tangent"] = cg.tolist()
        info["cov_gravity"] = gravity_covariance(res.g, cg).tolist()
        info["gravity_sigma_rad"] = float(math.sqrt(max(np.linalg.eigvalsh(cg).max(), 0.0)))
    return info


_RIGID_REASON = "the rig has no flexible bar (every EI is inf or mass 0), so gravity is unobservable from vision"


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
    info = {"ransac_iterations": rr.iterations, **_pose_info(res, False)}
    return R, t, None, inliers, info


def score_gravity_hypotheses(rig, m: Matches, idx, R, t, hypotheses, threshold):
    """MSAC cost of each gravity hypothesis (K, 3) on correspondences idx at fixed (R, t)."""
    f1, f2, cam = m.f1[idx], m.f2[idx], m.cam[idx]
    w1, W1 = deformed_extrinsics(rig, hypotheses)
    w2, W2 = deformed_extrinsics(rig, hypotheses @ R)  # rows R^T g_k
    o1, d1 = w1[:, cam], np.einsum("knij,nj->kni", W1[:, cam], f1)
    o2, d2 = w2[:, cam], np.einsum("knij,nj->kni", W2[:, cam], f2)
    err = two_view_angular_errors(o1, d1, o2, d2, R, t)
    return np.minimum(err * err, threshold**2).sum(axis=1)


def _starts_from_rigid_fit(rig, m, opts, rng, loose, gravity_hint=None):
    """The paper's route: 6-point RANSAC with canonical extrinsics, then gravity hypotheses scored at that pose
    (or only the gravity_hint)."""
    rr = _ransac_6pt(rig.as_rigid(), m, loose, opts, rng)
    if rr is None:
        return [], {}
    R0, t0 = rr.model
    idx = _subset(rng, np.flatnonzero(rr.inliers), int(opts.subset_size))
    info = {"ransac_iterations": rr.iterations, "stage1_inliers": rr.num_inliers}
    if gravity_hint is not None:
        return [(R0, t0, gravity_hint, idx)], info
    hyp = rig.gravity_magnitude * fibonacci_sphere(int(opts.gravity_hypotheses))
    costs = score_gravity_hypotheses(rig, m, idx, R0, t0, hyp, loose)
    starts = []
    for k in np.argsort(costs):
        if all(angle_between(hyp[k], s[2]) > 0.5 for s in starts):
            starts.append((R0, t0, hyp[k], idx))
        if len(starts) >= int(opts.gravity_refine_starts):
            break
    return starts, info


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
    info = {"cameras_with_rotation": int(len(cams)), "camera_inliers": int(cam_inl.sum()), "ransac_iterations": 0}
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
            info["ransac_iterations"] += 0 if rr is None else rr.iterations
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
    return float(np.minimum(err * err, threshold**2).sum()), err < threshold


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
        return R, t, None, inliers, {"ransac_iterations": rr.iterations, **_pose_info(res, False),
                                     "gravity_unobservable": _RIGID_REASON}
    axis = _common_bar_axis(rig, m)
    # parallel bars observe gravity weakly (paper, section 3.3): search wider there
    num_starts = int(opts.gravity_refine_starts if axis is None else max(opts.gravity_refine_starts,
                                                                          opts.weak_geometry_starts))
    starts, info, camera_inl = _starts_from_camera_rotations(rig, m, opts, rng, loose, tight, num_starts,
                                                             weak_geometry=axis is not None,
                                                             gravity_hint=gravity_hint)
    if gravity_hint is not None:
        info["gravity_hint"] = True
        axis = None  # stay in the hint's basin: no mirrored or reversed starts
    if info["cameras_with_rotation"] < 2:
        starts, more = _starts_from_rigid_fit(rig, m, opts, rng, loose, gravity_hint)
        info.update(more)
        info.pop("camera_inliers")  # of fewer than two cameras: no yardstick for the starts
    best = best_score = None
    info["gravity_starts"] = 0
    candidates = []  # (MSAC score, refined gravity of a start): the basins this pair leaves open
    accepted = camera_inl if info["cameras_with_rotation"] >= 2 else None
    min_starts = 1 if axis is None else WEAK_MIN_STARTS
    for R0, t0, g0, idx in starts:
        res, score, inliers = _start_refinement(rig, m, idx, R0, t0, g0, tight, opts)
        info["gravity_starts"] += 1
        candidates.append((score, res.g))
        if best is None or score < best_score:
            best, best_score, best_idx, best_inliers = res, score, idx, inliers
        if accepted is not None and info["gravity_starts"] >= min_starts and _explains(rig, opts, best_inliers,
                                                                                        accepted):
            break  # explains the correspondences the cameras' own epipolar geometry accepts: the right basin
    if best is None:
        return None
    if axis is not None:
        # All observing cameras sit on parallel bars: mirroring gravity's axial component leaves view 1's
        # bending unchanged, and on rendered two-camera bags the bending reversed (perpendicular part
        # flipped) can fit as well; both are second basins (paper, section 3.3, degenerate cases).
        # Refine from them too and keep the best.
        ga = (axis @ best.g) * axis  # axial part; flipping it, or the rest (bars bent the other way):
        info["mirrored_start"] = False
        for g_m in (best.g - 2.0 * ga, 2.0 * ga - best.g):
            mirrored, score, inliers = _start_refinement(rig, m, best_idx, best.R, best.t, g_m, tight, opts)
            candidates.append((score, mirrored.g))
            if score < best_score:
                best, best_score, best_inliers, info["mirrored_start"] = mirrored, score, inliers, True
    info["gravity_candidates"] = [gc for _, gc in sorted(candidates, key=lambda c: c[0]) if gc is not None]
    if not opts.final_refinement:
        info["msac_score_rad2"] = best_score
        info.update(_pose_info(best, True))
        return best.R, best.t, best.g, best_inliers, info
    if axis is not None:
        # on parallel bars the adjustment creeps along the weakly observed gravity direction: the winner is
        # first settled on its subset, at its own noise scale, where iterations are cheap
        best = refine_two_view(rig, m.f1[best_idx], m.f2[best_idx], m.cam[best_idx], best.R, best.t, best.g,
                               max_iter=int(opts.max_ba_iterations), huber_k=opts.huber_k)
        best_inliers = _start_score(rig, m, best, tight)[1]
    R, t, g, inliers, res, info["msac_score_rad2"] = _refine_loop(rig, m, best.R, best.t, best.g, tight, opts,
                                                                   inliers=best_inliers)
    info.update(_pose_info(res, True))
    return R, t, g, inliers, info


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
    info = {"ransac_iterations": rr.iterations, "stage1_inliers": rr.num_inliers,
            "measured_gravity": [g1m.tolist(), g2m.tolist()]}
    flexible = rig.is_flexible
    prior = None
    if flexible and math.isfinite(opts.gravity_prior_sigma):
        prior = two_view_priors(g1m, g2m, float(opts.gravity_prior_sigma))
    R, t, g, inliers, res, _ = _refine_loop(rig, m, R, t, g1m, tight, opts, prior=prior, optimize_gravity=flexible,
                                         inliers=rr.inliers)
    info.update(_pose_info(res, flexible))
    if not flexible:
        info["gravity_unobservable"] = _RIGID_REASON
        g = None
    return R, t, g, inliers, info


_METHODS = {
    "6pt-nonbending": _six_point_nonbending,
    "6pt-bending": _six_point_bending,
    "4pt-bending": _four_point_bending,
}


def estimate(rig: Rig, matches: Matches, method: str = "6pt-bending", seed: int = 0,
             options: EstimatorOptions | dict | None = None, *, gravity_hint=None) -> Estimate:
    """Relative pose (R, t) and, for the bending methods, gravity from two views (docs/CONVENTIONS.md (Estimators)).

    ``seed`` makes RANSAC deterministic. Raises EstimationError / InputError for
    an unknown method, 4pt-bending without gravity measurements, or matches
    that do not fit the rig. A run that cannot produce a pose returns
    ``success=False`` with the reason in ``info['reason']``.

    ``gravity_hint`` (6pt-bending only; view 1's body frame, m/s^2): gravity
    known roughly from elsewhere, e.g. fused from earlier views. The search
    then starts from it alone and stays in its basin, which settles the
    two-fold ambiguity of parallel bars (paper, section 3.3) by history; the
    result is still a vision-only estimate. ``info['msac_score_rad2']`` (MSAC
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
                        info={"reason": f"needs at least {need + 2} correspondences seen by at least 2 cameras, "
                                        f"got {len(matches)} from {cams_seen} camera(s)"})
    rng = default_rng(seed)
    hint = {} if gravity_hint is None else {"gravity_hint": gravity_hint}
    out = _METHODS[method](rig, matches, opts, rng, **hint)
    elapsed = time.perf_counter() - t_start
    if out is None:
        return Estimate(method=method, success=False, time_s=elapsed,
                        info={"reason": "no minimal sample gave a valid pose"})
    R, t, g, inliers, info = out
    if g is not None:
        g = rig.gravity_magnitude * normalize(g)
    return Estimate(method=method, success=True, R=R, t=t, gravity=g, inliers=np.flatnonzero(inliers),
                    time_s=elapsed, info=info)


__all__ = ["METHODS", "Estimate", "EstimatorOptions", "estimate"]
