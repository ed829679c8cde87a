import math

import numpy as np
import pytest
import yaml

from nrmpc_ros.core import load_rig, save_rig
from nrmpc_ros.errors import InputError

GOOD = {
    "body_frame": "base_link",
    "gravity_magnitude": 9.81,
    "imu": {"topic": "/imu/data", "mount": "body", "rotation_xyzw": [0, 0, 0, 1]},
    "cameras": [
        {"name": "cam0", "image_topic": "/cam0/image_raw", "model": "pinhole", "intrinsics": [800, 800, 320, 240],
         "distortion": [], "resolution": [640, 480], "position": [0.4, 0.0, 0.0],
         "rotation_xyzw": [0.5, -0.5, 0.5, -0.5], "bar": {"mass": 0.1, "EI": 0.1}},
        {"name": "cam1", "model": "equidistant", "intrinsics": [300, 300, 320, 240], "distortion": [0.1, 0, 0, 0],
         "resolution": [640, 480], "position": [-0.4, 0.0, 0.0], "rotation_xyzw": [0.5, 0.5, -0.5, -0.5],
         "bar": {"mass": 0.1, "EI": ".inf"}},
    ],
}


def write(tmp_path, data, name="rig.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data))
    return p


def test_load_good_rig(tmp_path):
    rig = load_rig(write(tmp_path, GOOD))
    assert rig.num_cameras == 2
    assert rig.cameras[0].is_flexible and not rig.cameras[1].is_flexible
    assert math.isinf(rig.cameras[1].EI)
    assert rig.cameras[1].image_topic == "/cam1/image_raw"
    assert rig.cameras[0].info_topic == "/cam0/camera_info"
    assert np.allclose(rig.compliance, [1.0, 0.0])


def test_round_trip(tmp_path):
    rig = load_rig(write(tmp_path, GOOD))
    save_rig(rig, tmp_path / "out.yaml", header="written by a test")
    rig2 = load_rig(tmp_path / "out.yaml")
    assert np.allclose(rig.rotations, rig2.rotations) and np.allclose(rig.positions, rig2.positions)
    assert [c.EI for c in rig.cameras] == [c.EI for c in rig2.cameras]


def _mutate(path_fn):
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    path_fn(data)
    return data


@pytest.mark.parametrize(
    "mutation, field",
    [
        (lambda d: d.update(extra=1), "extra"),
        (lambda d: d["cameras"][0].update(colour="red"), "cameras[0].colour"),
        (lambda d: d["cameras"][0].pop("intrinsics"), "cameras[0].intrinsics"),
        (lambda d: d["cameras"][0]["bar"].update(mass=-1), "cameras[0].bar.mass"),
        (lambda d: d["cameras"][0]["bar"].update(EI=-0.1), "cameras[0].bar.EI"),
        (lambda d: d["cameras"][0]["bar"].pop("EI"), "cameras[0].bar.EI"),
        (lambda d: d["cameras"][0].update(rotation_xyzw=[0, 0, 0, 2]), "cameras[0].rotation_xyzw"),
        (lambda d: d["cameras"][0].update(model="omni"), "cameras[0].model"),
        (lambda d: d["cameras"][1].update(name="cam0"), "cameras[1].name"),
        (lambda d: d["cameras"][0].update(distortion=[1, 2, 3]), "cameras[0].distortion"),
        (lambda d: d["cameras"][0].update(resolution=[640]), "cameras[0].resolution"),
        (lambda d: d["imu"].update(mount="cam7"), "imu.mount"),
        (lambda d: d.update(cameras=[]), "cameras"),
        (lambda d: d["cameras"][0].update(position=[0.4, "x", 0]), "cameras[0].position"),
    ],
)
def test_bad_rig_names_file_and_field(tmp_path, mutation, field):
    path = write(tmp_path, _mutate(mutation))
    with pytest.raises(InputError) as exc:
        load_rig(path)
    assert str(path) in str(exc.value)
    assert field in str(exc.value)


def test_unreadable_and_invalid_yaml(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        load_rig(tmp_path / "missing.yaml")
    p = tmp_path / "bad.yaml"
    p.write_text("cameras: [\n")
    with pytest.raises(InputError, match="not valid YAML"):
        load_rig(p)
