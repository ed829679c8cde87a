"""The node's settings without ROS: parameters from the configs with their ranges, typos, files looked up in
the working directory then share/nrmpc_ros, the IMU and image topics to subscribe, the command line."""

from __future__ import annotations

import math
import os
from types import SimpleNamespace

import pytest
from rendered_bags import rig_file

from nrmpc_ros.core import load_rig
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.node_config import (
    NodeConfig,
    command_line,
    configs_from_parameters,
    describe_parameter,
    find_file,
    imu_topic,
    parameter_fields,
    parameter_range,
    transport,
    unknown_parameters,
)
from nrmpc_ros.frontend.topics import expand_topic


@pytest.fixture
def rig(tmp_path):
    return load_rig(rig_file(tmp_path, 64))


def test_parameters_come_from_the_configs_with_their_ranges():
    fields = {f.name: f for f in parameter_fields()}
    for name in ("rig_file", "method", "image_transport", "camera_timeout_s", "input.max_future_s",
                 "input.sync_tolerance_s", "pipeline.holds.measure_s", "pipeline.sequence.estimator.threshold_px"):
        assert name in fields and fields[name].doc, name
    assert "pipeline.sequence.gravity_bias_sigma" not in fields, "no default value: not a parameter"
    assert parameter_range(fields["pipeline.holds.measure_s"]) == ("float", 0.0, 3600.0)
    assert parameter_range(fields["input.max_future_s"]) == ("float", 0.0, math.inf)
    assert parameter_range(fields["pipeline.seed"]) == ("int", 0, 2**63 - 1)
    assert parameter_range(fields["method"]) is None and "one of: auto," in describe_parameter(fields["method"])
    assert describe_parameter(fields["input.max_future_s"]).endswith("(>= 0)")


def test_unknown_parameters_are_the_typos():
    assert unknown_parameters(["rig_file", "use_sim_time", "qos_overrides./diagnostics.publisher.depth",
                               "pipeline.holds.measure", "pipline.seed"]) == ["pipeline.holds.measure", "pipline.seed"]


def test_configs_from_flat_parameters_and_errors_naming_the_parameter():
    node, pipe = configs_from_parameters({"rig_file": "r.yaml", "method": "6pt-bending", "input.jump_back_s": 2.0,
                                          "pipeline.holds.measure_s": 3.0, "pipeline.seed": 7})
    assert node.method == "6pt-bending" and node.input.jump_back_s == 2.0
    assert pipe.holds.measure_s == 3.0 and pipe.seed == 7
    with pytest.raises(InputError, match="parameter rig_file: required"):
        configs_from_parameters({})
    with pytest.raises(InputError, match=r"field 'pipeline.holds.measure_s': must be > 0"):
        configs_from_parameters({"rig_file": "r.yaml", "pipeline.holds.measure_s": 0.0})
    with pytest.raises(InputError, match=r"field 'image_transport': must be one of auto, raw, compressed"):
        configs_from_parameters({"rig_file": "r.yaml", "image_transport": "theora"})


def test_files_are_found_in_the_working_directory_then_in_share_with_every_place_named(tmp_path, monkeypatch):
    share, cwd = tmp_path / "share", tmp_path / "cwd"
    (share / "config").mkdir(parents=True)
    cwd.mkdir()
    (share / "config" / "rig.yaml").write_text("x")
    monkeypatch.chdir(cwd)
    assert find_file("config/rig.yaml", "parameter rig_file", [share]) == share / "config" / "rig.yaml"
    (cwd / "rig.yaml").write_text("x")
    assert find_file("rig.yaml", "parameter rig_file", [share]) == cwd / "rig.yaml"
    with pytest.raises(InputError) as err:
        find_file("other.yaml", "parameter rig_file", [share])
    text = str(err.value)
    assert text.startswith("parameter rig_file: no such file: other.yaml (looked for ")
    assert str(cwd / "other.yaml") in text and str(share / "config" / "other.yaml") in text
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)  # a pip install: no ament index, no OSError
    with pytest.raises(InputError, match="no such file"):
        find_file("missing.yaml", "parameter rig_file")
    assert os.environ.get("AMENT_PREFIX_PATH") is None


def test_the_imu_follows_the_rig_file_and_use_imu(rig):
    assert imu_topic(rig, NodeConfig()) == ("imu/data", None)
    assert imu_topic(rig, NodeConfig(imu_topic="/other/imu")) == ("/other/imu", None)
    assert imu_topic(rig, NodeConfig(use_imu=False)) == (None, None)
    no_imu = SimpleNamespace(imu=None, source="rig.yaml")
    topic, warning = imu_topic(no_imu, NodeConfig(imu_topic="/imu"))
    assert topic is None and "has no imu block" in warning


def test_the_compressed_topic_follows_the_image_topic_unless_remapped_itself():
    remaps = {"/rig1/cam0/image_raw": "/front/image_raw", "/rig1/cam1/image_raw/compressed": "/left/jpeg"}

    def resolve(name, only_expand=False):
        full = expand_topic(name, "/rig1")
        return full if only_expand else remaps.get(full, full)

    raw, comp = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"
    assert transport("cam0/image_raw", "compressed", {}, resolve) == ("/front/image_raw/compressed", True)
    assert transport("cam1/image_raw", "compressed", {}, resolve) == ("/left/jpeg", True)
    assert transport("cam1/image_raw", "raw", {}, resolve) == ("/rig1/cam1/image_raw", False)
    assert transport("cam0/image_raw", "auto", {"/front/image_raw/compressed": [comp]}, resolve) == (
        "/front/image_raw/compressed", True)
    assert transport("cam0/image_raw", "auto", {"/front/image_raw": [raw]}, resolve) == ("/front/image_raw", False)
    assert transport("cam0/image_raw", "auto", {}, resolve) == ("/front/image_raw", False)


def test_command_line_help_and_bad_arguments(capsys):
    assert command_line(["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: estimator") and "  pipeline.holds.measure_s [default 2.0]" in out
    assert "~/relative_pose_reference" in out
    assert command_line(["--bogus"]) == 2 and "unknown arguments --bogus" in capsys.readouterr().err
    assert command_line(["--ros-args", "-p", "a:=1", "--"]) is None
    assert command_line([], ros_error="rclpy is not importable") == 2
