"""The ROS 2 node ``estimator`` (SPEC section 10); the only module of nrmpc_ros that imports rclpy.

One sensor_msgs/Image (or CompressedImage) subscription per camera of the rig
file, sensor-data QoS, synchronized by stamp with the shared
:class:`~nrmpc_ros.frontend.sync.StampSynchronizer`; optional sensor_msgs/Imu.
Callbacks only decode, check and hand over: estimation runs in a worker
thread fed by a bounded queue, and synchronized sets arriving while it is
full are dropped and counted. Publishes ``~/relative_pose``
(geometry_msgs/PoseStamped: the current body frame in the reference view's
body frame), ``~/gravity`` (geometry_msgs/Vector3Stamped, current body frame,
m/s^2; the pair's own, or the fused one when the pair's is weak or outvoted:
see ``gravity_source`` in the diagnostics), ``~/gravity_fused`` (the fused estimate, same frame), ``~/attitude``
(sensor_msgs/Imu with roll and pitch only) and diagnostics on ``/diagnostics``.

Run ``estimator --help`` for the parameters.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import queue
import statistics
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .core.estimators import METHODS
from .core.rig import Rig, load_rig
from .core.so3 import matrix_to_quat_xyzw
from .errors import ROS_EXTRA_HINT, InputError, NrmpcError

try:  # rclpy is optional for the package; --help works without it
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import PoseStamped, Vector3Stamped
    from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
    from rclpy.exceptions import InvalidParameterTypeException
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, qos_profile_sensor_data
    from sensor_msgs.msg import CompressedImage, Image, Imu

    _RCLPY_ERROR = None
except ImportError as _exc:  # pragma: no cover - exercised only without ROS
    rclpy = None
    Node = object
    _RCLPY_ERROR = _exc

NODE_NAME = "estimator"
MODES = ("auto",) + tuple(METHODS)
TRANSPORTS = ("raw", "compressed")



@dataclass(frozen=True)
class ParamSpec:
    """A node parameter: name, default, description and (optionally) the allowed values."""

    name: str
    default: object
    description: str
    choices: tuple = ()
    read_only: bool = True


# Node parameters; the pipeline's (tracking, pairing, ...) follow as ``pipeline.<field>``.
NODE_PARAMETERS = (
    ParamSpec("rig_file", "", "rig YAML file (SPEC section 7): cameras, topics, bars, IMU; required. A relative "
              "path is looked up in the working directory, then in share/nrmpc_ros"),
    ParamSpec("method", "auto", "auto: 4pt-bending while IMU samples arrive within imu_max_age_s of the images, "
              "6pt-bending otherwise; or force one method (may be changed at run time)", MODES, read_only=False),
    ParamSpec("sync_tolerance_s", 0.01, "largest stamp difference (s) between the images of one synchronized set"),
    ParamSpec("queue_size", 10, "per-camera depth of the image subscriptions and of the stamp synchronizer"),
    ParamSpec("work_queue_size", 2, "synchronized sets waiting for the estimator (1 or 2); sets arriving while "
              "it is full are dropped and counted"),
    ParamSpec("imu_topic", None, "sensor_msgs/Imu topic; default: the rig file's imu.topic; empty: no IMU"),
    ParamSpec("imu_queue_size", 400, "depth of the IMU subscription (samples; 2 s at 200 Hz)"),
    ParamSpec("imu_max_age_s", 0.5, "auto mode uses 4pt-bending while the newest IMU sample is at most this "
              "much older (s, by stamp) than the images"),
    ParamSpec("image_transport", "raw", "raw: sensor_msgs/Image on each image_topic; compressed: "
              "sensor_msgs/CompressedImage on image_topic + '/compressed'", TRANSPORTS),
    ParamSpec("camera_timeout_s", 2.0, "a camera silent this long while the node runs is reported as stopped"),
    ParamSpec("diagnostics_period_s", 1.0, "period (s) of the /diagnostics message"),
)


def pipeline_parameters() -> tuple:
    """``pipeline.<field>`` parameters from the fields of PipelineConfig (nested configs flattened with dots)."""
    from .frontend.pipeline import PipelineConfig

    return tuple(_flatten_config(PipelineConfig(), "pipeline"))


def _flatten_config(cfg, prefix: str):
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        name = f"{prefix}.{f.name}"
        if dataclasses.is_dataclass(value):
            yield from _flatten_config(value, name)
            continue
        if f.name == "estimator" and isinstance(value, dict):  # EstimatorOptions as a mapping
            from .core.estimators import EstimatorOptions

            yield from _flatten_config(dataclasses.replace(EstimatorOptions(), **value), name)
            continue
        if isinstance(value, tuple):
            value = list(value)
        if not _ros_representable(value):
            continue  # not settable from a params file
        doc = _field_comments(type(cfg)).get(f.name, "")
        block = _BLOCKS.get(prefix.rsplit(".", 1)[-1], "pipeline setting")
        yield ParamSpec(name, value, f"{block}: {doc}" if doc else f"{block} ({type(cfg).__name__}.{f.name})")


_BLOCKS = {"tracking": "feature tracking and matching", "static": "static-view detection",
           "imu": "IMU averaging (pipeline)", "estimator": "estimator option", "pipeline": "pairing"}


def _field_comments(cls) -> dict:
    """The ``# comment`` after each field of a dataclass's source: the documentation of its parameter."""
    import inspect
    import re

    try:
        src = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    return {m.group(1): m.group(2).strip() for m in re.finditer(r"^\s+(\w+)\s*:[^=\n]+=[^#\n]*#\s*(.+)$", src, re.M)}


def _ros_representable(value) -> bool:
    if isinstance(value, (bool, int, float, str)):
        return True
    if isinstance(value, list) and value:
        kinds = {bool if isinstance(v, bool) else int if isinstance(v, int) else type(v) for v in value}
        return len(kinds) == 1 and next(iter(kinds)) in (bool, int, float, str)
    return False


def build_pipeline_config(values: dict):
    """A PipelineConfig from flattened ``pipeline.*`` parameter values (unknown keys are an InputError)."""
    from .frontend.pipeline import PipelineConfig

    return _unflatten(PipelineConfig(), values, "pipeline")


def _unflatten(cfg, values: dict, prefix: str):
    changes = {}
    for f in dataclasses.fields(cfg):
        current = getattr(cfg, f.name)
        name = f"{prefix}.{f.name}"
        if dataclasses.is_dataclass(current):
            changes[f.name] = _unflatten(current, values, name)
        elif f.name == "estimator" and isinstance(current, dict):
            from .core.estimators import EstimatorOptions

            opts = _unflatten(dataclasses.replace(EstimatorOptions(), **current), values, name)
            changes[f.name] = {k: v for k, v in dataclasses.asdict(opts).items() if v != getattr(EstimatorOptions, k)}
        elif name in values:
            v = values[name]
            if isinstance(current, tuple):
                v = tuple(v)
            elif isinstance(current, float) and isinstance(v, int):
                v = float(v)
            changes[f.name] = v
    return dataclasses.replace(cfg, **changes)


# --------------------------------------------------------------------------- pure logic (no rclpy)
class MethodSelector:
    """Chooses the estimator for each synchronized set.

    In ``auto`` mode: ``4pt-bending`` while the newest IMU sample is at most
    ``max_age_s`` older than the images (by stamp), ``6pt-bending`` otherwise.
    :meth:`select` returns the method and, only when it changed, a message
    saying why (so each switch is logged once).
    """

    def __init__(self, mode: str = "auto", max_age_s: float = 0.5, imu_enabled: bool = True):
        if mode not in MODES:
            raise InputError("parameter method", f"'{mode}' is not one of {', '.join(MODES)}")
        self.mode = mode
        self.max_age_s = float(max_age_s)
        self.imu_enabled = imu_enabled
        self.last_imu_stamp: float | None = None
        self.current: str | None = None
        self.switches = 0

    def imu_sample(self, stamp: float) -> None:
        if self.last_imu_stamp is None or stamp > self.last_imu_stamp:
            self.last_imu_stamp = float(stamp)

    def imu_age(self, now: float) -> float:
        return math.inf if self.last_imu_stamp is None else now - self.last_imu_stamp

    def select(self, now: float) -> tuple[str, str | None]:
        if self.mode != "auto":
            method, why = self.mode, f"method forced to {self.mode}"
        elif not self.imu_enabled:
            method, why = "6pt-bending", "no IMU topic configured: using 6pt-bending"
        else:
            age = self.imu_age(now)
            if age <= self.max_age_s:
                method, why = "4pt-bending", f"IMU samples arriving (age {age:.3f} s): using 4pt-bending"
            elif self.last_imu_stamp is None:
                method, why = "6pt-bending", "no IMU sample yet: using 6pt-bending"
            else:
                method, why = "6pt-bending", (f"newest IMU sample is {age:.2f} s old (> imu_max_age_s "
                                              f"{self.max_age_s:g}): falling back to 6pt-bending")
        if method == self.current:
            return method, None
        if self.current is not None:
            self.switches += 1
        self.current = method
        return method, why


class DropQueue:
    """Hand-over to the worker: ``put`` never blocks; an item arriving while the queue is full is dropped."""

    def __init__(self, maxsize: int = 1):
        self._q: queue.Queue = queue.Queue(maxsize=max(1, int(maxsize)))
        self.accepted = 0
        self.dropped = 0

    def put(self, item) -> bool:
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1
            return False
        self.accepted += 1
        return True

    def get(self, timeout: float):
        try:
            return self._q.get(timeout=timeout)
        except queue.Empty:
            return None

    def qsize(self) -> int:
        return self._q.qsize()


class ErrorLog:
    """Counts bad input per (topic, kind) and says when a message must be logged (the first time only)."""

    def __init__(self):
        self.counts: collections.Counter = collections.Counter()
        self.last: dict = {}

    def report(self, topic: str, kind: str, message: str) -> bool:
        key = (topic, kind)
        self.counts[key] += 1
        self.last[topic] = message
        return self.counts[key] == 1

    def per_topic(self) -> dict:
        out: collections.Counter = collections.Counter()
        for (topic, _), n in self.counts.items():
            out[topic] += n
        return dict(out)


class RateMeter:
    """Message rate over the last diagnostics period."""

    def __init__(self):
        self.count = 0
        self._last_count = 0
        self._last_time: float | None = None

    def tick(self) -> None:
        self.count += 1

    def rate(self, now: float) -> float:
        if self._last_time is None:
            self._last_time, self._last_count = now, self.count
            return 0.0
        dt = now - self._last_time
        r = (self.count - self._last_count) / dt if dt > 0 else 0.0
        self._last_time, self._last_count = now, self.count
        return r


YAW_VARIANCE_UNOBSERVABLE = 1e6  # rad^2: gravity says nothing about yaw


def attitude_message(header, gravity, cov_gravity=None):
    """sensor_msgs/Imu carrying only roll and pitch from fused gravity (body frame x forward, z up).

    Orientation covariance (roll, pitch, yaw about x, y, z; rad^2) from the
    gravity covariance, yaw marked unobservable by a very large variance;
    angular velocity and linear acceleration are not provided (-1 in element 0
    of their covariances, as sensor_msgs/Imu documents).
    """
    from .core.fusion import roll_pitch_from_gravity, tangent_covariance

    g = np.asarray(gravity, dtype=float).reshape(3)
    cov_t = None if cov_gravity is None else tangent_covariance(g, np.asarray(cov_gravity, dtype=float))
    _, _, q, cov_rp = roll_pitch_from_gravity(g, cov_t)
    msg = Imu(header=header)
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = (float(v) for v in q)
    cov = np.zeros((3, 3))
    cov[:2, :2] = cov_rp if cov_rp is not None else np.eye(2) * 1e-2
    cov[2, 2] = YAW_VARIANCE_UNOBSERVABLE
    msg.orientation_covariance = [float(v) for v in cov.ravel()]
    msg.angular_velocity_covariance = [-1.0] + [0.0] * 8
    msg.linear_acceleration_covariance = [-1.0] + [0.0] * 8
    return msg


def stamp_to_sec(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _resolve_rig_path(path: str) -> Path:
    p = Path(path).expanduser()
    if p.is_absolute() or p.exists():
        return p
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        share = Path(get_package_share_directory("nrmpc_ros"))
        for candidate in (share / p, share / "config" / p.name):
            if candidate.exists():
                return candidate
    except (ImportError, PackageNotFoundError, LookupError):
        pass
    return p


# --------------------------------------------------------------------------- the node
class EstimatorNode(Node):
    """The ``estimator`` node; ``start_worker=False`` leaves the estimation thread stopped (tests)."""

    def __init__(self, *, start_worker: bool = True, **node_kwargs):
        if rclpy is None:
            raise NrmpcError(f"rclpy is not importable ({_RCLPY_ERROR}); {ROS_EXTRA_HINT}")
        super().__init__(NODE_NAME, **node_kwargs)
        from .frontend.images import decode_image
        from .frontend.pipeline import FrameSet, Pipeline
        from .frontend.sync import StampSynchronizer

        self._decode_image = decode_image
        self._frame_set = FrameSet
        self.params = self._declare_parameters()
        self.rig: Rig = self._load_rig(self.params["rig_file"])
        self.imu_topic = self._declare_imu_topic()
        if self.imu_topic and self.rig.imu is None:
            self.get_logger().warning(f"imu_topic {self.imu_topic} is set but the rig file {self.rig.source} has no "
                                      "imu block (the IMU mounting is unknown): not subscribing to the IMU")
            self.imu_topic = ""
        self.camera_topics = [self._camera_topic(c) for c in self.rig.cameras]
        self.selector = MethodSelector(self.params["method"], self.params["imu_max_age_s"], bool(self.imu_topic))
        self.config = build_pipeline_config(self.pipeline_values)
        initial = self.params["method"] if self.params["method"] != "auto" else (
            "4pt-bending" if self.imu_topic else "6pt-bending")
        self.pipeline = Pipeline(self.rig, self.config, method=initial)
        self.sync = StampSynchronizer(
            len(self.rig.cameras), tolerance_s=self.params["sync_tolerance_s"], queue_size=self.params["queue_size"],
            min_streams=len(self.rig.cameras))
        self.work = DropQueue(self.params["work_queue_size"])
        self.errors = ErrorLog()
        self._imu_buffer: collections.deque = collections.deque(maxlen=20000)
        self._stamp_lookup: collections.OrderedDict = collections.OrderedDict()
        self._lock = threading.Lock()  # guards the counters the worker writes and the timer reads
        self.counters = collections.Counter()
        self.latency_ms: collections.deque = collections.deque(maxlen=500)
        self.process_ms: collections.deque = collections.deque(maxlen=500)
        self.last_estimate = None
        self.last_error = ""
        self._start_time = time.monotonic()
        self._last_rx = [None] * len(self.rig.cameras)
        self._stale = [False] * len(self.rig.cameras)
        self._rates = {t: RateMeter() for t in self.camera_topics + ([self.imu_topic] if self.imu_topic else [])}

        self.pose_pub = self.create_publisher(PoseStamped, "~/relative_pose", 10)
        self.gravity_pub = self.create_publisher(Vector3Stamped, "~/gravity", 10)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.gravity_fused_pub = self.create_publisher(Vector3Stamped, "~/gravity_fused", 10)
        self.attitude_pub = self.create_publisher(Imu, "~/attitude", 10)

        qos = QoSProfile(history=qos_profile_sensor_data.history, depth=int(self.params["queue_size"]),
                         reliability=qos_profile_sensor_data.reliability,
                         durability=qos_profile_sensor_data.durability)
        msg_type = CompressedImage if self.params["image_transport"] == "compressed" else Image
        self._subs = [
            self.create_subscription(msg_type, topic, lambda msg, i=i: self._on_image(i, msg), qos)
            for i, topic in enumerate(self.camera_topics)
        ]
        if self.imu_topic:
            imu_qos = QoSProfile(history=qos_profile_sensor_data.history, depth=int(self.params["imu_queue_size"]),
                                 reliability=qos_profile_sensor_data.reliability,
                                 durability=qos_profile_sensor_data.durability)
            self._subs.append(self.create_subscription(Imu, self.imu_topic, self._on_imu, imu_qos))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._timer = self.create_timer(self.params["diagnostics_period_s"], self._on_timer)

        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._work_loop, name="nrmpc-estimator", daemon=True)
        if start_worker:
            self._worker.start()
        self.get_logger().info(
            f"rig {self.rig.source}: {len(self.rig.cameras)} cameras on {', '.join(self.camera_topics)}; "
            f"IMU: {self.imu_topic or 'none'}; method {self.params['method']}; publishing "
            f"{self.pose_pub.topic_name}, {self.gravity_pub.topic_name}")

    # ------------------------------------------------------------------ parameters
    def _declare_parameters(self) -> dict:
        values = {}
        for spec in NODE_PARAMETERS:
            if spec.name == "imu_topic":
                continue  # its default comes from the rig file
            values[spec.name] = self._declare(spec)
        self.pipeline_values = {}
        for spec in pipeline_parameters():
            self.pipeline_values[spec.name] = self._declare(spec)
        self._validate(values)
        return values

    def _declare(self, spec: ParamSpec):
        desc = spec.description + (f" ({' | '.join(spec.choices)})" if spec.choices else "")
        descriptor = ParameterDescriptor(description=desc, read_only=spec.read_only)
        if spec.choices:
            descriptor.additional_constraints = "one of: " + ", ".join(spec.choices)
        try:
            value = self.declare_parameter(spec.name, spec.default, descriptor).value
        except InvalidParameterTypeException as exc:
            given = getattr(self, "_parameter_overrides", {}).get(spec.name)
            given = given.value if given is not None else "a value of another type"
            hint = f" (write {float(given)!r})" if isinstance(spec.default, float) and isinstance(given, int) else ""
            raise InputError(f"parameter {spec.name}",
                             f"expected a {type(spec.default).__name__}, got {given!r}{hint}") from exc
        if isinstance(spec.default, float) and isinstance(value, int):
            value = float(value)
        return value

    def _declare_imu_topic(self) -> str:
        default = self.rig.imu.topic if self.rig.imu is not None else ""
        spec = next(s for s in NODE_PARAMETERS if s.name == "imu_topic")
        topic = str(self._declare(dataclasses.replace(spec, default=default)))
        self.params["imu_topic"] = topic
        return topic

    @staticmethod
    def _validate(values: dict) -> None:
        if not values["rig_file"]:
            raise InputError("parameter rig_file", "required (e.g. --ros-args -p rig_file:=config/sample_cross4.yaml "
                                                   "or --params-file config/estimator.yaml)")
        for spec in NODE_PARAMETERS:
            if spec.choices and values.get(spec.name) not in spec.choices:
                raise InputError(f"parameter {spec.name}", f"'{values.get(spec.name)}' is not one of "
                                                           f"{', '.join(spec.choices)}")
        for name in ("sync_tolerance_s", "imu_max_age_s", "camera_timeout_s", "diagnostics_period_s"):
            if not values[name] > 0:
                raise InputError(f"parameter {name}", f"must be > 0, got {values[name]}")
        for name in ("queue_size", "imu_queue_size"):
            if values[name] < 1:
                raise InputError(f"parameter {name}", f"must be >= 1, got {values[name]}")
        if values["work_queue_size"] not in (1, 2):
            raise InputError("parameter work_queue_size", f"must be 1 or 2, got {values['work_queue_size']}")

    def _load_rig(self, path: str) -> Rig:
        return load_rig(_resolve_rig_path(path))

    def _camera_topic(self, cam) -> str:
        if not cam.image_topic:
            raise InputError(self.rig.source, "camera has no image_topic", f"cameras[{cam.name}].image_topic")
        if self.params["image_transport"] == "compressed":
            return cam.image_topic.rstrip("/") + "/compressed"
        return cam.image_topic

    def _on_set_parameters(self, params):
        for p in params:
            if p.name == "method":
                if p.value not in MODES:
                    return SetParametersResult(successful=False, reason=f"method must be one of {', '.join(MODES)}")
                self.selector.mode = p.value
                self.get_logger().info(f"parameter method set to {p.value}")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ callbacks (never block)
    def _on_image(self, index: int, msg) -> None:
        topic = self.camera_topics[index]
        self._last_rx[index] = time.monotonic()
        self._rates[topic].tick()
        if self._stale[index]:
            self._stale[index] = False
            self.get_logger().info(f"camera topic {topic}: publishing again")
        try:
            image = self._decode_image(msg, topic)
        except InputError as exc:
            self._bad_input(topic, "decode", str(exc))
            return
        except Exception as exc:  # a broken message must not stop the node
            self._bad_input(topic, "decode", f"{topic}: cannot decode image: {exc}")
            return
        width, height = self.rig.cameras[index].resolution
        if image.shape[:2] != (height, width):
            self._bad_input(topic, "size", f"{topic}: image is {image.shape[1]}x{image.shape[0]}, the rig file "
                                           f"says {width}x{height}; message ignored")
            return
        stamp = stamp_to_sec(msg.header.stamp)
        for sync_stamp, images in self._sync_add(index, stamp, image):
            self._remember_stamp(sync_stamp, msg.header.stamp)
            with self._lock:
                self.counters["synchronized_sets"] += 1
            if not self.work.put((sync_stamp, images, time.monotonic())):
                with self._lock:
                    self.counters["dropped_busy"] += 1

    def _sync_add(self, index: int, stamp: float, image):
        """Feed the shared synchronizer; yields (stamp, images in rig camera order) for each completed set."""
        for group in self.sync.add(index, stamp, image) or ():
            yield group.stamp, list(group.items)

    def _remember_stamp(self, stamp: float, ros_stamp) -> None:
        self._stamp_lookup[stamp] = (ros_stamp.sec, ros_stamp.nanosec)
        while len(self._stamp_lookup) > 256:
            self._stamp_lookup.popitem(last=False)

    def _on_imu(self, msg) -> None:
        self._rates[self.imu_topic].tick()
        a = msg.linear_acceleration
        w = msg.angular_velocity
        accel = np.array([a.x, a.y, a.z], dtype=float)
        gyro = np.array([w.x, w.y, w.z], dtype=float)
        if not (np.all(np.isfinite(accel)) and np.all(np.isfinite(gyro))):
            self._bad_input(self.imu_topic, "nan", f"{self.imu_topic}: IMU sample with NaN/inf values ignored")
            return
        if not np.linalg.norm(accel) > 0:
            self._bad_input(self.imu_topic, "zero", f"{self.imu_topic}: IMU sample with zero acceleration ignored")
            return
        stamp = stamp_to_sec(msg.header.stamp)
        self._imu_buffer.append((stamp, accel, gyro))
        self.selector.imu_sample(stamp)

    def _bad_input(self, topic: str, kind: str, message: str) -> None:
        with self._lock:
            first = self.errors.report(topic, kind, message)
        if first:
            self.get_logger().warning(f"{message} (reported once for {topic}; counted in /diagnostics)")

    # ------------------------------------------------------------------ worker thread
    def _work_loop(self) -> None:
        while not self._stop.is_set():
            item = self.work.get(timeout=0.1)
            if item is not None:
                self.process(*item)

    def process(self, stamp: float, images: list, t_complete: float) -> list:
        """Estimate from one synchronized set and publish the results (runs in the worker thread)."""
        while self._imu_buffer:
            s, accel, gyro = self._imu_buffer.popleft()
            try:
                self.pipeline.add_imu(s, accel, gyro)
            except InputError as exc:
                self._bad_input(self.imu_topic, "pipeline", str(exc))
        method, why = self.selector.select(stamp)
        if why:
            self.get_logger().info(why)
        self._set_pipeline_method(method)
        t0 = time.perf_counter()
        try:
            estimates = self.pipeline.add_frames(self._frame_set(stamp, images))
        except Exception as exc:  # keep the node alive; report the first of each kind
            with self._lock:
                self.counters["errors"] += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
                first = self.errors.report("pipeline", type(exc).__name__, self.last_error)
            if first:
                self.get_logger().error(f"estimation failed at stamp {stamp:.3f}: {self.last_error} "
                                        "(reported once; counted in /diagnostics)")
            return []
        elapsed_ms = (time.perf_counter() - t0) * 1e3
        for est in estimates:
            self._publish_estimate(est)
        latency = (time.monotonic() - t_complete) * 1e3
        with self._lock:
            self.counters["processed_sets"] += 1
            self.process_ms.append(elapsed_ms)
            if estimates:
                self.counters["estimates"] += len(estimates)
                self.latency_ms.append(latency)
                self.last_estimate = estimates[-1]
        return estimates

    def _set_pipeline_method(self, method: str) -> None:
        """Forced methods go to the pipeline as they are; auto with a live IMU lets the pipeline fall back to
        6pt-bending for a pair whose views lack IMU gravity (e.g. a reference taken while the IMU was out)."""
        if self.selector.mode == "auto" and method == "4pt-bending":
            method = "auto"
        self.pipeline.method = method

    def _header(self, est):
        from std_msgs.msg import Header

        header = Header(frame_id=self.rig.body_frame)
        sec_ns = self._stamp_lookup.get(est.stamp)
        if sec_ns is None:
            sec = math.floor(est.stamp)
            sec_ns = (int(sec), int(round((est.stamp - sec) * 1e9)))
        header.stamp.sec, header.stamp.nanosec = sec_ns
        return header

    def _publish_estimate(self, est) -> None:
        header = self._header(est)
        pose = PoseStamped(header=header)
        t = np.asarray(est.t, dtype=float).reshape(3)
        q = matrix_to_quat_xyzw(np.asarray(est.R, dtype=float))
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(v) for v in t)
        o = pose.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in q)
        self.pose_pub.publish(pose)
        if est.gravity is not None:
            g = Vector3Stamped(header=header)
            g.vector.x, g.vector.y, g.vector.z = (float(v) for v in np.asarray(est.gravity, dtype=float).reshape(3))
            self.gravity_pub.publish(g)
        fused = getattr(est, "gravity_fused", None)
        if fused is not None:
            gf = Vector3Stamped(header=header)
            gf.vector.x, gf.vector.y, gf.vector.z = (float(v) for v in np.asarray(fused, dtype=float).reshape(3))
            self.gravity_fused_pub.publish(gf)
            self.attitude_pub.publish(attitude_message(header, fused, getattr(est, "cov_gravity_fused", None)))

    # ------------------------------------------------------------------ timer: stale cameras, diagnostics
    def _on_timer(self) -> None:
        now = time.monotonic()
        timeout = self.params["camera_timeout_s"]
        others_alive = any(t is not None and now - t <= timeout for t in self._last_rx)
        for i, topic in enumerate(self.camera_topics):
            if self._stale[i]:
                continue
            if self._last_rx[i] is not None and now - self._last_rx[i] > timeout:
                self._stale[i] = True
                self._bad_input(topic, "stopped", f"camera topic {topic} stopped publishing (nothing for "
                                                  f"{now - self._last_rx[i]:.1f} s)")
            elif self._last_rx[i] is None and others_alive and now - self._start_time > timeout:
                self._stale[i] = True  # the other cameras publish, this one never did
                self._bad_input(topic, "stopped", f"camera topic {topic}: no image yet while the other cameras "
                                                  "publish (wrong topic or transport?)")
        self.diag_pub.publish(self.diagnostics(now))

    def diagnostics(self, now: float | None = None):
        """The DiagnosticArray published on /diagnostics."""
        now = time.monotonic() if now is None else now
        with self._lock:
            counters = dict(self.counters)
            latency = list(self.latency_ms)
            proc = list(self.process_ms)
            errors = self.errors.per_topic()
            last_msgs = dict(self.errors.last)
            last = self.last_estimate
        values = {
            "method": self.selector.mode,
            "active_method": self.selector.current or "",
            "last_estimate_method": last.method if last is not None else "",
            "imu_age_s": f"{self.selector.imu_age(self._latest_image_stamp()):.3f}" if self.imu_topic else "no IMU",
            "synchronized_sets": counters.get("synchronized_sets", 0),
            "processed_sets": counters.get("processed_sets", 0),
            "dropped_sets_busy": self.work.dropped,
            "estimates_published": counters.get("estimates", 0),
            "errors": sum(errors.values()),
            "num_inliers": last.num_inliers if last is not None else "",
            "time_ms_last": f"{last.time_ms:.1f}" if last is not None and getattr(last, "time_ms", None) else "",
            "processing_ms_median": f"{statistics.median(proc):.1f}" if proc else "",
            "processing_ms_max": f"{max(proc):.1f}" if proc else "",
            "latency_ms_median": f"{statistics.median(latency):.1f}" if latency else "",
            "gravity_source": getattr(last, "gravity_source", "") if last is not None else "",
            "gravity_fused_sigma_deg": (f"{last.gravity_fused_sigma_deg:.3f}"
                                        if last is not None and getattr(last, "gravity_fused", None) is not None
                                        else ""),
        }
        for key, val in self._sync_stats().items():
            values[f"sync_{key}"] = val
        for key, val in self._pipeline_stats().items():
            values[f"pipeline_{key}"] = val
        for topic, meter in self._rates.items():
            values[f"rate_hz {topic}"] = f"{meter.rate(now):.2f}"
            values[f"received {topic}"] = meter.count
        for topic, n in errors.items():
            values[f"errors {topic}"] = n
            values[f"last_error {topic}"] = last_msgs.get(topic, "")
        stale = [t for t, s in zip(self.camera_topics, self._stale) if s]
        if stale:
            level, message = DiagnosticStatus.WARN, f"no images on {', '.join(stale)}"
        elif errors:
            level, message = DiagnosticStatus.WARN, f"{sum(errors.values())} bad inputs (see errors *)"
        else:
            level, message = DiagnosticStatus.OK, f"{values['active_method'] or 'waiting for images'}"
        status = DiagnosticStatus(level=level, name=f"nrmpc_ros: {self.get_fully_qualified_name()}",
                                  message=message, hardware_id=self.rig.body_frame,
                                  values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        return array

    def _latest_image_stamp(self) -> float:
        return max(self._stamp_lookup) if self._stamp_lookup else 0.0

    def _sync_stats(self) -> dict:
        out = {"emitted": self.sync.emitted}
        out.update({f"dropped {reason}": n for reason, n in sorted(self.sync.dropped.items())})
        return out

    def _pipeline_stats(self) -> dict:
        out = {}
        for key, value in self.pipeline.stats.as_dict().items():
            if isinstance(value, dict):
                out.update({f"{key} {k}": v for k, v in sorted(value.items())})
            else:
                out[key] = value
        return out

    # ------------------------------------------------------------------ shutdown
    def summary(self) -> str:
        with self._lock:
            c = dict(self.counters)
            lat = list(self.latency_ms)
        med = f"{statistics.median(lat):.1f} ms" if lat else "n/a"
        return (f"{c.get('synchronized_sets', 0)} synchronized sets, {c.get('processed_sets', 0)} processed, "
                f"{self.work.dropped} dropped while busy, {c.get('estimates', 0)} estimates published, "
                f"median latency {med}, {sum(self.errors.per_topic().values())} bad inputs")

    def stop_worker(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._worker.is_alive():
            self._worker.join(timeout)

    def destroy_node(self):
        self.stop_worker()
        return super().destroy_node()


# --------------------------------------------------------------------------- entry point
def usage() -> str:
    """The text of ``estimator --help``: usage and every parameter with its default."""
    lines = [
        "usage: estimator [--help] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] ...]",
        "",
        "ROS 2 node 'estimator' of nrmpc_ros: relative pose and gravity of a non-rigid multi-camera rig.",
        "Subscribes to the rig file's camera topics (sensor_msgs/Image or CompressedImage) and, optionally,",
        "sensor_msgs/Imu; publishes ~/relative_pose (geometry_msgs/PoseStamped), ~/gravity and",
        "~/gravity_fused (geometry_msgs/Vector3Stamped), ~/attitude (sensor_msgs/Imu: roll and pitch",
        "only) and /diagnostics (diagnostic_msgs/DiagnosticArray).",
        "",
        "example: estimator --ros-args --params-file config/estimator.yaml",
        "         ros2 run nrmpc_ros estimator --ros-args -p rig_file:=config/sample_cross4.yaml -p method:=auto",
        "",
        "parameters:",
    ]
    try:
        specs = NODE_PARAMETERS + pipeline_parameters()
    except ImportError as exc:  # the front end is part of the package; say so if it is broken
        specs = NODE_PARAMETERS
        lines.append(f"  (pipeline.* parameters unavailable: {exc})")
    for spec in specs:
        default = "(from the rig file)" if spec.default is None else repr(spec.default)
        lines.append(f"  {spec.name} [default {default}]")
        lines.append(f"      {spec.description}" + (f"; one of: {', '.join(spec.choices)}" if spec.choices else ""))
    return "\n".join(lines)


def _user_args(argv: list) -> list:
    """Arguments outside any --ros-args ... [--] section."""
    out, in_ros = [], False
    for a in argv:
        if a == "--ros-args":
            in_ros = True
        elif a == "--" and in_ros:
            in_ros = False
        elif not in_ros:
            out.append(a)
    return out


def main(argv: list | None = None) -> int:
    """Entry point of ``estimator`` and ``ros2 run nrmpc_ros estimator``."""
    argv = list(sys.argv if argv is None else argv)
    user = _user_args(argv[1:])
    if "-h" in user or "--help" in user:
        print(usage())
        return 0
    if user:
        print(f"estimator: error: unknown arguments {' '.join(user)} (parameters go after --ros-args; "
              "see --help)", file=sys.stderr)
        return 2
    if rclpy is None:
        print(f"estimator: error: rclpy is not importable ({_RCLPY_ERROR}); {ROS_EXTRA_HINT}", file=sys.stderr)
        return 2
    rclpy.init(args=argv)
    node = None
    try:
        try:
            node = EstimatorNode()
        except NrmpcError as exc:
            print(f"estimator: error: {exc}", file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            executor.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        node.get_logger().info("shutting down: " + node.summary())
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
