"""Feeder: the input policy of the node and the replay (checks, stamps, frame grouping, IMU merged by stamp)."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rendered_bags import rig_file

from nrmpc_ros.config import from_mapping
from nrmpc_ros.core import load_rig
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.droplog import DropLog
from nrmpc_ros.frontend.drops import Drop
from nrmpc_ros.frontend.feeder import IMU, Feeder, FeederConfig
from nrmpc_ros.frontend.imu_block import ImuBlock
from nrmpc_ros.frontend.stamps import JumpPolicy
from nrmpc_ros.frontend.work import WorkKind

ROOT = Path(__file__).resolve().parents[1]
TOPICS = [f"/cam{i}/image_raw" for i in range(4)]


@pytest.fixture
def rig(tmp_path):
    """The sample rig with 64x48 cameras (cheap images)."""
    return load_rig(rig_file(tmp_path, 64))


def stamp_of(t: float):
    sec = math.floor(t)
    return SimpleNamespace(sec=int(sec), nanosec=int(round((t - sec) * 1e9)))


def image(t: float, w=64, h=48, encoding="mono8", value=0):
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp_of(t)), height=h, width=w, encoding=encoding, step=w,
                           is_bigendian=0, data=bytes([value]) * (w * h))


def imu(t: float, accel=(0.0, 0.0, 9.81)):
    v3 = SimpleNamespace
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp_of(t)), linear_acceleration=v3(x=accel[0], y=accel[1],
                           z=accel[2]), angular_velocity=v3(x=0.0, y=0.0, z=0.0))


def feeder(rig, imu_topic="/imu/data", **cfg):
    work, logs = [], []
    f = Feeder(rig, FeederConfig(**cfg), work.append, DropLog(), TOPICS, imu_topic,
               log=lambda level, line: logs.append((level, line)), clock=lambda: 0.0)
    return f, work, logs


def messages(t0=100.0, seconds=2.0, frame_hz=10.0, imu_hz=200.0, imu_delay=0.0):
    """(arrival, kind, index, stamp) of 4 cameras and an IMU; the IMU arrives ``imu_delay`` s late."""
    out = []
    for k in range(int(seconds * frame_hz)):
        t = t0 + k / frame_hz
        out += [(t + 0.001 * i, "image", i, t) for i in range(4)]
    for k in range(int(seconds * imu_hz)):
        t = t0 + k / imu_hz
        out.append((t + imu_delay, "imu", None, t))
    return sorted(out, key=lambda m: m[0])


def feed(f, msgs, now=None):
    for _, kind, i, t in msgs:
        if kind == "image":
            f.image(i, image(t), now)
        else:
            f.imu_msg(imu(t), now)


def trace(work):
    return [(w.kind, round(w.stamp, 6) if math.isfinite(w.stamp) else None) for w in work]


def test_work_leaves_merged_by_stamp_whatever_order_the_topics_arrive_in(rig):
    runs = []
    for delay in (0.0, 0.02, 0.3, -0.3):  # the IMU in step, a little late, far late, early
        f, work, _ = feeder(rig)
        feed(f, messages(imu_delay=delay))
        f.end()
        runs.append(trace(work))
    assert all(r == runs[0] for r in runs[1:])
    frames = [(i, t) for i, (k, t) in enumerate(runs[0]) if k is WorkKind.FRAMES]
    assert len(frames) == 20 and runs[0][-1][0] == WorkKind.FLUSH
    lead = FeederConfig().imu_lead_s
    for i, t in frames:  # every IMU sample stamped before t + lead goes before the set, none later
        before = [s for k, s in runs[0][:i] if k is WorkKind.IMU]
        after = [s for k, s in runs[0][i:] if k is WorkKind.IMU]
        assert max(before, default=-math.inf) < t + lead and (not after or min(after) >= t + lead)
    assert len([s for k, s in runs[0][:frames[1][0]] if k is WorkKind.IMU]) > 0


def round_robin(msgs):
    """The messages as a busy process takes them: each topic's queue in turn, one message of each at a time."""
    queues = {}
    for m in msgs:
        queues.setdefault((m[1], m[2]), []).append(m)
    out = []
    while any(queues.values()):
        out += [q.pop(0) for q in queues.values() if q]
    return out


def test_an_imu_taken_in_turns_with_the_cameras_is_waited_for(rig):
    """A busy node takes one message per subscription in turn: the 10 Hz frames run seconds (of stamps) ahead of
    the 200 Hz IMU, which keeps arriving. The sets wait for it (up to imu_max_lag_s), so the work is the same
    as in step; only frames that far ahead, or an IMU that sends nothing while frames imu_wait_s newer come, let
    a set go without its samples."""
    f, work, _ = feeder(rig)
    feed(f, messages())
    f.end()
    in_step = trace(work)
    f, work, _ = feeder(rig)
    feed(f, round_robin(messages()))
    f.end()
    assert trace(work) == in_step
    f, work, _ = feeder(rig, imu_max_lag_s=1.0)  # the IMU lags beyond what the sets may wait
    feed(f, round_robin(messages()))
    f.end()
    sets = [i for i, (k, _) in enumerate(trace(work)) if k is WorkKind.FRAMES]
    assert len(sets) == 20 and trace(work) != in_step


def test_without_imu_sets_leave_at_once_and_with_a_stopped_imu_after_the_wait(rig):
    f, work, _ = feeder(rig, imu_topic=None)
    feed(f, [m for m in messages(seconds=0.5) if m[1] == "image"])
    assert [k for k, _ in trace(work)].count(WorkKind.FRAMES) >= 4  # the last set waits for its partial window only
    f, work, _ = feeder(rig, imu_wait_s=0.5)
    feed(f, [m for m in messages(seconds=1.0) if m[1] == "image" or m[3] < 100.2])  # the IMU stops at 100.2 s
    sets = [t for k, t in trace(work) if k is WorkKind.FRAMES]
    assert sets[0] == pytest.approx(100.0) and sets[-1] <= 100.9 - 0.5 + 1e-6, "released once 0.5 s newer came"


def test_bad_inputs_are_dropped_counted_and_logged_once(rig):
    f, work, logs = feeder(rig)
    f.image(0, image(100.0, encoding="32FC1"))
    f.image(0, image(100.1, encoding="32FC1"))
    f.image(1, image(100.0, w=48, h=48))  # another aspect ratio: no resize recovers it
    f.imu_msg(imu(100.0, accel=(math.nan, 0.0, 9.81)))
    f.imu_msg(imu(100.005, accel=(0.0, 0.0, 0.0)))
    f.imu_msg(imu(100.01))
    f.imu_msg(imu(100.008))  # older than the last
    counts = f.drops.counts()
    assert counts[(TOPICS[0], Drop.IMAGE_NOT_DECODED)] == 2
    assert counts[(TOPICS[1], Drop.WRONG_IMAGE_SIZE)] == 1
    assert counts[("/imu/data", Drop.IMU_NOT_FINITE)] == 1
    assert counts[("/imu/data", Drop.IMU_ZERO_ACCEL)] == 1
    assert counts[("/imu/data", Drop.IMU_OUT_OF_ORDER)] == 1
    warned = [line for level, line in logs if level == "warn"]
    assert len(warned) == 5 and any("32FC1" in w for w in warned) and any("48x48" in w for w in warned)
    f.end()
    assert [k for k, _ in trace(work)] == [WorkKind.IMU, WorkKind.FLUSH]  # the good sample went on


def test_stamps_in_the_future_are_dropped_and_the_present_stays(rig):
    f, work, _ = feeder(rig)
    feed(f, messages(seconds=0.5), now=100.5)
    for i in range(4):
        f.image(i, image(2145916800.0), now=100.5)
    f.imu_msg(imu(2145916800.0), now=100.5)
    feed(f, messages(t0=100.5, seconds=0.5), now=101.0)
    f.end()
    assert f.drops.by_reason()[Drop.STAMP_IN_FUTURE] == 5
    assert max(t for _, t in trace(work) if t is not None) < 101.0
    assert sum(k is WorkKind.FRAMES for k, _ in trace(work)) == 10


def test_a_jump_back_flushes_and_restarts_then_carries_on(rig):
    f, work, logs = feeder(rig)
    feed(f, messages(seconds=2.0))
    n = len(work)
    feed(f, messages(seconds=2.0))  # played again: the same stamps
    kinds = [k for k, _ in trace(work)]
    i = kinds.index(WorkKind.RESTART)
    assert kinds[i - 1] == WorkKind.FLUSH and i >= n, "the old time's work, a flush, then the restart"
    assert kinds[i + 1:].count(WorkKind.FRAMES) >= 18, "the second pass goes through"
    assert f.events["time jumps back"] == 1
    assert sum("detected jump back in time" in line for _, line in logs) == 1
    assert "detected jump back in time" in work[i].data


def test_one_jump_policy_and_the_grouping_settings_from_the_input_config(rig):
    cfg = from_mapping(FeederConfig, {"jump_back_s": 2.0, "jump_confirm": 5,
                                      "grouping": {"min_streams": 2, "jump_periods": 8.0}}, "input config")
    f = Feeder(rig, cfg, [].append, DropLog(), TOPICS, "/imu/data")
    assert f.guard.policy == f.sync.policy == JumpPolicy(2.0, 5)
    assert f.sync.min_streams == 2 and f.sync.jump_periods == 8.0
    with pytest.raises(InputError, match="grouping.period_fraction"):
        from_mapping(FeederConfig, {"grouping": {"period_fraction": 0.0}}, "input config")


def test_frames_dropped_by_the_grouping_are_counted_with_their_topic(rig):
    f, _, _ = feeder(rig, imu_topic=None)
    feed(f, [m for m in messages(seconds=1.0) if m[1] == "image"])
    f.image(2, image(100.65))  # after its stream moved on: late
    assert f.drops.counts()[(TOPICS[2], Drop.FRAME_LATE)] == 1


def test_ros_stamps_come_back_as_received(rig):
    f, _, _ = feeder(rig, imu_topic=None)
    t = 1700000000.123456789
    msg = image(t)
    msg.header.stamp = SimpleNamespace(sec=1700000000, nanosec=123456789)
    f.image(0, msg)
    assert f.ros_stamp(1700000000 + 1e-9 * 123456789) == (1700000000, 123456789)
    assert f.ros_stamp(5.25) == (5, 250000000)
    assert np.isfinite(t)


def imu_block(stamps, accel=None):
    n = len(stamps)
    accel = np.tile([0.0, 0.0, 9.81], (n, 1)) if accel is None else np.asarray(accel, float)
    return ImuBlock(np.asarray(stamps, float), accel, np.zeros((n, 3)), np.zeros((n, 9)), np.zeros((n, 9)))


def feed_in_blocks(f, msgs, rng, now=None):
    """As :func:`feed`, with the IMU samples that arrive one after another handed over as blocks of 1-40."""
    pending = []

    def hand_over():
        while pending:
            k = int(rng.integers(1, 41))
            f.imu_block(imu_block(pending[:k]), now)
            del pending[:k]

    for _, kind, i, t in msgs:
        if kind == "image":
            hand_over()
            f.image(i, image(t), now)
        else:
            pending.append(t)
    hand_over()


@pytest.mark.parametrize("order", ["in step", "round robin", "imu late"])
def test_imu_samples_handed_over_in_blocks_give_the_work_of_sample_by_sample(rig, order):
    msgs = {"in step": messages(), "round robin": round_robin(messages()),
            "imu late": messages(imu_delay=0.3)}[order]
    f, work, _ = feeder(rig)
    feed(f, msgs, now=110.0)
    f.end()
    g, blocks, _ = feeder(rig)
    feed_in_blocks(g, msgs, np.random.default_rng(4), now=110.0)
    g.end()
    assert trace(blocks) == trace(work) and g.events == f.events
    imu = [w for w in blocks if w.kind is WorkKind.IMU]
    assert len(imu) == 400 and all(tuple(w.data[0]) == (0.0, 0.0, 9.81) for w in imu)


def test_bad_samples_in_a_block_are_dropped_as_one_by_one(rig):
    stamps = [100.0, 100.005, 100.01, 100.008, 100.02, 99.0, 2145916800.0, 100.03]
    accel = np.tile([0.0, 0.0, 9.81], (len(stamps), 1))
    accel[0, 0], accel[1] = math.nan, 0.0
    f, work, _ = feeder(rig)
    for t, a in zip(stamps, accel):
        f.imu_msg(imu(t, accel=tuple(a)), now=100.5)
    g, blocks, _ = feeder(rig)
    g.imu_block(imu_block(stamps, accel), now=100.5)
    assert g.drops.counts() == f.drops.counts()
    assert {r for _, r in g.drops.counts()} == {Drop.IMU_NOT_FINITE, Drop.IMU_ZERO_ACCEL, Drop.IMU_OUT_OF_ORDER,
                                                 Drop.STAMP_FAR_PAST, Drop.STAMP_IN_FUTURE}
    f.end()
    g.end()
    imu_stamps = [(WorkKind.IMU, 100.01), (WorkKind.IMU, 100.02), (WorkKind.IMU, 100.03)]
    assert trace(blocks) == trace(work) == imu_stamps + [(WorkKind.FLUSH, None)]


def in_bursts(msgs, kind: str, burst_s: float, phase_s: float, t0: float = 100.0, by_topic: bool = False):
    """The messages of ``kind`` received in bursts: each at the end of the ``burst_s`` interval its stamp falls
    in (intervals starting at t0 - phase_s; the frames of one instant in one burst), the others as they were; in
    arrival order (``by_topic``: within a burst topic by topic, each message's arrival its burst's end)."""
    def arrival(m):
        if m[1] != kind:
            return m[0]
        return t0 - phase_s + math.ceil((m[3] - t0 + phase_s) / burst_s - 1e-9) * burst_s
    if by_topic:
        return sorted([(arrival(m), *m[1:]) for m in msgs], key=lambda m: (m[0], m[1] == kind, m[2] or 0, m[3]))
    return sorted(msgs, key=lambda m: (arrival(m), m[0]))


def feed_arriving(f, msgs):
    """``feed`` with each message's arrival as the present."""
    for arrival, kind, i, t in msgs:
        if kind == "image":
            f.image(i, image(t), arrival)
        else:
            f.imu_msg(imu(t), arrival)


@pytest.mark.parametrize("burst_s, phase_s", [(1.0, 0.0), (1.0, 0.3), (2.5, 1.0), (0.7, 0.2)])
def test_cameras_that_deliver_in_bursts_are_waited_for(rig, burst_s, phase_s):
    """A camera driver (or link) that buffers: every frame of an interval received at its end, seconds after the
    IMU samples of their instants. The IMU waits for the frames, its first burst included (a camera is waited for
    up to imu_max_lag_s while it is young, then for the silences it has shown): the work of steady delivery."""
    f, work, _ = feeder(rig)
    feed(f, messages(seconds=8.0))
    f.end()
    g, bursty, _ = feeder(rig)
    feed(g, in_bursts(messages(seconds=8.0), "image", burst_s, phase_s))
    g.end()
    assert trace(bursty) == trace(work)


@pytest.mark.parametrize("burst_s, phase_s", [(1.0, 0.0), (2.5, 1.0), (0.7, 0.2)])
def test_bursts_that_come_topic_by_topic_are_grouped_as_steady_frames(rig, burst_s, phase_s):
    """A driver that buffers each camera's topic: within a burst one camera's frames of the whole interval, then
    the next camera's. The frame grouping waits through the spread of delays the burst shows, so the work is that
    of steady delivery, every frame set complete (not the partial sets of the cameras first in the burst)."""
    f, work, _ = feeder(rig)
    feed_arriving(f, messages(seconds=8.0))
    f.end()
    g, bursty, _ = feeder(rig)
    feed_arriving(g, in_bursts(messages(seconds=8.0), "image", burst_s, phase_s, by_topic=True))
    g.end()
    assert trace(bursty) == trace(work) and g.sync.complete == g.sync.emitted == 80


def test_an_imu_that_delivers_in_bursts_is_waited_for_after_its_first(rig):
    """An IMU driver that sends its samples in 1 s bursts: after the first burst has shown its silence, every
    frame set leaves after the IMU samples stamped before it, as with steady delivery (frame sets are not held
    back for a young IMU: that would delay every set of a start-up)."""
    f, work, _ = feeder(rig)
    feed(f, messages(seconds=8.0))
    f.end()
    g, bursty, _ = feeder(rig)
    feed(g, in_bursts(messages(seconds=8.0), "imu", 1.0, 0.0))
    g.end()
    def imu_before(w):
        out, n = {}, 0
        for kind, t in trace(w):
            n += kind is WorkKind.IMU
            if kind is WorkKind.FRAMES:
                out[t] = n
        return out
    steady, late = imu_before(work), imu_before(bursty)
    assert [t for t in steady if steady[t] != late[t]] and all(steady[t] == late[t] for t in steady if t >= 102.0)



@pytest.mark.parametrize("blocks", [False, True])
def test_an_imu_clock_offset_moves_every_imu_stamp_into_the_cameras_clock(rig, rng, blocks):
    """An IMU stamped 9 s late, read with imu_clock_offset_s = -9: its samples come out as if stamped by the
    cameras' clock, merged with the frame sets by that stamp (one sample at a time or in blocks alike)."""
    late = [(arrival, kind, i, t + 9.0 if kind == "imu" else t) for arrival, kind, i, t in messages(seconds=1.0)]
    runs = []
    for offset, msgs in ((0.0, messages(seconds=1.0)), (-9.0, late)):
        f, work, _ = feeder(rig, imu_clock_offset_s=offset)
        if blocks:
            feed_in_blocks(f, msgs, rng)
        else:
            feed(f, msgs)
        f.end()
        runs.append(trace(work))
    assert runs[0] == runs[1] and any(k is WorkKind.IMU for k, _ in runs[1])


@pytest.mark.parametrize("blocks", [False, True])
def test_unit_scales_multiply_every_sample_and_its_covariance(rig, blocks):
    """input.imu_gyro_scale pi/180 and input.imu_accel_scale 9.80665 (a driver's deg/s and g): every rate and
    specific force the pipeline gets is the sample's times its scale and each covariance times the square (so a
    claim of 'unknown', -1, stays negative: unknown), one sample at a time or in blocks alike."""
    k, m = math.pi / 180.0, 9.80665
    stamps = 100.0 + np.arange(40) / 200.0
    rates = np.outer(np.arange(1, 41), [10.0, -20.0, 30.0])  # deg/s
    accels = np.tile([0.1, -0.2, 0.97], (40, 1))  # g
    cov = np.tile(np.diag([4.0, 4.0, -1.0]).reshape(-1), (40, 1))
    f, work, _ = feeder(rig, imu_gyro_scale=k, imu_accel_scale=m)
    if blocks:
        f.imu_block(ImuBlock(stamps, accels, rates, 0.5 * cov, cov))
    else:
        for t, a, w, c in zip(stamps, accels, rates, cov):
            msg = imu(t, a)
            msg.angular_velocity = SimpleNamespace(x=w[0], y=w[1], z=w[2])
            msg.angular_velocity_covariance, msg.linear_acceleration_covariance = c, 0.5 * c
            f.imu_msg(msg)
    f.end()
    got = [w.data for w in work if w.kind is WorkKind.IMU]
    assert len(got) == 40
    for (a, w, (ca, cw)), want_a, want_w, want_c in zip(got, accels, rates, cov):
        assert np.allclose(w, k * want_w, rtol=1e-12) and np.allclose(a, m * want_a, rtol=1e-12)
        assert np.allclose(cw, k * k * want_c, rtol=1e-12) and np.asarray(cw)[8] < 0
        assert np.allclose(ca, 0.5 * m * m * want_c, rtol=1e-12)


@pytest.mark.parametrize("blocks", [False, True])
def test_an_axes_turn_turns_every_sample_and_its_covariance(rig, blocks):
    """input.imu_axes_turn_xyzw (the IMU's axes the rig file has wrong, measured or given): every rate and specific
    force the pipeline gets is the sample turned by it (after the unit scales) and each covariance C S C^T; an
    unknown covariance (-1 first) stays unknown; one sample at a time or in blocks alike."""
    from nrmpc_ros.core.so3 import exp_so3, matrix_to_quat_xyzw

    C = exp_so3(np.radians([30.0, -20.0, 100.0]))
    stamps = 100.0 + np.arange(20) / 200.0
    rates = np.outer(np.arange(1, 21), [0.1, -0.2, 0.3])
    accels = np.tile([0.5, -1.0, 9.7], (20, 1))
    cov = np.tile(np.diag([4.0, 1.0, 2.0]).reshape(-1), (20, 1))
    cov[::2, 0] = -1.0
    f, work, _ = feeder(rig, imu_axes_turn_xyzw=[float(x) for x in matrix_to_quat_xyzw(C)], imu_gyro_scale=2.0)
    if blocks:
        f.imu_block(ImuBlock(stamps, accels, rates, cov, cov))
    else:
        for t, a, w, c in zip(stamps, accels, rates, cov):
            msg = imu(t, a)
            msg.angular_velocity = SimpleNamespace(x=w[0], y=w[1], z=w[2])
            msg.angular_velocity_covariance, msg.linear_acceleration_covariance = c, c
            f.imu_msg(msg)
    f.end()
    got = [w.data for w in work if w.kind is WorkKind.IMU]
    assert len(got) == 20
    for k, ((a, w, (ca, cw)), want_a, want_w, c) in enumerate(zip(got, accels, rates, cov)):
        assert np.allclose(a, C @ want_a, rtol=1e-12) and np.allclose(w, 2.0 * C @ want_w, rtol=1e-12)
        if k % 2:
            S = c.reshape(3, 3)
            assert np.allclose(np.reshape(ca, (3, 3)), C @ S @ C.T) and np.allclose(np.reshape(cw, (3, 3)),
                                                                                  4.0 * C @ S @ C.T)
        else:
            assert np.asarray(ca)[0] == -1.0 and np.asarray(cw)[0] == -1.0


def test_an_axes_turn_that_is_no_quaternion_is_one_error_naming_it():
    from nrmpc_ros.errors import InputError
    from nrmpc_ros.frontend.feeder import FeederConfig

    for bad in ([0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, float("nan"), 1.0], "0,0,0,1"):
        with pytest.raises(InputError, match="imu_axes_turn_xyzw"):
            FeederConfig(imu_axes_turn_xyzw=bad)


def test_imu_samples_stamped_alike_in_batches_are_kept_and_spread_over_their_interval(rig):
    """A driver that stamps samples when the host reads them gets several in one read with one stamp: they are
    the samples taken since the read before, in order. Each batch is spread evenly over the interval since the
    stamp before it (its last sample keeps the stamp); none is dropped, and a sample older than the newest still
    is (out of order)."""
    f, work, _ = feeder(rig)
    reads = [100.0, 100.02, 100.02, 100.02, 100.02, 100.03, 100.05, 100.05]
    for t in reads:
        f.imu_msg(imu(t))
    f.imu_msg(imu(100.04))  # older than the newest
    f.end()
    stamps = [t for k, t in trace(work) if k is WorkKind.IMU]
    assert stamps == pytest.approx([100.0, 100.005, 100.01, 100.015, 100.02, 100.03, 100.04, 100.05])
    assert f.drops.counts()[("/imu/data", Drop.IMU_OUT_OF_ORDER)] == 1
    assert f.events["imu samples stamped alike"] == 4
    g, blocks, _ = feeder(rig)  # the node hands samples over in blocks: the same work
    g.imu_block(imu_block(reads[:3]))
    g.imu_block(imu_block(reads[3:]))
    g.imu_block(imu_block([100.04]))
    g.end()
    assert trace(blocks) == trace(work) and g.events == f.events


def test_images_binned_or_resized_from_the_rig_files_size_are_resized_back_and_said_once(rig):
    """A stream at half (or twice) the size its rig file was calibrated at, same aspect ratio: each image is
    resampled to the rig file's size, pixel centres kept, with one warning per camera; the frame sets carry
    images of the rig's size."""
    f, work, logs = feeder(rig, imu_topic=None)
    for t in (100.0, 100.1, 100.2):
        for i in range(4):
            w, h = (32, 24) if i < 2 else (128, 96)
            f.image(i, image(t, w=w, h=h, value=100))
    f.end()
    sets = [w.data[0] for w in work if w.kind is WorkKind.FRAMES]
    assert sets and all(img.shape == (48, 64) for fs in sets for img in fs.images if img is not None)
    warned = [line for level, line in logs if level == "warn" and "resized by" in line]
    assert len(warned) == 4 and any("32x24" in w and "resized by 2" in w for w in warned)
    assert f.resized == [3, 3, 3, 3] and not f.drops.counts()


def feed_as_arrived(f, msgs, blocks: bool = False):
    """As :func:`feed`, each message at its own arrival time (``now``); with ``blocks`` the IMU samples that
    arrive one after another are handed over in blocks of up to 8, at the last one's arrival."""
    pending = []

    def hand_over():
        for k in range(0, len(pending), 8):
            part = pending[k:k + 8]
            f.imu_block(imu_block([t for _, t in part]), part[-1][0])
        pending.clear()

    for arrival, kind, i, t in msgs:
        if kind == "image":
            hand_over()
            f.image(i, image(t), arrival)
        elif blocks:
            pending.append((arrival, t))
        else:
            f.imu_msg(imu(t), arrival)
    hand_over()


@pytest.mark.parametrize("blocks", [False, True])
@pytest.mark.parametrize("first", ["imu", "cameras"])
@pytest.mark.parametrize("clock_s", [-1699999000.0 + 100.0, 3600.0])
def test_an_imu_on_another_clock_is_moved_onto_the_cameras_by_its_arrival_times(rig, blocks, first, clock_s):
    """An IMU stamped by its own counter (100 s at the cameras' 1.7e9) or an hour ahead (a time zone), each sample
    arriving when it was taken: its stamps are moved onto the cameras' clock once a camera and three samples
    have arrived, said once, whichever input starts first, one sample at a time or in blocks; the work is the
    same as with an IMU on the cameras' clock from the moment both run."""
    t0 = 1_700_000_000.0
    late = {"imu": "image", "cameras": "imu"}[first]
    msgs = [m for m in messages(t0=t0, seconds=3.0) if m[1] != late or m[3] >= t0 + 0.5]
    runs = []
    for offset in (0.0, clock_s):
        f, work, logs = feeder(rig)
        feed_as_arrived(f, [(a, kind, i, t + offset if kind == "imu" else t) for a, kind, i, t in msgs], blocks)
        f.end()
        runs.append((f, [(k, t) for k, t in trace(work) if t is None or t >= t0 + 1.0], logs))
    (same, same_work, _), (other, other_work, logs) = runs
    assert not same.rebases and len(other.rebases) == 1
    assert other.rebases[0].offset_s == pytest.approx(-clock_s, abs=1e-6) and other.rebases[0].onto_arrival
    assert other.config.imu_clock_offset_s == pytest.approx(-clock_s, abs=1e-6)
    assert [k for k, _ in other_work] == [k for k, _ in same_work]
    assert [t for _, t in other_work] == pytest.approx([t for _, t in same_work], abs=1e-5)
    warned = [line for level, line in logs if "another clock" in line]
    assert len(warned) == 1 and f"{abs(clock_s):.3f} s" in warned[0]


@pytest.mark.parametrize("first, count, shift_s", [(50, 1, 3600.0), (0, 400, 5.0)],
                         ids=["one corrupt stamp", "a lag of seconds"])
def test_a_corrupt_stamp_or_a_lag_of_seconds_is_no_other_clock(rig, first, count, shift_s):
    """One IMU stamp an hour off among good ones is the stamp checks' to drop (a clock needs three in a row);
    an IMU 5 s off the cameras is the measured searches' (within FAR_CLOCK_S): neither is moved."""
    t0 = 1_700_000_000.0
    msgs = messages(t0=t0, seconds=2.0)
    imu_at = [k for k, m in enumerate(msgs) if m[1] == "imu"]
    assert len(imu_at) == 400
    shifted = list(msgs)
    for k in imu_at[first:first + count]:
        a, kind, i, t = msgs[k]
        shifted[k] = (a, kind, i, t + shift_s)
    f, _, _ = feeder(rig)
    feed_as_arrived(f, shifted)
    f.end()
    assert not f.rebases and f.config.imu_clock_offset_s == 0.0


@pytest.mark.parametrize("first", ["together", "foreign camera", "imu"])
def test_a_camera_on_its_own_clock_is_moved_onto_the_others_and_its_frames_grouped_with_theirs(rig, first):
    """Camera 1 stamps with a counter since its power-on (2500 s at the others' 1.7e9), each frame arriving when
    it was taken: once it and another input are known, it is moved onto the arrival clock the others stamp
    with, said once; from then on every frame set is complete and the work is that of a camera on the common
    clock. Its first frames, held while its clock was unknown, are not lost; where it starts alone (before the
    others), the first frames handed over with the old clock start afresh."""
    t0 = 1_700_000_000.0
    late = {"together": None, "foreign camera": "others", "imu": "cameras"}[first]

    def starts(m):
        kind, i, t = m[1], m[2], m[3]
        if late == "others" and (kind == "imu" or i != 1):
            return t >= t0 + 0.5
        return late != "cameras" or kind == "imu" or t >= t0 + 0.5

    msgs = [m for m in messages(t0=t0, seconds=3.0) if starts(m)]
    runs = []
    for offset in (0.0, -t0 + 2500.0):
        f, work, logs = feeder(rig)
        feed_as_arrived(f, [(a, kind, i, t + offset if kind == "image" and i == 1 else t)
                            for a, kind, i, t in msgs])
        f.end()
        runs.append((f, work, logs))
    (same, same_work, _), (other, other_work, logs) = runs
    assert [r.stream for r in other.rebases] == [1] and other.camera_clock_offset_s(1) == pytest.approx(t0 - 2500.0)
    assert len([line for _, line in logs if "another clock" in line]) == 1
    after = t0 + (1.0 if late else 0.0)
    sets = [w.data[0] for w in other_work if w.kind is WorkKind.FRAMES and w.stamp >= after]
    assert sets and all(all(img is not None for img in fs.images) for fs in sets)

    def tail(work, since):
        kept = [(k, t) for k, t in trace(work) if t is not None and t >= since]
        return [k for k, _ in kept], [t for _, t in kept]

    assert tail(other_work, after)[0] == tail(same_work, after)[0]
    assert tail(other_work, after)[1] == pytest.approx(tail(same_work, after)[1], abs=1e-5)
    restarted = any(w.kind is WorkKind.RESTART for w in other_work)
    assert restarted == (first == "foreign camera")
    if late is None:
        assert tail(other_work, 0.0)[0] == tail(same_work, 0.0)[0], "held, not lost"


@pytest.mark.parametrize("blocks", [False, True])
def test_inputs_whose_stamps_do_not_advance_are_stamped_by_their_arrival(rig, blocks):
    """A camera and an IMU whose drivers leave header.stamp at 0, each message arriving when it was taken: once
    three messages in a row arrived over more than 0.1 s with one stamp, they are stamped by when they arrive,
    said once each; the frame sets are complete and the work is that of inputs stamped when taken (the IMU's
    first 0.1 s, read before, is dropped and counted)."""
    t0 = 1_700_000_000.0
    msgs = messages(t0=t0, seconds=2.0)
    runs = []
    for frozen in (False, True):
        f, work, logs = feeder(rig)
        feed_as_arrived(f, [(a, kind, i, 0.0 if frozen and (kind == "imu" or i == 2) else t)
                            for a, kind, i, t in msgs], blocks)
        f.end()
        runs.append((f, work, logs))
    (_, same, _), (f, work, logs) = runs
    assert f.stamped_by_arrival(2) and f.stamped_by_arrival(IMU) and not f.stamped_by_arrival(0)
    assert len([line for _, line in logs if "stamps do not advance" in line]) == 2 and not f.rebases
    sets = [w.data[0] for w in work if w.kind is WorkKind.FRAMES]
    assert len(sets) == 20 and all(all(img is not None for img in fs.images) for fs in sets)
    after = [(k, t) for k, t in trace(work) if t is not None and t >= t0 + 0.2]
    expected = [(k, t) for k, t in trace(same) if t is not None and t >= t0 + 0.2]
    assert [k for k, _ in after] == [k for k, _ in expected]
    assert [t for _, t in after] == pytest.approx([t for _, t in expected], abs=1e-6)
    assert 0 < f.drops.counts()[("/imu/data", Drop.IMU_FROZEN_STAMP)] <= 25


def test_samples_a_host_read_at_once_share_a_stamp_and_are_not_frozen(rig):
    """A driver that stamps samples when the host reads them: batches of one stamp, each arriving at once. Not a
    frozen stamp: the batches are spread over their intervals, nothing is stamped by arrival."""
    f, work, _ = feeder(rig)
    t = 100.0
    for k in range(40):
        read = t + 0.02 * k
        for _ in range(4):
            f.imu_msg(imu(read), now=read + 0.001)
    f.end()
    assert not f.stamped_by_arrival(IMU) and f.events["imu samples stamped alike"] == 40 * 3


def test_a_camera_whose_stamps_froze_through_a_stall_uses_its_own_again_when_they_advance(rig):
    """A driver that repeats its last stamp while the camera stalls (0.5 s), then goes on: stamped by arrival
    through the stall, by its own stamps again once they advance, each change said."""
    f, work, logs = feeder(rig)
    t0 = 1_700_000_000.0
    for k in range(30):
        t = t0 + 0.1 * k
        for i in range(4):
            stamp = t0 + 0.9 if i == 3 and 10 <= k < 15 else t
            f.image(i, image(stamp), now=t + 0.001)
    f.end()
    said = [line for _, line in logs if "stamps do not advance" in line or "advance again" in line]
    assert len(said) == 2 and not f.stamped_by_arrival(3)
    sets = [w.data[0] for w in work if w.kind is WorkKind.FRAMES]
    assert sum(fs.images[3] is not None for fs in sets) >= 27
