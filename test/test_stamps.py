"""StampGuard: stamps in the future dropped, jumps back confirmed by two inputs or several messages, glitches
dropped, stragglers from before a jump dropped, streams that lag behind rejoin."""

import math

import pytest

from nrmpc_ros.frontend.drops import Drop
from nrmpc_ros.frontend.stamps import JumpPolicy, StampGuard

IMU, CAM0, CAM1 = "imu", 0, 1


def run(guard, msgs, now=None):
    """(accepted (stream, stamp), drops (reason), jumps) for messages (stream, stamp) in arrival order."""
    accepted, drops, jumps = [], [], []
    for stream, stamp in msgs:
        v = guard.check(stream, stamp, payload=(stream, stamp), now=now)
        drops += [r for r, _ in v.drops]
        if v.jump is not None:
            jumps.append(v.jump)
            accepted += [(s, t) for s, t, _ in v.jump.held]
        elif v.accept:
            accepted.append((stream, stamp))
    return accepted, drops, jumps


def stream(t0, n, dt, streams=(IMU, CAM0, CAM1)):
    return [(s, t0 + k * dt) for k in range(n) for s in streams]


def test_a_stamp_far_ahead_of_the_clock_is_dropped_not_adopted():
    g = StampGuard(max_future_s=10.0)
    accepted, drops, _ = run(g, stream(100.0, 5, 0.1), now=100.5)
    assert len(accepted) == 15 and not drops
    v = g.check(CAM0, 2145916800.0, now=100.6)  # 2038
    assert not v.accept and v.drops[0][0] is Drop.STAMP_IN_FUTURE and "ahead of the clock" in v.drops[0][1]
    assert g.newest() == pytest.approx(100.4)  # the present did not move
    accepted, drops, _ = run(g, stream(100.5, 3, 0.1), now=100.8)
    assert len(accepted) == 9 and not drops
    # without a clock there is no such test
    assert StampGuard().check(CAM0, 2145916800.0, now=None).accept


def test_non_finite_stamps_are_dropped():
    v = StampGuard().check(CAM0, math.nan)
    assert not v.accept and v.drops[0][0] is Drop.STAMP_NOT_FINITE


def test_a_bag_played_again_is_one_jump_back_confirmed_by_a_second_input():
    g = StampGuard(jumps=JumpPolicy(jump_back_s=1.0))
    run(g, stream(100.0, 30, 0.1))
    accepted, drops, jumps = run(g, stream(100.0, 3, 0.1))  # the same stamps again
    assert len(jumps) == 1 and not drops
    j = jumps[0]
    assert j.stream == IMU and j.old == pytest.approx(102.9) and j.new == pytest.approx(100.0)
    assert "detected jump back in time" in j.describe("/imu/data") and "2.900 s back" in j.describe("/imu/data")
    assert [m[0] for m in j.held] == [IMU, CAM0]  # held until the second input showed the same jump
    assert len(accepted) == 9, "after the jump every message of the new time goes through"
    assert g.jumps == 1


def test_one_input_alone_confirms_with_several_messages():
    g = StampGuard(jumps=JumpPolicy(jump_back_s=1.0, confirm=3))
    run(g, [(CAM0, 100.0 + 0.1 * k) for k in range(30)])
    _, _, jumps = run(g, [(CAM0, 50.0), (CAM0, 50.1)])
    assert not jumps
    _, _, jumps = run(g, [(CAM0, 50.2)])
    assert len(jumps) == 1 and len(jumps[0].held) == 3


def test_a_single_stale_stamp_is_a_glitch_and_dropped():
    g = StampGuard(jumps=JumpPolicy(jump_back_s=1.0))
    run(g, stream(100.0, 30, 0.1))
    accepted, drops, jumps = run(g, [(CAM0, 95.0), (IMU, 103.0), (CAM0, 103.0), (CAM1, 103.0)])
    assert not jumps and drops == [Drop.STAMP_FAR_PAST]
    assert accepted == [(IMU, 103.0), (CAM0, 103.0), (CAM1, 103.0)]


def test_messages_from_before_the_jump_are_dropped_until_their_input_sends_the_new_time():
    g = StampGuard(jumps=JumpPolicy(jump_back_s=1.0))
    run(g, stream(100.0, 30, 0.1))
    _, _, jumps = run(g, [(IMU, 100.0), (CAM0, 100.0)])
    assert jumps
    accepted, drops, _ = run(g, [(CAM1, 102.95), (IMU, 100.05), (CAM1, 100.0), (CAM1, 100.1)])
    assert drops == [Drop.BEFORE_JUMP_BACK]
    assert accepted == [(IMU, 100.05), (CAM1, 100.0), (CAM1, 100.1)]


def test_messages_of_an_input_delivered_late_are_dropped_as_from_before_the_jump():
    """The IMU's messages arrive 2 s late (a backlog) when the cameras jump back: its messages up to the cameras'
    old time are from before the jump too, not a second jump."""
    g = StampGuard(jumps=JumpPolicy(jump_back_s=1.0))
    cameras = [(c, 100.0 + 0.1 * k) for k in range(30) for c in (CAM0, CAM1)]
    run(g, cameras + [(IMU, 100.0 + 0.1 * k) for k in range(10)])
    _, _, jumps = run(g, [(CAM0, 50.0), (CAM1, 50.0), (CAM0, 50.1), (CAM1, 50.1)])
    assert len(jumps) == 1
    accepted, drops, jumps = run(g, [(IMU, 101.0 + 0.1 * k) for k in range(20)] + [(IMU, 50.0), (IMU, 50.1)])
    assert not jumps and drops == [Drop.BEFORE_JUMP_BACK] * 20
    assert accepted == [(IMU, 50.0), (IMU, 50.1)]


def test_an_input_that_fell_behind_rejoins_the_others():
    """A camera whose one bad stamp ran ahead of the others comes back to their time without a jump."""
    g = StampGuard(jumps=JumpPolicy(jump_back_s=1.0))
    run(g, stream(100.0, 10, 0.1))
    assert g.check(CAM1, 103.0).accept  # ahead of the others, but not of the clock: taken
    accepted, drops, jumps = run(g, [(CAM1, 101.0), (IMU, 101.0), (CAM1, 101.1)])
    assert not jumps and not drops and len(accepted) == 3
