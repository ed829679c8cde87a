"""Drop reasons: one member per reason, every outcome type of a family mapped, the messages users read kept."""

import math

import pytest

from nrmpc_ros.core.incremental import StartReason
from nrmpc_ros.frontend.drops import Drop, Stage, sorted_counts
from nrmpc_ros.frontend.holds import Refusal
from nrmpc_ros.frontend.imu import ImuRefusal, ImuReject
from nrmpc_ros.frontend.motion import Motion, MotionKind
from nrmpc_ros.frontend.work import WorkKind


def test_every_outcome_of_a_family_has_its_drop():
    families = [(ImuReject, Drop.imu_sample), (MotionKind, Drop.not_at_rest), (Refusal, Drop.hold_refused),
                (ImuRefusal, Drop.no_imu_gravity)]
    for outcomes, drop in families:
        members = [drop(o) for o in outcomes]
        assert len(set(members)) == len(members) and all(m.stage is Stage.PIPELINE for m in members)
        assert all(o.value in m.message for o, m in zip(outcomes, members)), "the message names the outcome"
    breaks = [r for r in StartReason if r is not StartReason.FIRST_VIEW]
    assert {Drop.new_sequence(r) for r in breaks} == {Drop.NEW_SEQUENCE_NO_SHARED, Drop.NEW_SEQUENCE_PAIR_FAILED,
                                                      Drop.NEW_SEQUENCE_FEW_INLIERS}
    with pytest.raises(KeyError):  # a sequence's first view is no drop
        Drop.new_sequence(StartReason.FIRST_VIEW)
    assert len({Drop.busy(kind) for kind in WorkKind}) == len(WorkKind)
    assert all(Drop.busy(kind).stage is Stage.WORKER for kind in WorkKind)


def test_messages_are_unique_and_user_facing_ones_unchanged():
    assert len({d.message for d in Drop}) == len(Drop)
    # read by users, the DDS tests and scripts/bench_node.py as /diagnostics keys "dropped: <source>: <message>"
    assert Drop.BUSY_FRAME_SET.message == "frame set dropped while the estimator is busy"
    assert Drop.STAMP_IN_FUTURE.message == "stamp in the future"
    assert Drop.IMU_NOT_FINITE.message == "IMU sample with NaN or inf"
    assert Drop.NOT_AT_REST_IMU.message == "frame not at rest (the IMU says the rig moved)"
    assert Drop.FRAME_LATE.message == "frame late" and Drop.FRAME_LATE.label == "late"
    assert Drop("stamp in the future") is Drop.STAMP_IN_FUTURE and str(Drop.STAMP_IN_FUTURE) == "stamp in the future"


def test_counts_are_shown_in_the_order_of_their_text():
    counts = {("/imu", Drop.IMU_NOT_FINITE): 1, ("/cam0", Drop.FRAME_UNMATCHED): 2, ("/cam0", Drop.FRAME_LATE): 3}
    assert [k for k, _ in sorted_counts(counts)] == [("/cam0", Drop.FRAME_LATE), ("/cam0", Drop.FRAME_UNMATCHED),
                                                      ("/imu", Drop.IMU_NOT_FINITE)]
    assert [k for k, _ in sorted_counts({Drop.SNAPSHOT_MOVED: 1, Drop.BAD_FRAME_SET: 1})] == \
        [Drop.BAD_FRAME_SET, Drop.SNAPSHOT_MOVED]


def test_motion_sentences():
    assert str(Motion(MotionKind.IMU_MOVED)) == "the IMU says the rig moved"
    assert str(Motion(MotionKind.TRACKS_LOST, "cam1")) == "cam1: tracks lost"
    assert str(Motion(MotionKind.IMAGE_MOVED, "cam0", 1.234)) == "cam0: image moved 1.23 px"
    assert str(Motion(MotionKind.LEFT_HOLD, "cam2", 7.25)) == "cam2: image left the hold (7.2 px from its first frame)"
    assert math.isnan(Motion(MotionKind.IMU_MOVED).px)
