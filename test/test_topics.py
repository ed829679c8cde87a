"""Image topics as recorded: raw, compressed fallback, clear errors; transport choice for the node; a compressed bag."""

import csv
from pathlib import Path

import pytest
from rendered_bags import stream_bag

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.bag.writer import BagWriter
from nrmpc_ros.cli.main import main
from nrmpc_ros.core import load_rig
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.images import decode_image
from nrmpc_ros.frontend.replay import resolve_imu_topic
from nrmpc_ros.frontend.topics import (
    COMPRESSED_TYPE,
    RAW_TYPE,
    bag_topic,
    choose_transport,
    expand_topic,
    resolve_image_topics,
)

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "bags" / "sample"
RIG = ROOT / "config" / "sample_cross4.yaml"
IMU = "sensor_msgs/msg/Imu"


@pytest.fixture
def rig(cross_rig):
    """The synthetic cross rig (cameras on /camN/image_raw)."""
    return cross_rig


def topics_of(rig, compressed=(), plain_compressed=()):
    out = {"/imu/data": IMU, "/cam0/camera_info": "sensor_msgs/msg/CameraInfo"}
    for i, cam in enumerate(rig.cameras):
        if i in compressed:
            out[cam.image_topic + "/compressed"] = COMPRESSED_TYPE
        elif i in plain_compressed:
            out[cam.image_topic] = COMPRESSED_TYPE
        else:
            out[cam.image_topic] = RAW_TYPE
    return out


def test_raw_topics_as_in_the_rig(rig):
    res = resolve_image_topics(topics_of(rig), rig)
    assert [r.topic for r in res] == [c.image_topic for c in rig.cameras]
    assert all(not r.compressed and r.msgtype == RAW_TYPE and r.note == "" for r in res)


def test_compressed_fallback_is_used_and_said(rig):
    res = resolve_image_topics(topics_of(rig, compressed={1, 3}), rig)
    for i, (r, cam) in enumerate(zip(res, rig.cameras)):
        if i in (1, 3):
            assert r.topic == cam.image_topic + "/compressed" and r.compressed and r.msgtype == COMPRESSED_TYPE
            assert cam.image_topic in r.note and "not in the bag" in r.note and r.topic in r.note
        else:
            assert r.topic == cam.image_topic and not r.compressed and r.note == ""


def test_compressed_images_under_the_plain_name(rig):
    res = resolve_image_topics(topics_of(rig, plain_compressed={0}), rig)
    assert res[0].topic == rig.cameras[0].image_topic and res[0].compressed and "compressed" in res[0].note
    ros1 = {k: v.replace("/msg/", "/") for k, v in topics_of(rig).items()}  # ROS 1 spelling of the types
    assert not any(r.compressed for r in resolve_image_topics(ros1, rig))


def test_missing_topic_is_one_clear_error(rig):
    bag = topics_of(rig)
    missing = rig.cameras[2].image_topic
    del bag[missing]
    with pytest.raises(InputError) as e:
        resolve_image_topics(bag, rig, "bags/x")
    msg = str(e.value)
    assert msg.startswith("bags/x") and f"{missing!r} not in the bag" in msg and f"{missing}/compressed" in msg
    assert rig.cameras[0].image_topic in msg and "/imu/data" not in msg  # lists the image topics only


def test_wrong_type_is_an_error(rig):
    bag = topics_of(rig)
    bag[rig.cameras[1].image_topic] = IMU
    with pytest.raises(InputError, match=f"{rig.cameras[1].image_topic}.*has type {IMU}"):
        resolve_image_topics(bag, rig)
    bag = topics_of(rig, compressed={1})
    bag[rig.cameras[1].image_topic + "/compressed"] = RAW_TYPE
    with pytest.raises(InputError, match=f"not {COMPRESSED_TYPE}"):
        resolve_image_topics(bag, rig)


def test_choose_transport():
    raw, comp = ["sensor_msgs/msg/Image"], ["sensor_msgs/msg/CompressedImage"]
    assert choose_transport("/cam0/image_raw", {"/cam0/image_raw": raw, "/cam0/image_raw/compressed": comp}) == (
        "/cam0/image_raw", False)
    assert choose_transport("/cam0/image_raw", {"/cam0/image_raw/compressed": comp, "/imu": [IMU]}) == (
        "/cam0/image_raw/compressed", True)
    assert choose_transport("/cam0/image_raw", {"/cam0/image_raw": comp}) == ("/cam0/image_raw", True)
    assert choose_transport("/cam0/image_raw", {"/cam0/image_raw": [IMU]}) == ("/cam0/image_raw", False)
    assert choose_transport("/cam0/image_raw", {}) == ("/cam0/image_raw", False)  # nothing yet: wait for raw


def transcode(src, dst, images):
    """Copy a bag, writing the images of the topics in ``images`` as PNG on their /compressed topic."""
    with BagReader(src) as bag, BagWriter(dst) as out:
        for topic, stamp, msg in bag.messages(list(bag.topics)):
            if topic in images:
                out.write(topic + "/compressed", out.image_msg(decode_image(msg, topic), stamp,
                                                               msg.header.frame_id, "png"), stamp)
            else:
                out.write(topic, msg, stamp)


def rows(path):
    with open(path) as f:
        return [{k: v for k, v in r.items() if k != "time_ms"} for r in csv.DictReader(f)]


@pytest.mark.slow
def test_replay_of_a_compressed_bag_matches_the_raw_one(tmp_path, tmp_path_factory, capsys):
    bag, rig_path, _ = stream_bag(tmp_path_factory)
    rig = load_rig(rig_path)
    comp_bag = tmp_path / "compressed"
    transcode(bag, comp_bag, {bag_topic(c.image_topic) for c in rig.cameras[1:]})  # cam0 stays raw
    assert main(["replay", str(bag), "--rig", str(rig_path), "--out", str(tmp_path / "raw.csv"), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["replay", str(comp_bag), "--rig", str(rig_path), "--out", str(tmp_path / "c.csv"),
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert all(f"camera {c.name}: {bag_topic(c.image_topic)}/compressed ({bag_topic(c.image_topic)} is not in "
               f"the bag)" in out for c in rig.cameras[1:])
    assert f"camera {rig.cameras[0].name}:" not in out  # raw where the rig says
    assert rows(tmp_path / "c.csv") == rows(tmp_path / "raw.csv") != []


def test_names_expand_like_ros_before_remapping():
    assert expand_topic("/cam0/image_raw", "/rig1") == "/cam0/image_raw"
    assert expand_topic("cam0/image_raw") == "/cam0/image_raw"
    assert expand_topic("cam0/image_raw", "/rig1") == expand_topic("cam0/image_raw", "rig1/") == "/rig1/cam0/image_raw"
    assert expand_topic("~/pose", "/rig1") == "/rig1/estimator/pose" and expand_topic("~", "/") == "/estimator"
    assert bag_topic("imu/data") == "/imu/data"


def test_a_relative_rig_topic_matches_the_bags_root_topic():
    """The sample rig's topics are relative (cam0/image_raw), so -r __ns:=/rig1 moves the node's inputs; offline
    they are the bag's /cam0/image_raw."""
    rig = load_rig(RIG)
    assert rig.cameras[0].image_topic == "cam0/image_raw" and rig.imu.topic == "imu/data"
    res = resolve_image_topics(topics_of_names([f"/cam{i}/image_raw" for i in range(4)]), rig)
    assert [r.topic for r in res] == [f"/cam{i}/image_raw" for i in range(4)] and not any(r.note for r in res)
    with pytest.raises(InputError, match="image topic '/cam0/image_raw' not in the bag"):
        resolve_image_topics(topics_of_names([f"/rig1/cam{i}/image_raw" for i in range(4)]), rig)


@pytest.mark.skipif(not (BAG / "metadata.yaml").exists(), reason="sample bag not present")
def test_the_imu_topic_of_a_relative_rig_is_found_in_the_bag():
    with BagReader(BAG) as bag:
        assert resolve_imu_topic(bag, load_rig(RIG)) == "/imu/data"
        assert resolve_imu_topic(bag, load_rig(RIG), requested="imu/data") == "/imu/data"


def topics_of_names(names):
    return {**{n: RAW_TYPE for n in names}, "/imu/data": IMU}
