"""The ROS 2 node ``estimator``; with ``ros_play`` the only rclpy user in nrmpc_ros (README, "The ROS 2 node").

Parameters are declared from :class:`~nrmpc_ros.frontend.node_config.NodeConfig` and ``pipeline.*``; callbacks
hand messages to :class:`~nrmpc_ros.frontend.service.EstimatorService`, whose two worker threads run the
pipeline (the intake of frame sets, and the estimation of measured holds); this module turns its outputs into
messages. ``estimator --help`` lists topics and parameters.
"""

from __future__ import annotations

# isort: off
from . import threads  # noqa: F401 - one BLAS thread, before numpy is imported
# isort: on
import importlib.util
import os
import signal
import sys
import threading
import time

from .core.rig import load_rig
from .errors import ROS_EXTRA_HINT, InputError, NrmpcError
from .frontend import node_config as cfgs
from .frontend.image_cdr import read_image
from .frontend.imu_block import ImuDecoder
from .frontend.markers import build_markers, marker_array_fields
from .frontend.outputs import OUTPUTS, HoldOutput, fill_message, frame_pose_fields, message_fields
from .frontend.service import SHUTDOWN_S, EstimatorService
from .ros_play import message_class

try:  # rclpy is optional for the package; --help works without it
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
    from rclpy.callback_groups import CallbackGroup
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.exceptions import InvalidHandle, InvalidParameterTypeException, InvalidParameterValueException
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu
    from std_srvs.srv import Trigger

    _RCLPY_ERROR = None
except ImportError as _exc:  # pragma: no cover - exercised only without ROS
    rclpy, Node, CallbackGroup, _RCLPY_ERROR = None, object, object, _exc

NODE_NAME = "estimator"
MARKERS = ("visualization_msgs/msg/MarkerArray", "~/markers")  # latched: the last state of the rig
SUMMARY_LINGER_S = 0.5  # after the shutdown summary: time for a reliable /rosout delivery on a busy machine
IMU_DRAIN_MAX = 2000  # IMU samples taken from the subscription's queue at once (2 s at 1 kHz)
SIGNAL_WAKE_S = 0.1  # longest wait of the executor before Python sees a signal that arrived during it
EXIT_S = 0.4  # after the linger: destroying the node and the context, ending the process (measured: 0.1-0.25 s)


def _sensor_qos(depth: int):
    return QoSProfile(history=qos_profile_sensor_data.history, depth=int(depth),
                      reliability=qos_profile_sensor_data.reliability, durability=qos_profile_sensor_data.durability)


def take_waiting(sub, limit: int):
    """The messages waiting in ``sub``'s queue, up to ``limit``, taken as the executor takes them; stops at the
    first empty take (or when the subscription is gone)."""
    for _ in range(limit):
        try:
            with sub.handle:
                got = sub.handle.take_message(sub.msg_type, sub.raw)
        except InvalidHandle:  # destroyed meanwhile (shutdown)
            return
        if got is None:
            return
        yield got[0]


class TakenByTimer(CallbackGroup):
    """Subscriptions the executor neither waits on nor runs: a thread of the node takes their waiting messages
    (:meth:`EstimatorNode._take_loop`). A 1 kHz IMU would otherwise wake the executor a thousand times a second,
    and each wake (the wait set built again over every subscription, timer and QoS event of the node: about
    1.6 ms of CPU for a 6-camera rig) costs more than the sample it brings; and the executor takes one message
    per subscription per wake, so after a stall one input would run ahead of the others."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


class EstimatorNode(Node):
    """The ``estimator`` node; ``start_worker=False`` leaves both workers stopped (tests drive them)."""

    def __init__(self, *, start_worker: bool = True, **node_kwargs):
        if rclpy is None:
            raise NrmpcError(f"rclpy is not importable ({_RCLPY_ERROR}); {ROS_EXTRA_HINT}")
        super().__init__(NODE_NAME, automatically_declare_parameters_from_overrides=True, **node_kwargs)
        cfg, pipe_cfg = cfgs.configs_from_parameters(self._declare_parameters())
        self.cfg, self.rig = cfg, load_rig(cfgs.find_file(cfg.rig_file, "parameter rig_file"))
        imu, warning = cfgs.imu_topic(self.rig, cfg)
        if warning:
            self._log("warn", warning)
        imu = imu and self.resolve_topic_name(imu)
        self.camera_topics = [self.resolve_topic_name(c.image_topic) for c in self.rig.cameras]
        self.service = EstimatorService(self.rig, cfg, pipe_cfg, self.camera_topics, imu, self.publish_hold, self._log,
                                        publish_poses=self.publish_poses, publish_status=self.publish_markers)
        self._subs, self._transport = [None] * self.rig.num_cameras, [None] * self.rig.num_cameras
        self._reliable = [None] * self.rig.num_cameras
        self._taken = TakenByTimer() if cfg.take_period_s > 0 else None
        for i in range(self.rig.num_cameras):
            self._subscribe_camera(i)
        self._info = {i: self.create_subscription(CameraInfo, self.resolve_topic_name(c.info_topic),
                                                  lambda m, i=i: self._on_info(i, m), _sensor_qos(1))
                      for i, c in enumerate(self.rig.cameras) if c.info_topic}
        self._imu_sub = None
        if imu:
            self._imu_decoder = ImuDecoder()
            self._imu_sub = self.create_subscription(Imu, imu, self._on_imu, _sensor_qos(cfg.imu_queue_size),
                                                     raw=True, callback_group=self._taken)
        outputs = {**OUTPUTS, "diag": ("diagnostic_msgs/msg/DiagnosticArray", "/diagnostics")}
        if not cfg.publish_tf or importlib.util.find_spec("tf2_msgs") is None:  # not always installed
            del outputs["tf"]
        self.pubs = {k: self.create_publisher(message_class(t, topic), topic, 100) for k, (t, topic) in outputs.items()}
        if importlib.util.find_spec("visualization_msgs") is not None:  # transient local: a late RViz gets the last
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.pubs["markers"] = self.create_publisher(message_class(*MARKERS), MARKERS[1], latched)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(cfg.diagnostics_period_s, self._on_timer)
        outputs = ", ".join(p.topic_name for p in self.pubs.values())
        cams = ", ".join(f"{t} ({'compressed' if c else 'raw'})" for t, c in self._transport)
        self._log("info", f"rig {self.rig.source}: cameras on {cams}; IMU: {imu or 'none'}; method {cfg.method}; "
                          f"publishing {outputs}")
        if start_worker:
            self.service.start()
        self._taking = threading.Event()
        self._taker = None
        if self._taken is not None:
            self._taker = threading.Thread(target=self._take_loop, name="nrmpc-take", daemon=True)
            self._taker.start()

    # ------------------------------------------------------------------ parameters and inputs
    def _declare_parameters(self) -> dict:
        given = {n: self.get_parameter(n).value for n in self.list_parameters([], 0).names}
        unknown = cfgs.unknown_parameters(given)
        if unknown:
            raise InputError(f"parameter {unknown[0]}", f"unknown parameter(s) {', '.join(unknown)} (a typo? "
                                                        "`estimator --help` lists the parameters)")
        values = {}
        for f in cfgs.parameter_fields():
            if f.name in given:
                self.undeclare_parameter(f.name)
            d = fill_message(ParameterDescriptor(), cfgs.parameter_descriptor(f))
            value, lenient = given.get(f.name), isinstance(f.default, float) and type(given.get(f.name)) is int
            try:  # an integer for a float parameter is taken as that float
                values[f.name] = self.declare_parameter(f.name, float(value) if lenient else f.default, d,
                                                        ignore_override=lenient).value
            except InvalidParameterTypeException:
                expected = type(f.default).__name__
                raise InputError(f"parameter {f.name}", f"expected a {expected}, got {value!r}") from None
            except InvalidParameterValueException:
                raise InputError(f"parameter {f.name}", f"{value!r} is not allowed: {d.description}") from None
        return values

    def _subscribe_camera(self, i: int) -> None:
        """Subscribe camera ``i`` on the topic its transport says, reliably unless a publisher offers only best
        effort (``node_config.images_reliable``); again when either changes while nothing comes (before the
        first image, or while the camera is silent: a driver started again with other QoS), the new
        subscription first: the take thread always finds one. Reliable while no publisher is known: a
        best-effort publisher then delivers nothing to it (incompatible), so the switch loses no image."""
        topic = self.rig.cameras[i].image_topic
        infos = {t: self.get_publishers_info_by_topic(t)
                 for t in cfgs.transport_topics(topic, self.resolve_topic_name)}  # not our own subscription
        publishers = {t: [p.topic_type for p in v] for t, v in infos.items()}
        choice = cfgs.transport(topic, self.cfg.image_transport, publishers, self.resolve_topic_name)
        reliable = cfgs.images_reliable([p.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                                         for p in infos.get(choice[0], [])])
        if (choice, reliable) == (self._transport[i], self._reliable[i]):
            return
        qos = _sensor_qos(self.cfg.image_queue_size)
        if reliable:
            qos.reliability = ReliabilityPolicy.RELIABLE
        old = self._subs[i]
        self._transport[i], self._reliable[i] = choice, reliable
        quiet = SubscriptionEventCallbacks(incompatible_qos=lambda _event: None)  # the switch below says it
        self._subs[i] = self.create_subscription(CompressedImage if choice[1] else Image, choice[0],
                                                 lambda raw, i=i: self._on_image(i, raw), qos,
                                                 callback_group=self._taken, event_callbacks=quiet,
                                                 raw=True)  # read in place (frontend/image_cdr.py)
        if old is not None:
            self.destroy_subscription(old)
            how = "" if reliable else ", best effort as its publisher offers"
            self._log("info", f"camera {self.rig.cameras[i].name}: subscribing to {choice[0]} instead "
                              f"(published{how})")

    def _on_image(self, i: int, raw) -> None:
        """One serialized image of camera ``i``; runs only with ``take_period_s`` 0 (see :meth:`_on_imu`)."""
        self.service.on_image(i, read_image(raw, self._transport[i][1]), self._now())

    def _on_info(self, i: int, msg) -> None:
        if i not in self.service.camera_info:  # the first one only
            self.service.on_camera_info(i, msg, self.resolve_topic_name(self.rig.cameras[i].info_topic))

    def _now(self) -> float | None:
        ns = self.get_clock().now().nanoseconds
        return ns * 1e-9 if ns > 0 else None  # simulated time before the first /clock: no clock

    def _on_imu(self, raw) -> None:
        """One serialized IMU message and the ones already waiting in the subscription's queue, decoded as one
        block: the executor takes one message per subscription per turn, so a 200-1000 Hz IMU would fall seconds
        behind the cameras' 10-60 frames a second whenever the process is busy, and turning each message into a
        Python object would cost more than what the pipeline does with it (docs/ARCHITECTURE.md, "The node's
        two workers"). Runs only with ``take_period_s`` 0; otherwise :meth:`_take_inputs` takes them."""
        self.service.on_imu_block(self._imu_decoder.decode([raw, *take_waiting(self._imu_sub, IMU_DRAIN_MAX)]),
                                  self._now())

    def _take_loop(self) -> None:
        """Every ``take_period_s`` on a steady clock (draining queues is no matter of ROS time: a simulated clock
        may be paused, slow, or not published yet while messages keep arriving), until :meth:`stop_taking`.
        A thread, not an executor timer: a wake costs a few microseconds here, an executor turn 1.6 ms."""
        period = self.cfg.take_period_s
        due = time.monotonic()
        while not self._taking.wait(max(0.0, due - time.monotonic())):
            due = max(due + period, time.monotonic())  # after a stall: one take of everything, no catch-up run
            try:
                self._take_inputs()
            except Exception as exc:  # noqa: BLE001 - the node must outlive it (a context shut down under it)
                if not self.context.ok():
                    return
                self.service.input_failed("inputs", exc)

    def stop_taking(self) -> None:
        """End the thread that takes the inputs (before the service stops; idempotent)."""
        self._taking.set()
        if self._taker is not None and self._taker is not threading.current_thread():
            self._taker.join()

    def destroy_node(self) -> None:
        self.stop_taking()
        super().destroy_node()

    def _take_inputs(self) -> None:
        """Every message waiting in the camera and IMU subscriptions (see :class:`TakenByTimer`), handed over in
        stamp order (frontend/taken.py). A subscription's message type says how to read its images: the
        transport of a camera may change meanwhile (``image_transport: auto``)."""
        limit = self.cfg.image_queue_size
        images = [[] if sub is None else [read_image(raw, sub.msg_type is CompressedImage)
                                          for raw in take_waiting(sub, limit)] for sub in self._subs]
        raws = list(take_waiting(self._imu_sub, IMU_DRAIN_MAX)) if self._imu_sub is not None else []
        if raws or any(images):
            self.service.on_taken(images, self._imu_decoder.decode(raws) if raws else None, self._now())

    def _on_timer(self) -> None:
        self.service.tick()
        for i in [i for i in self._info if i in self.service.camera_info]:
            self.destroy_subscription(self._info.pop(i))
        for i, topic in enumerate(self.camera_topics):  # publishers that came since, while nothing comes
            if not self.service.received[topic] or self.service.watch.is_silent(i):
                self._subscribe_camera(i)
        array = fill_message(DiagnosticArray(), self.service.diagnostic_fields(self.get_fully_qualified_name()))
        array.header.stamp = self.get_clock().now().to_msg()
        self.pubs["diag"].publish(array)

    def _on_reset(self, _request, response):
        response.success, response.message = True, self.service.reset("requested on ~/reset")
        return response

    def _on_set_parameters(self, params):
        bad = [self.service.set_method(p.value) for p in params if p.name == "method"]
        return SetParametersResult(successful=not any(bad), reason="; ".join(filter(None, bad)))

    def _log(self, level: str, line: str) -> None:
        logger = self.get_logger()  # one call site per severity: rclpy ties a severity to its call site
        if level == "info":
            logger.info(line)
        elif level == "error":
            logger.error(line)
        else:
            logger.warning(line)

    @property
    def image_subscriptions(self) -> list[tuple[str, bool] | None]:
        """Per camera, the image topic subscribed to and whether it is compressed (None: not yet)."""
        return list(self._transport)

    def publish_hold(self, out: HoldOutput) -> None:
        """Publish one hold's outputs on the node's topics; the service calls it from its estimation worker."""
        for key, fields in message_fields(out, self.service.frames, self.service.feeder.ros_stamp).items():
            if key in self.pubs:
                self.pubs[key].publish(fill_message(self.pubs[key].msg_type(), fields))

    def publish_poses(self, out) -> None:
        """Publish one frame set's camera poses (TF, and ~/camera_poses when due); from the intake worker."""
        for key, fields in frame_pose_fields(out, self.service.frames, self.service.feeder.ros_stamp).items():
            if key in self.pubs:
                self.pubs[key].publish(fill_message(self.pubs[key].msg_type(), fields))

    def publish_markers(self, status, out: HoldOutput | None) -> None:
        """Publish the rig's markers (frontend/markers.py) for its state and last estimate; the service calls it
        from either worker after every estimate and state change (one at a time)."""
        pub = self.pubs.get("markers")
        if pub is None:
            return
        markers = build_markers(self.rig, out, status, self.cfg.markers_bend_scale)
        stamp = self.service.feeder.ros_stamp(out.estimate.stamp if out is not None else status.stamp)
        pub.publish(fill_message(pub.msg_type(), marker_array_fields(markers, self.rig.body_frame, stamp)))

    def shutdown(self, budget_s: float = SHUTDOWN_S) -> None:
        """Stop the workers and log the summary (while the context still carries it to /rosout), all within
        ``budget_s`` of the call (README, "The ROS 2 node", Drops and logs)."""
        self.stop_taking()
        worker = self.service.stop(max(0.0, budget_s - SUMMARY_LINGER_S - EXIT_S))
        self._log("info", f"shutting down: {self.service.summary()}; {worker}")
        time.sleep(SUMMARY_LINGER_S)  # DDS delivers it to /rosout's subscribers before the context goes


def main(argv: list | None = None) -> int:
    """Entry point of ``estimator`` and ``ros2 run nrmpc_ros estimator``.

    SIGINT and SIGTERM end the process within ``SHUTDOWN_S`` (README, "The ROS 2 node"): the executor waits at
    most ``SIGNAL_WAKE_S`` before it sees the signal, the node stops within the rest, and as the process's entry
    point (``argv`` None) it ends without the interpreter's own teardown (modules, and an estimate abandoned in
    the worker thread), which on a busy machine could take longer than the budget.
    """
    entry = argv is None
    argv = list(sys.argv if argv is None else argv)
    code = cfgs.command_line(argv[1:], rclpy is None and f"rclpy is not importable ({_RCLPY_ERROR}); {ROS_EXTRA_HINT}")
    if code is not None:
        return code
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)  # Ctrl-C: the summary still reaches /rosout
    stop = []  # the signal that asked to stop: the executor loop ends at its next wake-up
    for sig in (signal.SIGINT, signal.SIGTERM):  # both stop the node, also where SIGINT came ignored (a shell's
        signal.signal(sig, lambda signum, _frame: stop.append(signum))  # background job): launch files send it
    node = None
    try:
        try:
            node = EstimatorNode()
        except NrmpcError as exc:
            print(f"estimator: error: {exc}", file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:  # a flag, not an exception: an exception raised inside rclpy's C calls (taking a message) would
            # come out as another error, and the summary would be lost
            while rclpy.ok() and not stop:  # the wait ends every SIGNAL_WAKE_S: a signal does not end a DDS wait
                executor.spin_once(timeout_sec=SIGNAL_WAKE_S)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        node.shutdown(SHUTDOWN_S - SIGNAL_WAKE_S)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if entry:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
