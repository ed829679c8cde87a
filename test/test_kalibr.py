"""``nrmpc import-kalibr``: Kalibr camchains (plain and OpenCV %YAML:1.0) to rig files
(docs/CONVENTIONS.md, Files)."""

import json

import numpy as np
import pytest
import yaml

from nrmpc_ros.cli.main import main
from nrmpc_ros.core import load_rig
from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.errors import InputError
from nrmpc_ros.kalibr import load_kalibr_yaml, rig_from_kalibr


def T(R, t):
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = t
    return M


# Ground truth: camera poses in the IMU frame (camera -> IMU).
T_IMU_C = [T(exp_so3([0.1, -1.2, 0.3]), [0.3, 0.0, 0.05]), T(exp_so3([0.2, 1.3, -0.1]), [-0.3, 0.02, 0.0]),
           T(exp_so3([1.4, 0.1, 0.2]), [0.0, 0.25, -0.1])]


def camchain(with_imu=True, models=("radtan", "equidistant", "none")):
    d = {}
    dists = {"radtan": [-0.28, 0.07, 1e-4, -2e-4], "equidistant": [0.01, -0.003, 0.001, -0.0002], "none": []}
    for i, dm in enumerate(models):
        c = {"camera_model": "pinhole", "intrinsics": [460.0 + i, 461.0, 320.5, 240.5], "distortion_model": dm,
             "distortion_coeffs": dists[dm], "resolution": [640, 480], "rostopic": f"/rig/cam{i}/image"}
        if i:
            c["T_cn_cnm1"] = (np.linalg.inv(T_IMU_C[i]) @ T_IMU_C[i - 1]).tolist()
        if with_imu:
            c["T_cam_imu"] = np.linalg.inv(T_IMU_C[i]).tolist()
        d[f"cam{i}"] = c
    return d


def write(tmp_path, data, name="camchain.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data))
    return p


def check_poses(rig, T_body_imu):
    for cam, T_ic in zip(rig.cameras, T_IMU_C):
        expected = T_body_imu @ T_ic
        assert np.allclose(cam.rotation, expected[:3, :3], atol=1e-9)
        assert np.allclose(cam.position, expected[:3, 3], atol=1e-9)


def test_body_at_imu(tmp_path):
    rig, notes = rig_from_kalibr(write(tmp_path, camchain()), body_frame="imu")
    check_poses(rig, np.eye(4))
    assert [c.model for c in rig.cameras] == ["pinhole", "equidistant", "pinhole"]
    assert rig.cameras[0].distortion == (-0.28, 0.07, 1e-4, -2e-4) and rig.cameras[2].distortion == ()
    assert rig.cameras[1].image_topic == "/rig/cam1/image" and rig.cameras[1].info_topic == "/rig/cam1/camera_info"
    assert rig.cameras[0].intrinsics == (460.0, 461.0, 320.5, 240.5)
    assert not rig.is_flexible
    assert rig.imu is not None and np.allclose(rig.imu.rotation, np.eye(3))
    assert any("RIGID" in n for n in notes) and any("rotation_std_deg" in n for n in notes)


def test_body_at_camera_chains_extrinsics(tmp_path):
    chain = camchain(with_imu=False)
    rig, _ = rig_from_kalibr(write(tmp_path, chain), body_frame="cam1")
    check_poses(rig, np.linalg.inv(T_IMU_C[1]))
    assert np.allclose(rig.cameras[1].position, 0) and np.allclose(rig.cameras[1].rotation, np.eye(3))
    assert rig.imu is None


def test_imu_chain_gives_the_imu_rotation(tmp_path):
    cc = write(tmp_path, camchain(with_imu=False))
    imucam = write(tmp_path, camchain(with_imu=True), "camchain-imucam.yaml")
    rig, _ = rig_from_kalibr(cc, imucam, body_frame="cam0")
    T_b_imu = np.linalg.inv(T_IMU_C[0])
    check_poses(rig, T_b_imu)
    assert np.allclose(rig.imu.rotation, T_b_imu[:3, :3], atol=1e-9)


def test_opencv_yaml_header_and_matrices(tmp_path):
    chain = camchain()
    lines = ["%YAML:1.0", "---"]
    for key, c in chain.items():
        lines.append(f"{key}:")
        for k, v in c.items():
            if k.startswith("T_"):
                flat = ", ".join(repr(float(x)) for x in np.ravel(v))
                lines += [f"   {k}: !!opencv-matrix", "      rows: 4", "      cols: 4", "      dt: d",
                          f"      data: [ {flat} ]"]
            else:
                lines.append(f"   {k}: {v if isinstance(v, str) else json.dumps(v)}")
    p = tmp_path / "opencv.yaml"
    p.write_text("\n".join(lines) + "\n")
    assert load_kalibr_yaml(p)["cam1"]["T_cn_cnm1"] == pytest.approx(np.array(chain["cam1"]["T_cn_cnm1"]))
    rig, _ = rig_from_kalibr(p, body_frame="imu")
    check_poses(rig, np.eye(4))


def test_plain_header_line_too(tmp_path):
    p = write(tmp_path, camchain())
    p.write_text("%YAML:1.0\n" + p.read_text())
    rig, _ = rig_from_kalibr(p, body_frame="imu")
    check_poses(rig, np.eye(4))


@pytest.mark.parametrize("field,value,fragment", [
    ("camera_model", "omni", "omnidirectional"),
    ("camera_model", "ds", "double-sphere"),
    ("camera_model", "eucm", "extended unified"),
    ("distortion_model", "fov", "FOV"),
    ("intrinsics", [1, 2, 3], "4 numbers"),
])
def test_unsupported_models_name_file_and_field(tmp_path, field, value, fragment):
    chain = camchain()
    chain["cam1"][field] = value
    p = write(tmp_path, chain)
    with pytest.raises(InputError) as exc:
        rig_from_kalibr(p, body_frame="imu")
    assert str(p) in str(exc.value) and f"cam1.{field}" in str(exc.value) and fragment in str(exc.value)


def test_bad_inputs(tmp_path):
    chain = camchain()
    del chain["cam2"]["T_cn_cnm1"]
    with pytest.raises(InputError, match=r"cam2\.T_cn_cnm1"):
        rig_from_kalibr(write(tmp_path, chain), body_frame="imu")
    chain = camchain()
    chain["cam1"]["T_cn_cnm1"][0][0] = 3.0
    with pytest.raises(InputError, match="not a rotation"):
        rig_from_kalibr(write(tmp_path, chain), body_frame="imu")
    with pytest.raises(InputError, match="needs T_cam_imu"):
        rig_from_kalibr(write(tmp_path, camchain(with_imu=False)), body_frame="imu")
    with pytest.raises(InputError, match="field 'body_frame'"):
        rig_from_kalibr(write(tmp_path, camchain()), body_frame="cam7")
    with pytest.raises(InputError, match="no cameras"):
        rig_from_kalibr(write(tmp_path, {"imu0": {"rostopic": "/imu"}}))
    with pytest.raises(InputError, match="cannot read"):
        rig_from_kalibr(tmp_path / "missing.yaml")


def test_cli_writes_a_loadable_rig_and_says_bars_are_rigid(tmp_path, capsys):
    cc = write(tmp_path, camchain())
    out = tmp_path / "rig.yaml"
    assert main(["import-kalibr", str(cc), "--out", str(out), "--body-frame", "imu"]) == 0
    err = capsys.readouterr().err
    assert "RIGID" in err and "EI" in err
    rig = load_rig(out)
    check_poses(rig, np.eye(4))
    assert "RIGID" in out.read_text()
    assert main(["import-kalibr", str(cc), "--out", str(out)]) == 2, "refuses to overwrite without --force"
    assert main(["import-kalibr", str(cc), "--out", str(out), "--force", "--body-frame", "cam2"]) == 0
    chain = camchain()
    chain["cam0"]["camera_model"] = "omni"
    assert main(["import-kalibr", str(write(tmp_path, chain, "omni.yaml")), "--out", str(tmp_path / "o.yaml")]) == 2
    assert "cam0.camera_model" in capsys.readouterr().err
