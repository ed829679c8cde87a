import math
from dataclasses import replace

import numpy as np
import pytest

from nrmpc_ros.core import (
    deformed_extrinsics,
    gravity_from_accelerometer,
    gravity_from_camera,
    plucker_lines,
    rays,
)
from nrmpc_ros.core.deformation import deformation_jacobians
from nrmpc_ros.core.rig import ImuMount
from nrmpc_ros.core.so3 import angle_between, exp_so3, log_so3, quat_xyzw_to_matrix
from nrmpc_ros.errors import InputError

G_DOWN = np.array([0.0, 0.0, -9.81])


def test_hand_computed_tip_displacement_and_rotation(cross_rig):
    # camera 0 at v = (0.4, 0, 0), m = 0.1 kg, EI = 0.1 N m^2, gravity straight down
    w, W = deformed_extrinsics(cross_rig, G_DOWN)
    delta = 0.1 * 0.4**3 / (3 * 0.1) * -9.81  # m L^3 / (3 EI) |g|
    theta = 0.1 * 0.4**2 / (2 * 0.1) * 9.81  # m L^2 / (2 EI) |g|
    assert np.allclose(w[0], [0.4, 0.0, delta], atol=1e-12)
    expected = exp_so3(np.array([0.0, theta, 0.0])) @ cross_rig.rotations[0]
    assert np.allclose(W[0], expected, atol=1e-12)
    # the tip droops: the optical axis (+x) turns towards -z
    assert W[0][2, 2] < 0 and math.isclose(W[0][2, 2], -math.sin(theta), rel_tol=1e-12)


def test_axial_load_is_ignored(cross_rig):
    w, W = deformed_extrinsics(cross_rig, np.array([9.81, 0.0, 0.0]))
    assert np.allclose(w[0], cross_rig.positions[0]) and np.allclose(W[0], cross_rig.rotations[0])
    assert not np.allclose(w[1], cross_rig.positions[1])  # camera 1 (on y) bends sideways


def test_rigid_limit(cross_rig):
    rigid = cross_rig.as_rigid()
    w, W = deformed_extrinsics(rigid, G_DOWN)
    assert np.array_equal(w, rigid.positions) and np.allclose(W, rigid.rotations)
    stiff = replace(cross_rig, cameras=tuple(replace(c, EI=1e9) for c in cross_rig.cameras))
    w2, W2 = deformed_extrinsics(stiff, G_DOWN)
    assert np.abs(w2 - stiff.positions).max() < 1e-9 and np.abs(W2 - stiff.rotations).max() < 1e-8


def test_small_load_linearity(cross_rig, rng):
    g = rng.normal(size=3) * 1e-3
    w1, W1 = deformed_extrinsics(cross_rig, g)
    w2, W2 = deformed_extrinsics(cross_rig, 2 * g)
    d1, d2 = w1 - cross_rig.positions, w2 - cross_rig.positions
    assert np.allclose(d2, 2 * d1, rtol=1e-12, atol=1e-18)
    r1 = log_so3(W1 @ np.swapaxes(cross_rig.rotations, 1, 2))
    r2 = log_so3(W2 @ np.swapaxes(cross_rig.rotations, 1, 2))
    assert np.allclose(r2, 2 * r1, rtol=1e-9, atol=1e-15)


def test_depends_only_on_spec_inputs(cross_rig, rng):
    g = rng.normal(size=3) * 5
    w, W = deformed_extrinsics(cross_rig, g)
    other = replace(cross_rig, cameras=tuple(
        replace(c, name=c.name + "x", intrinsics=(1, 2, 3, 4), image_topic="/x", resolution=(10, 10))
        for c in cross_rig.cameras))
    w2, W2 = deformed_extrinsics(other, g)
    assert np.array_equal(w, w2) and np.array_equal(W, W2)
    # a camera's bending does not depend on the other cameras
    single = replace(cross_rig, cameras=cross_rig.cameras[2:3])
    w3, W3 = deformed_extrinsics(single, g)
    assert np.allclose(w3[0], w[2]) and np.allclose(W3[0], W[2])


def test_batch_equals_single(cross_rig, rng):
    gs = rng.normal(size=(7, 3)) * 9.81
    wb, Wb = deformed_extrinsics(cross_rig, gs)
    assert wb.shape == (7, 4, 3) and Wb.shape == (7, 4, 3, 3)
    for k in range(7):
        w, W = deformed_extrinsics(cross_rig, gs[k])
        assert np.allclose(w, wb[k]) and np.allclose(W, Wb[k])


def test_model_jacobians_match_finite_differences(cross_rig, rng):
    g = rng.normal(size=3) * 5
    y = rng.normal(size=3)
    w, W, D, K = deformation_jacobians(cross_rig, g)
    eps = 1e-6
    for k in range(3):
        dg = np.zeros(3)
        dg[k] = eps
        wp, Wp = deformed_extrinsics(cross_rig, g + dg)
        wm, Wm = deformed_extrinsics(cross_rig, g - dg)
        assert np.allclose((wp - wm) / (2 * eps), D[:, :, k], atol=1e-8)
        num = (np.swapaxes(Wp, 1, 2) @ y - np.swapaxes(Wm, 1, 2) @ y) / (2 * eps)
        ana = np.einsum("mji,mj->mi", W, (_skew(y) @ K)[:, :, k])
        assert np.allclose(num, ana, atol=1e-7)


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def test_plucker_lines_contain_the_camera_centre(cross_rig, rng):
    f = rng.normal(size=(10, 3))
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    cam = rng.integers(0, 4, size=10)
    lines = plucker_lines(cross_rig, f, cam, G_DOWN)
    o, d = rays(cross_rig, f, cam, G_DOWN)
    assert np.allclose(np.linalg.norm(lines[:, :3], axis=1), 1.0)
    assert np.allclose(np.sum(lines[:, :3] * lines[:, 3:], axis=1), 0.0, atol=1e-12)
    assert np.allclose(np.cross(o + 2.5 * d, lines[:, :3]), lines[:, 3:])


def test_gravity_from_camera_inverts_the_model(cross_rig, rng):
    for _ in range(5):
        g = 9.81 * rng.normal(size=3) / 1.0
        g = 9.81 * g / np.linalg.norm(g)
        _, W = deformed_extrinsics(cross_rig, g)
        g_cam = W[1].T @ g * 0.37  # only the direction counts
        est = gravity_from_camera(cross_rig, 1, g_cam)
        assert angle_between(est, g) < 1e-10 and math.isclose(np.linalg.norm(est), 9.81)
    rigid = cross_rig.as_rigid()
    assert np.allclose(gravity_from_camera(rigid, 0, [0, 1, 0]), rigid.rotations[0] @ [0, 9.81, 0])
    with pytest.raises(InputError, match="g_cam"):
        gravity_from_camera(cross_rig, 0, [np.nan, 0, 1])


def test_gravity_from_accelerometer_body_and_camera_mounts(cross_rig):
    level = gravity_from_accelerometer(cross_rig, [0.0, 0.0, 9.7])  # a level IMU reads +z
    assert np.allclose(level, G_DOWN)
    R_body_imu = quat_xyzw_to_matrix([0, 0, 1, 0])  # IMU yawed by 180 deg
    rig = replace(cross_rig, imu=ImuMount(mount="body", rotation=R_body_imu))
    assert np.allclose(gravity_from_accelerometer(rig, [0.0, 0.0, 9.81]), G_DOWN)
    g = np.array([1.0, -2.0, -9.0])
    g = 9.81 * g / np.linalg.norm(g)
    _, W = deformed_extrinsics(cross_rig, g)
    in_cam = replace(cross_rig, imu=ImuMount(mount="cam2", rotation=np.eye(3)))
    est = gravity_from_accelerometer(in_cam, -(W[2].T @ g))
    assert angle_between(est, g) < 1e-10
    with pytest.raises(InputError, match="linear_acceleration"):
        gravity_from_accelerometer(cross_rig, [np.nan, 0, 9.8])
    with pytest.raises(InputError, match="imu"):
        gravity_from_accelerometer(replace(cross_rig, imu=None), [0, 0, 9.8])
