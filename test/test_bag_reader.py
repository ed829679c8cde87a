"""BagReader: rosbag2 sqlite3 / mcap and ROS 1 bags, time order, clear errors, never modifies the bag."""

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.errors import InputError

TS = get_typestore(Stores.ROS2_JAZZY)
SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample"


def vec_msg(t_ns, x):
    Header, Time = TS.types["std_msgs/msg/Header"], TS.types["builtin_interfaces/msg/Time"]
    V3, V3S = TS.types["geometry_msgs/msg/Vector3"], TS.types["geometry_msgs/msg/Vector3Stamped"]
    return V3S(header=Header(stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id="b"),
               vector=V3(x=float(x), y=0.0, z=0.0))


MSGTYPE = "geometry_msgs/msg/Vector3Stamped"
STAMPS = {"/a": [3, 1, 5], "/b": [2, 4]}  # seconds, written out of order per topic


def write_ros2(path, storage):
    with Writer(path, version=9, storage_plugin=storage) as w:
        conns = {t: w.add_connection(t, MSGTYPE, typestore=TS) for t in STAMPS}
        for t, stamps in STAMPS.items():
            for s in stamps:
                w.write(conns[t], s * 10**9, TS.serialize_cdr(vec_msg(s * 10**9, s), MSGTYPE))
    return path


def write_ros1(path):
    with Writer1(path) as w:
        conns = {t: w.add_connection(t, MSGTYPE, typestore=TS) for t in STAMPS}
        for t, stamps in STAMPS.items():
            for s in stamps:
                w.write(conns[t], s * 10**9, TS.serialize_ros1(vec_msg(s * 10**9, s), MSGTYPE))
    return path


def digest(path):
    files = sorted(p for p in Path(path).rglob("*") if p.is_file()) if Path(path).is_dir() else [Path(path)]
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


@pytest.mark.parametrize("kind", ["sqlite3", "mcap", "ros1"])
def test_reads_in_time_order_without_modifying(tmp_path, kind):
    if kind == "ros1":
        path = write_ros1(tmp_path / "x.bag")
    else:
        storage = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        path = write_ros2(tmp_path / "bag", storage)
    before = digest(path)
    with BagReader(path) as bag:
        assert bag.topics == {"/a": (MSGTYPE, 3), "/b": (MSGTYPE, 2)}
        got = [(t, ns // 10**9, msg.vector.x) for t, ns, msg in bag.messages(["/a", "/b"])]
        assert [g[1] for g in got] == [1, 2, 3, 4, 5]
        assert all(g[2] == g[1] for g in got)
        assert [g[1] for g in bag.messages(["/b"])] == [2 * 10**9, 4 * 10**9]
        assert bag.count(["/a", "/b", "/missing"]) == 5
    assert digest(path) == before


def test_missing_topic_lists_topics(tmp_path):
    path = write_ros2(tmp_path / "bag", StoragePlugin.SQLITE3)
    with BagReader(path) as bag:
        with pytest.raises(InputError, match=r"topic '/cam0/image_raw' not in the bag; topics present: /a .*/b"):
            list(bag.messages(["/a", "/cam0/image_raw"]))


def test_not_a_bag(tmp_path):
    with pytest.raises(InputError, match="no such bag"):
        BagReader(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="metadata.yaml"):
        BagReader(tmp_path / "empty")
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(InputError, match="rosbag2 directory"):
        BagReader(tmp_path / "x.txt")


def test_truncated_sqlite_bag(tmp_path):
    src = write_ros2(tmp_path / "bag", StoragePlugin.SQLITE3) if not SAMPLE.exists() else SAMPLE
    dst = tmp_path / "cut"
    shutil.copytree(src, dst)
    db = next(dst.glob("*.db3"))
    db.write_bytes(db.read_bytes()[: db.stat().st_size // 3])
    with pytest.raises(InputError, match=str(dst)):
        with BagReader(dst) as bag:
            for _ in bag.messages(list(bag.topics)):
                pass


def test_corrupt_mcap_and_ros1(tmp_path):
    path = write_ros2(tmp_path / "m", StoragePlugin.MCAP)
    f = next(path.glob("*.mcap"))
    data = bytearray(f.read_bytes())
    f.write_bytes(bytes(data[: len(data) // 2]))
    with pytest.raises(InputError, match="truncated or corrupt"):
        with BagReader(path) as bag:
            list(bag.messages(["/a", "/b"]))
    b1 = write_ros1(tmp_path / "y.bag")
    b1.write_bytes(b1.read_bytes()[:100])
    with pytest.raises(InputError, match="truncated or corrupt"):
        with BagReader(b1) as bag:
            list(bag.messages(["/a"]))


def test_db3_path_opens_its_directory(tmp_path):
    path = write_ros2(tmp_path / "bag", StoragePlugin.SQLITE3)
    with BagReader(next(path.glob("*.db3"))) as bag:
        assert set(bag.topics) == {"/a", "/b"}
        assert np.isclose(sum(m.vector.x for _, _, m in bag.messages(["/a"])), 9.0)
