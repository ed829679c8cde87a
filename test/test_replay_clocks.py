"""``nrmpc replay`` survives bad clocks and bad samples: a bag played twice (a jump back in time) gives the same
estimates on both passes, in two sequences; stamps in 2038 and NaN IMU samples are dropped and counted, and
change no estimate."""

from __future__ import annotations

import copy
import csv
import math

import numpy as np
import pytest
from rendered_bags import CAMERAS, IMU, played_twice, restamped, rewrite, stamp_ns, stream_bag

from nrmpc_ros.cli.main import main

YEAR_2038 = 2145916800 * 1_000_000_000


def replay(bag, rig, out, capsys) -> tuple:
    assert main(["replay", str(bag), "--rig", str(rig), "--out", str(out), "--no-progress", "--quiet"]) == 0
    printed = capsys.readouterr()
    with open(out) as fh:
        return list(csv.DictReader(fh)), printed.out + printed.err


def gravity(row) -> np.ndarray:
    return np.array([float(row[k]) for k in ("gx", "gy", "gz")])


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return stream_bag(tmp_path_factory)


@pytest.mark.slow
def test_a_bag_played_twice_gives_its_estimates_on_both_passes(clean, tmp_path, capsys):
    bag, rig, _ = clean
    once, _ = replay(bag, rig, tmp_path / "once.csv", capsys)
    twice, printed = replay(played_twice(bag, tmp_path / "twice"), rig, tmp_path / "twice.csv", capsys)
    n = len(once)
    assert n >= 3 and len(twice) == 2 * n
    for a, b in zip(once, twice[n:]):
        assert a["stamp"] == b["stamp"] and a["ref_stamp"] == b["ref_stamp"]
        assert np.array_equal(gravity(a), gravity(b)), "a fresh pipeline on the same input: the same numbers"
    assert {r["sequence"] for r in twice[:n]} != {r["sequence"] for r in twice[n:]}, "the second pass is a new sequence"
    assert "time jumps back: 1" in printed and "detected jump back in time" in printed


@pytest.mark.slow
def test_stamps_in_2038_and_nan_imu_samples_are_dropped_counted_and_change_nothing(clean, tmp_path, capsys):
    bag, rig, _ = clean
    injected = {"future": 0, "nan": 0}

    def edit(topic, t, msg):
        yield topic, t, msg
        k = (t - 1_700_000_000 * 1_000_000_000) // 100_000_000  # frame index at 10 Hz
        if topic in CAMERAS and k == 30 and stamp_ns(msg) == t:  # one frame set and ...
            injected["future"] += 1
            yield topic, t + 1_000_000, restamped(msg, YEAR_2038)
        if topic == IMU and 5_000 <= (t // 1_000_000) % 10_000 < 5_100:  # ... a NaN IMU burst every 10 s
            bad = copy.deepcopy(restamped(msg, t + 1_000_000))
            bad.linear_acceleration.x = math.nan
            injected["nan"] += 1
            yield topic, t + 1_000_000, bad

    dirty = rewrite(bag, tmp_path / "dirty", edit)
    assert injected["future"] == 4 and injected["nan"] >= 10
    rows, _ = replay(bag, rig, tmp_path / "clean.csv", capsys)
    dirty_rows, printed = replay(dirty, rig, tmp_path / "dirty.csv", capsys)
    print(printed)
    assert [r["stamp"] for r in rows] == [r["stamp"] for r in dirty_rows] and rows
    assert all(np.array_equal(gravity(a), gravity(b)) for a, b in zip(rows, dirty_rows))
    assert printed.count(": stamp in the future 1") == 4, "counted per camera topic"
    assert f"/imu/data: IMU sample with NaN or inf {injected['nan']}" in printed


@pytest.mark.slow
@pytest.mark.parametrize("topic, clock_ns", [(IMU, 1000 * 1_000_000_000), (IMU, 1_700_003_600 * 1_000_000_000),
                                             (CAMERAS[1], 2500 * 1_000_000_000), (IMU, None), (CAMERAS[1], None)],
                         ids=["IMU counter since power-on", "IMU an hour ahead", "camera counter", "IMU unstamped",
                              "camera unstamped"])
def test_an_input_on_its_own_clock_is_moved_onto_the_others_and_gives_their_estimates(clean, tmp_path, capsys,
                                                                                        topic, clock_ns):
    """An IMU stamped by its own clock (a counter at 1000 s when the recording starts, or a clock an hour ahead),
    or a camera by its counter: the replay moves it onto the others' clock by the recording times and says so;
    every hold keeps its IMU gravity and all its cameras, and its estimate is the one of the bag stamped right.
    A driver that leaves the stamps at 0 (``clock_ns`` None): its messages are stamped by the recording time,
    the same estimates (to 1e-4 m/s^2: the IMU's samples before its stamps were found frozen, 0.1 s, are left
    out)."""
    bag, rig, _ = clean
    start = 1_700_000_000 * 1_000_000_000

    def edit(t, k, msg):
        moved = 0 if clock_ns is None else stamp_ns(msg) - start + clock_ns
        yield t, k, (restamped(msg, moved) if t == topic else msg)

    other = rewrite(bag, tmp_path / "other", edit)
    rows, _ = replay(bag, rig, tmp_path / "right.csv", capsys)
    other_rows, printed = replay(other, rig, tmp_path / "other.csv", capsys)
    assert rows and [r["stamp"] for r in rows] == [r["stamp"] for r in other_rows]
    assert [r["method"] for r in rows] == [r["method"] for r in other_rows] and rows[0]["method"] == "4pt-bending"
    assert all(np.allclose(gravity(a), gravity(b), atol=1e-6 if clock_ns else 1e-4) for a, b in zip(rows, other_rows))
    assert "camera sync: 104 sets (104 complete" in printed
    if clock_ns is None:
        assert f"stamps that do not advance (header.stamp unset?): {topic}; stamped by the recording time" in printed
        return
    offset = (clock_ns - start) * 1e-9
    said = [line for line in printed.splitlines() if line.startswith(f"{'IMU' if topic == IMU else 'camera'} clock: "
                                                                      f"{topic}: stamps")]
    assert len(said) == 1 and f"{abs(offset):.3f} s {'ahead of' if offset > 0 else 'behind'}" in said[0]
