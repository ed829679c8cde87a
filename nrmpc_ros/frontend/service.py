"""Everything the ``estimator`` node does at run time that needs no ROS: inputs, worker, outputs, reports.

The node (``nrmpc_ros.node``) only turns ROS messages, timers and services
into calls of :class:`EstimatorService` and its outputs into messages; its
settings are :mod:`nrmpc_ros.frontend.node_config`. Here:

- inputs: a :class:`~nrmpc_ros.frontend.feeder.Feeder` (the same input policy
  as ``nrmpc replay``) hands work to a bounded queue; frame sets arriving
  while it is full are dropped and counted;
- the worker thread runs the queue through a
  :class:`~nrmpc_ros.frontend.runner.PipelineRunner` and hands a
  :class:`~nrmpc_ros.frontend.outputs.HoldOutput` per hold estimate to
  ``publish``;
- reports: camera liveness, rate-limited drop logs, the diagnostics per part
  (cameras, IMU, estimation) and the shutdown summary.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass

from ..core.rig import Rig
from .camera_info import camera_info_mismatch
from .droplog import DropLog
from .feeder import Feeder, Work
from .liveness import CameraWatch
from .node_config import NodeConfig
from .outputs import FrameNames, HoldOutput, hold_output
from .pipeline import PIPELINE_METHODS, PipelineConfig
from .runner import PipelineRunner

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels


class WorkQueue:
    """Work for the worker thread: ``put`` never blocks; a frame set is refused while ``max_frames`` wait."""

    def __init__(self, max_frames: int, max_items: int = 200000):
        self.max_frames = int(max_frames)
        self.max_items = int(max_items)
        self._items: deque = deque()
        self._frames = 0
        self._cv = threading.Condition()

    def put(self, work: Work) -> bool:
        with self._cv:
            frames = work.kind == "frames"
            if (frames and self._frames >= self.max_frames) or len(self._items) >= self.max_items:
                return False
            self._items.append(work)
            self._frames += frames
            self._cv.notify()
            return True

    def get(self, timeout: float):
        with self._cv:
            if not self._items:
                self._cv.wait(timeout)
            if not self._items:
                return None
            work = self._items.popleft()
            self._frames -= work.kind == "frames"
            return work

    def frames(self) -> int:
        with self._cv:
            return self._frames

    def __len__(self) -> int:
        with self._cv:
            return len(self._items)


@dataclass
class Status:
    """One diagnostic_msgs/DiagnosticStatus: part name, level (OK / WARN / ERROR), message, key-values."""

    name: str
    level: int
    message: str
    values: dict


def _median(values) -> str:
    return f"{statistics.median(values):.1f}" if values else ""


class EstimatorService:
    """The node without ROS (see the module docstring).

    ``camera_topics`` and ``imu_topic`` are the input topics as the node resolved them (after remapping; None:
    no IMU); ``publish(HoldOutput)`` is called from the worker thread; ``log(level, line)`` with level "info",
    "warn" or "error" from either thread. ``clock`` gives arrival times (monotonic seconds).
    """

    def __init__(self, rig: Rig, config: NodeConfig, pipeline_config: PipelineConfig, camera_topics: list,
                 imu_topic: str | None, publish, log, clock=time.monotonic):
        self.rig, self.config = rig, config
        self.camera_topics, self.imu_topic = list(camera_topics), imu_topic
        self.publish, self.log, self.clock = publish, log, clock
        self.drops = DropLog(config.log_every_s, clock)
        self.queue = WorkQueue(config.work_queue_size)
        self.feeder = Feeder(rig, config.input, self._put, self.drops, self.camera_topics, imu_topic, log, clock)
        self.runner = PipelineRunner(rig, pipeline_config, config.method, self.drops, catch=True, log=log)
        self.stats = self.runner.stats  # a copy the worker renews after each work item (the timer reads it)
        self.watch = CameraWatch(self.camera_topics, config.camera_timeout_s)
        self.frames = FrameNames(rig.body_frame, config.origin_frame or f"{rig.body_frame}_origin",
                                 tuple(c.name + config.camera_frame_suffix for c in rig.cameras))
        self.received: Counter = Counter()
        self.camera_info: dict = {}  # camera index -> "agrees with the rig file" or what differs
        self.counts: Counter = Counter()
        self.latency_ms: deque = deque(maxlen=500)
        self.process_ms: deque = deque(maxlen=500)
        self.last: HoldOutput | None = None
        self._holds: dict = {}  # sequence -> {stamp: hold index} (reference frame names)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._running = False  # the worker is on a work item
        self._reported: dict = {}  # part -> drop count at the last diagnostics
        self._rates: dict = {}  # topic -> (count, clock) at the last diagnostics

    # ------------------------------------------------------------------ inputs (the node's executor thread)
    def on_image(self, index: int, msg, now: float | None) -> None:
        """An image message of camera ``index``; ``now`` is the node's clock (s), None while it does not run."""
        for level, line in self.watch.seen(index, self.clock()):
            self.log(level, line)
        self.received[self.camera_topics[index]] += 1
        self._guarded(self.camera_topics[index], self.feeder.image, index, msg, now)

    def on_imu(self, msg, now: float | None) -> None:
        self.received[self.imu_topic] += 1
        self._guarded(self.imu_topic, self.feeder.imu_msg, msg, now)

    def _guarded(self, source: str, fn, *args) -> None:
        """Run an input step; a failure (a bug, not bad input: that is dropped on its own) is counted and logged,
        and the node goes on."""
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - the node must outlive it
            line = self.drops.drop(source, "input failed", f"{source}: handling a message failed: "
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
        self.feeder.reset(why)
        self.counts["resets"] += 1
        return f"a new sequence starts with the next hold ({why})"

    def set_method(self, method: str) -> str | None:
        """A new method from the next hold on (the open hold is estimated first; a new sequence starts); returns
        why not when ``method`` is not one."""
        if method not in PIPELINE_METHODS:
            return f"parameter method: must be one of {', '.join(PIPELINE_METHODS)}, got {method!r}"
        self.feeder.end()
        self._put(Work("method", data=method))
        self.log("info", f"method {method} from the next hold on (a new sequence)")
        return None

    def tick(self) -> None:
        """Timer: camera liveness (the end of the input flushes the open hold) and the drop counts due."""
        for level, line in self.watch.check(self.clock()):
            if level == "ended":
                self.log("info", line)
                self.feeder.end()
            else:
                self.log(level, line)
        for line in self.drops.due():
            self.log("warn", line)

    def _put(self, work: Work) -> None:
        if not self.queue.put(work):
            what = "frame set" if work.kind == "frames" else f"{work.kind} item"
            line = self.drops.drop("worker", f"{what} dropped while the estimator is busy",
                                   f"{what} at {work.stamp:.3f} s dropped while the estimator is busy: "
                                   f"{self.queue.frames()} frame sets wait (work_queue_size "
                                   f"{self.config.work_queue_size})")
            if line:
                self.log("warn", line)

    # ------------------------------------------------------------------ worker thread
    def start(self) -> None:
        self._thread = threading.Thread(target=self._work_loop, name="nrmpc-estimator", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(timeout)

    def _work_loop(self) -> None:
        while not self._stop.is_set():
            self.work_once(0.1)

    def work_once(self, timeout: float = 0.0) -> list:
        """Run one work item (waiting up to ``timeout`` s for one); publish and return its outputs."""
        work = self.queue.get(timeout)
        if work is None:
            return []
        self._running = True
        try:
            if work.kind == "method":
                self.runner.restart(f"method {work.data}", work.data)
                return []
            t0 = time.perf_counter()
            estimates = self.runner.run(work)
            elapsed_ms = 1e3 * (time.perf_counter() - t0)
            outputs = [self._output(est) for est in estimates]
            for out in outputs:
                self.publish(out)
        finally:
            self._running = False
        stats = self.runner.stats
        with self._lock:
            self.stats = stats
            if work.kind == "frames":
                self.counts["processed frame sets"] += 1
                self.process_ms.append(elapsed_ms)
                if outputs:
                    self.latency_ms.append(1e3 * (self.clock() - work.data[1]))
            self.counts["estimates"] += len(outputs)
            if outputs:
                self.last = outputs[-1]
        return outputs

    def _output(self, est) -> HoldOutput:
        holds = self._holds.setdefault(est.sequence, {est.origin_stamp: 0})
        holds[est.stamp] = est.hold_index
        while len(self._holds) > 4:  # only recent sequences are referred to
            del self._holds[min(self._holds)]
        return hold_output(est, self.rig, self.frames, holds.get(est.ref_stamp))

    # ------------------------------------------------------------------ reports
    def _rate(self, topic: str, now: float) -> float:
        n = self.received[topic]
        n0, t0 = self._rates.get(topic, (n, now))
        self._rates[topic] = (n, now)
        return (n - n0) / (now - t0) if now > t0 else 0.0

    def _drops_of(self, sources) -> tuple:
        counts = {k: v for k, v in self.drops.counts().items() if k[0] in sources}
        return sum(counts.values()), {f"dropped: {s}: {r}": n for (s, r), n in sorted(counts.items())}

    def _new_drops(self, part: str, total: int) -> int:
        new = total - self._reported.get(part, 0)
        self._reported[part] = total
        return new

    def diagnostics(self) -> list:
        """One :class:`Status` per part: cameras, IMU, estimation (called by the node's timer)."""
        now = self.clock()
        return [self._camera_status(now), self._imu_status(now), self._estimation_status()]

    def diagnostic_fields(self, node_name: str) -> dict:
        """:meth:`diagnostics` as the fields of a diagnostic_msgs/DiagnosticArray (one status per part, named
        ``<node name>: <part>``, hardware_id the body frame)."""
        return {"status": [{"level": bytes([s.level]), "name": f"{node_name}: {s.name}", "message": s.message,
                            "hardware_id": self.rig.body_frame,
                            "values": [{"key": k, "value": str(v)} for k, v in s.values.items()]}
                           for s in self.diagnostics()]}

    def _camera_status(self, now: float) -> Status:
        values = {}
        for i, topic in enumerate(self.camera_topics):
            values[f"{topic}: images"] = self.received[topic]
            values[f"{topic}: rate (Hz)"] = f"{self._rate(topic, now):.2f}"
            values[f"{topic}: state"] = "input ended" if self.watch.ended is not None else self.watch.state[i]
            values[f"{topic}: camera_info"] = self.camera_info.get(i, "none received")
        total, dropped = self._drops_of(set(self.camera_topics))
        values.update(dropped)
        values["frame sets"] = self.feeder.events["frame sets"]
        values["frame grouping"] = self.feeder.sync.describe()
        new = self._new_drops("cameras", total)
        silent = self.watch.silent()
        if silent:
            level, message = WARN, f"no images from {', '.join(silent)}"
        elif new:
            level, message = WARN, f"{new} images dropped in the last period (see dropped: *)"
        elif self.watch.ended is not None:
            level, message = OK, f"the input ended {now - self.watch.ended:.0f} s ago"
        elif self.watch.first_any is None:
            level, message = OK, "waiting for the first images"
        else:
            level, message = OK, f"{len(self.camera_topics)} cameras publishing"
        return Status("cameras", level, message, values)

    def _imu_status(self, now: float) -> Status:
        if self.imu_topic is None:
            why = "the rig file has no imu block" if self.rig.imu is None else "use_imu is false"
            return Status("IMU", OK, f"no IMU ({why}): vision only", {})
        topic = self.imu_topic
        total, dropped = self._drops_of({topic})
        values = {"topic": topic, "samples": self.received[topic], "rate (Hz)": f"{self._rate(topic, now):.2f}",
                  **dropped}
        new = self._new_drops("imu", total)
        if new:
            level, message = WARN, f"{new} IMU samples dropped in the last period (see dropped: *)"
        elif not self.received[topic] and self.watch.first_any is not None:
            level, message = WARN, f"no IMU sample on {topic} yet while the cameras publish"
        else:
            level, message = OK, f"{self.received[topic]} samples"
        return Status("IMU", level, message, values)

    def _estimation_status(self) -> Status:
        with self._lock:
            counts, last, st = dict(self.counts), self.last, self.stats
            latency, process = list(self.latency_ms), list(self.process_ms)
        values = {"method": self.config.method, "frame sets processed": counts.get("processed frame sets", 0),
                  "frame sets waiting": self.queue.frames(), "work waiting": len(self.queue) + self._running,
                  "holds": st.holds,
                  "estimates": counts.get("estimates", 0), "time jumps back": self.feeder.events["time jumps back"],
                  "resets": counts.get("resets", 0), "latency median (ms)": _median(latency),
                  "processing median (ms)": _median(process)}
        values.update({f"methods: {m}": n for m, n in sorted(st.methods.items())})
        values.update({f"not estimated: {k}": n for k, n in sorted(st.dropped.items())})
        inputs = set(self.camera_topics) | {self.imu_topic}
        total, dropped = self._drops_of({s for s, _ in self.drops.counts()} - inputs)
        values.update(dropped)
        if last is not None:
            e = last.estimate
            values.update({"last: stamp": f"{e.stamp:.6f}", "last: sequence": e.sequence, "last: hold": e.hold_index,
                           "last: method": e.method, "last: gravity sigma (deg)": f"{e.gravity_sigma_deg:.3f}",
                           "last: inliers": e.num_inliers})
        failed = sum(n for (s, r), n in self.drops.counts().items() if r == "estimation failed")
        if self._new_drops("failed", failed):
            level, message = ERROR, "estimation failed (see dropped: pipeline: *)"
        elif self._new_drops("estimation", total):
            level, message = WARN, "frame sets dropped in the last period (see dropped: *)"
        elif last is not None:
            e = last.estimate
            level, message = OK, (f"sequence {e.sequence}, hold {e.hold_index}: {e.method}, gravity +-"
                                  f"{e.gravity_sigma_deg:.2f} deg")
        else:
            level, message = OK, "waiting for holds"
        return Status("estimation", level, message, values)

    def summary(self) -> str:
        """The shutdown summary: what came in, what was estimated, every drop by reason."""
        with self._lock:
            counts, latency, st = dict(self.counts), list(self.latency_ms), self.stats
        images = sum(self.received[t] for t in self.camera_topics)
        imu = self.received[self.imu_topic] if self.imu_topic else 0
        return (f"{images} images, {imu} IMU samples; {self.feeder.events['frame sets']} frame sets, "
                f"{counts.get('processed frame sets', 0)} processed; {st.holds} holds, "
                f"{counts.get('estimates', 0)} estimates; {self.feeder.events['time jumps back']} time jumps back; "
                f"median latency {_median(latency) or 'n/a'} ms; dropped: {self.drops.summary()}")


__all__ = ["ERROR", "EstimatorService", "OK", "Status", "WARN", "WorkQueue"]
