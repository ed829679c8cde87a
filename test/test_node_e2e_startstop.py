"""The estimator node's start and stop over DDS (processes, as ``ros2 launch`` runs them): SIGINT and SIGTERM end
it within ``SHUTDOWN_S`` at full load with the shutdown summary logged; ``image_transport: auto`` finds raw and
compressed cameras whether the node or the publishers start first; an IMU stamped by its own clock is moved
onto the cameras' whichever driver starts first.

Harness (listener, injector, bag, CPU hog) from :mod:`test_node_e2e`.
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time

import numpy as np
import pytest
from dds import domain_id
from rendered_bags import CAMERAS, IMU, restamped, rewrite, stamp_ns
from test_node_e2e import (
    CpuHog,
    Injector,
    Listener,
    Session,
    bag,  # noqa: F401 - fixture
    env_for,
    estimator,
    msg_stamp,
    replayed,  # noqa: F401 - fixture
    stamp_key,
    start,
    stop,
)

rclpy = pytest.importorskip("rclpy", reason="rclpy is not importable: install the ros extra (pip install -e .[ros])")


from nrmpc_ros.frontend.service import SHUTDOWN_S  # noqa: E402

pytestmark = pytest.mark.slow
# every message kept until the node takes it (no loss in the subscription queues on a busy machine): the node
# then sees what the replay reads
DEEP_QUEUES = ("-p", "work_queue_size:=1000", "-p", "image_queue_size:=1000", "-p", "imu_queue_size:=5000")
FRAME_PERIOD_US = 100_000  # the bag's 10 Hz, in the stamp keys' microseconds
POLL_S = 0.01  # how often the test looks whether the node has ended: the resolution of the measured exit time


def exit_seconds(proc, sig) -> tuple:
    """Send ``sig`` to the node; returns the time until its process has ended (s) and the wall-clock time of the
    signal (to place the node's log lines)."""
    t0, wall = time.monotonic(), time.time()
    os.kill(proc.pid, sig)
    while proc.poll() is None and time.monotonic() - t0 < 30:
        time.sleep(POLL_S)
    return time.monotonic() - t0, wall


def summary_after(log: str, wall: float) -> float:
    """Seconds from ``wall`` to the node's "shutting down" log line (its [INFO] [stamp])."""
    line = next(line for line in log.splitlines() if "shutting down:" in line)
    return float(line.split("] [")[1].split("]")[0]) - wall


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_ends_the_node_within_its_budget_at_full_load(bag, tmp_path, sig):  # noqa: F811
    """The bag at 4x with every core busy (a CPU hog beside the node): the estimator has a queue full of frame
    sets and a hold open or in estimation when the signal comes. The exit is timed from the signal to the
    process's end, and must not exceed ``SHUTDOWN_S`` (+ the poll period of this test)."""
    path, rig, _ = bag
    domain = domain_id(1, 100)
    env = env_for(domain, tmp_path)
    listener = Listener(domain)
    node = start(estimator(rig, "-p", "work_queue_size:=30"), env, tmp_path / "node.log")
    inject = None
    try:
        assert listener.wait_for_node(), (tmp_path / "node.log").read_text()
        inject = Injector(domain, path)
        inject.wait_for_subscribers()
        with CpuHog(60.0):
            player = threading.Thread(target=inject.play, kwargs={"rate": 4.0}, daemon=True)
            player.start()
            deadline = time.monotonic() + 60  # into the second hold: an estimate is done or under way
            while len(listener.got["gravity"]) < 1 and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(0.5)
            est = listener.last("estimation")[2]
            busy = int(est.get("work waiting", 0))
            seconds, wall = exit_seconds(node, sig)
            player.join(30)
    finally:
        stop(node)
        if inject is not None:
            inject.close()
        listener.close()
    log = (tmp_path / "node.log").read_text()
    print(f"{signal.Signals(sig).name}: exit after {seconds:.3f} s (summary logged after "
          f"{summary_after(log, wall):.3f} s); work waiting before it: {busy}\n{log[-3000:]}")
    assert node.returncode == 0, log
    assert seconds <= SHUTDOWN_S + POLL_S, f"{seconds:.3f} s from {signal.Signals(sig).name} to the end"
    summary = next(line for line in log.splitlines() if "shutting down:" in line)
    assert "images" in summary and "estimates" in summary and "dropped:" in summary
    assert any(what in summary for what in ("no open hold", "open hold estimated at shutdown",
                                            "open hold not estimated: would not fit",
                                            "estimation in progress was abandoned", "open hold abandoned"))
    assert "Traceback" not in log


def stream(domain: int, path, compressed: bool, node_up: threading.Event) -> None:
    """The bag's cameras (raw, or JPEG on <topic>/compressed) and IMU at 2x from this process, once every topic
    has a subscriber (as ``ros2 bag play --wait-for-subscribers`` would) and the node publishes: a publisher
    sees the node's subscription before the node's reader has matched the publisher, and on a busy machine
    the first messages of a best-effort topic would be lost in between (a count of 104 images could not hold)."""
    inject = Injector(domain, path, compressed=compressed)
    try:
        inject.wait_for_subscribers(timeout=90.0)
        assert node_up.wait(120.0), "the node did not come up"
        inject.play(rate=2.0)
    finally:
        inject.close()


@pytest.mark.parametrize("transport", ["raw", "compressed"])
@pytest.mark.parametrize("order", ["node first", "publishers first"])
def test_auto_transport_finds_the_cameras_in_either_start_order(bag, replayed, tmp_path, transport,  # noqa: F811
                                                                 order):
    """``image_transport: auto``: the node subscribes to what the cameras publish, raw or compressed, whether it
    starts before the publishers (it switches when they appear) or after them; its estimates are the replay's
    within a frame period. The publishers wait for a subscriber
    before they play, as ``nrmpc play --wait-for-subscribers`` does: the node subscribes to a compressed camera
    once it has seen its publisher."""
    path, rig, _ = bag
    domain = domain_id(1, 100)
    env = env_for(domain, tmp_path)
    listener = Listener(domain)
    node_up = threading.Event()
    publisher = threading.Thread(target=stream, args=(domain, path, transport == "compressed", node_up), daemon=True)
    node = None
    try:
        if order == "publishers first":
            publisher.start()
            time.sleep(3.0)  # the publishers are on the graph before the node starts
        node = start(estimator(rig, "-p", "image_transport:=auto", *DEEP_QUEUES), env, tmp_path / "node.log")
        assert listener.wait_for_node(), (tmp_path / "node.log").read_text()
        node_up.set()
        if order == "node first":
            time.sleep(2.0)  # the node has looked at the graph (nothing published) and subscribed to the raw topic
            publisher.start()
        publisher.join(180)
        listener.wait_until_done(timeout=180)
        time.sleep(0.5)
    finally:
        stop(node)
        listener.close()
    log = (tmp_path / "node.log").read_text()
    print(log[-3000:])
    cams = listener.last("cameras")[2]
    assert all(int(cams.get(f"{t}: images", 0)) > 0 for t in CAMERAS), cams
    got = sorted(stamp_key(msg_stamp(m.header)) for m in listener.got["gravity"])
    assert all(int(cams[f"{t}: images"]) == 104 for t in CAMERAS), cams
    # the replay's holds: each estimate within a frame period of the replay's (not to the last digit: JPEG
    # changes the pixels, and on a busy machine the executor takes the IMU and image callbacks in another
    # interleaving than the bag's order, which moves the IMU's stillness decisions by a frame)
    assert len(got) == len(replayed), (got, sorted(replayed))
    assert all(abs(a - b) <= FRAME_PERIOD_US for a, b in zip(got, sorted(replayed))), (got, sorted(replayed))
    if order == "node first" and transport == "compressed":
        assert "subscribing to /cam0/image_raw/compressed instead (published)" in log


@pytest.mark.parametrize("topic, first", [(IMU, "imu"), (CAMERAS[1], "cameras")],
                         ids=["IMU clock, IMU first", "camera clock, cameras first"])
def test_an_input_on_its_own_clock_is_moved_onto_the_others_whichever_driver_starts_first(bag, replayed,  # noqa: F811
                                                                                          tmp_path, topic, first):
    """The IMU (or one camera) stamps with a counter since its power-on (1000 s when the recording starts), the
    others with the host's clock; one driver starts 1.5 s (of stamps) before the other (the other orders are
    the feeder's tests'). The node moves it onto
    the others' clock by when its messages arrive, says so in its diagnostics, and publishes the replay's
    estimates of the bag stamped right (the holds the late driver saw whole), each within its std: played at
    2x, the arrival clock runs at half the stamps' rate, so the samples sit up to half a frame period off
    where they were taken."""
    path, rig, _ = bag
    start_ns = 1_700_000_000 * 1_000_000_000

    def edit(t, k, msg):
        yield t, k, (restamped(msg, stamp_ns(msg) - start_ns + 1000 * 1_000_000_000) if t == topic else msg)

    own = rewrite(path, tmp_path / "own", edit)
    with Session(tmp_path, rig, *DEEP_QUEUES) as run:
        inject = Injector(run.domain, own)
        try:
            inject.wait_for_subscribers(timeout=90.0)
            inject.play(rate=2.0, skip=lambda dt, t: dt < 1_500_000_000 and (t == IMU) == (first == "cameras"))
        finally:
            inject.close()
        run.listener.wait_until_done(timeout=180)
        time.sleep(0.5)
    log = run.log()
    if topic == IMU:
        said = run.listener.last("IMU")[2].get("clock offset", "")
        assert "from the arrival times" in said, (said, log[-3000:])
    else:
        cams = run.listener.last("cameras")[2]
        assert "another clock" in cams.get(f"{topic}: clock", ""), (cams, log[-3000:])
    assert "another clock" in log
    got = run.listener.gravity_by_stamp()
    later = [s for s in got if s >= stamp_key(1_700_000_002.0)]
    assert len(later) >= len([s for s in replayed if s >= stamp_key(1_700_000_002.0)]) >= 2
    for s in later:
        row = replayed[s]
        g = np.array([float(row[k]) for k in ("gx", "gy", "gz")])
        off = math.degrees(math.acos(np.clip(got[s] @ g / np.linalg.norm(got[s]) / np.linalg.norm(g), -1, 1)))
        assert off < float(row["gravity_sigma_deg"]), (s, off, row["gravity_sigma_deg"], log[-3000:])
