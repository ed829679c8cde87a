"""The estimator node in this process (a real rclpy context of its own, random domain): parameters and their
descriptors, start-up errors naming what is wrong, transports, the published messages and their frames,
~/reset, the method at run time. The worker is left stopped where a test drives it by hand."""

from __future__ import annotations

import threading
import time
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest
from dds import domain_id

from nrmpc_ros.errors import InputError

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: install the ros extra (pip install -e .[ros])")

from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped, Vector3Stamped  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from nrmpc_ros import node as estimator_node  # noqa: E402
from nrmpc_ros.core.deformation import deformed_extrinsics  # noqa: E402
from nrmpc_ros.core.so3 import exp_so3, quat_xyzw_to_matrix  # noqa: E402
from nrmpc_ros.frontend.outputs import hold_output  # noqa: E402
from nrmpc_ros.frontend.pipeline import HoldEstimate  # noqa: E402
from nrmpc_ros.frontend.work import WorkKind  # noqa: E402
from nrmpc_ros.node import EstimatorNode, main  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
RIG = str(REPO / "config" / "sample_cross4.yaml")


@pytest.fixture
def ctx():
    context = Context()
    rclpy.init(context=context, domain_id=domain_id(101, 200))
    yield context
    rclpy.try_shutdown(context=context)


def make_node(ctx, namespace="", **params):
    params.setdefault("rig_file", RIG)
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    return EstimatorNode(start_worker=False, context=ctx, parameter_overrides=overrides, namespace=namespace)


@pytest.mark.slow
def test_parameters_have_descriptions_ranges_and_reach_the_configs(ctx):
    node = make_node(ctx, **{"pipeline.holds.measure_s": 3, "input.jump_back_s": 2.5, "image_transport": "raw"})
    try:
        d = node.describe_parameters(["pipeline.holds.measure_s"])[0]
        assert "settled part" in d.description and d.read_only
        assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (0.0, 3600.0)
        assert node.describe_parameters(["pipeline.seed"])[0].integer_range[0].to_value == 2**63 - 1
        assert "one of: auto" in node.describe_parameters(["method"])[0].description
        assert not node.describe_parameters(["method"])[0].read_only
        assert node.get_parameter("pipeline.holds.measure_s").value == 3.0, "an integer for a float is that float"
        assert node.service.runner.pipeline.config.holds.measure_s == 3.0
        assert node.service.feeder.config.jump_back_s == 2.5
        assert node.camera_topics == [f"/cam{i}/image_raw" for i in range(4)]
        assert all(node.count_subscribers(t) == 1 for t in node.camera_topics)
        assert node.count_subscribers("/imu/data") == 1 and node.count_subscribers("/cam0/camera_info") == 1
    finally:
        node.destroy_node()


@pytest.mark.slow
def test_relative_rig_topics_follow_the_namespace(ctx):
    node = make_node(ctx, namespace="/rig1")
    try:
        assert node.camera_topics == [f"/rig1/cam{i}/image_raw" for i in range(4)]
        assert node.count_subscribers("/rig1/imu/data") == 1
        assert node.pubs["pose"].topic_name == "/rig1/estimator/pose"
    finally:
        node.destroy_node()


@pytest.mark.slow
@pytest.mark.parametrize("params, match", [
    ({"pipeline.holds.measure": 2.0}, r"parameter pipeline.holds.measure: unknown parameter"),
    ({"pipline.seed": 1}, r"unknown parameter\(s\) pipline.seed"),
    ({"method": "8pt"}, r"field 'method': must be one of"),
    ({"image_transport": "theora"}, r"field 'image_transport'"),
    ({"pipeline.holds.measure_s": -1.0}, r"parameter pipeline.holds.measure_s: -1.0 is not allowed"),
    ({"pipeline.holds.measure_s": "long"}, r"parameter pipeline.holds.measure_s: expected a float, got 'long'"),
    ({"work_queue_size": 0}, r"parameter work_queue_size: 0 is not allowed"),
    ({"rig_file": "no/such/rig.yaml"}, r"parameter rig_file: no such file: no/such/rig.yaml \(looked for "),
])
def test_bad_parameters_stop_the_start_with_their_name(ctx, params, match):
    with pytest.raises(InputError, match=match):
        make_node(ctx, **params).destroy_node()


@pytest.mark.slow
def test_no_rig_file_is_a_clear_error(ctx):
    with pytest.raises(InputError, match="parameter rig_file: required"):
        EstimatorNode(start_worker=False, context=ctx)


@pytest.mark.slow
def test_transports_and_no_imu(ctx):
    node = make_node(ctx, image_transport="compressed", use_imu=False)
    try:
        assert [t for t, _ in node.image_subscriptions] == [f"/cam{i}/image_raw/compressed" for i in range(4)]
        assert node.count_subscribers("/imu/data") == 0 and node.service.imu_topic is None
        assert node.service.diagnostics()[1].message.startswith("no IMU (use_imu is false)")
    finally:
        node.destroy_node()
    node = make_node(ctx, image_transport="auto")  # nothing published yet: the raw topics, checked again later
    try:
        assert node.image_subscriptions == [(f"/cam{i}/image_raw", False) for i in range(4)]
    finally:
        node.destroy_node()


def test_auto_transport_switches_when_a_compressed_camera_appears_after_the_node(ctx):
    """The node's own raw subscriptions are no publishers: a camera that then publishes only compressed images is
    followed on its /compressed topic; a raw camera keeps the raw topic."""
    from sensor_msgs.msg import CompressedImage, Image

    node = make_node(ctx, image_transport="auto", diagnostics_period_s=0.1)
    camera = rclpy.create_node("camera", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        assert node.image_subscriptions == [(f"/cam{i}/image_raw", False) for i in range(4)]
        camera.create_publisher(CompressedImage, "/cam0/image_raw/compressed", 10)
        camera.create_publisher(Image, "/cam1/image_raw", 10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and node.image_subscriptions[0][1] is False:
            executor.spin_once(timeout_sec=0.1)  # the diagnostics timer looks at the graph again
        assert node.image_subscriptions[:3] == [("/cam0/image_raw/compressed", True), ("/cam1/image_raw", False),
                                                ("/cam2/image_raw", False)]
        # both read in place from their serialized messages, each by its subscription's type
        img = np.random.default_rng(0).integers(0, 256, (480, 640), dtype=np.uint8)
        jpeg = CompressedImage(format="jpeg", data=cv2.imencode(".jpg", img)[1].tobytes())
        raw = Image(height=480, width=640, encoding="mono8", step=640, data=img.tobytes())
        pubs = [camera.create_publisher(CompressedImage, "/cam0/image_raw/compressed", 10),
                camera.create_publisher(Image, "/cam1/image_raw", 10)]
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not all(node.service.received[t] for t in node.camera_topics[:2]):
            for pub, msg in zip(pubs, (jpeg, raw)):
                msg.header.stamp.sec += 1
                pub.publish(msg)
            executor.spin_once(timeout_sec=0.1)
        assert all(node.service.received[t] for t in node.camera_topics[:2])
        assert node.service.drops.total() == 0, node.service.drops.summary()
    finally:
        executor.shutdown(timeout_sec=1.0)
        camera.destroy_node()
        node.destroy_node()
    assert "nrmpc-take" not in [t.name for t in threading.enumerate()], "destroying the node ends its take thread"


def test_a_camera_started_again_best_effort_after_a_reliable_one_is_followed(ctx):
    """A bag played back (reliable), then the live driver (best effort): once the camera is silent the node
    looks at its publishers again and takes the driver's images."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    node = make_node(ctx, image_transport="raw", diagnostics_period_s=0.1, camera_timeout_s=0.3)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    raw = Image(height=480, width=640, encoding="mono8", step=640, data=bytes(640 * 480))
    topic = node.camera_topics[0]
    try:
        for reliability in (ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT):
            camera = rclpy.create_node("camera", context=ctx)
            pub = camera.create_publisher(Image, "/cam0/image_raw", QoSProfile(depth=10, reliability=reliability))
            before, deadline = node.service.received[topic], time.monotonic() + 10
            while time.monotonic() < deadline and node.service.received[topic] <= before:
                raw.header.stamp.sec += 1
                pub.publish(raw)
                executor.spin_once(timeout_sec=0.1)
            assert node.service.received[topic] > before, reliability
            camera.destroy_node()
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and not node.service.watch.is_silent(0):
                executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()


@pytest.mark.parametrize("reliable", [False, True], ids=["best effort", "reliable"])
def test_images_are_taken_as_their_publisher_offers_whichever_starts_first(ctx, reliable):
    """A camera driver that publishes best effort (most do) started after the node: the node, reliable while
    it knows no publisher, goes best effort and receives its images; a reliable publisher (a bag played back)
    is taken reliably, so a burst is not lost in the middleware."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    node = make_node(ctx, image_transport="raw", diagnostics_period_s=0.1)
    camera = rclpy.create_node("camera", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE if reliable else
                         ReliabilityPolicy.BEST_EFFORT)
        pub = camera.create_publisher(Image, "/cam0/image_raw", qos)
        raw = Image(height=480, width=640, encoding="mono8", step=640, data=bytes(640 * 480))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not node.service.received[node.camera_topics[0]]:
            raw.header.stamp.sec += 1
            pub.publish(raw)
            executor.spin_once(timeout_sec=0.1)
        assert node.service.received[node.camera_topics[0]] > 0
        sub = next(s for s in node.subscriptions if s.topic_name == "/cam0/image_raw")
        want = ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT
        assert sub.qos_profile.reliability == want
    finally:
        executor.shutdown(timeout_sec=1.0)
        camera.destroy_node()
        node.destroy_node()


def hold_estimate():
    rng = np.random.default_rng(7)
    R0k = exp_so3(rng.normal(scale=0.3, size=3))
    g = (exp_so3(np.array([0.3, 0.1, 0.0])) @ R0k).T @ np.array([0, 0, -9.81])
    return HoldEstimate(stamp=1700000002.5, ref_stamp=1700000001.5, method="4pt-bending", R=exp_so3([0.1, 0, 0.2]),
                        t=np.array([0.1, 0.2, 0.3]), gravity=g, gravity_sigma_deg=0.1, cov_gravity=1e-6 * np.eye(3),
                        num_inliers=50, num_observations=60, time_ms=1.0, origin_stamp=1700000000.5, R_origin=R0k,
                        t_origin=np.array([1.0, 0.0, 0.0]), cov_pose=1e-6 * np.eye(6), sequence=0, hold_index=2,
                        hold=None, links=Counter())


@pytest.mark.slow
def test_published_messages_carry_their_frames_and_the_bent_camera_poses(ctx):
    node = make_node(ctx)
    listener = rclpy.create_node("listener", context=ctx)
    topics = {"pose": (PoseWithCovarianceStamped, "/estimator/pose"), "rel": (PoseStamped, "/estimator/relative_pose"),
              "ref": (Header, "/estimator/relative_pose_reference"), "g": (Vector3Stamped, "/estimator/gravity"),
              "att": (Imu, "/estimator/attitude"), "cams": (PoseArray, "/estimator/camera_poses")}
    got = {}
    for key, (cls, topic) in topics.items():
        listener.create_subscription(cls, topic, lambda m, k=key: got.setdefault(k, m), 10)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    executor.add_node(listener)
    est = hold_estimate()
    out = hold_output(est, node.rig, node.service.frames, reference_hold=1)
    try:
        deadline = time.monotonic() + 10
        while len(got) < len(topics) and time.monotonic() < deadline:
            node.publish_hold(out)
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown(timeout_sec=1.0)
        listener.destroy_node()
        node.destroy_node()
    assert set(got) == set(topics)
    assert got["pose"].header.frame_id == "base_link_origin" and got["rel"].header.frame_id == "base_link_s0_h1"
    assert got["ref"].frame_id == "base_link_s0_h1" and (got["ref"].stamp.sec, got["ref"].stamp.nanosec) == (
        1700000001, 500000000)
    assert (got["rel"].header.stamp.sec, got["rel"].header.stamp.nanosec) == (1700000002, 500000000)
    assert all(got[k].header.frame_id == "base_link" for k in ("g", "att", "cams"))
    g = np.array([got["g"].vector.x, got["g"].vector.y, got["g"].vector.z])
    w, W = deformed_extrinsics(node.rig, g)
    for i, p in enumerate(got["cams"].poses):
        assert np.allclose([p.position.x, p.position.y, p.position.z], w[i], atol=1e-9, rtol=0)
        q = p.orientation
        assert np.allclose(quat_xyzw_to_matrix([q.x, q.y, q.z, q.w]), W[i], atol=1e-9, rtol=0)
    q = got["pose"].pose.pose.orientation
    assert np.allclose(quat_xyzw_to_matrix([q.x, q.y, q.z, q.w]) @ g, [0, 0, -9.81], atol=1e-9), "levelled origin"


@pytest.mark.slow
def test_reset_service_and_method_at_run_time(ctx):
    node = make_node(ctx)
    client_node = rclpy.create_node("client", context=ctx)
    client = client_node.create_client(Trigger, "/estimator/reset")
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    executor.add_node(client_node)
    try:
        assert client.wait_for_service(timeout_sec=10)
        future = client.call_async(Trigger.Request())
        executor.spin_until_future_complete(future, timeout_sec=10)
        assert future.result().success and "a new sequence" in future.result().message
        assert node.service.queue.get(0.0).kind is WorkKind.RESET
        assert node.set_parameters([Parameter("method", value="6pt-bending")])[0].successful
        assert not node.set_parameters([Parameter("method", value="magic")])[0].successful
        assert not node.set_parameters([Parameter("input.jump_back_s", value=5.0)])[0].successful, "read-only"
        for _ in range(3):
            node.service.work_once()
        assert node.service.runner.method == "6pt-bending"
    finally:
        executor.shutdown(timeout_sec=1.0)
        client_node.destroy_node()
        node.destroy_node()


@pytest.mark.slow
def test_the_shutdown_summary_reaches_rosout(ctx):
    node = make_node(ctx)
    listener = rclpy.create_node("rosout_listener", context=ctx)
    lines = []
    listener.create_subscription(Log, "/rosout", lambda m: lines.append(m.msg), 100)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(listener)
    try:
        deadline = time.monotonic() + 10
        while not listener.count_publishers("/rosout") and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        time.sleep(0.5)
        node.shutdown()
        deadline = time.monotonic() + 5
        while not any("shutting down" in line for line in lines) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown(timeout_sec=1.0)
        listener.destroy_node()
        node.destroy_node()
    summary = next(line for line in lines if "shutting down" in line)
    assert "0 images" in summary and "dropped: nothing dropped" in summary


def test_help_needs_no_ros_graph(capsys):
    assert main(["estimator", "--help"]) == 0
    out = capsys.readouterr().out
    for name in ("rig_file", "method", "image_transport", "camera_timeout_s", "input.max_future_s",
                 "pipeline.holds.measure_s"):
        assert f"  {name} [default" in out
    assert main(["estimator", "--bogus"]) == 2


def test_no_rclpy_outside_node_and_play():
    import subprocess
    import sys

    code = ("import sys, nrmpc_ros.core, nrmpc_ros.frontend.service, nrmpc_ros.frontend.replay, nrmpc_ros.cli.main;"
            "nrmpc_ros.cli.main.build_parser(); print('rclpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    assert estimator_node.rclpy is rclpy
