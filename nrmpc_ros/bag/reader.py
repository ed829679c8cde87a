"""Reading rosbag2 (sqlite3, mcap) and ROS 1 bags with ``rosbags`` (no ROS install needed), read-only.

    with BagReader("bags/sample") as bag:
        bag.require(["/cam0/image_raw"])
        for topic, stamp_ns, msg in bag.messages(["/cam0/image_raw", "/imu/data"]):
            ...

Messages come in bag-time order. Problems (no such bag, a missing topic, a
truncated or corrupt file) raise :class:`~nrmpc_ros.errors.InputError` naming
the bag and what is wrong. Files are opened read-only; the bag is never modified.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from ..errors import InputError, NrmpcError

DEFAULT_STORE = Stores.ROS2_JAZZY


def _bag_paths(path: Path) -> list:
    """The path(s) AnyReader wants: a rosbag2 directory, or a ROS 1 .bag file."""
    if path.is_dir():
        if not (path / "metadata.yaml").exists():
            raise InputError(str(path), "not a rosbag2 directory (no metadata.yaml)")
        return [path]
    if path.suffix == ".bag":
        return [path]
    if path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").exists():
        return [path.parent]
    raise InputError(str(path), "expected a rosbag2 directory (with metadata.yaml) or a ROS 1 .bag file")


def bag_root(path) -> Path:
    """What holds the whole bag named by ``path``: the rosbag2 directory (also when one of its storage files is
    given), or the ROS 1 .bag file. Outputs must stay outside it. Anything else is returned as it is."""
    p = Path(path)
    try:
        if p.suffix in (".db3", ".mcap") and (p.parent / "metadata.yaml").exists():
            return p.parent
    except (OSError, ValueError):
        pass
    return p


class BagReader:
    """Read-only access to the topics of one bag."""

    def __init__(self, path):
        self.path = Path(path)
        self.source = str(path)
        if not self.path.exists():
            raise InputError(self.source, "no such bag")
        self._reader = None
        try:
            self._reader = AnyReader(_bag_paths(self.path), default_typestore=get_typestore(DEFAULT_STORE))
            self._reader.open()
        except NrmpcError:
            raise
        except Exception as exc:  # rosbags, sqlite/apsw, mcap and yaml errors alike
            self._reader = None
            raise InputError(self.source, f"cannot open bag (truncated or corrupt?): {exc}") from None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        if self._reader is not None:
            try:
                self._reader.close()
            finally:
                self._reader = None

    @property
    def topics(self) -> dict:
        """topic -> (message type, message count)."""
        return {name: (info.msgtype, info.msgcount) for name, info in self._reader.topics.items()}

    def describe_topics(self) -> str:
        return ", ".join(f"{n} ({t})" for n, (t, _) in sorted(self.topics.items())) or "none"

    def has_topic(self, topic: str) -> bool:
        return topic in self.topics

    def require(self, topics: Iterable[str]) -> None:
        """Raise InputError for the first topic the bag does not have, listing those it has."""
        have = self.topics
        for t in topics:
            if t not in have:
                raise InputError(self.source, f"topic {t!r} not in the bag; topics present: {self.describe_topics()}",
                                 "topic")

    def count(self, topics: Iterable[str]) -> int:
        have = self.topics
        return sum(have[t][1] for t in topics if t in have)

    def messages(self, topics: Iterable[str]) -> Iterator[tuple]:
        """(topic, bag time in ns, deserialised message) of ``topics`` in time order."""
        topics = list(topics)
        self.require(topics)
        conns = [c for c in self._reader.connections if c.topic in topics]
        if not conns:
            return
        it = self._reader.messages(connections=conns)
        while True:
            try:
                conn, stamp, raw = next(it)
            except StopIteration:
                return
            except Exception as exc:
                raise InputError(self.source, f"cannot read messages (truncated or corrupt bag?): {exc}") from None
            try:
                msg = self._reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise InputError(self.source, f"cannot decode a {conn.msgtype} message at bag time {stamp} ns: {exc}",
                                 conn.topic) from None
            yield conn.topic, stamp, msg
