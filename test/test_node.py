"""Unit tests of the estimator node: parameters, the auto switch (fake clock), drop counting, bad input.

The node runs in this process on a real rclpy context of its own (random
domain); its worker thread is left stopped where a test drives it by hand.
"""

from __future__ import annotations

import math
import random
import time
from pathlib import Path

import numpy as np
import pytest

from nrmpc_ros.errors import InputError

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: install the ros extra (pip install -e .[ros])")

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import PoseStamped, Vector3Stamped  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Image, Imu  # noqa: E402

from nrmpc_ros import node as estimator_node  # noqa: E402
from nrmpc_ros.core.so3 import exp_so3, quat_xyzw_to_matrix  # noqa: E402
from nrmpc_ros.frontend.pipeline import PipelineEstimate  # noqa: E402
from nrmpc_ros.node import DropQueue, ErrorLog, EstimatorNode, MethodSelector, main  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
RIG = str(REPO / "config" / "sample_cross4.yaml")
CAMERAS = [f"/cam{i}/image_raw" for i in range(4)]


@pytest.fixture
def ctx():
    context = Context()
    rclpy.init(context=context, domain_id=random.randint(101, 200))
    yield context
    rclpy.try_shutdown(context=context)


def make_node(ctx, start_worker=False, **params):
    overrides = [Parameter("rig_file", value=RIG)] + [Parameter(k, value=v) for k, v in params.items()]
    return EstimatorNode(start_worker=start_worker, context=ctx, parameter_overrides=overrides)


def image_msg(stamp: float, width=640, height=480, encoding="mono8", value=None):
    msg = Image(height=height, width=width, encoding=encoding, step=width)
    msg.header.stamp.sec = int(stamp)
    msg.header.stamp.nanosec = int(round((stamp - int(stamp)) * 1e9))
    rng = np.random.default_rng(int(stamp * 1000))
    pixels = rng.integers(0, 255, (height, width), dtype=np.uint8) if value is None else np.full((height, width),
                                                                                                  value, np.uint8)
    msg.data = pixels.tobytes()
    return msg


def imu_msg(stamp: float, accel=(0.0, 0.0, 9.81)):
    msg = Imu()
    msg.header.stamp.sec = int(stamp)
    msg.header.stamp.nanosec = int(round((stamp - int(stamp)) * 1e9))
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = accel
    return msg


def diag_values(node) -> dict:
    return {kv.key: kv.value for kv in node.diagnostics().status[0].values}


# --------------------------------------------------------------------------- pure logic
def test_auto_switches_with_imu_age_and_logs_each_switch_once():
    sel = MethodSelector("auto", max_age_s=0.5, imu_enabled=True)
    assert sel.select(10.0) == ("6pt-bending", "no IMU sample yet: using 6pt-bending")
    t = 10.0
    messages = []
    for _ in range(30):  # IMU at 200 Hz, frames at 10 Hz (fake clock = stamps)
        for k in range(20):
            sel.imu_sample(t + k * 0.005)
        t += 0.1
        method, why = sel.select(t)
        messages.append(why)
        assert method == "4pt-bending"
    assert [m for m in messages if m] == [messages[0]] and "4pt-bending" in messages[0]
    # the IMU stops: 4pt-bending until the newest sample is older than max_age_s, then 6pt-bending, once
    last_imu = sel.last_imu_stamp
    results = [sel.select(last_imu + dt) for dt in np.arange(0.1, 3.0, 0.1)]
    assert all(m == "4pt-bending" for (m, _), dt in zip(results, np.arange(0.1, 3.0, 0.1)) if dt <= 0.5 - 1e-9)
    assert results[-1][0] == "6pt-bending"
    switch_msgs = [w for _, w in results if w]
    assert len(switch_msgs) == 1 and "falling back to 6pt-bending" in switch_msgs[0]
    # and back when samples arrive again
    sel.imu_sample(last_imu + 5.0)
    method, why = sel.select(last_imu + 5.05)
    assert method == "4pt-bending" and why
    assert sel.switches == 3


def test_forced_and_imu_less_modes():
    assert MethodSelector("6pt-nonbending").select(1.0)[0] == "6pt-nonbending"
    sel = MethodSelector("auto", imu_enabled=False)
    sel.imu_sample(1.0)
    assert sel.select(1.0)[0] == "6pt-bending"
    with pytest.raises(InputError, match="parameter method"):
        MethodSelector("8pt")


def test_drop_queue_counts_what_it_drops():
    q = DropQueue(2)
    assert [q.put(i) for i in range(5)] == [True, True, False, False, False]
    assert (q.accepted, q.dropped) == (2, 3)
    assert q.get(0.01) == 0 and q.get(0.01) == 1 and q.get(0.01) is None


def test_error_log_says_log_once_per_topic_and_kind():
    log = ErrorLog()
    assert log.report("/a", "size", "x") and not log.report("/a", "size", "y")
    assert log.report("/a", "nan", "z") and log.report("/b", "size", "w")
    assert log.per_topic() == {"/a": 3, "/b": 1}


def test_help_needs_no_ros_graph(capsys):
    assert main(["estimator", "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: estimator")
    for name in ("rig_file", "method", "sync_tolerance_s", "queue_size", "imu_topic", "imu_max_age_s",
                 "image_transport", "pipeline.tracking.mode", "pipeline.static.max_motion_px", "pipeline.min_tilt_deg"):
        assert f"  {name} [default" in out
    assert main(["estimator", "--bogus"]) == 2


# --------------------------------------------------------------------------- the node in-process
def test_parameters_defaults_descriptors_and_pipeline_config(ctx):
    node = make_node(ctx, **{"pipeline.tracking.mode": "klt", "pipeline.estimator.threshold_px": 3.0,
                             "pipeline.min_tilt_deg": 4.0})
    try:
        assert node.imu_topic == "/imu/data"  # from the rig file's imu block
        assert node.camera_topics == CAMERAS
        assert node.params["method"] == "auto" and node.params["image_transport"] == "raw"
        assert node.config.tracking.mode == "klt" and node.config.min_tilt_deg == 4.0
        assert node.pipeline.estimator_options.threshold_px == 3.0
        for name in ("rig_file", "method", "sync_tolerance_s", "queue_size", "imu_topic", "imu_max_age_s",
                     "image_transport", "pipeline.tracking.max_tracks"):
            desc = node.describe_parameters([name])[0]
            assert len(desc.description) > 10, name
        assert node.describe_parameters(["rig_file"])[0].read_only
        # method may change at run time, to one of the allowed values only
        assert node.set_parameters([Parameter("method", value="6pt-bending")])[0].successful
        assert node.selector.mode == "6pt-bending"
        assert not node.set_parameters([Parameter("method", value="magic")])[0].successful
        assert node.count_subscribers("/imu/data") == 1
        assert all(node.count_subscribers(t) == 1 for t in CAMERAS)
    finally:
        node.destroy_node()


def test_compressed_transport_and_no_imu(ctx):
    node = make_node(ctx, image_transport="compressed", imu_topic="")
    try:
        assert node.camera_topics == [t + "/compressed" for t in CAMERAS]
        assert node.imu_topic == "" and node.count_subscribers("/imu/data") == 0
        assert node.selector.select(0.0)[0] == "6pt-bending"
    finally:
        node.destroy_node()


@pytest.mark.parametrize("params, match", [
    ({"method": "8pt"}, "parameter method"),
    ({"image_transport": "theora"}, "parameter image_transport"),
    ({"work_queue_size": 5}, "parameter work_queue_size"),
    ({"sync_tolerance_s": 0.0}, "parameter sync_tolerance_s"),
    ({"rig_file": "/nonexistent/rig.yaml"}, "rig.yaml"),
    ({"pipeline.min_tilt_deg": 4}, r"parameter pipeline.min_tilt_deg: expected a float, got 4 \(write 4.0\)"),
])
def test_bad_parameters_are_named(ctx, params, match):
    with pytest.raises(InputError, match=match):
        make_node(ctx, **params).destroy_node()


def test_missing_rig_file_is_a_clear_error(ctx):
    with pytest.raises(InputError, match="rig_file"):
        EstimatorNode(start_worker=False, context=ctx)


def test_sets_arriving_while_busy_are_dropped_and_counted(ctx):
    node = make_node(ctx, work_queue_size=1)  # worker stopped: it is "busy" for the whole test
    try:
        for k in range(4):
            stamp = 100.0 + 0.1 * k
            for i in range(4):
                node._on_image(i, image_msg(stamp + 0.001 * i))
        d = diag_values(node)
        assert d["synchronized_sets"] == "4"
        assert d["dropped_sets_busy"] == "3" and node.work.accepted == 1
        assert node.work.qsize() == 1
        # the queued set is processed (by hand here) and the count moves on
        item = node.work.get(0.1)
        assert item[0] == pytest.approx(100.0) and len(item[1]) == 4
        node.process(*item)
        assert diag_values(node)["processed_sets"] == "1"
    finally:
        node.destroy_node()


def test_worker_thread_takes_sets_off_the_executor(ctx):
    node = make_node(ctx, start_worker=True, work_queue_size=2)
    try:
        for k in range(3):
            for i in range(4):
                node._on_image(i, image_msg(200.0 + k, value=40 + k))
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and node.counters["processed_sets"] + node.work.dropped < 3:
            time.sleep(0.05)
        assert node.counters["processed_sets"] + node.work.dropped == 3
        assert node.counters["processed_sets"] >= 2
    finally:
        node.destroy_node()
    assert not node._worker.is_alive()


def test_bad_input_is_counted_and_the_node_goes_on(ctx):
    node = make_node(ctx)
    try:
        node._on_image(0, image_msg(1.0, encoding="yuv422"))
        node._on_image(0, image_msg(1.1, encoding="yuv422"))
        node._on_image(1, image_msg(1.0, width=320, height=240))
        node._on_imu(imu_msg(1.0, accel=(math.nan, 0.0, 9.81)))
        node._on_imu(imu_msg(1.0, accel=(0.0, 0.0, 9.81)))
        counts = node.errors.counts
        assert counts[("/cam0/image_raw", "decode")] == 2
        assert counts[("/cam1/image_raw", "size")] == 1
        assert counts[("/imu/data", "nan")] == 1
        assert "yuv422" in node.errors.last["/cam0/image_raw"]
        assert "320x240" in node.errors.last["/cam1/image_raw"]
        assert len(node._imu_buffer) == 1  # the good sample went through
        d = diag_values(node)
        assert d["errors /cam0/image_raw"] == "2" and d["errors /imu/data"] == "1"
        # good images still make a set
        for i in range(4):
            node._on_image(i, image_msg(2.0))
        assert node.work.qsize() == 1
    finally:
        node.destroy_node()


def test_a_camera_that_stops_is_reported_once(ctx):
    node = make_node(ctx, camera_timeout_s=0.5)
    try:
        now = time.monotonic()
        node._last_rx = [now, now, now, now - 5.0]  # fake clock: cam3 went silent 5 s ago
        node._on_timer()
        node._on_timer()
        assert node.errors.counts[("/cam3/image_raw", "stopped")] == 1
        assert sum(node.errors.counts.values()) == 1
        status = node.diagnostics().status[0]
        assert status.level == DiagnosticStatus.WARN and "/cam3/image_raw" in status.message
        node._on_image(3, image_msg(5.0))  # it comes back
        assert not node._stale[3]
    finally:
        node.destroy_node()


def test_auto_switch_inside_the_node_sets_the_pipeline_method(ctx):
    node = make_node(ctx, imu_max_age_s=0.3)
    try:
        images = [np.full((480, 640), 90, np.uint8)] * 4
        for k in range(40):
            node._on_imu(imu_msg(10.0 + 0.005 * k, accel=(0.0, 0.0, 9.81)))
        node.process(10.2, images, time.monotonic())
        assert node.selector.current == "4pt-bending" and node.pipeline.method == "auto"
        node.process(10.4, images, time.monotonic())
        assert node.selector.current == "4pt-bending"
        node.process(10.6, images, time.monotonic())  # newest IMU sample 0.405 s old
        assert node.selector.current == "6pt-bending" and node.pipeline.method == "6pt-bending"
        assert node.selector.switches == 1
        assert diag_values(node)["active_method"] == "6pt-bending"
    finally:
        node.destroy_node()


def _publish_and_collect(ctx, est, topics: dict, wanted: int) -> dict:
    """Publish ``est`` from a fresh node until a listener got ``wanted`` of ``topics`` (key -> (type, topic))."""
    node = make_node(ctx)
    listener = rclpy.create_node("listener", context=ctx)
    got = {}
    for key, (msg_type, topic) in topics.items():
        listener.create_subscription(msg_type, topic, lambda m, k=key: got.setdefault(k, m), 10)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    executor.add_node(listener)
    try:
        node._remember_stamp(est.stamp, type("S", (), {"sec": int(est.stamp), "nanosec": int(round(
            (est.stamp - int(est.stamp)) * 1e9))})())
        deadline = time.monotonic() + 10
        while len(got) < wanted and time.monotonic() < deadline:
            node._publish_estimate(est)
            executor.spin_once(timeout_sec=0.2)
    finally:
        executor.shutdown(timeout_sec=1.0)
        listener.destroy_node()
        node.destroy_node()
    return got


def test_published_messages_follow_spec_section_10(ctx):
    R = exp_so3(np.array([0.1, -0.2, 0.3]))
    t = np.array([0.5, -0.25, 0.125])
    g = np.array([0.0, 1.0, -9.81 + 0.05])
    est = PipelineEstimate(stamp=1700000002.5, ref_stamp=1700000000.5, method="4pt-bending", R=R, t=t,
                           gravity=g, num_inliers=100, time_ms=5.0)
    got = _publish_and_collect(ctx, est, {"pose": (PoseStamped, "/estimator/relative_pose"),
                                          "g": (Vector3Stamped, "/estimator/gravity"),
                                          "gf": (Vector3Stamped, "/estimator/gravity_fused")}, 2)
    pose, grav = got["pose"], got["g"]
    assert "gf" not in got  # no fused estimate in this PipelineEstimate: nothing on ~/gravity_fused
    assert pose.header.frame_id == "base_link" and grav.header.frame_id == "base_link"
    assert (pose.header.stamp.sec, pose.header.stamp.nanosec) == (1700000002, 500000000)
    q = pose.pose.orientation
    assert np.allclose(quat_xyzw_to_matrix([q.x, q.y, q.z, q.w]), R, atol=1e-9)
    p = pose.pose.position
    assert np.allclose([p.x, p.y, p.z], t)
    assert np.allclose([grav.vector.x, grav.vector.y, grav.vector.z], g)


def test_fused_gravity_and_attitude_messages(ctx):
    R_wb = exp_so3(np.array([0.2, 0.0, 0.0])) @ exp_so3(np.array([0.0, 0.1, 0.0]))  # roll-ish and pitch
    g = R_wb.T @ np.array([0.0, 0.0, -9.81])
    sigma = 0.002  # rad
    B = np.linalg.svd(np.eye(3) - np.outer(g, g) / 9.81**2)[0][:, :2]
    cov = (9.81 * sigma) ** 2 * B @ B.T
    est = PipelineEstimate(stamp=1700000003.0, ref_stamp=1700000000.5, method="6pt-bending", R=np.eye(3),
                           t=np.zeros(3), gravity=g, num_inliers=100, time_ms=5.0, gravity_fused=g,
                           cov_gravity_fused=cov)
    got = _publish_and_collect(ctx, est, {"gf": (Vector3Stamped, "/estimator/gravity_fused"),
                                          "att": (Imu, "/estimator/attitude")}, 2)
    gf, att = got["gf"], got["att"]
    assert np.allclose([gf.vector.x, gf.vector.y, gf.vector.z], g)
    q = att.orientation
    R_level = quat_xyzw_to_matrix([q.x, q.y, q.z, q.w])
    assert np.allclose(R_level @ g, [0, 0, -9.81], atol=1e-9)  # orientation levels the body: gravity straight down
    c = np.array(att.orientation_covariance).reshape(3, 3)
    assert np.allclose(np.diag(c)[:2], sigma**2, rtol=0.2) and c[2, 2] >= 1e6
    assert att.angular_velocity_covariance[0] == -1 and att.linear_acceleration_covariance[0] == -1


def test_no_rclpy_outside_node_and_play():
    import subprocess
    import sys

    code = ("import sys, nrmpc_ros.core, nrmpc_ros.frontend.pipeline, nrmpc_ros.cli.main, nrmpc_ros.cli.play;"
            "nrmpc_ros.cli.main.build_parser(); print('rclpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    assert estimator_node.rclpy is rclpy


def test_imu_topic_without_imu_block_in_the_rig_is_ignored(ctx, tmp_path):
    import yaml

    rig = yaml.safe_load(Path(RIG).read_text())
    del rig["imu"]
    path = tmp_path / "rig_no_imu.yaml"
    path.write_text(yaml.safe_dump(rig))
    node = EstimatorNode(start_worker=False, context=ctx, parameter_overrides=[
        Parameter("rig_file", value=str(path)), Parameter("imu_topic", value="/imu/data")])
    try:
        assert node.imu_topic == "" and node.count_subscribers("/imu/data") == 0
        assert node.selector.select(1.0)[0] == "6pt-bending"
    finally:
        node.destroy_node()
