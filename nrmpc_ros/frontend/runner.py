"""The work of a :class:`~nrmpc_ros.frontend.feeder.Feeder` run through a Pipeline (the node's worker, the replay).

- "imu" and "frames" go to :meth:`Pipeline.add_imu` / :meth:`Pipeline.add_frames`;
  a frame set the pipeline refuses is dropped and counted ("bad frame set").
- "flush" closes the open hold (its estimate comes out).
- "reset" starts a new sequence (:meth:`Pipeline.reset`).
- "restart" (time jumped back) replaces the pipeline by a fresh one of the
  same rig, settings and method: its hold state, IMU samples and trackers
  all belong to the old time. The statistics of every pipeline run so far
  add up in :attr:`PipelineRunner.stats`.

Sequence numbers of the estimates are unique over restarts (each pipeline
counts its own from 0; the runner offsets them).
"""

from __future__ import annotations

import dataclasses
from collections import Counter

from ..core.rig import Rig
from ..errors import InputError
from .droplog import DropLog
from .pipeline import Pipeline, PipelineConfig, PipelineStats


def merge_stats(a: PipelineStats, b: PipelineStats) -> PipelineStats:
    """Counts added, per-hold lists joined."""
    out = {}
    for f in dataclasses.fields(PipelineStats):
        x, y = getattr(a, f.name), getattr(b, f.name)
        out[f.name] = Counter(x) + Counter(y) if isinstance(x, Counter) else x + y
    return PipelineStats(**out)


class PipelineRunner:
    """Runs work items through the current pipeline (see the module docstring).

    ``catch`` (the node): an unexpected exception of the pipeline is counted and logged as "estimation failed"
    and the work goes on; without it (the replay) it propagates.
    """

    def __init__(self, rig: Rig, config: PipelineConfig | None = None, method: str = "auto",
                 drops: DropLog | None = None, catch: bool = False, log=None, pipeline: Pipeline | None = None):
        self.pipeline = pipeline if pipeline is not None else Pipeline(rig, config, method)
        self.drops = drops if drops is not None else DropLog()
        self.catch = catch
        self.log = log or (lambda level, line: None)
        self.restarts = 0
        self._done = PipelineStats()  # statistics of the pipelines replaced so far
        self._base = 0  # sequence number offset of the current pipeline
        self._max_sequence = -1
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
    def method(self) -> str:
        return self.pipeline.method

    def run(self, work) -> list:
        """Run one work item; returns the hold estimates it completed (0 or more)."""
        p = self.pipeline
        if work.kind == "imu":
            p.add_imu(work.stamp, *work.data)
            return []
        if work.kind == "frames":
            try:
                return self._numbered(p.add_frames(work.data[0]))
            except InputError as exc:
                self._drop(exc.source, "bad frame set", str(exc))
            except Exception as exc:  # noqa: BLE001 - the node must outlive a bug in one hold
                if not self.catch:
                    raise
                self._drop("pipeline", "estimation failed", f"estimation failed at the frame set of "
                                                            f"{work.stamp:.3f} s: {type(exc).__name__}: {exc}")
            return []
        if work.kind == "flush":
            return self._numbered(p.flush())
        if work.kind == "reset":
            p.reset()
            return []
        if work.kind == "restart":
            self.restart(work.data)
            return []
        raise ValueError(f"unknown work item {work.kind!r}")

    def restart(self, why: str = "", method: str | None = None) -> None:
        """A fresh pipeline (same rig and settings; ``method`` if given): a new sequence in a new time."""
        old = self.pipeline
        self._done = merge_stats(self._done, old.stats)
        self.pipeline = Pipeline(old.rig, old.config, method or old.method)
        if old.sequence.keep_history:  # what the old sequences measured stays available (bar calibration)
            self.retired_sequences += old.sequence.sequences()
            self.pipeline.sequence.keep_history = True
        self._base = self._max_sequence + 1
        self.restarts += 1

    def _numbered(self, estimates: list) -> list:
        out = []
        for est in estimates:
            seq = self._base + est.sequence
            self._max_sequence = max(self._max_sequence, seq)
            out.append(est if seq == est.sequence else dataclasses.replace(est, sequence=seq))
        return out

    def _drop(self, source: str, reason: str, message: str) -> None:
        line = self.drops.drop(source, reason, message)
        if line:
            self.log("error" if reason == "estimation failed" else "warn", line)


__all__ = ["PipelineRunner", "merge_stats"]
