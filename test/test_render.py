"""Rendered bags' ingredients: the ray caster (pixels see the right world points, texture), the trajectory
(move profiles, capture modes) and the bars' loads (quasi-static or ringing)."""

import math

import cv2
import numpy as np
import pytest

from nrmpc_ros.cameras import bearings_to_pixels
from nrmpc_ros.core import deformed_extrinsics
from nrmpc_ros.core.dynamics import bar_natural_frequencies
from nrmpc_ros.core.rig import Camera, Rig
from nrmpc_ros.core.so3 import exp_so3, log_so3
from nrmpc_ros.render import Renderer, cast_rays, contains, make_scene, shade
from nrmpc_ros.render.bars import CameraLoads, bent_extrinsics
from nrmpc_ros.render.scene import BOXES, WALKER, WALKER_LANE_X, walker_offset, with_box_moved
from nrmpc_ros.render.sequence import PROFILES, MotionOptions, make_trajectory, move_profile
from nrmpc_ros.sim.synthetic import RigSpec, make_rig


@pytest.fixture(scope="module")
def scene():
    return make_scene(seed=3)


def _fisheye_rig():
    base = make_rig(RigSpec(num_cameras=2, layout="line", focal=470.0, EI=0.2))
    fish = Camera(name="fish", model="equidistant", intrinsics=(300.0, 301.0, 330.0, 236.0),
                  distortion=(0.02, -0.01, 0.003, -0.001), resolution=(640, 480), position=np.array([0.0, 0.0, 0.3]),
                  rotation=base.cameras[0].rotation, mass=0.1, EI=0.3)
    return Rig(cameras=base.cameras + (fish,))


def _slab_hit(o, d, lo, hi):
    """Reference: entry distance of one ray into one box (inf when missed), plain scalar code."""
    t0, t1 = -math.inf, math.inf
    for a in range(3):
        if abs(d[a]) < 1e-15:
            if not lo[a] <= o[a] <= hi[a]:
                return math.inf
            continue
        ta, tb = sorted(((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]))
        t0, t1 = max(t0, ta), min(t1, tb)
    return t0 if t0 <= t1 and t0 > 0 else math.inf


def test_cast_rays_matches_scalar_reference(scene):
    rng = np.random.default_rng(0)
    o = np.array([0.1, -0.2, 0.3])
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, face = cast_rays(scene, o, d)
    for k in range(len(d)):
        exits = [((scene.hi[0, a] if d[k, a] > 0 else scene.lo[0, a]) - o[a]) / d[k, a] for a in range(3)]
        expected = min([min(exits)] + [_slab_hit(o, d[k], scene.lo[b], scene.hi[b]) for b in range(1, len(scene.lo))])
        assert t[k] == pytest.approx(expected, rel=1e-5, abs=1e-5)
    # The hit point lies on the plane of the reported face.
    p = o + t[:, None] * d
    box, rem = np.divmod(face, 6)
    axis, side = np.divmod(rem, 2)
    plane = np.where(side == 1, scene.hi[box, axis], scene.lo[box, axis])
    assert np.allclose(p[np.arange(len(p)), axis], plane, atol=1e-4)
    assert set(np.unique(box)) != {0}, "some random rays should hit the boxes inside the room"


def test_principal_rays_hit_known_walls(scene):
    t, face = cast_rays(scene, np.zeros(3), np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 0, 1.0], [-1.0, 0, 0]]))
    assert t == pytest.approx([3.4, 1.3, 2.2, 3.0], abs=1e-5)
    assert face.tolist() == [1, 4, 5, 0]  # room: +x wall, floor, ceiling, -x wall


@pytest.mark.parametrize("cam_index", [0, 2])
def test_rendered_pixels_see_the_right_world_points(scene, cam_index):
    """A pixel's world point, projected through the BENT camera pose, lands back on that pixel."""
    rig = _fisheye_rig()
    r = Renderer(rig, scene)
    R_wb = exp_so3(np.array([0.2, -0.3, 0.5]))
    p_wb = np.array([0.1, 0.05, -0.1])
    g = R_wb.T @ np.array([0.0, 0.0, -9.81])
    Rs, cs = r.camera_poses(R_wb, p_wb, g)
    w, W = deformed_extrinsics(rig, g)
    assert np.allclose(Rs[cam_index], R_wb @ W[cam_index]) and np.allclose(cs[cam_index], R_wb @ w[cam_index] + p_wb)
    img, pts = r.render_camera(cam_index, Rs[cam_index], cs[cam_index], return_points=True)
    cam = rig.cameras[cam_index]
    assert img.shape == (cam.resolution[1], cam.resolution[0])
    rng = np.random.default_rng(1)
    idx = rng.choice(len(pts), 500, replace=False)
    f = (pts[idx] - cs[cam_index]) @ Rs[cam_index]  # world -> camera frame
    uv = bearings_to_pixels(cam, f)
    expected = np.stack([idx % cam.resolution[0], idx // cam.resolution[0]], axis=1)
    assert np.abs(uv - expected).max() < 0.05
    assert np.all(contains(scene, cs)), "cameras must be inside the free space of the room"


def test_pixel_values_are_the_texture_at_the_hit(scene):
    rig = make_rig(RigSpec(focal=470.0, EI=0.2))
    r = Renderer(rig, scene)
    Rs, cs = r.camera_poses(np.eye(3), np.zeros(3), np.array([0.0, 0.0, -9.81]))
    img, pts = r.render_camera(1, Rs[1], cs[1], return_points=True)
    d = r.bearings(1) @ Rs[1].T.astype(np.float32)
    _, face = cast_rays(scene, cs[1], d)
    assert np.allclose(img.ravel(), shade(scene, pts, face), atol=1e-3)


def test_bending_changes_the_images(scene):
    rig = make_rig(RigSpec(focal=470.0, EI=0.2))
    r = Renderer(rig, scene)
    g = np.array([0.0, 0.0, -9.81])
    bent = r.render_rig(np.eye(3), np.zeros(3), g)
    rigid = r.render_rig(np.eye(3), np.zeros(3), None)
    assert all(np.mean(np.abs(a - b)) > 10.0 for a, b in zip(bent, rigid))
    # The rigid rig renders identically whatever the load.
    rr = Renderer(rig.as_rigid(), scene)
    assert np.array_equal(rr.render_rig(np.eye(3), np.zeros(3), g)[0], rigid[0])


def test_images_are_richly_textured(scene):
    rig = make_rig(RigSpec(focal=470.0, EI=0.2))
    images = Renderer(rig, scene).render_rig(exp_so3(np.array([0.3, 0.1, 0.7])), np.zeros(3),
                                             np.array([1.0, -2.0, -9.5]))
    orb = cv2.ORB_create(2000)
    for img in images:
        u8 = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        corners = cv2.goodFeaturesToTrack(u8, 2000, 0.01, 7)
        assert corners is not None and len(corners) > 400
        # spread over the image: every quadrant has corners
        c = corners.reshape(-1, 2)
        for qx in (c[:, 0] < 320, c[:, 0] >= 320):
            for qy in (c[:, 1] < 240, c[:, 1] >= 240):
                assert np.count_nonzero(qx & qy) > 40
        assert len(orb.detect(u8, None)) > 1000
        assert u8.std() > 30


def test_scene_is_deterministic_per_seed():
    a, b, c = make_scene(seed=5), make_scene(seed=5), make_scene(seed=6)
    assert np.array_equal(a.atlas, b.atlas)
    assert not np.array_equal(a.atlas, c.atlas)


def test_the_walker_walks_its_lane_at_its_speed_and_carries_its_texture():
    """A person walks back and forth along the lane at the speed, from its middle; the moved box's faces carry
    their texture with it, and nothing else moves."""
    t = np.linspace(0.0, 20.0, 20001)
    x = walker_offset(t, 1.5)
    assert np.allclose(x[:, 1:], 0.0) and x[0, 0] == pytest.approx(0.5 * sum(WALKER_LANE_X))
    assert x[:, 0].min() == pytest.approx(WALKER_LANE_X[0], abs=2e-3)
    assert x[:, 0].max() == pytest.approx(WALKER_LANE_X[1], abs=2e-3)
    speed = np.abs(np.diff(x[:, 0])) / np.diff(t)
    assert np.median(speed) == pytest.approx(1.5) and speed.max() <= 1.5 + 1e-9
    scene = make_scene(seed=1, boxes=BOXES + (WALKER,))
    moved = with_box_moved(scene, scene.num_boxes - 1, [0.7, 0.0, 0.0])
    face = 6 * (scene.num_boxes - 1) + 2 * 1 + 0  # the walker's face towards -y, which the rig sees
    pts = np.stack([np.linspace(-0.2, 0.2, 50), np.full(50, WALKER[0][1]), np.linspace(-1.2, 0.4, 50)], axis=1)
    assert np.allclose(shade(moved, pts + [0.7, 0.0, 0.0], np.full(50, face)),
                       shade(scene, pts, np.full(50, face)), atol=1e-3)
    assert np.array_equal(moved.lo[:-1], scene.lo[:-1]), "only the walker moves"


# -- trajectories: move profiles, capture modes ---------------------------------------------------------------

@pytest.mark.parametrize("profile", PROFILES)
def test_move_profiles_and_their_derivatives(profile):
    tau = np.linspace(0.0, 1.0, 20001)
    s, ds, dds = move_profile(profile, tau, accel_fraction=0.2)
    assert s[0] == pytest.approx(0.0, abs=1e-15) and s[-1] == pytest.approx(1.0, abs=1e-12)
    assert ds[0] == pytest.approx(0.0, abs=1e-12) and ds[-1] == pytest.approx(0.0, abs=1e-12), "still at both ends"
    h = tau[1] - tau[0]
    assert np.allclose(np.gradient(s, h)[1:-1], ds[1:-1], atol=1e-3)
    inner = slice(1, -1)
    jumps = np.abs(np.diff(dds))
    if profile == "min-jerk":
        assert s == pytest.approx(10 * tau**3 - 15 * tau**4 + 6 * tau**5)
        assert abs(dds[0]) < 1e-12 and abs(dds[-1]) < 1e-12 and jumps.max() < 0.01, "acceleration continuous"
        assert np.allclose(np.gradient(ds, h)[inner], dds[inner], atol=1e-3)
    elif profile == "trapezoid":
        A = 1 / (0.2 * 0.8)
        assert set(np.round(np.unique(np.round(dds, 9)), 6)) == {round(A, 6), 0.0, round(-A, 6)}, "three levels"
        assert np.count_nonzero(jumps > 1.0) == 2 and jumps.max() == pytest.approx(A), "two steps inside the move"
        assert ds.max() == pytest.approx(1 / 0.8), "peak speed of a trapezoid covering s = 1"
    else:
        assert dds[0] == pytest.approx(np.pi**2 / 2) and jumps.max() < 0.01


@pytest.mark.parametrize("profile", PROFILES)
def test_trajectory_rates_are_the_exact_derivatives(profile):
    """omega (body) and the world acceleration of state() are the derivatives of the pose it returns."""
    opts = MotionOptions(views=3, hold_seconds=0.5, move_seconds=0.8, move_profile=profile, accel_fraction=0.3)
    traj = make_trajectory(np.random.default_rng(4), opts)
    t = np.linspace(traj.start_ns + 1, traj.end_ns - 3_000_000, 300).astype(np.int64)
    h = 100_000  # 0.1 ms
    R0, p0, w0, a0 = traj.state(t)
    R1, p1, _, _ = traj.state(t + h)
    Rm, pm, wm, _ = traj.state(t - h)
    w_num = log_so3(np.einsum("nji,njk->nik", Rm, R1)) / (2 * h * 1e-9)
    assert np.abs(w_num - w0).max() < 2e-3
    a_num = (p1 - 2 * p0 + pm) / (h * 1e-9) ** 2
    smooth = np.abs(a_num - a0).max(axis=1) < 1e-2
    assert smooth.mean() > 0.97  # all but the samples straddling a trapezoid's acceleration step
    assert np.allclose(w0[traj.view_index(t) >= 0], 0.0) and np.allclose(a0[traj.view_index(t) >= 0], 0.0)
    # The moves turn the body from one hold's attitude to the next.
    R_end, _, _, _ = traj.state(traj.hold_start)
    assert np.allclose(R_end, traj.R, atol=1e-12)


def test_capture_modes_trigger_times():
    traj = make_trajectory(np.random.default_rng(1), MotionOptions(views=3, hold_seconds=2.0, move_seconds=0.5))
    snap, view = traj.frame_times("snapshot")
    assert np.all(np.diff(snap) == 2_500_000_000), "holds of 2 s and moves of 0.5 s"
    assert view.tolist() == [0, 1, 2] and np.all(snap == traj.hold_end - traj.period_ns)
    holds, hv = traj.frame_times("holds")
    assert len(holds) == 3 * 20 and np.all(traj.view_index(holds) == hv)
    stream, sv = traj.frame_times("stream")
    assert len(stream) == 70 and np.all(np.diff(stream) == 100_000_000) and np.count_nonzero(sv < 0) == 10
    assert set(holds) <= set(stream) and set(snap) <= set(holds)


# -- bar loads: quasi-static or ringing ---------------------------------------------------------------------

def _stiff_rig():
    return make_rig(RigSpec(num_cameras=2, layout="line", EI=2.0, mass=0.1, focal=100.0, resolution=(160, 120)))


def test_without_damping_the_load_is_quasi_static():
    rig = _stiff_rig()
    traj = make_trajectory(np.random.default_rng(2), MotionOptions(views=2, hold_seconds=0.5))
    loads = CameraLoads(rig, traj)
    t = np.linspace(traj.start_ns, traj.end_ns - 1, 97).astype(np.int64)
    R, _, omega, acc = traj.state(t)
    assert not loads.ringing and loads.settle_times_ns() is None
    v = rig.positions[None]
    alpha, w = traj.angular_acceleration(t)[:, None], omega[:, None]
    tip = traj.load_body(R, acc)[:, None] - np.cross(alpha, v) - np.cross(w, np.cross(w, v))  # docs: rig in motion
    assert np.allclose(loads.at(t), tip, rtol=0, atol=1e-12)
    still = traj.view_index(t) >= 0
    assert np.array_equal(loads.at(t[still]), np.broadcast_to(traj.gravity_body(R[still])[:, None],
                                                              (still.sum(), 2, 3)))


@pytest.mark.parametrize("profile", ["cosine", "trapezoid"])
def test_ringing_after_a_move_has_the_bar_frequency_and_damping(profile):
    """After the move stops the load oscillates about gravity at the bar's (damped) natural frequency, decays
    with the damping ratio (log decrement), and has decayed to 1e-3 at the reported settle time."""
    rig, zeta = _stiff_rig(), 0.03
    f = bar_natural_frequencies(rig)[0]
    assert f == pytest.approx(math.sqrt(3 * 2.0 / (0.1 * 0.4**3)) / (2 * math.pi))
    traj = make_trajectory(np.random.default_rng(0), MotionOptions(views=2, hold_seconds=8, move_seconds=0.5,
                                                                   move_profile=profile))
    loads = CameraLoads(rig, traj, damping=zeta)
    t0 = int(traj.hold_start[1])
    t = t0 + np.arange(0, 3_000_000_000, 200_000)
    x, v, u = loads.state(t)
    assert np.allclose(u, traj.gravity_body(traj.R[1:2]))  # still: the quasi-static load is gravity
    dev = x[:, 0] - u[:, 0]
    y = dev[:, np.argmax(np.abs(dev).max(axis=0))]
    assert np.abs(y).max() > 0.1, "the move excites the bar"
    sign = np.signbit(y)
    k = np.flatnonzero(sign[1:] != sign[:-1])
    crossings = (t[k] + (t[k + 1] - t[k]) * y[k] / (y[k] - y[k + 1])) * 1e-9
    period = 2 * np.mean(np.diff(crossings))
    assert period == pytest.approx(1 / (f * math.sqrt(1 - zeta**2)), rel=1e-3)
    peaks = np.array([np.abs(y[a:b]).max() for a, b in zip(k[:-1], k[1:])])  # one extreme per half cycle
    log_decrement = 2 * np.mean(np.log(peaks[:-1] / peaks[1:]))
    assert log_decrement / math.sqrt(4 * math.pi**2 + log_decrement**2) == pytest.approx(zeta, rel=0.02)
    # Amplitude of the free oscillation, sqrt(y^2 + ((y' + sigma y) / w_d)^2), at the hold start and settle time.
    w, wd = 2 * math.pi * f, 2 * math.pi * f * math.sqrt(1 - zeta**2)
    settled = loads.settle_times_ns()
    assert settled[0] == traj.hold_start[0] and settled[1] - t0 == pytest.approx(
        math.log(1e3) / (zeta * w) * 1e9, abs=1)
    xs, vs, us = loads.state(np.array([t0, settled[1]]))
    amp = np.linalg.norm(np.hypot(xs[:, 0] - us[:, 0], (vs[:, 0] + zeta * w * (xs[:, 0] - us[:, 0])) / wd), axis=1)
    assert amp[1] / amp[0] == pytest.approx(1e-3, rel=1e-3)
    # The bars start at rest: the first hold is still.
    x0, v0, u0 = loads.state(np.array([traj.start_ns, traj.hold_end[0] - 1]))
    assert np.allclose(x0, u0, atol=1e-12) and np.allclose(v0, 0.0, atol=1e-12)


def test_each_camera_renders_at_its_own_load(scene):
    rig = make_rig(RigSpec(num_cameras=3, layout="ring", focal=120.0, EI=0.2, resolution=(160, 120)))
    r = Renderer(rig, scene)
    R_wb = exp_so3(np.array([0.1, -0.2, 0.4]))
    g = R_wb.T @ np.array([0.0, 0.0, -9.81])
    loads = g + np.array([[0.0, 0.0, 0.0], [2.0, -1.0, 0.5], [-3.0, 0.0, 1.0]])
    images = r.render_rig(R_wb, np.zeros(3), loads)
    w, W = bent_extrinsics(rig, loads)
    for i in range(3):
        assert np.array_equal(images[i], r.render_rig(R_wb, np.zeros(3), loads[i])[i])
        w_i, W_i = deformed_extrinsics(rig, loads[i])
        assert np.allclose(w[i], w_i[i]) and np.allclose(W[i], W_i[i])
    assert np.array_equal(images[0], r.render_rig(R_wb, np.zeros(3), g)[0])
    assert np.abs(images[1] - r.render_rig(R_wb, np.zeros(3), g)[1]).mean() > 5.0
