"""EstimatorService and the node's settings without ROS: parameters from the configs, files, the work queue,
drops while busy, liveness, resets, restarts, diagnostics and the summary."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from rendered_bags import rig_file
from test_feeder import TOPICS, image, imu, messages

from nrmpc_ros.core import load_rig
from nrmpc_ros.frontend.drops import Drop
from nrmpc_ros.frontend.feeder import FeederConfig
from nrmpc_ros.frontend.node_config import (
    NodeConfig,
)
from nrmpc_ros.frontend.pipeline import FrameSet, PipelineConfig
from nrmpc_ros.frontend.runner import PipelineRunner
from nrmpc_ros.frontend.service import ERROR, OK, WARN, EstimatorService, WorkQueue, image_change
from nrmpc_ros.frontend.sync import StampSynchronizer
from nrmpc_ros.frontend.work import Work, WorkKind


@pytest.fixture
def rig(tmp_path):
    return load_rig(rig_file(tmp_path, 64))


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


def service(rig, clock=None, imu_topic="/imu/data", **cfg):
    cfg.setdefault("rig_file", rig.source)
    out, logs = [], []
    s = EstimatorService(rig, NodeConfig(**cfg), PipelineConfig(), TOPICS, imu_topic, out.append,
                         lambda level, line: logs.append((level, line)), clock or Clock())
    return s, out, logs


# --------------------------------------------------------------------------- the work queue and the service
def test_the_work_queue_refuses_frame_sets_when_full_but_not_imu_samples():
    q = WorkQueue(max_frames=2)
    dropped = [q.put(Work(WorkKind.FRAMES, k)) for k in range(3)]
    assert dropped[:2] == [None, None] and dropped[2].stamp == 1, "equals: the first and the newest are kept"
    assert q.put(Work(WorkKind.IMU, 1.0)) is None and q.put(Work(WorkKind.FLUSH)) is None and q.frames() == 2
    assert q.get(0.01).stamp == 0 and q.frames() == 1


def test_a_full_work_queue_drops_the_frame_sets_of_moves_and_keeps_those_of_holds():
    """Frame sets ranked by how much their images changed, a worker at half the input rate: the move is thinned
    first, then the holds evenly, each keeping its first and last frames (its span)."""
    q = WorkQueue(max_frames=4)
    change = {k: (1.5 if k < 8 or k >= 16 else 30.0) for k in range(40)}  # hold 0-7, move 8-15, hold 16-39
    dropped, kept = [], []
    for k in range(40):
        d = q.put(Work(WorkKind.FRAMES, 0.1 * k), change[k])
        dropped += [] if d is None else [round(d.stamp * 10)]
        if k % 2:
            kept.append(round(q.get(0.0).stamp * 10))
    while (w := q.get(0.0)) is not None:
        kept.append(round(w.stamp * 10))
    assert sorted(dropped + kept) == list(range(40))
    moves = [k for k in dropped if 8 <= k < 16]
    assert moves and min(d for d in dropped if d >= 16) > max(moves), "holds lose frames only once no move waits"
    assert {0, 7} <= set(kept) and len([k for k in kept if k < 8]) >= 6, "the first hold keeps its span"
    assert 16 in kept and 39 in kept and len([k for k in kept if k >= 16]) >= 12, "the second keeps its span"


def test_a_full_work_queue_keeps_both_ends_of_a_time_jump_back():
    """A worker behind when the stamps jump back: the last set before the jump and the first after it end their
    sequences' spans and are kept (the gap across the jump is no gap in time), with or without a restart item."""
    for restart in (True, False):
        q = WorkQueue(max_frames=4)
        dropped = []
        for k in range(6):
            dropped.append(q.put(Work(WorkKind.FRAMES, 8.0 + 0.1 * k), 1.5))
        if restart:
            assert q.put(Work(WorkKind.RESTART, data="time jumped back")) is None
        for k in range(6):
            dropped.append(q.put(Work(WorkKind.FRAMES, 0.1 * k), 1.5))
        dropped = [round(d.stamp * 10) for d in dropped if d is not None]
        kept = []
        while (w := q.get(0.0)) is not None:
            kept += [round(w.stamp * 10)] if w.kind is WorkKind.FRAMES else []
        assert {85, 0, 5} <= set(kept), (restart, kept, dropped)


def test_image_change_ranks_a_moved_image_above_a_still_one():
    rng = np.random.default_rng(0)
    scene = cv2.GaussianBlur(rng.integers(0, 255, (240, 320), dtype=np.uint8), (0, 0), 3)
    still = np.clip(scene + rng.normal(0, 2, scene.shape), 0, 255).astype(np.uint8)
    moved = np.roll(scene, 5, axis=1)
    change0, small = image_change([None], [scene])
    assert change0 == 0.0 and small[0].shape == (30, 40)
    assert image_change(small, [still])[0] < image_change(small, [moved])[0]


def feed_sets(s, stamps, now=None):
    for t in stamps:
        for i in range(4):
            s.on_image(i, image(t, value=int(t * 10) % 200), now)


def test_sets_arriving_while_the_estimator_is_busy_are_dropped_counted_and_logged(rig):
    s, _, logs = service(rig, imu_topic=None, work_queue_size=2)
    feed_sets(s, [100.0 + 0.1 * k for k in range(8)])  # no IMU: sets go to the queue at once
    busy = s.drops.counts()[("worker", Drop.BUSY_FRAME_SET)]
    assert busy >= 4 and s.queue.frames() == 2
    assert sum("dropped while the estimator is busy" in line for _, line in logs) == 1, "logged once"
    while s.queue.frames():
        s.work_once()
    assert s.counts["processed frame sets"] == 2
    est = s.diagnostics()[2]
    assert est.name == "estimation" and est.level == WARN and "dropped" in est.message
    assert s.diagnostics()[2].level == OK, "the warning is about the last period"
    assert "worker: frame set dropped while the estimator is busy" in s.summary()


def test_a_burst_of_late_frames_finds_room_in_the_work_queue_and_steady_frames_do_not_widen_it(rig):
    """A camera link that buffers: 2 s of frame sets arrive at once, 2 s after the IMU samples of their time.
    They are a backlog, not a busy estimator's surplus: the queue holds them all (none dropped); frames that
    come on time keep the configured bound."""
    s, _, _ = service(rig, work_queue_size=4)
    def imu_until(t0, t1):
        for k in range(int(round((t1 - t0) * 200))):
            s.on_imu(imu(t0 + k / 200), None)
    for k in range(10):  # one steady second, the worker keeping up
        imu_until(100.0 + 0.1 * k, 100.1 + 0.1 * k)
        feed_sets(s, [100.0 + 0.1 * k])
        while s.queue.frames():
            s.work_once()
    assert s.queue.max_frames == 4, "on time: the configured bound"
    imu_until(101.0, 103.0)
    feed_sets(s, [101.0 + 0.1 * k for k in range(20)])  # the burst
    assert s.drops.counts().get(("worker", Drop.BUSY_FRAME_SET), 0) == 0
    assert s.queue.frames() >= 19 and s.queue.max_frames >= 20


def test_the_end_of_the_input_flushes_and_the_diagnostics_say_so(rig):
    clock = Clock()
    s, _, logs = service(rig, clock=clock, camera_timeout_s=1.0)
    feed_sets(s, [100.0, 100.1])
    clock.t = 5.0
    s.tick()
    assert any("the input ended" in line for _, line in logs)
    kinds = []
    while (w := s.queue.get(0.0)) is not None:
        kinds.append(w.kind)
    assert kinds[-1] == WorkKind.FLUSH and kinds.count(WorkKind.FRAMES) == 2
    cams = s.diagnostics()[0]
    assert cams.level == OK and "the input ended" in cams.message
    assert cams.values["/cam0/image_raw: state"] == "input ended"


@pytest.mark.parametrize("how", ["own clock", "unstamped"])
def test_the_input_ends_on_time_after_a_cameras_stamps_are_read_another_way(rig, how):
    """Camera 1 stamps with a counter since its power-on (2500 s at the others' 1.7e9 s), or leaves its stamps at
    0, and speaks 0.5 s before the others: once its stamps are read another way (moved onto the others' clock,
    or stamped by their arrival) the delays measured before are of another timeline, so when every camera falls
    silent the input ends after the camera timeout, as for cameras on one clock (not once the window that
    measures how cameras deliver has forgotten the old stamps, a minute later)."""
    t0 = 1_700_000_000.0
    msgs = [m for m in messages(t0=t0, seconds=3.0) if (m[1] == "image" and m[2] == 1) or m[3] >= t0 + 0.5]
    clock = Clock()
    s, _, logs = service(rig, clock=clock, camera_timeout_s=1.0)
    for arrival, kind, i, t in msgs:
        clock.t = arrival
        if kind == "image":
            stamp = (t - t0 + 2500.0 if how == "own clock" else 0.0) if i == 1 else t
            s.on_image(i, image(stamp), arrival)
        else:
            s.on_imu(imu(t), arrival)
    moved = s.feeder.rebases if how == "own clock" else [line for _, line in logs if "stamps do not advance" in line]
    assert moved, logs
    end = clock.t
    clock.t = end + 2.0
    s.tick()
    assert any("the input ended" in line for _, line in logs), [line for _, line in logs]


def test_a_silent_camera_and_bad_imu_samples_are_warnings_in_the_diagnostics(rig):
    clock = Clock()
    s, _, logs = service(rig, clock=clock, camera_timeout_s=1.0)
    for k in range(40):
        clock.t = 0.1 * k
        for i in range(4 if k < 10 else 3):
            s.on_image(i, image(100.0 + 0.1 * k), None)
        s.tick()
    s.on_imu(imu(103.0, accel=(math.nan, 0, 9.81)), None)
    cams, imu_status, _ = s.diagnostics()
    assert cams.level == WARN and "/cam3/image_raw" in cams.message
    assert imu_status.level == WARN and imu_status.values["dropped: /imu/data: IMU sample with NaN or inf"] == 1
    assert sum("camera /cam3/image_raw stopped publishing" in line for _, line in logs) == 1
    s.on_image(3, image(104.0), None)
    assert any("/cam3/image_raw is publishing again" in line for _, line in logs)


def test_reset_and_method_changes_reach_the_pipeline_in_order(rig):
    s, _, _ = service(rig)
    assert "a new sequence" in s.reset("test")
    s.set_method("6pt-nonbending")
    assert s.set_method("8pt").startswith("parameter method: must be one of")
    first = s.runner.pipeline
    for _ in range(3):  # reset, flush, method
        s.work_once()
    assert s.queue.get(0.0) is None
    assert s.runner.method == "6pt-nonbending" and s.runner.restarts == 1 and s.runner.pipeline is not first
    assert s.diagnostics()[2].values["resets"] == 1


def test_the_runner_keeps_statistics_and_sequence_numbers_over_restarts(rig):
    runner = PipelineRunner(rig, PipelineConfig())
    rng = np.random.default_rng(0)
    for k in range(3):
        imgs = [rng.integers(0, 255, (48, 64), dtype=np.uint8) for _ in range(4)]
        runner.run(Work(WorkKind.FRAMES, 1.0 + k, (FrameSet(1.0 + k, imgs), 0.0)))
    first = runner.pipeline
    runner.run(Work(WorkKind.RESTART, data="time jumped back"))
    assert runner.pipeline is not first and runner.restarts == 1
    runner.run(Work(WorkKind.FRAMES, 0.5, (FrameSet(0.5, imgs), 0.0)))  # an older stamp: fine in the new pipeline
    assert runner.stats.frames == 4
    runner.run(Work(WorkKind.FRAMES, 0.6, (FrameSet(0.6, imgs[:2]), 0.0)))  # the pipeline refuses it: counted
    assert runner.drops.by_reason()[Drop.BAD_FRAME_SET] == 1


def test_frame_grouping_reports_which_messages_it_dropped():
    sync = StampSynchronizer(2)
    for k in range(10):
        sync.add(0, k * 0.1, None)
        sync.add(1, k * 0.1, None)
    sync.take_dropped()
    sync.add(1, 0.85, None)
    assert sync.take_dropped() == [(1, 0.85, Drop.FRAME_LATE)] and sync.take_dropped() == []
    assert sync.oldest == math.inf  # every set went out
    sync.add(0, 1.0, None)
    assert sync.oldest == pytest.approx(1.0)
    assert FeederConfig().imu_wait_s > FeederConfig().imu_lead_s


def test_with_an_imu_every_frame_set_gives_the_cameras_poses_and_camera_poses_follow_their_rate(rig):
    """docs/CONVENTIONS.md (The rig in motion): TF of every camera at every frame set, ~/camera_poses at most
    camera_poses_rate_hz times per second of frame stamps."""
    from nrmpc_ros.frontend.outputs import FrameNames, frame_pose_fields

    poses = []
    cfg = NodeConfig(rig_file=rig.source, camera_poses_rate_hz=4.0, work_queue_size=20)
    s = EstimatorService(rig, cfg, PipelineConfig(), TOPICS, "/imu/data", lambda out: None,
                         lambda level, line: None, Clock(), publish_poses=poses.append)
    for k in range(300):
        s.on_imu(imu(100.0 + 0.005 * k), None)
    feed_sets(s, [100.0 + 0.1 * k for k in range(12)])
    while s.work_once():
        pass
    while len(s.queue):
        s.work_once()
    assert len(poses) >= 10
    assert all(p.poses.cameras.tolist() == [0, 1, 2, 3] for p in poses)
    due = [float(p.poses.stamps[0]) for p in poses if p.camera_poses]
    assert len(due) >= 2 and np.all(np.diff(due) >= 0.25 - 1e-9), "4 Hz by the frame stamps"
    names = FrameNames("base_link", "origin", tuple(f"{c.name}_optical" for c in rig.cameras))
    msgs = frame_pose_fields(poses[0], names, lambda t: (int(t), int(round((t % 1) * 1e9))))
    tf = msgs["tf"]["transforms"]
    assert [m["child_frame_id"] for m in tf] == list(names.cameras) and tf[0]["header"]["frame_id"] == "base_link"
    assert ("cams" in msgs) == poses[0].camera_poses


def test_stop_estimates_the_open_hold_only_when_it_fits_in_the_budget(rig):
    """Shutdown: the frame sets waiting are dropped and counted; the open hold is estimated when the longest hold
    estimate measured so far fits in the budget, and said so either way."""
    for measured_ms, budget_s, said in ((1e4, 0.5, "open hold not estimated: would not fit in the 0.5 s"),
                                        (None, 30.0, "open hold estimated at shutdown")):
        s, _, _ = service(rig, imu_topic=None)
        feed_sets(s, [100.0 + 0.1 * k for k in range(4)])
        while s.queue.frames():
            s.work_once()
        assert s.runner.hold_open
        feed_sets(s, [100.4, 100.5])  # waiting when the stop comes
        if measured_ms is not None:
            s.hold_ms.append(measured_ms)
        s.start()
        assert s.stop(budget_s).startswith(said)
        assert s.runner.hold_open == (measured_ms is not None)
        assert "frame set not processed at shutdown" in s.summary() or s.counts["processed frame sets"] == 6


# --------------------------------------------------------------------------- the two workers on a rendered bag
def _feed_bag(s, path, topics, imu_topic, end: bool = True, live: bool = False) -> None:
    """Every message of the bag to the service, as the node's executor would hand them over (bag time as now);
    then the end of the input, or (``end`` False) nothing: the node is stopped before it saw the input end.
    ``live``: both workers run what waits after each message, as a node that keeps up (what the intake
    measures reaches the input before the next message)."""
    from nrmpc_ros.bag.reader import BagReader

    index = {t: i for i, t in enumerate(topics)}
    with BagReader(path) as bag:
        for topic, t_ns, msg in bag.messages(list(topics) + [imu_topic]):
            if topic == imu_topic:
                s.on_imu(msg, t_ns * 1e-9)
            else:
                s.on_image(index[topic], msg, t_ns * 1e-9)
            while live and len(s.queue):
                s.work_once()
            while live and s.estimate_once() is not None:
                pass
    if end:
        s.feeder.end()


def _stream_service(tmp_path_factory, clock=None) -> tuple:
    """(service, its outputs, bag, rig) on the rendered stream bag, with a work queue no frame set overflows."""
    from rendered_bags import CAMERAS, IMU, stream_bag

    path, rig_path, _ = stream_bag(tmp_path_factory)
    rig = load_rig(rig_path)
    out = []
    s = EstimatorService(rig, NodeConfig(rig_file=str(rig_path), work_queue_size=100000), PipelineConfig(), CAMERAS,
                         IMU, out.append, lambda level, line: None, *([clock] if clock is not None else []))
    return s, out, path, rig


def _replayed(path, rig, imu_topic) -> list:
    from nrmpc_ros.bag.reader import BagReader
    from nrmpc_ros.frontend.replay import replay_bag

    with BagReader(path) as bag:
        return [e for batch in replay_bag(bag, rig, PipelineRunner(rig, PipelineConfig()), imu_topic) for e in batch]


def _same_estimates(got: list, want: list) -> None:
    assert len(got) == len(want) >= 3
    for a, b in zip(got, want):
        assert (a.stamp, a.ref_stamp, a.sequence, a.hold_index) == (b.stamp, b.ref_stamp, b.sequence, b.hold_index)
        assert np.array_equal(a.gravity, b.gravity) and np.array_equal(a.R_origin, b.R_origin)


@pytest.mark.slow
def test_frame_intake_goes_on_while_holds_wait_and_both_workers_give_the_replays_estimates(tmp_path_factory):
    """The intake worker takes every frame set while the measured holds wait for the estimation worker (here: it
    is not run until the input ended), and the estimates it then publishes are the replay's, bit for bit, over
    a bag played twice (its stamps jump back: a restart between the passes)."""
    from rendered_bags import CAMERAS, IMU, played_twice

    s, out, path, rig = _stream_service(tmp_path_factory, Clock())
    twice = played_twice(path, tmp_path_factory.mktemp("twice") / "twice")
    _feed_bag(s, twice, CAMERAS, IMU)
    sets = s.queue.frames()
    while s.work_once():
        pass
    while len(s.queue):
        s.work_once()
    assert s.counts["processed frame sets"] == sets and not out, "no estimate ran: intake did not wait for one"
    est = s.diagnostics()[2].values
    assert est["holds waiting"] == s.holds.holds() >= 6 and est["frame sets waiting"] == 0
    assert est["work waiting"] == len(s.holds) > 0 and s.runner.restarts == 1
    while s.estimate_once() is not None:
        pass
    assert s.holds_waiting() == 0 and s.work_waiting() == 0
    want = _replayed(twice, rig, IMU)
    _same_estimates([o.estimate for o in out], want)
    assert s.stats.estimates == len(want) and s.counts["estimates"] == len(want)
    assert {e.sequence for e in want} == {0, 1}, "the restart numbers the second pass's sequence on"


@pytest.mark.slow
def test_the_two_worker_threads_give_the_replays_estimates_and_report_both_latencies(tmp_path_factory):
    """Both workers running while the bag is handed over as fast as it can be: nothing is dropped (a queue large
    enough), the estimates are the replay's, and the diagnostics give both latencies."""
    import time

    from rendered_bags import CAMERAS, IMU

    s, out, path, rig = _stream_service(tmp_path_factory)
    s.start()
    try:
        _feed_bag(s, path, CAMERAS, IMU)
        deadline = time.monotonic() + 300.0
        while s.work_waiting() and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        said = s.stop(5.0)
    assert said == "no open hold"
    _same_estimates([o.estimate for o in out], _replayed(path, rig, IMU))
    est = s.diagnostics()[2].values
    assert float(est["frame set latency p95 (ms)"]) > 0 and float(est["hold latency p95 (ms)"]) > 0
    assert est["holds waiting"] == 0 and est["work waiting"] == 0


@pytest.mark.slow
def test_the_open_hold_estimated_at_shutdown_is_the_replays_last_estimate(tmp_path_factory):
    """Stopped before it saw the input end (a simulated clock that never ran, a shutdown right after the bag):
    the open hold is measured on everything received, the frames still grouped and the IMU samples held after
    the last frame set included, so its estimate is the replay's, which saw the bag's end."""
    import time

    from rendered_bags import CAMERAS, IMU

    s, out, path, rig = _stream_service(tmp_path_factory)
    s.start()
    _feed_bag(s, path, CAMERAS, IMU, end=False)
    deadline = time.monotonic() + 300.0
    while (len(s.queue) or s.holds_waiting()) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert s.runner.hold_open
    assert s.stop(60.0) == "open hold estimated at shutdown"
    _same_estimates([o.estimate for o in out], _replayed(path, rig, IMU))


def test_a_failing_hold_estimate_is_counted_and_the_estimation_worker_goes_on(rig):
    """A bug in one hold's estimation (here: a measured hold without its measurement) is dropped as "estimation
    failed", logged as an error and reported; the next item still runs."""
    from nrmpc_ros.frontend.estimation import MeasuredHold, SequenceReset
    from nrmpc_ros.frontend.runner import StageWork

    s, _, logs = service(rig)
    p = s.runner.pipeline
    s.holds.put(StageWork(p, MeasuredHold(None, None, None, None)), 0.0)
    s.holds.put(StageWork(p, SequenceReset()), 0.0)
    assert s.estimate_once() == [] and s.holds_waiting() == 0 and len(s.holds) == 1, "a reset waits, no hold"
    assert s.estimate_once() == [] and len(s.holds) == 0
    assert s.drops.by_reason()[Drop.ESTIMATION_FAILED] == 1
    assert any(level == "error" and "estimation failed" in line for level, line in logs)
    assert s.diagnostics()[2].level == ERROR


def test_an_imu_clock_measured_seconds_off_is_in_the_imu_diagnostics_with_the_setting(rig):
    """The frame stage's measurement (the moves against the gyro, taken once the images refute the IMU's gravity)
    reaches the IMU's diagnostics with the value of input.imu_clock_offset_s that fixes it."""
    from nrmpc_ros.frontend.imu_clock import FarClockOffset
    from nrmpc_ros.frontend.imu_clock_check import ClockEvidence, MeasuredClockOffset

    s, _, _ = service(rig)
    assert "clock check" not in s.diagnostics()[1].values
    far = FarClockOffset(offset_s=-2.02, correlation=0.9, rival_correlation=0.2, confidence=1.0, moves=7)
    s.runner.pipeline.imu_clock_off = MeasuredClockOffset(-2.02, ClockEvidence.MOVES, far)
    check = s.diagnostics()[1].values["clock check"]
    assert "+2.020 s off the cameras'" in check and "input.imu_clock_offset_s to -2.020" in check


@pytest.mark.slow
def test_an_imu_stamped_a_fraction_of_a_second_late_is_measured_and_applied_by_the_running_node(tmp_path):
    """The IMU's stamps 0.15 s late: every hold's IMU stillness reaches into the next move and the holds never
    settle, so no IMU gravity is refuted and the far search is never asked. The node asks the near search as
    holds end (once three moves are behind them), applies the lag it finds (one new sequence), and the holds
    after the restart's first are estimated, each within 3 of its std of the truth."""
    from nrmpc_ros.cli.main import main

    path, rig_file = tmp_path / "late", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(path), "--save-rig", str(rig_file), "--resolution", "320x240",
                 "--supersample", "1", "--cameras", "4", "--imu-time-offset-ms", "150", "--rate", "20",
                 "--capture", "stream", "--bar-hz", "3", "--damping", "0.03", "--views", "10", "--seed", "105",
                 "--no-progress"]) == 0
    s, ests, logs = live_service(path, rig_file)
    assert s.counts["IMU clock offsets applied"] == 1
    assert abs(s.feeder.config.imu_clock_offset_s + 0.15) < 0.01
    applied = [line for line in logs if "added to the IMU's stamps" in line]
    assert len(applied) == 1 and "a new sequence" in applied[0]
    assert len(ests) >= 5
    within_3_std_of_the_truth(path, ests)


@pytest.mark.slow
def test_an_uncalibrated_accelerometer_is_said_in_the_imu_diagnostics_and_the_node_keeps_its_stds(tmp_path):
    """An accelerometer 80 mg off (up to 4.7 deg of tilt): the running node grades the tilt's prior by the still
    norms as replay does, every estimate lies within 3 of its std of the truth, and the IMU diagnostics say the
    bias the norms show."""
    from nrmpc_ros.cli.main import main

    path, rig_file = tmp_path / "biased", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(path), "--save-rig", str(rig_file), "--resolution", "240x180",
                 "--supersample", "1", "--cameras", "4", "--views", "6", "--imu-bias", "0.8", "--seed", "21",
                 "--no-progress"]) == 0
    s, ests, _ = live_service(path, rig_file)
    assert len(ests) == 6  # every hold (the first one's with the second's)
    within_3_std_of_the_truth(path, ests)
    said = s.diagnostics()[1].values["accelerometer bias"]
    assert "tilts its gravity by up to 4.6" in said and "estimated with a prior of" in said
    assert "subtract it from the readings" in said


def live_service(path, rig_file) -> tuple:
    """(service, the estimates it published, its log lines) of the node fed a make-bag recording as it runs
    (:func:`_feed_bag` ``live``), its workers run to the end."""
    rig = load_rig(rig_file)
    cameras = [f"/cam{i}/image_raw" for i in range(rig.num_cameras)]
    out, logs = [], []
    s = EstimatorService(rig, NodeConfig(rig_file=str(rig_file), work_queue_size=100000), PipelineConfig(),
                         cameras, "/imu/data", out.append, lambda level, line: logs.append(line), Clock())
    _feed_bag(s, path, cameras, "/imu/data", live=True)
    while len(s.queue):
        s.work_once()
    while s.estimate_once() is not None:
        pass
    return s, [o.estimate for o in out], logs


def within_3_std_of_the_truth(path, estimates) -> None:
    """Every estimate's gravity within 3 of its own std of the recording's /ground_truth/gravity."""
    from nrmpc_ros.bag.reader import BagReader
    from nrmpc_ros.frontend.reference import nearest_stamp, read_reference

    with BagReader(path) as bag:
        truth = read_reference(bag)
    for e in estimates:
        g = truth.grav_g[nearest_stamp(truth.grav_t, e.stamp)]
        err = math.degrees(math.acos(np.clip(g @ e.gravity / np.linalg.norm(g) / np.linalg.norm(e.gravity), -1, 1)))
        assert err < 3.0 * e.gravity_sigma_deg, (e.stamp, err, e.gravity_sigma_deg)


@pytest.mark.slow
def test_an_imu_read_in_batches_and_filtered_under_a_claim_of_a_fifth_of_its_noise_loses_no_hold_in_the_node(
        tmp_path):
    """A driver that stamps samples when the host reads them (batches stamped alike) of a 20 Hz low-pass
    filtered IMU, claiming a fifth of its noise: the running node keeps every sample, drops the claim once the
    images held still where it read motion, estimates every hold after the first within 3 of its std of the
    truth, and its IMU diagnostics say both."""
    from nrmpc_ros.cli.main import main

    path, rig_file = tmp_path / "host", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(path), "--save-rig", str(rig_file), "--resolution", "240x180",
                 "--supersample", "1", "--cameras", "3", "--views", "6", "--imu-rate", "400", "--imu-lowpass-hz",
                 "20", "--imu-covariance-scale", "0.2", "--imu-stamp-jitter-ms", "6", "--seed", "22",
                 "--no-progress"]) == 0
    s, ests, _ = live_service(path, rig_file)
    assert len(ests) == 6  # every hold (the first one's with the second's)
    within_3_std_of_the_truth(path, ests)
    values = s.diagnostics()[1].values
    assert "not used" in values["covariances"] and "read in batches" in values["samples stamped alike"]
    assert not any("out of order" in str(k) for k in values)


def test_diagnostics_say_the_rest_turns_where_the_rig_file_states_its_calibration(rig):
    """A rig file with rotation_std_deg: /diagnostics carries each such camera's estimated rest turn (0 before
    any hold); a rig file without says nothing of them."""
    from dataclasses import replace

    plain, _, _ = service(rig)
    assert not any(k.startswith("rest turn:") for k in plain.diagnostics()[2].values)
    stated = replace(rig, cameras=tuple(replace(c, rotation_std_deg=0.05 if i else 0.0)
                                        for i, c in enumerate(rig.cameras)))
    s, _, _ = service(stated)
    values = s.diagnostics()[2].values
    turns = {k: v for k, v in values.items() if k.startswith("rest turn:")}
    assert turns == {f"rest turn: {c.name} (deg)": "0.000" for c in stated.cameras[1:]}
