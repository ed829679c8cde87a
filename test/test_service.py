"""EstimatorService and the node's settings without ROS: parameters from the configs, files, the work queue,
drops while busy, liveness, resets, restarts, diagnostics and the summary."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rendered_bags import rig_file
from test_feeder import TOPICS, image, imu

from nrmpc_ros.core import load_rig
from nrmpc_ros.frontend.feeder import FeederConfig, Work
from nrmpc_ros.frontend.node_config import (
    NodeConfig,
)
from nrmpc_ros.frontend.pipeline import FrameSet, PipelineConfig
from nrmpc_ros.frontend.runner import PipelineRunner
from nrmpc_ros.frontend.service import OK, WARN, EstimatorService, WorkQueue
from nrmpc_ros.frontend.sync import StampSynchronizer


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
    assert [q.put(Work("frames", k)) for k in range(3)] == [True, True, False]
    assert q.put(Work("imu", 1.0)) and q.put(Work("flush")) and q.frames() == 2
    assert q.get(0.01).stamp == 0 and q.frames() == 1


def feed_sets(s, stamps, now=None):
    for t in stamps:
        for i in range(4):
            s.on_image(i, image(t, value=int(t * 10) % 200), now)


def test_sets_arriving_while_the_estimator_is_busy_are_dropped_counted_and_logged(rig):
    s, _, logs = service(rig, imu_topic=None, work_queue_size=2)
    feed_sets(s, [100.0 + 0.1 * k for k in range(8)])  # no IMU: sets go to the queue at once
    busy = s.drops.counts()[("worker", "frame set dropped while the estimator is busy")]
    assert busy >= 4 and s.queue.frames() == 2
    assert sum("dropped while the estimator is busy" in line for _, line in logs) == 1, "logged once"
    while s.queue.frames():
        s.work_once()
    assert s.counts["processed frame sets"] == 2
    est = s.diagnostics()[2]
    assert est.name == "estimation" and est.level == WARN and "dropped" in est.message
    assert s.diagnostics()[2].level == OK, "the warning is about the last period"
    assert "worker: frame set dropped while the estimator is busy" in s.summary()


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
    assert kinds[-1] == "flush" and kinds.count("frames") == 2
    cams = s.diagnostics()[0]
    assert cams.level == OK and "the input ended" in cams.message
    assert cams.values["/cam0/image_raw: state"] == "input ended"


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
        runner.run(Work("frames", 1.0 + k, (FrameSet(1.0 + k, imgs), 0.0)))
    first = runner.pipeline
    runner.run(Work("restart", data="time jumped back"))
    assert runner.pipeline is not first and runner.restarts == 1
    runner.run(Work("frames", 0.5, (FrameSet(0.5, imgs), 0.0)))  # an older stamp: fine in the new pipeline
    assert runner.stats.frames == 4
    runner.run(Work("frames", 0.6, (FrameSet(0.6, imgs[:2]), 0.0)))  # the pipeline refuses it: counted
    assert runner.drops.by_reason()["bad frame set"] == 1


def test_frame_grouping_reports_which_messages_it_dropped():
    sync = StampSynchronizer(2)
    for k in range(10):
        sync.add(0, k * 0.1, None)
        sync.add(1, k * 0.1, None)
    sync.take_dropped()
    sync.add(1, 0.85, None)
    assert sync.take_dropped() == [(1, 0.85, "late")] and sync.take_dropped() == []
    assert sync.oldest == math.inf  # every set went out
    sync.add(0, 1.0, None)
    assert sync.oldest == pytest.approx(1.0)
    assert FeederConfig().imu_wait_s > FeederConfig().imu_lead_s
