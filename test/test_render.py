"""The ray caster of rendered bags: geometry (pixels see the right world points) and texture (issue 4)."""

import math

import cv2
import numpy as np
import pytest

from nrmpc_ros.cameras import bearings_to_pixels
from nrmpc_ros.core import deformed_extrinsics
from nrmpc_ros.core.rig import Camera, Rig
from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.render import Renderer, cast_rays, contains, make_scene, shade
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
