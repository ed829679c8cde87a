"""Damaged copies of a rendered rosbag2 (sqlite3): a topic declared with another message type, a message whose
bytes do not decode. Each helper works on a copy, so the recording it starts from stays as it was."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import yaml

from nrmpc_ros.safeio import content_digest


def copy_bag(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _database(bag: Path) -> Path:
    return next(bag.glob("*.db3"))


def retype(bag: Path, topic: str, msgtype: str) -> Path:
    """Declare ``topic`` as ``msgtype`` in metadata.yaml and in the database (its messages stay as they are)."""
    meta = bag / "metadata.yaml"
    d = yaml.safe_load(meta.read_text())
    for t in d["rosbag2_bagfile_information"]["topics_with_message_count"]:
        if t["topic_metadata"]["name"] == topic:
            t["topic_metadata"]["type"] = msgtype
    meta.write_text(yaml.safe_dump(d, sort_keys=False))
    with sqlite3.connect(_database(bag)) as db:
        db.execute("UPDATE topics SET type = ? WHERE name = ?", (msgtype, topic))
    return bag


def corrupt_message(bag: Path, topic: str) -> Path:
    """Replace the middle message of ``topic`` with five bytes that no deserializer accepts."""
    with sqlite3.connect(_database(bag)) as db:
        ids = [r[0] for r in db.execute("SELECT m.id FROM messages m JOIN topics t ON m.topic_id = t.id "
                                        "WHERE t.name = ? ORDER BY m.timestamp", (topic,))]
        db.execute("UPDATE messages SET data = ? WHERE id = ?", (b"\x00\x01\x00\x00\xff", ids[len(ids) // 2]))
    return bag


digest = content_digest  # a file's or a directory's content, to show nothing was written into it
