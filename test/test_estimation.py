"""The pipeline's estimation stage (frontend/estimation.py): measured holds handed over in order, run at once or
later, the same estimates either way."""

from __future__ import annotations

import numpy as np
import pytest
from rendered_bags import IMU, rig_file, stream_bag

from nrmpc_ros.core import load_rig
from nrmpc_ros.frontend.estimation import MeasuredHold, SequenceReset
from nrmpc_ros.frontend.pipeline import Pipeline, PipelineConfig, RigState
from nrmpc_ros.frontend.runner import PipelineRunner


def test_a_reset_is_handed_to_the_estimation_stage_in_order(tmp_path):
    pipe = Pipeline(load_rig(rig_file(tmp_path, 64)), PipelineConfig())
    pipe.handoff = []
    pipe.reset()
    assert pipe.take_handoff() == [SequenceReset()] and pipe.take_handoff() == []


def _replay(path, rig, runner) -> list:
    from nrmpc_ros.bag.reader import BagReader
    from nrmpc_ros.frontend.replay import replay_bag

    with BagReader(path) as bag:
        return [e for batch in replay_bag(bag, rig, runner, IMU) for e in batch]


@pytest.mark.slow
def test_holds_estimated_later_give_the_estimates_of_holds_estimated_at_once(tmp_path_factory):
    """The deferred runner (the node's) hands every measured hold over and estimates nothing itself; run later in
    order, the items give the immediate runner's (the replay's) estimates bit for bit, and while they wait the
    rig's state counts them as added."""
    path, rig_path, _ = stream_bag(tmp_path_factory)
    rig = load_rig(rig_path)
    want = _replay(path, rig, PipelineRunner(rig, PipelineConfig()))
    deferred = PipelineRunner(rig, PipelineConfig(), deferred=True)
    assert _replay(path, rig, deferred) == []
    work = deferred.take_stage_work()
    holds = [w for w in work if w.is_hold]
    assert len(holds) == deferred.stats.holds == len(want), "one estimate per hold, the origin's too"
    assert all(isinstance(w.item, MeasuredHold) and w.item.imu is not None for w in holds)
    status = deferred.pipeline.status()
    assert status.state is not RigState.WAITING
    got = [e for w in work for e in deferred.estimate(w)]
    assert len(got) == len(want) >= 3
    for a, b in zip(got, want):
        assert (a.stamp, a.ref_stamp, a.sequence, a.hold_index) == (b.stamp, b.ref_stamp, b.sequence, b.hold_index)
        assert np.array_equal(a.gravity, b.gravity) and np.array_equal(a.cov_pose, b.cov_pose)
    assert deferred.stats.estimates == len(want) and deferred.take_stage_work() == []
