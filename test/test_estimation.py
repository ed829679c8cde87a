"""The pipeline's estimation stage (frontend/estimation.py): measured holds handed over in order, run at once or
later, the same estimates either way."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rendered_bags import IMU, rig_file, stream_bag

from nrmpc_ros.core import load_rig
from nrmpc_ros.core.so3 import angle_between
from nrmpc_ros.core.tilt_mixture import prior_sigma_rad
from nrmpc_ros.frontend.estimation import IMU_ONLY_METHOD, InputEnded, MeasuredHold, SequenceReset
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


def _stage_work(tmp_path_factory, method: str = "auto") -> tuple:
    """(rig, the deferred runner, its stage work) of the 4-hold stream."""
    path, rig_path, _ = stream_bag(tmp_path_factory)
    rig = load_rig(rig_path)
    deferred = PipelineRunner(rig, PipelineConfig(), method, deferred=True)
    _replay(path, rig, deferred)
    return rig, deferred, deferred.take_stage_work()


@pytest.mark.slow
def test_a_hold_no_later_hold_links_gets_the_imus_gravity_at_its_std(tmp_path_factory):
    """A reset right after the first hold leaves it alone: it is estimated from its averaged accelerometer at the
    std of that average with the accelerometer's tilt prior (its two, calibrated or not, as the norms weigh
    them), its pose the identity in its own origin; the holds after the reset are estimated as a sequence of
    their own. The end of the input does the same for a last hold alone, once, and a vision-only method never
    does it."""
    rig, deferred, work = _stage_work(tmp_path_factory)
    holds = [w for w in work if w.is_hold]
    stage = deferred.pipeline.estimator
    first = holds[0].item
    alone = stage.run(first) + stage.run(SequenceReset())
    assert len(alone) == 1
    e = alone[0]
    assert e.method == IMU_ONLY_METHOD and e.stamp == e.ref_stamp == e.origin_stamp == first.hold.stamp
    assert np.array_equal(e.gravity, first.imu.gravity) and np.array_equal(e.R, np.eye(3))
    sigma = math.hypot(first.imu_sigma_rad, prior_sigma_rad(first.tilt_sigma_rad, first.calibration))
    assert e.gravity_sigma_deg == pytest.approx(math.degrees(sigma))
    u = e.gravity / np.linalg.norm(e.gravity)
    assert np.allclose(e.cov_gravity @ u, 0.0, atol=1e-12)
    assert np.sqrt(np.linalg.eigvalsh(e.cov_gravity).max()) / np.linalg.norm(e.gravity) == pytest.approx(sigma)
    rest = [x for w in holds[1:] for x in stage.run(w.item)]
    assert len(rest) == len(holds) - 1 and all(x.method == "4pt-bending" for x in rest)
    assert stage.run(InputEnded()) == []  # the last hold is in a sequence: nothing alone
    last = holds[-1].item
    stage.run(SequenceReset())
    assert stage.run(last) == []
    ended = stage.run(InputEnded())
    assert [x.method for x in ended] == [IMU_ONLY_METHOD] and ended[0].stamp == last.hold.stamp
    assert stage.run(InputEnded()) == [] and stage.run(SequenceReset()) == []  # once
    assert deferred.stats.methods[IMU_ONLY_METHOD] == 2

    _, vision, work = _stage_work(tmp_path_factory, "6pt-bending")
    stage = vision.pipeline.estimator
    holds = [w for w in work if w.is_hold]
    assert stage.run(holds[0].item) + stage.run(SequenceReset()) + stage.run(InputEnded()) == []


@pytest.mark.slow
def test_holds_far_apart_are_each_estimated_and_those_alone_within_their_std(tmp_path):
    """Snapshots 0.8 m and up to 30 deg apart: some holds share no landmarks with any other. Each still gets an
    estimate (those alone from the IMU), within 3 of its std of the truth."""
    from nrmpc_ros.bag.reader import BagReader
    from nrmpc_ros.frontend.reference import nearest_stamp, read_reference
    from nrmpc_ros.render.bagmaker import BagOptions, make_bag
    from nrmpc_ros.render.sequence import MotionOptions

    rig = load_rig(rig_file(tmp_path))
    make_bag(rig, tmp_path / "far", BagOptions(motion=MotionOptions(views=10, capture="snapshot",
                                                                    max_translation=0.8), seed=0), progress=False)
    runner = PipelineRunner(rig, PipelineConfig())
    got = _replay(tmp_path / "far", rig, runner)
    with BagReader(tmp_path / "far") as bag:
        ref = read_reference(bag, None)
    assert len({e.stamp for e in got}) == len(got) == runner.stats.holds == 10
    alone = [e for e in got if e.method == IMU_ONLY_METHOD]
    assert alone, "the recording has holds no other links"
    for e in got:
        g = ref.grav_g[nearest_stamp(ref.grav_t, e.stamp)]
        assert math.degrees(angle_between(e.gravity, g)) <= 3.0 * e.gravity_sigma_deg
