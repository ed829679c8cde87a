"""Publish a bag's messages over ROS 2 with their original timing (``nrmpc play``); imports rclpy lazily.

For users without rosbag2 and for the end-to-end tests. The bag is read with
``rosbags``; rosbag2 messages are published as the serialized CDR bytes they
are stored as (no deserialization), ROS 1 bags are converted to CDR first.
Each topic is published from its own context (DDS participant), as separate
drivers would: Fast DDS's shared-memory segment (512 KB per participant by
default) holds one VGA image at a time, and best-effort (sensor-data)
subscribers would lose the images of the other cameras sent at the same
instant. rclpy is imported inside :func:`play` only, so the CLI loads without ROS.
"""

from __future__ import annotations

import importlib
import math
import sys
import threading
import time
from pathlib import Path

from .errors import ROS_EXTRA_HINT, InputError, NrmpcError


def message_class(msgtype: str, topic: str):
    """The rclpy message class of a ``pkg/msg/Name`` type."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    try:
        module = importlib.import_module(f"{parts[0]}.{parts[1]}")
        return getattr(module, parts[2])
    except (ImportError, AttributeError, IndexError) as exc:
        raise InputError(topic, f"message type {msgtype} is not available in this ROS 2 install ({exc})") from exc


def _open_reader(bag: str):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(bag)
    if not path.exists():
        raise InputError(bag, "no such bag")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise InputError(bag, "not a rosbag2 directory: it has no metadata.yaml (a ROS 1 bag is one .bag file)")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types for unreadable bags
        raise InputError(bag, f"cannot open bag: {exc}") from None
    if not reader.connections:
        reader.close()
        raise InputError(bag, "the bag has no topics: nothing to play")
    return reader


def check_args(args) -> None:
    """One clear error for a bad --rate, --delay or --wait-for-subscribers."""
    for flag, value, positive in (("--rate", args.rate, True), ("--delay", args.delay, False),
                                  ("--wait-for-subscribers", args.wait_for_subscribers, False)):
        if not math.isfinite(value) or value < 0 or (positive and value == 0):
            raise InputError(flag, f"must be a finite number {'> 0' if positive else '>= 0'}, got {value!r}")


def play(args) -> int:
    """Play ``args.bag`` (see ``nrmpc play --help`` for the fields of args); returns the exit code."""
    check_args(args)
    try:
        import rclpy
        from rclpy.context import Context
        from rclpy.qos import QoSDurabilityPolicy, QoSHistoryPolicy, QoSProfile, QoSReliabilityPolicy
    except ImportError as exc:
        raise NrmpcError(f"rclpy is not importable ({exc}); {ROS_EXTRA_HINT}") from exc

    reader = _open_reader(args.bag)
    try:
        available = {c.topic: c.msgtype for c in reader.connections}
        wanted = list(args.topics) if args.topics else sorted(available)
        missing = [t for t in wanted if t not in available]
        if missing:
            raise InputError(args.bag, f"topic(s) {', '.join(missing)} not in the bag (it has: "
                                       f"{', '.join(sorted(available))})")
        connections = [c for c in reader.connections if c.topic in wanted]
        classes = {t: message_class(available[t], t) for t in wanted}
        convert = not getattr(reader, "is2", True)  # ROS 1 bag: raw is not CDR

        nodes = []
        _sigterm_as_interrupt()
        try:
            qos = QoSProfile(history=QoSHistoryPolicy.KEEP_LAST, depth=100,
                             reliability=QoSReliabilityPolicy.RELIABLE, durability=QoSDurabilityPolicy.VOLATILE)
            pubs = {}
            for k, topic in enumerate(wanted):
                node = _node(rclpy, Context, f"nrmpc_play_{k}")
                nodes.append(node)
                pubs[topic] = node.create_publisher(classes[topic], topic, qos)
            clock_pub = None
            if args.clock:
                from rosgraph_msgs.msg import Clock

                nodes.append(_node(rclpy, Context, "nrmpc_play_clock"))
                clock_pub = nodes[-1].create_publisher(Clock, "/clock", 10)
            _wait_for_subscribers(nodes[0], pubs, args.wait_for_subscribers)
            if args.delay > 0:
                time.sleep(args.delay)
            count = 0
            start = time.monotonic()
            while True:
                count += _play_once(reader, connections, pubs, clock_pub, args.rate, convert, nodes[0].context)
                if not args.loop or not nodes[0].context.ok():
                    break
            if not args.quiet:
                print(f"nrmpc play: published {count} messages on {len(pubs)} topics in "
                      f"{time.monotonic() - start:.1f} s", file=sys.stderr)
        finally:
            for node in nodes:
                ctx = node.context
                node.destroy_node()
                rclpy.try_shutdown(context=ctx)
    finally:
        reader.close()
    return 0


def _node(rclpy, context_class, name: str):
    """A node in a context of its own, i.e. its own DDS participant (Ctrl-C stays a KeyboardInterrupt)."""
    from rclpy.signals import SignalHandlerOptions

    ctx = context_class()
    rclpy.init(args=None, context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    return rclpy.create_node(name, context=ctx)


def _sigterm_as_interrupt() -> None:
    """SIGTERM ends the playback like Ctrl-C (publishers are destroyed cleanly)."""
    import signal

    def handler(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)


def _wait_for_subscribers(node, pubs: dict, timeout: float) -> None:
    """Wait up to ``timeout`` seconds until every publisher has matched a subscriber."""
    if timeout <= 0:
        return
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        lonely = [t for t, p in pubs.items() if p.get_subscription_count() == 0]
        if not lonely:
            time.sleep(0.5)  # the subscriber side may match our publisher a little later
            return
        time.sleep(0.05)
    node.get_logger().warning(f"no subscriber after {timeout:.1f} s on: {', '.join(lonely)}; playing anyway")


def _play_once(reader, connections, pubs, clock_pub, rate: float, convert: bool, context) -> int:
    """Publish the bag once with its recorded spacing; return the number of messages published."""
    t0_bag = None
    t0_wall = time.monotonic()
    count = 0
    clock_msg = None
    if clock_pub is not None:
        from rosgraph_msgs.msg import Clock

        clock_msg = Clock()
    for conn, stamp_ns, raw in _messages(reader, connections):
        if not context.ok():
            break
        if t0_bag is None:
            t0_bag = stamp_ns
        due = t0_wall + (stamp_ns - t0_bag) * 1e-9 / rate
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if convert:
            raw = reader.typestore.ros1_to_cdr(raw, conn.msgtype)
        if clock_msg is not None:
            clock_msg.clock.sec, clock_msg.clock.nanosec = divmod(int(stamp_ns), 1_000_000_000)
            clock_pub.publish(clock_msg)
        pubs[conn.topic].publish(bytes(raw))
        count += 1
    return count


def _messages(reader, connections):
    """The bag's messages; a read error (a corrupt or truncated bag) is one InputError naming the bag."""
    it = reader.messages(connections=connections)
    while True:
        try:
            yield next(it)
        except StopIteration:
            return
        except Exception as exc:  # sqlite3, mcap and rosbags raise their own types
            raise InputError(str(reader.paths[0]), f"cannot read messages (corrupt or truncated bag?): {exc}") from None


class BackgroundNode:
    """An rclpy node in a context (DDS participant, ``domain``) of its own, spun in a daemon thread.

    The listeners of the end-to-end tests and of ``scripts/bench_node.py``
    subclass it: create subscriptions on ``self.node``, then call ``start``.
    """

    def __init__(self, name: str, domain: int):
        try:
            import rclpy
            from rclpy.context import Context
            from rclpy.executors import SingleThreadedExecutor
        except ImportError as exc:
            raise NrmpcError(f"rclpy is not importable ({exc}); {ROS_EXTRA_HINT}") from None
        self.rclpy = rclpy
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _spin(self) -> None:
        while self.ctx.ok():
            try:
                self.executor.spin_once(timeout_sec=0.1)
            except Exception:  # shutdown while spinning
                break

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.ctx)
        if self._thread.is_alive():
            self._thread.join(2.0)
