"""``nrmpc play``: one clear error for a bad rate, a bag without metadata.yaml, a bag without topics, a corrupt
database, a missing bag (no traceback); a good bag plays."""

from __future__ import annotations

import shutil

import pytest
from dds import domain_id

from nrmpc_ros.bag.writer import BagWriter
from nrmpc_ros.cli.main import main
from nrmpc_ros.core import load_rig

pytest.importorskip("rclpy", reason="rclpy is not importable: install the ros extra (pip install -e .[ros])")


@pytest.fixture
def small_bag(tmp_path):
    from test_feeder import ROOT

    rig = load_rig(ROOT / "config" / "sample_cross4.yaml")
    path = tmp_path / "small"
    with BagWriter(path) as bag:
        for k in range(3):
            for cam in rig.cameras:
                bag.write("/" + cam.info_topic, bag.camera_info_msg(cam, (1 + k) * 10**9), (1 + k) * 10**9)
    return path


def play(args, capsys) -> tuple:
    code = main(["play", *map(str, args)])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("rate", ["nan", "-1", "0", "inf"])
def test_a_bad_rate_is_one_clear_error(small_bag, capsys, rate):
    code, err = play([small_bag, "--rate", rate], capsys)
    assert code == 2 and err.startswith("nrmpc play: error: --rate: must be a finite number > 0")


def test_bad_bags_are_one_clear_error_each(small_bag, tmp_path, capsys):
    no_meta = tmp_path / "no_meta"
    shutil.copytree(small_bag, no_meta)
    (no_meta / "metadata.yaml").unlink()
    code, err = play([no_meta], capsys)
    assert code == 2 and "no_meta: not a rosbag2 directory: it has no metadata.yaml" in err

    corrupt = tmp_path / "corrupt"
    shutil.copytree(small_bag, corrupt)
    db = next(corrupt.glob("*.db3"))
    data = bytearray(db.read_bytes())
    data[100:4100] = b"\xff" * 4000
    db.write_bytes(bytes(data))
    code, err = play([corrupt], capsys)
    assert code == 2 and "corrupt: cannot open bag:" in err and "Traceback" not in err

    from rosbags.rosbag2 import Writer

    with Writer(tmp_path / "empty", version=9):
        pass
    code, err = play([tmp_path / "empty"], capsys)
    assert code == 2 and "the bag has no topics: nothing to play" in err

    code, err = play([tmp_path / "nowhere"], capsys)
    assert code == 2 and "nowhere: no such bag" in err
    code, err = play([small_bag, "--topics", "/nope"], capsys)
    assert code == 2 and "topic(s) /nope not in the bag" in err


@pytest.mark.slow
def test_a_good_bag_plays(small_bag, capsys, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain_id(101, 200)))
    code, err = play([small_bag, "--rate", "100"], capsys)
    assert code == 0 and "published 12 messages on 4 topics" in err
