"""Everything the ``estimator`` node does at run time that needs no ROS: inputs, worker, outputs, reports.

The node (``nrmpc_ros.node``) only turns ROS messages, timers and services
into calls of :class:`EstimatorService` and its outputs into messages; its
settings are :mod:`nrmpc_ros.frontend.node_config`. Here:

- inputs: a :class:`~nrmpc_ros.frontend.feeder.Feeder` (the same input policy
  as ``nrmpc replay``) hands work to a bounded queue (:class:`WorkQueue`); when
  it is full the waiting frame set whose images changed most is dropped and
  counted (moves are thinned, holds kept), which bounds the latency;
- two worker threads (docs/ARCHITECTURE.md, "The node's two workers"): the
  intake worker runs the queue through the intake of a
  :class:`~nrmpc_ros.frontend.runner.PipelineRunner` (tracking, holds, a
  hold's measurement) and hands each measured hold to the estimation worker
  (:class:`HoldQueue`, in order, never dropped), which links and estimates it
  and hands a :class:`~nrmpc_ros.frontend.outputs.HoldOutput` per hold
  estimate to ``publish``: frame sets never wait behind a hold's estimate;
- the rig's state (:class:`~nrmpc_ros.frontend.pipeline.RigStatus`) goes to
  ``publish_status`` after every estimate and whenever it changes;
- reports: camera liveness, rate-limited drop logs, the diagnostics per part
  (cameras, IMU, estimation: :mod:`.diagnostics`) and the shutdown summary;
- shutdown within a budget (:meth:`EstimatorService.stop`): the frame sets
  waiting are dropped and counted, the item in progress is abandoned when it
  does not end in time, the measured holds waiting are estimated until the
  deadline, and the open hold is estimated only when its estimate, judged by
  the longest hold estimate measured so far and the holds ahead of it, fits in
  what is left of the budget; the line returned says which (README, "The ROS 2
  node", Drops and logs).
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter, deque

import cv2
import numpy as np

from ..core.rig import Rig
from .camera_info import camera_info_mismatch
from .delivery import BURST_MARGIN
from .diagnostics import ERROR, OK, WARN, ServiceDiagnostics, Status
from .droplog import DropLog
from .drops import Drop
from .extrinsics import NO_IMU_NOTE, imu_mount_warning
from .feeder import IMU, Feeder
from .images import stamp_seconds
from .imu_clock import MIN_MOVES
from .imu_clock_check import CLOCK_PASSES, LAG_ASKS_GROWTH, describe_clock, lag_from_moves
from .imu_mount import AxesVerdict, describe_imu_axes, imu_axes
from .imu_units import describe_units, imu_units
from .liveness import CameraWatch
from .node_config import NodeConfig
from .outputs import FrameNames, FramePosesOutput, HoldOutput, hold_output
from .pipeline import PIPELINE_METHODS, PipelineConfig, RigState
from .preload import ESTIMATION, INTAKE, preload
from .runner import PipelineRunner
from .taken import stamp_order
from .work import Work, WorkKind

SHUTDOWN_S = 2.0  # SIGINT or SIGTERM to the end of the process: what launch files and test harnesses wait for


def image_change(previous, images) -> tuple:
    """How much a frame set's images changed since the camera's previous ones: the largest over the cameras of
    the mean absolute grey-level difference on every 8th pixel of every 8th row (a few microseconds per image),
    and the subsampled images to compare the next set with. Used only to rank waiting frame sets (more change:
    more motion), never as a threshold; a camera without a previous image ranks its set first to keep."""
    small = [None if img is None else np.ascontiguousarray(img[::8, ::8]) for img in images]
    change = 0.0
    for a, b in zip(previous, small):
        if a is not None and b is not None and a.shape == b.shape:
            change = max(change, float(cv2.absdiff(a, b).mean()))
    return change, small


WORK_POLL_S = 0.1  # a worker waits this long for work before it looks at its stop flag again
ESTIMATE_POLL_S = 0.05  # ... the estimation worker (shorter: a hold waiting at shutdown starts sooner)
RECENT_TIMINGS = 500  # latencies and processing times per frame set: the diagnostics' percentiles over this many
RECENT_HOLD_TIMINGS = 50  # the estimation stage's time per hold: the shutdown judges the open hold by these
class WorkQueue:
    """Work for the worker thread: ``put`` never blocks; at most ``max_frames`` frame sets wait.

    When a frame set arrives while ``max_frames`` wait, one of them (or the new one) is dropped, chosen by
    :meth:`_victim`: frames taken while the rig moves go first, the frames of a hold, whose images barely
    change, last and evenly, so a busy estimator thins the moves and keeps the holds with their span, and the
    frame sets waiting (the latency) stay bounded. IMU samples and other work are never dropped (below
    ``max_items``)."""

    def __init__(self, max_frames: int, max_items: int = 200000):
        self.max_frames = int(max_frames)
        self.max_items = int(max_items)
        self._items: deque = deque()  # (Work, image change)
        self._last_stamp = -math.inf  # of the last frame set taken by the worker
        self._frames = 0
        self._cv = threading.Condition()

    def put(self, work: Work, change: float = 0.0):
        """Queue ``work``; returns None, or the frame set dropped to make room (``work`` itself when it ranks
        last; any work when ``max_items`` wait)."""
        with self._cv:
            frames = work.kind is WorkKind.FRAMES
            if len(self._items) >= self.max_items:
                return work
            dropped = None
            self._items.append((work, change))
            if frames and self._frames >= self.max_frames:
                at = self._victim()
                dropped = self._items[at][0]
                del self._items[at]
                self._frames -= 1
            self._frames += frames
            self._cv.notify()
            return dropped

    def _victim(self) -> int:
        """Index of the frame set to drop: the largest image change, on a doubling scale (so the noise between
        two still frames does not decide); among equals the one whose neighbours lie closest in time, so a
        hold is thinned evenly and keeps its span (the newest is kept: it extends the span). A time jump back
        or a reset between two frame sets starts a new sequence: the sets on either side of it are the ends of
        their sequences' spans and are kept like the newest (a gap across sequences is no gap in time)."""
        sets, ends, start = [], set(), True  # ends: indices in sets of a sequence's first or last set
        for k, (w, c) in enumerate(self._items):
            if w.kind.ends_sequence:
                start = True
                if sets:
                    ends.add(len(sets) - 1)
            elif w.kind is WorkKind.FRAMES:
                if start or (sets and w.stamp <= sets[-1][1]):
                    ends.update({len(sets), len(sets) - 1} if sets else {0})
                start = False
                sets.append((k, w.stamp, c))
        stamps = [t for _, t, _ in sets]
        best, at = None, sets[-1][0]
        for j, (k, _, c) in enumerate(sets[:-1]):
            gap = math.inf if j in ends else stamps[j + 1] - (stamps[j - 1] if j else self._last_stamp)
            key = (math.floor(math.log2(1.0 + c)), -gap)
            if best is None or key > best:
                best, at = key, k
        newest = (math.floor(math.log2(1.0 + sets[-1][2])), -math.inf)
        return sets[-1][0] if best is None or newest > best else at

    def get(self, timeout: float):
        with self._cv:
            item = _wait_pop(self._cv, self._items, timeout)
            if item is None:
                return None
            work, _ = item
            if work.kind is WorkKind.FRAMES:
                self._frames -= 1
                self._last_stamp = work.stamp
            elif work.kind.ends_sequence:
                self._last_stamp = -math.inf
            return work

    def frames(self) -> int:
        with self._cv:
            return self._frames

    def __len__(self) -> int:
        with self._cv:
            return len(self._items)

    def clear(self) -> int:
        """Remove everything waiting; returns how many frame sets were among it."""
        with self._cv:
            frames, self._frames = self._frames, 0
            self._items.clear()
            return frames


def _wait_pop(cv: threading.Condition, items: deque, timeout: float):
    """The oldest of ``items`` (``cv`` held), waiting up to ``timeout`` s for one; None if none came."""
    if not items:
        cv.wait(timeout)
    return items.popleft() if items else None


class HoldQueue:
    """Work for the estimation worker: measured holds and the markers around them, in order; nothing is ever
    dropped (a hold is a few averaged tracks, and frame sets are thinned before they reach the intake)."""

    def __init__(self):
        self._items: deque = deque()  # (StageWork, arrival clock of the frame set that completed it)
        self._holds = 0
        self._cv = threading.Condition()

    def put(self, work, arrival: float) -> None:
        with self._cv:
            self._items.append((work, arrival))
            self._holds += work.is_hold
            self._cv.notify()

    def get(self, timeout: float):
        """The oldest (work, arrival), or None when nothing came within ``timeout`` s."""
        with self._cv:
            item = _wait_pop(self._cv, self._items, timeout)
            if item is None:
                return None
            work, arrival = item
            self._holds -= work.is_hold
            return work, arrival

    def holds(self) -> int:
        with self._cv:
            return self._holds

    def __len__(self) -> int:
        with self._cv:
            return len(self._items)


class EstimatorService:
    """The node without ROS (see the module docstring).

    ``camera_topics`` and ``imu_topic`` are the input topics as the node resolved them (after remapping; None:
    no IMU); ``publish(HoldOutput)`` is called from the worker thread; ``log(level, line)`` with level "info",
    "warn" or "error" from either thread. ``clock`` gives arrival times (monotonic seconds).
    """

    def __init__(self, rig: Rig, config: NodeConfig, pipeline_config: PipelineConfig, camera_topics: list,
                 imu_topic: str | None, publish, log, clock=time.monotonic, publish_poses=None, publish_status=None):
        self.rig, self.config = rig, config
        self.camera_topics, self.imu_topic = list(camera_topics), imu_topic
        self.publish, self.log, self.clock = publish, log, clock
        self.publish_poses = publish_poses  # FramePosesOutput of every frame set (with an IMU), worker thread
        self._poses_stamp = -float("inf")  # stamp of the last ~/camera_poses from the bars' dynamics
        self.publish_status = publish_status  # (RigStatus, last HoldOutput or None): on estimates and state changes
        self._status = None  # the RigStatus last handed to publish_status
        self.drops = DropLog(config.log_every_s, clock)
        self.queue = WorkQueue(config.work_queue_size)
        self.holds = HoldQueue()  # measured holds for the estimation worker
        self.feeder = Feeder(rig, config.input, self._put, self.drops, self.camera_topics, imu_topic, log, clock)
        self.runner = PipelineRunner(rig, pipeline_config, config.method, self.drops, catch=True, log=log,
                                     on_poses=self._on_poses if publish_poses is not None else None,
                                     deferred=True)
        if imu_topic is None:
            log("info", NO_IMU_NOTE)
        elif imu_mount_warning(rig):
            log("warn", imu_mount_warning(rig))
        self.stats = self.runner.stats  # a copy the worker renews after each work item (the timer reads it)
        self.watch = CameraWatch(self.camera_topics, config.camera_timeout_s, config.diagnostics_period_s)
        self.frames = FrameNames(rig.body_frame, config.origin_frame or f"{rig.body_frame}_origin",
                                 tuple(c.name + config.camera_frame_suffix for c in rig.cameras))
        self.received: Counter = Counter()
        self.camera_info: dict = {}  # camera index -> "agrees with the rig file" or what differs
        self.counts: Counter = Counter()
        self.latency_ms: deque = deque(maxlen=RECENT_TIMINGS)  # arrival of the set that completed a hold to its output
        self.process_ms: deque = deque(maxlen=RECENT_TIMINGS)  # the intake's processing time per frame set
        self.set_latency_ms: deque = deque(maxlen=2 * RECENT_TIMINGS)  # arrival of a frame set to the end of its intake
        self.hold_ms: deque = deque(maxlen=RECENT_HOLD_TIMINGS)  # the estimation stage's time per hold estimated
        self.last: HoldOutput | None = None
        self._lock = threading.Lock()
        self._input_lock = threading.RLock()  # the inputs, the liveness timer, resets and method changes come from
        # the node's executor and its thread that takes the inputs: one at a time into the feeder
        self._stop = threading.Event()  # the intake worker stops
        self._drain = threading.Event()  # the estimation worker stops once no hold waits
        self._halt = threading.Event()  # the estimation worker stops after its item
        self._status_lock = threading.Lock()  # both workers hand the rig's state over
        self._thread: threading.Thread | None = None
        self._estimator: threading.Thread | None = None
        self._running = False  # the intake worker is on a work item
        self._estimating = False  # the estimation worker is on a hold
        self.reports = ServiceDiagnostics(self)
        self._small: list = [None] * rig.num_cameras  # the last frame set's images, subsampled (image_change)
        self.measured_from = None  # the pipeline whose measurement of the IMU (units, clock) went to the input
        self._lag_ask = (None, MIN_MOVES + 1)  # (pipeline, its holds ended when the moves are next asked)

    # ------------------------------------------------------------------ inputs (the node's threads, one at a time)
    def on_image(self, index: int, msg, now: float | None) -> None:
        """An image message of camera ``index``; ``now`` is the node's clock (s), None while it does not run."""
        with self._input_lock:
            before = self.feeder.newest_frame(index)
            self.received[self.camera_topics[index]] += 1
            self._guarded(self.camera_topics[index], self.feeder.image, index, msg, now)
            after = self.feeder.newest_frame(index)  # the stamp of an accepted frame tells how the camera delivers
            for level, line in self.watch.seen(index, self.clock(), after if after != before else None,
                                               self.feeder.timeline):
                self.log(level, line)

    def on_imu(self, msg, now: float | None) -> None:
        with self._input_lock:
            self.received[self.imu_topic] += 1
            self._guarded(self.imu_topic, self.feeder.imu_msg, msg, now)

    def on_imu_block(self, block, now: float | None) -> None:
        """IMU samples taken together (an :class:`~nrmpc_ros.frontend.imu_block.ImuBlock`), as :meth:`on_imu`."""
        with self._input_lock:
            self.received[self.imu_topic] += len(block)
            self._guarded(self.imu_topic, self.feeder.imu_block, block, now)

    def on_taken(self, images: list, block, now: float | None) -> None:
        """Messages taken from the subscriptions together: ``images[i]`` camera ``i``'s image messages and
        ``block`` the IMU's samples (an :class:`~nrmpc_ros.frontend.imu_block.ImuBlock`, or None), each in
        arrival order; handed over merged by stamp (:mod:`~nrmpc_ros.frontend.taken`)."""
        imu_stamps = block.stamps if block is not None else ()
        with self._input_lock:
            for run in stamp_order([[stamp_seconds(m) for m in msgs] for msgs in images], imu_stamps):
                if run.stream == IMU:
                    self.on_imu_block(block.part(run.start, run.stop), now)
                else:
                    self.on_image(run.stream, images[run.stream][run.start], now)

    def _guarded(self, source: str, fn, *args) -> None:
        """Run an input step; a failure (a bug, not bad input: that is dropped on its own) is counted and logged,
        and the node goes on."""
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - the node must outlive it
            self.input_failed(source, exc)

    def input_failed(self, source: str, exc: Exception) -> None:
        """Count and log (when due) a failure in handling the inputs of ``source``: a bug, not bad input."""
        line = self.drops.drop(source, Drop.INPUT_FAILED, f"{source}: handling a message failed: "
                                                          f"{type(exc).__name__}: {exc}")
        if line:
            self.log("error", line)

    def on_camera_info(self, index: int, msg, topic: str) -> None:
        """The first CameraInfo of a camera: reported once when it disagrees with the rig file."""
        problem = camera_info_mismatch(self.rig.cameras[index], msg, self.rig.source)
        self.camera_info[index] = problem or "agrees with the rig file"
        if problem:
            self.log("warn", f"{topic}: {problem}")

    def reset(self, why: str = "requested") -> str:
        """Start a new sequence: the next hold is the origin."""
        with self._input_lock:
            self.feeder.reset(why)
        self.counts["resets"] += 1
        return f"a new sequence starts with the next hold ({why})"

    def set_method(self, method: str) -> str | None:
        """A new method from the next hold on (the open hold is estimated first; a new sequence starts); returns
        why not when ``method`` is not one."""
        if method not in PIPELINE_METHODS:
            return f"parameter method: must be one of {', '.join(PIPELINE_METHODS)}, got {method!r}"
        with self._input_lock:
            self.feeder.end()
            self._put(Work(WorkKind.METHOD, data=method))
        self.log("info", f"method {method} from the next hold on (a new sequence)")
        return None

    def tick(self) -> None:
        """Timer: camera liveness (the end of the input flushes the open hold) and the drop counts due."""
        with self._input_lock:
            for level, line in self.watch.check(self.clock()):
                if level == "ended":
                    self.log("info", line)
                    self.feeder.end()
                else:
                    self.log(level, line)
        for line in self.drops.due():
            self.log("warn", line)

    def _put(self, work: Work) -> None:
        change = 0.0
        if work.kind is WorkKind.FRAMES:
            change, self._small = image_change(self._small, work.data[0].images)
            # a camera that delivers in bursts brings seconds of frame sets at once: room for a burst, not a
            # drop of its moves while the estimator would catch up before the next one
            burst = math.ceil(BURST_MARGIN * self.feeder.burst_frame_sets())
            self.queue.max_frames = max(self.config.work_queue_size, burst)
        elif work.kind.ends_sequence:  # the next set is compared with nothing: it starts a sequence
            self._small = [None] * self.rig.num_cameras
        dropped = self.queue.put(work, change)
        if dropped is not None:
            what = "frame set" if dropped.kind is WorkKind.FRAMES else f"{dropped.kind.value} item"
            line = self.drops.drop("worker", Drop.busy(dropped.kind),
                                   f"{what} at {dropped.stamp:.3f} s dropped while the estimator is busy (of "
                                   f"the {self.queue.frames() + 1} waiting, the one whose images changed most: "
                                   f"holds are kept, moves thinned; work_queue_size {self.config.work_queue_size})")
            if line:
                self.log("warn", line)

    # ------------------------------------------------------------------ worker threads
    def start(self) -> None:
        """Start the intake worker (frame sets: tracking, holds) and the estimation worker (measured holds)."""
        self._thread = threading.Thread(target=self._work_loop, name="nrmpc-intake", daemon=True)
        self._estimator = threading.Thread(target=self._estimate_loop, name="nrmpc-estimator", daemon=True)
        self._thread.start()
        self._estimator.start()

    def holds_waiting(self) -> int:
        """Measured holds handed to the estimation worker and not published yet."""
        return self.holds.holds() + self._estimating

    def work_waiting(self) -> int:
        """Work items of either worker not done yet (0: everything that came in is processed)."""
        return len(self.queue) + self._running + len(self.holds) + self._estimating

    def stop(self, budget_s: float = SHUTDOWN_S) -> str:
        """Stop both workers within ``budget_s`` seconds; returns what became of the work in progress, the holds
        waiting and the open hold (one line for the shutdown summary).

        The frame sets waiting are dropped and counted ("not processed at shutdown"); the intake finishes its
        item if it can within the budget, else that item is abandoned (the threads are daemons: they end with
        the process). The open hold is then measured and handed to the estimation worker only when the longest
        hold estimate measured so far, times the holds still ahead of it, fits in what is left; without a
        measurement it is tried. It is measured on everything received, as at the end of a replay: the frames
        the feeder still groups and the IMU samples it holds after the last frame set go in first. The
        estimation worker goes on with the holds waiting until the deadline.
        """
        end = time.monotonic() + budget_s
        self._stop.set()
        waiting = self.queue.clear()
        if waiting:
            self.drops.drop("worker", Drop.SHUTDOWN,
                            f"{waiting} frame sets not processed at shutdown", count=waiting)
        line = self._stop_intake(end, budget_s)
        self._drain.set()
        estimator = self._estimator
        if estimator is None or not estimator.is_alive():  # never started: its work is done here, as bounded
            estimator = threading.Thread(target=self._estimate_loop, name="nrmpc-shutdown-estimate", daemon=True)
            estimator.start()
        estimator.join(max(0.0, end - time.monotonic()))
        self._halt.set()
        if not self.holds_waiting():
            return line or "open hold estimated at shutdown"
        return ((line or "open hold abandoned: its estimate did not end in time") +
                f"; {self.holds_waiting()} measured holds (with the one in progress) were not estimated within the "
                f"{budget_s:g} s of the shutdown")

    def _stop_intake(self, end: float, budget_s: float) -> str:
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(max(0.0, end - time.monotonic()))
            if self._thread.is_alive():
                return (f"the frame set in progress was abandoned: it did not end within the {budget_s:g} s "
                        "of the shutdown")
        if not self.runner.hold_open:
            return "no open hold"
        ahead = self.holds_waiting() + 1
        left, need = end - time.monotonic(), ahead * 1e-3 * max(self.hold_ms, default=0.0)
        if need > left:
            return (f"open hold not estimated: would not fit in the {budget_s:g} s of the shutdown (hold "
                    f"estimates took up to {1e3 * need / ahead:.0f} ms, {ahead - 1} holds waited ahead of it, "
                    f"{max(0.0, 1e3 * left):.0f} ms were left)")
        with self._input_lock:
            self.feeder.end()  # what the feeder still holds, then a flush: the open hold on all that was received
        flush = threading.Thread(target=self._work_left, name="nrmpc-shutdown-flush", daemon=True)
        flush.start()
        flush.join(max(0.0, end - time.monotonic()))
        if flush.is_alive():
            return f"open hold abandoned: its measurement did not end within the {budget_s:g} s of the shutdown"
        return ""  # handed to the estimation worker: estimated if it ends in time

    def _work_left(self) -> None:
        while len(self.queue):
            self.work_once()

    def _work_loop(self) -> None:
        preload(INTAKE)
        while not self._stop.is_set():
            self.work_once(WORK_POLL_S)

    def _estimate_loop(self) -> None:
        preload(ESTIMATION)
        while not self._halt.is_set():
            if self.estimate_once(ESTIMATE_POLL_S) is None and self._drain.is_set() and not len(self.holds):
                return

    def work_once(self, timeout: float = 0.0) -> list:
        """Run one work item of the intake (waiting up to ``timeout`` s for one): the measured holds it made go
        to the estimation worker; returns the outputs it published itself (none: estimates come from
        :meth:`estimate_once`)."""
        work = self.queue.get(timeout)
        if work is None:
            return []
        self._running = True
        outputs = []
        try:
            if work.kind is WorkKind.METHOD:
                self.runner.restart(f"method {work.data}", work.data)
            else:
                t0 = time.perf_counter()
                outputs = [self._output(est) for est in self.runner.run(work)]
                elapsed_ms = 1e3 * (time.perf_counter() - t0)
                for out in outputs:
                    self._publish(self.publish, out)
            arrival = work.data[1] if work.kind is WorkKind.FRAMES else self.clock()
            for item in self.runner.take_stage_work():
                self.holds.put(item, arrival)
            self._apply_imu_measures()
        finally:
            self._running = False
        stats = self.runner.stats
        with self._lock:
            self.stats = stats
            if work.kind is WorkKind.FRAMES:
                self.counts["processed frame sets"] += 1
                self.process_ms.append(elapsed_ms)
                self.set_latency_ms.append(1e3 * (self.clock() - work.data[1]))
            self._outputs(outputs, work.data[1] if work.kind is WorkKind.FRAMES else None)
        self._status_changed(outputs)
        return outputs

    def _apply_imu_measures(self) -> None:
        """What the frame stage measured of the IMU goes to the input, a new sequence starting: its units (deg/s,
        g: multiplied into rad/s and m/s^2 from the next sample on, once a run; ``input.imu_units_measured``),
        the IMU's axes (:meth:`_apply_imu_axes`),
        an IMU clock offset (seconds off the cameras', from the moves; or a lag within a quarter second)
        added to the IMU's stamps (``input.imu_clock_measured``; at most ``CLOCK_PASSES - 1``
        times a run, as the replay's passes). Both are asked as holds end (:meth:`_asked`)."""
        pipeline = self.runner.pipeline
        if pipeline is self.measured_from:
            return  # (the pipeline that measured it runs on until the restart queued behind its frames)
        asked = self._asked(pipeline)
        if asked and not self.counts["IMU units applied"] and not self.counts["IMU units warned"]:
            units = imu_units(pipeline)
            given = self.feeder.config
            if units.wrong and not self.config.input.imu_units_measured:
                self.counts["IMU units warned"] += 1
                self.log("warn", f"{describe_units(units)}: set input.imu_gyro_scale to "
                                 f"{given.imu_gyro_scale * units.gyro_scale:.7g} and input.imu_accel_scale to "
                                 f"{given.imu_accel_scale * units.accel_scale:.7g}, or fix the driver")
            elif units.wrong:
                self.measured_from = pipeline
                with self._input_lock:
                    self.feeder.rescale_imu(units.gyro_scale, units.accel_scale, "the IMU's units measured")
                self.counts["IMU units applied"] += 1
                self.log("warn", f"{describe_units(units)}: the rates are multiplied by {units.gyro_scale:.7g} and "
                                 f"the specific force by {units.accel_scale:.7g} from now on (input.imu_gyro_scale "
                                 f"{self.feeder.config.imu_gyro_scale:.7g}, input.imu_accel_scale "
                                 f"{self.feeder.config.imu_accel_scale:.7g}): the holds start afresh (a new sequence)")
                return
        if asked and self._apply_imu_axes(pipeline):
            return
        if not self.config.input.imu_clock_measured or self.counts["IMU clock offsets applied"] >= CLOCK_PASSES - 1:
            return
        measured = pipeline.imu_clock_off or (lag_from_moves(pipeline.imu_clock) if asked else None)
        if measured is None:
            return
        self.measured_from = pipeline
        why = (f"{describe_clock(measured)}: {measured.offset_s:+.3f} s added to the IMU's stamps from now on "
               f"(input.imu_clock_offset_s {self.feeder.config.imu_clock_offset_s + measured.offset_s:.3f})")
        with self._input_lock:
            self.feeder.reclock_imu(measured.offset_s, "the IMU's clock measured off the cameras'")
        self.counts["IMU clock offsets applied"] += 1
        self.log("warn", f"{why}: the holds start afresh (a new sequence)")

    def _apply_imu_axes(self, pipeline) -> bool:
        """The IMU's axes the turns between holds measure (:func:`~nrmpc_ros.frontend.imu_mount.imu_axes`): where
        the rig file's are wrong every sample is turned from the next on (``input.imu_axes_measured``), a new
        sequence starting, once a run; a verdict that keeps them (the IMU's gravity so turned still off the
        images') is said once. Returns whether the samples were turned."""
        if self.rig.imu is None or self.counts["IMU axes applied"] or self.counts["IMU axes warned"]:
            return False
        axes = imu_axes(pipeline)
        verdict = None if axes is None else axes.verdict
        if verdict in (None, AxesVerdict.AGREE, AxesVerdict.NOT_MEASURABLE, AxesVerdict.UNCERTAIN):
            return False  # later holds may measure it (the stage sets the IMU's gravity aside meanwhile)
        said = describe_imu_axes(axes, self.rig.imu.rotation)
        if not axes.applies or not self.config.input.imu_axes_measured:
            self.counts["IMU axes warned"] += 1
            self.log("warn", said + (" (input.imu_axes_measured is false: not applied)" if axes.applies else ""))
            return False
        self.measured_from = pipeline
        with self._input_lock:
            self.feeder.turn_imu_axes(axes.correction(self.rig.imu.rotation), "the IMU's axes measured")
        self.counts["IMU axes applied"] += 1
        self.log("warn", f"{said}: every IMU sample is turned from now on (fix the rig file to keep it): the holds "
                         "start afresh (a new sequence)")
        return True

    def _asked(self, pipeline) -> bool:
        """Whether the moves are asked what they say of the IMU now (:func:`~nrmpc_ros.frontend.imu_clock_check.
        lag_from_moves`, :func:`~nrmpc_ros.frontend.imu_units.imu_units`): once the holds ``pipeline`` ended
        have ``MIN_MOVES`` moves between them, and again each time the holds ended have grown by
        ``LAG_ASKS_GROWTH`` (docs/PIPELINE.md, "IMU gravity that the images refute"). Replay measures the whole
        recording after its pass; a running node has only what came so far, and neither a lag (a stamping delay:
        it holds every hold's IMU stillness into the next move, so no hold settles) nor a gyro in deg/s (no hold
        is still) lets the images refute the IMU's gravity."""
        if self._lag_ask[0] is not pipeline:
            self._lag_ask = (pipeline, MIN_MOVES + 1)
        if self.rig.imu is None or pipeline.holds_ended < self._lag_ask[1]:
            return False
        self._lag_ask = (pipeline, math.ceil(LAG_ASKS_GROWTH * pipeline.holds_ended))
        return True

    def estimate_once(self, timeout: float = 0.0) -> list | None:
        """Run one item of the estimation worker (waiting up to ``timeout`` s for one); publish and return its
        outputs (None: nothing waited)."""
        got = self.holds.get(timeout)
        if got is None:
            return None
        work, arrival = got
        self._estimating = work.is_hold
        try:
            t0 = time.perf_counter()
            outputs = [self._output(est) for est in self.runner.estimate(work)]
            elapsed_ms = 1e3 * (time.perf_counter() - t0)
            for out in outputs:
                self._publish(self.publish, out)
        finally:
            self._estimating = False
        stats = self.runner.stats
        with self._lock:
            self.stats = stats
            self._outputs(outputs, arrival)
            if outputs:
                self.hold_ms.append(elapsed_ms)
        self._status_changed(outputs)  # after the estimate's latency is taken: the markers do not add to it
        return outputs

    def _outputs(self, outputs: list, arrival: float | None) -> None:
        """Count published estimates and their latency (under ``_lock``)."""
        self.counts["estimates"] += len(outputs)
        if outputs:
            self.last = outputs[-1]
            if arrival is not None:
                self.latency_ms.append(1e3 * (self.clock() - arrival))

    def _on_poses(self, poses) -> None:
        """The cameras' poses of a frame set (bars driven by the IMU) to ``publish_poses``; ~/camera_poses is
        rate-limited by the frame stamps (``camera_poses_rate_hz``) and needs every camera."""
        rate = self.config.camera_poses_rate_hz
        stamp = float(poses.stamps[0])
        due = rate > 0 and len(poses.cameras) == self.rig.num_cameras and \
            (stamp - self._poses_stamp >= 1.0 / rate or stamp < self._poses_stamp)
        if due:
            self._poses_stamp = stamp
        self._publish(self.publish_poses, FramePosesOutput(poses, due))

    def _status_changed(self, outputs: list) -> None:
        """Hand the rig's state to ``publish_status`` after an estimate or when it changed (not per frame)."""
        if self.publish_status is None:
            return
        with self._status_lock:
            status = self.runner.pipeline.status()
            if status.state is RigState.WAITING:  # no frame set yet (a fresh pipeline): nothing to show
                return
            if outputs or status.state != getattr(self._status, "state", None) or status.hold != self._status.hold:
                self._status = status
                self._publish(self.publish_status, status, outputs[-1] if outputs else self.last)

    def _publish(self, publish, *args) -> None:
        """Publish, unless the service stops: an estimate abandoned at shutdown may end after the node's
        context is gone, and must not fail then."""
        try:
            publish(*args)
        except Exception:  # noqa: BLE001 - a publisher destroyed at shutdown
            if not self._stop.is_set():
                raise

    def _output(self, est) -> HoldOutput:
        return hold_output(est, self.rig, self.frames, est.ref_hold_index)

    # ------------------------------------------------------------------ reports (frontend/diagnostics.py)
    def diagnostics(self) -> list:
        """One :class:`~nrmpc_ros.frontend.diagnostics.Status` per part: cameras, IMU, estimation (called by the
        node's timer)."""
        return self.reports.statuses()

    def diagnostic_fields(self, node_name: str) -> dict:
        """:meth:`diagnostics` as the fields of a diagnostic_msgs/DiagnosticArray (one status per part, named
        ``<node name>: <part>``, hardware_id the body frame)."""
        return self.reports.fields(node_name)

    def summary(self) -> str:
        """The shutdown summary: what came in, what was estimated, every drop by reason."""
        return self.reports.summary()

__all__ = ["ERROR", "EstimatorService", "HoldQueue", "OK", "Status", "WARN", "WorkQueue"]
