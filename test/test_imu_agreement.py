"""The pair test of each hold's IMU gravity against the images: a rig file whose IMU is turned the wrong way
is caught, its gravity left out and no wrong gravity published; a right one is never refuted."""

import math

import numpy as np
import pytest
import yaml
from recordings import recording

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.core import load_rig
from nrmpc_ros.core.so3 import angle_between, exp_so3, matrix_to_quat_xyzw, quat_xyzw_to_matrix
from nrmpc_ros.frontend.imu_agreement import describe_check
from nrmpc_ros.frontend.pipeline import Pipeline, PipelineConfig
from nrmpc_ros.frontend.reference import nearest_stamp, read_reference
from nrmpc_ros.frontend.replay import replay_bag, resolve_imu_topic

pytestmark = pytest.mark.slow  # renders bags


def replay(path, rig_file):
    rig = load_rig(rig_file)
    with BagReader(path) as bag:
        imu_topic = resolve_imu_topic(bag, rig, warn=lambda m: None)
        pipe = Pipeline(rig, PipelineConfig())
        ests = [e for es in replay_bag(bag, rig, pipe, imu_topic, warn=lambda m: None) for e in es]
        ref = read_reference(bag, imu_topic)
    return pipe, ests, ref


def turned(rig_file, tmp_path, deg):
    """The rig file with its IMU turned by ``deg`` about the body's x axis (axes of another convention)."""
    data = yaml.safe_load(rig_file.read_text())
    R = quat_xyzw_to_matrix(np.array(data["imu"].get("rotation_xyzw", [0, 0, 0, 1]), float))
    data["imu"]["rotation_xyzw"] = [float(x) for x in matrix_to_quat_xyzw(exp_so3(np.radians([deg, 0, 0])) @ R)]
    out = tmp_path / f"turned{deg}.yaml"
    out.write_text(yaml.safe_dump(data))
    return out


def test_an_imu_turned_the_wrong_way_is_refuted_and_no_wrong_gravity_is_published(recordings_dir, tmp_path):
    """With the IMU's rotation 90 deg off, its gravity is tens of degrees off at every hold; trusted, the joint
    estimate published it at the std of a good IMU (and poses 10-40 deg off). The images refute it on two
    holds in a row; from then it is not used, and the sequence that held it publishes no gravity."""
    path, rig_file, _ = recording(recordings_dir, "cross4", "stream-smooth")
    pipe, ests, ref = replay(path, turned(rig_file, tmp_path, 90.0))
    check = pipe.estimator.imu_check
    assert check.refuted >= 2 and not check.usable
    assert "imu rotation" in describe_check(check)
    assert ests, "the holds are still estimated (their poses from the images)"
    for e in ests:
        k = nearest_stamp(ref.grav_t, e.stamp)
        if e.gravity is not None and k is not None:
            error = math.degrees(angle_between(e.gravity, ref.grav_g[k]))
            assert error <= 3.0 * e.gravity_sigma_deg + 0.5, (e.stamp, error, e.gravity_sigma_deg)


@pytest.mark.parametrize("rig_name", ["line2", "fish3", "cross4"])
def test_a_right_imu_is_never_refuted(recordings_dir, rig_name):
    path, rig_file, _ = recording(recordings_dir, rig_name, "stream-ringing")
    pipe, ests, _ = replay(path, rig_file)
    check = pipe.estimator.imu_check
    assert check.tested >= 1 and check.refuted == 0 and check.usable
    assert describe_check(check) is None
    assert all(e.gravity is not None for e in ests)
