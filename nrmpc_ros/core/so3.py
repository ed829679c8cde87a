"""Rotations and unit vectors: small vectorised helpers (no state, no ROS).

All functions accept batches with leading dimensions; angles are in radians,
quaternions are (x, y, z, w) as in ROS messages (docs/CONVENTIONS.md (Frames)).
"""

from __future__ import annotations

import math

import numpy as np

_EPS = 1e-12


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b along the last axis with broadcasting (faster than np.cross for small last axes)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b, float))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def skew(v: np.ndarray) -> np.ndarray:
    """[v]_x for v of shape (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def _rodrigues_coeffs(theta: np.ndarray):
    """sin(t)/t, (1-cos t)/t^2, (t - sin t)/t^3 with series near zero."""
    small = theta < 1e-4
    if not small.any():  # the usual case, without the series branch
        s, c = np.sin(theta), np.cos(theta)
        return s / theta, (1.0 - c) / (theta * theta), (theta - s) / (theta * theta * theta)
    ts = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(ts)) / (ts * ts))
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (ts - np.sin(ts)) / (ts**3))
    return a, b, c


def _rodrigues_terms(phi: np.ndarray):
    """Coefficients (each (..., 1, 1)), [phi]_x and [phi]_x^2 = phi phi^T - |phi|^2 I of rotation vectors (..., 3)."""
    theta2 = np.sum(phi * phi, axis=-1)
    coeffs = tuple(x[..., None, None] for x in _rodrigues_coeffs(np.sqrt(theta2)))
    K2 = phi[..., :, None] * phi[..., None, :] - theta2[..., None, None] * np.eye(3)
    return coeffs, skew(phi), K2


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """SO(3) exponential (Rodrigues) of rotation vectors (..., 3) -> (..., 3, 3).

    Batches are built entry-wise as cos(t) I + (sin t / t) [phi]_x + ((1 - cos t) / t^2) phi phi^T, which
    takes about half the array operations of I + a K + b K^2 (the gravity grid evaluates thousands).
    """
    phi = np.asarray(phi, dtype=float)
    if phi.ndim == 1:  # fast path for one vector
        theta = math.sqrt(float(phi @ phi))
        K = skew(phi)
        if theta < 1e-4:
            a, b = 1.0 - theta * theta / 6.0, 0.5 - theta * theta / 24.0
        else:
            a, b = math.sin(theta) / theta, (1.0 - math.cos(theta)) / (theta * theta)
        return np.eye(3) + a * K + b * (K @ K)
    theta = np.sqrt(np.einsum("...i,...i->...", phi, phi))
    a, b, _ = _rodrigues_coeffs(theta)
    c = np.cos(theta)
    out = (b[..., None] * phi)[..., :, None] * phi[..., None, :]
    ap = a[..., None] * phi
    for i in range(3):
        out[..., i, i] += c
    out[..., 0, 1] -= ap[..., 2]
    out[..., 1, 0] += ap[..., 2]
    out[..., 0, 2] += ap[..., 1]
    out[..., 2, 0] -= ap[..., 1]
    out[..., 1, 2] -= ap[..., 0]
    out[..., 2, 1] += ap[..., 0]
    return out


def exp_and_left_jacobian(phi: np.ndarray):
    """Exp(phi) and J_l(phi) = J_r(-phi) of rotation vectors (..., 3), sharing one Rodrigues evaluation."""
    (a, b, c), K, K2 = _rodrigues_terms(np.asarray(phi, dtype=float))
    eye = np.eye(3)
    return eye + a * K + b * K2, eye + b * K + c * K2


def right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Right Jacobian J_r of SO(3): Exp(phi + d) ~ Exp(phi) Exp(J_r(phi) d)."""
    (_, b, c), K, K2 = _rodrigues_terms(np.asarray(phi, dtype=float))
    return np.eye(3) - b * K + c * K2


def log_so3(R: np.ndarray) -> np.ndarray:
    """SO(3) logarithm (..., 3, 3) -> rotation vectors (..., 3), robust near pi."""
    R = np.asarray(R, dtype=float)
    tr = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(tr)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.sin(theta)
    small = theta < 1e-6
    scale = np.where(small, 0.5 + theta**2 / 12.0, theta / (2.0 * np.where(small, 1.0, s)))
    out = w * scale[..., None]
    near_pi = theta > np.pi - 1e-3
    if np.any(near_pi):
        Rp = R[near_pi]
        B = (Rp + np.swapaxes(Rp, -1, -2)) / 2.0 - np.eye(3) * np.cos(theta[near_pi])[..., None, None]
        diag = np.diagonal(B, axis1=-2, axis2=-1)
        k = np.argmax(diag, axis=-1)
        col = np.take_along_axis(B, k[..., None, None].repeat(3, -1), axis=-2)[..., 0, :]
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        sgn = np.sign(np.sum(axis * w[near_pi], axis=-1))
        sgn = np.where(sgn == 0, 1.0, sgn)
        out[near_pi] = axis * (sgn * theta[near_pi])[..., None]
    return out


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle (rad) of rotation matrices, robust for small angles."""
    return np.linalg.norm(log_so3(R), axis=-1)


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) between vectors along the last axis; atan2 form, exact near 0 and pi."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c = np.linalg.norm(cross(a, b), axis=-1)
    d = np.sum(a * b, axis=-1)
    return np.arctan2(c, d)


def normalize(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    if v.ndim == 1:  # fast path for one vector (hot in the bundle adjustment)
        return v / max(math.sqrt(float(v @ v)), _EPS)
    n = np.sqrt(np.sum(v * v, axis=-1, keepdims=True))
    return v / np.maximum(n, _EPS)


def tangent_basis(n: np.ndarray) -> np.ndarray:
    """Orthonormal basis (..., 3, 2) of the plane orthogonal to unit vectors n (..., 3).

    Columns b1, b2 with (b1, b2, n) right-handed; smooth away from n = -e_z-ish
    switch, which is fine because callers only use it as a local chart.
    """
    n = normalize(n)
    if n.ndim == 1:  # fast path for one vector (hot in the bundle adjustment): plain floats
        x, y, z = n.tolist()
        a, b, c = (-y, x, 0.0) if abs(z) < 0.9 else (0.0, -z, y)  # helper e_z, else e_x, cross n
        s = 1.0 / math.sqrt(a * a + b * b + c * c)
        a, b, c = a * s, b * s, c * s
        return np.array([[a, y * c - z * b], [b, z * a - x * c], [c, x * b - y * a]])
    helper = np.where(np.abs(n[..., 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    b1 = normalize(cross(helper, n))
    b2 = cross(n, b1)
    return np.stack([b1, b2], axis=-1)


def quat_xyzw_to_matrix(q) -> np.ndarray:
    """Unit quaternion (x, y, z, w) -> rotation matrix (normalises first)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return R.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion (x, y, z, w) with w >= 0."""
    R = np.asarray(R, dtype=float)
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def rotation_aligning(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation A with A a_hat = b_hat (single vectors)."""
    a = normalize(a)
    b = normalize(b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis)
    c = float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = tangent_basis(a)[:, 0]
        return exp_so3(np.pi * perp)
    return exp_so3(axis / s * np.arctan2(s, c))


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (n, 3) on the sphere (deterministic)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.pi * (1.0 + 5**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
