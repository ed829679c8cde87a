"""StampSynchronizer: approximate-time sets on jittered, missing and late stamps; bounded queues."""

import numpy as np
import pytest

from nrmpc_ros.frontend.sync import StampSynchronizer


def feed(sync, msgs):
    out = []
    for stream, stamp in msgs:
        out += sync.add(stream, stamp, (stream, stamp))
    return out


def interleave(rng, stamps_per_stream, max_delay=0.03):
    """Messages of all streams in arrival order: stamp + a random transport delay (per-stream order kept)."""
    msgs = []
    for s, stamps in enumerate(stamps_per_stream):
        arrival = np.maximum.accumulate(np.asarray(stamps) + rng.uniform(0, max_delay, len(stamps)))
        msgs += [(a, s, t) for a, t in zip(arrival, stamps)]
    msgs.sort()
    return [(s, t) for _, s, t in msgs]


def test_exact_stamps_all_grouped():
    sync = StampSynchronizer(3, 0.001, 5)
    sets = feed(sync, [(s, 0.1 * k) for k in range(10) for s in (2, 0, 1)])
    assert len(sets) == 10
    assert all(len(x.items) == 3 and len(set(x.stamps)) == 1 for x in sets)
    assert [x.stamp for x in sets] == pytest.approx([0.1 * k for k in range(10)])
    assert sum(sync.dropped.values()) == 0


def test_jittered_stamps(rng):
    M, n, tol = 5, 200, 0.005
    base = 0.1 * np.arange(n)
    stamps = [base + rng.uniform(-0.002, 0.002, n) for _ in range(M)]
    sync = StampSynchronizer(M, tol, 10)
    sets = feed(sync, interleave(rng, stamps))
    assert len(sets) == n
    for k, x in enumerate(sets):
        assert max(x.stamps) - min(x.stamps) <= tol
        assert [it[1] for it in x.items] == [stamps[s][k] for s in range(M)]  # the right message of every stream
    assert sum(sync.dropped.values()) == 0


def test_missing_messages_drop_only_their_sets(rng):
    M, n = 4, 100
    base = 0.1 * np.arange(n) + rng.uniform(-0.001, 0.001, n)
    missing = {1: {5, 6, 40}, 3: {6, 77}}
    stamps = [np.array([t for k, t in enumerate(base) if k not in missing.get(s, ())]) for s in range(M)]
    sync = StampSynchronizer(M, 0.003, 10)
    sets = feed(sync, interleave(rng, stamps))
    got = sorted(round(x.stamp, 6) for x in sets)
    expect = sorted(round(t, 6) for k, t in enumerate(base) if k not in {5, 6, 40, 77})
    assert got == expect
    # every message of an incomplete set is dropped and counted (except those still queued at the end)
    incomplete = sum(M - sum(k in missing.get(s, ()) for s in range(M)) for k in {5, 6, 40, 77})
    assert sync.dropped["unmatched"] + sum(sync.queued) >= incomplete
    assert sync.dropped["unmatched"] <= incomplete


def test_stream_stops_queues_stay_bounded():
    sync = StampSynchronizer(3, 0.001, queue_size=4)
    sets = feed(sync, [(s, 0.1 * k) for k in range(50) for s in (0, 1)])  # stream 2 silent
    assert sets == []
    assert max(sync.queued) <= 4
    assert sync.dropped["queue overflow"] == 2 * (50 - 4)
    # it recovers when the stream comes back
    sets = feed(sync, [(s, 5.0 + 0.1 * k) for k in range(3) for s in (0, 1, 2)])
    assert len(sets) == 3


def test_late_and_duplicate_messages_are_dropped():
    sync = StampSynchronizer(2, 0.001, 5)
    feed(sync, [(0, 1.0), (1, 1.0), (0, 2.0), (1, 2.0)])
    assert sync.emitted == 2
    assert feed(sync, [(0, 1.5)]) == [] and sync.dropped["late"] == 1
    assert feed(sync, [(1, 2.0)]) == [] and sync.dropped["late"] == 2


def test_picks_closest_of_a_faster_stream():
    sync = StampSynchronizer(2, 0.02, 10)
    sets = feed(sync, [(1, 0.990), (1, 0.999), (1, 1.008), (0, 1.0)])
    assert len(sets) == 1 and sets[0].stamps == [1.0, 0.999]


def test_bad_arguments():
    with pytest.raises(ValueError):
        StampSynchronizer(0, 0.01, 5)
    with pytest.raises(ValueError):
        StampSynchronizer(2, -1.0, 5)
    with pytest.raises(ValueError):
        StampSynchronizer(2, 0.01, 5).add(2, 0.0, None)
