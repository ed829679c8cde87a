"""Roll, pitch and the level frame from gravity; angular covariance of a gravity direction."""

from __future__ import annotations

import math

import numpy as np

from nrmpc_ros.core.attitude import leveling_rotation, roll_pitch_from_gravity, roll_pitch_jacobian, tangent_covariance
from nrmpc_ros.core.so3 import exp_so3, normalize, quat_xyzw_to_matrix, tangent_basis


def test_level_body_has_zero_roll_and_pitch():
    r, p, q, cov = roll_pitch_from_gravity(np.array([0, 0, -9.81]), np.eye(2) * 1e-4)
    assert abs(r) < 1e-12 and abs(p) < 1e-12 and np.allclose(q, [0, 0, 0, 1])
    assert np.allclose(np.diag(cov), 1e-4, rtol=1e-9)


def test_pitched_and_rolled_bodies():
    # nose up by 0.2 rad (a rotation about body y by -0.2): gravity gains a -x component; roll stays 0
    g_body = exp_so3(np.array([0.0, -0.2, 0.0])).T @ np.array([0, 0, -9.81])
    r, p, _, _ = roll_pitch_from_gravity(g_body)
    assert abs(r) < 1e-12 and math.isclose(abs(p), 0.2, rel_tol=1e-9)
    g_body = exp_so3(np.array([0.3, 0.0, 0.0])).T @ np.array([0, 0, -9.81])
    r, p, _, _ = roll_pitch_from_gravity(g_body)
    assert math.isclose(r, 0.3, rel_tol=1e-9) and abs(p) < 1e-12


def test_leveling_rotation_puts_gravity_down_and_keeps_the_heading():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R_world_body = exp_so3(rng.normal(scale=0.6, size=3))
        g_body = R_world_body.T @ np.array([0, 0, -9.81])
        R = leveling_rotation(g_body)
        assert np.allclose(R @ g_body, [0, 0, -9.81], atol=1e-9)
        # the level frame's x axis is the body's x axis projected on the horizontal plane
        x_level = R @ np.array([1.0, 0.0, 0.0])
        assert abs(x_level[1]) < 1e-9 and x_level[0] > 0
        _, _, q, _ = roll_pitch_from_gravity(g_body)
        assert np.allclose(quat_xyzw_to_matrix(q), R, atol=1e-12)


def test_covariance_follows_the_jacobian_of_roll_and_pitch():
    """The analytic Jacobian equals central differences along the tangent chart of gravity's direction."""
    rng = np.random.default_rng(1)
    for _ in range(10):
        g = normalize(rng.normal(size=3) + np.array([0, 0, -2.0])) * 9.81
        n, B = normalize(g), tangent_basis(normalize(g))
        eps = 1e-6
        num = np.zeros((2, 2))
        for k in range(2):
            d = np.zeros(2)
            d[k] = eps
            rp = np.array(roll_pitch_from_gravity(n + B @ d)[:2])
            rm = np.array(roll_pitch_from_gravity(n - B @ d)[:2])
            num[:, k] = (rp - rm) / (2 * eps)
        assert np.allclose(roll_pitch_jacobian(g), num, atol=1e-6)
        C = np.diag([4e-6, 1e-6])
        _, _, _, cov = roll_pitch_from_gravity(g, C)
        J = roll_pitch_jacobian(g)
        assert np.allclose(cov, J @ C @ J.T) and np.all(np.linalg.eigvalsh(cov) > 0)


def test_tangent_covariance_of_an_isotropic_vector_covariance():
    g = np.array([1.0, -2.0, -9.0])
    sigma = 0.02  # m/s^2 per axis
    cov = tangent_covariance(g, sigma**2 * np.eye(3))
    assert np.allclose(cov, (sigma / np.linalg.norm(g)) ** 2 * np.eye(2))
    # a covariance along gravity itself (its norm) carries no angular uncertainty
    n = normalize(g)
    assert np.allclose(tangent_covariance(g, np.outer(n, n)), 0, atol=1e-15)
