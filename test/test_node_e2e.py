"""End to end over DDS: the estimator node and ``nrmpc play`` as separate processes, a listener in this one.

Each test uses its own random ROS_DOMAIN_ID; every process started here is
killed with its process group in ``finally``.
"""

from __future__ import annotations

import csv
import math
import os
import random
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "sample"
RIG = REPO / "config" / "sample_cross4.yaml"
PARAMS = REPO / "config" / "estimator.yaml"
BIN = Path(sys.executable).parent
CAMERAS = [f"/cam{i}/image_raw" for i in range(4)]
IMU = "/imu/data"

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: install the ros extra (pip install -e .[ros])")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped, Vector3Stamped  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from nrmpc_ros.core.so3 import angle_between, quat_xyzw_to_matrix, rotation_angle  # noqa: E402
from nrmpc_ros.ros_play import BackgroundNode  # noqa: E402

pytestmark = pytest.mark.skipif(not BAG.exists(), reason="the sample bag bags/sample is not in this checkout")


# --------------------------------------------------------------------------- helpers
def _stamp(msg_stamp) -> float:
    return msg_stamp.sec + 1e-9 * msg_stamp.nanosec


class Listener(BackgroundNode):
    """Collects ~/relative_pose, ~/gravity and /diagnostics in this process (own context and domain)."""

    def __init__(self, domain: int):
        super().__init__("e2e_listener", domain)
        self.poses, self.gravity, self.diagnostics = [], [], []
        self.arrival = {}
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(PoseStamped, "/estimator/relative_pose", self._on_pose, qos)
        self.node.create_subscription(Vector3Stamped, "/estimator/gravity", self.gravity.append, qos)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, qos)
        self.start()

    def _on_pose(self, msg):
        self.arrival[_stamp(msg.header.stamp)] = time.monotonic()
        self.poses.append(msg)

    def _on_diag(self, msg):
        for status in msg.status:
            if status.name.startswith("nrmpc_ros"):
                self.diagnostics.append({kv.key: kv.value for kv in status.values})

    def last_diag(self) -> dict:
        return self.diagnostics[-1] if self.diagnostics else {}

    def wait_for_node(self, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.node.count_publishers("/estimator/relative_pose") and self.diagnostics:
                return True
            time.sleep(0.1)
        return False



def _env(domain: int, tmp: Path) -> dict:
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain)
    env["ROS_LOG_DIR"] = str(tmp / "ros_log")
    env["PYTHONUNBUFFERED"] = "1"
    env["RCUTILS_COLORIZED_OUTPUT"] = "0"
    return env


def _start(cmd: list, env: dict, log: Path) -> subprocess.Popen:
    out = open(log, "w")
    try:
        return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    finally:
        out.close()


def _kill(proc: subprocess.Popen | None, grace: float = 10.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(wait)
            return
        except subprocess.TimeoutExpired:
            continue


def _read_bag(bag: Path) -> dict:
    """Ground truth of the bag: stamp -> (R_world_body, p_world_body), stamp -> gravity in body."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    poses, gravity = {}, {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic in ("/ground_truth/pose", "/ground_truth/gravity")]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            s = round(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, 6)
            if conn.topic == "/ground_truth/pose":
                q, p = msg.pose.orientation, msg.pose.position
                poses[s] = (quat_xyzw_to_matrix([q.x, q.y, q.z, q.w]), np.array([p.x, p.y, p.z]))
            else:
                gravity[s] = np.array([msg.vector.x, msg.vector.y, msg.vector.z])
    return {"pose": poses, "gravity": gravity}


def _replay(bag: Path, tmp: Path) -> dict:
    """``nrmpc replay`` on the same bag: stamp -> row."""
    out = tmp / "replay.csv"
    proc = subprocess.run([str(BIN / "nrmpc"), "replay", str(bag), "--rig", str(RIG), "--method", "auto",
                           "--out", str(out)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"nrmpc replay failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    with open(out) as fh:
        return {round(float(r["stamp"]), 6): r for r in csv.DictReader(fh)}


def _run(tmp: Path, bag: Path, extra_params: list) -> dict:
    """Start the node, play ``bag`` into it, collect what it publishes; return everything for the asserts."""
    domain = random.randint(1, 100)
    env = _env(domain, tmp)
    listener = Listener(domain)
    node = player = None
    try:
        node = _start([str(BIN / "estimator"), "--ros-args", "--params-file", str(PARAMS), *extra_params], env,
                      tmp / "node.log")
        assert listener.wait_for_node(90), f"node did not come up:\n{(tmp / 'node.log').read_text()}"
        player = _start([str(BIN / "nrmpc"), "play", str(bag), "--topics", *CAMERAS, IMU,
                         "--wait-for-subscribers", "60"], env, tmp / "play.log")
        player.wait(300)
        assert player.returncode == 0, (tmp / "play.log").read_text()
        deadline = time.monotonic() + 120  # let the worker finish the sets it has
        settled = 0
        while time.monotonic() < deadline and settled < 2:
            time.sleep(1.0)
            d = listener.last_diag()
            done = d and int(d["processed_sets"]) + int(d["dropped_sets_busy"]) == int(d["synchronized_sets"])
            settled = settled + 1 if done else 0
        time.sleep(1.0)
        assert node.poll() is None, f"the node died:\n{(tmp / 'node.log').read_text()}"
    finally:
        _kill(player)
        _kill(node)
        listener.close()
    log = (tmp / "node.log").read_text()
    print(log[-3000:])
    return {"poses": listener.poses, "gravity": listener.gravity, "diag": listener.last_diag(), "log": log,
            "diags": listener.diagnostics}


def _errors(result: dict, truth: dict, replay: dict):
    """Per estimate: gravity error (deg), rotation error (deg) against ground truth, and against the replay."""
    grav = {round(_stamp(m.header.stamp), 6): np.array([m.vector.x, m.vector.y, m.vector.z])
            for m in result["gravity"]}
    rows = []
    for m in result["poses"]:
        s = round(_stamp(m.header.stamp), 6)
        q = m.pose.orientation
        R = quat_xyzw_to_matrix([q.x, q.y, q.z, q.w])
        g = grav.get(s)
        rep = replay.get(s)
        assert rep is not None, f"the node published an estimate at {s} that nrmpc replay does not have"
        ref = round(float(rep["ref_stamp"]), 6)
        R_ref, _ = truth["pose"][ref]
        R_cur, _ = truth["pose"][s]
        R_gt = R_ref.T @ R_cur
        R_rep = quat_xyzw_to_matrix([float(rep[k]) for k in ("qx", "qy", "qz", "qw")])
        g_rep = np.array([float(rep[k]) for k in ("gx", "gy", "gz")]) if rep["gx"] else None
        rows.append({
            "stamp": s,
            "frame_id": m.header.frame_id,
            "rot_err": math.degrees(float(rotation_angle(R_gt.T @ R))),
            "grav_err": math.degrees(float(angle_between(g, truth["gravity"][s]))) if g is not None else None,
            "rot_vs_replay": math.degrees(float(rotation_angle(R_rep.T @ R))),
            "grav_vs_replay": (math.degrees(float(angle_between(g, g_rep)))
                               if g is not None and g_rep is not None else None),
            "norm": float(np.linalg.norm(g)) if g is not None else None,
        })
    return rows


def _node_and_replay(bag: Path, tmp: Path, label: str):
    """Replay ``bag`` offline, play it to the node over DDS; (replay, node result, per-estimate rows) against the
    sample bag's ground truth."""
    replay = _replay(bag, tmp)
    result = _run(tmp, bag, ["-p", "work_queue_size:=2"])
    rows = _errors(result, _read_bag(BAG), replay)
    print(f"{label}node: {len(rows)} estimates, replay: {len(replay)}; diagnostics: {result['diag']}")
    for r in rows:
        print(r)
    return replay, result, rows


# --------------------------------------------------------------------------- tests
def test_node_over_dds_matches_ground_truth_and_replay(tmp_path):
    replay, result, rows = _node_and_replay(BAG, tmp_path, "")
    assert len(replay) >= 5
    diag = result["diag"]

    dropped = int(diag.get("dropped_sets_busy", 0))
    assert int(diag["synchronized_sets"]) == 18, "every image set of the bag reaches the node over DDS"
    assert len(result["gravity"]) == len(result["poses"])
    assert len(rows) >= len(replay) - dropped and len(rows) >= 5
    assert all(r["frame_id"] == "base_link" for r in rows)
    assert all(abs(r["norm"] - 9.81) < 1e-6 for r in rows)
    # every estimate is 4pt-bending (IMU present all along)
    assert diag["active_method"] == "4pt-bending"
    assert "pipeline_methods 6pt-bending" not in diag
    assert statistics.median(r["grav_err"] for r in rows) <= 1.0
    assert statistics.median(r["rot_err"] for r in rows) <= 0.5
    # the same pipeline as the replay: the same estimates up to the IMU samples available in time
    assert max(r["rot_vs_replay"] for r in rows) <= 0.2
    assert max(r["grav_vs_replay"] for r in rows) <= 0.5
    # latency from the last image of a set to the published estimate, as the node measures it
    print(f"latency median {diag['latency_ms_median']} ms, processing median {diag['processing_ms_median']} ms, "
          f"dropped while busy {dropped}")


def _cut_imu(src: Path, dst: Path, keep_s: float) -> float:
    """A copy of ``src`` whose IMU messages stop ``keep_s`` seconds after the start; returns the cut time (s)."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(src) as reader, Writer(dst, version=9) as writer:
        cut_ns = reader.start_time + int(keep_s * 1e9)
        out = {}
        for conn in reader.connections:
            out[conn.id] = writer.add_connection(conn.topic, conn.msgtype, typestore=store)
        for conn, stamp, raw in reader.messages():
            if conn.topic == IMU and stamp > cut_ns:
                continue
            writer.write(out[conn.id], stamp, raw)
    return cut_ns * 1e-9


def test_imu_cut_off_half_way_falls_back_to_6pt_bending(tmp_path):
    bag = tmp_path / "imu_cut"
    cut = _cut_imu(BAG, bag, keep_s=8.0)
    _, result, rows = _node_and_replay(bag, tmp_path, f"IMU cut at {cut:.3f}; ")
    diag = result["diag"]

    log = result["log"]
    assert log.count("falling back to 6pt-bending") == 1, "the switch is logged once"
    assert diag["active_method"] == "6pt-bending"
    before = [r for r in rows if r["stamp"] <= cut]
    after = [r for r in rows if r["stamp"] > cut + 0.5]
    assert len(before) >= 2 and len(after) >= 2, "it keeps publishing after the IMU stops"
    assert int(diag.get("pipeline_methods 6pt-bending", 0)) >= len(after) - int(diag.get("dropped_sets_busy", 0))
    assert statistics.median(r["grav_err"] for r in after) <= 2.0
    assert statistics.median(r["rot_err"] for r in rows) <= 0.5
    assert max(r["grav_vs_replay"] for r in rows) <= 0.5
