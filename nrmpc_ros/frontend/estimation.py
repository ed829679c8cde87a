"""The estimation stage of the pipeline: measured holds in, hold estimates out (docs/PIPELINE.md, "Two stages").

The intake stage (:class:`~nrmpc_ros.frontend.pipeline.Pipeline`: tracking, holds, settling, a hold's
measurement and its IMU gravity) hands each measured hold over as a :class:`MeasuredHold`; the
:class:`HoldEstimator` links its tracks to the landmarks of earlier holds (:mod:`.linking`, with patch
alignment) and adds it to the joint estimate over the sequence of holds
(:class:`~nrmpc_ros.core.incremental.IncrementalSequence`). Items are consumed in the order they were made and
none is dropped; :class:`SequenceReset` starts a new sequence at its place in that order.

Everything the estimator needs comes with the item: what depends on the IMU samples (the hold's averaged
accelerometer gravity, the gyro's rotation from the previous hold) is computed by the intake when it closes
the hold, so the estimate is the same whether the stage runs at once (replay) or later in its own worker
thread (the node). The one result that flows back, a hold's gravity as evidence of the accelerometer's bias,
goes to ``on_gravity`` and only moves the cameras' published extrinsics, never a decision of the intake.
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from ..core.bundle import gravity_covariance
from ..core.incremental import IncrementalSequence, NewSequence, StartReason, ViewEstimate
from ..core.rig import Rig
from ..core.tilt_mixture import CalibrationOdds, prior_sigma_rad, prior_weight
from .drops import Drop
from .gyro import GyroRotation
from .holds import Hold, RingingSource
from .imu import ImuGravity, ImuRefusal
from .imu_agreement import Agreement, ImuGravityCheck
from .imu_mount import TURNS_KEPT, imu_axes_from_turns, turn_refutes_axes, turn_refutes_gyro, turns_share_axes
from .linking import CORNER_BIAS_PX, HoldLinker


def _focal_px(rig: Rig) -> float:
    """The rig's typical focal length (px): its cameras' median, what a hold's ringing in pixels is turned into
    bearing angles with."""
    return float(np.median([c.focal_px for c in rig.cameras]))


def ringing_noise_rad(rig: Rig, hold: Hold, cam) -> float:
    """The angular noise (rad) a hold's residual ringing adds to each of its bearings (``cam``: the camera of
    each of them), on top of the averaged track noise.

    A snapshot's ringing is the predicted envelope of its bars' ringing at that instant (or, the ringing
    predicted and removed, that prediction's error): an offset that turns
    all of a camera's bearings together, so that camera's n points tell its rotation no better than one bearing
    with the ringing's std (per point sigma^2 + n ringing^2: the information n / (sigma^2 + n ringing^2) about
    the rotation). So is the uncertainty of a ringing stream hold's fitted rest beyond its tracks' noise (what the
    fit does not follow, e.g. the stamps' jitter times the ringing's speed, moves all of a camera's tracks alike).
    What remains of a settled hold's ringing after averaging many frames, or a short hold's spread, enters per
    point, as measured (docs/PIPELINE.md, "Graded trust")."""
    focal = _focal_px(rig)
    coherent = hold.ringing_source in (RingingSource.IMU, RingingSource.DEFAULT, RingingSource.PREDICTED,
                                       RingingSource.FIT) and len(cam)
    per_camera = float(np.median(np.unique(np.asarray(cam), return_counts=True)[1])) if coherent else 1.0
    return hold.ringing_px / focal * math.sqrt(per_camera)


def ringing_offset_rad(rig: Rig, hold: Hold) -> float:
    """How far (rad) a hold's residual ringing may move all of a camera's bearings alike: its envelope over the
    focal length (the pair estimates' inlier thresholds take it in: :meth:`.IncrementalSequence.pair_options`)."""
    return hold.ringing_px / _focal_px(rig) if math.isfinite(hold.ringing_px) and hold.ringing_px > 0 else 0.0


@dataclass
class HoldEstimate:
    """The estimate of one hold: its pose relative to the reference hold (p_ref = R p + t) and in the
    sequence origin, its gravity (current body frame) from the joint solution, and how the hold was measured."""

    stamp: float  # a frame inside the hold's settled part
    ref_stamp: float  # the same of the reference hold (the one it was paired with)
    method: str
    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray | None  # m/s^2, this hold's body frame
    gravity_sigma_deg: float
    cov_gravity: np.ndarray | None
    num_inliers: int
    num_observations: int
    time_ms: float
    origin_stamp: float  # the sequence's first hold: the origin frame
    R_origin: np.ndarray  # pose in the origin (p_origin = R_origin p + t_origin)
    t_origin: np.ndarray
    cov_pose: np.ndarray  # (6, 6): rotation (body frame) and translation (origin frame)
    sequence: int
    hold_index: int
    hold: Hold
    imu_gravity: np.ndarray | None = None  # this hold's averaged accelerometer gravity (body frame)
    links: Counter = field(default_factory=Counter)
    window: int = 0
    noise_scale: float = 1.0  # the hold's bearing noise over the nominal one: its residual ringing's penalty
    ref_hold_index: int | None = None  # the reference hold's index in the sequence (its TF frame's name)
    # the weight the calibrated accelerometer's prior of the tilt got in the gravity (None: one prior;
    # docs/PIPELINE.md, "Calibrated or not")
    imu_calibrated_weight: float | None = None


@dataclass
class MeasuredHold:
    """A hold the intake measured, ready for the estimation stage: the hold, its averaged accelerometer gravity
    (None: no IMU or too few samples) with that gravity's angular std (rad), the gyro's rotation from the
    previous hold given to the stage since the last reset as (that hold's stamp, R, std rad) (None: no such
    hold or no gyro), the entry of the pipeline's hold log it fills in (None: no log kept), and the prior std
    (rad) of the accelerometer's tilt the still holds' norms support so far
    (:class:`~nrmpc_ros.frontend.accel_tilt.AccelTiltEvidence`; None: the sequence options')."""

    hold: Hold
    imu: ImuGravity | None
    imu_sigma_rad: float | None
    turn: tuple | None
    attempt: object | None = None
    tilt_sigma_rad: float | None = None
    scale_tilt_rad: float = 0.0  # the tilt uncalibrated axis scales may give its IMU gravity (.accel_tilt)
    scales_unknown: bool | None = None  # whether the norms show the accelerometer uncalibrated so far
    calibration: CalibrationOdds | None = None  # the tilt's calibrated prior and its odds (.accel_tilt)

    @property
    def gravity_sigma_rad(self) -> float | None:
        """The IMU gravity's std as the sequence takes it now: with the scales' tilt where they are unknown."""
        if self.imu_sigma_rad is None:
            return None
        return math.hypot(self.imu_sigma_rad, self.scale_tilt_rad) if self.scales_unknown else self.imu_sigma_rad


@dataclass
class SettledAnchors:
    """The anchor frames of a hold that has settled and is not measured yet: per camera (tracker ids, pixels)
    of its anchor frame or None, and the anchor images. The stage aligns the landmarks' reference patches with
    them ahead of the hold's measurement (:meth:`~nrmpc_ros.frontend.linking.HoldLinker.align_ahead`)."""

    anchors: list
    images: list


@dataclass(frozen=True)
class SequenceReset:
    """Start a new sequence here: the next measured hold is its origin."""


@dataclass(frozen=True)
class InputEnded:
    """The input ended (a bag's end, every camera silent): no later hold links the hold that started the current
    sequence, if it is still alone."""


IMU_ONLY_METHOD = "imu-only"
"""The method of an estimate whose gravity is the hold's averaged accelerometer alone: a hold no other hold shares
landmarks with (docs/PIPELINE.md, "A hold no other hold links")."""


@dataclass
class _PendingOrigin:
    """The hold that started the current sequence, waiting for its first estimate (it comes with the solve of
    the sequence's next hold): its measured hold, why it started a sequence, its noise scale, the sequence's
    number, whether its IMU gravity passed the agreement test (it may then stand alone) and whether its IMU-only
    estimate is out (the input ended; a hold after a restart of the input may still link it)."""

    item: MeasuredHold
    reason: StartReason
    noise_scale: float
    sequence: int
    imu_used: bool
    alone: bool = False


IMAGES_GRAVITIES_KEPT = 200
"""Holds whose images' gravity (beside their IMU's) the stage keeps: a recording's worth of holds."""

# verdicts of the pair test that leave a hold's IMU gravity out without a refutation, and the rule counted
_LEFT_OUT = {Agreement.UNUSABLE: ImuRefusal.UNUSABLE, Agreement.AXES_OFF: ImuRefusal.AXES_OFF,
             Agreement.DOUBTED: ImuRefusal.DOUBTED,
             Agreement.PENDING: ImuRefusal.PENDING}


class HoldEstimator:
    """Links and estimates the measured holds in order (see the module docstring).

    ``stats`` is the pipeline's :class:`~nrmpc_ros.frontend.pipeline.PipelineStats`: the stage counts its
    estimates, methods, sequences, merges, bridges and penalised holds there (the intake counts frames and
    holds). ``require_imu`` (the method 4pt-bending forced): a hold without IMU gravity is linked (its tracks
    stay landmarks for later holds) but not estimated, never silently by another method.
    ``on_gravity((sequence, gravity, cov_gravity, turns))`` receives each estimate's gravity with the rotation
    [(stamp, R)] of every hold of its sequence into its frame (the accelerometer bias's evidence,
    :meth:`~nrmpc_ros.frontend.extrinsics.FrameExtrinsics.observe_sequence`). ``on_turn((stamp before, stamp,
    R))`` receives the rotation the images turned the body by between a hold and the hold its gyro turn was
    measured from (p_before = R p_after): the gyro's unit (:func:`~nrmpc_ros.frontend.imu_units.
    gyro_units_from_turns`). The IMU's axes take the turns with their stds from :attr:`axes_turns`.
    """

    def __init__(self, rig: Rig, sequence: IncrementalSequence, linker: HoldLinker, stats,
                 require_imu: bool = False, on_gravity=None, on_turn=None):
        self.rig = rig
        self.sequence = sequence
        self.linker = linker
        self.stats = stats
        self.require_imu = require_imu
        self.on_gravity = on_gravity
        self.on_turn = on_turn
        self.imu_check = ImuGravityCheck(sequence)  # does each hold's IMU gravity agree with the images?
        # (IMU gravity, the images' gravity, its std rad) of the holds whose gravity the images measured without
        # the IMU's: whether the IMU's axes, measured from the turns, read the body's gravity (.imu_mount)
        self.images_gravities: dict = {}  # hold stamp -> ..., the latest estimate of each hold
        # (R_images, its std, the gyro's GyroRotation) of the turns measured without the IMU: the pair test's (between
        # a hold and its test's reference, the gyro's turns between composed) and sequences' without its gravity
        self.axes_turns: deque = deque(maxlen=TURNS_KEPT)
        self._gyro_turns: dict = {}  # hold stamp -> (the hold before's stamp, R, std rad): the gyro's turns
        self._turns_refuting: deque = deque(maxlen=TURNS_KEPT)  # of them, those that refute the gyro's turn as
        # the rig file reads it
        self.consumed = 0  # measured holds run so far (the intake counts those it made: the difference waits)
        self._hold_stamps: list = []  # stamp of every hold of the current sequence
        self._broken_stamps: dict = {}  # sequence number -> its holds' stamps, for the sequences a break ended
        # the hold that started the current sequence after a break, and why: a merge estimates it at last
        self._origin: _PendingOrigin | None = None

    def run(self, item) -> list:
        """Run one item of the intake (a :class:`MeasuredHold`, :class:`SettledAnchors`, :class:`SequenceReset` or
        :class:`InputEnded`); returns the hold estimates it gave (0 or more)."""
        if isinstance(item, InputEnded):
            return self._alone(keep=True)
        if isinstance(item, SequenceReset):
            alone = self._alone()
            self.reset()
            return alone
        if isinstance(item, SettledAnchors):  # work ahead, not a hold: the intake does not count it
            self.linker.align_ahead(item.anchors, item.images)
            return []
        try:
            return self._estimate(item)
        finally:
            self.consumed += 1

    def reset(self) -> None:
        self.sequence.reset()
        self.linker.reset()
        self.imu_check.reset()
        self.axes_turns.clear()
        self._gyro_turns.clear()
        self._turns_refuting.clear()
        self.images_gravities.clear()
        self._hold_stamps = []
        self._broken_stamps = {}
        self._origin = None

    def _estimate(self, item: MeasuredHold) -> list:
        st, hold, imu, attempt = self.stats, item.hold, item.imu, item.attempt
        t0 = time.perf_counter()
        obs = self.linker.link(hold)
        offset = ringing_offset_rad(self.rig, hold)
        g, verdict = (None, None) if imu is None else self._checked_gravity(obs, item, offset)
        if g is None and self.require_imu:  # forced: no silent fall back to 6pt-bending
            st.dropped[Drop.HOLD_FORCED_WITHOUT_IMU] += 1
            if attempt is not None:
                attempt.why = Drop.HOLD_FORCED_WITHOUT_IMU.message
            return []
        scale = self.sequence.noise_scale(ringing_noise_rad(self.rig, hold, obs.cam))
        st.penalized_holds += scale > 1.0
        number = self.sequence.number
        unknown = None if hold.unknown_ringing_px is None else \
            hold.unknown_ringing_px / np.array([c.focal_px for c in self.rig.cameras])
        out = self.sequence.add_view(obs.cam, obs.landmark, obs.f, g, item.imu_sigma_rad, noise_scale=scale,
                                     key=hold.stamp, turn=item.turn, offset_rad=offset, unknown_turn_rad=unknown,
                                     tilt_sigma_rad=item.tilt_sigma_rad, obs_scale=self._corner_scales(obs),
                                     scale_tilt_rad=item.scale_tilt_rad, scales_unknown=item.scales_unknown,
                                     calibration=item.calibration)
        if attempt is not None:
            attempt.sequence, attempt.index = self.sequence.number, self.sequence.num_views - 1
        if isinstance(out, NewSequence):
            alone = self._alone()  # the hold that started the sequence this one could not join: no other links it
            if out.reason is not StartReason.FIRST_VIEW:
                self._broke(number)
            if out.reason is not StartReason.FIRST_VIEW and item.turn is not None and \
                    self.sequence.bridge(*item.turn[1:]):
                st.bridges += 1
            self._hold_stamps = [hold.stamp]
            st.sequences = max(st.sequences, out.sequence + 1)
            # its estimate comes with the sequence's next hold
            self._origin = _PendingOrigin(item, out.reason, scale, out.sequence,
                                          g is not None and self.sequence.method == "4pt-bending")
            if out.reason is not StartReason.FIRST_VIEW:
                st.dropped[Drop.new_sequence(out.reason)] += 1
            return alone
        alone = []
        if out.continued:  # no sequence of its own: the one it broke is kept for a later merge, as a break keeps it
            self._broke(number)
            alone = self._alone()  # (the hold that started the sequence it broke had no other)
            self._hold_stamps, self._origin = [], None
        if out.merged is not None:  # this sequence's holds now follow those of the earlier one, in its origin
            st.merges += 1
            self._hold_stamps = self._broken_stamps.pop(out.merged, [math.nan] * out.merged_views) + \
                self._hold_stamps
        self._hold_stamps.append(hold.stamp)
        # the hold that started this sequence gets its first estimate from the solve of the sequence's next hold,
        # or of the merge that links it where that solve has no gravity for it (docs/PIPELINE.md, "The origin's
        # estimate"), late by the holds between them
        origin = None
        if out.origin is not None and self._origin is not None:
            origin, self._origin = (out.origin, self._origin), None
        elif out.merged is not None:
            self._origin = None
        if item.turn is not None and not self.sequence.has_measured_gravity:
            # (a sequence with the IMU's gravities also has the gyro's turns as priors: its poses follow them)
            turned = self.sequence.images_turn(item.turn[0], hold.stamp)
            if turned is not None and self.on_turn is not None:
                self.on_turn((item.turn[0], hold.stamp, turned))
            if turned is not None:  # its std: the hold's own rotation's (the origin's is fixed), both ways
                cov = out.cov_pose
                sigma = math.sqrt(2.0 * max(float(np.trace(cov[:3, :3])), 0.0) / 3.0) \
                    if cov is not None and np.all(np.isfinite(cov[:3, :3])) else math.inf
                gyro = self._gyro_between(item.turn[0], hold.stamp)
                if gyro is not None and math.isfinite(sigma):
                    self.axes_turns.append((turned, sigma, gyro))
        if g is None and out.gravity is not None:  # the images' gravity of the hold
            self.imu_check.remember(obs.cam, obs.landmark, obs.f, out.gravity, out.gravity_sigma_rad, offset,
                                    hold.stamp)
            if imu is not None:
                self.images_gravities[hold.stamp] = (imu.gravity, out.gravity, out.gravity_sigma_rad)
                while len(self.images_gravities) > IMAGES_GRAVITIES_KEPT:
                    self.images_gravities.pop(next(iter(self.images_gravities)))
        withheld = Drop.HOLD_IMU_REFUTED if verdict is Agreement.REFUTED else Drop.HOLD_IMU_DOUBTED if (
            verdict is Agreement.DOUBTED and self.sequence.has_measured_gravity) else None
        if withheld is not None:
            # the sequence still holds the earlier holds' IMU gravities, one of which may be the wrong one of the
            # refuted pair, and its window solve placed this hold with them: nothing to promise (the next test
            # decides). An IMU mounted otherwise than the rig file says put a hold 111 deg off at a std of 1 deg
            # so, a hold after a refutation that no test could reach.
            st.dropped[withheld] += 1
            if attempt is not None:
                attempt.why = withheld.message
            return alone  # (the origin's estimate from the same solve likewise)
        done = alone + ([] if origin is None else [self._origin_estimate(*origin)])
        est = self._hold_estimate(out, hold, imu, obs.links, time.perf_counter() - t0, scale)
        if attempt is not None:
            attempt.estimate = est
        return done + [est]

    def _origin_estimate(self, v: ViewEstimate, started: _PendingOrigin) -> HoldEstimate:
        """The first estimate of the hold that started the current sequence (``started``), from the solve that
        placed a later hold."""
        first = started.item
        if started.reason is not StartReason.FIRST_VIEW and not started.alone:
            self.stats.dropped[Drop.new_sequence(started.reason)] -= 1
        est = self._hold_estimate(v, first.hold, first.imu, Counter(), 0.0, started.noise_scale)
        if first.attempt is not None:
            first.attempt.estimate = est
        return est

    def _alone(self, keep: bool = False) -> list:
        """The hold that started the current sequence where no later hold will link it (the next hold starts or
        continues another sequence, a reset comes, or the input ends): its gravity from its averaged accelerometer
        alone, at the std of that average and of the accelerometer's tilt the sequence would have estimated (its
        prior), as :data:`IMU_ONLY_METHOD`; its pose the identity in its own origin (docs/PIPELINE.md, "A hold no
        other hold links"). Nothing where the hold's IMU gravity was not used (none, refused, or vision only) or
        this estimate is out already. ``keep``: the hold still waits for a later hold's solve (the input ended,
        and may start again)."""
        started = self._origin
        self._origin = started if keep else None
        if started is None or not started.imu_used or started.alone:
            return []
        started.alone = True
        first = started.item
        g = np.asarray(first.imu.gravity, dtype=float).reshape(3)
        tilt = first.tilt_sigma_rad if first.tilt_sigma_rad is not None else \
            (self.sequence.options.gravity_bias_sigma or 0.0)
        # calibrated or not, as the norms weigh them (docs/PIPELINE.md, "Calibrated or not")
        sigma = math.hypot(first.gravity_sigma_rad or 0.0, prior_sigma_rad(tilt, first.calibration))
        cov = gravity_covariance(g, sigma ** 2 * np.eye(2))
        if started.reason is not StartReason.FIRST_VIEW:
            self.stats.dropped[Drop.new_sequence(started.reason)] -= 1
        st = self.stats
        st.estimates += 1
        st.methods[IMU_ONLY_METHOD] += 1
        hold = first.hold
        est = HoldEstimate(
            stamp=hold.stamp, ref_stamp=hold.stamp, method=IMU_ONLY_METHOD, R=np.eye(3), t=np.zeros(3), gravity=g,
            gravity_sigma_deg=math.degrees(sigma), cov_gravity=cov, num_inliers=0, num_observations=0,
            time_ms=0.0, origin_stamp=hold.stamp, R_origin=np.eye(3), t_origin=np.zeros(3),
            cov_pose=np.zeros((6, 6)), sequence=started.sequence, hold_index=0, hold=hold, imu_gravity=g,
            noise_scale=started.noise_scale, ref_hold_index=0,
            imu_calibrated_weight=prior_weight(first.calibration))
        if first.attempt is not None:
            first.attempt.estimate = est
        return [est]

    def _corner_scales(self, obs) -> np.ndarray | None:
        """Each observation's noise over the nominal one (None: all nominal): a link at a corner found in this
        hold carries the corner's viewpoint bias (:data:`~.linking.CORNER_BIAS_PX`) on top."""
        if obs.corner is None:
            return None
        per_camera = np.array([self.sequence.noise_scale(CORNER_BIAS_PX / c.focal_px) for c in self.rig.cameras])
        return np.where(obs.corner, per_camera[obs.cam], 1.0)

    def _broke(self, number: int) -> None:
        """A break ended sequence ``number``: its holds' stamps are kept where a later hold may merge it back."""
        if len(self._hold_stamps) >= 2:
            self._broken_stamps[number] = self._hold_stamps
            keep = self.sequence.options.merge_sequences
            self._broken_stamps = dict(list(self._broken_stamps.items())[-keep:]) if keep else {}

    def _checked_gravity(self, obs, item: MeasuredHold, offset_rad: float) -> tuple:
        """(the hold's IMU gravity, or None where it is not to be used, and the verdict of
        :mod:`.imu_agreement`); refusals are counted. When the IMU's gravity turns unusable the sequence restarts
        without the earlier holds' gravities, which are the same IMU's. The pair test's images-only estimate, where
        it made one, measures the IMU's axes (:mod:`.imu_mount`): where they are off the rig file's, the IMU's
        gravity is not used again."""
        usable = self.imu_check.usable
        verdict = self.imu_check.check(obs.cam, obs.landmark, obs.f, item.imu.gravity, self.sequence.num_views > 0,
                                       offset_rad, item.hold.stamp)
        axes = self._axes_verdict(item, verdict is Agreement.AXES_OFF)
        if verdict is Agreement.REFUTED or axes is not None:
            rule = axes or ImuRefusal.REFUTED
            self.stats.dropped[Drop.no_imu_gravity(rule)] += 1
            if self.sequence.has_measured_gravity or (usable and not self.imu_check.usable and self.sequence.num_views):
                # the sequence's earlier gravities are the same IMU's: in doubt. A pair test is relative: an IMU
                # mounted otherwise than the rig file says passes some pairs (both gravities turned alike), and
                # a sequence kept on them published a hold 111 deg off at a std of 1 deg; it starts afresh here
                self.sequence.reset()
                self._hold_stamps, self._broken_stamps, self._origin = [], {}, None
            return None, Agreement.AXES_OFF if axes is ImuRefusal.AXES_OFF else \
                Agreement.REFUTED if axes is ImuRefusal.TURN_REFUTED else verdict
        if verdict in _LEFT_OUT:
            self.stats.dropped[Drop.no_imu_gravity(_LEFT_OUT[verdict])] += 1
            return None, verdict
        return item.imu.gravity, verdict

    def _axes_verdict(self, item: MeasuredHold, off: bool) -> ImuRefusal | None:
        """What the turn (and the gravity) the pair test's images-only estimate just measured says of the IMU's
        axes, with the earlier ones (:mod:`.imu_mount`): :attr:`ImuRefusal.AXES_OFF` where they put them off the
        rig file's, or where this turn and the earlier ones that each refute the axes (:func:`~.imu_mount.
        turn_refutes_axes`) fit one rotation (:func:`~.imu_mount.turns_share_axes`; the IMU's gravity is not used
        again: :meth:`~.imu_agreement.ImuGravityCheck.refuse_axes`); :attr:`ImuRefusal.TURN_REFUTED` where this
        turn refutes the gyro's (:func:`~.imu_mount.turn_refutes_gyro`: this hold's is not used); else None. The
        turn goes to ``on_turn`` too. A sequence resting on the IMU's gravity also takes the gyro's turns as
        priors: the first refuted turn is the first hold that would have been published off. ``off``: the axes
        are off already (the turn is only kept)."""
        check = self.imu_check
        if item.turn is not None:
            self._gyro_turns[item.hold.stamp] = item.turn
            while len(self._gyro_turns) > IMAGES_GRAVITIES_KEPT:
                self._gyro_turns.pop(next(iter(self._gyro_turns)))
        tested = check.images_turn
        gyro = None if tested is None else self._gyro_between(tested[0], tested[1])
        if gyro is None:
            return None
        if self.on_turn is not None and tested[0] == item.turn[0]:
            self.on_turn(tested[:3])
        turn = (tested[2], tested[3], gyro)
        self.axes_turns.append(turn)
        if off:
            return None
        refutes = turn_refutes_gyro(turn)
        if refutes and turn_refutes_axes(turn):
            self._turns_refuting.append(turn)
        sigma = math.hypot(item.gravity_sigma_rad, item.tilt_sigma_rad or 0.0)
        axes = imu_axes_from_turns(list(self.axes_turns), list(self.images_gravities.values()), sigma)
        if (axes is not None and axes.off) or (refutes and turns_share_axes(self._turns_refuting)):
            check.refuse_axes()
            return ImuRefusal.AXES_OFF
        return ImuRefusal.TURN_REFUTED if refutes else None

    def _gyro_between(self, key_before, key) -> GyroRotation | None:
        """The gyro's turn from hold ``key`` into hold ``key_before`` (p_before = R p), the turns between the holds
        in between composed (their variances added); None where one is missing."""
        R, var, k = np.eye(3), 0.0, key
        for _ in range(len(self._gyro_turns)):
            if k == key_before:
                return GyroRotation(R, math.sqrt(var), 0)
            if k not in self._gyro_turns:
                return None
            before, Rk, sigma = self._gyro_turns[k]
            R, var, k = Rk @ R, var + sigma ** 2, before
        return GyroRotation(R, math.sqrt(var), 0) if k == key_before else None

    def _hold_estimate(self, v: ViewEstimate, hold: Hold, imu, links, elapsed_s: float,
                       noise_scale: float = 1.0) -> HoldEstimate:
        st = self.stats
        st.estimates += 1
        st.methods[v.method] += 1
        if v.gravity_withheld is not None:
            st.gravity_withheld[v.gravity_withheld] += 1
        R, t = self.sequence.relative_pose(v.view, v.reference)
        if self.on_gravity is not None and imu is not None and v.gravity is not None:
            # the accelerometer's bias: the sequence's gravity with every hold's rotation into this one's frame
            turns = [(s, self.sequence.relative_pose(v.view, k)[0]) for k, s in enumerate(self._hold_stamps)]
            self.on_gravity((v.sequence, v.gravity, v.cov_gravity, turns))
        return HoldEstimate(
            stamp=hold.stamp, ref_stamp=self._hold_stamps[v.reference], method=v.method, R=R, t=t,
            gravity=v.gravity, gravity_sigma_deg=math.degrees(v.gravity_sigma_rad), cov_gravity=v.cov_gravity,
            num_inliers=v.num_inliers, num_observations=v.num_observations, time_ms=1000.0 * elapsed_s,
            origin_stamp=self._hold_stamps[0], R_origin=v.R, t_origin=v.t, cov_pose=v.cov_pose,
            sequence=v.sequence, hold_index=v.view, hold=hold, imu_gravity=None if imu is None else imu.gravity,
            links=links, window=v.window, noise_scale=noise_scale, ref_hold_index=v.reference,
            imu_calibrated_weight=v.imu_calibrated_weight)

    def batch(self) -> list:
        """Every hold of the current sequence estimated jointly at once: (stamp, R_origin, t_origin, gravity,
        gravity_sigma_deg) per hold, origin first; empty with fewer than two holds."""
        est = self.sequence.batch()
        if not est.success:
            return []
        out = []
        for k, stamp in enumerate(self._hold_stamps[: len(est.R)]):
            g = None if est.gravity is None else est.gravity[k]
            s = math.nan if est.gravity_sigma_rad is None else math.degrees(est.gravity_sigma_rad[k])
            out.append((stamp, est.R[k], est.t[k], g, s))
        return out


__all__ = ["IMU_ONLY_METHOD", "HoldEstimate", "HoldEstimator", "InputEnded", "MeasuredHold", "SequenceReset",
           "ringing_noise_rad"]
