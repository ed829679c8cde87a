"""CameraInfo against the rig file: one message with numbers per disagreement; agreement and uncalibrated
cameras are silent; ``nrmpc replay`` runs the same check on a bag."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.bag.writer import BagWriter
from nrmpc_ros.core import load_rig
from nrmpc_ros.frontend.camera_info import camera_info_mismatch
from nrmpc_ros.frontend.replay import check_camera_info

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def rig():
    return load_rig(ROOT / "config" / "sample_cross4.yaml")


def info(cam, **change):
    fx, fy, cx, cy = cam.intrinsics
    d = dict(width=cam.resolution[0], height=cam.resolution[1], distortion_model="plumb_bob",
             d=[0.0] * 5, k=[fx, 0, cx, 0, fy, cy, 0, 0, 1])
    d.update(change)
    return SimpleNamespace(**d)


def test_an_agreeing_or_uncalibrated_camera_info_says_nothing(rig):
    cam = rig.cameras[0]
    assert camera_info_mismatch(cam, info(cam)) is None
    assert camera_info_mismatch(cam, info(cam, k=[471.2, 0, 319.5, 0, 470.0, 239.5, 0, 0, 1])) is not None
    assert camera_info_mismatch(cam, info(cam, k=[470.3, 0, 319.5, 0, 470.0, 239.5, 0, 0, 1])) is None  # < 0.5 px
    assert camera_info_mismatch(cam, info(cam, width=0, height=0, k=[0.0] * 9, d=[])) is None


def test_each_disagreement_is_named_with_its_numbers(rig):
    cam = rig.cameras[1]
    msg = info(cam, width=320, height=240, k=[235, 0, 159.5, 0, 235, 119.5, 0, 0, 1], d=[0.1, 0, 0, 0, 0])
    text = camera_info_mismatch(cam, msg, rig.source)
    assert text.startswith(f"CameraInfo of camera 'cam1' disagrees with the rig file {rig.source}: ")
    assert "resolution 320x240, the rig file 640x480" in text
    assert "intrinsics fx fy cx cy 235.00 235.00 159.50 119.50, the rig file 470.00 470.00 319.50 239.50" in text
    assert "distortion [0.1, 0, 0, 0, 0]" in text and text.endswith("(using the rig file)")
    assert "distortion model 'equidistant'" in camera_info_mismatch(cam, info(cam, distortion_model="equidistant"))


def test_replay_checks_the_first_camera_info_of_each_camera_in_a_bag(rig, tmp_path):
    bad = rig.cameras[2]
    with BagWriter(tmp_path / "bag") as bag:
        for stamp in (1, 2):
            for cam in rig.cameras:
                msg = bag.camera_info_msg(cam, stamp * 10**9)
                if cam is bad:
                    msg.k = np.array([400.0, 0, 319.5, 0, 400.0, 239.5, 0, 0, 1])
                bag.write("/" + cam.info_topic, msg, stamp * 10**9)  # the rig's topics are relative
    warned = []
    with BagReader(tmp_path / "bag") as reader:
        out = check_camera_info(reader, rig, warned.append)
    assert out == warned and len(warned) == 1
    assert warned[0].startswith("/cam2/camera_info: CameraInfo of camera 'cam2'") and "400.00" in warned[0]
