#!/usr/bin/env python3
"""Benchmark of the estimator node over DDS (issue 5 targets).

1. latency: the sample bag played into the node with ``nrmpc play``; the node
   measures, per estimate, the time from the arrival of the last image of the
   synchronized set to the publication of the estimate (``latency_ms_median``
   in /diagnostics).
2. drops: 4 VGA cameras at 10 Hz (+ IMU at 200 Hz) published by this script
   for ``--seconds``: the bag's static views, each held for ``--hold`` frames;
   counts the sets the node synchronized, processed and dropped while busy.

The node runs as its own process (``--cpus 0`` pins it to one core with
taskset). Usage: python scripts/bench_node.py [--cpus 0] [--seconds 30] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from nrmpc_ros.ros_play import BackgroundNode

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
CAMERAS = [f"/cam{i}/image_raw" for i in range(4)]
IMU = "/imu/data"


def _start_node(env, cpus, extra, log):
    cmd = [str(BIN / "estimator"), "--ros-args", "--params-file", str(REPO / "config" / "estimator.yaml"), *extra]
    if cpus and shutil.which("taskset"):
        cmd = ["taskset", "-c", cpus] + cmd
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=open(log, "w"), stderr=subprocess.STDOUT,
                            start_new_session=True)


def _kill(proc):
    if proc is None or proc.poll() is not None:
        return
    for sig in (signal.SIGINT, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
            proc.wait(10)
            return
        except (ProcessLookupError, subprocess.TimeoutExpired):
            continue


class DiagListener(BackgroundNode):
    """Latest nrmpc_ros diagnostics and every estimate's arrival, in a context of its own."""

    def __init__(self, domain):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped

        super().__init__("bench_listener", domain)
        self.diag, self.poses = {}, 0
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.node.create_subscription(PoseStamped, "/estimator/relative_pose", self._on_pose, 50)
        self.start()

    def _on_diag(self, msg):
        for st in msg.status:
            if st.name.startswith("nrmpc_ros"):
                self.diag = {kv.key: kv.value for kv in st.values}

    def _on_pose(self, _msg):
        self.poses += 1

    def wait_ready(self, timeout=90.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.diag and self.node.count_publishers("/estimator/relative_pose"):
                return True
            time.sleep(0.1)
        return False

    def settle(self, timeout=120.0):
        """Wait until the node has processed or dropped every set it synchronized (twice in a row)."""
        end, ok = time.monotonic() + timeout, 0
        while time.monotonic() < end and ok < 2:
            time.sleep(1.0)
            d = self.diag
            done = d and int(d["processed_sets"]) + int(d["dropped_sets_busy"]) == int(d["synchronized_sets"])
            ok = ok + 1 if done else 0
        time.sleep(1.0)
        return dict(self.diag)



def _load_bag_views():
    """The sample bag's image sets (raw bytes per camera) with the IMU accelerometer near each."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    sets, imu = {}, []
    with AnyReader([REPO / "bags" / "sample"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic in CAMERAS + [IMU]]
        for conn, t, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == IMU:
                a = msg.linear_acceleration
                imu.append((t, (a.x, a.y, a.z)))
            else:
                sets.setdefault(t, {})[conn.topic] = (msg.width, msg.height, msg.encoding, bytes(msg.data))
    views = []
    for t in sorted(sets):
        if len(sets[t]) == len(CAMERAS):
            accel = min(imu, key=lambda s: abs(s[0] - t))[1]
            views.append(([sets[t][c] for c in CAMERAS], accel))
    return views


def stream_10hz(rclpy, domain: int, seconds: float, hold: int, rate_hz: float = 10.0, imu_hz: float = 200.0) -> int:
    """Publish 4 cameras at ``rate_hz`` and the IMU at ``imu_hz``; returns the number of image sets sent."""
    from rclpy.context import Context
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import Image, Imu

    views = _load_bag_views()
    nodes, pubs = [], []
    for k, topic in enumerate(CAMERAS + [IMU]):  # one participant per topic, like separate drivers
        ctx = Context()
        rclpy.init(context=ctx, domain_id=domain)
        nodes.append(rclpy.create_node(f"bench_pub_{k}", context=ctx))
        pubs.append(nodes[-1].create_publisher(Imu if topic == IMU else Image, topic, QoSProfile(depth=10)))
    end = time.monotonic() + 60
    while time.monotonic() < end and not all(p.get_subscription_count() for p in pubs):
        time.sleep(0.1)
    time.sleep(0.5)
    msgs = []
    for cams, accel in views:
        per_cam = []
        for w, h, enc, data in cams:
            m = Image(width=w, height=h, encoding=enc, step=len(data) // h)
            m.data = data
            per_cam.append(m)
        msgs.append((per_cam, accel))
    imu = Imu()
    t0_wall = time.monotonic()
    stamp0 = 1_800_000_000.0
    n_sets, k_imu = 0, 0
    frame_dt, imu_dt = 1.0 / rate_hz, 1.0 / imu_hz
    while True:
        now = time.monotonic() - t0_wall
        if now >= seconds:
            break
        next_frame, next_imu = n_sets * frame_dt, k_imu * imu_dt
        if next_imu <= next_frame:
            due, is_imu = next_imu, True
        else:
            due, is_imu = next_frame, False
        if due > now:
            time.sleep(due - now)
        view = msgs[(int(due / frame_dt) // hold) % len(msgs)]
        sec, frac = divmod(stamp0 + due, 1.0)
        if is_imu:
            imu.header.stamp.sec, imu.header.stamp.nanosec = int(sec), int(frac * 1e9)
            imu.linear_acceleration.x, imu.linear_acceleration.y, imu.linear_acceleration.z = view[1]
            pubs[-1].publish(imu)
            k_imu += 1
        else:
            for pub, m in zip(pubs, view[0]):
                m.header.stamp.sec, m.header.stamp.nanosec = int(sec), int(frac * 1e9)
                pub.publish(m)
            n_sets += 1
    for node in nodes:
        ctx = node.context
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return n_sets


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cpus", default="", help="taskset CPU list for the node, e.g. 0 (one core)")
    ap.add_argument("--seconds", type=float, default=30.0, help="duration of the 10 Hz stream")
    ap.add_argument("--hold", type=int, default=10, help="frames each static view is held in the 10 Hz stream")
    ap.add_argument("--work-queue-size", type=int, default=2)
    ap.add_argument("--json", help="also write the results to this file")
    ap.add_argument("--skip-bag", action="store_true", help="only the 10 Hz stream")
    args = ap.parse_args(argv)
    try:
        import rclpy
    except ImportError:
        print("bench_node: rclpy is not importable: install the ros extra: pip install -e .[ros]", file=sys.stderr)
        return 2
    out = {"cpus": args.cpus or "all", "load_avg_start": os.getloadavg()[0]}
    logdir = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_node_{os.getpid()}"
    logdir.mkdir(parents=True, exist_ok=True)
    runs = [] if args.skip_bag else ["bag"]
    runs.append("stream")
    for run in runs:
        domain = random.randint(1, 100)
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_LOG_DIR=str(logdir / "ros_log"))
        listener = DiagListener(domain)
        node = player = None
        try:
            node = _start_node(env, args.cpus, ["-p", f"work_queue_size:={args.work_queue_size}"],
                               logdir / f"node_{run}.log")
            if not listener.wait_ready():
                print(f"node did not start; see {logdir}", file=sys.stderr)
                return 1
            if run == "bag":
                player = subprocess.Popen([str(BIN / "nrmpc"), "play", str(REPO / "bags" / "sample"), "--topics",
                                           *CAMERAS, IMU, "--wait-for-subscribers", "60", "--quiet"], cwd=REPO,
                                          env=env, start_new_session=True)
                player.wait(600)
                sent = 18
            else:
                sent = stream_10hz(rclpy, domain, args.seconds, args.hold)
            d = listener.settle()
        finally:
            _kill(player)
            _kill(node)
            listener.close()
        synced = int(d.get("synchronized_sets", 0))
        out[run] = {
            "sets_sent": sent, "sets_synchronized": synced, "sets_processed": int(d.get("processed_sets", 0)),
            "dropped_busy": int(d.get("dropped_sets_busy", 0)), "lost_before_sync": sent - synced,
            "estimates": int(d.get("estimates_published", 0)), "estimates_received": listener.poses,
            "latency_ms_median": d.get("latency_ms_median", ""), "processing_ms_median": d.get("processing_ms_median"),
            "processing_ms_max": d.get("processing_ms_max"),
            "pair_time_ms_last": d.get("time_ms_last", ""), "sync_drops": {k: v for k, v in d.items()
                                                                           if k.startswith("sync_dropped")},
        }
    out["load_avg_end"] = os.getloadavg()[0]
    for run in runs:
        r = out[run]
        what = "sample bag (nrmpc play, 1x)" if run == "bag" else f"4 VGA cameras at 10 Hz for {args.seconds:g} s"
        print(f"{what}: sets sent {r['sets_sent']}, synchronized {r['sets_synchronized']}, processed "
              f"{r['sets_processed']}, dropped while busy {r['dropped_busy']}, lost before sync "
              f"{r['lost_before_sync']}; estimates {r['estimates']}; latency median {r['latency_ms_median']} ms "
              f"(processing per set: median {r['processing_ms_median']} ms, max {r['processing_ms_max']} ms)")
    print(f"node CPUs: {out['cpus']}; load average {out['load_avg_start']:.1f} -> {out['load_avg_end']:.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
