"""The work of a :class:`~nrmpc_ros.frontend.feeder.Feeder` run through a Pipeline (the node's worker, the replay).

The items (:class:`~nrmpc_ros.frontend.work.Work`), by kind (:class:`~nrmpc_ros.frontend.work.WorkKind`):

- IMU and FRAMES go to :meth:`Pipeline.add_imu` / :meth:`Pipeline.add_frames`;
  a frame set the pipeline refuses is dropped and counted ("bad frame set").
- FLUSH closes the open hold (its estimate comes out).
- RESET starts a new sequence (:meth:`Pipeline.reset`).
- RESTART (time jumped back) replaces the pipeline by a fresh one of the
  same rig, settings and method: its hold state, IMU samples and trackers
  all belong to the old time. The statistics of every pipeline run so far
  add up in :attr:`PipelineRunner.stats`.

Sequence numbers of the estimates are unique over restarts (each pipeline
counts its own from 0; the runner offsets them).

With ``deferred`` (the node) the pipeline's estimation stage does not run
inside :meth:`PipelineRunner.run`: the measured holds (and sequence resets)
it made are taken with :meth:`PipelineRunner.take_stage_work` and run later,
in order, by :meth:`PipelineRunner.estimate` (in the node: its own worker
thread, docs/ARCHITECTURE.md). A restart then retires the old pipeline at its
place in that order, so the holds it measured before the restart are still
estimated by it and numbered in its sequences. Without it (the replay) every
estimate comes out of the ``run`` that completed its hold.
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from dataclasses import dataclass

from ..core.rig import Rig
from ..errors import InputError
from .droplog import DropLog
from .drops import Drop
from .estimation import MeasuredHold
from .pipeline import Pipeline, PipelineConfig, PipelineStats
from .work import Work, WorkKind


@dataclass(frozen=True)
class StageWork:
    """One item for the estimation stage (``deferred``): a measured hold or a sequence reset of ``pipeline``, or
    ``item`` None: ``pipeline`` was replaced (a restart) and everything it measured is estimated."""

    pipeline: Pipeline
    item: object | None

    @property
    def is_hold(self) -> bool:
        return isinstance(self.item, MeasuredHold)


def merge_stats(a: PipelineStats, b: PipelineStats) -> PipelineStats:
    """Counts added, per-hold lists joined; a stamp the first of the two that has one."""
    out = {}
    for f in dataclasses.fields(PipelineStats):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if x is None or y is None:
            out[f.name] = y if x is None else x
        else:
            out[f.name] = Counter(x) + Counter(y) if isinstance(x, Counter) else x + y
    return PipelineStats(**out)


class PipelineRunner:
    """Runs work items through the current pipeline (see the module docstring).

    ``catch`` (the node): an unexpected exception of the pipeline is counted and logged as "estimation failed"
    and the work goes on; without it (the replay) it propagates.
    """

    def __init__(self, rig: Rig, config: PipelineConfig | None = None, method: str = "auto",
                 drops: DropLog | None = None, catch: bool = False, log=None, pipeline: Pipeline | None = None,
                 on_poses=None, deferred: bool = False):
        self.deferred = deferred
        self.pipeline = pipeline if pipeline is not None else Pipeline(rig, config, method)
        if deferred:
            self.pipeline.handoff = []
        self._stage: list = []  # StageWork not taken yet (deferred)
        self.on_poses = on_poses  # called with the cameras' CameraPoses of every frame set the pipeline took
        self.poses_s = 0.0  # time spent answering the cameras' poses (s)
        self.poses_sets = 0  # frame sets they were answered for
        self.drops = drops if drops is not None else DropLog()
        self.catch = catch
        self.log = log or (lambda level, line: None)
        self.restarts = 0
        self._done = PipelineStats()  # statistics of the pipelines replaced so far
        self._base = 0  # sequence number offset of the current pipeline
        self._max_sequence = -1
        self._logged = 0  # hold log entries numbered so far
        self.retired_sequences: list = []  # with keep_history: the sequences of the pipelines replaced so far

    @classmethod
    def around(cls, pipeline: Pipeline, **kw) -> PipelineRunner:
        """A runner that starts with ``pipeline`` (restarts make new ones like it)."""
        return cls(pipeline.rig, pipeline.config, pipeline.method, pipeline=pipeline, **kw)

    @property
    def stats(self) -> PipelineStats:
        """Statistics of every pipeline run so far."""
        return merge_stats(self._done, self.pipeline.stats)

    def sequences(self) -> list:
        """Every sequence of holds measured so far (``SequenceRecord`` each; the pipeline's sequence must keep its
        history, ``pipeline.sequence.keep_history``)."""
        return self.retired_sequences + self.pipeline.sequence.sequences()

    @property
    def hold_open(self) -> bool:
        """Whether a hold is open and not estimated yet (a "flush" would estimate it)."""
        hold = self.pipeline.open_hold
        return hold is not None and not hold.measured

    @property
    def method(self) -> str:
        return self.pipeline.method

    def run(self, work: Work) -> list:
        """Run one work item; returns the hold estimates it completed (0 or more)."""
        p = self.pipeline
        if work.kind is WorkKind.IMU:
            p.add_imu(work.stamp, *work.data)
            return []
        if work.kind is WorkKind.FRAMES:
            try:
                out = self._numbered(p.add_frames(work.data[0]))
                self._take(p)
                self._poses(work.data[0])
                return out
            except InputError as exc:
                self._drop(exc.source, Drop.BAD_FRAME_SET, str(exc))
            except Exception as exc:  # noqa: BLE001 - the node must outlive a bug in one hold
                if not self.catch:
                    raise
                self._drop("pipeline", Drop.ESTIMATION_FAILED, f"estimation failed at the frame set of "
                                                           f"{work.stamp:.3f} s: {type(exc).__name__}: {exc}")
            self._take(p)
            return []
        if work.kind is WorkKind.FLUSH:
            out = self._numbered(p.flush())
            self._take(p)
            return out
        if work.kind is WorkKind.RESET:
            p.reset()
            self._take(p)
            return []
        if work.kind is WorkKind.RESTART:
            self.restart(work.data)
            return []
        raise ValueError(f"unknown work item {work.kind!r}")

    def _take(self, p: Pipeline) -> None:
        if self.deferred:
            self._stage += [StageWork(p, item) for item in p.take_handoff()]

    def take_stage_work(self) -> list:
        """The :class:`StageWork` the runs since the last call made (``deferred``), in order."""
        out, self._stage = self._stage, []
        return out

    def estimate(self, work: StageWork) -> list:
        """Run one item of the estimation stage (``deferred``); returns its hold estimates, numbered."""
        if work.item is None:
            self._retire(work.pipeline)
            return []
        try:
            return self._numbered(work.pipeline.estimator.run(work.item), getattr(work.item, "attempt", None))
        except Exception as exc:  # noqa: BLE001 - the node must outlive a bug in one hold
            if not self.catch:
                raise
            stamp = getattr(getattr(work.item, "hold", None), "stamp", float("nan"))
            self._drop("pipeline", Drop.ESTIMATION_FAILED, f"estimation failed for the hold at {stamp:.3f} s: "
                                                        f"{type(exc).__name__}: {exc}")
            return []

    def _poses(self, frames) -> None:
        """The cameras' extrinsics at this frame set (from the IMU-driven bars) to ``on_poses``."""
        if self.on_poses is None:
            return
        t0 = time.perf_counter()
        poses = self.pipeline.camera_poses(frames)
        self.poses_s += time.perf_counter() - t0
        self.poses_sets += 1
        if poses is not None:
            self.on_poses(poses)

    def restart(self, why: str = "", method: str | None = None) -> None:
        """A fresh pipeline (same rig and settings; ``method`` if given): a new sequence in a new time."""
        old = self.pipeline
        self.pipeline = Pipeline(old.rig, old.config, method or old.method)
        self.pipeline.hold_log = old.hold_log  # one log over restarts (None: not kept)
        self.pipeline.sequence.keep_history = old.sequence.keep_history
        if self.deferred:
            self.pipeline.handoff = []
            self._stage.append(StageWork(old, None))  # retired once the stage has estimated its holds
        else:
            self._retire(old)
        self.restarts += 1

    def _retire(self, old: Pipeline) -> None:
        """The statistics and sequences of a replaced pipeline join those kept; the next sequences number on."""
        self._done = merge_stats(self._done, old.stats)
        if old.sequence.keep_history:  # what the old sequences measured stays available (bar calibration)
            self.retired_sequences += old.sequence.sequences()
        self._base = self._max_sequence + 1

    def _numbered(self, estimates: list, attempt=None) -> list:
        out = []
        for est in estimates:
            seq = self._base + est.sequence
            self._max_sequence = max(self._max_sequence, seq)
            out.append(est if seq == est.sequence else dataclasses.replace(est, sequence=seq))
        if self.deferred:  # the hold's own log entry (the stage ran it after the intake's later entries)
            if attempt is not None and self._base:
                if attempt.sequence is not None:
                    attempt.sequence += self._base
                if attempt.estimate is not None:
                    attempt.estimate = next((b for a, b in zip(estimates, out) if a is attempt.estimate),
                                            attempt.estimate)
            return out
        log = self.pipeline.hold_log
        if log is not None and self._base:  # the hold log numbers sequences as the estimates do
            numbered = {id(a): b for a, b in zip(estimates, out)}
            for attempt in log[self._logged:]:
                if attempt.sequence is not None:
                    attempt.sequence += self._base
                if attempt.estimate is not None:
                    attempt.estimate = numbered.get(id(attempt.estimate), attempt.estimate)
        if log is not None:
            self._logged = len(log)
        return out

    def _drop(self, source: str, reason: Drop, message: str) -> None:
        line = self.drops.drop(source, reason, message)
        if line:
            self.log("error" if reason is Drop.ESTIMATION_FAILED else "warn", line)


__all__ = ["PipelineRunner", "StageWork", "merge_stats"]
