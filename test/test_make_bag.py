"""``nrmpc make-bag``: topics, counts, stamps, IMU a = -g, bent extrinsics, and the recording styles (capture
modes, move profiles, ringing bars, jitter, drops, compressed images, no IMU, scenario files)."""

import dataclasses
import math

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from nrmpc_ros.bag.writer import ENCODINGS
from nrmpc_ros.cli.main import main
from nrmpc_ros.core import ImuMount, gravity_from_accelerometer, load_rig, save_rig
from nrmpc_ros.core.so3 import angle_between, exp_so3, log_so3, quat_xyzw_to_matrix, rotation_angle
from nrmpc_ros.render import Renderer, make_scene
from nrmpc_ros.render.bagmaker import BagOptions, imu_readings, make_bag
from nrmpc_ros.render.bars import CameraLoads, bent_extrinsics
from nrmpc_ros.render.sequence import MotionOptions, make_trajectory
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


@pytest.mark.slow
def test_topics_counts_and_stamps(clean_bag):
    path, rig = clean_bag
    msgs, types = read_bag(path)
    cams = [f"/cam{i}/image_raw" for i in range(4)]
    infos = [f"/cam{i}/camera_info" for i in range(4)]
    gt_extrinsics = [f"/ground_truth/extrinsics/{c.name}" for c in rig.cameras]
    assert set(msgs) == set(cams + infos + gt_extrinsics + ["/imu/data", "/ground_truth/pose", "/ground_truth/gravity",
                                                            "/ground_truth/angular_velocity"])
    assert types["/cam0/image_raw"] == "sensor_msgs/msg/Image"
    assert types["/imu/data"] == "sensor_msgs/msg/Imu"
    assert types["/ground_truth/pose"] == "geometry_msgs/msg/PoseStamped"
    assert types["/ground_truth/gravity"] == "geometry_msgs/msg/Vector3Stamped"
    frames = 3 * 2  # views x (0.5 s at 4 Hz)
    for topic in cams + infos + ["/ground_truth/pose", "/ground_truth/gravity", "/ground_truth/angular_velocity"]:
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


@pytest.mark.slow
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
        assert np.allclose(acc[k], -g, atol=1e-9), "a = -g, body-mounted identity IMU"
        assert np.allclose(gravity_from_accelerometer(rig, acc[k]), g)
        assert np.allclose(gyro[k], 0.0)
    # Gravity is tilted 10-40 deg from the body's -z, and the rig turns between views (the gyro sees it).
    g = np.array([[m.vector.x, m.vector.y, m.vector.z] for _, m in msgs["/ground_truth/gravity"]])
    tilt = np.degrees(angle_between(g, np.array([0.0, 0.0, -1.0])))
    assert np.all((tilt > 10 - 1e-6) & (tilt < 40 + 1e-6))
    assert np.abs(gyro).max() > 0.05


@pytest.mark.slow
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


@pytest.mark.slow
def test_images_use_the_bent_extrinsics(clean_bag):
    path, rig = clean_bag
    msgs, _ = read_bag(path)
    _, pose = msgs["/ground_truth/pose"][2]
    _, grav = msgs["/ground_truth/gravity"][2]
    q, p = pose.pose.orientation, pose.pose.position
    R = quat_xyzw_to_matrix([q.x, q.y, q.z, q.w])
    g = np.array([grav.vector.x, grav.vector.y, grav.vector.z])
    r = Renderer(rig, make_scene(7), BagOptions().supersample)  # as the bag's renderer
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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_imu_inside_a_camera_bends_with_it(tmp_path):
    """An IMU mounted in camera 0 reads a = -W_0(g)^T g (rotated into the IMU); gravity_from_accelerometer
    (docs/CONVENTIONS.md, Gravity measurements) recovers g."""
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


@pytest.mark.slow
@pytest.mark.parametrize("encoding", ENCODINGS)
def test_image_encodings(tmp_path, encoding):
    import cv2

    from nrmpc_ros.bag.writer import SENSOR_GAINS_BGR, BagWriter
    from nrmpc_ros.frontend.images import decode_image

    yy, xx = np.mgrid[0:12, 0:20]
    img = np.rint(60 + 6 * xx + 4 * yy).astype(np.uint8)  # smooth: a Bayer mosaic's demosaic is exact inside
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
    assert (m.width, m.height, m.encoding) == (20, 12, encoding)
    grey = decode_image(m, "/img").astype(float)
    if encoding.startswith("bayer_"):  # a raw sensor without white balance: a checkerboard, demosaiced to grey
        b, g, r = SENSOR_GAINS_BGR
        assert np.abs(np.diff(np.asarray(m.data).view("<u2" if encoding.endswith("16") else np.uint8)
                              .reshape(12, 20)[4].astype(float))).max() > 20
        np.testing.assert_allclose(grey[2:-2, 2:-2], img[2:-2, 2:-2] * (0.114 * b + 0.587 * g + 0.299 * r), atol=2)
    else:
        np.testing.assert_array_equal(grey, img)
    if encoding == "mono16":
        assert np.array_equal(np.asarray(m.data).view("<u2").reshape(12, 20), img.astype(np.uint16) * 257)
    elif encoding == "mono8":
        assert np.array_equal(np.asarray(m.data).reshape(12, 20), img)
    elif encoding in ("bgr8", "rgb8"):
        assert np.array_equal(np.asarray(m.data).reshape(12, 20, 3)[:, :, 1], img) and m.step == 60


# -- recording styles ------------------------------------------------------------------------------------------

TINY = ["--cameras", "2", "--layout", "line", "--resolution", "160x120", "--no-progress"]
QUIET = ["--image-noise", "0", "--imu-noise", "0", "--gyro-noise", "0", "--imu-bias", "0", "--gyro-bias", "0"]


def make(tmp_path, name, *args):
    out = tmp_path / name
    assert main(["make-bag", *TINY, *args, "--out", str(out)]) == 0
    return read_bag(out)


def vectors(msgs, topic, attr):
    return np.array([[getattr(getattr(m, attr), k) for k in "xyz"] for _, m in msgs[topic]])


@pytest.fixture(scope="module")
def styles(tmp_path_factory):
    """One trajectory recorded as holds, with jitter, with drops, as png and as jpeg (same seed)."""
    d = tmp_path_factory.mktemp("styles")
    base = ["--views", "3", "--hold-seconds", "0.5", "--rate", "10", "--seed", "5", "--imu-noise", "0"]
    return {name: make(d, name, *base, *extra)[0] for name, extra in {
        "plain": [], "jitter": ["--jitter-ms", "4"], "drops": ["--drop-rate", "0.3"],
        "png": ["--encoding", "png"], "jpeg": ["--encoding", "jpeg", "--jpeg-quality", "40"],
        "bursts": ["--camera-latency-ms", "150", "--camera-burst-s", "1"],
        "by_topic": ["--camera-burst-s", "1", "--camera-burst-stagger-ms", "7"],
    }.items()}


@pytest.mark.slow
def test_snapshot_one_image_per_camera_per_hold(tmp_path):
    msgs, _ = make(tmp_path, "s", "--capture", "snapshot", "--views", "3", "--hold-seconds", "2",
                   "--move-seconds", "0.5", "--seed", "2")
    for topic in ["/cam0/image_raw", "/cam1/image_raw", "/cam0/camera_info", "/ground_truth/pose",
                  "/ground_truth/gravity"]:
        ts = [t for t, _ in msgs[topic]]
        assert len(ts) == 3 and np.all(np.diff(ts) == 2_500_000_000), topic
    imu_t = np.array([t for t, _ in msgs["/imu/data"]])
    assert len(imu_t) == 7 * 200 and np.all(np.diff(imu_t) == 5_000_000), "IMU throughout, holds and moves"
    # Each snapshot is the last frame of its hold: the next 100 ms are still, then the rig moves.
    gyro = vectors(msgs, "/imu/data", "angular_velocity")
    for t, _ in msgs["/cam0/image_raw"][:2]:
        still = (imu_t >= t - 1_900_000_000) & (imu_t < t + 100_000_000)
        after = (imu_t > t + 100_000_000) & (imu_t < t + 600_000_000)
        assert np.abs(gyro[still]).max() < 0.01 < np.abs(gyro[after]).max()


@pytest.mark.slow
@pytest.mark.parametrize("capture, expected", [("holds", 3 * 5), ("stream", 3 * 5 + 2 * 5)])
def test_holds_and_stream_counts(tmp_path, capture, expected):
    msgs, _ = make(tmp_path, capture, "--capture", capture, "--views", "3", "--hold-seconds", "0.5",
                   "--move-seconds", "0.5", "--stream-hz", "10")
    ts = np.array([t for t, _ in msgs["/cam1/image_raw"]])
    assert len(ts) == expected and len(msgs["/ground_truth/pose"]) == expected
    assert np.all(np.diff(ts) % 100_000_000 == 0) and np.all(np.diff(ts) > 0)
    assert (np.diff(ts) == 100_000_000).all() == (capture == "stream")


@pytest.mark.slow
def test_jitter_moves_each_camera_stamp_but_not_the_content(styles):
    plain, jit = styles["plain"], styles["jitter"]
    assert [t for t, _ in jit["/ground_truth/pose"]] == [t for t, _ in plain["/ground_truth/pose"]]
    trigger = np.array([t for t, _ in plain["/cam0/image_raw"]])
    offsets = []
    for i in range(2):
        img, info = jit[f"/cam{i}/image_raw"], jit[f"/cam{i}/camera_info"]
        ts = np.array([t for t, _ in img])
        assert all(t == stamp(m) for t, m in img + info), "header stamp = bag time"
        assert [t for t, _ in info] == ts.tolist()
        off = ts - trigger
        assert np.abs(off).max() <= 4_000_000 and np.abs(off).max() > 1_000_000
        offsets.append(off)
        for (_, a), (_, b) in zip(img, plain[f"/cam{i}/image_raw"]):
            assert np.array_equal(a.data, b.data), "rendered (and noised) at the trigger time"
    assert np.count_nonzero(offsets[0] != offsets[1]) == len(trigger), "cameras are not synchronised"
    # The IMU and the ground truth are untouched; the bag stays in time order.
    assert [t for t, _ in jit["/imu/data"]] == [t for t, _ in plain["/imu/data"]]


@pytest.mark.slow
def test_late_cameras_in_bursts_keep_their_stamps_and_are_received_later(styles):
    """--camera-latency-ms and --camera-burst-s move the bag time of images and camera infos (when the recorder
    received them), never their stamps or pixels; the IMU is received at its stamps."""
    plain, late = styles["plain"], styles["bursts"]
    start = plain["/imu/data"][0][0]
    for i in range(2):
        for topic in (f"/cam{i}/image_raw", f"/cam{i}/camera_info"):
            got = late[topic]
            assert [stamp(m) for _, m in got] == [stamp(m) for _, m in plain[topic]]
            received = np.array([t for t, _ in got])
            due = np.array([stamp(m) for _, m in got]) + 150_000_000
            assert np.all(received >= due) and np.all(received - due < 1_000_000_000)
            assert np.all((received - start) % 1_000_000_000 == 0), "at the end of a 1 s burst"
        for (_, a), (_, b) in zip(late[f"/cam{i}/image_raw"], plain[f"/cam{i}/image_raw"]):
            assert np.array_equal(a.data, b.data)
    assert [t for t, _ in late["/imu/data"]] == [stamp(m) for _, m in late["/imu/data"]]


@pytest.mark.slow
def test_a_staggered_burst_comes_topic_by_topic(styles):
    """--camera-burst-stagger-ms: camera i's images of a burst are received i x MS after its end, so a burst
    reaches a reader camera by camera; stamps stay."""
    plain, late = styles["plain"], styles["by_topic"]
    start = plain["/imu/data"][0][0]
    for i in range(2):
        got = late[f"/cam{i}/image_raw"]
        assert [stamp(m) for _, m in got] == [stamp(m) for _, m in plain[f"/cam{i}/image_raw"]]
        received = np.array([t for t, _ in got])
        assert np.all((received - start) % 1_000_000_000 == i * 7_000_000)
        assert np.all(received >= [stamp(m) for _, m in got])


@pytest.mark.slow
def test_drops_remove_image_and_camera_info(styles):
    plain, drops = styles["plain"], styles["drops"]
    n = len(plain["/ground_truth/pose"])
    assert len(drops["/ground_truth/pose"]) == n == 15
    kept = []
    for i in range(2):
        img, info = drops[f"/cam{i}/image_raw"], drops[f"/cam{i}/camera_info"]
        assert [t for t, _ in info] == [t for t, _ in img]
        kept.append([t for t, _ in img])
        ref = {t: m for t, m in plain[f"/cam{i}/image_raw"]}
        assert all(np.array_equal(m.data, ref[t].data) for t, m in img), "a drop changes no other image"
    assert 0 < len(kept[0]) < n and 0 < len(kept[1]) < n and kept[0] != kept[1], "independent per camera"


@pytest.mark.slow
def test_compressed_images_on_the_compressed_topic(styles):
    import cv2

    plain = styles["plain"]
    for name in ("png", "jpeg"):
        msgs = styles[name]
        assert "/cam0/image_raw" not in msgs and len(msgs["/cam0/image_raw/compressed"]) == 15
        assert len(msgs["/cam0/camera_info"]) == 15
        for (t, m), (tr, raw) in zip(msgs["/cam1/image_raw/compressed"], plain["/cam1/image_raw"]):
            dec = cv2.imdecode(np.asarray(m.data), cv2.IMREAD_UNCHANGED)
            ref = raw.data.reshape(raw.height, raw.width)
            assert t == tr and dec.shape == (120, 160) and m.format.startswith(f"mono8; {name}")
            err = np.abs(dec.astype(int) - ref).mean()
            assert err == 0 if name == "png" else 0 < err < 20
    size = {name: np.mean([len(m.data) for _, m in styles[name]["/cam0/image_raw/compressed"]])
            for name in ("png", "jpeg")}
    assert size["jpeg"] < 0.5 * size["png"], "--jpeg-quality 40 compresses"


@pytest.mark.slow
def test_no_imu_and_resolution(tmp_path):
    rig_path = tmp_path / "rig.yaml"
    msgs, _ = make(tmp_path, "n", "--no-imu", "--views", "2", "--hold-seconds", "0.2", "--rate", "5",
                   "--resolution", "320x240", "--save-rig", str(rig_path))
    assert "/imu/data" not in msgs and len(msgs["/cam0/image_raw"]) == 2
    m = msgs["/cam0/image_raw"][0][1]
    assert (m.width, m.height) == (320, 240)
    assert msgs["/cam0/camera_info"][0][1].k.tolist() == [235.0, 0, 159.5, 0, 235.0, 119.5, 0, 0, 1]
    assert "imu" not in yaml.safe_load(rig_path.read_text())
    rig = load_rig(rig_path)
    assert rig.imu is None and rig.cameras[0].resolution == (320, 240)


@pytest.mark.slow
@pytest.mark.parametrize("profile", ["min-jerk", "trapezoid"])
def test_move_profiles_through_the_imu(tmp_path, profile):
    """The integrated gyro reproduces each move's attitude change; the accelerometer is smooth (min-jerk) or
    steps where the trapezoid switches between accelerating, coasting and decelerating."""
    msgs, _ = make(tmp_path, "p", "--capture", "snapshot", "--views", "3", "--hold-seconds", "0.3",
                   "--move-seconds", "1.0", "--move-profile", profile, "--accel-fraction", "0.25", "--seed", "3",
                   *QUIET)
    imu_t = np.array([t for t, _ in msgs["/imu/data"]])
    gyro = vectors(msgs, "/imu/data", "angular_velocity")
    acc = vectors(msgs, "/imu/data", "linear_acceleration")
    poses = [m.pose for _, m in msgs["/ground_truth/pose"]]
    Rs = [quat_xyzw_to_matrix([p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w]) for p in poses]
    ps = np.array([[p.position.x, p.position.y, p.position.z] for p in poses])
    snaps = [t for t, _ in msgs["/ground_truth/pose"]]
    for k in range(2):
        window = (imu_t >= snaps[k]) & (imu_t <= snaps[k + 1])
        rotvec = np.trapezoid(gyro[window], imu_t[window] * 1e-9, axis=0)  # the axis is fixed during a move
        expected = log_so3(Rs[k].T @ Rs[k + 1])
        assert np.degrees(np.linalg.norm(rotvec - expected)) < 0.01
        assert np.degrees(np.linalg.norm(expected)) > 4.0
        jumps = np.linalg.norm(np.diff(acc[window], axis=0), axis=1)
        peak = np.linalg.norm(ps[k + 1] - ps[k]) / (0.25 * 0.75)  # |dp| s''_max / T^2, T = 1 s
        if profile == "min-jerk":
            assert jumps.max() < 0.05 * peak + 0.05, "acceleration continuous"
        else:
            assert np.sort(jumps)[-4:] == pytest.approx([peak] * 4, rel=0.1, abs=0.05), "four acceleration steps"
            assert np.sort(jumps)[-5] < 0.2 * peak


@pytest.mark.slow
def test_make_bag_summary_hold_intervals(tmp_path):
    rig = make_rig(RigSpec(num_cameras=2, layout="line", EI=0.2, focal=117.5, resolution=(160, 120)))
    opts = BagOptions(motion=MotionOptions(views=3, hold_seconds=0.5, rate=10, capture="snapshot"), seed=1,
                      gyro_noise=0.0, gyro_bias=0.0, image_noise=0.0)
    summary = make_bag(rig, tmp_path / "b", opts, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"], "nothing written outside --out"
    holds = summary["holds"]
    assert len(holds) == 3 and all(h["settled"] is None for h in holds)
    assert holds[0]["start"] == pytest.approx(1_700_000_000.0)
    assert all(h["end"] - h["start"] == pytest.approx(0.5, abs=1e-6) for h in holds)
    msgs, _ = read_bag(tmp_path / "b")
    imu_t = np.array([t for t, _ in msgs["/imu/data"]]) * 1e-9
    gyro = np.linalg.norm(vectors(msgs, "/imu/data", "angular_velocity"), axis=1)
    still = np.zeros(len(imu_t), bool)
    for h in holds:
        still |= (imu_t >= h["start"] - 1e-6) & (imu_t <= h["end"] + 1e-6)
    assert np.all(gyro[still] == 0.0) and np.all(gyro[~still] > 0.0), "the body is still exactly in the holds"
    assert summary["bar_frequencies_hz"] == pytest.approx([math.sqrt(3 * 0.2 / (0.1 * 0.4**3)) / (2 * math.pi)] * 2)


@pytest.mark.slow
def test_ringing_bars_render_their_own_load(tmp_path):
    """With --damping every frame of a hold is re-rendered at each camera's filtered load."""
    rig = make_rig(RigSpec(num_cameras=2, layout="line", EI=0.2, focal=117.5, resolution=(160, 120)))
    opts = BagOptions(motion=MotionOptions(views=2, hold_seconds=1.0, rate=5, move_seconds=0.6), seed=4,
                      image_noise=0.0, damping=0.05)
    summary = make_bag(rig, tmp_path / "b", opts, progress=False)
    traj = summary["trajectory"]
    h = summary["holds"][1]
    assert h["settled"] - h["start"] == pytest.approx(math.log(1e3) / (0.05 * 2 * math.pi * 1.5411), rel=1e-3)
    assert summary["holds"][0]["settled"] == summary["holds"][0]["start"]
    msgs, _ = read_bag(tmp_path / "b")
    frames = msgs["/cam0/image_raw"]
    second = [(t, m) for t, m in frames if t >= traj.hold_start[1]]
    assert len(second) == 5
    a, b = (m.data.reshape(120, 160).astype(int) for _, m in second[:2])
    assert np.abs(a - b).mean() > 1.0, "the bars still ring: frames of one hold differ"
    loads = CameraLoads(rig, traj, damping=0.05)
    renderer = Renderer(rig, make_scene(4), opts.supersample)
    for t, m in second[:2]:
        R, p, _, _ = traj.state([t])
        expected = renderer.render_rig(R[0], p[0], loads.at([t])[0])[0]
        assert np.abs(m.data.reshape(120, 160) - np.clip(np.rint(expected), 0, 255)).max() <= 1.0
        quasi = renderer.render_rig(R[0], p[0], traj.gravity_body(R)[0])[0]
        assert np.abs(m.data.reshape(120, 160) - quasi).mean() > 1.0
    # First hold: at rest, so its frames are identical.
    first = [m.data for t, m in frames if t < traj.hold_end[0]]
    assert len(first) == 5 and all(np.array_equal(first[0], x) for x in first)


def test_imu_inside_a_ringing_camera_feels_the_tip_motion():
    """An IMU in a ringing camera reads the specific force of the moving, bending tip and the camera's angular
    velocity: both checked against finite differences of the bent camera's pose in the world, during the move
    (body rotation: lever arm, Coriolis) and while it rings in the next hold."""
    rig = make_rig(RigSpec(num_cameras=2, layout="line", EI=2.0, mass=0.1, focal=100.0, resolution=(160, 120)))
    rig = dataclasses.replace(rig, imu=ImuMount(mount="cam1", rotation=exp_so3(np.array([0.3, -0.2, 0.1]))))
    traj = make_trajectory(np.random.default_rng(8), MotionOptions(views=2, hold_seconds=0.5, move_seconds=0.6))
    opts = BagOptions(imu_noise=0.0, gyro_noise=0.0, imu_bias=0.0, gyro_bias=0.0, damping=0.05)
    loads = CameraLoads(rig, traj, damping=0.05)
    t = np.linspace(traj.hold_end[0] + 50_000_000, traj.end_ns - 50_000_000, 40).astype(np.int64)
    accel, gyro = imu_readings(rig, traj, t, np.random.default_rng(0), opts, loads)
    h = 20_000  # 20 us

    def camera_in_world(tt):
        R, p, _, _ = traj.state(tt)
        w, W = bent_extrinsics(rig, loads.at(tt))
        return R @ W[:, 1], np.einsum("nij,nj->ni", R, w[:, 1]) + p

    Rc, pc = camera_in_world(t)
    Rp, pp = camera_in_world(t + h)
    Rm, pm = camera_in_world(t - h)
    a_world = (pp - 2 * pc + pm) / (h * 1e-9) ** 2
    f_cam = np.einsum("nji,nj->ni", Rc, a_world - np.array([0.0, 0.0, -9.81]))  # specific force, camera frame
    w_cam = log_so3(np.einsum("nji,njk->nik", Rm, Rp)) / (2 * h * 1e-9)
    to_imu = rig.imu.rotation.T
    assert np.abs(accel - f_cam @ to_imu.T).max() < 1e-4  # m/s^2, of readings up to 10
    assert np.abs(gyro - w_cam @ to_imu.T).max() < 1e-6
    swing = np.linalg.norm(np.diff(accel, axis=0), axis=1).max()
    assert swing > 1.0, "the ringing tip shakes the accelerometer"


@pytest.mark.slow
def test_scenario_file_and_flag_overrides(tmp_path):
    sc = tmp_path / "sc.yaml"
    sc.write_text("cameras: 2\nlayout: line\nresolution: 160x120\nviews: 2\nhold-seconds: 0.2\nrate: 5\n"
                  "capture: snapshot\nno_imu: true\nencoding: jpeg\n")
    out = tmp_path / "b"
    assert main(["make-bag", "--scenario", str(sc), "--views", "3", "--no-progress", "--out", str(out)]) == 0
    msgs, _ = read_bag(out)
    assert set(msgs) == {"/cam0/image_raw/compressed", "/cam1/image_raw/compressed", "/cam0/camera_info",
                         "/cam1/camera_info", "/ground_truth/pose", "/ground_truth/gravity",
                         "/ground_truth/angular_velocity",
                         "/ground_truth/extrinsics/cam0", "/ground_truth/extrinsics/cam1"}
    assert len(msgs["/cam0/image_raw/compressed"]) == 3, "--views on the command line overrides the file"
    assert msgs["/cam0/camera_info"][0][1].width == 160


@pytest.mark.slow
def test_scenario_rig_path_is_relative_to_the_file(tmp_path):
    d = tmp_path / "scenarios"
    d.mkdir()
    save_rig(make_rig(RigSpec(num_cameras=2, layout="line", focal=60.0, resolution=(80, 60))), d / "rig.yaml")
    (d / "sc.yaml").write_text("rig: rig.yaml\nviews: 2\nhold_seconds: 0.2\nrate: 5\ncapture: snapshot\n")
    assert main(["make-bag", "--scenario", str(d / "sc.yaml"), "--no-progress", "--out", str(tmp_path / "b")]) == 0
    msgs, _ = read_bag(tmp_path / "b")
    assert msgs["/cam1/camera_info"][0][1].width == 80 and len(msgs["/cam1/image_raw"]) == 2


@pytest.mark.parametrize("text, key", [
    ("holds_seconds: 2\n", "holds_seconds"), ("views: two\n", "views"), ("views: 2.5\n", "views"),
    ("no-imu: 1\n", "no-imu"), ("capture: bursts\n", "capture"), ("motion: static\ncapture: stream\n", "motion"),
    ("- 1\n", None),
])
def test_bad_scenario_files(tmp_path, capsys, text, key):
    sc = tmp_path / "sc.yaml"
    sc.write_text(text)
    assert main(["make-bag", "--scenario", str(sc), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert str(sc) in err and (key is None or f"'{key}'" in err)
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("args, flag", [
    (["--drop-rate", "1"], "--drop-rate"), (["--jitter-ms", "60"], "--jitter-ms"), (["--damping", "0"], "--damping"),
    (["--accel-fraction", "0.7"], "--accel-fraction"), (["--jpeg-quality", "101"], "--jpeg-quality"),
    (["--move-seconds", "-1"], "--move-seconds"), (["--hold-seconds", "0"], "--hold-seconds"),
    (["--motion", "static", "--capture", "stream"], "--motion"), (["--imu-noise", "-1"], "--imu-noise"),
    (["--rig", "config/sample_cross4.yaml", "--resolution", "320x240"], "--resolution"),
    (["--width", "1"], "--width"), (["--cameras", "0", "--layout", "ring"], "--cameras"), (["--seed", "-1"], "--seed"),
    (["--camera-burst-s", "-1"], "--camera-burst-s"), (["--camera-latency-ms", "nan"], "--camera-latency-ms"),
    (["--camera-burst-stagger-ms", "-1"], "--camera-burst-stagger-ms"),
    (["--imu-in-camera", "cam9"], "--imu-in-camera"), (["--imu-in-camera", "1", "--no-imu"], "--imu-in-camera"),
])
def test_bad_options_name_the_flag(tmp_path, capsys, args, flag):
    try:
        code = main(["make-bag", "--no-progress", *args, "--out", str(tmp_path / "b")])
    except SystemExit as exc:  # a flag out of range is refused while parsing
        code = exc.code
    assert code == 2
    assert flag in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_save_rig_never_overwrites_the_input_rig(tmp_path, capsys):
    rig_path = tmp_path / "rig.yaml"
    save_rig(make_rig(RigSpec(num_cameras=2, layout="line", resolution=(160, 120))), rig_path)
    before = rig_path.read_text()
    assert main(["make-bag", "--rig", str(rig_path), "--save-rig", str(rig_path), "--out", str(tmp_path / "b")]) == 2
    assert "--save-rig" in capsys.readouterr().err and rig_path.read_text() == before


# -- recordings like users make: hold lengths, creep, per-camera triggers, snapshots, exposure, clocks, bars ------

def test_random_hold_lengths_are_whole_frame_periods_and_keep_the_attitudes():
    fixed = make_trajectory(np.random.default_rng(3), MotionOptions(views=8, rate=10.0))
    traj = make_trajectory(np.random.default_rng(3), MotionOptions(views=8, rate=10.0, hold_seconds_range=(1.0, 3.0)))
    assert np.allclose(traj.R, fixed.R) and np.allclose(traj.p, fixed.p)
    assert np.all((traj.hold_frames >= 10) & (traj.hold_frames <= 30)) and len(set(traj.hold_frames.tolist())) > 2
    assert np.array_equal(traj.hold_end - traj.hold_start, traj.hold_frames * traj.period_ns)
    assert np.all(traj.hold_start[1:] == traj.hold_end[:-1] + traj.move_ns)
    t, view = traj.frame_times("holds")
    assert np.array_equal(np.bincount(view), traj.hold_frames)
    assert np.all(traj.view_index(t) == view)


def test_creeping_holds_turn_at_the_given_rate_and_the_rest_stay_still():
    opts = MotionOptions(views=7, rate=10.0, hold_seconds=2.0, creep_fraction=0.5, creep_deg_per_s=0.5)
    traj = make_trajectory(np.random.default_rng(4), opts)
    still = make_trajectory(np.random.default_rng(4), dataclasses.replace(opts, creep_fraction=0.0))
    assert np.allclose(traj.R, still.R), "creep is drawn last: the attitudes of the seed stay"
    assert traj.creeping.sum() == 3 and not traj.creeping[0]
    for k in range(traj.R.shape[0]):
        a, b = int(traj.hold_start[k]), int(traj.hold_end[k])
        t = np.array([a, (a + b) // 2, b - 1])
        R, _, omega, acc = traj.state(t)
        turned = math.degrees(float(rotation_angle(R[0].T @ R[-1])))
        if traj.creeping[k]:
            assert np.allclose(np.degrees(np.linalg.norm(omega, axis=1)), 0.5)
            assert turned == pytest.approx(0.5 * (b - 1 - a) * 1e-9, rel=1e-6)
        else:
            assert np.all(omega == 0) and turned == 0
        assert np.all(acc == 0)
    # the move after a creeping hold starts where the creep ended, and reaches the next hold's attitude
    k = int(np.flatnonzero(traj.creeping)[0])
    R_end, _, _, _ = traj.state(np.array([traj.hold_end[k], traj.hold_start[k + 1]]) if k + 1 < len(traj.R)
                                else np.array([traj.hold_end[k] - 1, traj.hold_end[k] - 1]))
    assert float(rotation_angle(R_end[0].T @ traj.R_end[k])) < 1e-6
    if k + 1 < len(traj.R):
        assert float(rotation_angle(R_end[1].T @ traj.R[k + 1])) < 1e-9


def test_each_camera_fires_at_its_own_rate_and_phase():
    opts = MotionOptions(views=3, rate=10.0, hold_seconds=1.0, camera_rates=(10.0, 15.0, 30.0),
                         camera_phases_ms=(0.0, 20.0, 5.0))
    traj = make_trajectory(np.random.default_rng(0), opts)
    t, view, fires = traj.camera_triggers(opts, 3)
    assert np.all(np.diff(t) > 0) and np.all(view >= 0) and fires.any(axis=1).all()
    for i, (rate, phase) in enumerate(zip(opts.camera_rates, opts.camera_phases_ms)):
        ti = t[fires[:, i]]
        for k in range(3):
            own = ti[view[fires[:, i]] == k]
            assert own[0] == traj.hold_start[k] + round(phase * 1e6)
            assert np.all(np.diff(own) == round(1e9 / rate)) and own[-1] < traj.hold_end[k]
    stream = dataclasses.replace(opts, capture="stream")
    ts, vs, fs = traj.camera_triggers(stream, 3)
    assert (vs < 0).any() and fs.sum(axis=0).tolist() == [
        len(np.arange(traj.start_ns + round(p * 1e6), traj.end_ns, round(1e9 / r))) for r, p in
        zip(opts.camera_rates, opts.camera_phases_ms)]


def test_without_camera_options_every_camera_fires_on_the_frame_grid():
    for capture in ("holds", "snapshot", "stream"):
        opts = MotionOptions(views=3, hold_seconds=1.0, capture=capture)
        traj = make_trajectory(np.random.default_rng(1), opts)
        t, view, fires = traj.camera_triggers(opts, 4)
        t0, v0 = traj.frame_times(capture)
        assert np.array_equal(t, t0) and np.array_equal(view, v0) and fires.all()


def test_snapshot_delay_takes_one_image_per_camera_that_long_after_each_stop():
    opts = MotionOptions(views=4, hold_seconds_range=(1.0, 2.0), capture="snapshot", snapshot_delay=0.5,
                         camera_phases_ms=(0.0, 3.0))
    traj = make_trajectory(np.random.default_rng(2), opts)
    t, view, fires = traj.camera_triggers(opts, 2)
    for i, phase in enumerate((0.0, 3.0)):
        assert np.array_equal(t[fires[:, i]], traj.hold_start + 500_000_000 + round(phase * 1e6))
    assert np.array_equal(np.unique(view), np.arange(4))


def test_exposure_drifts_slowly_within_its_amplitude_and_differs_per_camera():
    from nrmpc_ros.render.bagmaker import EXPOSURE_OFFSET_GREY, Exposure

    exp = Exposure(3, BagOptions(exposure_drift=0.3, exposure_period_s=10.0), np.random.default_rng(0))
    t = np.linspace(0.0, 60.0, 601)
    go = np.array([[exp.gain_offset(i, s) for s in t] for i in range(3)])  # (3, T, 2)
    assert np.all(np.abs(go[..., 0] - 1) <= 0.3) and np.ptp(go[..., 0], axis=1).min() > 0.4
    assert np.all(np.abs(go[..., 1]) <= EXPOSURE_OFFSET_GREY * 0.3)
    assert np.abs(np.diff(go[..., 0], axis=1)).max() < 0.3 * 2 * math.pi * 0.1 / 7.0 + 1e-12  # slow: 0.1 s steps
    assert not np.allclose(go[0], go[1])
    none = Exposure(1, BagOptions(), np.random.default_rng(0))
    assert none.gain_offset(0, 12.3) == (1.0, 0.0)


def test_bar_hz_sets_the_bars_natural_frequency():
    from nrmpc_ros.cli.make_bag import ei_for_frequency
    from nrmpc_ros.core.dynamics import bar_natural_frequencies

    for hz in (1.5, 4.2, 8.0):
        rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=ei_for_frequency(hz, 0.1, 0.4), mass=0.1,
                               bar_length=0.4))
        assert np.allclose(bar_natural_frequencies(rig), hz)


@pytest.mark.parametrize("args, flag", [
    (["--camera-rates", "10,15,20"], "--camera-rates"), (["--camera-rates", "10,x"], "--camera-rates"),
    (["--camera-rates", "10,0"], "--camera-rates"),
    (["--camera-rates", "10,10", "--camera-phases-ms", "0,100"], "--camera-phases-ms"),
    (["--camera-phases-ms", "0"], "--camera-phases-ms"),
    (["--hold-seconds-range", "3,1"], "--hold-seconds-range"), (["--hold-seconds-range", "2"], "--hold-seconds-range"),
    (["--capture", "snapshot", "--hold-seconds", "2", "--snapshot-delay", "2"], "--snapshot-delay"),
    (["--capture", "snapshot", "--snapshot-delay", "-1"], "--snapshot-delay"),
    (["--snapshot-delay", "0.5"], "--snapshot-delay"), (["--camera-phases-ms", "0,100"], "--camera-phases-ms"),
    (["--creep-fraction", "1.5"], "--creep-fraction"), (["--creep-deg-per-s", "0"], "--creep-deg-per-s"),
    (["--exposure-drift", "0.9"], "--exposure-drift"), (["--exposure-period-s", "0"], "--exposure-period-s"),
    (["--imu-time-offset-ms", "nan"], "--imu-time-offset-ms"), (["--bar-hz", "3", "--EI", "1"], "--bar-hz"),
    (["--bar-hz", "0"], "--bar-hz"), (["--bar-hz", "3", "--mass", "0"], "--bar-hz"),
    (["--rig", "config/sample_cross4.yaml", "--bar-hz", "3"], "--bar-hz"),
    (["--accel-scale-error", "-0.01"], "--accel-scale-error"), (["--accel-scale-error", "1"], "--accel-scale-error"),
    (["--vibration", "-1"], "--vibration"), (["--imu-stamp-jitter-ms", "-1"], "--imu-stamp-jitter-ms"),
    (["--vibration-hz", "0"], "--vibration-hz"),
    (["--vibration-hz", "inf"], "--vibration-hz"),
    (["--imu-clock-start-s", "-1"], "--imu-clock-start-s"), (["--imu-clock-start-s", "3e9"], "--imu-clock-start-s"),
    (["--camera-clock-start-s", "1,x"], "--camera-clock-start-s"),
    (["--camera-clock-start-s", ",-5"], "--camera-clock-start-s"),
    (["--camera-clock-start-s", "1,2,3"], "--camera-clock-start-s"), (["--unstamped", "cam9"], "--unstamped"),
    (["--unstamped", "cam0,,imu"], "--unstamped"), (["--rig-imu-turn-deg", "0,90"], "--rig-imu-turn-deg"),
    (["--rig-imu-turn-deg", "0,0,90"], "--rig-imu-turn-deg"),  # no --save-rig to turn it in
    (["--imu-loss", "0.7"], "--imu-loss"), (["--imu-loss-burst-ms", "-1"], "--imu-loss-burst-ms"),
    (["--shutter-ms", "200"], "--shutter-ms"),  # longer than the frame period
    (["--walker-speed", "-1"], "--walker-speed"), (["--walker-speed", "5"], "--walker-speed"),
    (["--rig-rotation-error-deg", "0.1"], "--rig-rotation-error-deg"),  # no --save-rig to turn it in
    (["--rig-position-error-m", "0.001"], "--rig-position-error-m"),
    (["--rig-position-error-m", "0.5", "--save-rig", "never.yaml"], "--rig-position-error-m"),
])
def test_bad_new_options_name_the_flag(tmp_path, capsys, args, flag):
    rig_flags = ["--no-progress"] if "--rig" in args else TINY
    try:
        code = main(["make-bag", *rig_flags, *args, "--out", str(tmp_path / "b")])
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    assert flag in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_scenario_lists_for_per_camera_options(tmp_path, capsys):
    sc = tmp_path / "s.yaml"
    sc.write_text("camera-rates: [10, 20, 30]\nhold-seconds-range: [1, 2]\n")
    assert main(["make-bag", *TINY, "--scenario", str(sc), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "--camera-rates" in err and "one value per camera (2)" in err


@pytest.mark.slow
def test_users_recording_options_in_a_bag(tmp_path):
    """Per-camera rates and phases, a 100 Hz IMU 7 ms off the cameras' clock, creeping holds, exposure drift."""
    msgs, types = make(tmp_path, "b", "--resolution", "80x60", "--views", "4", "--hold-seconds-range", "0.5,1",
                       "--camera-rates", "10,20", "--camera-phases-ms", "0,10", "--imu-rate", "100",
                       "--imu-time-offset-ms", "7", "--creep-fraction", "0.34", "--exposure-drift", "0.3",
                       "--exposure-period-s", "2", "--bar-hz", "4", "--damping", "0.2", "--jitter-ms", "3",
                       *QUIET)
    with Reader(tmp_path / "b") as r:
        assert np.all(np.diff([t for _, t, _ in r.messages()]) >= 0), "bag time never goes back"
    c0 = np.array([stamp(m) for _, m in msgs["/cam0/image_raw"]])
    c1 = np.array([stamp(m) for _, m in msgs["/cam1/image_raw"]])
    assert 1.7 * len(c0) < len(c1) < 2.3 * len(c0)
    imu_t = np.array([stamp(m) for _, m in msgs["/imu/data"]])
    assert np.all(np.diff(imu_t) == 10_000_000) and imu_t[0] == 1_700_000_000_000_000_000 + 7_000_000
    received = np.array([t for t, _ in msgs["/imu/data"]])
    assert np.all(received == imu_t - 7_000_000), "received when taken: the recorder's clock is the cameras'"
    gt = np.array([stamp(m) for _, m in msgs["/ground_truth/pose"]])
    w = np.linalg.norm(vectors(msgs, "/ground_truth/angular_velocity", "vector"), axis=1)
    assert types["/ground_truth/angular_velocity"] == "geometry_msgs/msg/Vector3Stamped"
    assert len(gt) == len(w) and np.all(np.isin(np.round(c1, -7), np.round(gt, -7)))  # a truth per trigger
    assert np.allclose(np.degrees(w[w > 0]), 0.5) and (w == 0).sum() > 0, "one hold creeps, the others are still"
    means = np.array([m.data.mean() for _, m in msgs["/cam0/image_raw"]])
    assert np.ptp(means) > 5, "the exposure drifts"


@pytest.mark.slow
@pytest.mark.parametrize("cameras", [5, 6])
def test_rings_of_five_and_six_cameras_see_different_views(cameras):
    rig = make_rig(RigSpec(num_cameras=cameras, layout="ring", resolution=(64, 48), focal=47.0))
    renderer = Renderer(rig, make_scene(0), 1)
    R, c = renderer.camera_poses(np.eye(3), np.zeros(3), np.broadcast_to(rig.gravity_magnitude * np.array(
        [0.0, 0.0, -1.0]), (cameras, 3)))
    images = [renderer.render_camera(i, R[i], c[i]) for i in range(cameras)]
    for i in range(cameras):
        for j in range(i + 1, cameras):
            assert np.mean(np.abs(images[i] - images[j])) > 5.0, (i, j)


def test_imu_units_of_a_driver_that_breaks_rep_103(tmp_path):
    """--gyro-unit deg/s and --accel-unit g write the same IMU in those units, covariances included (a driver
    consistent in its own units: the noise it claims is the noise its samples show)."""
    args = ["--views", "2", "--hold-seconds", "0.4", "--rate", "5", "--resolution", "160x120", "--seed", "3"]
    si, _ = make(tmp_path, "si", *args)
    other, _ = make(tmp_path, "other", *args, "--gyro-unit", "deg/s", "--accel-unit", "g")
    for (_, a), (_, b) in zip(si["/imu/data"], other["/imu/data"]):
        for name, k in (("angular_velocity", 180.0 / math.pi), ("linear_acceleration", 1.0 / 9.80665)):
            va, vb = getattr(a, name), getattr(b, name)
            assert np.allclose([vb.x, vb.y, vb.z], k * np.array([va.x, va.y, va.z]), rtol=1e-12, atol=1e-15)
            assert np.allclose(getattr(b, name + "_covariance"), k * k * getattr(a, name + "_covariance"))
    assert len(si["/imu/data"]) == len(other["/imu/data"]) > 10


def test_an_accelerometer_scale_error_scales_each_axis_within_its_bound(tmp_path):
    """--accel-scale-error S: each axis of the accelerometer reads (1 + s) times what it reads without, s within
    +-S and one per axis (the bias and noise drawn as before); the gyro and the images are untouched."""
    args = ["--views", "2", "--hold-seconds", "0.4", "--rate", "5", "--resolution", "160x120", "--seed", "3",
            "--imu-noise", "0", "--imu-bias", "0"]
    exact, _ = make(tmp_path, "exact", *args)
    scaled, _ = make(tmp_path, "scaled", *args, "--accel-scale-error", "0.03")
    a = vectors(exact, "/imu/data", "linear_acceleration")
    b = vectors(scaled, "/imu/data", "linear_acceleration")
    ratio = b / a
    assert np.allclose(ratio, ratio[0], rtol=1e-9) and np.all(np.abs(ratio[0] - 1) <= 0.03)
    assert np.ptp(ratio[0]) > 1e-3, "a scale per axis"
    assert np.array_equal(vectors(exact, "/imu/data", "angular_velocity"),
                          vectors(scaled, "/imu/data", "angular_velocity"))


def test_a_motors_vibration_shakes_the_imu_at_its_frequency_and_leaves_the_images(tmp_path):
    """--vibration A --vibration-hz F: the accelerometer reads a sine at F of A m/s^2 RMS over its axes on top of
    what it read without (the gyro its rocking, smaller), sampled at the IMU's stamps (aliased where those are
    slower than 2 F); the images and everything drawn before are untouched."""
    args = ["--views", "2", "--hold-seconds", "0.4", "--rate", "5", "--resolution", "160x120", "--seed", "3",
            "--imu-rate", "1000"]
    calm, _ = make(tmp_path, "calm", *args)
    shaken, _ = make(tmp_path, "shaken", *args, "--vibration", "1.5", "--vibration-hz", "60")
    d = vectors(shaken, "/imu/data", "linear_acceleration") - vectors(calm, "/imu/data", "linear_acceleration")
    assert math.sqrt(float(np.mean(np.sum(d ** 2, axis=1)))) == pytest.approx(1.5, rel=0.05)
    spectrum = np.abs(np.fft.rfft(d - d.mean(axis=0), axis=0)).sum(axis=1)
    peak_hz = np.fft.rfftfreq(len(d), 1e-3)[int(np.argmax(spectrum))]
    assert peak_hz == pytest.approx(60.0, abs=1.0)
    g = vectors(shaken, "/imu/data", "angular_velocity") - vectors(calm, "/imu/data", "angular_velocity")
    assert 0.0 < float(np.abs(g).max()) < 0.1
    images = [topic for topic in calm if topic.endswith("image_raw")]
    assert images and all(np.array_equal(a.data, b.data) for topic in images
                          for (_, a), (_, b) in zip(calm[topic], shaken[topic]))


def test_an_imu_stamped_when_the_host_reads_it_trails_its_samples_in_order(tmp_path):
    """--imu-stamp-jitter-ms J: each sample is stamped (and recorded) up to J ms after it was taken, in arrival
    order, so above the sample period some come in batches of one stamp; the readings and the images are those
    of the recording stamped when taken."""
    args = ["--views", "2", "--hold-seconds", "0.4", "--rate", "5", "--resolution", "160x120", "--seed", "3",
            "--imu-rate", "500"]
    taken, _ = make(tmp_path, "taken", *args)
    read, _ = make(tmp_path, "read", *args, "--imu-stamp-jitter-ms", "6")
    t0 = np.array([stamp(m) for _, m in taken["/imu/data"]])
    t1 = np.array([stamp(m) for _, m in read["/imu/data"]])
    assert len(t0) == len(t1)
    late = (t1 - t0) * 1e-6
    assert late.min() >= 0.0 and late.max() <= 6.0 and late.mean() > 2.0
    assert np.all(np.diff(t1) >= 0) and np.any(np.diff(t1) == 0), "in order, some in batches"
    assert [t for t, _ in read["/imu/data"]] == t1.tolist()
    assert np.array_equal(vectors(taken, "/imu/data", "linear_acceleration"),
                          vectors(read, "/imu/data", "linear_acceleration"))


def test_an_imu_or_a_camera_on_its_own_clock_is_stamped_by_it_and_recorded_when_taken(tmp_path):
    """--imu-clock-start-s S: the IMU's stamps come from its own clock, which reads S at the first frame (a counter
    since power-on); the recorder receives each sample when it was taken, on the cameras' clock. The same for a
    camera (--camera-clock-start-s, one entry per camera, empty for the common clock). --unstamped: drivers
    that leave header.stamp at 0."""
    args = ["--views", "2", "--hold-seconds", "0.4", "--rate", "5", "--resolution", "160x120", "--seed", "3"]
    right, _ = make(tmp_path, "right", *args)
    own, _ = make(tmp_path, "own", *args, "--imu-clock-start-s", "1000.5")
    t0 = np.array([stamp(m) for _, m in right["/imu/data"]])
    t1 = np.array([stamp(m) for _, m in own["/imu/data"]])
    first_frame = stamp(right["/cam0/image_raw"][0][1])
    assert np.array_equal(t1 - t0, np.full(len(t0), 1_000_500_000_000 - first_frame))
    assert [t for t, _ in own["/imu/data"]] == t0.tolist()
    cams, _ = make(tmp_path, "cams", *args, "--camera-clock-start-s", ",2500")
    for topic, shift in (("/cam0/image_raw", 0), ("/cam1/image_raw", 2_500_000_000_000 - first_frame)):
        assert [stamp(m) - shift for _, m in cams[topic]] == [stamp(m) for _, m in right[topic]]
        assert [t for t, _ in cams[topic]] == [t for t, _ in right[topic]], "received on the common clock"
    unstamped, _ = make(tmp_path, "unstamped", *args, "--unstamped", "1,imu")
    for topic in ("/cam1/image_raw", "/cam1/camera_info", "/imu/data"):
        assert {stamp(m) for _, m in unstamped[topic]} == {0} and len(unstamped[topic]) == len(right[topic])
    assert [stamp(m) for _, m in unstamped["/cam0/image_raw"]] == [stamp(m) for _, m in right["/cam0/image_raw"]]


def test_an_imu_topic_with_gravity_taken_out_reads_about_zero_at_rest(tmp_path):
    """--imu-gravity-removed: a fused driver's linear acceleration, the specific force plus gravity (in the
    IMU's axes): about 0 at rest where the raw accelerometer reads gravity's size; the gyro is the same."""
    args = ["--views", "2", "--hold-seconds", "0.4", "--rate", "5", "--resolution", "160x120", "--seed", "3",
            "--imu-noise", "0", "--imu-bias", "0"]
    raw, _ = make(tmp_path, "raw", *args)
    linear, _ = make(tmp_path, "linear", *args, "--imu-gravity-removed")
    a, b = (vectors(m, "/imu/data", "linear_acceleration") for m in (raw, linear))
    assert np.linalg.norm(a[0]) == pytest.approx(9.81, abs=1e-6) and np.linalg.norm(b[0]) < 1e-6
    assert np.allclose(np.linalg.norm(a - b, axis=1), 9.81)
    assert np.array_equal(vectors(raw, "/imu/data", "angular_velocity"),
                          vectors(linear, "/imu/data", "angular_velocity"))


def test_a_rig_file_with_the_imu_axes_turned_keeps_the_bag_as_recorded(tmp_path):
    """--rig-imu-turn-deg writes the rig file's IMU rotation turned (a hand-written rig file with the axes wrong);
    the bag is the one recorded with the true axes."""
    from nrmpc_ros.core import load_rig
    from nrmpc_ros.core.so3 import exp_so3

    args = [*TINY, "--views", "2", "--capture", "snapshot", "--seed", "4"]
    assert main(["make-bag", *args, "--out", str(tmp_path / "a"), "--save-rig", str(tmp_path / "a.yaml")]) == 0
    assert main(["make-bag", *args, "--out", str(tmp_path / "b"), "--save-rig", str(tmp_path / "b.yaml"),
                 "--rig-imu-turn-deg", "180,0,0"]) == 0
    right, turned = load_rig(tmp_path / "a.yaml"), load_rig(tmp_path / "b.yaml")
    assert np.allclose(turned.imu.rotation, exp_so3(np.radians([180.0, 0.0, 0.0])) @ right.imu.rotation)
    from nrmpc_ros.bag.reader import BagReader

    def imu(path):
        with BagReader(path) as bag:
            return np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z,
                              m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                             for _, _, m in bag.messages(["/imu/data"])])

    recorded = imu(tmp_path / "a")
    assert len(recorded) > 100 and np.array_equal(recorded, imu(tmp_path / "b"))


def test_a_rig_file_calibrated_to_a_std_keeps_the_bag_as_recorded(tmp_path):
    """--rig-rotation-error-deg S writes each camera's rest rotation turned by a random turn of S deg per axis and
    says so (rotation_std_deg: S), the same turns for the same seed, --rig-position-error-m its rest position
    moved (position_std_m); the images are those of the true rig."""
    from nrmpc_ros.core import load_rig
    from nrmpc_ros.core.so3 import rotation_angle

    args = [*TINY, "--views", "2", "--capture", "snapshot", "--seed", "4"]
    off_flags = ["--rig-rotation-error-deg", "0.2", "--rig-position-error-m", "0.002"]
    for name, extra in (("a", []), ("b", off_flags), ("c", off_flags)):
        assert main(["make-bag", *args, "--out", str(tmp_path / name), "--save-rig", str(tmp_path / f"{name}.yaml"),
                     *extra]) == 0
    true, off, again = (load_rig(tmp_path / f"{n}.yaml") for n in "abc")
    turns = [math.degrees(rotation_angle(a.rotation.T @ b.rotation)) for a, b in zip(true.cameras, off.cameras)]
    assert all(0.0 < t < 1.0 for t in turns) and [c.rotation_std_deg for c in off.cameras] == [0.2, 0.2]
    assert all(np.array_equal(b.rotation, c.rotation) for b, c in zip(off.cameras, again.cameras))
    shifts = np.linalg.norm(off.positions - true.positions, axis=1)
    assert np.all((shifts > 0) & (shifts < 0.01)) and [c.position_std_m for c in off.cameras] == [0.002, 0.002]
    assert np.array_equal(off.positions, again.positions)
    assert true.cameras[0].rotation_std_deg == 0.0 and true.cameras[0].position_std_m == 0.0
    a, b = read_bag(tmp_path / "a")[0], read_bag(tmp_path / "b")[0]
    assert all(x.data.tobytes() == y.data.tobytes()
               for (_, x), (_, y) in zip(a["/cam0/image_raw"], b["/cam0/image_raw"]))


def test_an_imu_link_that_loses_samples_in_runs_keeps_the_others_as_recorded(tmp_path):
    """--imu-loss P --imu-loss-burst-ms B: about P of the IMU's samples are missing, in runs B ms long on average;
    every sample left is the one recorded without the loss (stamp and reading), and the images are untouched."""
    args = ["--views", "3", "--hold-seconds", "1.0", "--rate", "5", "--resolution", "160x120", "--seed", "3",
            "--imu-rate", "1000"]
    whole, _ = make(tmp_path, "whole", *args)
    lossy, _ = make(tmp_path, "lossy", *args, "--imu-loss", "0.1", "--imu-loss-burst-ms", "20")
    t_whole = np.array([stamp(m) for _, m in whole["/imu/data"]])
    t_lossy = np.array([stamp(m) for _, m in lossy["/imu/data"]])
    kept = np.isin(t_whole, t_lossy)
    assert kept.sum() == len(t_lossy) and 0.03 < 1.0 - kept.mean() < 0.25
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[1], kept.astype(int), [1]]))))[::2]  # lost runs
    assert 5 < runs.mean() < 60, "runs of about 20 samples at 1 kHz"
    for attr in ("linear_acceleration", "angular_velocity"):
        assert np.array_equal(vectors(whole, "/imu/data", attr)[kept], vectors(lossy, "/imu/data", attr))
    images = [topic for topic in whole if topic.endswith("image_raw")]
    assert images and all(np.array_equal(a.data, b.data) for topic in images
                          for (_, a), (_, b) in zip(whole[topic], lossy[topic]))


def test_a_shutter_time_blurs_the_moving_images_only(tmp_path):
    """--shutter-ms S: an image integrates the scene over S ms from its stamp; in a still hold it is the image an
    instant shutter takes, during a move it is smoothed along the motion (less detail: a smaller mean gradient)."""
    from nrmpc_ros.bag.reader import BagReader

    args = ["--views", "2", "--hold-seconds", "0.6", "--move-seconds", "0.6", "--rate", "10", "--capture", "stream",
            "--resolution", "160x120", "--seed", "2", "--image-noise", "0", "--imu-rate", "100"]
    instant, _ = make(tmp_path, "instant", *args)
    blurred, _ = make(tmp_path, "blurred", *args, "--shutter-ms", "40")
    with BagReader(tmp_path / "instant") as bag:
        moving = [float(np.linalg.norm([m.vector.x, m.vector.y, m.vector.z])) > 1e-6
                  for _, _, m in bag.messages(["/ground_truth/angular_velocity"])]
    still = [not (a or b) for a, b in zip(moving, moving[1:] + [False])]  # through the shutter (40 of 100 ms)
    sharp, detail = 0, np.zeros(2)
    for quiet, (_, a), (_, b) in zip(still, instant["/cam0/image_raw"], blurred["/cam0/image_raw"]):
        ia = np.frombuffer(a.data, np.uint8).reshape(120, 160).astype(float)
        ib = np.frombuffer(b.data, np.uint8).reshape(120, 160).astype(float)
        if quiet:
            assert np.abs(ia - ib).max() <= 1.0, "a still image is the instant's"
            sharp += 1
        else:
            detail += [np.abs(np.diff(i, axis=1)).mean() + np.abs(np.diff(i, axis=0)).mean() for i in (ia, ib)]
    assert sharp >= 8 and detail[1] < 0.95 * detail[0], detail


def test_someone_walking_changes_the_still_images_only_where_they_are_seen(tmp_path):
    """--walker-speed V: a person-sized box walks through the room; in a still hold the images change from frame
    to frame only where a camera sees the walker, and the rig's ground truth and IMU are those of the same recording
    without it."""
    args = ["--cameras", "4", "--layout", "cross", "--views", "2", "--hold-seconds", "1", "--rate", "10", "--seed",
            "0", *QUIET]
    nobody, _ = make(tmp_path, "nobody", *args)
    walking, _ = make(tmp_path, "walking", *args, "--walker-speed", "1.2")
    for topic in ("/ground_truth/pose", "/ground_truth/gravity", "/imu/data", "/cam0/image_raw"):
        assert [t for t, _ in nobody[topic]] == [t for t, _ in walking[topic]], topic
    assert np.array_equal(vectors(nobody, "/ground_truth/gravity", "vector"),
                          vectors(walking, "/ground_truth/gravity", "vector"))
    assert np.array_equal(vectors(nobody, "/imu/data", "linear_acceleration"),
                          vectors(walking, "/imu/data", "linear_acceleration"))
    changed = {}
    for c in range(4):
        frames = [np.frombuffer(m.data, np.uint8).reshape(120, 160).astype(float)
                  for _, m in walking[f"/cam{c}/image_raw"]]
        still = [np.frombuffer(m.data, np.uint8).reshape(120, 160).astype(float)
                 for _, m in nobody[f"/cam{c}/image_raw"]]
        hold = frames[:10]  # the first hold's ten frames: the rig does not move
        assert all(np.array_equal(still[0], s) for s in still[1:10]), "without the walker still images repeat"
        changed[c] = max(float(np.mean(np.abs(a - b) > 10)) for a, b in zip(hold, hold[1:]))
    seen = [c for c, share in changed.items() if share > 0.01]
    assert seen and len(seen) < 4, changed  # some camera sees the walker move, not every camera

