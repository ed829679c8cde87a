"""Roll and pitch of the body from gravity in its frame, with their covariance (the rig as a "passive IMU").

Body axes follow REP-103 (x forward, y left, z up): a level body sees gravity
(0, 0, -|g|). The level frame keeps the body's heading (yaw 0) and has z up;
``R_level`` maps body vectors into it, so ``R_level g = (0, 0, -|g|)``. Yaw
is unobservable from gravity. Angles are in radians, gravity in m/s^2.

A direction's angular covariance lives in the chart of
:func:`~nrmpc_ros.core.so3.tangent_basis`: the unit vector n moves to
n + B d for small tangent coordinates d (rad), B = tangent_basis(n).
"""

from __future__ import annotations

import math

import numpy as np

from .so3 import exp_so3, matrix_to_quat_xyzw, normalize, tangent_basis


def tangent_covariance(g: np.ndarray, cov_g: np.ndarray) -> np.ndarray:
    """2x2 angular covariance (rad^2) of the direction of gravity ``g`` from its 3x3 covariance (m^2/s^4).

    A displacement dg of the vector turns its direction by B^T dg / |g| (B = tangent_basis(g)).
    """
    g = np.asarray(g, dtype=float)
    B = tangent_basis(normalize(g)) / np.linalg.norm(g)
    return B.T @ np.asarray(cov_g, dtype=float) @ B


def leveling_rotation(gravity: np.ndarray) -> np.ndarray:
    """R_level = R_y(pitch) R_x(roll): body vectors -> the level frame of the same heading (z up)."""
    roll, pitch = _roll_pitch(normalize(np.asarray(gravity, dtype=float)))
    return exp_so3(np.array([0.0, pitch, 0.0])) @ exp_so3(np.array([roll, 0.0, 0.0]))


def _roll_pitch(n: np.ndarray) -> tuple:
    gx, gy, gz = (float(v) for v in n)
    return math.atan2(-gy, -gz), math.atan2(gx, math.hypot(gy, gz))


def roll_pitch_jacobian(gravity: np.ndarray) -> np.ndarray:
    """2x2 derivative of (roll, pitch) by the tangent coordinates of gravity's direction (rad / rad)."""
    n = normalize(np.asarray(gravity, dtype=float))
    nx, ny, nz = (float(v) for v in n)
    h2 = ny * ny + nz * nz
    h = math.sqrt(h2)
    if h < 1e-12:  # gravity along the body's x axis: roll undefined
        return np.full((2, 2), np.nan)
    d_n = np.array([[0.0, nz / h2, -ny / h2],  # roll = atan2(-ny, -nz)
                    [h, -nx * ny / h, -nx * nz / h]])  # pitch = atan2(nx, h), |n| = 1
    return d_n @ tangent_basis(n)


def roll_pitch_from_gravity(gravity: np.ndarray, cov_tangent: np.ndarray | None = None):
    """Roll and pitch (rad) of the body from gravity in the body frame.

    Returns (roll, pitch, quaternion xyzw of R_level, i.e. the body's orientation in the level frame as a
    sensor_msgs/Imu carries it, 2x2 covariance of (roll, pitch) in rad^2 or None).
    ``cov_tangent`` is the 2x2 angular covariance of gravity's direction (:func:`tangent_covariance`).
    """
    g = np.asarray(gravity, dtype=float)
    roll, pitch = _roll_pitch(normalize(g))
    q = matrix_to_quat_xyzw(leveling_rotation(g))
    cov = None
    if cov_tangent is not None:
        J = roll_pitch_jacobian(g)
        cov = J @ np.asarray(cov_tangent, dtype=float) @ J.T
    return roll, pitch, q, cov


__all__ = ["leveling_rotation", "roll_pitch_from_gravity", "roll_pitch_jacobian", "tangent_covariance"]
