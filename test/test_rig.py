import math

import numpy as np
import pytest
import yaml

from nrmpc_ros.core import load_rig, rig_from_dict, save_rig
from nrmpc_ros.core.so3 import exp_so3
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


# --- strict types, ROS names and topics, physical bounds -------------------------

BAD_VALUES = [
    # YAML booleans and strings are not numbers
    (lambda d: d["cameras"][0]["bar"].update(mass=True), "cameras[0].bar.mass", "got a boolean"),
    (lambda d: d["cameras"][0]["bar"].update(EI="0.1"), "cameras[0].bar.EI", "got the string '0.1'"),
    (lambda d: d.update(gravity_magnitude="9.81"), "gravity_magnitude", "expected a number"),
    (lambda d: d["cameras"][0].update(intrinsics=[800, 800, "320", 240]), "cameras[0].intrinsics[2]", "string"),
    (lambda d: d["cameras"][0].update(resolution=[640, False]), "cameras[0].resolution[1]", "boolean"),
    (lambda d: d["cameras"][0].update(rotation_xyzw=[0.5, -0.5, 0.5, None]), "cameras[0].rotation_xyzw[3]", "null"),
    (lambda d: d["cameras"][0].update(distortion=0), "cameras[0].distortion", "expected a list"),
    (lambda d: d["cameras"][0].update(position=[10**400, 0, 0]), "cameras[0].position[0]", "integer too large"),
    # names, strings and ROS rules
    (lambda d: d["cameras"][0].update(name=None), "cameras[0].name", "expected a string, got null"),
    (lambda d: d["cameras"][0].update(name=["cam0"]), "cameras[0].name", "expected a string, got a list"),
    (lambda d: d["cameras"][0].update(name=7), "cameras[0].name", "expected a string"),
    (lambda d: d["cameras"][0].update(name="cam-0"), "cameras[0].name", "not a valid ROS name"),
    (lambda d: d["cameras"][0].update(name="0cam"), "cameras[0].name", "must not start with a digit"),
    (lambda d: d["cameras"][0].update(name=""), "cameras[0].name", "must not be empty"),
    (lambda d: d.update(body_frame="/base_link"), "body_frame", "not a valid ROS name"),
    (lambda d: d.update(body_frame=None), "body_frame", "expected a string"),
    (lambda d: d["cameras"][0].update(model=["pinhole"]), "cameras[0].model", "unknown camera model"),
    (lambda d: d["imu"].update(topic=["/imu"]), "imu.topic", "expected a string"),
    (lambda d: d["imu"].update(mount=None), "imu.mount", "expected a string"),
    (lambda d: d["cameras"][0].update(image_topic=""), "cameras[0].image_topic", "empty"),
    (lambda d: d["cameras"][0].update(image_topic="/cam0//image"), "cameras[0].image_topic", "empty token"),
    (lambda d: d["cameras"][0].update(image_topic="/cam0/image/"), "cameras[0].image_topic", "end with '/'"),
    (lambda d: d["cameras"][0].update(image_topic="/"), "cameras[0].image_topic", "end with '/'"),
    (lambda d: d["cameras"][0].update(image_topic="/cam0/1st"), "cameras[0].image_topic", "starts with a digit"),
    (lambda d: d["cameras"][0].update(image_topic="/cam0/~img"), "cameras[0].image_topic", "'~' may only be"),
    (lambda d: d["cameras"][0].update(image_topic="~img"), "cameras[0].image_topic", "followed by '/'"),
    (lambda d: d["cameras"][0].update(image_topic="/cam 0/img"), "cameras[0].image_topic", "found ' '"),
    (lambda d: d["cameras"][0].update(image_topic="/{ns}/img"), "cameras[0].image_topic", "substitutions"),
    (lambda d: d["cameras"][0].update(info_topic="/cam0/info/"), "cameras[0].info_topic", "end with '/'"),
    (lambda d: d["imu"].update(topic="imu//data"), "imu.topic", "empty token"),
    # topics that would mix two streams
    (lambda d: d["cameras"][1].update(image_topic="/cam0/image_raw"), "cameras[1].image_topic", "also the image"),
    (lambda d: d["cameras"][1].update(image_topic="/imu/data"), "imu.topic", "image topic of cameras[1]"),
    (lambda d: d["imu"].update(topic="/cam1/camera_info"), "imu.topic", "info topic of cameras[1]"),
    (lambda d: d["cameras"][1].update(info_topic="/cam0/image_raw"), "cameras[1].info_topic", "image topic of"),
    (lambda d: d["cameras"][0].update(info_topic="/cam0/image_raw"), "cameras[0].info_topic", "image topic of"),
    (lambda d: d["cameras"][1].update(info_topic="/cam0/camera_info"), "cameras[1].info_topic", "also the info"),
    # physical plausibility
    (lambda d: d["cameras"][0]["bar"].update(mass=1e300), "cameras[0].bar.mass", "[0, 1000] kg"),
    (lambda d: d["cameras"][0]["bar"].update(mass=-1e-3), "cameras[0].bar.mass", "[0, 1000] kg"),
    (lambda d: d["cameras"][0]["bar"].update(EI=1e-300), "cameras[0].bar", "tip displacement under 1 g"),
    (lambda d: d["cameras"][0]["bar"].update(EI=0.07), "cameras[0].bar", "tip rotation under 1 g, m L^2 g / (2 EI) "
                                                                           "= 64.2 deg, exceeds 60 deg"),
    (lambda d: d["cameras"][0]["bar"].update(EI=0.0), "cameras[0].bar.EI", "must be > 0"),
    (lambda d: d["cameras"][0]["bar"].update(EI=float("nan")), "cameras[0].bar.EI", "finite"),
    (lambda d: d["cameras"][0]["bar"].update(EI=float("-inf")), "cameras[0].bar.EI", "finite"),
    (lambda d: d["cameras"][0].update(position=[1e200, 0, 0]), "cameras[0].position", "beyond the plausible 100 m"),
    (lambda d: d["cameras"][0].update(position=[0, 0, 0]), "cameras[0].position", "bar length 0"),
    (lambda d: d.update(gravity_magnitude=1e308), "gravity_magnitude", "[0.1, 100] m/s^2"),
    (lambda d: d.update(gravity_magnitude=0.0), "gravity_magnitude", "[0.1, 100] m/s^2"),
    (lambda d: d.update(gravity_magnitude=float("inf")), "gravity_magnitude", "finite"),
    (lambda d: d["cameras"][0].update(resolution=[64000, 480]), "cameras[0].resolution", "width = 64000 px"),
    (lambda d: d["cameras"][0].update(resolution=[640.5, 480]), "cameras[0].resolution", "positive integers"),
    (lambda d: d["cameras"][0].update(intrinsics=[1e6, 800, 320, 240]), "cameras[0].intrinsics", "fx = 1e+06 px"),
    (lambda d: d["cameras"][0].update(intrinsics=[800, 1e-9, 320, 240]), "cameras[0].intrinsics", "fy = 1e-09 px"),
    (lambda d: d["cameras"][0].update(intrinsics=[800, 800, 1e9, 240]), "cameras[0].intrinsics", "cx = 1e+09 px"),
    (lambda d: d["cameras"][0].update(distortion=[1e9, 0, 0, 0]), "cameras[0].distortion[0]", "[-1000, 1000]"),
    (lambda d: d["cameras"][1].update(distortion=[0, float("inf"), 0, 0]), "cameras[1].distortion[1]", "finite"),
    (lambda d: d.update({1: 2}), "1", "unknown key"),
    (lambda d: d.update(cameras={"cam0": {}}), "cameras", "non-empty list"),
    (lambda d: d["cameras"].append("cam2"), "cameras[2]", "expected a mapping, got the string 'cam2'"),
]


@pytest.mark.parametrize("mutation, field, fragment", BAD_VALUES)
def test_odd_values_name_file_field_and_reason(tmp_path, mutation, field, fragment):
    path = write(tmp_path, _mutate(mutation))
    with pytest.raises(InputError) as exc:
        load_rig(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}: field '{field}': ") and fragment in msg, msg


def test_camera_count_bounded():
    d = _mutate(lambda d: d.update(cameras=d["cameras"] * 501))
    with pytest.raises(InputError, match=r"<mine>: field 'cameras': 1002 cameras, more than the 1000"):
        rig_from_dict(d, "<mine>")


def test_nominal_rig_bends_45_degrees_and_loads(tmp_path):
    """The paper's nominal bar (m 0.1 kg, L 0.4 m, EI 0.1 N m^2) is well inside the bounds."""
    rig = load_rig(write(tmp_path, GOOD))
    _, _, cr = rig.bar_coefficients
    assert math.degrees(cr[0] * rig.gravity_magnitude) == pytest.approx(44.97, abs=0.01)


def test_accepted_spellings(tmp_path):
    text = yaml.safe_dump(GOOD).replace("EI: 0.1", "EI: 1e-1").replace("mass: 0.1", "mass: 1.0e-1")
    assert "EI: 1e-1" in text
    rig = load_rig(write_text(tmp_path, text))
    assert rig.cameras[0].EI == 0.1 and rig.cameras[0].mass == 0.1
    for spelling in ("inf", "Infinity", "+.inf", ".INF"):
        d = _mutate(lambda d, s=spelling: d["cameras"][0]["bar"].update(EI=s))
        assert math.isinf(load_rig(write(tmp_path, d)).cameras[0].EI)
    d = _mutate(lambda d: (d["cameras"][0].update(image_topic="front/image"), d["imu"].update(topic="~/imu")))
    rig = load_rig(write(tmp_path, d))
    assert rig.cameras[0].info_topic == "front/camera_info" and rig.imu.topic == "~/imu"
    assert load_rig(write(tmp_path, _mutate(lambda d: d["cameras"][0].update(image_topic="image")))
                    ).cameras[0].info_topic == "camera_info"


def write_text(tmp_path, text, name="rig.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("name, payload, fragment", [
    ("utf16", yaml.safe_dump(GOOD).encode("utf-16"), "rig file is UTF-16-LE text"),
    ("latin1", yaml.safe_dump(GOOD).replace("cam1", "cam\u00e9").encode("latin-1"), "looks like Latin-1"),
    ("binary", bytes(range(256)), "rig file is binary"),
    ("alias_bomb", ("a: &a [x, x, x, x, x, x, x, x, x, x]\n"
                    + "".join(f"{c}: &{c} [{', '.join(['*' + p] * 10)}]\n" for p, c in zip("abcdefg", "bcdefgh"))
                    ).encode(), "alias bomb"),
    ("deep", b"cameras: " + b"[" * 50_000 + b"]" * 50_000, "nested deeper than 64 levels"),
    ("empty", b"", "the rig file is empty"),
    ("list", b"- cam0\n- cam1\n", "expected a mapping, got a list"),
])
def test_hostile_rig_files(tmp_path, name, payload, fragment):
    path = tmp_path / f"{name}.yaml"
    path.write_bytes(payload)
    with pytest.raises(InputError) as exc:
        load_rig(path)
    assert str(exc.value).startswith(str(path)) and fragment in str(exc.value), str(exc.value)


def test_huge_rig_file_refused_before_reading(tmp_path):
    path = tmp_path / "huge.yaml"
    with open(path, "wb") as fh:
        fh.truncate(50 * 1024 * 1024)  # sparse: instant, and reading it would show as time
    with pytest.raises(InputError, match=r"rig file is 50 MiB, more than the 1 MiB"):
        load_rig(path)


def test_bar_damping_is_read_checked_and_written(tmp_path):
    """docs/CONVENTIONS.md (The rig in motion): ``bar.damping`` is zeta_i in (0, 1), optional."""
    d = _mutate(lambda d: d["cameras"][0]["bar"].update(damping=0.03))
    rig = load_rig(write(tmp_path, d))
    assert rig.cameras[0].damping == 0.03 and rig.cameras[1].damping is None
    save_rig(rig, tmp_path / "out.yaml")
    assert load_rig(tmp_path / "out.yaml").cameras[0].damping == 0.03
    bad = _mutate(lambda d: d["cameras"][0]["bar"].update(damping=1.5))
    with pytest.raises(InputError, match=r"cameras\[0\].bar.damping.*\(0, 1\)"):
        load_rig(write(tmp_path, bad, "bad.yaml"))


def test_bar_dynamics_stds_are_read_checked_and_written(tmp_path):
    """docs/CONVENTIONS.md (The rig in motion): ``damping_std``, ``frequency_hz`` and ``frequency_std_hz``,
    optional, as nrmpc calibrate-bars writes them; a negative std or a zero frequency is refused."""
    d = _mutate(lambda d: d["cameras"][0]["bar"].update(damping=0.03, damping_std=0.001, frequency_hz=2.5,
                                                        frequency_std_hz=0.002))
    rig = load_rig(write(tmp_path, d))
    c = rig.cameras[0]
    assert (c.damping_std, c.frequency_hz, c.frequency_std_hz) == (0.001, 2.5, 0.002)
    assert rig.cameras[1].damping_std is None and rig.cameras[1].frequency_hz is None
    save_rig(rig, tmp_path / "out.yaml")
    back = load_rig(tmp_path / "out.yaml").cameras[0]
    assert (back.damping_std, back.frequency_hz, back.frequency_std_hz) == (0.001, 2.5, 0.002)
    for key, value in (("damping_std", -0.01), ("frequency_hz", 0.0), ("frequency_std_hz", -1.0)):
        bad = _mutate(lambda d, kv={key: value}: d["cameras"][0]["bar"].update(kv))
        with pytest.raises(InputError, match=rf"cameras\[0\].bar.{key}"):
            load_rig(write(tmp_path, bad, "bad.yaml"))


def test_a_cameras_calibration_stds_are_read_checked_and_written(tmp_path):
    """docs/CONVENTIONS.md (Files): ``rotation_std_deg`` and ``position_std_m``, optional (0: taken as exact), how
    well the camera's rest rotation and position are calibrated; negative, or beyond 10 deg and 0.1 m, is
    refused, naming the key."""
    d = _mutate(lambda d: d["cameras"][0].update(rotation_std_deg=0.03, position_std_m=0.002))
    rig = load_rig(write(tmp_path, d))
    assert (rig.cameras[0].rotation_std_deg, rig.cameras[0].position_std_m) == (0.03, 0.002)
    assert (rig.cameras[1].rotation_std_deg, rig.cameras[1].position_std_m) == (0.0, 0.0)
    save_rig(rig, tmp_path / "out.yaml")
    back = load_rig(tmp_path / "out.yaml").cameras
    assert [(c.rotation_std_deg, c.position_std_m) for c in back] == [(0.03, 0.002), (0.0, 0.0)]
    written = yaml.safe_load((tmp_path / "out.yaml").read_text())["cameras"][1]
    assert "rotation_std_deg" not in written and "position_std_m" not in written
    for key, value in (("rotation_std_deg", -0.01), ("rotation_std_deg", 11.0), ("rotation_std_deg", "a lot"),
                       ("position_std_m", -1e-3), ("position_std_m", 0.5)):
        bad = _mutate(lambda d, kv={key: value}: d["cameras"][0].update(kv))
        with pytest.raises(InputError, match=rf"cameras\[0\].{key}"):
            load_rig(write(tmp_path, bad, "bad.yaml"))


def test_a_rig_with_rotation_errors_is_a_calibration_good_to_its_std():
    """Each camera's rest rotation turned about its own axes by a random rotation of the std per axis (the angles
    of many draws spread as a 3-D Gaussian's norm does), its position kept, and the std stated."""
    from nrmpc_ros.core.so3 import rotation_angle
    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    rig = make_rig(RigSpec(num_cameras=6, layout="ring", EI=0.5))
    rng = np.random.default_rng(4)
    angles = []
    for _ in range(50):
        off = rig.with_rotation_errors(0.1, rng)
        assert all(c.rotation_std_deg == 0.1 for c in off.cameras)
        assert np.array_equal(off.positions, rig.positions)
        angles += [math.degrees(rotation_angle(a.rotation.T @ b.rotation)) for a, b in zip(rig.cameras, off.cameras)]
    assert np.sqrt(np.mean(np.square(angles))) == pytest.approx(0.1 * math.sqrt(3), rel=0.1)
    shifts = np.concatenate([np.linalg.norm(rig.with_position_errors(0.002, rng).positions - rig.positions, axis=1)
                             for _ in range(50)])
    assert np.sqrt(np.mean(np.square(shifts))) == pytest.approx(0.002 * math.sqrt(3), rel=0.1)


def test_with_bar_ei_sets_every_bar_with_a_tip_mass():
    from dataclasses import replace

    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.5))
    rig = replace(rig, cameras=(replace(rig.cameras[0], mass=0.0, EI=math.inf),) + rig.cameras[1:])
    stiffer = rig.with_bar_ei(2.0)
    assert [c.EI for c in stiffer.cameras] == [math.inf, 2.0, 2.0]
    assert [c.mass for c in stiffer.cameras] == [c.mass for c in rig.cameras]
    np.testing.assert_allclose(stiffer.compliance[1:], rig.compliance[1:] / 4.0)
    assert not rig.with_bar_ei(math.inf).is_flexible


def test_an_imu_inside_a_camera(cross_rig):
    """with_imu_in mounts the IMU in a camera (its axes by default, or a given rotation), the topic kept."""
    name = cross_rig.cameras[2].name
    on_bar = cross_rig.with_imu_in(name)
    assert on_bar.imu.mount == name and np.array_equal(on_bar.imu.rotation, np.eye(3))
    assert on_bar.imu.topic == cross_rig.imu.topic and on_bar.cameras == cross_rig.cameras
    turned = cross_rig.with_imu_in(name, exp_so3(np.array([0.1, 0.2, 0.3])))
    assert np.allclose(turned.imu.rotation, exp_so3(np.array([0.1, 0.2, 0.3])))
    with pytest.raises(KeyError):
        cross_rig.with_imu_in("no such camera")
