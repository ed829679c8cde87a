"""DropLog: every drop counted by source and reason; the first logged, later ones as a count every N seconds."""

import math

from nrmpc_ros.frontend.droplog import DropLog
from nrmpc_ros.frontend.drops import Drop


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_first_drop_logged_then_a_count_every_period():
    clock = Clock()
    log = DropLog(every_s=10.0, clock=clock)
    first = log.drop("/cam0", Drop.WRONG_IMAGE_SIZE, "image is 32x24")
    assert first.startswith("image is 32x24 (dropped;") and "every 10 s" in first
    lines = []
    for k in range(100):  # a burst of 100 more within 5 s: nothing logged
        clock.t = 0.05 * k
        lines.append(log.drop("/cam0", Drop.WRONG_IMAGE_SIZE, f"image {k} is 32x24"))
    assert not any(lines) and log.due() == []
    clock.t = 12.0  # the burst is over: the timer reports what is left, once
    due = log.due()
    assert len(due) == 1 and "100 more dropped (wrong image size) in the last 12 s, 101 in all" in due[0]
    assert "image 99 is 32x24" in due[0] and log.due() == []
    clock.t = 30.0
    assert "1 more" in log.drop("/cam0", Drop.WRONG_IMAGE_SIZE, "again")


def test_counts_by_source_and_reason():
    log = DropLog()
    log.drop("/cam0", Drop.FRAME_LATE, "a")
    log.drop("/cam1", Drop.FRAME_LATE, "b")
    log.drop("/imu", Drop.IMU_NOT_FINITE, "c", count=3)
    assert log.counts() == {("/cam0", Drop.FRAME_LATE): 1, ("/cam1", Drop.FRAME_LATE): 1,
                            ("/imu", Drop.IMU_NOT_FINITE): 3}
    assert log.by_reason() == {Drop.FRAME_LATE: 2, Drop.IMU_NOT_FINITE: 3} and log.total() == 5
    assert log.summary() == "/cam0: frame late 1; /cam1: frame late 1; /imu: IMU sample with NaN or inf 3"
    assert DropLog().summary() == "nothing dropped"


def test_offline_only_counts_after_the_first():
    log = DropLog(every_s=math.inf)
    assert "later drops of this kind are counted)" in log.drop("bag", Drop.FRAME_LATE, "x")
    assert log.drop("bag", Drop.FRAME_LATE, "y") is None and log.due() == []
