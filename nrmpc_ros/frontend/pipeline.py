"""The front-end pipeline shared by ``nrmpc replay`` and the ROS 2 node (docs/PIPELINE.md).

    pipe = Pipeline(rig, PipelineConfig(), method="auto")
    pipe.add_imu(stamp, accel, gyro)                 # any time, optional
    out = pipe.add_frames(FrameSet(stamp, images))   # -> list[HoldEstimate]; None for a camera without a frame
    out += pipe.flush()                              # at the end: the hold still open

Per frame set: KLT tracking in every camera (from the hold's anchor frame
inside a hold), then the hold logic: two frames belong to one hold when the
image barely moved between them and, with an IMU, the zero-velocity detector
says the rig was still; a frame alone (no other frame nearby) is a hold of
its own unless the IMU says the rig moved. When a hold ends (or its settled
part is long enough) it is measured (:mod:`.holds`), its tracks get landmark
ids (:mod:`.linking`) and the joint estimate over the sequence of holds
(:class:`~nrmpc_ros.core.incremental.IncrementalSequence`) gives the hold's
pose and gravity.
"""

from __future__ import annotations

import enum
import math
from collections import Counter, deque
from dataclasses import dataclass, field, replace

import numpy as np

from ..cameras import check_image_size
from ..config import check, from_mapping, option
from ..core import METHODS
from ..core.bar_state import BarPropagator, tip_loads
from ..core.incremental import IncrementalSequence
from ..core.rig import Rig
from ..core.sequence_steps import CORRESPONDENCE_BIAS_FLOOR_PX, SequenceOptions
from ..errors import InputError
from .accel_tilt import UNCALIBRATED_TILT_DEG, AccelTiltEvidence
from .drops import Drop, sorted_counts
from .estimation import HoldEstimate, HoldEstimator, InputEnded, MeasuredHold, SequenceReset, SettledAnchors
from .extrinsics import CameraPoses, FrameExtrinsics
from .gyro import CameraTurns, rotation_between
from .holds import BarRinging, Hold, HoldConfig, HoldRecorder, HoldRefusal, Refusal, RingingSource, slowest_bar_period
from .imu import ImuBuffer, ImuConfig, ImuGravity, ImuRefusal, _vec3
from .imu_clock import ImuClockEstimator
from .imu_clock_check import MeasuredClockOffset, offset_from_moves
from .imu_units import reads_no_gravity
from .linking import HoldLinker
from .motion import Motion, MotionKind
from .noise_correlation import mean_variance_factor, periodic
from .patch_align import PatchAlignConfig
from .ringing_watch import RingingWatch
from .snapshot_ringing import correct_pixels, correction_rotations, predict, residual_px, uncertainty
from .steady_turn import creep_span, steady_turn
from .sync import MIN_FRAME_PERIOD_S
from .tracking import HoldThinning, KltTracker, TrackingConfig
from .zupt import (
    IMAGES_STILL_WINDOWS,
    ZuptConfig,
    ZuptDetector,
    claim_disputed,
    describe_noise,
    ringing_damping,
)
from .zupt import for_rig as zupt_for_rig

PIPELINE_METHODS = ("auto",) + METHODS
TURNS_KEPT = 200  # the gyro's and the images' turns between holds kept for the gyro's unit
# the IMU's samples either side of a hold a slow turn through it is looked for in (s): the longest hold the
# windowed stillness test may have cut into pieces
CREEP_LOOKAROUND_S = 10.0
RECENT_PERIODS = 20  # the frame period is the median of this many recent intervals (robust to drops and gaps)


@dataclass
class PipelineConfig:
    """All front-end settings; nested blocks have their own defaults."""

    tracking: TrackingConfig = option(TrackingConfig(), "feature tracking and matching")
    patch_align: PatchAlignConfig = option(PatchAlignConfig(), "landmarks' positions in later holds from their "
                                           "reference patch (docs/PIPELINE.md, Patch alignment)")
    holds: HoldConfig = option(HoldConfig(), "holds: when frames belong to one, which are settled")
    imu: ImuConfig = option(ImuConfig(), "IMU samples and a hold's averaged accelerometer")
    zupt: ZuptConfig = option(ZuptConfig(), "the IMU stillness test")
    sequence: SequenceOptions = option(SequenceOptions(), "the joint estimate over the sequence of holds")
    window: int = option(10, "holds adjusted jointly when a new hold arrives (older ones keep their poses)",
                         lo=2, hi=10000)
    imu_gravity_floor_deg: float = option(0.05, "least angular std of a hold's averaged IMU gravity (deg), "
                                          "besides its bias", lo=0.0, hi=90.0, lo_open=True)
    imu_bias_sigma_deg: float = option(0.3, "prior std of a calibrated accelerometer's constant tilt (bias) "
                                       "estimated jointly (deg), what its still norms cannot rule out; 0: no such "
                                       "tilt", lo=0.0, hi=90.0)
    imu_bias_max_deg: float = option(round(UNCALIBRATED_TILT_DEG, 2), "the tilt an uncalibrated accelerometer's bias "
                                     "may give its gravity (deg): the tilt's prior until the still holds' norms "
                                     "measure it (docs/PIPELINE.md, The accelerometer's tilt)", lo=0.0, hi=90.0)
    seed: int = option(0, "RANSAC seed", lo=0, hi=2**63 - 1)
    imu_time_offset_s: float = option(0.0, "added to every IMU stamp before the bars' state is propagated from "
                                      "it: the IMU's clock against the cameras' (s)", lo=-1.0, hi=1.0)

    def __post_init__(self):
        check(self, "pipeline config")

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "pipeline config") -> PipelineConfig:
        """Build from a nested mapping (e.g. YAML / ROS parameters); unknown keys are errors naming them."""
        return from_mapping(cls, d, source)

    def sequence_options(self) -> SequenceOptions:
        bias = math.radians(self.imu_bias_sigma_deg) if self.imu_bias_sigma_deg > 0 else None
        return replace(self.sequence, gravity_bias_sigma=bias)


@dataclass
class FrameSet:
    """Images (2-D uint8, rig camera order; None for a camera without a frame) with one stamp (seconds)."""

    stamp: float
    images: list
    stamps: list | None = None  # each camera's own stamp (None: the set's stamp)

    def camera_stamp(self, i: int) -> float:
        """Camera ``i``'s own stamp (s), the set's where none is given."""
        own = None if self.stamps is None else self.stamps[i]
        return float(self.stamp if own is None else own)


class RigState(enum.Enum):
    """What the rig is doing as the pipeline sees it after its latest frame set (docs/PIPELINE.md)."""

    WAITING = "waiting"  # no frame set yet
    MOVING = "moving"  # no hold open: the rig moves (or a hold just ended)
    SETTLING = "settling"  # a hold is open and no part of it has settled yet (its bars may still ring)
    MEASURING = "measuring"  # a hold is open past the settle time: its frames are being collected
    ESTIMATED = "estimated"  # the open hold has been estimated already (a long hold stays open until a move)


@dataclass(frozen=True)
class RigStatus:
    """The rig's state, the index its open hold gets in the current sequence (None: no hold open) and the stamp
    of the latest frame set (s)."""

    state: RigState
    hold: int | None
    stamp: float

    def describe(self) -> str:
        """One line for a person: "moving", "settling", "measuring hold 3", "hold 3 estimated"."""
        if self.state is RigState.MEASURING:
            return f"measuring hold {self.hold}"
        if self.state is RigState.ESTIMATED:
            return f"hold {self.hold} estimated"
        return self.state.value


@dataclass
class HoldAttempt:
    """One hold the pipeline closed, as ``Pipeline.hold_log`` keeps it: when it started (the stop) and ended, its
    measurement (None: refused, ``why`` says by which rule), its index in its sequence (None: not added) and its
    estimate (None for a sequence's first hold, the origin, and for holds that were not estimated)."""

    start: float
    end: float
    frames: int
    hold: Hold | None
    why: str = ""
    sequence: int | None = None
    index: int | None = None
    estimate: HoldEstimate | None = None


@dataclass
class PipelineStats:
    frames: int = 0
    holds: int = 0  # holds measured
    ringing_holds: int = 0  # of which the bars still rang in the frames used (measured at the fitted rest)
    penalized_holds: int = 0  # holds whose residual ringing raised their noise (noise_scale > 1)
    ringing_px: list = field(default_factory=list)  # per measured hold: its expected residual ringing
    ringing_sources: Counter = field(default_factory=Counter)  # where that expectation came from
    estimates: int = 0
    sequences: int = 0
    merges: int = 0  # sequences a later hold linked to an earlier one, merged into it
    bridges: int = 0  # breaks the gyro bridged (the new sequence's gravity carried over)
    methods: Counter = field(default_factory=Counter)
    gravity_withheld: Counter = field(default_factory=Counter)  # GravityWithheld -> estimates published without
    dropped: Counter = field(default_factory=Counter)  # Drop -> count (frames, holds, IMU samples)
    settle_s: list = field(default_factory=list)  # per measured hold
    residual_px: list = field(default_factory=list)
    noise_px: list = field(default_factory=list)  # one frame's track position noise
    averaged_noise_px: list = field(default_factory=list)
    settled_frames: list = field(default_factory=list)
    covariance_distrusted_at: float | None = None  # stamp (s) from which the IMU's noise is the samples' own

    def as_dict(self) -> dict:
        def med(v):
            v = [x for x in v if math.isfinite(x)]
            return float(np.median(v)) if v else math.nan

        return {"frames": self.frames, "holds": self.holds, "ringing_holds": self.ringing_holds,
                "penalized_holds": self.penalized_holds, "median_ringing_px": med(self.ringing_px),
                "ringing_sources": dict(self.ringing_sources),
                "estimates": self.estimates,
                "sequences": self.sequences, "merges": self.merges, "bridges": self.bridges,
                "methods": dict(self.methods), "dropped": {k.message: n for k, n in sorted_counts(self.dropped)},
                "gravity_withheld": {k.value: n for k, n in sorted_counts(self.gravity_withheld)},
                "median_settle_s": med(self.settle_s), "median_residual_px": med(self.residual_px),
                "median_noise_px": med(self.noise_px), "median_averaged_noise_px": med(self.averaged_noise_px),
                "covariance_distrusted_at": self.covariance_distrusted_at}


class Pipeline:
    """Frames and IMU samples in, hold estimates out (see the module docstring)."""

    def __init__(self, rig: Rig, config: PipelineConfig | None = None, method: str = "auto"):
        if method not in PIPELINE_METHODS:
            raise InputError("pipeline", f"unknown method {method!r} (choose one of {', '.join(PIPELINE_METHODS)})",
                             "method")
        self.rig = rig
        self.config = config or PipelineConfig()
        self.method = method
        # an IMU on a flexible bar rings with it after every stop: no motion of the rig, and no part of a hold's
        # accelerometer mean (docs/PIPELINE.md, Holds)
        zupt = zupt_for_rig(self.config.zupt, rig)
        self.imu = ImuBuffer(rig, self.config.imu, zupt.mount_ringing_hz or 0.0, ringing_damping(zupt))
        self.zupt = ZuptDetector(zupt, buffer=self.imu)
        self._images_still_s = 0.0  # how long the images have held still while the IMU read motion (s)
        self.bar_period_s = slowest_bar_period(rig)
        # the bars' state from the IMU: every camera's extrinsics at any frame set (docs/PIPELINE.md)
        # the accelerometer's bias: prior std and floor are the configured tilts at the rig's gravity
        def ms2(deg):
            return rig.gravity_magnitude * math.tan(math.radians(deg))

        self.extrinsics = FrameExtrinsics(rig, self.config.imu_time_offset_s,
                                          bias_prior_ms2=ms2(self.config.imu_bias_sigma_deg),
                                          floor_ms2=ms2(self.config.imu_gravity_floor_deg)) if rig.imu else None
        self.imu_clock = ImuClockEstimator(rig)  # the IMU's clock against the cameras', from the moves
        # how far the accelerometer's bias tilts its gravity, from the still holds' norms: the tilt's prior
        self.accel_tilt = AccelTiltEvidence(math.radians(self.config.imu_bias_sigma_deg),
                                            math.radians(self.config.imu_bias_max_deg),
                                            math.radians(self.config.imu_gravity_floor_deg))
        self.imu_clock_off: MeasuredClockOffset | None = None  # seconds off, measured once the images refute
        self._clock_measured_at = 0  # the refutations counted when it was last measured
        self.holds_ended = 0  # holds ended by a move, a jump or the input's end, estimated or not
        self.bars = BarRinging.of(rig, self.config.holds)  # frequency, damping, image offset per load
        self.measured_holds: list | None = None  # a list keeps every measured hold (the bars' ringing, offline)
        self.stats = PipelineStats()
        seq_method = "4pt-bending" if method == "auto" else method
        self.sequence = IncrementalSequence(rig, seq_method, self.config.sequence_options(), self.config.window,
                                            seed=self.config.seed)
        self.linker = HoldLinker(rig, self.config.tracking, self.config.patch_align)
        # the estimation stage (docs/PIPELINE.md, "Two stages"): it owns the sequence and the linker; a hold's
        # gravity reaches the accelerometer's bias through an inbox the intake empties before it next uses the
        # bars' state (the node runs the stage in another thread)
        self._gravity_inbox: deque = deque()
        # the gyro's turn between consecutive holds (stamp -> (earlier hold's stamp, GyroRotation)) and the
        # images' turn between them (the stage appends (earlier stamp, stamp, R)): the gyro's unit where the moves
        # are off camera
        self.gyro_turns: dict = {}
        self.images_turns: deque = deque(maxlen=TURNS_KEPT)
        self.estimator = HoldEstimator(rig, self.sequence, self.linker, self.stats, method == "4pt-bending",
                                       self._gravity_inbox.append if self.extrinsics is not None else None,
                                       self.images_turns.append if rig.imu is not None else None)
        self.handoff: list | None = None  # None: a measured hold is estimated at once; a list: it is appended
        self._handed = 0  # measured holds handed to the estimation stage
        self.trackers = [KltTracker(self.config.tracking, cam) for cam in rig.cameras]
        # each camera's turn between its images (gyro and bars): where KLT starts. The bars' state for it is
        # driven by the samples as they came: the intake's tracks do not wait for the estimated bias
        self._tracking_bars = BarPropagator(rig, imu_time_offset_s=self.config.imu_time_offset_s) \
            if self.extrinsics is not None and self.config.tracking.imu_prediction else None
        self.turns = CameraTurns(self.imu, rig.imu, self.extrinsics, rig.num_cameras, self.config.imu_time_offset_s,
                                 self._tracking_bars)
        self.thinning = HoldThinning(CORRESPONDENCE_BIAS_FLOOR_PX)  # frames of a settled hold left untracked
        # each camera's image path: without an IMU, ringing about a rest that stays put is no move
        self.watch = RingingWatch(self.bars.camera_freq_hz if self.bars.camera_freq_hz is not None else
                                  np.full(rig.num_cameras, self.bars.freq_hz), self.bars.zeta)
        self._hold: HoldRecorder | None = None
        self._hold_rest: list = []  # per camera: the open hold's rest in the camera's image path (None: unknown)
        self._last_hold: Hold | None = None  # the latest hold given to the sequence (a gyro bridge starts there)
        self._periods: list = []  # recent intervals between frame sets (s)
        self.last_stamp = -math.inf
        self._last_check = -math.inf  # when an open hold's settled part was last measured
        self._settled_s = 0.0  # how long the open hold's settled part lasted when last measured (s)
        self._last_motion: dict = {}  # Drop of a frame not at rest -> the latest such Motion, with its numbers
        self.hold_log: list | None = None  # a list: a HoldAttempt is appended for every hold closed (nrmpc report)

    # ------------------------------------------------------------------ input
    def add_imu(self, stamp: float, accel, gyro=None, covariance=None) -> None:
        """One IMU sample (specific force m/s^2, angular rate rad/s, IMU frame) and, optionally, its message's
        (linear_acceleration_covariance, angular_velocity_covariance); bad samples are counted."""
        if self.rig.imu is None:
            self.stats.dropped[Drop.IMU_IGNORED] += 1
            return
        reason = self.zupt.add(stamp, accel, gyro, covariance)
        if reason:
            self.stats.dropped[Drop.imu_sample(reason)] += 1
        else:  # accepted: three finite numbers each, in whatever container
            self._observe_gravity()
            a, w = _vec3(accel), None if gyro is None else _vec3(gyro)
            self.extrinsics.add_imu(stamp, a, (0.0, 0.0, 0.0) if w is None else w)
            if self._tracking_bars is not None:
                self._tracking_bars.add_imu(stamp, a, (0.0, 0.0, 0.0) if w is None else w)
            if w is not None:
                self.imu_clock.add_imu(stamp, w, a)
            h = self._hold
            if h is not None and h.prediction_at is not None and self.zupt.decided(h.prediction_at[0]):
                self._predict_ringing(h)

    def camera_poses(self, frames: FrameSet) -> CameraPoses | None:
        """Each camera's extrinsics (body frame) at its image stamp in ``frames``, from the bars' state; None
        without an IMU or before its first samples (then only the static extrinsics of holds are known)."""
        if self.extrinsics is None:
            return None
        self._observe_gravity()
        present = [img is not None for img in frames.images]
        return self.extrinsics.at(frames.stamp, frames.stamps, present)

    def _observe_gravity(self) -> None:
        """The holds estimated since the last call tell the bars' state the accelerometer's bias (and the cameras'
        rest turns, where the rig file lets the joint estimate find them)."""
        while self._gravity_inbox:
            self.extrinsics.observe_sequence(*self._gravity_inbox.popleft())
        self.extrinsics.rest_turns = self.sequence.rest_turns

    def _check(self, frames: FrameSet) -> list:
        src = f"frame set at {frames.stamp!r}"
        if isinstance(frames.stamp, bool) or not isinstance(frames.stamp, (int, float, np.floating)) or \
                not math.isfinite(float(frames.stamp)):
            raise InputError(src, "stamp must be a finite number of seconds", "stamp")
        imgs = list(frames.images)
        if len(imgs) != self.rig.num_cameras:
            raise InputError(src, f"got {len(imgs)} images but the rig {self.rig.source} has "
                             f"{self.rig.num_cameras} cameras", "images")
        out = []
        for cam, img in zip(self.rig.cameras, imgs):
            if img is None:
                out.append(None)
                continue
            where = cam.image_topic or cam.name
            a = np.asarray(img)
            if a.ndim != 2 or a.dtype != np.uint8:
                raise InputError(where, f"camera {cam.name!r}: expected a 2-D uint8 image, got shape {a.shape} "
                                 f"dtype {a.dtype}", "images")
            check_image_size(cam, a.shape[1], a.shape[0], where)
            out.append(np.ascontiguousarray(a))
        if all(x is None for x in out):
            raise InputError(src, "no camera has an image", "images")
        return out

    def _thin(self, stamp: float) -> bool:
        """Whether this frame set goes untracked (:class:`.tracking.HoldThinning`): a hold is open, its settled
        part (at the last check) has the frames its averaging needs at the per-frame noise of the latest
        measured holds, and the IMU says the rig stayed still since the last frame set."""
        h = self._hold
        if h is None or self._settled_s <= 0.0 or not self._periods or not self.stats.noise_px or \
                self.rig.imu is None or not len(self.imu):
            return False
        noise = max(self.stats.noise_px[-3:])
        frames = self._settled_s / float(np.median(self._periods)) + 1.0
        return self.thinning.skip(stamp, h.stamps[-1], frames, noise, self.bar_period_s, self.config.holds.measure_s,
                                  lambda: self.zupt.is_still(self.last_stamp, stamp) is True)

    def _note_period(self, gap: float) -> None:
        """One more interval between consecutive frame sets of a stream (s); one shorter than any camera's frame
        period (a burst of glitched stamps) is no period."""
        if gap < MIN_FRAME_PERIOD_S:
            return
        self._periods = (self._periods + [gap])[-RECENT_PERIODS:]

    def _lone_gap(self) -> float:
        """Frames further apart than this do not belong to one stream (s)."""
        p = float(np.median(self._periods)) if self._periods else 0.0
        return max(self.config.holds.lone_gap_s, self.config.holds.lone_periods * p)

    def add_frames(self, frames: FrameSet) -> list:
        """Process one frame set; returns the hold estimates it completed (0 or more).

        Raises InputError (naming the camera) for a wrong number, size or type of images; the pipeline's state
        is untouched then and later frames work.
        """
        images = self._check(frames)
        stamp = float(frames.stamp)
        taken = [None if img is None else frames.camera_stamp(i) for i, img in enumerate(images)]
        if stamp <= self.last_stamp:
            self.stats.dropped[Drop.FRAME_SET_OUT_OF_ORDER] += 1
            return []
        gap = stamp - self.last_stamp
        self.stats.frames += 1
        if self._thin(stamp):  # a settled, still hold with the frames its averaging needs
            self._note_period(gap)
            self.last_stamp = stamp
            return self._measure_early(stamp)
        turns = self.turns.advance(stamp, [img is not None for img in images], self._lone_gap(), taken) \
            if self.config.tracking.imu_prediction else [None] * len(images)
        steps = [None if img is None else trk.track(img, turn)
                 for trk, img, turn in zip(self.trackers, images, turns)]
        lone_gap = self._lone_gap()
        if gap > lone_gap:
            self.watch.reset()
        for i, s in enumerate(steps):
            if s is not None:
                self.watch.add(i, stamp if taken[i] is None else taken[i], s.shift_px, s.lost)
                if s.lost and i < len(self._hold_rest):
                    self._hold_rest[i] = None  # its path starts again: the hold's rest in it is not known
        if gap <= lone_gap:  # the images' rotation rate over this frame interval, for the IMU clock
            rates = [math.nan if s is None else s.motion_px / cam.focal_px / gap
                     for s, cam in zip(steps, self.rig.cameras)]
            shifts = [(math.nan, math.nan) if s is None else (s.shift_px[0] / cam.focal_px / gap,
                                                                s.shift_px[1] / cam.focal_px / gap)
                      for s, cam in zip(steps, self.rig.cameras)]
            self.imu_clock.add_frame(self.last_stamp, stamp, rates, shifts)
        out = []
        lost = any(s is not None and s.lost for s in steps)
        settling = self._settling(stamp)
        imu_moved = settling and lost and self.rig.imu is not None and len(self.imu) and \
            self.zupt.is_still(self.last_stamp, stamp) is False
        if lost and settling and gap <= lone_gap and not imu_moved and self._settled_s <= 0.0:
            self._reanchor(stamp, images, taken)  # the bars ring too far for the tracks: anchor again, keep the stop
            self._note_period(gap)  # (once the hold has settled, the tracks lost end it: a move or a knock begins
            # that the IMU's window has not shown yet, and anchoring again would throw its settled frames away)
        elif gap > lone_gap or lost:
            # a new stream, a snapshot, or a jump the tracks could not follow: what was open ends with the
            # previous frame, and this one may start a hold (the rig may be at rest here, its bars ringing)
            out += self._close()
            self._open(stamp, images, taken, snapshot=True, top_up=gap > lone_gap)
            cams = [i for i, img in enumerate(images) if img is not None]
            self._hold.prediction_at = (stamp, cams, [frames.camera_stamp(i) for i in cams])
            if gap <= lone_gap:  # a jump inside a stream (tracks lost), not a lone frame
                self._hold.jumped = next(c.name for c, s in zip(self.rig.cameras, steps) if s is not None and s.lost)
                self._note_period(gap)
        else:
            self._note_period(gap)
            still, why = self._still(self.last_stamp, stamp, steps)
            if self._hold is not None and still:
                self._record(stamp, images, taken)
            elif self._hold is not None and why.kind is MotionKind.LEFT_HOLD and settling:
                # the image left the hold before the bars could have settled: ringing, not a move (a move this
                # soon after a stop could not give a settled hold anyway). Anchor again, keep the stop time.
                self._reanchor(stamp, images, taken)
            elif self._hold is not None:
                if len(self._hold) == 1 and self._hold.snapshot:
                    self._moving(why)  # the first frame of a moving stream
                    self._discard()
                else:
                    out += self._close()
            elif still:
                self._open(stamp, images, taken, snapshot=False)
            else:
                self._moving(why)
        self.last_stamp = stamp
        out += self._measure_early(stamp)
        return out

    @property
    def open_hold(self) -> HoldRecorder | None:
        """The hold being recorded (None between holds)."""
        return self._hold

    def flush(self) -> list:
        """Close the open hold (end of a bag, or the cameras stopped); a hold no other links so far gets its
        estimate from the IMU alone (:class:`~.estimation.InputEnded`)."""
        return self._close() + self._hand_over(InputEnded())

    def reset(self) -> None:
        """Start a new sequence (the next hold is its origin)."""
        self._discard()
        self._last_hold = None
        self._hand_over(SequenceReset())

    def _hand_over(self, item) -> list:
        """An item for the estimation stage: run at once (returns its estimates) or appended to ``handoff``."""
        if self.handoff is None:
            return self.estimator.run(item)
        self.handoff.append(item)
        return []

    def take_handoff(self) -> list:
        """The items handed to the estimation stage since the last call (``handoff`` a list), in order."""
        items, self.handoff[:] = list(self.handoff), []
        return items

    def status(self) -> RigStatus:
        """The rig's state after the latest frame set (changes only with frame sets, flushes and resets)."""
        h = self._hold
        if h is None:
            state = RigState.WAITING if not self.stats.frames else RigState.MOVING
        elif h.measured:
            state = RigState.ESTIMATED
        elif self._settled_s <= 0.0:  # no settled part yet when the hold was last measured
            state = RigState.SETTLING
        else:
            state = RigState.MEASURING
        waiting = self._handed - self.estimator.consumed  # holds handed over and not estimated yet count as added
        hold = None if h is None else self.sequence.num_views + waiting - int(h.measured)
        return RigStatus(state, hold, float(self.last_stamp))

    # ------------------------------------------------------------------ holds
    def _still(self, t0: float, t1: float, steps: list) -> tuple:
        """Whether the rig was at rest between two frames, and why not (a :class:`.motion.Motion`, else None).

        With an IMU sample in between, the IMU decides (the bars may ring while the body is still); the images
        only say that the tracks were lost. Without one, a hold starts when the image barely moved between
        two frames and lasts while it stays near the hold's first frame (ringing stays near, a move leaves); or,
        on bars that ring far and long, where each camera's image rings about a rest that stays within the hold's
        radius of the one it had when the hold began (:mod:`.ringing_watch`).
        """
        imu = self.zupt.is_still(t0, t1) if self.rig.imu is not None and len(self.imu) else None
        cfg = self.config.holds
        if imu is False:
            self._dispute_imu(t0, t1, steps)
            return False, Motion(MotionKind.IMU_MOVED)
        if imu is True:
            self._images_still_s = 0.0
        for i, s in enumerate(steps):
            if s is None:
                continue
            name = self.rig.cameras[i].name
            if s.lost:
                return False, Motion(MotionKind.TRACKS_LOST, name)
            if imu is True:
                continue
            radius = math.radians(cfg.hold_radius_deg) * self.rig.cameras[i].focal_px
            stepped = math.isfinite(s.motion_px) and s.motion_px > cfg.still_step_px
            path = self.watch.judge(i) if stepped or (math.isfinite(s.offset_px) and s.offset_px > radius) else None
            if self._hold is None and stepped and not self._rings_about(path, i, radius):
                return False, Motion(MotionKind.IMAGE_MOVED, name, s.motion_px)
            if self._hold is None:
                continue
            if path is not None and path.rings and self._hold_rest[i] is None and path.since >= self._hold.start:
                self._hold_rest[i] = path.rest  # the hold's rest: the first fitted over a window after the stop
            if math.isfinite(s.offset_px) and s.offset_px > radius and not self._rings_about(path, i, radius):
                return False, Motion(MotionKind.LEFT_HOLD, name, s.offset_px)
            if stepped and path.kept() is False:  # near the hold, but no longer ringing about its rest: moving
                return False, Motion(MotionKind.LEFT_HOLD, name, s.offset_px)
        return True, None

    def _dispute_imu(self, t0: float, t1: float, steps: list) -> None:
        """The IMU read motion between two frames: where every camera's image held still (no track lost, a step
        of at most ``still_step_px``) for :data:`~.zupt.IMAGES_STILL_WINDOWS` stillness-test windows in a row
        while the noise in use is a claim the quietest windows dispute, the claim is dropped for the samples' own
        noise and a new sequence starts (docs/PIPELINE.md, Holds)."""
        limit = self.config.holds.still_step_px
        quiet = [s for s in steps if s is not None]
        if not quiet or any(s.lost or not (math.isfinite(s.motion_px) and s.motion_px <= limit) for s in quiet):
            self._images_still_s = 0.0
            return
        self._images_still_s += t1 - t0
        if self._images_still_s >= IMAGES_STILL_WINDOWS * self.zupt.window_s and \
                claim_disputed(self.zupt.noise_in_use) and self.zupt.distrust_covariance():
            self.stats.covariance_distrusted_at = t1
            self._images_still_s = 0.0
            # no hold is open (the claim read the last second as motion), but the last one may have been cut
            # by it from the hold about to open at the same pose: a pair without motion. A new sequence starts.
            self.reset()

    def _rings_about(self, path, i: int, radius_px: float) -> bool:
        """Whether camera i's image rings about a rest (``path``, :meth:`.ringing_watch.RingingWatch.judge`): no
        hold open, any rest; inside one, ringing on (the looser bound) about a rest within ``radius_px`` of the
        hold's (``_hold_rest``: the first rest fitted over a window that lies wholly after the stop, an earlier
        window holding the end of the move; any rest while none is known)."""
        if self._hold is None:
            return bool(path.rings)
        if not path.kept():
            return False
        ref = self._hold_rest[i]
        return ref is None or float(np.linalg.norm(path.rest - ref)) <= radius_px

    def _open(self, stamp: float, images: list, taken: list, snapshot: bool, top_up: bool = False) -> None:
        """A hold starts at this frame set (``top_up``: a frame after a gap, whose tracks may be few)."""
        anchors, anchor_images = [], []
        for trk, img in zip(self.trackers, images):
            if img is None:
                anchors.append(None)
                anchor_images.append(None)
                trk.end_hold()
                continue
            trk.start_hold(top_up)
            anchors.append(trk.positions())
            anchor_images.append(img)
        self._hold = HoldRecorder(stamp, anchors, anchor_images, snapshot, stamp - self.last_stamp)
        self._hold_rest = [None] * len(anchors)
        self._record(stamp, images, taken)
        self._last_check = stamp
        self._settled_s = 0.0

    def _moving(self, why: Motion) -> None:
        """Count a frame that is not at rest by kind of motion (the latest one of each kind is kept)."""
        drop = Drop.not_at_rest(why.kind)
        self.stats.dropped[drop] += 1
        self._last_motion[drop] = why

    def turns_between_holds(self) -> list:
        """[(R_images, GyroRotation)]: the body's turn between a hold and the hold before it as the images measured
        it without the IMU (a sequence without the IMU's gravity, or the IMU gravity test's images-only estimate of
        the pair; the latest per hold) and as the gyro did, for each hold both measured from the same hold: the
        gyro's unit."""
        images = {stamp: (before, R) for before, stamp, R in list(self.images_turns)}
        out = []
        for stamp, (before, R) in images.items():
            gyro = self.gyro_turns.get(stamp)
            if gyro is not None and gyro[0] == before:
                out.append((R, gyro[1]))
        return out

    def no_hold_report(self) -> str:
        """Why no hold was found (empty once one was): what judged the frames moving, with the numbers."""
        st = self.stats
        if st.holds or not st.frames:
            return ""
        lines = [f"no hold found in {st.frames} frame sets"]
        moving = {k: v for k, v in st.dropped.items() if k in self._last_motion}
        for k, n in sorted(moving.items(), key=lambda kv: -kv[1]):
            lines.append(f"  {n} frame sets not at rest: {self._last_motion[k]} (the latest)")
        noise = self.zupt.noise if self.rig.imu is not None and len(self.imu) else None
        if noise is not None:
            z = self.zupt.config
            ringing = f", the IMU's mount ringing at {z.mount_ringing_hz:.3g} Hz taken out" if z.mount_ringing_hz \
                else ""
            lines.append(f"  IMU stillness test: {describe_noise(noise, z)}, false-alarm probability "
                         f"{z.significance:g} per {self.zupt.window_s:.3g} s window{ringing}")
        elif self.rig.imu is not None:
            lines.append("  no IMU samples were given: the images alone decided")
        if self.rig.imu is None or not len(self.imu):
            lines.append(f"  without an IMU a hold starts where the image moves at most "
                         f"{self.config.holds.still_step_px:g} px between two frames")
        for rule in sorted(Refusal, key=lambda r: r.value):
            n = st.dropped[Drop.hold_refused(rule)]
            if n:
                lines.append(f"  {n} holds too short or unsettled: {rule.value}")
        if st.frames < 2:
            lines.append("  a single frame set: a hold of one frame needs the IMU still before it, or no IMU")
        return "\n".join(lines)

    def _settle_window(self) -> float:
        """How long after a stop the bars may ring beyond the hold's radius (s): until the ringing a stop of
        ``holds.stop_load_m_s2`` sets off decays below ``holds.hold_radius_deg`` at the bars' damping (at least
        one period: the first swing)."""
        b, cfg = self.bars, self.config.holds
        if not b.period_s:
            return 0.0
        a0 = cfg.stop_load_m_s2 * float(np.max(b.px_per_load, initial=0.0))
        radius = math.radians(cfg.hold_radius_deg) * min(c.focal_px for c in self.rig.cameras)
        decay = math.log(a0 / radius) / (b.zeta * 2.0 * math.pi * b.freq_hz) if a0 > radius else 0.0
        return max(decay, b.period_s)

    def _settling(self, stamp: float) -> bool:
        """Whether the open hold's bars may still ring beyond its radius at ``stamp`` (then lost tracks or an
        image leaving the hold re-anchor it instead of ending it): within ``_settle_window`` of the stop and, judged
        by the images alone, while its frames since the anchor span less than a bar period. Frames kept inside
        the radius over a period saw the ringing through its swing, and its envelope only decays: the image
        leaving the radius later is a move (the light default damping may stretch the window past a hold)."""
        h = self._hold
        if h is None or stamp - h.start >= self._settle_window():
            return False
        if self.rig.imu is not None and len(self.imu):
            return True  # the IMU tells a move from ringing
        return len(h) < 2 or h.stamps[-1] - h.stamps[0] < self.bar_period_s

    def _reanchor(self, stamp: float, images: list, taken: list) -> None:
        """The open hold starts again from this frame (new anchor) but keeps the time the rig stopped. Its tracks
        are topped up with new corners, as between holds: the ringing that made the hold anchor again lost part of
        them (a camera kept 9 of 150 after a 1.5 Hz bar's first swings), and the hold's landmarks are what links it
        to the holds before it."""
        start, snapshot, rests, jumped = self._hold.start, self._hold.snapshot, self._hold_rest, self._hold.jumped
        self._open(stamp, images, taken, snapshot=snapshot, top_up=True)
        self._hold.start, self._hold.jumped = start, jumped
        self._hold_rest = rests  # the rests the camera's paths ring about stay (a lost path's is None already)

    def _record(self, stamp: float, images: list, taken: list) -> None:
        """One frame set of the open hold: the track positions of each camera that has an image in it, taken at
        that image's own stamp (``taken``). A camera without one adds nothing: its tracker still holds its
        previous image's positions, which at its own slower rate would be counted again, at the wrong time."""
        h = self._hold
        for i, (trk, img) in enumerate(zip(self.trackers, images)):
            if img is not None and h.anchors[i] is None:  # the camera's frame was missing when the hold began
                trk.start_hold()
                h.anchors[i], h.anchor_images[i] = trk.positions(), img
        h.add(stamp, [trk.positions() if trk.in_hold and img is not None else None
                      for trk, img in zip(self.trackers, images)], taken)

    def _discard(self) -> None:
        self._hold = None
        for trk in self.trackers:
            trk.end_hold()

    def _imu_still_since(self, hold: HoldRecorder):
        if self.rig.imu is None or not len(self.imu):
            return None
        if hold.snapshot and len(hold) == 1:  # a snapshot moments after the stop: the stop found sample by sample
            run = self.zupt.leading_run(hold.stamps[0])
            return None if run is None else run[0]
        return self.zupt.still_since(hold.stamps[0])

    def _measure_early(self, stamp: float) -> list:
        """Estimate a long hold once its settled part lasts ``measure_s`` (it stays open until the rig moves)."""
        h = self._hold
        cfg = self.config.holds
        if h is None or h.measured or len(h) < 2 or stamp - self._last_check < 0.25 * cfg.measure_s:
            return []
        self._last_check = stamp
        self._settled_s = h.settled_duration(cfg, self.bar_period_s, self._imu_still_since(h), self.bars)
        if self._settled_s > 0.0 and not h.aligned_ahead:  # its anchors are final: their patches can be aligned
            h.aligned_ahead = True  # (docs/PIPELINE.md, "Aligning ahead")
            self._hand_over(SettledAnchors(list(h.anchors), list(h.anchor_images)))
        if self._settled_s < cfg.measure_s:
            return []
        out = self._estimate_hold(h)
        h.measured = True
        return out

    def _close(self) -> list:
        refuted = self.estimator.imu_check.refuted
        if refuted != self._clock_measured_at:  # the images refuted the IMU's gravity since: is its clock off?
            self._clock_measured_at = refuted  # (here, with the samples and frames this stage collects)
            self.imu_clock_off = offset_from_moves(self.imu_clock)
        h = self._hold
        self.holds_ended += h is not None
        self._discard()
        if h is None or h.measured:
            return []
        if h.snapshot and len(h) == 1 and self.rig.imu is not None and len(self.imu):
            # the rig must be still when the image was taken: its instant in a still run of the IMU, or, for a lone
            # frame, before one (which starts half a stillness window after the stop) with every sample since
            # reading still. A stream's frame the tracks jumped to is the end of a move the images could not
            # follow: a stop moments before it, its ringing at its largest and its stop's load unseen (a 4 Hz
            # stream's such frame, taken so, moved its sequence's gravity from 0.012 to 0.14 deg)
            t = h.stamps[0]
            if self.zupt.is_still(t, t) is False and (h.jumped or self.zupt.leading_run(t) is None):
                self.stats.dropped[Drop.SNAPSHOT_MOVED] += 1
                return []
        elif h.snapshot and len(h) == 1 and h.jumped:
            # without an IMU, a stream's frame whose tracks were lost and that no still frame followed is a jump
            # the images could not follow (a fast move, far ringing), not a snapshot taken at rest
            self._moving(Motion(MotionKind.TRACKS_LOST, h.jumped))
            return []
        return self._estimate_hold(h)

    def _stop_amplitude_px(self, rec: HoldRecorder, since: float | None) -> float | None:
        """The image ringing a hold's stop set off (px, largest camera): the largest change of each bar's tip
        load over the two bar periods before the still onset, times its camera's offset per load. The tip load
        is the specific force and the turn's (docs/CONVENTIONS.md, "The rig in motion"): an abrupt stop of a turn
        loads a tip at a lever v by alpha x v (60 deg/s stopped within 0.1 s: 4 m/s^2 at 0.4 m, more than the
        linear deceleration). alpha is the gyro's difference over an eighth of a bar period (the band the bar
        answers; one sample's difference is its noise over one period)."""
        if since is None or not len(rec) or not self.bars.period_s:
            return None
        t, a, w = self.imu.window(since - 2.0 * self.bars.period_s, rec.stamps[0])
        if len(t) < 2:
            return None
        k = int(np.clip(round(0.125 * self.bars.period_s / max(float(np.median(np.diff(t))), 1e-9)), 1, len(t) - 1))
        mount = self.rig.imu
        M = mount.rotation  # IMU -> its mount (the body, or a camera: then on to the body, unbent)
        if mount.mount != "body":
            M = self.rig.rotations[self.rig.camera_index(mount.mount)] @ M
        f, w = a @ M.T, w @ M.T
        mid = np.arange(len(t) - k) + k // 2  # the samples at the middle of each difference
        alpha = (w[k:] - w[:-k]) / (t[k:] - t[:-k])[:, None]
        load = tip_loads(f[mid], w[mid], alpha, self.rig.positions)  # (n, cams, 3), the tips from the body origin
        still = t[mid] >= since
        if still.sum() < 1 or (~still).sum() < 1:
            return None
        change = np.max(np.linalg.norm(load[~still] - load[still].mean(axis=0), axis=2), axis=0)  # (cams,)
        return float(np.max(change * self.bars.px_per_load, initial=0.0))

    def _predict_ringing(self, rec: HoldRecorder) -> None:
        """The ringing of a hold that may be a snapshot (``rec.prediction_at``), predicted by the bars' state at
        its cameras' stamps (:func:`.snapshot_ringing.predict`) into ``rec.prediction``: once the IMU's stillness
        test has decided its instant (half a stillness window of samples after it, while the propagator still
        holds it), or when the hold is measured before that. None without an IMU, rigid bars, an IMU not
        still at the frames (a snapshot taken moments after the stop sits in a still run shorter than a window:
        its onset is taken as it stands; whether the rig was still is decided when the hold closes), or once the
        images refuted the IMU's gravity (its rotation or clock is wrong, and so are the loads it drives)."""
        t, cams, stamps = rec.prediction_at
        rec.prediction_at = None
        cfg = self.config.holds
        if self.extrinsics is None or not cfg.predict_ringing or not self.bars.period_s or not len(self.imu) \
                or self.estimator.imu_check.refuted:
            return
        since = self.zupt.still_since(t, any_length=True)
        if since is None:  # a snapshot moments after the stop, before a run of the windowed test
            run = self.zupt.leading_run(t)
            since = None if run is None else run[0]
        if since is None:
            return
        # the accelerometer's bias cancels in the ringing (docs/PIPELINE.md, "Settling"): the estimation stage's
        # newest bias is not taken here, so this intake decision does not depend on when that stage ran
        off = self.config.imu_time_offset_s  # the still onset in the cameras' clock, as the propagator's stamps
        rec.prediction = predict(self.extrinsics.bars, stamps, cams, max(since, t - cfg.measure_s) + off, t,
                                 since + off)

    def _remove_predicted_ringing(self, rec: HoldRecorder, hold: Hold) -> None:
        """A snapshot whose ringing was predicted: each camera's pixels turned to where the static model sees
        them, and the prediction's error as its residual ringing (docs/PIPELINE.md, "Settling")."""
        p = rec.prediction
        if p is None or not hold.snapshot or hold.ringing_source not in (RingingSource.IMU, RingingSource.DEFAULT):
            return
        R = correction_rotations(self.rig, p)
        noise = self.zupt.noise
        cfg = self.config.holds
        u = uncertainty(self.rig, cfg.damping_rel_std, cfg.unknown_damping_std, cfg.frequency_rel_std,
                        math.nan if noise is None else noise.accel_sigma, self.imu.period_s,
                        math.nan if noise is None else noise.gyro_sigma)
        res = residual_px(self.rig, self.extrinsics.bars.zeta, p, u,
                          math.inf if cfg.ringing_depth_m is None else cfg.ringing_depth_m)
        used = []
        for k, i in enumerate(p.cams):
            ch = hold.cameras[i]
            if ch is None:
                continue
            ch.uv = correct_pixels(self.rig.cameras[i], ch.uv, R[k])
            used.append(float(res[k]))
        if used:
            hold.ringing_px, hold.ringing_source = max(used), RingingSource.PREDICTED

    def _estimate_hold(self, rec: HoldRecorder) -> list:
        """Measure a closed (or long enough) hold and hand it to the estimation stage with what it needs of
        the IMU; returns the estimates when the stage runs at once."""
        if rec.prediction_at is not None:
            self._predict_ringing(rec)
        since = self._imu_still_since(rec)
        hold, why = rec.measure(self.config.holds, self.bar_period_s, since, self.bars,
                                self._stop_amplitude_px(rec, since))
        if hold is not None:
            turned = self._steady_turn(hold)
            if turned is not None:
                hold, why = None, turned
        if hold is not None:
            self._remove_predicted_ringing(rec, hold)
        attempt = HoldAttempt(rec.start, rec.stamps[-1] if len(rec) else rec.start, len(rec), hold,
                              str(why) if why is not None else "")
        if self.hold_log is not None:
            self.hold_log.append(attempt)
        if hold is None:
            self.stats.dropped[Drop.hold_refused(why.rule)] += 1
            return []
        if self.measured_holds is not None:
            self.measured_holds.append(hold)
        st = self.stats
        st.holds += 1
        st.ringing_holds += hold.ringing
        st.ringing_px.append(hold.ringing_px)
        st.ringing_sources[hold.ringing_source.value] += 1
        st.settle_s.append(hold.settle_s)
        st.residual_px.append(hold.residual_px)
        st.noise_px.append(hold.noise_px)
        st.averaged_noise_px.append(hold.averaged_noise_px)
        st.settled_frames.append(hold.settled_frames)
        imu = self._imu_gravity(hold)
        sigma = tilt = odds = None
        scale_tilt = 0.0
        if imu is not None:
            white = imu.accel_mean_std / self.rig.gravity_magnitude
            tilt = self.accel_tilt.observe_still(imu.accel_mean, imu.accel_mean_std ** 2).prior_sigma_rad
            # the averaged noise and the floor; on a chip nobody calibrated, the tilt its axes' scales may give
            # this attitude, which the joint estimate's constant tilt cannot take, goes with it (:mod:`.accel_tilt`;
            # the sequence adds it to every hold once the norms show such a chip)
            sigma = math.hypot(white, math.radians(self.config.imu_gravity_floor_deg))
            scale_tilt = self.accel_tilt.axes_scale_tilt_rad(imu.accel_mean)
            odds = self.accel_tilt.calibration_odds()  # calibrated or not: the tilt's two priors (.accel_tilt)
            if self.extrinsics is not None:  # every still hold tells the accelerometer's bias, under that prior
                self.extrinsics.set_bias_prior(self.rig.gravity_magnitude * math.tan(tilt))
                self.extrinsics.observe_still(hold.stamp, imu.accel_mean, imu.accel_mean_std, 1)
        refused = imu is None and self.method == "4pt-bending"  # the stage links it, then refuses it
        turn = None if refused or self._last_hold is None else self._gyro_rotation(self._last_hold, hold)
        if not refused:
            self._last_hold = hold
        self._handed += 1
        return self._hand_over(MeasuredHold(hold, imu, sigma, turn, attempt if self.hold_log is not None else None,
                                            tilt, scale_tilt, self.accel_tilt.shows_bias if imu is not None else None,
                                            odds))

    def _gyro_rotation(self, before: Hold, after: Hold):
        """(``before``'s stamp, R, std rad): the body's rotation from hold ``after`` into hold ``before`` from the
        gyro (:func:`.gyro.rotation_between`); None without an IMU or its samples over the move."""
        if self.rig.imu is None or not len(self.imu):
            return None
        t0 = before.settled_end
        still = (t0 - self.config.imu.pad_s if before.snapshot else before.settled_start, t0)
        move = (t0, after.settled_end if after.snapshot else after.settled_start)
        # where the IMU shows both holds' still runs: the gyro's bias from the whole earlier run, its rate
        # integrated over the move between the runs only (at rest the body does not turn)
        run_a, run_b = self.zupt.still_run(t0), self.zupt.still_run(move[1])
        if run_a is not None and run_b is not None and run_a[1] < run_b[0]:
            still, move = run_a, (run_a[1], run_b[0])
        turn = rotation_between(self.imu, self.rig.imu, still, move, self.config.imu.max_age_s,
                                self.config.imu.gyro_scale_error)
        if turn is None:
            return None
        self.gyro_turns[after.stamp] = (before.stamp, turn)
        while len(self.gyro_turns) > TURNS_KEPT:
            self.gyro_turns.pop(next(iter(self.gyro_turns)))
        return before.stamp, turn.R, turn.sigma_rad

    def _steady_turn(self, hold: Hold) -> HoldRefusal | None:
        """The refusal of a hold the body turned through (:mod:`.steady_turn`: the gyro's mean rate over the span
        its IMU gravity averages), else None; None too without an IMU or its noise."""
        # the noise the stillness test used last (asking for a new estimate here would move when it is made)
        noise = self.zupt.noise_in_use if self.rig.imu is not None and len(self.imu) else None
        if noise is None:
            return None
        t0, t1 = self._imu_span(hold)
        t, _, w = self.imu.window(t0 - CREEP_LOOKAROUND_S, t1 + CREEP_LOOKAROUND_S)
        t0, t1 = creep_span(t, w, noise, self.zupt.config, t0, t1)
        inside = (t >= t0) & (t <= t1)
        turn = steady_turn(t[inside], w[inside], noise, self.zupt.config, self.imu.ringing_hz)
        return HoldRefusal(Refusal.TURNING, turn.describe()) if turn is not None and turn.turning else None

    def _imu_span(self, hold: Hold) -> tuple:
        """(t0, t1): the IMU's samples a hold's gravity averages."""
        t0, t1 = hold.settled_start, hold.settled_end
        ringing = self.imu.ringing_hz > 0
        if hold.snapshot or (ringing and t1 - t0 < 1.0 / self.imu.ringing_hz):
            # the still run's samples before the image, at most measure_s; a snapshot taken less than pad_s into
            # its run takes that run's samples after it too (the rig stood there until it moved again). An IMU
            # on a ringing bar takes the run after it up to measure_s: the longer the span, the better its mean
            # tells the decaying ringing from the constant (docs/PIPELINE.md, "IMU gravity"); so does an IMU that
            # vibrates, whose sine averages out only over many of its periods (a snapshot 0.05 s after the stop
            # averaged 4 periods of a motor's 80 Hz where its run held 160: its mean was 1 deg off). So does a stream
            # hold whose frames span less than a period of that ringing (images ringing by tens of pixels split a
            # hold the IMU holds still; over 0.33 s of a 1.5 Hz bar the mean was 5.7 deg off); its run is found
            # from either end of its frames (the test's window ends a run up to half a window before the move)
            run = self.zupt.leading_run(t1) if hold.snapshot else self.zupt.still_run(t1) or self.zupt.still_run(t0)
            if run is not None:
                t0 = min(t0, max(run[0], t1 - self.config.holds.measure_s))
                noise = self.zupt.noise_in_use
                vibrates = noise is not None and (periodic(noise.accel_correlation) or
                                                  periodic(noise.gyro_correlation))
                after = self.config.holds.measure_s if ringing or vibrates else self.imu.pad_s
                t1 = max(t1, min(run[1], t0 + after))
            elif hold.snapshot:
                t0 = t1 - self.imu.pad_s
        return t0, t1

    def _imu_gravity(self, hold: Hold) -> ImuGravity | None:
        if self.rig.imu is None or not len(self.imu):
            return None
        t0, t1 = self._imu_span(hold)
        imu, why = self.imu.gravity(t0, t1)
        if imu is None:
            self.stats.dropped[Drop.no_imu_gravity(why.rule)] += 1
            return None
        # a low-pass filtered IMU's samples share their noise: its mean varies more; a motor's vibration, which
        # the samples' scatter holds, averages out: it varies less
        noise = self.zupt.noise_in_use
        if noise is None:
            return imu
        if reads_no_gravity(noise, self.rig.gravity_magnitude):
            self.stats.dropped[Drop.no_imu_gravity(ImuRefusal.NO_GRAVITY)] += 1
            return None
        factor = mean_variance_factor(noise.accel_correlation, imu.num_samples)
        if factor > 1.0 or periodic(noise.accel_correlation):
            return replace(imu, accel_mean_std=imu.accel_mean_std * math.sqrt(factor))
        return imu

    # ------------------------------------------------------------------ batch
    def batch(self) -> list:
        """Every hold of the current sequence estimated jointly at once: (stamp, R_origin, t_origin, gravity,
        gravity_sigma_deg) per hold, origin first; empty with fewer than two holds."""
        return self.estimator.batch()

__all__ = ["FrameSet", "HoldAttempt", "HoldEstimate", "PIPELINE_METHODS", "Pipeline", "PipelineConfig",
           "PipelineStats", "RigState", "RigStatus"]
