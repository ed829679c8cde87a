"""The steps of a joint estimate over holds, shared by its two entry points and the bar calibration.

:func:`.sequence.estimate_sequence` (all holds at once) and
:class:`.incremental.IncrementalSequence` (hold by hold) set up their
problems differently and share what follows (docs/ARCHITECTURE.md, "The
joint estimate over holds"): the options, the result, resection on
triangulated landmarks, the choice of the gravity basin by the joint cost
(:func:`choose_gravity`), the robust refinement (:func:`refine_sequence`),
the repair of links the inlier classification broke
(:func:`repair_links`), and the one last step both end with
(:func:`adjust_sequence`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..config import check, from_mapping, option
from .bundle import (
    BundleResult,
    BundleState,
    GravityInformation,
    GravityPriors,
    Observations,
    ParameterLayout,
    SequenceBundleProblem,
    adjust_bundle,
    camera_noise_factors,
    cluster_robust_covariance,
    rest_turns_start,
    robust_sigma,
)
from .estimators import RIGID_REASON, EstimatorOptions, estimate, pair_method
from .loss import msac_score
from .resection import resect_view
from .rig import Rig
from .so3 import angle_between
from .tracks import Tracks


@dataclass
class SequenceOptions:
    """Tuning of :func:`estimate_sequence`; the pairwise estimators and thresholds come from ``estimator``."""

    estimator: EstimatorOptions = option(EstimatorOptions(), "the two-view estimators and the thresholds")
    max_iterations: int = option(50, "joint bundle-adjustment iterations per inlier round", lo=1, hi=10000)
    # chi^2/2 of a sequence is about its number of observations: 1e-4 of it moves the parameters far below
    # their std, while the inlier rounds re-classify and re-adjust anyway
    relative_tolerance: float = option(1e-4, "a joint adjustment stops once a step gains less than this share "
                                       "of the cost", lo=0.0, hi=1.0)
    inlier_rounds: int = option(4, "joint adjustments while the inlier set still changes", lo=1, hi=100)
    camera_noise: bool = option(True, "view by view, the last joint adjustment weighs each hold's camera by its "
                                "own noise (a posteriori variance factor, with the correspondence-bias floor)")
    candidate_iterations: int = option(8, "short joint adjustment of each gravity candidate", lo=1, hi=10000)
    candidate_tracks: int = option(300, "tracks (random subset) those short adjustments use", lo=8, hi=10000000)
    candidate_separation_deg: float = option(3.0, "gravity candidates closer than this (deg) are one", lo=0.0,
                                             hi=180.0)
    max_candidates: int = option(8, "distinct gravity candidates scored at the chained poses", lo=1, hi=1000)
    refined_candidates: int = option(3, "of which the best get a short joint adjustment", lo=1, hi=1000)
    max_pair_gap: int = option(3, "a view is paired with at most this many views back", lo=1, hi=1000)
    min_pair_matches: int = option(12, "correspondences a pair needs (from two cameras at least)", lo=8,
                                   hi=10000000)
    gravity_bias_sigma: float = option(None, "rad: 4pt-bending also estimates a constant tilt of the measured "
                                       "gravity with this prior std (null: no such tilt)", lo=0.0, lo_open=True,
                                       nullable=True)
    # the pairwise estimates only start the joint adjustment: they compare gravity starts on fewer
    # correspondences and leave the final refinement to the joint adjustment
    pair_subset_size: int = option(100, "pairwise starts: correspondences that compare gravity starts", lo=8,
                                   hi=10000000)
    pair_refine_starts: int = option(2, "pairwise starts: gravity hypotheses refined", lo=1, hi=1000)
    pair_ba_iterations: int = option(10, "pairwise starts: bundle-adjustment iterations", lo=1, hi=10000)
    # view by view (core.incremental): once the gravity is settled a new view is placed on the landmarks the
    # window already knows, and the window, adjusted already but for that view, needs one inlier round
    # the batch: the first views' pairs give the gravity candidates, later views are placed on their landmarks
    chain_pairs: int = option(3, "batch: views after the origin placed by the two-view estimator (their gravity "
                              "candidates compete); later ones by resection on the landmarks of the views "
                              "before, the estimator only where that fails (null: every view)", lo=1,
                              hi=1000000, nullable=True)
    resect_views: bool = option(True, "view by view: place a new view by resection on the window's landmarks "
                                "once the sequence is no longer young (else the two-view estimator)")
    link_repairs: int = option(4, "batch: views re-placed (with the views after them) where the adjusted "
                               "sequence kept few of the landmarks they share with the view before", lo=0, hi=100)
    link_retention: float = option(0.5, "a link between consecutive views is broken when the share of their "
                                   "common landmarks kept as inliers is below this fraction of the median link's",
                                   lo=0.0, hi=1.0)
    young_views: int = option(5, "view by view: a sequence is young for this many views: the joint gravity "
                              "competes with each new pair's candidates, and vision only on parallel bars no "
                              "gravity is published yet (its first pairs' basins are not told apart reliably, "
                              "docs/PIPELINE.md)", lo=1, hi=1000)
    reconsider_deg: float = option(3.0, "view by view: past its young views, a sequence's joint gravity is chosen "
                                   "again among the candidates when a new pair's gravity differs from it by more "
                                   "than this (deg) and by more than 3 of the pair's own stds", lo=0.0, hi=180.0)
    merge_sequences: int = option(4, "view by view: sequences a break ended that are kept so that a later view "
                                  "linking to one of them merges it with the current sequence (0: no merges)",
                                  lo=0, hi=1000)
    ambiguity_significance: float = option(0.01, "view by view: a gravity basin whose joint cost exceeds the "
                                           "best one's by less than the chi^2 (2 dof) quantile at 1 - this is a "
                                           "rival: its spread enters the published std until the views tell them "
                                           "apart", lo=0.0, hi=0.5, lo_open=True)
    window_rounds: int = option(2, "view by view: joint adjustments of the window while its inliers change",
                                lo=1, hi=100)
    inlier_sigmas: float = option(5.0, "after a joint adjustment, an observation stays an inlier within this many "
                                  "of its (hold, camera)'s bulk noise (per axis, from the median residual), the "
                                  "fixed threshold at most (null: the fixed threshold alone)", lo=1.0,
                                  nullable=True)

    def __post_init__(self):
        check(self, "sequence options")

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "sequence options") -> SequenceOptions:
        return from_mapping(cls, d, source)

    def pair_estimator(self) -> EstimatorOptions:
        """Options of the pairwise estimates that start the joint adjustment. Every gravity start is refined
        and returned: the joint cost chooses among their basins, and the first start that explains the
        correspondences within the pixel threshold may be a wrong basin on holds averaged far below it
        (docs/PIPELINE.md, "The joint estimate over the sequence", step 2)."""
        return replace(self.estimator, subset_size=self.pair_subset_size,
                       gravity_refine_starts=self.pair_refine_starts, max_ba_iterations=self.pair_ba_iterations,
                       final_refinement=False, stop_at_explaining_start=False)


@dataclass
class SequenceEstimate:
    """Result of :func:`estimate_sequence`: view k's pose in view 0 (p_0 = R_k p_k + t_k), its gravity."""

    method: str
    success: bool
    R: np.ndarray | None = None  # (K, 3, 3)
    t: np.ndarray | None = None  # (K, 3)
    gravity: np.ndarray | None = None  # (K, 3) body frames, m/s^2; None without gravity
    gravity_sigma_rad: np.ndarray | None = None  # (K,) largest angular std of each view's gravity
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # (N,) over the tracks' observations
    time_s: float = 0.0
    reason: str = ""  # why not (success False), or why there is no gravity
    bundle: BundleResult | None = None
    pair_methods: list = field(default_factory=list)  # the two-view method and reference view of each view k >= 1
    candidates: int = 0  # distinct gravity candidates compared
    link_repairs: int = 0  # views re-placed where the adjusted sequence broke the link to the view before

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))

    def to_json(self, tracks_path: str | None = None) -> dict:
        """The result object of ``nrmpc solve-sequence`` (docs/CONVENTIONS.md, "Command line")."""
        views = []
        if self.success:
            for k in range(len(self.R)):
                g = None if self.gravity is None else self.gravity[k].tolist()
                s = None if self.gravity is None else float(math.degrees(self.gravity_sigma_rad[k]))
                views.append({"R": self.R[k].tolist(), "t": self.t[k].tolist(), "gravity": g,
                              "gravity_sigma_deg": s if s is None or math.isfinite(s) else None})
        out = {"tracks": tracks_path, "method": self.method, "success": bool(self.success), "views": views,
               "num_inliers": self.num_inliers, "time_s": self.time_s}
        if self.reason:
            out["reason"] = self.reason
        return out


@dataclass(frozen=True)
class PairAttempt:
    """One earlier view tried as the reference of a new view: how many landmarks it shares with it and from how
    many cameras and, where the two-view estimate was made (``estimated``) and failed, the estimator's reason."""

    view: int
    shared: int
    cameras: int
    estimated: bool = False
    failure: str | None = None  # the two-view estimator's reason (EstimateInfo.reason)

    def describe(self, landmarks: str = "tracks") -> str:
        """The phrase shown to the user; ``landmarks`` names what is shared."""
        if self.estimated:
            return f"view {self.view}: {self.failure or 'estimation failed'}"
        return f"view {self.view}: {self.shared} shared {landmarks} from {self.cameras} camera(s)"


@dataclass(frozen=True)
class Unlinked:
    """Why a chain of two-view estimates stops: view ``view`` links to none of the views before it, each
    earlier view tried (newest first) with what it shared or why its pair failed."""

    view: int
    tried: tuple[PairAttempt, ...] = ()

    def __str__(self) -> str:
        why = "; ".join(a.describe() for a in self.tried) or "no earlier view"
        return f"view {self.view} cannot be linked to the views before it ({why})"


@dataclass
class Chain:
    """:func:`_chain_pairs`'s outcome: the poses of the views placed, in view 0, the gravity candidates for g_0
    (list of (g_0, weight)) and each placed view's (method, reference view); ``unlinked`` says why the chain
    stops before the last view (None: every view is placed)."""

    R: np.ndarray  # (K', 3, 3)
    t: np.ndarray  # (K', 3)
    candidates: list
    methods: list
    unlinked: Unlinked | None = None


def resect_on_landmarks(rig: Rig, known, R, t, gravity, new, guess, threshold: float, min_inliers: int,
                        seed: int = 0, min_cameras: int = 2):
    """Place a new view by resection on the landmarks earlier views triangulate.

    ``known`` = (view, cam, track, f) of the earlier views' observations (views index ``R``, ``t``: poses in
    view 0), ``new`` = (cam, track, f) of the new view; landmarks seen twice in ``known`` are triangulated at
    those poses (cameras bent at ``gravity`` = g_0, None for straight) and the new view's observations of
    them resected (:func:`.resection.resect_view`) from ``guess`` = (R, t). Returns (Resection, indices into
    ``new`` of the observations used), or None with fewer than ``min_inliers`` landmarks or inliers, or
    inliers from fewer than ``min_cameras`` cameras (one suffices for the pose: the landmarks are known in 3D
    and the camera's bent extrinsics at the view's gravity give the body's).
    """
    view, cam, track, f = known
    new_cam, new_track, new_f = new
    if len(view) == 0:
        return None
    obs, ids = Observations.from_arrays(view, cam, track, f, len(R))
    twice = np.bincount(obs.point, minlength=obs.num_points) >= 2
    if np.count_nonzero(twice) < min_inliers:
        return None
    obs, used = obs.subset(twice[obs.point])
    ids = ids[used]
    points = triangulated(rig, obs, BundleState(np.asarray(R), np.asarray(t), gravity,
                                                np.zeros((obs.num_points, 3))))[0].points
    pos = np.minimum(np.searchsorted(ids, new_track), len(ids) - 1)
    hit = np.flatnonzero(ids[pos] == new_track)
    if len(hit) < min_inliers:
        return None
    res = resect_view(rig, points[pos[hit]], new_f[hit], new_cam[hit], guess[0], guess[1], gravity, threshold,
                      seed=seed)
    if res is None or res.num_inliers < min_inliers or len(np.unique(new_cam[hit[res.inliers]])) < min_cameras:
        return None
    return res, hit


def distinct_candidates(candidates, separation_rad: float, limit: int) -> list:
    """Greedy over (gravity, weight) pairs: in order of weight, each at least separation_rad from those kept."""
    kept = []
    for g, _ in sorted(candidates, key=lambda c: -c[1]):
        if all(angle_between(g, k) > separation_rad for k in kept):
            kept.append(g)
        if len(kept) >= limit:
            break
    return kept


def tracks_observations(tracks: Tracks):
    """Observations of the tracks seen in at least two views (the others carry no information), and their
    indices into the tracks."""
    ids, inv = np.unique(tracks.track, return_inverse=True)
    first = np.full(len(ids), np.iinfo(np.int64).max)
    last = np.full(len(ids), -1)
    np.minimum.at(first, inv, tracks.view)
    np.maximum.at(last, inv, tracks.view)
    keep = (last > first)[inv]
    obs, _ = Observations.from_arrays(tracks.view[keep], tracks.cam[keep], tracks.track[keep], tracks.f[keep],
                                      tracks.num_views)
    return obs, np.flatnonzero(keep)


# What remains of a landmark's correspondence bias between holds after patch alignment (px, median over the
# rendered rooms' landmarks, pinhole and fisheye, 5-30 deg of viewpoint change: 0.025-0.035 px, docs/RESULTS.md,
# scripts/bench_correspondence.py). It is the same in every frame of a hold, so the residuals of one solve
# cannot show it against the averaged noise: it enters every camera's noise as a floor of this many pixels.
CORRESPONDENCE_BIAS_FLOOR_PX = 0.03


def camera_noise_scale(rig: Rig, obs: Observations, res: BundleResult, huber_k: float,
                       bias_floor_px: float = CORRESPONDENCE_BIAS_FLOOR_PX) -> np.ndarray:
    """Each camera's angular noise relative to ``res.sigma_rad`` (M,): its a posteriori variance factor from
    the residuals of the solve ``res`` on ``obs`` (:func:`~nrmpc_ros.core.bundle.camera_noise_factors`), with
    the correspondence-bias floor ``bias_floor_px`` / focal length added in quadrature."""
    _, prob = triangulated(rig, obs, res.state)
    factors = camera_noise_factors(prob.residuals(res.state), obs.cam, rig.num_cameras, huber_k)
    focal = np.array([c.focal_px for c in rig.cameras])
    floor = bias_floor_px / focal / max(res.sigma_rad, 1e-12)
    return np.sqrt(factors**2 + floor**2)


def hold_camera_noise_scale(rig: Rig, obs: Observations, res: BundleResult, huber_k: float,
                            bias_floor_px: float = CORRESPONDENCE_BIAS_FLOOR_PX,
                            measured_on: Observations | None = None) -> np.ndarray:
    """Each observation's angular noise relative to ``res.sigma_rad`` (N,): the a posteriori variance factor of
    its (hold, camera) from the residuals of the solve ``res`` on ``obs``, with the correspondence-bias floor
    ``bias_floor_px`` / focal length added in quadrature (docs/PIPELINE.md, "The joint estimate over the
    sequence", step 5). ``measured_on``: observations of the same views (a superset of ``obs``, landmarks
    triangulated at the solve) whose residuals give the noise's level instead, never below that of ``obs``
    (the factors between holds' cameras, which decide the estimate, stay those of ``obs``).

    The correspondences' remaining bias is the same in every frame of a hold and differs between holds and
    cameras (the viewpoint change to the landmark's reference patch, the settling of that hold's bars): one
    hold's camera can carry residuals ten times another's. One factor per camera would weigh a clean hold as
    much as a biased one and let the biased hold pull gravity, most of all on a rig that observes one of
    gravity's components weakly (two cameras on one bar). A (hold, camera) with fewer than 10 observations
    keeps the factor 1 (too few to tell). A hold whose bearings were told to carry extra noise (``obs.scale``
    above 1: residual ringing of its bars) keeps it: ringing turns a camera's bearings alike, the hold's pose
    absorbs most of it and its residuals do not show it, so the factor measured from the residuals (on the
    told noise) and the told extra add in quadrature instead of the residuals taking the extra back."""
    _, prob = triangulated(rig, obs, res.state)
    M = rig.num_cameras
    group = obs.view * M + obs.cam
    e = prob.residuals(res.state)
    factors = camera_noise_factors(e, group, obs.num_views * M, huber_k)
    if measured_on is not None and len(measured_on) >= 10:
        wide, wprob = triangulated(rig, measured_on, res.state)
        level = robust_sigma(wprob.residuals(wide), 0, 0, huber_k=huber_k)
        factors = factors * max(level / max(robust_sigma(e, 0, 0, huber_k=huber_k), 1e-300), 1.0)
    focal = np.array([c.focal_px for c in rig.cameras])[obs.cam]
    floor = bias_floor_px / focal / max(res.sigma_rad, 1e-12)
    # a told extra noise (obs.scale = sqrt(1 + extra^2 / nominal^2)) stays: the measured factor and the extra
    # add in quadrature, relative to the told noise
    told_extra = 0.0 if obs.scale is None else 1.0 - 1.0 / np.maximum(np.asarray(obs.scale, float), 1.0) ** 2
    return np.sqrt(factors[group] ** 2 + told_extra + floor**2)


# Significance of the test of the measured gravities against the joint solution (chi-square, upper tail).
IMU_CONSISTENCY_SIGNIFICANCE = 0.01


def measured_gravity_excess(priors: GravityPriors | None, state: BundleState) -> float:
    """How much the measured (IMU) gravities disagree with the joint solution beyond their own stds: the
    chi-square of their residuals (:meth:`GravityPriors.direction_residual`, the estimated constant tilt
    included: 2 degrees of freedom per active prior, its third component being second order near the
    measurement and large only where the two disagree grossly) over its degrees of freedom when it exceeds the
    test at ``IMU_CONSISTENCY_SIGNIFICANCE``, else 1.

    The IMU's std comes from its measured noise; vision's from residuals that cannot show the
    correspondences' remaining bias. When the two disagree by more than their stds allow, the vision term
    is the optimistic one: its noise is inflated by this factor's square root, so the fusion follows the
    evidence and is not pulled off a sound IMU by an overconfident vision term."""
    if priors is None or state.gravity is None:
        return 1.0
    from scipy.special import chdtri  # the chi-square quantile without importing scipy.stats (seconds)

    active = np.flatnonzero(priors.active)
    if len(active) == 0:
        return 1.0
    total = priors.directions_chi2(state)
    dof = 2 * len(active)
    if total <= chdtri(dof, IMU_CONSISTENCY_SIGNIFICANCE):
        return 1.0
    return total / dof


def triangulated(rig: Rig, obs: Observations, state: BundleState) -> tuple[BundleState, SequenceBundleProblem]:
    """The state with every landmark of obs triangulated, and a problem that evaluates it."""
    prob = SequenceBundleProblem(rig, obs, ParameterLayout(obs.num_views, [], False), 1.0)
    return replace(state, points=prob.triangulate(replace(state, points=np.zeros((obs.num_points, 3))))), prob


def observation_errors(prob: SequenceBundleProblem, state: BundleState) -> np.ndarray:
    """Angular error (rad) of every observation."""
    return np.linalg.norm(prob.residuals(state), axis=1)


@dataclass(frozen=True)
class CandidateScore:
    """One gravity candidate of :func:`choose_gravity`: its origin gravity after its short adjustment (or as
    given, scored at the chained poses), the MSAC score of its observations (rad^2), its priors' chi^2, and the
    angular noise of its observations of landmarks seen twice or more (rad per axis, :func:`.bundle.robust_sigma`
    with the landmarks and the free poses taken out of the degrees of freedom, as a solve measures it): the
    scale its differences are judged at before a solve has measured one."""

    gravity: np.ndarray
    msac_rad2: float
    prior_chi2: float
    noise_rad: float

    def chi2(self, noise_rad: float) -> float:
        """Its cost in chi^2 units at the images' noise ``noise_rad``."""
        return self.msac_rad2 / noise_rad ** 2 + self.prior_chi2


def _scored(gravity, prob: SequenceBundleProblem, e: np.ndarray, threshold: float, prior_chi2: float,
            num_params: int) -> CandidateScore:
    """The :class:`CandidateScore` of residuals ``e`` (N, 2) of ``prob``'s observations."""
    seen = np.bincount(prob.obs.point, minlength=prob.obs.num_points)
    tied = seen[prob.obs.point] >= 2  # a landmark seen once fits its ray exactly: no error to measure
    noise = robust_sigma(prob.unwhitened(e)[tied], int(np.count_nonzero(seen >= 2)), num_params) \
        if tied.any() else math.nan
    return CandidateScore(np.asarray(gravity, float).reshape(-1, 3)[0],
                          msac_score(np.linalg.norm(e, axis=1), threshold), prior_chi2, noise)


def choose_gravity(rig, obs, R, t, candidates, priors, threshold, opts: SequenceOptions, rng, *, free_views=None,
                   gravity_information: GravityInformation | None = None, scores: list | None = None,
                   noise_rad: float | None = None, view_poses: list | None = None):
    """The candidate g_0 whose short joint adjustment has the best score: the MSAC score over all observations
    plus the priors' chi^2 (measured gravities and rotations, :meth:`GravityPriors.chi2`) times the images'
    noise variance (``noise_rad``, default half the threshold). Where the images hardly tell gravity (bars
    still ringing, a stiff rig) the measured gravity decides, and a basin it puts upside down never wins on
    the images' noise. Returns (the candidate itself when there is only one, else the winner's BundleState,
    count).

    Every candidate is first scored at the chained poses (landmarks triangulated, no adjustment); the best
    ``refined_candidates`` of them get the short adjustment on a subset of the tracks. ``scores``, when given,
    receives a :class:`CandidateScore` of every candidate: after its adjustment where it had one, else at the
    chained poses (an upper bound of what an adjustment would reach); it stays empty for a single candidate.
    ``view_poses``, one per candidate: None, or (view, R, t) that view's start pose with that candidate (a pair's
    basin is a gravity and a pose: adjusted from another basin's pose, a candidate may drift off its own).
    """
    if len(candidates) == 1:
        return candidates[0], 1
    noise = threshold / 2.0 if noise_rad is None else noise_rad

    def prior_chi2(state) -> float:
        return 0.0 if priors is None else priors.chi2(state)

    num_params = 6 * (obs.num_views - 1 if free_views is None else len(free_views)) + 2  # free poses, gravity
    starts = []
    for i in range(len(candidates)):
        Ri, ti = np.array(R, float), np.array(t, float)
        if view_poses is not None and view_poses[i] is not None:
            v, Ri[v], ti[v] = view_poses[i]
        starts.append((Ri, ti))
    quick, within = [], []
    for g0, (Ri, ti) in zip(candidates, starts):
        st, prob = triangulated(rig, obs, BundleState(Ri, ti, g0, np.zeros((obs.num_points, 3))))
        e = prob.residuals(st)
        quick.append(_scored(g0, prob, e, threshold, prior_chi2(st), num_params))
        within.append(np.linalg.norm(e, axis=1) < threshold)
    order = np.argsort([q.chi2(noise) for q in quick])
    keep = order[: opts.refined_candidates]
    if scores is not None:
        scores.extend(quick[i] for i in order[opts.refined_candidates:])
    # the subset from the landmarks seen twice or more: one seen once fits its ray whatever the poses, and a
    # subset of mostly such landmarks leaves a view a few tracks that the short adjustment bends it to
    pts = np.flatnonzero(np.bincount(obs.point, minlength=obs.num_points) >= 2)
    if len(pts) > opts.candidate_tracks:
        pts = np.sort(rng.choice(pts, size=opts.candidate_tracks, replace=False))
    chosen = np.isin(obs.point, pts)
    best, best_score = None, math.inf
    for i in keep:
        # each candidate on its own inliers (within the threshold at its start, as its MSAC score counts
        # them): the Huber loss bounds an outlier's pull but not that of many, and on a stiff rig whose
        # bending tells gravity weakly they bent it tens of degrees
        sub, _ = obs.subset(chosen & within[i])
        res = adjust_bundle(rig, sub, *starts[i], candidates[i], priors=priors, gravity_information=gravity_information,
                            free_views=free_views, max_iterations=opts.candidate_iterations,
                            sigma_rad=threshold / 2.0, tol=1e-3)
        st, prob = triangulated(rig, obs, res.state)
        scored = _scored(res.state.gravity, prob, prob.residuals(st), threshold, prior_chi2(res.state), num_params)
        score = scored.chi2(noise)
        if scores is not None:
            scores.append(scored)
        if best is None or score < best_score:
            best, best_score = res.state, score
    return best, len(candidates)


# Median length of a 2-D Gaussian error of unit std per axis (Rayleigh): a residual norm's median over it is
# the per-axis noise of the bulk, blind to a tail of any weight below half.
RAYLEIGH_MEDIAN = math.sqrt(2.0 * math.log(2.0))
# Fewest inliers of one (hold, camera) whose median gives its own noise; fewer take the bulk of all.
MIN_GROUP_INLIERS = 10


def inlier_bounds(errors: np.ndarray, group: np.ndarray, inliers: np.ndarray, threshold: float,
                  sigmas: float | None) -> np.ndarray:
    """Each observation's inlier bound (N,), rad: ``sigmas`` times the bulk noise of its group (per axis,
    the median residual norm of the group's current ``inliers`` over :data:`RAYLEIGH_MEDIAN`; a group with
    fewer than :data:`MIN_GROUP_INLIERS` takes all inliers'), never above the fixed ``threshold``.

    The fixed threshold (pixels chosen for a rough start) is tens of times the noise of averaged tracks: a
    tail of correspondences at 0.1-2 px, each within it, pulls gravity more than the slight bending of a
    stiff bar tells (docs/PIPELINE.md, "The joint estimate over the sequence"). A bound from the measured
    noise cuts that tail and keeps a Gaussian bulk (4e-6 of it lies beyond 5 stds); each hold's camera its
    own noise, so a hold that rings or a blurrier camera is judged by its own spread, not the sharpest."""
    errors = np.asarray(errors, float)
    if sigmas is None or not np.any(inliers):
        return np.full(len(errors), threshold)
    group = np.asarray(group, np.int64)
    inl = np.asarray(inliers, bool)
    noise = np.full(int(group.max()) + 1, float(np.median(errors[inl])) / RAYLEIGH_MEDIAN)
    count = np.bincount(group[inl], minlength=len(noise))
    order = np.argsort(group[inl], kind="stable")
    e_sorted, g_sorted = errors[inl][order], group[inl][order]
    measured = np.flatnonzero(count >= MIN_GROUP_INLIERS)
    for g, a in zip(measured, np.searchsorted(g_sorted, measured)):  # groups, not observations
        noise[g] = float(np.median(e_sorted[a:a + count[g]])) / RAYLEIGH_MEDIAN
    return np.minimum(threshold, sigmas * noise[group])


def refine_sequence(rig: Rig, obs: Observations, R, t, gravity, threshold: float, *, priors=None,
                    gravity_information: GravityInformation | None = None, points=None, free_views=None,
                    max_iterations: int = 50, rounds: int = 4, huber_k: float = 3.0, start_factor: float = 4.0,
                    inliers=None, min_rounds: int = 2, tol: float = 1e-6, camera_noise: bool = False,
                    inlier_sigmas: float | None = None, offset_sigma=None, rest_turns=None):
    """Robust joint adjustment: classify observations as inliers (angular error below ``threshold``, rad,
    ``start_factor`` times that at the start, where the poses are only roughly right, and within the given
    ``inliers`` mask, for a start that is already adjusted and classified), adjust on the inliers, re-classify every
    observation and repeat (at least ``min_rounds`` times, each round from landmarks triangulated at the
    poses so far) while the inlier set changes by more than 1 %; ``tol``: relative cost decrease that ends an
    adjustment. ``inlier_sigmas``: after an adjustment an observation is an inlier within that many of its
    (hold, camera)'s measured noise, ``threshold`` at most (:func:`inlier_bounds`); the level of the noise
    the ``camera_noise`` weighing measures stays that of every observation within ``threshold``: the tail the
    bound cuts no longer pulls the estimate, but it is part of the noise the std must carry. ``camera_noise``: a last
    adjustment weighs each hold's camera by its own noise
    (:func:`hold_camera_noise_scale` of the solve so far, at that solve's sigma, kept fixed), so its covariance
    carries each (hold, camera)'s a posteriori variance factor and the correspondence-bias floor; with measured
    gravity priors that disagree with the solve beyond their stds, vision's noise is inflated by the excess
    (:func:`measured_gravity_excess`). ``offset_sigma`` (K, M): the std (rad per axis) of an unknown turn of
    each hold's camera (a residual ringing nothing measured), which the covariance carries too
    (:func:`.bundle.cluster_robust_covariance`). ``rest_turns`` (M, 3, 3): start of the cameras' rest turns,
    estimated under the rig file's ``rotation_std_deg`` (:func:`.bundle.adjust_bundle`; None: not estimated).
    Returns (BundleResult on the inliers, inlier mask over obs)."""
    state = BundleState(np.asarray(R, float), np.asarray(t, float), gravity,
                        np.zeros((obs.num_points, 3)) if points is None else np.asarray(points, float),
                        view_sequence=obs.view_sequence, rest_turns=rest_turns)
    full, prob = triangulated(rig, obs, state)
    if points is not None:
        full = replace(full, points=np.asarray(points, float))
    inl = observation_errors(prob, full) < start_factor * threshold
    inl = _seen_twice(obs, inl if inliers is None else inl & np.asarray(inliers, bool))
    res = None
    for r in range(max(1, rounds)):
        sub, used = obs.subset(inl)
        # landmarks start from triangulation at the current poses each round: points carried over from a
        # rougher state can hold the adjustment in a shallow local minimum
        res = adjust_bundle(rig, sub, full.R, full.t, full.gravity, None, priors=priors,
                            gravity_information=gravity_information, free_views=free_views,
                            max_iterations=max_iterations if r == 0 else max(10, max_iterations // 3),
                            huber_k=huber_k, tol=tol, rest_turns=full.rest_turns)
        new_full, prob = triangulated(rig, obs, res.state)
        new_full.points[used] = res.state.points
        full = new_full
        errors = observation_errors(prob, full)
        bound = inlier_bounds(errors, obs.view * rig.num_cameras + obs.cam, inl & (errors < threshold), threshold,
                              inlier_sigmas)
        new = _seen_twice(obs, errors < bound)
        changed = int(np.count_nonzero(new != inl))
        inl = new
        if r + 1 >= min_rounds and changed <= max(2, 0.01 * np.count_nonzero(inl)):
            break  # a rough start always gets a second round: from landmarks triangulated at the refined poses
    if camera_noise and res is not None:  # on the observations of the last adjustment (its landmarks)
        st = res.state
        # the noise's level is measured on every observation within the fixed threshold: the bound from the bulk
        # noise keeps the tail from pulling the estimate, but the tail is noise the std must carry (robust_sigma)
        within = _seen_twice(obs, errors < threshold) if inlier_sigmas is not None else None
        scale = hold_camera_noise_scale(rig, sub, res, huber_k,
                                        measured_on=None if within is None else obs.subset(within)[0])
        scale = scale * math.sqrt(measured_gravity_excess(priors, st))
        sub = replace(sub, scale=scale if sub.scale is None else sub.scale * scale)
        weighed = adjust_bundle(rig, sub, st.R, st.t, st.gravity, st.points, priors=priors,
                                gravity_information=gravity_information, free_views=free_views,
                                max_iterations=max(10, max_iterations // 3), huber_k=huber_k, tol=tol,
                                sigma_rad=res.sigma_rad, bias=st.bias, rest_turns=st.rest_turns)
        if np.all(np.isfinite(weighed.covariance)) or not np.all(np.isfinite(res.covariance)):
            res = weighed  # (a weighing that leaves the information singular keeps the solve before it)
            # errors shared within a hold's camera: the covariance holds for them too (cluster-robust)
            res = replace(res, covariance=cluster_robust_covariance(
                rig, sub, res, sub.view * rig.num_cameras + sub.cam, huber_k, priors, gravity_information,
                None if offset_sigma is None else np.asarray(offset_sigma, float).reshape(-1)))
    return res, inl


def link_retention(obs: Observations, inliers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(shared (K,), kept (K,)): for k >= 1 the landmarks seen in both views k-1 and k, and how many of them
    keep both observations among ``inliers``; entry 0 is 0."""
    K, P = obs.num_views, obs.num_points
    seen = np.zeros(K * P, bool)
    good = np.zeros(K * P, bool)
    key = obs.view * P + obs.point
    seen[key] = True
    good[key[np.asarray(inliers, bool)]] = True
    seen, good = seen.reshape(K, P), good.reshape(K, P)
    shared = np.zeros(K, np.int64)
    kept = np.zeros(K, np.int64)
    shared[1:] = np.count_nonzero(seen[1:] & seen[:-1], axis=1)
    kept[1:] = np.count_nonzero(good[1:] & good[:-1], axis=1)
    return shared, kept


def broken_link(obs: Observations, inliers: np.ndarray, fraction: float, min_shared: int) -> int | None:
    """The first view k whose link to view k-1 is broken: of at least ``min_shared`` common landmarks, a share
    kept as inliers below ``fraction`` of the median link's. An adjustment started with views k, k+1, ...
    misplaced together (a wrong pair estimate chained on) keeps them consistent among themselves and drops
    the observations that would pull them back; None when every link holds."""
    shared, kept = link_retention(obs, inliers)
    valid = np.flatnonzero(shared >= max(1, min_shared))
    if len(valid) < 2:
        return None
    share = kept[valid] / shared[valid]
    bad = valid[share < fraction * float(np.median(share))]
    return int(bad[0]) if len(bad) else None


def _relinked(rig: Rig, tracks: Tracks, obs: Observations, state: BundleState, k: int, method: str,
              threshold: float, opts: SequenceOptions, seed: int):
    """(R, t) with views k, k+1, ... moved together so that view k sits where the views before it put it; None
    when that fails.

    View k is placed by resection on the landmarks of the views before it, triangulated at the adjusted
    poses from those views alone (from their observations within ``threshold`` of them: the inlier
    classification of the whole sequence also dropped, in the views before k, the observations of the
    landmarks view k disagreed with); where too few such landmarks reach view k, by the two-view estimate
    of the pair (k-1, k) again, started from the gravity the views before k agree on."""
    g0 = None if state.gravity is None else np.asarray(state.gravity, float).reshape(-1, 3)[0]
    placed = None
    sub, used = obs.subset(obs.view < k)
    st, prob = triangulated(rig, sub, replace(state, points=np.zeros((sub.num_points, 3))))
    ok = observation_errors(prob, st) < threshold
    mine = obs.view == k
    found = resect_on_landmarks(rig, (sub.view[ok], sub.cam[ok], used[sub.point[ok]], sub.f[ok]), state.R[:k],
                                state.t[:k], g0, (obs.cam[mine], obs.point[mine], obs.f[mine]),
                                (state.R[k - 1], state.t[k - 1]), threshold, opts.min_pair_matches, seed)
    if found is not None:
        placed = found[0].R, found[0].t
    if placed is None:
        m = tracks.pair(k - 1, k)
        if len(m) < opts.min_pair_matches:
            return None
        pm = pair_method(method, m.has_gravity)
        hint = None if g0 is None or pm != "6pt-bending" else state.R[k - 1].T @ g0
        est = estimate(rig, m, method=pm, seed=seed, options=opts.pair_estimator(), gravity_hint=hint)
        if not est.success:
            return None
        placed = state.R[k - 1] @ est.R, state.R[k - 1] @ est.t + state.t[k - 1]
    dR = placed[0] @ state.R[k].T
    R, t = state.R.copy(), state.t.copy()
    R[k:] = dR @ state.R[k:]
    t[k:] = (state.t[k:] - state.t[k]) @ dR.T + placed[1]
    return R, t


def repair_links(rig: Rig, tracks: Tracks, obs: Observations, res, inliers, method: str, threshold: float,
                 opts: SequenceOptions, seed: int, **refine):
    """Re-place the views after each broken link (:func:`broken_link`) by resection and adjust again, kept
    where the joint MSAC score over all observations falls; returns (BundleResult, inliers, repairs)."""
    def score(state):
        st, prob = triangulated(rig, obs, state)
        return msac_score(observation_errors(prob, st), threshold)

    repairs = 0
    best = score(res.state)
    for _ in range(opts.link_repairs):
        k = broken_link(obs, inliers, opts.link_retention, opts.min_pair_matches)
        if k is None:
            break
        moved = _relinked(rig, tracks, obs, res.state, k, method, threshold, opts, seed + k)
        if moved is None:
            break
        res2, inl2 = refine_sequence(rig, obs, moved[0], moved[1], res.state.gravity, threshold, **refine)
        s2 = score(res2.state)
        if s2 >= best:
            break
        res, inliers, best, repairs = res2, inl2, s2, repairs + 1
    return res, inliers, repairs


def _seen_twice(obs: Observations, mask: np.ndarray) -> np.ndarray:
    """mask restricted to landmarks that keep at least two of their observations in it."""
    n = np.bincount(obs.point, weights=mask.astype(float), minlength=obs.num_points)
    return mask & (n[obs.point] >= 2)


def adjust_sequence(model_rig: Rig, tracks: Tracks, obs: Observations, obs_index: np.ndarray, R, t, gravity,
                    with_gravity: bool, method: str, priors, threshold: float, opts: SequenceOptions, seed: int,
                    t0: float) -> SequenceEstimate:
    """The joint adjustment of a placed sequence and its result: every orchestrator's last step.

    ``obs`` are the observations adjusted, ``obs_index`` their rows in ``tracks`` (the result's inlier mask is
    over the tracks); ``R``, ``t``, ``gravity`` the start (``with_gravity`` False: the rig is taken as rigid). The
    robust adjustment (:func:`refine_sequence`) is followed by the repair of broken links (:func:`repair_links`);
    every view's gravity and its std come from the adjusted sequence's one gravity."""
    refine = dict(priors=priors, max_iterations=opts.max_iterations, rounds=opts.inlier_rounds,
                  huber_k=opts.estimator.huber_k, tol=opts.relative_tolerance, inlier_sigmas=opts.inlier_sigmas,
                  rest_turns=rest_turns_start(model_rig) if with_gravity else None)
    res, inl = refine_sequence(model_rig, obs, R, t, gravity, threshold, **refine)
    res, inl, repairs = repair_links(model_rig, tracks, obs, res, inl, method, threshold, opts, seed, **refine)
    inliers = np.zeros(len(tracks), bool)
    inliers[obs_index[inl]] = True
    st = res.state
    grav = sig = None
    reason = ""
    if with_gravity and st.gravity is not None:
        grav = st.view_gravity
        sig = np.array([res.gravity_sigma_rad(k) for k in range(len(st.R))])
    elif method != "6pt-nonbending":
        reason = RIGID_REASON
    return SequenceEstimate(method=method, success=True, R=st.R, t=st.t, gravity=grav, gravity_sigma_rad=sig,
                            inliers=inliers, time_s=time.perf_counter() - t0, reason=reason, bundle=res,
                            link_repairs=repairs)


__all__ = ["CORRESPONDENCE_BIAS_FLOOR_PX", "Chain", "PairAttempt", "SequenceEstimate", "SequenceOptions", "Unlinked",
           "adjust_sequence", "broken_link", "camera_noise_scale", "choose_gravity", "distinct_candidates",
           "hold_camera_noise_scale", "link_retention", "measured_gravity_excess", "observation_errors",
           "refine_sequence", "repair_links", "resect_on_landmarks", "tracks_observations", "triangulated"]
