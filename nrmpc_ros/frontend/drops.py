"""Every reason an input, frame set or hold is dropped: one enum, its message and the stage that counts it.

Counters are keyed by :class:`Drop` members (``PipelineStats.dropped``, the
:class:`~nrmpc_ros.frontend.droplog.DropLog`, ``StampSynchronizer.dropped``);
the sentences are made only where they are shown -- the log lines, the node's
/diagnostics keys (``dropped: <topic>: <message>``, ``not estimated:
<message>``), the replay's summary and ``nrmpc report``'s table -- from
:attr:`Drop.message`, so those strings stay what users and scripts read.

The stages (:class:`Stage`) follow the way of a message (docs/ARCHITECTURE.md):
the feeder's checks and stamp policy (:mod:`.feeder`, :mod:`.stamps`), the
frame grouping (:mod:`.sync`), the node's work queue (:mod:`.service`), the
runner (:mod:`.runner`) and the pipeline itself (:mod:`.pipeline`).
"""

from __future__ import annotations

from enum import Enum

from ..core.incremental import StartReason
from .holds import Refusal
from .imu import ImuRefusal, ImuReject
from .motion import MotionKind
from .work import WorkKind


class Stage(Enum):
    """Where a drop is decided and counted."""

    INPUT = "input"  # a message refused by the feeder: not decodable, wrong shape or size, a bad stamp
    GROUPING = "frame grouping"  # a frame the stamp synchronizer could not put in a frame set
    WORKER = "worker"  # work the node's queue dropped (the estimator busy, the node shutting down)
    RUNNER = "runner"  # a frame set the pipeline refused, or one whose estimation failed
    PIPELINE = "pipeline"  # frame sets, holds and IMU samples the pipeline took but did not use


class Drop(Enum):
    """A reason for a drop: :attr:`message` is the phrase shown (the member's value), :attr:`stage` where it is
    counted and :attr:`label` the short form the frame grouping's own summary uses ("late" for "frame late")."""

    def __new__(cls, message: str, stage: Stage, label: str | None = None):
        obj = object.__new__(cls)
        obj._value_ = message
        obj.stage = stage
        obj.label = label or message
        return obj

    @property
    def message(self) -> str:
        return self.value

    def __str__(self) -> str:
        return self.value

    # the feeder's checks (counted with the topic)
    IMAGE_NOT_DECODED = "image not decoded", Stage.INPUT
    WRONG_IMAGE_SIZE = "wrong image size", Stage.INPUT
    IMU_WRONG_SHAPE = "IMU sample of the wrong shape", Stage.INPUT
    IMU_NOT_FINITE = "IMU sample with NaN or inf", Stage.INPUT
    IMU_ZERO_ACCEL = "IMU sample with zero acceleration", Stage.INPUT
    IMU_OUT_OF_ORDER = "IMU sample out of order", Stage.INPUT
    IMU_FROZEN_STAMP = "IMU sample at a frozen stamp", Stage.INPUT  # before its stamps were found frozen
    INPUT_FAILED = "input failed", Stage.INPUT  # a bug while handling a message (the node goes on)
    # the stamp policy (stamps.py)
    STAMP_NOT_FINITE = "stamp not finite", Stage.INPUT
    STAMP_IN_FUTURE = "stamp in the future", Stage.INPUT
    STAMP_FAR_PAST = "stamp far in the past", Stage.INPUT
    BEFORE_JUMP_BACK = "from before a time jump back", Stage.INPUT
    # the frame grouping (sync.py)
    FRAME_STAMP_NOT_FINITE = "frame stamp not finite", Stage.GROUPING, "stamp not finite"
    FRAME_LATE = "frame late", Stage.GROUPING, "late"
    FRAME_DUPLICATE = "frame duplicate", Stage.GROUPING, "duplicate"
    FRAME_QUEUE_OVERFLOW = "frame queue overflow", Stage.GROUPING, "queue overflow"
    FRAME_UNMATCHED = "frame unmatched", Stage.GROUPING, "unmatched"
    FRAME_FAR_PAST = "frame stamp far in the past", Stage.GROUPING, "stamp far in the past"
    FRAME_FAR_FUTURE = "frame stamp far in the future", Stage.GROUPING, "stamp far in the future"
    # the node's work queue (service.py), per kind of work item
    BUSY_FRAME_SET = "frame set dropped while the estimator is busy", Stage.WORKER
    BUSY_IMU = "imu item dropped while the estimator is busy", Stage.WORKER
    BUSY_FLUSH = "flush item dropped while the estimator is busy", Stage.WORKER
    BUSY_RESTART = "restart item dropped while the estimator is busy", Stage.WORKER
    BUSY_RESET = "reset item dropped while the estimator is busy", Stage.WORKER
    BUSY_METHOD = "method item dropped while the estimator is busy", Stage.WORKER
    SHUTDOWN = "frame set not processed at shutdown", Stage.WORKER
    # the runner (runner.py)
    BAD_FRAME_SET = "bad frame set", Stage.RUNNER
    ESTIMATION_FAILED = "estimation failed", Stage.RUNNER
    # the pipeline (pipeline.py): IMU samples
    IMU_IGNORED = "imu sample ignored: rig file has no imu block", Stage.PIPELINE
    IMU_SAMPLE_WRONG_SHAPE = f"imu sample: {ImuReject.WRONG_SHAPE.value}", Stage.PIPELINE
    IMU_SAMPLE_NOT_FINITE = f"imu sample: {ImuReject.NOT_FINITE.value}", Stage.PIPELINE
    IMU_SAMPLE_OUT_OF_ORDER = f"imu sample: {ImuReject.OUT_OF_ORDER.value}", Stage.PIPELINE
    # ... frame sets
    FRAME_SET_OUT_OF_ORDER = "frame set out of order", Stage.PIPELINE
    NOT_AT_REST_IMU = f"frame not at rest ({MotionKind.IMU_MOVED.value})", Stage.PIPELINE
    NOT_AT_REST_TRACKS_LOST = f"frame not at rest ({MotionKind.TRACKS_LOST.value})", Stage.PIPELINE
    NOT_AT_REST_IMAGE_MOVED = f"frame not at rest ({MotionKind.IMAGE_MOVED.value})", Stage.PIPELINE
    NOT_AT_REST_LEFT_HOLD = f"frame not at rest ({MotionKind.LEFT_HOLD.value})", Stage.PIPELINE
    # ... holds
    SNAPSHOT_MOVED = "snapshot while the IMU says the rig moved", Stage.PIPELINE
    HOLD_NO_FRAMES = f"hold not used: {Refusal.NO_FRAMES.value}", Stage.PIPELINE
    HOLD_NO_TRACKS = f"hold not used: {Refusal.NO_TRACKS.value}", Stage.PIPELINE
    HOLD_NOT_STILL = f"hold not used: {Refusal.NOT_STILL.value}", Stage.PIPELINE
    HOLD_TRACKS_LOST = f"hold not used: {Refusal.TRACKS_LOST.value}", Stage.PIPELINE
    HOLD_TURNING = f"hold not used: {Refusal.TURNING.value}", Stage.PIPELINE
    HOLD_FORCED_WITHOUT_IMU = "hold without IMU gravity (4pt-bending forced)", Stage.PIPELINE
    HOLD_IMU_REFUTED = ("hold not published: the images refuted its IMU gravity, and its sequence rests on the "
                        "same IMU's"), Stage.PIPELINE
    HOLD_IMU_DOUBTED = ("hold not published: the images refuted an earlier IMU gravity of its sequence, which rests "
                        "on the same IMU's"), Stage.PIPELINE
    NO_IMU_GRAVITY_NO_BLOCK = f"hold without IMU gravity: {ImuRefusal.NO_IMU_BLOCK.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_NO_SAMPLES = f"hold without IMU gravity: {ImuRefusal.NO_SAMPLES.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_FEW_SAMPLES = f"hold without IMU gravity: {ImuRefusal.FEW_SAMPLES.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_STALE = f"hold without IMU gravity: {ImuRefusal.STALE.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_BAD_MEAN = f"hold without IMU gravity: {ImuRefusal.BAD_MEAN.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_REFUTED = f"hold without IMU gravity: {ImuRefusal.REFUTED.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_PENDING = f"hold without IMU gravity: {ImuRefusal.PENDING.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_DOUBTED = f"hold without IMU gravity: {ImuRefusal.DOUBTED.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_UNUSABLE = f"hold without IMU gravity: {ImuRefusal.UNUSABLE.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_AXES_OFF = f"hold without IMU gravity: {ImuRefusal.AXES_OFF.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_TURN_REFUTED = f"hold without IMU gravity: {ImuRefusal.TURN_REFUTED.value}", Stage.PIPELINE
    NO_IMU_GRAVITY_NONE_AT_REST = f"hold without IMU gravity: {ImuRefusal.NO_GRAVITY.value}", Stage.PIPELINE
    NEW_SEQUENCE_NO_SHARED = f"hold starts a new sequence ({StartReason.NO_SHARED_LANDMARKS.value})", Stage.PIPELINE
    NEW_SEQUENCE_PAIR_FAILED = f"hold starts a new sequence ({StartReason.PAIR_FAILED.value})", Stage.PIPELINE
    NEW_SEQUENCE_FEW_INLIERS = f"hold starts a new sequence ({StartReason.FEW_INLIERS.value})", Stage.PIPELINE

    # ------------------------------------------------------------------ the families, by their own outcome types
    @classmethod
    def busy(cls, kind: WorkKind) -> Drop:
        """A work item of ``kind`` dropped while the estimator is busy."""
        return _BUSY[kind]

    @classmethod
    def imu_sample(cls, reject: ImuReject) -> Drop:
        return _IMU_SAMPLE[reject]

    @classmethod
    def not_at_rest(cls, kind: MotionKind) -> Drop:
        return _NOT_AT_REST[kind]

    @classmethod
    def hold_refused(cls, rule: Refusal) -> Drop:
        return _HOLD_REFUSED[rule]

    @classmethod
    def no_imu_gravity(cls, rule: ImuRefusal) -> Drop:
        return _NO_IMU_GRAVITY[rule]

    @classmethod
    def new_sequence(cls, reason: StartReason) -> Drop:
        """A hold that breaks its sequence (not a sequence's first view: that is no drop)."""
        return _NEW_SEQUENCE[reason]


_BUSY = {WorkKind.FRAMES: Drop.BUSY_FRAME_SET, WorkKind.IMU: Drop.BUSY_IMU, WorkKind.FLUSH: Drop.BUSY_FLUSH,
         WorkKind.RESTART: Drop.BUSY_RESTART, WorkKind.RESET: Drop.BUSY_RESET, WorkKind.METHOD: Drop.BUSY_METHOD}
_IMU_SAMPLE = {ImuReject.WRONG_SHAPE: Drop.IMU_SAMPLE_WRONG_SHAPE, ImuReject.NOT_FINITE: Drop.IMU_SAMPLE_NOT_FINITE,
               ImuReject.OUT_OF_ORDER: Drop.IMU_SAMPLE_OUT_OF_ORDER}
_NOT_AT_REST = {MotionKind.IMU_MOVED: Drop.NOT_AT_REST_IMU, MotionKind.TRACKS_LOST: Drop.NOT_AT_REST_TRACKS_LOST,
                MotionKind.IMAGE_MOVED: Drop.NOT_AT_REST_IMAGE_MOVED, MotionKind.LEFT_HOLD: Drop.NOT_AT_REST_LEFT_HOLD}
_HOLD_REFUSED = {Refusal.NO_FRAMES: Drop.HOLD_NO_FRAMES, Refusal.NO_TRACKS: Drop.HOLD_NO_TRACKS,
                 Refusal.NOT_STILL: Drop.HOLD_NOT_STILL, Refusal.TRACKS_LOST: Drop.HOLD_TRACKS_LOST,
                 Refusal.TURNING: Drop.HOLD_TURNING}
_NO_IMU_GRAVITY = {ImuRefusal.NO_IMU_BLOCK: Drop.NO_IMU_GRAVITY_NO_BLOCK,
                   ImuRefusal.NO_SAMPLES: Drop.NO_IMU_GRAVITY_NO_SAMPLES,
                   ImuRefusal.FEW_SAMPLES: Drop.NO_IMU_GRAVITY_FEW_SAMPLES,
                   ImuRefusal.STALE: Drop.NO_IMU_GRAVITY_STALE, ImuRefusal.BAD_MEAN: Drop.NO_IMU_GRAVITY_BAD_MEAN,
                   ImuRefusal.REFUTED: Drop.NO_IMU_GRAVITY_REFUTED, ImuRefusal.DOUBTED: Drop.NO_IMU_GRAVITY_DOUBTED,
                   ImuRefusal.PENDING: Drop.NO_IMU_GRAVITY_PENDING,
                   ImuRefusal.UNUSABLE: Drop.NO_IMU_GRAVITY_UNUSABLE, ImuRefusal.AXES_OFF: Drop.NO_IMU_GRAVITY_AXES_OFF,
                   ImuRefusal.TURN_REFUTED: Drop.NO_IMU_GRAVITY_TURN_REFUTED,
                   ImuRefusal.NO_GRAVITY: Drop.NO_IMU_GRAVITY_NONE_AT_REST}
_NEW_SEQUENCE = {StartReason.NO_SHARED_LANDMARKS: Drop.NEW_SEQUENCE_NO_SHARED,
                 StartReason.PAIR_FAILED: Drop.NEW_SEQUENCE_PAIR_FAILED,
                 StartReason.FEW_INLIERS: Drop.NEW_SEQUENCE_FEW_INLIERS}


def sorted_counts(counts: dict) -> list:
    """``(key, n)`` items in the order shown: by the key's text (a Drop's message; a (source, Drop) pair by
    source, then message), as the counts keyed by sentences were."""
    def text(key):
        return tuple(str(k) for k in key) if isinstance(key, tuple) else (str(key),)

    return sorted(counts.items(), key=lambda kv: text(kv[0]))


__all__ = ["Drop", "Stage", "sorted_counts"]
