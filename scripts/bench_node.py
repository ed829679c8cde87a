#!/usr/bin/env python3
"""Benchmark of the estimator node over DDS: agreement with ``nrmpc replay``, latency, drops.

1. bag: a bag played into the node with ``nrmpc play`` (``--rate``); the node's gravity estimates are compared
   with ``nrmpc replay``'s on the same bag (same stamps; largest difference in m/s^2), and the node reports,
   per estimate, the time from the arrival of the frame set that completed the hold to the publication
   (``latency median (ms)`` in /diagnostics) and the processing time per frame set.
2. stream: the bag's frames published by this script for ``--seconds`` at ``--fps`` with fresh stamps (the bag
   over and over, sped up to ``--fps``, its IMU with it), counting the frame sets the node processed and those it
   dropped while busy.

Without ``--bag`` a 320x240 bag of 4 holds streamed at 10 Hz is rendered first (about 15 s). The node runs as
its own process (``--cpus 0`` pins it to one core with taskset).

3. ``--matrix BAG RIG``: a 6-camera JPEG stream bag (``scripts/bench_replay_speed.py`` renders one) published at
   1x from this process for 2, 4 and 6 of its cameras at 15 and 30 Hz, raw (each JPEG decoded once beforehand)
   and compressed; per configuration the node's CPU seconds per second of data (from /proc, start-up
   excluded) and per image beside the cost of ``cv2.imdecode`` and of one forward ``calcOpticalFlowPyrLK`` on
   the same images measured in this run, frame-set latency median and p95 (its /diagnostics), hold latency
   median and p95 (arrival of the frame set that completed a hold to its estimate published), holds measured
   against the bag's and estimates published, frame sets dropped while busy, and the time from SIGINT to the
   node's exit. ``--matrix-rows 6x30 6x15 2x30`` runs only those camera x rate rows; ``--raw-encoding bgr8``
   sends the raw images in colour, as most camera drivers do.

    python scripts/bench_node.py [--bag BAG --rig RIG] [--cpus 0] [--rate 1] [--seconds 20] [--json OUT]
    python scripts/bench_node.py --matrix BAG RIG [--cpus 0] [--json OUT]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from nrmpc_ros.ros_play import BackgroundNode

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def render(directory: Path) -> tuple:
    """A 320x240 stream through 4 holds of the sample rig (relative topics)."""
    from nrmpc_ros.core import load_rig
    from nrmpc_ros.render.bagmaker import BagOptions, make_bag
    from nrmpc_ros.render.sequence import MotionOptions

    d = yaml.safe_load((REPO / "config" / "sample_cross4.yaml").read_text())
    for c in d["cameras"]:
        c["resolution"], c["intrinsics"] = [320, 240], [235.0, 235.0, 159.5, 119.5]
    rig = directory / "rig.yaml"
    rig.write_text(yaml.safe_dump(d, sort_keys=False))
    opts = BagOptions(motion=MotionOptions(views=4, hold_seconds=2.0, rate=10.0, move_seconds=0.8, max_step=15.0,
                                           capture="stream"))
    make_bag(load_rig(rig), directory / "bag", opts, progress=False)
    return directory / "bag", rig


class Listener(BackgroundNode):
    """The node's /diagnostics (per part) and its ~/gravity, in a context of its own."""

    def __init__(self, domain: int):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        super().__init__("bench_listener", domain)
        self.diag, self.gravity = {}, {}
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, qos)
        self.node.create_subscription(Vector3Stamped, "/estimator/gravity", self._on_gravity, qos)
        self.start()

    def _on_diag(self, msg):
        for s in msg.status:
            if "estimator: " in s.name:
                self.diag[s.name.split(": ", 1)[1]] = (s.message, {kv.key: kv.value for kv in s.values})

    def _on_gravity(self, m):
        self.gravity[round(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, 6)] = (m.vector.x, m.vector.y,
                                                                                     m.vector.z)

    def wait(self, condition, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end and not condition():
            time.sleep(0.2)
        return condition()

    def started(self) -> bool:
        return bool(self.diag)

    def done(self) -> bool:
        cams, est = self.diag.get("cameras", ("", {})), self.diag.get("estimation", ("", {}))
        return "the input ended" in cams[0] and est[1].get("work waiting") == "0"


def start(cmd: list, env: dict, log: Path, cpus: str = "") -> subprocess.Popen:
    if cpus and shutil.which("taskset"):
        cmd = ["taskset", "-c", cpus] + cmd
    with open(log, "w") as out:
        return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)


def stop(proc) -> None:
    for sig in (signal.SIGINT, signal.SIGKILL):
        if proc is None or proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, sig)
            proc.wait(10)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            continue


def replay(bag: Path, rig: Path, out: Path) -> dict:
    subprocess.run([str(BIN / "nrmpc"), "replay", str(bag), "--rig", str(rig), "--out", str(out), "--no-progress",
                    "--quiet"], check=True, capture_output=True, timeout=600)
    with open(out) as fh:
        return {round(float(r["stamp"]), 6): tuple(float(r[k]) for k in ("gx", "gy", "gz"))
                for r in csv.DictReader(fh)}


def stream(domain: int, bag: Path, seconds: float, fps: float) -> int:
    """The bag's images and IMU again and again with fresh stamps, frames at ``fps``; returns the sets sent."""
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    from sensor_msgs.msg import Image, Imu

    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.msgtype in ("sensor_msgs/msg/Image", "sensor_msgs/msg/Imu")]
        msgs = [(t, c.topic, deserialize_message(raw, Image if "Image" in c.msgtype else Imu))
                for c, t, raw in reader.messages(connections=conns)]
        length = (reader.end_time - reader.start_time) * 1e-9 + 0.1
    topics = sorted({t for _, t, _ in msgs})
    nodes = {t: BackgroundNode(f"bench_pub_{k}", domain) for k, t in enumerate(topics)}
    pubs = {t: n.node.create_publisher(type(next(m for _, tt, m in msgs if tt == t)), t, 10) for t, n in nodes.items()}
    end = time.monotonic() + 30
    while time.monotonic() < end and not all(p.get_subscription_count() for p in pubs.values()):
        time.sleep(0.1)
    speed = fps / 10.0  # the bag's frames are 10 Hz
    t0, wall0, sets, k = msgs[0][0], time.monotonic(), 0, 0
    stamp0 = int(time.time() * 1e9)
    while time.monotonic() - wall0 < seconds:
        base = k * length
        for t, topic, msg in msgs:
            due = wall0 + (base + (t - t0) * 1e-9) / speed
            if due - wall0 >= seconds:
                break
            if due > time.monotonic():
                time.sleep(due - time.monotonic())
            offset_ns = int((base + (t - t0) * 1e-9) / speed * 1e9)  # stamps follow the wall clock
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp0 + offset_ns, 1_000_000_000)
            pubs[topic].publish(msg)
            sets += topic == topics[0]
        k += 1
    for n in nodes.values():
        n.close()
    return sets


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a running process (all its threads), from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def matrix_messages(bag: Path, cameras: int, rate_hz: float, raw: bool, raw_encoding: str = "mono8") -> tuple:
    """([(t_ns, topic, rclpy message)] of the first ``cameras`` cameras at ``rate_hz`` and the IMU, raw Image
    in ``raw_encoding`` (decoded once here; bgr8 as a colour camera's driver sends it) or CompressedImage;
    seconds of data; images)."""
    import cv2
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    from sensor_msgs.msg import CompressedImage, Image, Imu

    topics = {f"/cam{i}/image_raw/compressed" for i in range(cameras)}
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic in topics or c.topic == "/imu/data"]
        msgs = [(t, c.topic, raw_msg) for c, t, raw_msg in reader.messages(connections=conns)]
    stamps = sorted({t for t, topic, _ in msgs if topic in topics})
    every = max(1, int(round(1.0 / (rate_hz * np.median(np.diff(stamps)) * 1e-9))))
    keep = set(stamps[::every])
    out, images = [], 0
    for t, topic, data in msgs:
        if topic == "/imu/data":
            out.append((t, topic, deserialize_message(data, Imu)))
        elif t in keep:
            msg = deserialize_message(data, CompressedImage)
            images += 1
            if raw:
                img = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_GRAYSCALE)
                if raw_encoding == "bgr8":
                    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
                msg = Image(header=msg.header, height=img.shape[0], width=img.shape[1],
                            step=img.shape[1] * img[0, 0].size, encoding=raw_encoding, data=img.tobytes())
                topic = topic[: -len("/compressed")]
            out.append((t, topic, msg))
    return out, (stamps[-1] - stamps[0]) * 1e-9, images


def publish_at_1x(domain: int, msgs: list) -> None:
    """``msgs`` at their recorded pace with fresh stamps, once every topic has a subscriber."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    topics = sorted({topic for _, topic, _ in msgs})
    nodes = {t: BackgroundNode(f"bench_pub_{k}", domain) for k, t in enumerate(topics)}
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {t: n.node.create_publisher(type(next(m for _, tt, m in msgs if tt == t)), t, qos)
            for t, n in nodes.items()}
    end = time.monotonic() + 60
    while time.monotonic() < end and not all(p.get_subscription_count() for p in pubs.values()):
        time.sleep(0.1)
    time.sleep(0.5)
    t0, wall0, stamp0 = msgs[0][0], time.monotonic(), int(time.time() * 1e9)
    for t, topic, msg in msgs:
        time.sleep(max(0.0, wall0 + (t - t0) * 1e-9 - time.monotonic()))
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp0 + (t - t0), 1_000_000_000)
        pubs[topic].publish(msg)
    for n in nodes.values():
        n.close()


def matrix(bag: Path, rig: Path, cpus: str, views: int, cameras=(2, 4, 6), rates=(15.0, 30.0),
           rows_only=None, raw_encoding: str = "mono8") -> list:
    """The DDS matrix (module docstring, 3.); one dict per configuration."""
    import bench_replay_speed as speed

    work = Path(tempfile.mkdtemp(prefix="bench_node_matrix_"))
    messages, _ = speed.load(bag)
    rows = []
    print("| cameras | Hz | transport | CPU s per s of data (node) | node ms/image | x decode | x KLT fwd | "
          "frame-set latency median / p95 (ms) | hold latency median / p95 (ms) | hold estimate median (ms) | holds | "
          "estimates | "
          "dropped busy | SIGINT to exit (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for cams, rate in (rows_only or [(c, r) for c in cameras for r in rates]):
        for raw in (True, False):
            msgs, seconds, images = matrix_messages(bag, cams, rate, raw, raw_encoding)
            unit = speed.unit_costs(messages, rig)
            domain = random.randint(1, 100)
            env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_LOG_DIR=str(work / "ros_log"))
            listener = Listener(domain)
            name = f"{cams}x{rate:g}_{'raw' if raw else 'jpeg'}"
            node = start([str(BIN / "estimator"), "--ros-args", "-p",
                          f"rig_file:={speed.sub_rig(rig, cams, work)}", "-p",
                          f"image_transport:={'raw' if raw else 'compressed'}", "-p", "camera_timeout_s:=1.0"],
                         env, work / f"node_{name}.log", cpus)
            try:
                if not listener.wait(listener.started, 90):
                    raise SystemExit(f"the node did not start; see {work}")
                cpu0 = cpu_seconds(node.pid)
                publish_at_1x(domain, msgs)
                listener.wait(listener.done, 60)
                cpu = cpu_seconds(node.pid) - cpu0
                t0 = time.monotonic()
                node.send_signal(signal.SIGINT)
                node.wait(30)
                exit_s = time.monotonic() - t0
            finally:
                stop(node)
                listener.close()
            est = listener.diag.get("estimation", ("", {}))[1]
            per_image = 1e3 * cpu / images
            row = {"cameras": cams, "rate_hz": rate, "transport": raw_encoding if raw else "compressed",
                   "images": images, "data_s": seconds, "cpu_per_data_s": cpu / seconds,
                   "ms_per_image": per_image, **unit, "x_decode": per_image / unit["decode_ms"],
                   "x_klt": per_image / unit["klt_forward_ms"],
                   "latency_median_ms": est.get("frame set latency median (ms)"),
                   "latency_p95_ms": est.get("frame set latency p95 (ms)"), "holds": int(est.get("holds", 0)),
                   # before the two workers: "latency median (ms)", the frame sets that completed an estimate
                   "hold_latency_median_ms": est.get("hold latency median (ms)", est.get("latency median (ms)")),
                   "hold_latency_p95_ms": est.get("hold latency p95 (ms)"),
                   "hold_estimate_median_ms": est.get("hold estimate median (ms)"),
                   "views": views, "estimates": int(est.get("estimates", 0)),
                   "dropped_busy": int(est.get("dropped: worker: frame set dropped while the estimator is busy",
                                               0)), "sigint_exit_s": exit_s}
            rows.append(row)
            print(f"| {cams} | {rate:g} | {row['transport']} | {row['cpu_per_data_s']:.2f} | {per_image:.2f} | "
                  f"{row['x_decode']:.2f} | {row['x_klt']:.2f} | {row['latency_median_ms']} / "
                  f"{row['latency_p95_ms']} | {row['hold_latency_median_ms']} / {row['hold_latency_p95_ms']} | "
                  f"{row['hold_estimate_median_ms']} | "
                  f"{row['holds']}/{views} | {row['estimates']} | {row['dropped_busy']} | {exit_s:.2f} |",
                  flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bag", type=Path, help="bag to play (default: render one)")
    ap.add_argument("--rig", type=Path, help="its rig file (with --bag)")
    ap.add_argument("--cpus", default="", help="taskset CPU list for the node, e.g. 0 (one core)")
    ap.add_argument("--rate", type=float, default=1.0, help="playback speed of the bag run")
    ap.add_argument("--seconds", type=float, default=20.0, help="duration of the stream run")
    ap.add_argument("--fps", type=float, default=10.0, help="frame rate of the stream run")
    ap.add_argument("--work-queue-size", type=int, default=8)
    ap.add_argument("--json", help="also write the results to this file")
    ap.add_argument("--matrix", nargs=2, type=Path, metavar=("BAG", "RIG"),
                    help="run the camera/rate/transport matrix on this 6-camera JPEG stream bag and rig instead")
    ap.add_argument("--views", type=int, default=4, help="holds of the --matrix bag")
    ap.add_argument("--matrix-cameras", type=int, nargs="+", default=[2, 4, 6], help="camera counts of --matrix")
    ap.add_argument("--matrix-rates", type=float, nargs="+", default=[15.0, 30.0], help="frame rates of --matrix")
    ap.add_argument("--matrix-rows", nargs="+", metavar="CAMSxHZ",
                    help="only these rows of --matrix, e.g. 6x30 6x15 2x30 (instead of cameras x rates)")
    ap.add_argument("--raw-encoding", choices=("mono8", "bgr8"), default="mono8",
                    help="encoding of the raw images of --matrix (bgr8: as a colour camera's driver sends them)")
    args = ap.parse_args(argv)
    if args.matrix:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        only = None
        if args.matrix_rows:
            try:
                only = [(int(c), float(r)) for c, r in (row.lower().split("x") for row in args.matrix_rows)]
            except ValueError:
                ap.error(f"--matrix-rows: expected CAMERASxHZ such as 6x30, got {' '.join(args.matrix_rows)}")
        rows = matrix(*args.matrix, args.cpus, args.views, args.matrix_cameras, args.matrix_rates, only,
                      args.raw_encoding)
        print(f"load average {os.getloadavg()[0]:.1f} (machine shared: compare ratios, not absolute times)")
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=2))
        return 0
    work = Path(tempfile.mkdtemp(prefix="bench_node_"))
    bag, rig = (args.bag, args.rig) if args.bag else render(work)
    expected = replay(bag, rig, work / "replay.csv")
    out = {"cpus": args.cpus or "all", "load_avg_start": os.getloadavg()[0], "replay_estimates": len(expected)}
    for run in ("bag", "stream"):
        domain = random.randint(1, 100)
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_LOG_DIR=str(work / "ros_log"))
        listener = Listener(domain)
        node = player = None
        try:
            node = start([str(BIN / "estimator"), "--ros-args", "-p", f"rig_file:={rig}", "-p",
                          f"work_queue_size:={args.work_queue_size}", "-p", "camera_timeout_s:=1.0"], env,
                         work / f"node_{run}.log", args.cpus)
            if not listener.wait(listener.started, 60):
                print(f"the node did not start; see {work}", file=sys.stderr)
                return 1
            if run == "bag":
                player = start([str(BIN / "nrmpc"), "play", str(bag), "--rate", str(args.rate),
                                "--wait-for-subscribers", "30", "--quiet"], env, work / "play.log")
                player.wait(600)
                sent = None
            else:
                sent = stream(domain, bag, args.seconds, args.fps)
            listener.wait(listener.done, 120)
        finally:
            stop(player)
            stop(node)
            listener.close()
        est = listener.diag.get("estimation", ("", {}))[1]
        r = {"frame_sets_processed": int(est.get("frame sets processed", 0)), "estimates": int(est.get("estimates", 0)),
             "dropped_busy": int(est.get("dropped: worker: frame set dropped while the estimator is busy", 0)),
             "latency_ms_median": est.get("latency median (ms)"),
             "processing_ms_median": est.get("processing median (ms)")}
        if run == "bag":
            common = sorted(set(expected) & set(listener.gravity))
            r["estimates_matching_replay"] = len(common)
            r["max_gravity_difference"] = max((float(np.max(np.abs(np.subtract(listener.gravity[s], expected[s]))))
                                               for s in common), default=None)
        else:
            r["frame_sets_sent"] = sent
        out[run] = r
    out["load_avg_end"] = os.getloadavg()[0]
    b, s = out["bag"], out["stream"]
    print(f"bag at {args.rate:g}x: {b['estimates']} estimates ({b['estimates_matching_replay']} of the replay's "
          f"{len(expected)} at the same stamps, largest gravity difference {b['max_gravity_difference']} m/s^2); "
          f"latency median {b['latency_ms_median']} ms; processing per frame set median {b['processing_ms_median']} ms")
    print(f"stream at {args.fps:g} fps for {args.seconds:g} s: {s['frame_sets_sent']} frame sets sent, "
          f"{s['frame_sets_processed']} processed, {s['dropped_busy']} dropped while busy; {s['estimates']} estimates; "
          f"latency median {s['latency_ms_median']} ms")
    print(f"node CPUs: {out['cpus']}; load average {out['load_avg_start']:.1f} -> {out['load_avg_end']:.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
