"""Image topics as recorded: raw, compressed fallback, clear errors; transport choice for the node; a compressed bag."""

import csv
from pathlib import Path

import pytest

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.bag.writer import BagWriter
from nrmpc_ros.cli.main import main
from nrmpc_ros.core import load_rig
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.images import decode_image
from nrmpc_ros.frontend.topics import COMPRESSED_TYPE, RAW_TYPE, choose_transport, resolve_image_topics

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
    """Copy a bag, writing the images of the compressed topics in ``images`` as raw mono8 on the topic they
    are compressed from (the decoded pixels, so the replay sees the same images)."""
    with BagReader(src) as bag, BagWriter(dst) as out:
        for topic, stamp, msg in bag.messages(list(bag.topics)):
            if topic in images:
                out.write(topic.removesuffix("/compressed"),
                          out.image_msg(decode_image(msg, topic), stamp, msg.header.frame_id, "mono8"), stamp)
            else:
                out.write(topic, msg, stamp)


def rows(path):
    with open(path) as f:
        return [{k: v for k, v in r.items() if k != "time_ms"} for r in csv.DictReader(f)]


@pytest.mark.skipif(not (BAG / "metadata.yaml").exists() or not RIG.exists(), reason="sample bag not present")
def test_replay_of_a_partly_raw_bag_matches_the_compressed_one(tmp_path, capsys):
    rig = load_rig(RIG)
    mixed = tmp_path / "mixed"
    transcode(BAG, mixed, {c.image_topic + "/compressed" for c in rig.cameras[:1]})  # cam0 raw, the rest JPEG
    assert main(["replay", str(BAG), "--rig", str(RIG), "--out", str(tmp_path / "c.csv"), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["replay", str(mixed), "--rig", str(RIG), "--out", str(tmp_path / "m.csv"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert all(f"camera {c.name}: {c.image_topic}/compressed ({c.image_topic} is not in the bag)" in out
               for c in rig.cameras[1:])
    assert f"camera {rig.cameras[0].name}:" not in out
    assert rows(tmp_path / "m.csv") == rows(tmp_path / "c.csv") != []
