"""StampSynchronizer: tolerance from the frame periods, partial sets, time jumps, bounded queues."""

import re

import numpy as np
import pytest

from nrmpc_ros.frontend.drops import Drop
from nrmpc_ros.frontend.stamps import JumpPolicy
from nrmpc_ros.frontend.sync import StampSynchronizer, SyncConfig


def feed(sync, msgs):
    out = []
    for stream, stamp in msgs:
        out += sync.add(stream, stamp, (stream, stamp))
    return out


def interleave(rng, stamps_per_stream, max_delay=0.03, items=None):
    """Messages of all streams in arrival order: stamp + a random transport delay (per-stream order kept)."""
    msgs = []
    for s, stamps in enumerate(stamps_per_stream):
        arrival = np.maximum.accumulate(np.asarray(stamps) + rng.uniform(0, max_delay, len(stamps)))
        its = items[s] if items is not None else stamps
        msgs += [(a, s, t, it) for a, t, it in zip(arrival, stamps, its)]
    msgs.sort(key=lambda m: m[0])
    return [(s, t, it) for _, s, t, it in msgs]


def triggered(rng, num_cams, rate, n, jitter, drop=0.0, t0=100.0, max_delay=0.03):
    """Software-triggered cameras: frame k of every camera is stamped trigger_k + U(-jitter, jitter); a fraction
    ``drop`` of the frames is lost. Returns the arrival-ordered messages (stream, stamp, (stream, k)) and the
    set of (camera, k) that were dropped."""
    trig = t0 + np.arange(n) / rate
    keep = rng.random((num_cams, n)) >= drop
    stamps = [trig[keep[c]] + rng.uniform(-jitter, jitter, keep[c].sum()) for c in range(num_cams)]
    items = [[(c, int(k)) for k in np.flatnonzero(keep[c])] for c in range(num_cams)]
    dropped = {(c, k) for c in range(num_cams) for k in np.flatnonzero(~keep[c])}
    return interleave(rng, stamps, max_delay, items), dropped


def run(sync, msgs):
    sets = []
    for stream, stamp, item in msgs:
        sets += sync.add(stream, stamp, item)
    return sets + sync.flush()


def check_triggered(sets, num_cams, n, dropped):
    """Every frame not dropped is in exactly one set and a set holds one trigger; returns the number of
    partial sets beyond those the drops explain (a trigger's frames split in two sets)."""
    seen, spurious = [], 0
    for s in sets:
        ks = {it[1] for it in s.items if it is not None}
        assert len(ks) == 1, f"set mixes triggers {sorted(ks)}"
        k = ks.pop()
        assert all(it == (c, k) for c, it in enumerate(s.items) if it is not None)
        lost = [c for c in range(num_cams) if (c, k) in dropped]
        assert set(lost) <= set(s.missing)
        spurious += s.missing != lost
        seen += [it for it in s.items if it is not None]
    assert len(seen) == len(set(seen)) == num_cams * n - len(dropped)
    return spurious


def test_exact_stamps_all_grouped():
    sync = StampSynchronizer(3, 0.001, 5)
    sets = feed(sync, [(s, 0.1 * k) for k in range(10) for s in (2, 0, 1)])
    assert len(sets) == 10
    assert all(x.complete and len(set(x.stamps)) == 1 for x in sets)
    assert [x.stamp for x in sets] == pytest.approx([0.1 * k for k in range(10)])
    assert sum(sync.dropped.values()) == 0


def test_jittered_stamps_fixed_tolerance(rng):
    M, n, tol = 5, 200, 0.005
    base = 0.1 * np.arange(n)
    stamps = [base + rng.uniform(-0.002, 0.002, n) for _ in range(M)]
    sync = StampSynchronizer(M, tol, 10)
    sets = feed(sync, [(s, t) for s, t, _ in interleave(rng, stamps)])
    assert len(sets) == n
    for k, x in enumerate(sets):
        assert max(x.stamps) - min(x.stamps) <= 2 * tol
        assert [it[1] for it in x.items] == [stamps[s][k] for s in range(M)]  # the right message of every stream
    assert sum(sync.dropped.values()) == 0


@pytest.mark.parametrize("cams, rate, drop, splits", [(4, 10.0, 0.02, 0), (4, 30.0, 0.02, 3), (2, 10.0, 0.05, 0)])
def test_jitter_8ms_with_drops(rng, cams, rate, drop, splits):
    """+-8 ms of stamp jitter and frame drops. At 30 Hz the jitter is a quarter of the period, the limit of any
    grouping by stamps: a trigger's frames may rarely be split in two partial sets, never mixed. With two
    cameras a dropped frame leaves the other camera's frame alone, and the next trigger's frame of the camera
    that dropped lies within 0.9 periods of it: only the nearest-frame rule keeps them apart."""
    n = 300
    msgs, dropped = triggered(rng, cams, rate, n, jitter=0.008, drop=drop)
    sync = StampSynchronizer(cams)
    sets = run(sync, msgs)
    assert check_triggered(sets, cams, n, dropped) <= splits
    assert len(dropped) > 10
    hit = {k for _, k in dropped if sum((c, k) in dropped for c in range(cams)) < cams}  # a frame left
    assert len(hit) <= sync.emitted - sync.complete <= len(hit) + 2 * splits
    assert sum(sync.dropped.values()) == 0
    assert sync.periods == pytest.approx([1.0 / rate] * cams, rel=0.02)
    assert sync.tolerance == pytest.approx(0.45 / rate, rel=0.02)
    fixed = StampSynchronizer(cams, 0.005, config=SyncConfig(min_streams=cams))  # fixed +-5 ms: complete sets
    kept = len(run(fixed, msgs))
    assert kept < (0.75 if cams == 4 else 0.95) * sync.complete


def test_partial_sets_wait_only_until_the_frame_cannot_arrive(rng):
    sync = StampSynchronizer(3)
    feed(sync, [(s, 0.1 * k) for k in range(5) for s in range(3)])  # periods known: 100 ms
    assert sync.add(0, 0.5, "a") == [] and sync.add(2, 0.501, "c") == []  # camera 1 dropped its frame
    assert sync.add(0, 0.6, "a2") == []  # camera 1 may still deliver 0.5
    out = sync.add(1, 0.599, "b2")  # camera 1 moved past 0.5 + tolerance: the set is final
    assert len(out) == 1 and out[0].missing == [1] and out[0].items == ["a", None, "c"]
    assert out[0].stamp == 0.5 and out[0].reference == pytest.approx(0.5005)
    assert sync.partial == {1: 1}


def test_snapshots_seconds_apart(rng):
    """One synchronised snapshot per hold (irregular, seconds apart): every set is complete and emitted as
    soon as its last frame arrives."""
    times = 50.0 + np.cumsum(rng.uniform(1.5, 3.5, 12))
    sync = StampSynchronizer(4)
    for k, t in enumerate(times):
        stamps = t + rng.uniform(-0.003, 0.003, 4)
        out = []
        for c in rng.permutation(4):
            out += sync.add(int(c), stamps[c], (int(c), k))
        assert len(out) == 1 and out[0].complete and out[0].items == [(c, k) for c in range(4)]
    assert sync.flush() == []
    assert 0.6 < sync.tolerance < 1.6  # 0.45 of a period of about 2.5 s


def test_one_silent_camera(rng):
    msgs, _ = triggered(rng, 4, 10.0, 100, jitter=0.008)
    msgs = [m for m in msgs if m[0] != 2]
    sync = StampSynchronizer(4, queue_size=10, names=["cam0", "cam1", "cam2", "cam3"])
    sets = []
    for stream, stamp, item in msgs:
        sets += sync.add(stream, stamp, item)
        assert max(sync.queued) <= 10
    assert len(sets) >= 95  # all but the newest few sets are final before the end of the bag
    sets += sync.flush()
    assert len(sets) == 100 and all(s.missing == [2] for s in sets)
    assert sync.partial == {2: 100} and sync.complete == 0
    assert sum(sync.dropped.values()) == 0
    assert "100 partial; missing: cam2 100" in sync.describe()
    strict = StampSynchronizer(4, config=SyncConfig(min_streams=4))  # complete sets only: everything is unmatched
    assert run(strict, msgs) == [] and strict.dropped[Drop.FRAME_UNMATCHED] == 300


def test_stream_stops_queues_stay_bounded_and_recovers():
    sync = StampSynchronizer(3, 0.001, queue_size=4, config=SyncConfig(min_streams=3))
    sets = feed(sync, [(s, 0.1 * k) for k in range(50) for s in (0, 1)])  # stream 2 silent
    assert sets == []
    assert max(sync.queued) <= 4
    assert sync.dropped[Drop.FRAME_UNMATCHED] + sync.dropped[Drop.FRAME_QUEUE_OVERFLOW] + sum(sync.queued) == 100
    sets = feed(sync, [(s, 5.0 + 0.1 * k) for k in range(3) for s in (0, 1, 2)])  # it comes back
    assert len(sets) == 3 and all(s.complete for s in sets)


def test_time_jump_back_resets_and_recovers(rng):
    """A bag played twice: the second play's stamps jump back; the synchronizer closes the first play and goes on."""
    first, _ = triggered(rng, 3, 10.0, 60, jitter=0.005)
    second, _ = triggered(rng, 3, 10.0, 60, jitter=0.005)
    second = [(s, t, (c, k + 1000)) for s, t, (c, k) in second]  # same stamps, items told apart
    sync = StampSynchronizer(3)
    sets = run(sync, first + second)
    assert sync.events["time jump back"] == 1
    for s in sets:
        assert len({it[1] for it in s.items if it is not None}) == 1  # never a set across the plays
    plays = [min(it[1] for it in s.items if it is not None) >= 1000 for s in sets]
    assert plays == sorted(plays)  # the first play's sets all come before the second's
    in_sets = sum(it is not None for s in sets for it in s.items)
    assert in_sets + sum(sync.dropped.values()) == 360
    assert sum(sync.dropped.values()) <= 3
    assert sum(s.complete for s in sets) >= 116


def test_a_single_stamp_far_back_is_dropped():
    sync = StampSynchronizer(2)
    feed(sync, [(s, 10.0 + 0.1 * k) for k in range(10) for s in (0, 1)])
    assert feed(sync, [(0, 3.0), (1, 11.0)]) == []  # a glitch on stream 0, held apart
    sets = feed(sync, [(0, 11.0), (0, 11.1), (1, 11.1)])
    assert sync.dropped[Drop.FRAME_FAR_PAST] == 1 and not sync.events
    assert [s.stamps for s in sets] == [[11.0, 11.0], [11.1, 11.1]]


def test_a_stamp_far_in_the_future_is_dropped(rng):
    msgs, _ = triggered(rng, 4, 10.0, 60, jitter=0.008)
    k_bad = next(i for i, m in enumerate(msgs) if m[2] == (1, 30))
    s, _, item = msgs[k_bad]
    msgs[k_bad] = (s, 2.15e9, item)  # year 2038
    sync = StampSynchronizer(4)
    sets = run(sync, msgs)
    assert sync.dropped == {Drop.FRAME_FAR_FUTURE: 1} and not sync.events
    assert len(sets) == 60
    assert [k for k, x in enumerate(sets) if not x.complete] == [30] and sets[30].missing == [1]
    assert sync.tolerance == pytest.approx(0.045, rel=0.05)


def test_one_stream_confirms_a_jump_after_the_policys_count():
    for confirm in (1, 3):
        sync = StampSynchronizer(2, jumps=JumpPolicy(confirm=confirm))
        feed(sync, [(s, 10.0 + 0.1 * k) for k in range(10) for s in (0, 1)])
        feed(sync, [(0, 500.0 + 0.1 * k) for k in range(confirm - 1)])
        assert not sync.events, "held until the policy's count"
        feed(sync, [(0, 500.0 + 0.1 * (confirm - 1))])
        assert sync.events["time jump ahead"] == 1 and sum(sync.dropped.values()) == 0


def test_a_confirmed_jump_ahead_is_adopted():
    sync = StampSynchronizer(2)
    feed(sync, [(s, 10.0 + 0.1 * k) for k in range(10) for s in (0, 1)])
    assert feed(sync, [(0, 500.0)]) == []
    sets = feed(sync, [(1, 500.001), (0, 500.1), (1, 500.1)])
    assert sync.events["time jump ahead"] == 1 and sum(sync.dropped.values()) == 0
    assert [s.stamps for s in sets] == [[500.0, 500.001], [500.1, 500.1]]


def test_describe_reports_tolerance_periods_and_drops(rng):
    msgs, dropped = triggered(rng, 2, 10.0, 50, jitter=0.005, drop=0.05)
    sync = StampSynchronizer(2, names=["left", "right"])
    run(sync, msgs)
    feed(sync, [(0, 1.0)])  # far back, never confirmed
    sync.flush()
    line = sync.describe()
    assert "\n" not in line
    assert f"{sync.emitted} sets ({sync.complete} complete, {sync.emitted - sync.complete} partial" in line
    assert "dropped: stamp far in the past 1" in line
    tol = re.search(r"tolerance \+-([0-9.]+) ms \(0.45 x the smallest period\)", line)
    assert tol and float(tol.group(1)) == pytest.approx(45.0, abs=0.5)
    periods = re.search(r"periods \(ms\): left ([0-9.]+), right ([0-9.]+)", line)
    assert periods and [float(p) for p in periods.groups()] == pytest.approx([100.0, 100.0], abs=1.0)
    capped = StampSynchronizer(2, config=SyncConfig(max_tolerance_s=0.02))
    run(capped, msgs)
    assert capped.tolerance == 0.02
    assert "tolerance +-15.0 ms (start value)" in StampSynchronizer(3).describe()


def test_multi_rate_streams_take_the_nearest_frame(rng):
    slow = 0.1 * np.arange(30) + rng.uniform(-0.003, 0.003, 30)
    fast = np.arange(90) / 30.0 + rng.uniform(-0.003, 0.003, 90)
    sync = StampSynchronizer(2, config=SyncConfig(min_streams=2))
    sets = run(sync, interleave(rng, [slow, fast]))
    assert len(sets) == 30
    for x in sets:
        assert x.stamps[1] == fast[np.argmin(np.abs(fast - x.stamps[0]))]
    assert sync.dropped[Drop.FRAME_UNMATCHED] == 60


def test_late_and_duplicate_messages_are_dropped():
    sync = StampSynchronizer(2, 0.001, 5)
    feed(sync, [(0, 1.0), (1, 1.0), (0, 2.0), (1, 2.0)])
    assert sync.emitted == 2
    assert feed(sync, [(0, 1.5)]) == [] and sync.dropped[Drop.FRAME_LATE] == 1
    assert feed(sync, [(1, 2.0)]) == [] and sync.dropped[Drop.FRAME_LATE] == 2
    assert feed(sync, [(0, 3.0), (0, 3.0)]) == [] and sync.dropped[Drop.FRAME_DUPLICATE] == 1


def test_picks_closest_of_a_faster_stream():
    sync = StampSynchronizer(2, 0.02, 10, config=SyncConfig(min_streams=2))
    sets = feed(sync, [(1, 0.990), (1, 0.999), (1, 1.008), (0, 1.0)])
    assert len(sets) == 1 and sets[0].stamps == [1.0, 0.999]
    assert sync.dropped[Drop.FRAME_UNMATCHED] == 1


def test_bad_arguments():
    with pytest.raises(ValueError):
        StampSynchronizer(0, 0.01, 5)
    with pytest.raises(ValueError):
        StampSynchronizer(2, -1.0, 5)
    with pytest.raises(ValueError):
        StampSynchronizer(2, 0.01, 5).add(2, 0.0, None)
    with pytest.raises(ValueError, match="min_streams"):
        StampSynchronizer(2, config=SyncConfig(min_streams=3))
    with pytest.raises(ValueError, match="period_fraction"):
        StampSynchronizer(2, config=SyncConfig(period_fraction=0.5))
    sync = StampSynchronizer(2)
    assert sync.add(0, float("nan"), None) == [] and sync.dropped[Drop.FRAME_STAMP_NOT_FINITE] == 1


def rated(rates, seconds=6.0, t0=100.0):
    """(stream, stamp, item) of cameras at ``rates`` (Hz) triggered by one clock, in stamp order."""
    msgs = [(i, t0 + k / r, (i, k)) for i, r in enumerate(rates) for k in range(int(seconds * r))]
    return sorted(msgs, key=lambda m: (m[1], m[0]))


def test_cameras_at_different_rates_group_by_instant():
    """15, 10, 5 and 15 Hz from one clock: instants a third of a 10 Hz period apart (0.3 and 0.333 s). The frames
    of one instant stay together, so no set repeats the stamp of the one before it (the pipeline would drop it)."""
    sync = StampSynchronizer(4)
    sets = run(sync, rated((15.0, 10.0, 5.0, 15.0)))
    assert all(len({round(t, 9) for t in s.stamps if t is not None}) == 1 for s in sets)
    stamps = [s.stamp for s in sets]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert sync.grouped == 90 + 60 + 30 + 90 and sum(sync.dropped.values()) == 0


def test_a_fast_camera_beside_a_slow_one_does_not_overflow_its_queue():
    """A 60 Hz camera sends 12 frames before the 5 Hz camera's next frame decides their sets."""
    sync = StampSynchronizer(3)  # default queue_size 10
    sets = run(sync, rated((5.0, 60.0, 30.0)))
    assert sum(sync.dropped.values()) == 0 and sync.grouped == 30 + 360 + 180
    assert all(b.stamp > a.stamp for a, b in zip(sets, sets[1:]))


def camera_by_camera(rng, num_cams, rate, seconds, burst_s, jitter=0.002, drop=0.0, silent=()):
    """Triggered frames received in bursts: every frame of a ``burst_s`` interval at its end, and within a burst
    camera by camera (all of one camera's frames, then the next camera's: a driver that buffers each topic);
    (arrival, stream, stamp, (stream, k)) in arrival order, and the (camera, k) lost."""
    n = int(round(seconds * rate))
    trig = 100.0 + np.arange(n) / rate
    keep = rng.random((num_cams, n)) >= drop
    keep[list(silent)] = False
    msgs = []
    for c in range(num_cams):
        for k in np.flatnonzero(keep[c]):
            t = trig[k] + rng.uniform(-jitter, jitter)
            msgs.append((100.0 + np.ceil((t - 100.0) / burst_s + 1e-9) * burst_s, c, t, (c, int(k))))
    msgs.sort(key=lambda m: (m[0], m[1], m[2]))
    return msgs, {(c, int(k)) for c in range(num_cams) for k in np.flatnonzero(~keep[c])}


@pytest.mark.parametrize("num_cams, rate, burst_s", [(2, 5.0, 1.0), (3, 15.0, 1.0), (4, 10.0, 2.5), (6, 30.0, 1.0),
                                                     (6, 60.0, 0.5), (2, 60.0, 2.0)])
def test_bursts_that_come_camera_by_camera_are_grouped_whole(rng, num_cams, rate, burst_s):
    """A burst reaches the grouping topic by topic: one camera's whole interval before the next camera's. The
    others are waited for through the spread of delays the burst shows (its first one too), so every set is
    complete and no queue overflows; without arrival times the first bursts split, later ones are whole (the
    lag measured behind the others)."""
    msgs, dropped = camera_by_camera(rng, num_cams, rate, 8.0, burst_s)
    sync = StampSynchronizer(num_cams)
    sets = []
    for arrival, stream, stamp, item in msgs:
        sets += sync.add(stream, stamp, item, arrival=arrival)
    sets += sync.flush()
    assert check_triggered(sets, num_cams, int(8.0 * rate), dropped) == 0
    assert sync.complete == sync.emitted == int(8.0 * rate) and sum(sync.dropped.values()) == 0
    blind = StampSynchronizer(num_cams)
    sets = run(blind, [m[1:] for m in msgs])
    late = [s for s in sets if s.stamp > 100.0 + 2 * burst_s]
    assert blind.emitted > blind.complete and all(s.complete for s in late)


def test_a_silent_camera_beside_bursts_is_waited_for_then_left_and_queues_stay_bounded(rng):
    """With one camera unplugged, the sets of the others leave partial once the streams moved on by the burst's
    backlog (1.5 x its 1 s spread), not earlier, not never; the queues hold what comes meanwhile."""
    msgs, dropped = camera_by_camera(rng, 3, 15.0, 10.0, 1.0, drop=0.05, silent=[1])
    sync = StampSynchronizer(3)
    sets, waited, newest = [], [], {}
    for arrival, stream, stamp, item in msgs:
        newest[stream] = max(newest.get(stream, stamp), stamp)
        out = sync.add(stream, stamp, item, arrival=arrival)
        waited += [min(newest.values()) - s.reference for s in out]  # how far both cameras moved on
        sets += out
    assert 0.5 < sync.backlog_s(1) <= 1.5 + 1e-9
    sets += sync.flush()
    assert check_triggered(sets, 3, 150, dropped) == 0 and sum(sync.dropped.values()) == 0
    assert all(1 in s.missing for s in sets) and 1.4 < min(waited) and max(waited) < 1.7
    capped = StampSynchronizer(3, config=SyncConfig(max_backlog_s=0.3))
    for arrival, stream, stamp, item in msgs:
        capped.add(stream, stamp, item, arrival=arrival)
    assert capped.backlog_s(1) == 0.3


def test_a_camera_with_a_longer_steady_latency_is_waited_for(rng):
    """One camera's frames always come 0.6 s after the others' (six 10 Hz periods, beyond wait_periods): once
    its first frame shows the lag, its sets are complete; the jump of the timeline forgets it."""
    stamps = [100.0 + 0.1 * k for k in range(60)]
    msgs = sorted([(t + 0.6 * (c == 2), c, t, (c, k)) for k, t in enumerate(stamps) for c in range(3)])
    sync = StampSynchronizer(3)
    sets = run(sync, [m[1:] for m in msgs])
    assert check_triggered(sets, 3, 60, set()) > 0
    assert all(s.complete for s in sets if s.stamp > 101.0) and 0.6 <= sync.backlog_s(2) < 1.0


def test_a_burst_of_stamps_microseconds_apart_leaves_the_period_and_the_tolerance_as_they_were(rng):
    """A driver glitch stamps 300 frames of every camera 2 us apart; the jittered frames after it still group
    whole (a period of zero would give a tolerance of zero: every set of jittered stamps split)."""
    rate, n = 30.0, 60
    before, _ = triggered(rng, 3, rate, n, jitter=0.004, max_delay=0.0)
    t_burst = 100.0 + n / rate
    burst = [(c, t_burst + 2e-6 * k, ("burst", k)) for k in range(300) for c in range(3)]
    after, _ = triggered(rng, 3, rate, n, jitter=0.004, t0=t_burst + 0.1, max_delay=0.0)
    after = [(s, t, (c, k + 1000)) for s, t, (c, k) in after]
    sync = StampSynchronizer(3)
    sets = run(sync, before + burst + after)
    assert sync.periods == pytest.approx([1.0 / rate] * 3, rel=0.05)
    assert sync.tolerance == pytest.approx(0.45 / rate, rel=0.05)
    later = [s for s in sets if any(it is not None and it[0] != "burst" and it[1] >= 1000 for it in s.items)]
    assert len(later) == n and all(s.complete for s in later)
