"""Everything the ``estimator`` node does that needs no ROS: its settings, inputs, worker, outputs and reports.

The node (``nrmpc_ros.node``) only turns ROS messages, parameters, timers and
services into calls of :class:`EstimatorService` and its outputs into
messages. Here:

- :class:`NodeConfig`: the node's parameters, each with its documentation and
  range; ``pipeline.*`` come from :class:`~nrmpc_ros.frontend.pipeline.PipelineConfig`
  (:func:`parameter_fields`, :func:`configs_from_parameters`);
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
import sys
import textwrap
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from pathlib import Path

from ..config import FieldInfo, describe_fields, from_mapping, option
from ..core.rig import Rig
from ..errors import InputError
from .camera_info import camera_info_mismatch
from .droplog import DropLog
from .feeder import Feeder, FeederConfig, Work
from .liveness import CameraWatch
from .outputs import FrameNames, HoldOutput, hold_output
from .pipeline import PIPELINE_METHODS, PipelineConfig
from .runner import PipelineRunner
from .topics import choose_transport, compressed_topic

TRANSPORTS = ("auto", "raw", "compressed")
OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels
PACKAGE = "nrmpc_ros"


@dataclass
class NodeConfig:
    """Parameters of the ``estimator`` node besides ``pipeline.*`` (docs: README, "The ROS 2 node")."""

    rig_file: str = option("", "rig YAML file (cameras, topics, bars, IMU mount); required. A relative path is "
                           "looked up in the working directory, then in share/nrmpc_ros and its config/")
    method: str = option("auto", "auto: 4pt-bending for holds with IMU gravity, 6pt-bending for the others; or "
                         "one method for all holds (a change at run time starts a new sequence)",
                         choices=PIPELINE_METHODS)
    use_imu: bool = option(True, "subscribe to the IMU when the rig file has an imu block")
    imu_topic: str = option("", "sensor_msgs/Imu topic; empty: the rig file's imu.topic")
    image_transport: str = option("auto", "auto: raw sensor_msgs/Image on each camera's image topic if that is "
                                  "published, else CompressedImage on <topic>/compressed (looked at until the "
                                  "camera's first image); raw; compressed", choices=TRANSPORTS)
    image_queue_size: int = option(10, "depth of each image subscription (messages)", lo=1, hi=10000)
    imu_queue_size: int = option(400, "depth of the IMU subscription (samples; 2 s at 200 Hz)", lo=1, hi=1000000)
    work_queue_size: int = option(8, "frame sets waiting for the estimator; sets arriving while it is full are "
                                  "dropped and counted", lo=1, hi=100000)
    camera_timeout_s: float = option(2.0, "a camera silent this long while another publishes is reported stopped; "
                                     "every camera silent this long: the input ended and the open hold is "
                                     "estimated (s)", lo=0.0, hi=3600.0, lo_open=True)
    diagnostics_period_s: float = option(1.0, "period of /diagnostics (s)", lo=0.0, hi=3600.0, lo_open=True)
    log_every_s: float = option(10.0, "dropped inputs of one kind after the first are logged as a count at most "
                                "this often (s)", lo=0.0, hi=86400.0, lo_open=True)
    origin_frame: str = option("", "frame_id of ~/pose: the sequence origin (the first hold's body frame, level "
                               "once gravity is known); empty: <body_frame>_origin")
    camera_frame_suffix: str = option("_optical", "TF frame of camera NAME: NAME + this suffix (OpenCV axes)")
    publish_tf: bool = option(True, "publish body -> camera frames (bent extrinsics) on /tf for every hold")
    input: FeederConfig = option(FeederConfig(), "stamps, frame grouping and IMU order")


# Parameters every node has, and prefixes of parameters ROS itself declares.
ROS_PARAMETERS = ("use_sim_time", "start_type_description_service")
ROS_PREFIXES = ("qos_overrides.",)


def _is_parameter(value) -> bool:
    return isinstance(value, (bool, int, float, str))


def parameter_fields() -> list:
    """Every parameter of the node: :class:`NodeConfig`'s, then ``pipeline.*`` (settable fields only)."""
    fields = describe_fields(NodeConfig) + describe_fields(PipelineConfig, "pipeline.")
    return [f for f in fields if _is_parameter(f.default)]


def unknown_parameters(names) -> list:
    """The names that are neither a parameter of the node nor one ROS declares, sorted."""
    known = {f.name for f in parameter_fields()} | set(ROS_PARAMETERS)
    return sorted(n for n in names if n not in known and not n.startswith(ROS_PREFIXES))


def configs_from_parameters(values: dict) -> tuple:
    """(NodeConfig, PipelineConfig) from flat dotted parameter values; InputError naming the parameter."""
    nested: dict = {}
    for name, value in values.items():
        *head, last = name.split(".")
        d = nested
        for h in head:
            d = d.setdefault(h, {})
        d[last] = value
    pipeline = nested.pop("pipeline", {})
    node = from_mapping(NodeConfig, nested, "parameters")
    if not node.rig_file:
        raise InputError("parameter rig_file", "required (e.g. --ros-args -p rig_file:=config/sample_cross4.yaml or "
                                               "--params-file config/estimator.yaml)")
    return node, from_mapping(PipelineConfig, pipeline, "parameters", "pipeline.")


def describe_parameter(f: FieldInfo) -> str:
    """One line: the documentation with the allowed values."""
    if f.choices:
        return f"{f.doc} (one of: {', '.join(map(str, f.choices))})"
    lo, hi = (None if v is None else str(v) if isinstance(v, int) else f"{v:g}" for v in (f.lo, f.hi))
    if lo is not None and hi is not None:
        return f"{f.doc} (range [{lo}, {hi}])"
    if lo is not None or hi is not None:
        return f"{f.doc} ({'>= ' + lo if lo is not None else '<= ' + hi})"
    return f.doc


def parameter_range(f: FieldInfo):
    """("float" | "int", lo, hi) of a numeric parameter with a range, open ends at the type's limits; else None."""
    if (f.lo, f.hi) == (None, None) or isinstance(f.default, bool) or not isinstance(f.default, (int, float)):
        return None
    if isinstance(f.default, float):
        return "float", float("-inf" if f.lo is None else f.lo), float("inf" if f.hi is None else f.hi)
    return "int", int(-2**63 if f.lo is None else f.lo), int(2**63 - 1 if f.hi is None else f.hi)


def parameter_descriptor(f: FieldInfo) -> dict:
    """The fields of the field's rcl_interfaces/ParameterDescriptor: description, read-only (all but
    ``method``), numeric range."""
    d = {"description": describe_parameter(f), "read_only": f.name != "method"}
    kind, lo, hi = parameter_range(f) or (None, None, None)
    if kind == "float":
        d["floating_point_range"] = [{"from_value": lo, "to_value": hi, "step": 0.0}]
    elif kind == "int":
        d["integer_range"] = [{"from_value": lo, "to_value": hi, "step": 1}]
    return d


def parameters_help() -> list:
    """Lines of ``estimator --help`` for the parameters."""
    lines = []
    for f in parameter_fields():
        lines.append(f"  {f.name} [default {f.default!r}]")
        lines.append(f"      {describe_parameter(f)}")
    return lines


TOPICS = ("~/pose (geometry_msgs/PoseWithCovarianceStamped, origin frame), ~/relative_pose (geometry_msgs/"
          "PoseStamped, the reference hold's body frame) with ~/relative_pose_reference (std_msgs/Header), ~/gravity "
          "(geometry_msgs/Vector3Stamped) and ~/gravity_covariance (geometry_msgs/AccelWithCovarianceStamped), "
          "~/attitude (sensor_msgs/Imu: roll, pitch), ~/camera_poses (geometry_msgs/PoseArray), all in the body "
          "frame but the first two; /tf, /diagnostics; service ~/reset (std_srvs/Trigger)")


def usage() -> str:
    """The text of ``estimator --help``."""
    about = ("ROS 2 node 'estimator' of nrmpc_ros: pose and gravity of a non-rigid multi-camera rig over holds. "
             "Subscribes to the rig file's image topics (sensor_msgs/Image or CompressedImage), their camera_info "
             f"and, optionally, sensor_msgs/Imu; publishes {TOPICS}.")
    return "\n".join([
        "usage: estimator [--help] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] [-r FROM:=TO ...]]", "",
        textwrap.fill(about, 110), "",
        "example: estimator --ros-args --params-file config/estimator.yaml -r __ns:=/rig1", "", "parameters:",
        *parameters_help()])


def user_arguments(argv: list) -> list:
    """Arguments outside any ``--ros-args ... [--]`` section."""
    out, in_ros = [], False
    for a in argv:
        in_ros = True if a == "--ros-args" else False if a == "--" and in_ros else in_ros
        if not in_ros and a != "--":
            out.append(a)
    return out


def command_line(argv: list, ros_error: str | None = None) -> int | None:
    """``--help`` printed (0), bad arguments or no ROS reported (2), or None: start the node."""
    user = user_arguments(argv)
    if "-h" in user or "--help" in user:
        print(usage())
        return 0
    if user or ros_error:
        why = f"unknown arguments {' '.join(user)} (parameters go after --ros-args; see --help)" if user else ros_error
        print(f"estimator: error: {why}", file=sys.stderr)
        return 2
    return None


def imu_topic(rig: Rig, config: NodeConfig) -> tuple:
    """(the IMU topic to subscribe or None, a warning or None)."""
    if rig.imu is None:
        warn = (f"imu_topic {config.imu_topic} is set but the rig file {rig.source} has no imu block (the IMU's "
                "mount is unknown): not subscribing to the IMU") if config.use_imu and config.imu_topic else None
        return None, warn
    return (config.imu_topic or rig.imu.topic) if config.use_imu else None, None


def transport(topic: str, how: str, graph: dict, resolve) -> tuple:
    """(topic to subscribe, compressed?) for a rig file's image ``topic`` with ``image_transport`` ``how``, the
    graph's topics and types, and the node's ``resolve(name, only_expand=False)`` (expansion and remapping).

    The compressed topic follows the image topic (a remap of ``cam0/image_raw`` moves both, as image_transport
    does) unless ``<topic>/compressed`` is remapped itself."""
    base, comp = resolve(topic), compressed_topic(topic)
    compressed = resolve(comp) if resolve(comp) != resolve(comp, only_expand=True) else compressed_topic(base)
    if how == "auto":
        return choose_transport(base, graph, compressed)
    return (compressed, True) if how == "compressed" else (base, False)


def share_directories() -> list:
    """Where installed files of the package may be: the ament index, the Python prefix, the source tree."""
    out = []
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        try:
            out.append(Path(get_package_share_directory(PACKAGE)))
        except (PackageNotFoundError, LookupError, ValueError, OSError):  # OSError: no AMENT_PREFIX_PATH
            pass
    except ImportError:
        pass
    out.append(Path(sys.prefix) / "share" / PACKAGE)
    out.append(Path(__file__).resolve().parents[2])  # a source checkout (pip install -e)
    return list(dict.fromkeys(out))


def find_file(path: str, what: str, shares: list | None = None) -> Path:
    """``path`` as given (absolute), else in the working directory, else in each share directory (default:
    :func:`share_directories`) and its config/; InputError naming ``what`` and every place looked in."""
    p = Path(path).expanduser()
    candidates = [p] if p.is_absolute() else [Path.cwd() / p]
    if not p.is_absolute():
        for share in share_directories() if shares is None else shares:
            candidates += [share / p, share / "config" / p.name]
    candidates = list(dict.fromkeys(candidates))
    for c in candidates:
        if c.is_file():
            return c
    raise InputError(what, f"no such file: {path} (looked for {', '.join(map(str, candidates))})")


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


__all__ = ["ERROR", "EstimatorService", "NodeConfig", "OK", "Status", "TRANSPORTS", "WARN", "WorkQueue",
           "command_line", "configs_from_parameters", "describe_parameter", "find_file", "imu_topic",
           "parameter_descriptor", "parameter_fields", "parameter_range", "parameters_help", "share_directories",
           "transport", "unknown_parameters", "usage", "user_arguments"]
