"""The joint estimate, view by view: a sliding window over the newest views of a sequence.

:class:`IncrementalSequence` takes the observations of one static view at a
time (camera, landmark id, bearing, optionally measured gravity) and returns
that view's pose in the sequence origin (view 0) and its gravity from the
joint solution (docs/PIPELINE.md, "The joint estimate over the sequence"):

1. The new view is paired with an earlier view that shares enough landmarks
   (seen by two cameras at least): the newest few first, then any older view
   of the sequence, most shared landmarks first. While the sequence is young it
   is estimated with the two-view estimator of the method and its pose in
   the origin follows by chaining; later it is placed by resection on the
   landmarks earlier views triangulate (:mod:`.resection`; the
   two-view estimator only where too few of them fit).
2. Gravity: the first pair's gravity candidates (its own and the basins it
   left open) are compared by the joint cost; while the sequence is young,
   or when a new pair's gravity contradicts the joint one beyond that pair's
   own noise, the joint gravity competes again with the pair's candidates.
   Candidates whose joint cost is within the noise of the winner's are
   rivals: their spread enters the published std until the views tell them
   apart; on parallel bars a young vision-only sequence publishes no gravity.
3. The newest ``window`` views are adjusted jointly (robust bundle adjustment
   with inlier classification, :func:`.sequence_steps.refine_sequence`; after a
   resection from the inliers so far, the rest of the window being adjusted
   already); older
   views keep their poses. Their observations of landmarks the window still
   sees stay in the problem (with those fixed poses); landmarks the window
   no longer sees are condensed, poses fixed, into information on the
   origin's gravity (:func:`.bundle.condense_gravity`) that every later solve
   uses as a prior. So every observation counts once and the problem stays
   the size of the window.

:meth:`IncrementalSequence.batch` adjusts all views of the sequence at once
from the incremental result. A view that shares too few landmarks with the
views before it starts a new sequence (:class:`NewSequence`; its gravity is
unknown again unless :meth:`IncrementalSequence.bridge` carries it over); a
later view that shares enough with a view of the sequence the break ended
merges the two in the earlier origin (docs/PIPELINE.md, "Merging sequences").
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np

from .bundle import (
    BundleState,
    GravityInformation,
    GravityPriors,
    Observations,
    RotationPrior,
    condense_gravity,
    covariance_from_information,
    gravity_covariance,
    largest_sigma,
    rest_turns_start,
)
from .estimators import MINIMAL_SAMPLE, Estimate, EstimatorOptions, estimate, pair_method
from .matches import Matches
from .rig import Rig
from .sequence_steps import (
    PairAttempt,
    SequenceEstimate,
    SequenceOptions,
    adjust_sequence,
    choose_gravity,
    distinct_candidates,
    refine_sequence,
    resect_on_landmarks,
    triangulated,
)
from .so3 import angle_between, log_so3, normalize, tangent_basis
from .tilt_mixture import CalibrationOdds, MixedGravity, mixed_gravity, prior_sigma_rad
from .tracks import Tracks

RECONSIDER_SIGMAS = 3.0  # a pair's gravity contradicts the joint one beyond this many of its own stds only
# a view keeps so few of its linked observations that a view keeping CHANCE_LINK_SHARE of the window's other
# views' share (its own outliers may be many more than theirs) would keep as few with at most this chance: its
# link held by chance (one in a million of the views that do belong)
CHANCE_LINK_PROBABILITY = 1e-6
CHANCE_LINK_SHARE = 0.5
PARALLEL_COS = 0.99  # bars whose axes are this close to (anti)parallel observe gravity as one bar (paper, 3.3)
# a pair's inlier thresholds take in this many times the two views' coherent offsets together (their residual
# ringings' envelopes): an envelope bounds how far a camera's bearings may be moved alike, and where the pair's
# model cannot follow such a turn the error it leaves reaches it
OFFSET_INLIER_FACTOR = 1.5


def parallel_bars(rig: Rig) -> bool:
    """Whether every flexible bar of the rig lies along one axis (e.g. two cameras at the ends of one bar): its
    bending then says nothing of gravity's axial component, and a few views leave two basins (paper, section
    3.3) that their joint cost does not reliably tell apart (docs/PIPELINE.md, "Gravity of a young sequence")."""
    u, _, cr = rig.bar_coefficients
    u = u[cr > 0]
    return len(u) > 0 and bool(np.all(np.abs(u @ u[0]) >= PARALLEL_COS))


def gravity_inflation(res) -> float:
    """How much the published covariance of the origin's gravity exceeds the model's (the information of the
    solve's independent-error model), as the largest ratio of variances in any direction (>= 1): 1 where the
    covariance is the model's, more where the cluster-robust one (:func:`.bundle.cluster_robust_covariance`)
    found errors shared within holds' cameras."""
    lay = res.layout
    if lay.gravity is None or res.state.gravity is None:
        return 1.0
    g = lay.gravity_of(0)
    model = covariance_from_information(res.information)
    Cm, Cr = model[g, g], res.covariance[g, g]
    if not (np.all(np.isfinite(Cm)) and np.all(np.isfinite(Cr))):
        return 1.0
    try:
        Li = np.linalg.inv(np.linalg.cholesky(0.5 * (Cm + Cm.T)))
    except np.linalg.LinAlgError:
        return 1.0
    return max(1.0, float(np.linalg.eigvalsh(Li @ Cr @ Li.T).max()))


class StartReason(Enum):
    """Why a view is the origin of a sequence (its gravity is unknown again); the value is the phrase shown."""

    FIRST_VIEW = "first view"  # the first view after construction or a reset
    NO_SHARED_LANDMARKS = "too few landmarks shared"  # no earlier view shares enough landmarks from two cameras
    PAIR_FAILED = "no pair estimate"  # views share enough landmarks but every two-view estimate failed
    # placed, but the joint solve kept fewer of its observations than its pair's solver needs: no pose of the images'
    FEW_INLIERS = "too few of its landmarks kept by the joint solve"


class GravityWithheld(Enum):
    """Why a view's estimate carries no gravity though its sequence has one (docs/PIPELINE.md, "Gravity of a young
    sequence"); the value is the phrase shown."""

    YOUNG_PARALLEL_BARS = ("its sequence is young and every bar lies along one axis: their bending says nothing of "
                           "gravity's component along it, and a few holds leave two basins (vision only)")
    ONE_ATTITUDE = ("every hold of its sequence lies within 1 deg of the first one's attitude: pieces of one hold, "
                    "whose bending differs by nothing gravity explains (vision only)")


@dataclass(frozen=True)
class NewSequence:
    """:meth:`IncrementalSequence.add_view`'s result for a view that starts a sequence: the sequence number,
    the reason and the earlier views tried: what each shared or why its pair failed (shown to the user)."""

    sequence: int
    reason: StartReason
    tried: tuple[PairAttempt, ...] = ()

    @property
    def detail(self) -> str:
        """What the earlier views tried shared or why their pairs failed, as shown to the user."""
        return "; ".join(a.describe("landmarks") for a in self.tried) or \
            ("" if self.reason is StartReason.FIRST_VIEW else "no earlier view")

    def __str__(self) -> str:
        return f"view starts sequence {self.sequence} ({self.reason.value}{': ' if self.detail else ''}{self.detail})"


@dataclass(frozen=True)
class _Pairing:
    """:meth:`IncrementalSequence._pair`'s outcome: the reference view, pair method and two-view estimate of a
    new view or, where no earlier view gives one (``estimate`` None), why a sequence starts and the views tried."""

    reference: int = -1
    method: str = ""
    estimate: Estimate | None = None
    reason: StartReason | None = None
    tried: tuple[PairAttempt, ...] = ()


@dataclass
class ViewEstimate:
    """One view of a sequence: pose in the origin (p_0 = R p + t), gravity in its body frame from the joint
    solution (m/s^2) with its largest angular std, and how it was obtained."""

    sequence: int  # sequence number (a reset or a break starts the next)
    view: int  # index in the sequence (0 = origin)
    reference: int  # the view it was paired with
    method: str  # two-view method of that pair
    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray | None
    gravity_sigma_rad: float
    cov_gravity: np.ndarray | None  # (3, 3) m^2/s^4, rank 2
    cov_pose: np.ndarray  # (6, 6) over (dr in the body frame, t in the origin)
    num_observations: int
    num_inliers: int
    window: int  # views adjusted in this solve
    time_s: float
    merged: int | None = None  # an earlier sequence this view linked to, merged into this one (its origin kept)
    merged_views: int = 0  # views that sequence brought: this sequence's earlier views moved up by as many
    # the first estimate of a sequence's origin view (it started the sequence, so it had none), from the same
    # solve as this view's: the sequence's own origin with its second view (where the solve gives it a gravity),
    # or, with a merge, the merged sequence's origin, now view merged_views (where the solve's window holds it);
    # None otherwise
    origin: ViewEstimate | None = None
    # the view linked to no view of the sequence before it but to an earlier sequence a break ended, which it
    # continues: that sequence (``merged``) is current again, the one it could not join was broken (a sequence
    # of its own it never had)
    continued: bool = False
    gravity_withheld: GravityWithheld | None = None  # why gravity is None where the sequence has one
    # the weight of the calibrated accelerometer's prior of the tilt in this gravity (:mod:`.tilt_mixture`; None:
    # one prior)
    imu_calibrated_weight: float | None = None


@dataclass
class SequenceRecord:
    """What a sequence measured and estimated: its tracks (with measured gravity), the views' poses in its
    origin, the origin's gravity and each view's measured-gravity std (rad)."""

    tracks: Tracks
    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray | None
    measured_sigma: np.ndarray
    noise_scale: np.ndarray | None = None  # (K,) each view's bearing noise over the nominal one (None: all 1)


def _observation_scales(scale, n: int) -> np.ndarray | None:
    """Each observation's own noise scale (n,), at least 1 (a non-finite one counts as 1), or None where all are 1."""
    if scale is None:
        return None
    out = np.broadcast_to(np.asarray(scale, float), (n,)).copy()
    out = np.where(np.isfinite(out), np.maximum(out, 1.0), 1.0)
    return None if np.all(out == 1.0) else out


def _landmark_keys(cam: np.ndarray, track: np.ndarray) -> np.ndarray:
    """One key per observation for its (camera, landmark) pair: views share a landmark when one camera sees it."""
    return cam * (1 << 40) + track


@dataclass
class _View:
    """One view of a sequence: its observations (camera, landmark id, unit bearing each), its measured gravity
    in its body frame (NaN: none) with that gravity's std (rad), its bearings' noise std over the nominal one,
    which of its observations the latest solve kept as inliers, and its pose in the sequence's origin
    (p_0 = R p + t; None until the view is placed)."""

    cam: np.ndarray  # (n,) int64
    track: np.ndarray  # (n,) int64
    f: np.ndarray  # (n, 3)
    measured: np.ndarray  # (3,), NaN without measured gravity
    measured_sigma: float
    noise_scale: float = 1.0
    offset_rad: float = 0.0  # how far all of a camera's bearings may be moved alike (a residual ringing's envelope)
    unknown_turn_rad: np.ndarray | None = None  # (M,) std of each camera's turn nothing measured (None: none)
    inlier: np.ndarray | None = None  # (n,) bool; None: all
    R: np.ndarray | None = None
    t: np.ndarray | None = None
    key: object = None  # what names the view (the hold's stamp), for the turns of later views
    turn: tuple | None = None  # (key of the view before it, R: p_before = R p_this, std rad) from the gyro
    tilt_sigma: float | None = None  # prior std (rad) of the measured gravity's tilt known at this view
    scale_tilt: float = 0.0  # std (rad) of the tilt uncalibrated axis scales may give this view's measured gravity
    scales_unknown: bool | None = None  # whether the accelerometer's scales are known to be uncalibrated at this view
    calibration: CalibrationOdds | None = None  # the tilt's calibrated prior and its odds known at this view
    obs_scale: np.ndarray | None = None  # (n,) each observation's noise over the view's (None: all 1)

    def __post_init__(self):
        if self.inlier is None:
            self.inlier = np.ones(len(self.cam), bool)

    @property
    def has_gravity(self) -> bool:
        return bool(np.all(np.isfinite(self.measured)))

    def keys(self) -> np.ndarray:
        """:func:`_landmark_keys` of its observations."""
        return _landmark_keys(self.cam, self.track)


ONE_ATTITUDE_DEG = 1.0
"""Views of a sequence all within this rotation of the first share one attitude: pieces of one hold (split where
the images or the IMU read motion in its middle), where the rig's holds lie 5-30 deg apart. Their bending differs
by nothing a gravity could explain, so what gravity the images seem to tell there is the bars' state in each piece
(a ringing bar's offset read as static bending: a split hold's first pieces published 93 deg off at a std of
0.12 deg). Vision only, such a sequence publishes no gravity; with measured gravities, none surer than the
measured one under its tilt's prior (the tilt and gravity are one thing at one attitude)."""


@dataclass
class _Sequence:
    """Everything one sequence has seen and estimated: one :class:`_View` per view, the origin's gravity (set
    by :meth:`set_gravity` only) and what else is known of it."""

    number: int
    views: list = field(default_factory=list)  # _View each, in order (index = view number)
    _gravity: np.ndarray | None = None  # origin's gravity
    condensed: GravityInformation | None = None
    retired: set = field(default_factory=set)  # landmark ids folded into ``condensed``
    rivals: list = field(default_factory=list)  # origin gravities of basins whose joint cost is within the noise
    carried: GravityInformation | None = None  # the gravity a gyro-bridged break carried over (a prior on g_0)

    @property
    def gravity(self) -> np.ndarray | None:
        """The origin's gravity (m/s^2), None while unknown."""
        return self._gravity

    def set_gravity(self, gravity: np.ndarray | None) -> None:
        """The origin's gravity: a chosen candidate, a window solve's or one carried over a break."""
        self._gravity = gravity

    def information(self) -> GravityInformation | None:
        """Every prior on the origin's gravity: condensed from retired landmarks, and carried over a break."""
        if self.carried is None:
            return self.condensed
        return self.carried.combined(self.condensed)

    @property
    def num_views(self) -> int:
        return len(self.views)

    def posed(self) -> bool:
        """Whether every view has its pose (a view being added has none until it is placed)."""
        return all(v.R is not None for v in self.views)

    def poses(self, upto: int | None = None) -> tuple:
        """((K, 3, 3), (K, 3)): the poses of views [0, upto) in the origin."""
        vs = self.views[:upto]
        return np.array([v.R for v in vs]), np.array([v.t for v in vs])

    def measured(self, upto: int | None = None) -> np.ndarray:
        """(K, 3) measured gravity of views [0, upto) (NaN rows: none)."""
        return np.array([v.measured for v in self.views[:upto]])

    def measured_sigmas(self, upto: int | None = None) -> np.ndarray:
        """(K,) the measured gravity's std (rad) of views [0, upto): with the tilt its axes' scales may give each
        view where the newest of them that knows says the scales are uncalibrated (as for the tilt's prior: the
        evidence grows, and a view measured before it showed keeps the same attitude-dependent error)."""
        vs = self.views[:upto]
        known = [v.scales_unknown for v in vs if v.scales_unknown is not None]
        unknown = known[-1] if known else False
        return np.array([math.hypot(v.measured_sigma, v.scale_tilt) if unknown else v.measured_sigma for v in vs])

    def tilt_sigma(self, upto: int | None, default: float | None) -> float | None:
        """The prior std (rad) of the measured gravity's tilt in a solve of views [0, upto): the newest of them
        that knows one (the accelerometer's evidence grows), else ``default``; None where ``default`` is None
        (no tilt estimated)."""
        if default is None:
            return None
        known = [v.tilt_sigma for v in self.views[:upto] if v.tilt_sigma is not None]
        return known[-1] if known else default

    def calibration(self, upto: int | None) -> CalibrationOdds | None:
        """The tilt's calibrated prior and its odds in a solve of views [0, upto): the newest view's that knows
        them (None: the one prior)."""
        known = [v.calibration for v in self.views[:upto] if v.calibration is not None]
        return known[-1] if known else None

    def turns(self, upto: int | None = None) -> tuple:
        """The gyro's rotations between consecutive views [0, upto) (:class:`~.bundle.RotationPrior` each): a
        view's turn counts where the view before it is the one it was measured from."""
        vs = self.views[:upto]
        return tuple(RotationPrior(i - 1, i, np.asarray(v.turn[1], float), float(v.turn[2]))
                     for i, v in enumerate(vs) if i > 0 and v.turn is not None and v.turn[0] is not None
                     and v.turn[0] == vs[i - 1].key and math.isfinite(v.turn[2]) and v.turn[2] > 0)

    def noise_scales(self) -> np.ndarray:
        """(K,) each view's bearing noise over the nominal one."""
        return np.array([v.noise_scale for v in self.views], dtype=float)

    def scales(self) -> np.ndarray | None:
        """Per observation (in the order of :meth:`arrays`): its view's noise scale times its own; None when all
        are 1."""
        if all(v.noise_scale == 1.0 and v.obs_scale is None for v in self.views):
            return None
        return np.concatenate([v.noise_scale * (np.ones(len(v.cam)) if v.obs_scale is None else v.obs_scale)
                               for v in self.views])

    def column(self, name: str, upto: int | None = None) -> np.ndarray:
        """One per-observation field of views [0, upto) concatenated (``cam``, ``track``, ``f``, ``inlier``)."""
        return np.concatenate([getattr(v, name) for v in self.views[:upto]])

    def view_index(self, upto: int | None = None) -> np.ndarray:
        """(n,) the view of each observation of views [0, upto)."""
        vs = self.views[:upto]
        return np.repeat(np.arange(len(vs), dtype=np.int64), [len(v.cam) for v in vs])

    def arrays(self):
        """(view, cam, track, f, inlier) of every observation, view by view."""
        return (self.view_index(), self.column("cam"), self.column("track"), self.column("f"),
                self.column("inlier"))

    def unknown_turns(self, upto: int | None = None) -> np.ndarray | None:
        """(K, M) the std (rad) of each view's cameras' unknown turns, or None where there are none."""
        views = self.views[:upto]
        if all(v.unknown_turn_rad is None or not np.any(v.unknown_turn_rad > 0) for v in views):
            return None
        M = next(len(v.unknown_turn_rad) for v in views if v.unknown_turn_rad is not None)
        return np.array([np.zeros(M) if v.unknown_turn_rad is None else v.unknown_turn_rad for v in views])

    def set_inliers(self, flat: np.ndarray) -> None:
        """Every view's inlier mask from one array in the order of :meth:`arrays`."""
        sizes = np.cumsum([len(v.cam) for v in self.views])[:-1]
        for v, part in zip(self.views, np.split(flat, sizes)):
            v.inlier = part


def _rotated(info: GravityInformation | None, M: np.ndarray) -> GravityInformation | None:
    """Gravity information re-expressed in another origin (x' = M x)."""
    if info is None:
        return None
    d = normalize(M @ info.direction)
    T = tangent_basis(d).T @ M @ tangent_basis(info.direction)
    return GravityInformation(d, T @ info.information @ T.T)


class IncrementalSequence:
    """Views in, joint poses and gravity out; see the module docstring."""

    def __init__(self, rig: Rig, method: str = "6pt-bending", options: SequenceOptions | dict | None = None,
                 window: int = 10, seed: int = 0, keep_history: bool = False):
        self.rig = rig
        self.method = method
        self.options = options if isinstance(options, SequenceOptions) else SequenceOptions.from_dict(options)
        if int(window) < 2:
            raise ValueError(f"window must be at least 2 views, got {window}")
        self.window = int(window)
        self.seed = int(seed)
        self.young_views = self.options.young_views  # the joint gravity competes with each pair's until then
        self.reconsider_rad = math.radians(self.options.reconsider_deg)  # ... and when a pair disagrees this much
        self.model_rig = rig.as_rigid() if method == "6pt-nonbending" else rig
        self.with_gravity = method != "6pt-nonbending" and rig.is_flexible
        self.parallel_bars = parallel_bars(rig)  # vision only: a young sequence publishes no gravity yet
        # the cameras' rest turns (their rest rotations' calibration errors, docs/PIPELINE.md, "The rig file's
        # calibration"), a property of the rig: estimated by every window solve, carried across sequences
        self.rest_turns = rest_turns_start(rig) if self.with_gravity else None
        focal = float(np.mean([c.focal_px for c in rig.cameras]))
        self._focal_px = focal
        self.threshold = self.options.estimator.threshold_px / focal
        self._pair_options = self.options.pair_estimator()
        self._noise_rad = self.threshold / 2.0  # angular noise of the latest solve (condenses retired landmarks)
        self._noise_solved = False  # whether a solve has measured it (else it is the threshold's guess)
        self._tilt_priors = None  # (the tilt's prior std of the latest window solve, its calibrated alternative)
        # the least evidence any solve since the last reset gave the calibrated prior of the accelerometer's tilt
        # (the chip is the same across sequences; .tilt_mixture)
        self._images_log_bayes = math.inf
        # the latest solve's gravity variance, cluster-robust over model (>= 1): what retired landmarks condense
        # to is a model information and is deflated by it (docs/PIPELINE.md, "The joint estimate over the
        # sequence", step 6)
        self._gravity_inflation = 1.0
        from scipy.special import chdtri  # the chi-square quantile without importing scipy.stats (seconds)

        # a rival basin: its joint cost exceeds the best one's by less than this (chi^2, 2 dof of the direction)
        self._ambiguity_chi2 = float(chdtri(2, self.options.ambiguity_significance))
        self._sequences = 0
        self.seq = _Sequence(0)
        self.keep_history = keep_history  # keep finished sequences (the bar calibration wants them all)
        self.history: list = []
        self._broken: list = []  # the latest sequences a break ended: a later view may link and merge them
        self._last_gravity = None  # (view, its gravity in its body frame, its std) as last published
        self._carry = None  # what the sequence a break ended passes to the next one (see bridge)
        self._ended = None  # the sequence the latest break ended

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Start a new sequence: the next view is its origin (with ``keep_history`` the old one is kept). A
        reset on request merges with nothing before it."""
        self._new_sequence()
        self._broken.clear()
        self._images_log_bayes = math.inf  # the user may have changed the IMU

    def _new_sequence(self) -> None:
        if self.keep_history and self.seq.num_views >= 2:
            self.history.append(self.seq)
        self._sequences += 1
        self.seq = _Sequence(self._sequences)
        self._carry = None
        self._last_gravity = None

    def bridge(self, rotation, sigma_rad: float) -> bool:
        """Carry the gravity of the sequence a break just ended into the new one (whose only view is the hold
        after the break), given the rotation of the rig between the two holds (``rotation`` maps the new
        hold's body frame into the previous hold's, p_prev = R p_new, e.g. the gyro integrated over the move)
        and its angular std (rad): g_0 of the new sequence starts at R^T g_prev and enters every solve as a
        prior with the two stds combined (docs/PIPELINE.md, "Bridging a break"). Vision only (measured
        gravity needs no bridge); False where there is nothing to carry."""
        s = self.seq
        if not self.with_gravity or s.num_views != 1 or self._carry is None or self._priors(1) is not None:
            return False
        g_prev, sigma_prev = self._carry
        sigma = math.hypot(sigma_prev, float(sigma_rad))
        if not math.isfinite(sigma) or sigma <= 0.0:
            return False
        g0 = np.asarray(rotation, float).T @ g_prev
        s.set_gravity(g0)
        s.carried = GravityInformation(normalize(g0), np.eye(2) / sigma ** 2)
        self._carry = None
        return True

    def sequences(self) -> list:
        """Every sequence of two views or more so far (with ``keep_history``; else the current one): a
        :class:`SequenceRecord` each."""
        seqs = self.history + ([self.seq] if self.seq.num_views >= 2 else [])
        return [SequenceRecord(self._tracks_of(s), *s.poses(), s.gravity, s.measured_sigmas(), s.noise_scales())
                for s in seqs if s.posed()]

    @property
    def num_views(self) -> int:
        return self.seq.num_views

    @property
    def has_measured_gravity(self) -> bool:
        """Whether a view of the current sequence has a measured (IMU) gravity: its estimates rest on it."""
        return self.seq.num_views > 0 and bool(np.isfinite(self.seq.measured()).all(axis=1).any())

    @property
    def number(self) -> int:
        """The current sequence's number (a reset or a break starts the next)."""
        return self.seq.number

    def tracks(self) -> Tracks:
        """The current sequence's observations as tracks (with the measured gravity)."""
        return self._tracks_of(self.seq)

    @staticmethod
    def _tracks_of(s: _Sequence) -> Tracks:
        view, cam, track, f, _ = s.arrays()
        g = s.measured()
        return Tracks(view, cam, track, f, g if np.isfinite(g).any() else None, num_views=s.num_views,
                      source=f"sequence {s.number}")

    def relative_pose(self, view: int, reference: int):
        """(R, t) of ``view`` in ``reference``'s body frame (p_ref = R p + t)."""
        s = self.seq
        r, v = s.views[reference], s.views[view]
        return r.R.T @ v.R, r.R.T @ (v.t - r.t)

    @property
    def noise_rad(self) -> float:
        """Angular std of one bearing as the latest joint solve measured it (rad): the nominal noise a view's
        ``noise_scale`` multiplies."""
        return float(self._noise_rad)

    def noise_scale(self, extra_sigma_rad: float) -> float:
        """The ``noise_scale`` of a view whose bearings carry ``extra_sigma_rad`` of noise on top of the
        nominal one: sqrt(1 + (extra / nominal)^2)."""
        if not (extra_sigma_rad > 0 and math.isfinite(extra_sigma_rad)):
            return 1.0
        return math.hypot(1.0, extra_sigma_rad / max(self.noise_rad, 1e-12))

    # ----------------------------------------------------------------- views
    def add_view(self, cam, track, f, measured_gravity=None, measured_sigma_rad: float | None = None,
                 noise_scale: float = 1.0, key=None, turn: tuple | None = None,
                 offset_rad: float = 0.0, unknown_turn_rad=None,
                 tilt_sigma_rad: float | None = None, obs_scale=None, scale_tilt_rad: float = 0.0,
                 scales_unknown: bool | None = None,
                 calibration: CalibrationOdds | None = None) -> ViewEstimate | NewSequence:
        """Add the next view's observations; returns its :class:`ViewEstimate`, or :class:`NewSequence` for a
        view that is the origin of a sequence (the first one, or one no earlier view links to).
        ``noise_scale`` (>= 1): the view's bearing noise std over the nominal one (a hold measured while
        its bars may still ring): its observations weigh 1 / noise_scale^2 in every joint solve.
        ``key`` names the view; ``turn`` = (key of an earlier view, R, std rad): the rotation the gyro measured
        from this view's body frame into that view's (p_that = R p_this), a prior of every joint solve with
        measured gravity while that view precedes this one in the sequence (:class:`~.bundle.RotationPrior`).
        ``offset_rad``: how far a residual ringing may move each camera's bearings alike (the pair thresholds take
        it in). ``unknown_turn_rad`` (M,) or one for all: the std (rad per axis) of a turn of each camera nothing
        measured (a snapshot's ringing without an IMU): the estimate is unchanged, its covariance carries it
        (:func:`~.bundle.cluster_robust_covariance`). ``tilt_sigma_rad``: the prior std of the measured gravity's
        constant tilt known at this view (what the accelerometer's norms show); the newest view's is the
        sequence's from then on (None: ``options.gravity_bias_sigma``; no tilt where that is None). ``obs_scale``
        (n,), each >= 1: an observation's own noise over the view's (a link whose position is a corner found in
        this hold, not the landmark's reference patch aligned: it carries the corner's viewpoint bias).
        ``scale_tilt_rad``: the std of the tilt uncalibrated axis scales may give this view's measured gravity (its
        attitude's), and ``scales_unknown`` whether the accelerometer is known so far to be such a chip (None: not
        known); the newest view's word holds for every view of the sequence (:meth:`_Sequence.measured_sigmas`).
        ``calibration``: the tilt's prior were the accelerometer calibrated and the odds that it is, known at this
        view (the newest view's word holds): each view's gravity is then the two priors' mixture
        (:mod:`.tilt_mixture`; None: the one prior).
        """
        t0 = time.perf_counter()
        cam = np.asarray(cam, dtype=np.int64)
        track = np.asarray(track, dtype=np.int64)
        f = normalize(np.asarray(f, dtype=float).reshape(-1, 3))
        g = np.full(3, np.nan) if measured_gravity is None else np.asarray(measured_gravity, float)
        sg = self.options.estimator.gravity_prior_sigma if measured_sigma_rad is None else float(measured_sigma_rad)
        s = self.seq
        k = s.num_views
        turned = None
        if unknown_turn_rad is not None:
            turned = np.broadcast_to(np.nan_to_num(np.asarray(unknown_turn_rad, float), nan=0.0, posinf=0.0),
                                     (self.rig.num_cameras,)).copy()
        new = _View(cam, track, f, g, sg, max(float(noise_scale), 1.0) if math.isfinite(noise_scale) else 1.0,
                    float(offset_rad) if offset_rad > 0 and math.isfinite(offset_rad) else 0.0,
                    unknown_turn_rad=turned, key=key, turn=turn,
                    tilt_sigma=float(tilt_sigma_rad) if tilt_sigma_rad is not None and tilt_sigma_rad > 0 else None,
                    obs_scale=_observation_scales(obs_scale, len(cam)),
                    scale_tilt=float(scale_tilt_rad) if math.isfinite(scale_tilt_rad) and scale_tilt_rad > 0 else 0.0,
                    scales_unknown=scales_unknown, calibration=calibration)
        s.views.append(new)
        if k == 0:
            new.R, new.t = np.eye(3), np.zeros(3)
            return NewSequence(s.number, StartReason.FIRST_VIEW)
        before = ([(v.R, v.t, v.inlier) for v in s.views[:k]], s.gravity, s.rivals)  # what the solves replace
        placed = self._resect(k)
        out = self._place_and_solve(k, placed, before, t0)
        if out is None and placed is not None:
            # the resection's pose did not hold in the window solve (placed on landmarks it matched by chance):
            # the pair route, as for a view no resection places
            out = self._place_and_solve(k, None, before, t0)
        if out is None:
            self._restart_from_last()
            out = NewSequence(self.seq.number, StartReason.FEW_INLIERS)
        if isinstance(out, NewSequence):
            return self._continue_broken(t0) or out
        return out

    def _continue_broken(self, t0: float) -> ViewEstimate | None:
        """The view a break just made an origin, placed in an earlier sequence a break ended where it shares
        enough landmarks with one of its views (:meth:`_merge`): that sequence goes on with it (docs/PIPELINE.md,
        "Merging sequences"); None where none links it."""
        merged = self._merge(0, skip=self._ended)  # (not the sequence it just failed to join)
        if merged is None:
            return None
        number, n, j, pm = merged
        self._carry = None  # (for a sequence of its own, which it is not)
        res, first = self._solve_window(n, False)
        self._retire(first + 1)
        out = self._estimate(n, j, pm, res, first, time.perf_counter() - t0)
        out.merged, out.merged_views, out.continued = number, n, True
        return out

    def _place_and_solve(self, k: int, placed, before: tuple, t0: float):
        """View k placed by ``placed`` (a resection's (reference, method, pose)) or, where None, by the pair route,
        then the window solve: its :class:`ViewEstimate`, :class:`NewSequence` where no pair links it, or None
        where the window solve kept too few of its observations (the views given back what ``before`` holds)."""
        s = self.seq
        new = s.views[k]
        warm = placed is not None
        if warm:
            j, pm, (new.R, new.t) = placed
        else:
            paired = self._pair(k)
            # a young sequence's view that no pair places (its links from one camera only: a generalized relative
            # pose leaves the scale free) is placed on the landmarks known in 3D, as an older sequence's would be
            placed = self._resect(k, young=True) if paired.estimate is None and k < self.young_views else None
            if placed is not None:
                warm = True
                j, pm, (new.R, new.t) = placed
            elif paired.estimate is None:
                self._restart_from_last()
                return NewSequence(self.seq.number, paired.reason, paired.tried)
            else:
                j, pm, est = paired.reference, paired.method, paired.estimate
                ref = s.views[j]
                new.R, new.t = ref.R @ est.R, ref.R @ est.t + ref.t
                if self.with_gravity:
                    self._update_gravity(k, j, est)
        merged = self._merge(k)
        if merged is not None:
            k, j = k + merged[1], j + merged[1]
            warm = False
        res, first = self._solve_window(k, warm)
        if merged is None and (np.count_nonzero(s.views[k].inlier) < MINIMAL_SAMPLE[pm]
                               or self._kept_by_chance(k, first)):
            # the window solve kept fewer of the new view's observations than its pair's solver needs, or a
            # share of them the other views' would keep by chance only: the images do not determine its pose
            # (a link that held by chance, its pose fitted to a few); the earlier views get back what they had.
            for v, (R, t, inlier) in zip(s.views, before[0]):
                v.R, v.t, v.inlier = R, t, inlier
            s.set_gravity(before[1])
            s.rivals = before[2]
            new.inlier = np.ones(len(new.cam), bool)
            return None
        self._retire(first + 1)
        origin = None
        if merged is not None and first <= merged[1] < k:  # the previous view in time is the earlier sequence's last
            origin = self._estimate(merged[1], merged[1] - 1, pm, res, first, time.perf_counter() - t0)
        elif merged is None and k == 1 and self.with_gravity:
            # the origin's gravity comes from the same solve as view 1's (its pose is the origin's by definition):
            # its estimate, paired with view 1, so that every hold of a sequence of two or more has one
            origin = self._estimate(0, 1, pm, res, first, time.perf_counter() - t0)
            origin = origin if origin.gravity is not None else None
        out = self._estimate(k, j, pm, res, first, time.perf_counter() - t0)
        out.origin = origin
        if merged is not None:
            out.merged, out.merged_views = merged[0], merged[1]
        return out

    # ----------------------------------------------------------------- merges
    def _merge(self, k: int, skip=None):
        """Merge the current sequence into an earlier one that a break ended, where view k shares enough
        landmarks with one of its views (docs/PIPELINE.md, "Merging sequences"): the current sequence's views
        are re-expressed in that sequence's origin from the two-view estimate of the pair, the two gravities
        (and rival basins) compete by the joint cost, condensed gravity information is rotated and summed.
        Returns (the earlier sequence's number, its number of views, the view of it the pair linked, the pair's
        method) or None."""
        s = self.seq
        opts = self.options
        vk = s.views[k]
        key = vk.keys()
        for p in reversed(self._broken):
            if p is skip:
                continue
            view, cam, track = p.view_index(), p.column("cam"), p.column("track")
            hit = np.isin(_landmark_keys(cam, track), key)
            ncam = self.rig.num_cameras
            per_cam = np.bincount(view[hit] * ncam + cam[hit], minlength=p.num_views * ncam).reshape(-1, ncam)
            shared = per_cam.sum(axis=1)
            ok = (shared >= opts.min_pair_matches) & (np.count_nonzero(per_cam, axis=1) >= 2)
            for j in np.argsort(-shared, kind="stable")[: opts.max_pair_gap]:
                if not ok[j]:
                    break
                vj = p.views[j]
                ia, ib = np.intersect1d(vj.keys(), key, return_indices=True)[1:]
                has_g = vj.has_gravity and vk.has_gravity
                pm = pair_method(self.method, has_g)
                m = Matches(vj.f[ia], vk.f[ib], vj.cam[ia], vj.measured if has_g else None,
                            vk.measured if has_g else None, source=f"sequence {p.number} view {j}, view {k}")
                est = estimate(self.model_rig, m, method=pm, seed=self.seed + k,
                               options=self.pair_options(vj.offset_rad, vk.offset_rad))
                if est.success:
                    n = p.num_views
                    self._join(p, int(j), k, est)
                    return p.number, n, int(j), pm
        return None

    def _join(self, p: _Sequence, j: int, k: int, est) -> None:
        """The current sequence appended to ``p`` (view k placed from p's view j by ``est``), and current."""
        s = self.seq
        vj, vk = p.views[j], s.views[k]
        M = vj.R @ est.R @ vk.R.T  # current origin -> p's origin
        c = vj.R @ est.t + vj.t - M @ vk.t
        p.views += [replace(v, R=M @ v.R, t=M @ v.t + c) for v in s.views]
        p.retired |= s.retired  # a gravity s carried over its break is dropped: p's own views say it again
        p.condensed = _rotated(s.condensed, M) if p.condensed is None else \
            p.condensed.combined(_rotated(s.condensed, M))
        self._broken = [b for b in self._broken if b is not p]
        self.history = [h for h in self.history if h is not p]
        self.seq = p
        if not self.with_gravity:
            return
        cands = [(g, math.inf) for g in [p.gravity] + p.rivals if g is not None]
        cands += [(M @ g, math.inf) for g in [s.gravity] + s.rivals if g is not None]
        if not cands:
            return
        self._choose_gravity(p, cands, p.num_views - 1)

    def _shared(self, j: int, k: int):
        """Observation indices (in views j and k) of the landmarks both see with the same camera."""
        s = self.seq
        _, ia, ib = np.intersect1d(s.views[j].keys(), s.views[k].keys(), assume_unique=False, return_indices=True)
        return ia, ib

    def _links(self, k: int, min_cameras: int = 2):
        """The earlier views view k may be paired with: (j, shared observation indices in j and in k, pair
        method) of those that share enough landmarks from ``min_cameras`` cameras (two for a two-view estimate:
        one camera's bearings leave a generalized relative pose's scale free); the newest ``max_pair_gap`` views first
        (newest first), then any older view of the sequence, most shared landmarks first (docs/PIPELINE.md,
        "The joint estimate over the sequence"), and, where there are none, what the best ones shared (for the
        user: the views tried of a :class:`NewSequence`)."""
        s = self.seq
        opts = self.options
        # landmarks shared with view k, per earlier view and camera, counted at once
        view, cam, track = s.view_index(k), s.column("cam", k), s.column("track", k)
        hit = np.isin(_landmark_keys(cam, track), s.views[k].keys())
        ncam = self.rig.num_cameras
        per_cam = np.bincount(view[hit] * ncam + cam[hit], minlength=k * ncam).reshape(k, ncam)
        shared = per_cam.sum(axis=1)
        cams = np.count_nonzero(per_cam, axis=1)
        ok = (shared >= opts.min_pair_matches) & (cams >= min_cameras)
        recent = np.arange(k - 1, max(-1, k - 1 - opts.max_pair_gap), -1)
        older = np.arange(k - 1 - opts.max_pair_gap, -1, -1)
        older = older[np.argsort(-shared[older], kind="stable")]
        out = []
        for j in np.concatenate([recent, older]).astype(int):
            if not ok[j]:
                continue
            ia, ib = self._shared(j, k)
            has_g = s.views[j].has_gravity and s.views[k].has_gravity
            out.append((int(j), ia, ib, pair_method(self.method, has_g)))
        if out:
            return out, ()
        best = np.argsort(-shared, kind="stable")[:3]
        return [], tuple(PairAttempt(int(j), int(shared[j]), int(cams[j])) for j in best)

    def _resect(self, k: int, young: bool = False):
        """(reference view, method, (R, t)) of view k placed by resection on the landmarks the earlier views
        of the window triangulate (docs/PIPELINE.md, "The joint estimate over the sequence"), or None where
        the two-view estimate is to place it: a young sequence (its gravity still competes with each pair's;
        ``young``: also then, for a view no pair places), no link, or too few landmarks that fit one pose."""
        s = self.seq
        opts = self.options
        if not opts.resect_views or (k < self.young_views and not young) or (self.with_gravity and s.gravity is None):
            return None
        if s.rivals:
            return None  # gravity still ambiguous: each new pair's candidates compete (_update_gravity)
        links, _ = self._links(k, min_cameras=1)  # landmarks known in 3D place a view from one camera
        if not links:
            return None
        j, _, _, pm = links[0]
        view, cam, track, f, inl = s.arrays()
        # every earlier view's landmarks (fixed poses outside the window): a view may return to an old place
        vk, vj = s.views[k], s.views[j]
        known = (view < k) & inl & np.isin(track, vk.track)
        placed = resect_on_landmarks(self.model_rig, (view[known], cam[known], track[known], f[known]),
                                     [v.R for v in s.views[:k]], [v.t for v in s.views[:k]],
                                     s.gravity if self.with_gravity else None,
                                     (vk.cam, vk.track, vk.f), (vj.R, vj.t), self.threshold,
                                     opts.min_pair_matches, self.seed + k, min_cameras=1)
        if placed is None:
            return None
        res, hit = placed
        inlier = np.zeros(len(vk.cam), bool)
        inlier[hit[res.inliers]] = True
        inlier[np.setdiff1d(np.arange(len(inlier)), hit)] = True  # new landmarks: judged by the window solve
        vk.inlier = inlier
        return j, pm, (res.R, res.t)

    def _pair(self, k: int) -> _Pairing:
        """The reference view, method and two-view estimate of view k, or why none. At most ``max_pair_gap``
        pairs are estimated, in the order of :meth:`_links`."""
        s = self.seq
        links, best = self._links(k)
        if not links:
            return _Pairing(reason=StartReason.NO_SHARED_LANDMARKS, tried=best)
        why = []
        for j, ia, ib, pm in links[: self.options.max_pair_gap]:
            vj, vk = s.views[j], s.views[k]
            has_g = vj.has_gravity and vk.has_gravity
            m = Matches(vj.f[ia], vk.f[ib], vj.cam[ia], vj.measured if has_g else None,
                        vk.measured if has_g else None, source=f"views {j}, {k}")
            est = estimate(self.model_rig, m, method=pm, seed=self.seed + k,
                           options=self.pair_options(vj.offset_rad, vk.offset_rad))
            if est.success:
                return _Pairing(j, pm, est)
            why.append(PairAttempt(j, len(ia), len(np.unique(vj.cam[ia])), estimated=True, failure=est.info.reason))
        return _Pairing(reason=StartReason.PAIR_FAILED, tried=tuple(why))

    def pair_options(self, *offsets_rad: float) -> EstimatorOptions:
        """The pair estimates' options for two views whose cameras' bearings may be moved alike by up to
        ``offsets_rad`` (a residual ringing: docs/PIPELINE.md, "Graded trust"): the inlier thresholds widened to
        take such an offset in, sqrt(threshold^2 + (OFFSET_INLIER_FACTOR x the views' offsets together)^2). A
        coherent offset is no outlier: a threshold below it keeps only the cameras it moved least and poses
        the view on them (its scale free with one camera)."""
        extra = OFFSET_INLIER_FACTOR * self._focal_px * math.hypot(*offsets_rad, 0.0)
        if not extra > 0:
            return self._pair_options
        o = self._pair_options
        return replace(o, threshold_px=math.hypot(o.threshold_px, extra),
                       loose_threshold_px=math.hypot(o.loose_threshold_px, extra))

    def two_view(self, matches: Matches, method: str, seed: int, offsets_rad: tuple = ()):
        """A two-view estimate with this sequence's rig model and pair options (a test on the side: nothing of
        the sequence changes); ``offsets_rad``: the two views' :meth:`pair_options`."""
        return estimate(self.model_rig, matches, method=method, seed=seed, options=self.pair_options(*offsets_rad))

    def _restart_from_last(self) -> None:
        """The newest view cannot be linked: it becomes the origin of a new sequence."""
        s = self.seq
        self._ended = s
        last = s.views.pop()
        if s.num_views >= 2 and s.posed() and self.options.merge_sequences > 0:
            self._broken = (self._broken + [s])[-self.options.merge_sequences:]
        carry = None
        if self._last_gravity is not None and self._last_gravity[0] == s.num_views - 1:
            carry = self._last_gravity[1:]  # the previous view's own gravity, in its body frame
        self._new_sequence()
        self._carry = carry
        self.seq.views.append(replace(last, inlier=None, R=np.eye(3), t=np.zeros(3)))

    def images_turn(self, key_before, key) -> np.ndarray | None:
        """The rotation the current sequence's poses turn the body by between the views named ``key_before``
        and ``key`` (p_before = R p_after, as the gyro's turn between them: what the images measured against it);
        None unless both are posed there."""
        views = {v.key: v for v in self.seq.views if v.key is not None and v.R is not None}
        a, b = views.get(key_before), views.get(key)
        if a is None or b is None:
            return None
        return a.R.T @ b.R

    # --------------------------------------------------------------- gravity
    def _priors(self, K: int) -> GravityPriors | None:
        s = self.seq
        if self.method != "4pt-bending" or not math.isfinite(self.options.estimator.gravity_prior_sigma):
            return None
        g = s.measured(K)
        if not np.isfinite(g).any():
            return None
        return GravityPriors(g, s.measured_sigmas(K), s.tilt_sigma(K, self.options.gravity_bias_sigma), s.turns(K))

    def _update_gravity(self, k: int, j: int, est) -> None:
        """Choose the origin's gravity among the joint one and the new pair's candidates (see the module)."""
        s = self.seq
        if est.gravity is None:
            return
        Rj, tj = s.views[j].R, s.views[j].t
        cands = [(Rj @ np.asarray(g, float), float(est.num_inliers))
                 for g in [est.gravity] + list(est.info.gravity_candidates)]
        # each basin's pose of view k in the origin (the pair's own first, then its starts')
        poses = [(Rj @ est.R, Rj @ est.t + tj)] + [(Rj @ P[:, :3], Rj @ P[:, 3] + tj)
                                                   for P in est.info.candidate_poses]
        basins = [(g, pose) for (g, _), pose in zip(cands, poses)]
        if self.method == "4pt-bending":
            cands += [(s.views[i].R @ s.views[i].measured, 0.0) for i in (j, k) if s.views[i].has_gravity]
        if s.gravity is not None:
            young = k < self.young_views or bool(s.rivals)
            # a pair contradicts the joint gravity by more than options.reconsider_deg and its own noise allows
            sigma = est.info.gravity_sigma_rad or 0.0
            if not young and angle_between(cands[0][0], s.gravity) < max(self.reconsider_rad,
                                                                         RECONSIDER_SIGMAS * sigma):
                return
            cands = [(s.gravity, math.inf)] + [(g, math.inf) for g in s.rivals] + cands
        self._choose_gravity(s, cands, k, basins)

    def _choose_gravity(self, s: _Sequence, cands: list, k: int, basins: list | None = None) -> None:
        """The joint gravity of sequence ``s`` (its window ending at view k) chosen among the candidates by the
        joint cost, the window's free views taking the winner's poses; candidates within the noise of it stay as
        rivals. Every candidate is adjusted: a basin left unadjusted could not be judged a rival. ``basins``:
        the new pair's (origin gravity, (R, t) of view k): each candidate starts view k at the pose of the
        basin nearest it."""
        opts = self.options
        distinct = distinct_candidates(cands, math.radians(opts.candidate_separation_deg), opts.max_candidates)
        view_poses = None
        if basins:
            view_poses = [(k, *min(basins, key=lambda b: angle_between(b[0], g))[1]) for g in distinct]
        obs, _, free = self._window_problem(k, max(0, k + 1 - self.window))
        scores = []
        chosen, _ = choose_gravity(self.model_rig, obs, *s.poses(), distinct, self._priors(k + 1),
                                   self.threshold,
                                   replace(opts, refined_candidates=max(opts.refined_candidates, len(distinct))),
                                   np.random.default_rng(self.seed + k), free_views=free,
                                   gravity_information=s.information(), scores=scores,
                                   noise_rad=self._noise_rad, view_poses=view_poses)
        if isinstance(chosen, np.ndarray):
            s.set_gravity(chosen)
        else:
            s.set_gravity(chosen.gravity)
            for i in free:
                s.views[i].R, s.views[i].t = chosen.R[i], chosen.t[i]
        s.rivals = self._rivals(s.gravity, scores)

    def _rivals(self, gravity: np.ndarray, scores: list) -> list:
        """The candidates' origin gravities whose joint cost is within the noise of the best one's and that lie
        apart from the chosen gravity: basins the views so far cannot tell apart (docs/PIPELINE.md, "Gravity
        of a young sequence"). Costs in chi^2 units: the score (MSAC and the priors') over the noise variance,
        the noise of the latest solve, or before any solve the best candidate's own (the threshold's guess of
        it is ten to a hundred times the noise of averaged holds: every basin would be a rival)."""
        if len(scores) < 2:
            return []
        noise = self._noise_rad
        best = min(scores, key=lambda c: c.chi2(noise))
        if not self._noise_solved and math.isfinite(best.noise_rad):
            # (a thousandth of the threshold: a guard for noise-free data, far below any image's noise)
            noise = max(best.noise_rad, 1e-3 * self.threshold)
        chi2 = np.array([c.chi2(noise) for c in scores])
        sep = math.radians(self.options.candidate_separation_deg)
        within = chi2 <= chi2.min() + self._ambiguity_chi2
        return [np.asarray(c.gravity, float) for c, w in zip(scores, within)
                if w and angle_between(c.gravity, gravity) > sep]

    # ---------------------------------------------------------------- solves
    def _window_problem(self, k: int, first: int):
        """Observations of the window views [first, k] and the older views' observations of landmarks the
        window sees (minus retired ones), and the free views."""
        s = self.seq
        view, cam, track, f, _ = s.arrays()
        sc = s.scales()
        # a retired landmark stays out even where a later view sees it again: what its older observations say
        # about gravity is in the condensed prior already (such a view is placed by resection on it)
        live = np.unique(track[view >= first])
        keep = np.isin(track, live)
        if s.retired:
            keep &= ~np.isin(track, np.fromiter(s.retired, np.int64))
        obs, _ = Observations.from_arrays(view[keep], cam[keep], track[keep], f[keep], k + 1,
                                          None if sc is None else sc[keep])
        free = np.arange(max(first, 1), k + 1)
        if first > 0 and not np.any(view[keep] < first):
            free = free[1:]  # nothing older ties the window to the origin: its first view holds the gauge
        return obs, np.flatnonzero(keep), free

    def _solve_window(self, k: int, warm: bool = False):
        """Robust adjustment of the window ending at view k. ``warm``: every view of it but k is adjusted
        already and k was placed by resection, so the inliers so far start it and one round may do."""
        s = self.seq
        first = max(0, k + 1 - self.window)
        obs, idx, free = self._window_problem(k, first)
        priors = self._priors(k + 1)
        # the tilt's prior of this solve and its calibrated alternative: each view's gravity weighs the two
        self._tilt_priors = None if priors is None or not priors.bias_sigma_rad else \
            (priors.bias_sigma_rad, s.calibration(k + 1))
        start = None
        if warm:  # the inliers so far, and the observations of landmarks not seen twice before view k
            before = np.bincount(obs.point, weights=obs.view < k, minlength=obs.num_points)
            start = s.column("inlier")[idx] | (before[obs.point] < 2)
        res, inl = refine_sequence(self.model_rig, obs, *s.poses(), s.gravity, self.threshold,
                                   priors=priors, gravity_information=s.information(), free_views=free,
                                   max_iterations=self.options.max_iterations, rounds=self.options.window_rounds,
                                   huber_k=self.options.estimator.huber_k, inliers=start,
                                   min_rounds=1 if warm else 2, tol=self.options.relative_tolerance,
                                   camera_noise=self.options.camera_noise,
                                   inlier_sigmas=self.options.inlier_sigmas, offset_sigma=s.unknown_turns(k + 1),
                                   rest_turns=self.rest_turns)
        st = res.state
        if st.rest_turns is not None and np.all(np.isfinite(st.rest_turns)):
            self.rest_turns = st.rest_turns
        for i in free:
            s.views[i].R, s.views[i].t = st.R[i], st.t[i]
        if self.with_gravity and st.gravity is not None:
            s.set_gravity(st.gravity)
        flat = s.column("inlier")
        flat[idx] = inl
        s.set_inliers(flat)
        return res, first

    def _kept_by_chance(self, k: int, first: int) -> bool:
        """Whether the window solve kept so few of view k's linked observations (of landmarks another window
        view sees) that a view keeping them at half the share q the window's other views keep theirs at would
        keep as few with a chance below CHANCE_LINK_PROBABILITY (the binomial tail): a pose fitted to the few
        bearings its link got right by chance, or to none (docs/PIPELINE.md, "The joint estimate over the
        sequence", step 1)."""
        from scipy.special import bdtr  # the binomial tail without importing scipy.stats (seconds)

        view, _, track, _, inl = self.seq.arrays()
        w = view >= first
        pairs = np.unique(np.stack([track[w], view[w]]), axis=1)  # each landmark once per view
        seen, times = np.unique(pairs[0], return_counts=True)
        linked = np.zeros(len(view), bool)
        linked[w] = np.isin(track[w], seen[times >= 2])
        mine, others = linked & (view == k), linked & (view < k)
        n, kept = int(mine.sum()), int(np.count_nonzero(inl[mine]))
        if n == 0 or not others.any():
            return False
        q = CHANCE_LINK_SHARE * float(np.mean(inl[others]))
        return float(bdtr(kept, n, q)) < CHANCE_LINK_PROBABILITY

    def _retire(self, first_next: int) -> None:
        """Fold landmarks no later window can see into the origin's gravity information (poses fixed)."""
        s = self.seq
        if not self.with_gravity or s.gravity is None or first_next <= 0:
            return
        view, cam, track, f, inl = s.arrays()
        still_seen = np.unique(track[view >= first_next])
        old = ~np.isin(track, still_seen) & inl
        if s.retired:
            old &= ~np.isin(track, np.fromiter(s.retired, np.int64))
        if not old.any():
            return
        sc = s.scales()
        obs, _ = Observations.from_arrays(view[old], cam[old], track[old], f[old], s.num_views,
                                          None if sc is None else sc[old])
        seen_twice = np.bincount(obs.point, minlength=obs.num_points) >= 2
        if seen_twice.any():
            obs, _ = obs.subset(seen_twice[obs.point])
            state = BundleState(*s.poses(), s.gravity, np.zeros((obs.num_points, 3)))
            state, _ = triangulated(self.model_rig, obs, state)
            info = condense_gravity(self.model_rig, obs, state, self._noise_rad, self.options.estimator.huber_k)
            if info is not None:
                info = GravityInformation(info.direction, info.information / self._gravity_inflation)
                s.condensed = info.combined(s.condensed)
        s.retired.update(int(x) for x in np.unique(track[old]))

    def gravity_resolved(self, k: int) -> bool:
        """Whether view k of the current sequence publishes its gravity: always with measured gravity or bars
        along more than one axis; vision only on parallel bars once the sequence is no longer young."""
        return (k >= self.young_views or not self.parallel_bars or self._priors(k + 1) is not None
                or self.seq.carried is not None)

    def ambiguity_rad(self) -> float:
        """Largest angle (rad) between the current sequence's gravity and a rival basin's (0 when resolved)."""
        s = self.seq
        if s.gravity is None or not s.rivals:
            return 0.0
        return max(float(angle_between(g, s.gravity)) for g in s.rivals)

    def one_attitude(self) -> bool:
        """Whether every view the current sequence has so far lies within :data:`ONE_ATTITUDE_DEG` of its first
        view's attitude: a hold split into pieces, whose bending differs between them by nothing gravity
        explains."""
        views = self.seq.views
        R0 = views[0].R
        return all(float(np.linalg.norm(log_so3(R0.T @ v.R))) < math.radians(ONE_ATTITUDE_DEG) for v in views[1:])

    def _calibrated_or_not(self, k: int, res) -> MixedGravity | None:
        """View k's gravity under the mixture of the tilt's two priors of the latest window solve ``res``
        (:mod:`.tilt_mixture`): None where that solve had one prior only."""
        if self._tilt_priors is None or self._tilt_priors[1] is None:
            return None
        C = res.gravity_tilt_covariance(k)
        mixed = None if C is None else mixed_gravity(res.state.bias, C, *self._tilt_priors,
                                                     images_log_bayes_cap=self._images_log_bayes)
        if mixed is not None:  # the chip's: what one solve refuted stays refuted (.tilt_mixture)
            self._images_log_bayes = min(self._images_log_bayes, mixed.images_log_bayes)
        return mixed

    def _estimate(self, k, j, pm, res, first, elapsed) -> ViewEstimate:
        s = self.seq
        self._noise_rad = res.sigma_rad
        self._noise_solved = True
        self._gravity_inflation = gravity_inflation(res)
        g = cov = mixed = None
        sigma = math.inf
        withheld = None
        if self.with_gravity and s.gravity is not None and not self.gravity_resolved(k):
            withheld = GravityWithheld.YOUNG_PARALLEL_BARS
        if self.with_gravity and s.gravity is not None and self.gravity_resolved(k):
            wide = s.views[k].R.T @ s.gravity
            # the local std knows one basin only: the spread to rival basins enters it (docs/PIPELINE.md)
            spread = self.ambiguity_rad()
            g, tangent = wide, res.gravity_tangent_covariance(k)
            wide_sigma = math.hypot(largest_sigma(tangent), spread)
            mixed = self._calibrated_or_not(k, res)
            if mixed is not None:  # the tilt's two priors weighed (docs/PIPELINE.md, "Calibrated or not")
                g = float(np.linalg.norm(wide)) * normalize(normalize(wide) + tangent_basis(normalize(wide)) @
                                                            mixed.shift)
                tangent = mixed.covariance
            sigma = math.hypot(largest_sigma(tangent), spread)
            cov = gravity_covariance(g, tangent)
            if spread > 0.0 and np.all(np.isfinite(cov)):
                u = normalize(g)
                cov = cov + spread ** 2 * float(g @ g) * (np.eye(3) - np.outer(u, u))
            if self.one_attitude():  # (docs/PIPELINE.md, "Gravity of a young sequence")
                priors = self._priors(len(s.views))
                if priors is None:
                    g = cov = None
                    sigma = math.inf
                    withheld = GravityWithheld.ONE_ATTITUDE
                else:  # no better than the measured gravity under its tilt's prior (the two, as weighed)
                    active = priors.active
                    measured = float(np.min(priors.sigma_rad[active])) if active.any() else 0.0
                    tilt = priors.bias_sigma_rad or 0.0
                    wide_sigma = max(wide_sigma, math.hypot(measured, tilt))
                    floor = math.hypot(measured, prior_sigma_rad(tilt, s.calibration(len(s.views))))
                    if sigma < floor and np.all(np.isfinite(cov)):
                        cov = cov * (floor / max(sigma, 1e-300)) ** 2
                        sigma = floor
            if g is not None:  # a break carries the sequence's own solve's gravity (the wide prior's)
                self._last_gravity = (k, wide, wide_sigma)
        vk = s.views[k]
        return ViewEstimate(sequence=s.number, view=k, reference=j, method=pm, R=vk.R.copy(), t=vk.t.copy(),
                            gravity=g, gravity_sigma_rad=sigma, cov_gravity=cov,
                            cov_pose=res.pose_covariance(k, body=True), num_observations=len(vk.cam),
                            num_inliers=int(np.count_nonzero(vk.inlier)), window=k + 1 - first,
                            time_s=elapsed, gravity_withheld=withheld,
                            imu_calibrated_weight=None if mixed is None or g is None else mixed.calibrated_weight)

    # ----------------------------------------------------------------- batch
    def batch(self) -> SequenceEstimate:
        """All views of the current sequence adjusted at once, from the incremental estimates."""
        t0 = time.perf_counter()
        s = self.seq
        K = s.num_views
        if K < 2 or not s.posed():
            return SequenceEstimate(method=self.method, success=False, reason="fewer than two linked views")
        view, cam, track, f, _ = s.arrays()
        obs, _ = Observations.from_arrays(view, cam, track, f, K, s.scales())
        seen = (np.bincount(obs.point, minlength=obs.num_points) >= 2)[obs.point]
        obs, _ = obs.subset(seen)
        return adjust_sequence(self.model_rig, self.tracks(), obs, np.flatnonzero(seen), *s.poses(), s.gravity,
                               self.with_gravity, self.method, self._priors(K),
                               self.threshold, self.options, self.seed, t0)


__all__ = ["ONE_ATTITUDE_DEG", "GravityWithheld", "IncrementalSequence", "NewSequence", "SequenceRecord", "StartReason",
           "ViewEstimate", "parallel_bars"]
