"""``nrmpc make-bag``: topics, counts, stamps, IMU a = -g, bent extrinsics (issue 4; SPEC sections 3, 4, 11)."""

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from nrmpc_ros.cli.main import main
from nrmpc_ros.core import gravity_from_accelerometer, load_rig
from nrmpc_ros.core.so3 import angle_between, quat_xyzw_to_matrix, rotation_angle
from nrmpc_ros.render import Renderer, make_scene
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

TS = get_typestore(Stores.ROS2_JAZZY)
SMALL = ["--views", "3", "--static-seconds", "0.5", "--rate", "4", "--seed", "7", "--no-progress"]


def read_bag(path):
    """topic -> list of (bag time ns, message)."""
    out = {}
    with Reader(path) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        for c, t, raw in r.messages():
            out.setdefault(c.topic, []).append((t, TS.deserialize_cdr(raw, c.msgtype)))
    return out, types


def stamp(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


@pytest.fixture(scope="module")
def clean_bag(tmp_path_factory):
    """Noise-free static bag of the default 4-camera cross rig, and its rig file."""
    d = tmp_path_factory.mktemp("bag")
    rig_path = d / "rig.yaml"
    rc = main(["make-bag", *SMALL, "--image-noise", "0", "--imu-noise", "0", "--gyro-noise", "0", "--imu-bias", "0",
               "--gyro-bias", "0", "--save-rig", str(rig_path), "--out", str(d / "b")])
    assert rc == 0
    return d / "b", load_rig(rig_path)


def test_topics_counts_and_stamps(clean_bag):
    path, rig = clean_bag
    msgs, types = read_bag(path)
    cams = [f"/cam{i}/image_raw" for i in range(4)]
    infos = [f"/cam{i}/camera_info" for i in range(4)]
    assert set(msgs) == set(cams + infos + ["/imu/data", "/ground_truth/pose", "/ground_truth/gravity"])
    assert types["/cam0/image_raw"] == "sensor_msgs/msg/Image"
    assert types["/imu/data"] == "sensor_msgs/msg/Imu"
    assert types["/ground_truth/pose"] == "geometry_msgs/msg/PoseStamped"
    assert types["/ground_truth/gravity"] == "geometry_msgs/msg/Vector3Stamped"
    frames = 3 * 2  # views x (0.5 s at 4 Hz)
    for topic in cams + infos + ["/ground_truth/pose", "/ground_truth/gravity"]:
        assert len(msgs[topic]) == frames, topic
        assert all(t == stamp(m) for t, m in msgs[topic]), "header stamp = bag time"
    ref = [t for t, _ in msgs["/cam0/image_raw"]]
    for topic in cams[1:] + infos + ["/ground_truth/pose", "/ground_truth/gravity"]:
        assert [t for t, _ in msgs[topic]] == ref, "one stamp per frame set"
    assert np.all(np.diff(ref)[::2] == 250_000_000)  # two frames 0.25 s apart in each static window
    img = msgs["/cam0/image_raw"][0][1]
    assert (img.width, img.height, img.encoding, img.step) == (640, 480, "mono8", 640)
    info = msgs["/cam0/camera_info"][0][1]
    assert info.k.tolist() == [470.0, 0, 319.5, 0, 470.0, 239.5, 0, 0, 1]
    assert info.header.frame_id == "cam0" and info.distortion_model == "plumb_bob"
    imu_t = np.array([t for t, _ in msgs["/imu/data"]])
    assert np.all(np.diff(imu_t) == 5_000_000), "200 Hz without gaps"
    assert imu_t[0] <= ref[0] and imu_t[-1] >= ref[-1]
    assert np.all(np.diff(ref) > 0)


def test_imu_reads_minus_gravity_when_still(clean_bag):
    path, rig = clean_bag
    msgs, _ = read_bag(path)
    imu_t = np.array([t for t, _ in msgs["/imu/data"]])
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                    for _, m in msgs["/imu/data"]])
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for _, m in msgs["/imu/data"]])
    for t, m in msgs["/ground_truth/gravity"]:
        g = np.array([m.vector.x, m.vector.y, m.vector.z])
        assert np.linalg.norm(g) == pytest.approx(9.81)
        k = np.searchsorted(imu_t, t)
        assert imu_t[k] == t
        assert np.allclose(acc[k], -g, atol=1e-9), "a = -g (SPEC section 4), body-mounted identity IMU"
        assert np.allclose(gravity_from_accelerometer(rig, acc[k]), g)
        assert np.allclose(gyro[k], 0.0)
    # Gravity is tilted 10-40 deg from the body's -z, and the rig turns between views (the gyro sees it).
    g = np.array([[m.vector.x, m.vector.y, m.vector.z] for _, m in msgs["/ground_truth/gravity"]])
    tilt = np.degrees(angle_between(g, np.array([0.0, 0.0, -1.0])))
    assert np.all((tilt > 10 - 1e-6) & (tilt < 40 + 1e-6))
    assert np.abs(gyro).max() > 0.05


def test_ground_truth_pose_and_gravity_agree(clean_bag):
    path, _ = clean_bag
    msgs, _ = read_bag(path)
    Rs = []
    for (_, p), (_, gm) in zip(msgs["/ground_truth/pose"], msgs["/ground_truth/gravity"]):
        q = p.pose.orientation
        R = quat_xyzw_to_matrix([q.x, q.y, q.z, q.w])
        assert p.header.frame_id == "world" and gm.header.frame_id == "base_link"
        assert np.allclose(R.T @ np.array([0, 0, -9.81]), [gm.vector.x, gm.vector.y, gm.vector.z], atol=1e-9)
        Rs.append(R)
    steps = [np.degrees(rotation_angle(Rs[k].T @ Rs[k + 2])) for k in range(0, len(Rs) - 2, 2)]
    assert all(5 - 1e-6 <= s <= 30 + 1e-6 for s in steps)


def test_images_use_the_bent_extrinsics(clean_bag):
    path, rig = clean_bag
    msgs, _ = read_bag(path)
    _, pose = msgs["/ground_truth/pose"][2]
    _, grav = msgs["/ground_truth/gravity"][2]
    q, p = pose.pose.orientation, pose.pose.position
    R = quat_xyzw_to_matrix([q.x, q.y, q.z, q.w])
    g = np.array([grav.vector.x, grav.vector.y, grav.vector.z])
    r = Renderer(rig, make_scene(7))
    bent = r.render_rig(R, [p.x, p.y, p.z], g)
    rigid = r.render_rig(R, [p.x, p.y, p.z], None)
    for i in range(4):
        m = msgs[f"/cam{i}/image_raw"][2][1]
        img = m.data.reshape(m.height, m.width).astype(float)
        assert np.abs(img - np.clip(np.rint(bent[i]), 0, 255)).max() <= 1.0
        assert np.abs(img - rigid[i]).mean() > 10.0
    # Both frames of one static window show the same (noise-free) image.
    a, b = msgs["/cam0/image_raw"][2][1], msgs["/cam0/image_raw"][3][1]
    assert np.array_equal(a.data, b.data)


def test_deterministic_and_noisy_options(tmp_path):
    args = ["make-bag", "--cameras", "2", "--layout", "line", "--views", "2", "--static-seconds", "0.25",
            "--rate", "4", "--seed", "3", "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    ma, _ = read_bag(tmp_path / "a")
    mb, _ = read_bag(tmp_path / "b")
    assert sorted(ma) == sorted(mb)
    for topic in ma:
        for (ta, x), (tb, y) in zip(ma[topic], mb[topic]):
            assert ta == tb
            if topic.endswith("image_raw"):
                assert np.array_equal(x.data, y.data)
    # IMU noise and bias: the static mean is off -g by about the bias only.
    imu_t = np.array([t for t, _ in ma["/imu/data"]])
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                    for _, m in ma["/imu/data"]])
    t0, gm = ma["/ground_truth/gravity"][0]
    g = np.array([gm.vector.x, gm.vector.y, gm.vector.z])
    window = (imu_t >= t0) & (imu_t < t0 + 250_000_000)
    mean = acc[window].mean(axis=0)
    assert 0.0 < np.degrees(angle_between(-mean, g)) < 1.0
    assert acc[window].std(axis=0).min() > 0.005


def test_continuous_motion_png_mcap(tmp_path):
    out = tmp_path / "c"
    rc = main(["make-bag", "--cameras", "3", "--layout", "ring", "--views", "2", "--static-seconds", "0.2",
               "--rate", "5", "--motion", "continuous", "--encoding", "png", "--storage", "mcap", "--seed", "1",
               "--no-progress", "--out", str(out)])
    assert rc == 0
    assert list(out.glob("*.mcap"))
    msgs, types = read_bag(out)
    assert "/cam0/image_raw" not in types, "compressed images go on <image_topic>/compressed"
    assert types["/cam0/image_raw/compressed"] == "sensor_msgs/msg/CompressedImage"
    assert "png" in msgs["/cam0/image_raw/compressed"][0][1].format
    ts = [t for t, _ in msgs["/cam0/image_raw/compressed"]]
    assert len(ts) > 2 and np.all(np.diff(ts) == 200_000_000), "frames stream through the move at the camera rate"
    assert len(msgs["/ground_truth/pose"]) == len(ts)


def test_existing_output_is_an_error(tmp_path, capsys):
    (tmp_path / "x").mkdir()
    rc = main(["make-bag", "--views", "1", "--no-progress", "--out", str(tmp_path / "x")])
    assert rc == 2
    assert "already exists" in capsys.readouterr().err


def test_imu_inside_a_camera_bends_with_it(tmp_path):
    """An IMU mounted in camera 0 reads a = -W_0(g)^T g (rotated into the IMU); SPEC section 4 recovers g."""
    rig_path = tmp_path / "rig.yaml"
    d = make_rig(RigSpec(num_cameras=2, layout="line", EI=0.15, focal=470.0)).to_dict()
    s = 0.5**0.5
    d["imu"] = {"topic": "/imu/data", "mount": "cam0", "rotation_xyzw": [0.0, 0.0, s, s]}
    rig_path.write_text(yaml.safe_dump(d))
    rig = load_rig(rig_path)
    assert rig.imu.mount == "cam0" and rig.cameras[0].is_flexible
    assert main(["make-bag", "--rig", str(rig_path), "--views", "2", "--static-seconds", "0.25", "--rate", "4",
                 "--imu-noise", "0", "--imu-bias", "0", "--no-progress", "--out", str(tmp_path / "b")]) == 0
    msgs, _ = read_bag(tmp_path / "b")
    acc = {t: np.array([m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z])
           for t, m in msgs["/imu/data"]}
    for t, m in msgs["/ground_truth/gravity"]:
        g = np.array([m.vector.x, m.vector.y, m.vector.z])
        body_reading = -g  # what a body-mounted, body-aligned IMU would read
        assert np.degrees(angle_between(acc[t], body_reading)) > 1.0, "the bar's bending tilts the IMU"
        assert np.allclose(gravity_from_accelerometer(rig, acc[t]), g, atol=1e-6)


@pytest.mark.parametrize("encoding", ["mono8", "bgr8", "rgb8", "mono16", "png", "jpeg"])
def test_image_encodings(tmp_path, encoding):
    import cv2

    from nrmpc_ros.bag.writer import BagWriter

    img = np.random.default_rng(0).integers(0, 256, size=(6, 10), dtype=np.uint8)
    with BagWriter(tmp_path / "e") as bag:
        bag.write("/img", bag.image_msg(img, 1_000_000_123, "cam0", encoding), 1_000_000_123)
    msgs, _ = read_bag(tmp_path / "e")
    (t, m), = msgs["/img"]
    assert t == stamp(m) == 1_000_000_123
    if encoding in ("png", "jpeg"):
        dec = cv2.imdecode(np.asarray(m.data), cv2.IMREAD_UNCHANGED)
        assert dec.shape == img.shape and m.format.startswith("mono8; " + encoding)
        assert np.abs(dec.astype(int) - img).max() <= (0 if encoding == "png" else 60)
        return
    assert (m.width, m.height, m.encoding) == (10, 6, encoding)
    if encoding == "mono16":
        assert np.array_equal(np.asarray(m.data).view("<u2").reshape(6, 10), img.astype(np.uint16) * 257)
    elif encoding == "mono8":
        assert np.array_equal(np.asarray(m.data).reshape(6, 10), img)
    else:
        assert np.array_equal(np.asarray(m.data).reshape(6, 10, 3)[:, :, 1], img) and m.step == 30
