"""~/markers over DDS: the estimator node runs a played bag; one MarkerArray per estimate and state change (not per
frame), in the body frame, and a subscriber that joins after the run still gets the last state (transient local).

Uses the processes and helpers of test_node_e2e (rendered bag, own ROS_DOMAIN_ID, process groups killed)."""

from __future__ import annotations

import time

import pytest
from test_node_e2e import Listener, Session, bag, play  # noqa: F401 - bag is a fixture

pytest.importorskip("visualization_msgs", reason="visualization_msgs is not importable: install the ros extra")

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from nrmpc_ros.ros_play import BackgroundNode  # noqa: E402

pytestmark = pytest.mark.slow
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class MarkerListener(BackgroundNode):
    def __init__(self, domain: int, name: str):
        super().__init__(name, domain)
        self.got = []
        self.node.create_subscription(MarkerArray, "/estimator/markers", self.got.append, LATCHED)
        self.start()

    def wait(self, n: int, timeout: float = 20.0) -> None:
        deadline = time.monotonic() + timeout
        while len(self.got) < n and time.monotonic() < deadline:
            time.sleep(0.05)


def test_markers_come_per_estimate_and_state_change_and_stay_latched(bag, tmp_path):  # noqa: F811
    path, rig_path, _ = bag
    with Session(tmp_path, rig_path, "-p", "work_queue_size:=1000", "-p", "markers_bend_scale:=10.0") as run:
        during = MarkerListener(run.domain, "markers_during")
        try:
            player = run.start(play(path, "--rate", "2"))
            assert player.wait(120) == 0, (tmp_path / "play.log").read_text()
            run.listener.wait_until_done()
            time.sleep(0.5)
            late = MarkerListener(run.domain, "markers_late")
            try:
                late.wait(1)
                assert len(late.got) == 1, "a late subscriber gets the last state"
                last = late.got[0]
            finally:
                late.close()
        finally:
            during.close()
    estimates = len(run.listener.got["gravity"])
    frame_sets = 104
    assert estimates >= 3 and estimates + 2 <= len(during.got) <= frame_sets / 3, (estimates, len(during.got))
    assert last == during.got[-1]
    assert last.markers[0].action == Marker.DELETEALL
    shown = {m.ns: m for m in last.markers[1:]}
    assert set(shown) == {"bars_rest", "bars_bent", "cameras", "gravity", "gravity_cone", "state"}
    assert all(m.header.frame_id == "base_link" for m in last.markers)
    assert len(shown["bars_bent"].points) == 8 and len(shown["cameras"].points) == 4 * 16
    texts = [next(m.text for m in a.markers if m.ns == "state") for a in during.got]
    assert any(t.startswith("settling") for t in texts) and any(t.startswith("measuring hold") for t in texts)
    assert "last: sequence 0 hold" in texts[-1]
