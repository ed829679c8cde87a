"""Messages taken together from several inputs: the hand-over order, and the service fed as the node takes
messages after stalls of the process."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nrmpc_ros.frontend.feeder import IMU
from nrmpc_ros.frontend.taken import Run, stamp_order

stamps = st.lists(st.floats(0.0, 10.0, allow_nan=False), max_size=12)


def test_messages_are_merged_by_stamp_imu_runs_together_and_first_at_equal_stamps():
    runs = stamp_order([[0.1, 0.2], [0.15]], [0.05, 0.1, 0.11, 0.16, 0.3])
    assert runs == [Run(IMU, 0, 2), Run(0, 0, 1), Run(IMU, 2, 3), Run(1, 0, 1), Run(IMU, 3, 4), Run(0, 1, 2),
                    Run(IMU, 4, 5)]
    assert stamp_order([[], []], []) == [] and stamp_order([[1.0]], []) == [Run(0, 0, 1)]


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.lists(stamps, min_size=1, max_size=6), stamps)
def test_every_message_is_handed_over_once_each_input_in_its_arrival_order(images, imu):
    runs = stamp_order(images, imu)
    order = {s: [k for r in runs if r.stream == s for k in range(r.start, r.stop)] for s in [IMU, *range(len(images))]}
    assert order[IMU] == list(range(len(imu)))
    for i, taken in enumerate(images):
        assert order[i] == list(range(len(taken)))
    assert all(r.stop - r.start == 1 for r in runs if r.stream != IMU)
    assert all(not (a.stream == b.stream == IMU) for a, b in zip(runs, runs[1:])), "IMU runs are joined"
    if all(s == sorted(s) for s in [imu, *images]):
        handed = [(imu if r.stream == IMU else images[r.stream])[r.start] for r in runs]
        assert handed == sorted(handed), "sorted inputs come out sorted"


# --------------------------------------------------------------------------- the service after stalls
def _takes(path, cameras, imu_topic, stall_s: float, camera_latency_s: float = 0.0) -> list:
    """The bag's messages as a node takes them when it stalls ``stall_s`` between takes: per take, each camera's
    image messages and the IMU's serialized messages that arrived meanwhile (bag time; the images
    ``camera_latency_s`` after their bag time)."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store, index = get_typestore(Stores.ROS2_JAZZY), {t: i for i, t in enumerate(cameras)}
    takes: list = []
    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic in index or c.topic == imu_topic]
        arrivals = sorted(((t_ns * 1e-9 + (0.0 if c.topic == imu_topic else camera_latency_s), n), c, raw)
                          for n, (c, t_ns, raw) in enumerate(reader.messages(connections=conns)))
        for (arrival, _), conn, raw in arrivals:
            k = int(arrival // stall_s)
            if not takes or takes[-1][0] != k:
                takes.append((k, [[] for _ in cameras], []))
            if conn.topic == imu_topic:
                takes[-1][2].append(raw)
            else:
                takes[-1][1][index[conn.topic]].append(store.deserialize_cdr(raw, conn.msgtype))
    return [(k * stall_s, images, raws) for k, images, raws in takes]


@pytest.mark.slow
@pytest.mark.parametrize(("stall_s", "camera_latency_s"), [(0.6, 0.0), (0.02, 1.2)])
def test_after_stalls_or_with_late_cameras_the_service_gives_the_replays_estimates(tmp_path_factory, stall_s,
                                                                                    camera_latency_s):
    """A stall of 0.6 s (more than ``input.imu_wait_s``) before every take: handed over input by input, the IMU's
    samples would be half a second newer than every camera's last frame and the feeder would let them go on
    without the cameras; merged by stamp the estimates are the replay's, bit for bit. So are they when every
    image arrives 1.2 s after the IMU samples of its instant (the IMU's first second comes before any frame)."""
    from rendered_bags import CAMERAS
    from rendered_bags import IMU as IMU_TOPIC
    from test_service import _replayed, _same_estimates, _stream_service

    from nrmpc_ros.frontend.imu_block import ImuDecoder

    s, out, path, rig = _stream_service(tmp_path_factory)
    decoder = ImuDecoder()
    for now, images, raws in _takes(path, CAMERAS, IMU_TOPIC, stall_s, camera_latency_s):
        s.on_taken(images, decoder.decode(raws) if raws else None, now)
    s.feeder.end()
    while len(s.queue):
        s.work_once()
    while s.estimate_once() is not None:
        pass
    assert not s.drops.by_reason(), s.drops.by_reason()
    _same_estimates([o.estimate for o in out], _replayed(path, rig, IMU_TOPIC))
    assert np.isfinite([o.estimate.gravity for o in out]).all()
