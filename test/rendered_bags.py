"""Small rendered bags for the tests of the node and the replay, made once per test session.

The rig is the sample cross rig at 320x240 with *relative* topics (``cam0/image_raw``, ``imu/data``): a node in
a namespace reads them there, offline they are the bag's ``/cam0/image_raw``. The bag streams frames at 10 Hz
through 4 holds (2 s each, 0.8 s moves of at most 15 deg), so the cameras' tracks survive the moves and every
hold after the first gets an estimate. :func:`rewrite` copies a bag with its messages edited (deserialised
with rosbags), for bags with bad clocks and bad samples.
"""

from __future__ import annotations

import copy
from pathlib import Path

import yaml

from nrmpc_ros.core import load_rig
from nrmpc_ros.render.bagmaker import BagOptions, make_bag
from nrmpc_ros.render.sequence import MotionOptions

ROOT = Path(__file__).resolve().parents[1]
CAMERAS = [f"/cam{i}/image_raw" for i in range(4)]
IMU = "/imu/data"
_made: dict = {}


def rig_file(directory: Path, width: int = 320) -> Path:
    """The sample rig with cameras ``width`` pixels wide (4:3, focal scaled; relative topics) in ``directory``."""
    d = yaml.safe_load((ROOT / "config" / "sample_cross4.yaml").read_text())
    s = width / 640
    for c in d["cameras"]:
        c["resolution"] = [width, width * 3 // 4]
        c["intrinsics"] = [470.0 * s, 470.0 * s, (width - 1) / 2, (width * 3 // 4 - 1) / 2]
    path = Path(directory) / "rig.yaml"
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return path


def stream_bag(factory) -> tuple:
    """(bag, rig file, make_bag summary) of the 4-hold stream, rendered once per session."""
    if "stream" not in _made:
        directory = factory.mktemp("rendered")
        rig = rig_file(directory)
        opts = BagOptions(motion=MotionOptions(views=4, hold_seconds=2.0, rate=10.0, move_seconds=0.8, max_step=15.0,
                                               capture="stream"), seed=0)
        summary = make_bag(load_rig(rig), directory / "stream", opts, progress=False)
        _made["stream"] = (directory / "stream", rig, summary)
    return _made["stream"]


def rewrite(src: Path, dst: Path, edit) -> Path:
    """Copy bag ``src`` to ``dst``; ``edit(topic, t_ns, msg)`` returns the (topic, t_ns, msg) to write instead
    (any number; the message may be changed in place or copied with :func:`copy.deepcopy`)."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(src) as reader, Writer(dst, version=9) as writer:
        types = {c.topic: c.msgtype for c in reader.connections}
        conns = {t: writer.add_connection(t, m, typestore=store) for t, m in types.items()}
        out = []
        for conn, t_ns, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            out += list(edit(conn.topic, t_ns, msg))
        out.sort(key=lambda m: m[1])
        for topic, t_ns, msg in out:
            writer.write(conns[topic], t_ns, store.serialize_cdr(msg, types[topic]))
    return dst


def stamp_ns(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def restamped(msg, t_ns: int):
    """A copy of ``msg`` with header stamp ``t_ns``."""
    out = copy.deepcopy(msg)
    out.header.stamp.sec, out.header.stamp.nanosec = divmod(int(t_ns), 1_000_000_000)
    return out


def played_twice(src: Path, dst: Path, gap_s: float = 0.2) -> Path:
    """The bag and then the bag again, recorded after it: the second pass's stamps jump back in time."""
    from rosbags.rosbag2 import Reader

    with Reader(src) as reader:
        shift = reader.end_time - reader.start_time + int(gap_s * 1e9)
    return rewrite(src, dst, lambda topic, t, msg: [(topic, t, msg), (topic, t + shift, msg)])
