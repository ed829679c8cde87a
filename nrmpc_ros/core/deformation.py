"""Static cantilever deformation model and Plücker lines (docs/CONVENTIONS.md (Bending, Gravity measurements)).

Everything is vectorised over cameras and, where useful, over a batch of
gravity vectors, so RANSAC can evaluate many gravity hypotheses at once.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .rig import Rig
from .so3 import cross, exp_and_left_jacobian, exp_so3, normalize, skew, tangent_basis


def bend_rotation_vectors(rig: Rig, g, cams=None) -> np.ndarray:
    """phi_i(g) = c_r,i (u_i x g) (docs/CONVENTIONS.md (Bending)) of all cameras (or of ``cams``): (M, 3), or (K, M, 3)
    for a batch of gravity vectors (K, 3)."""
    cr_ux = rig.bar_derivatives[1]
    if cams is not None:
        cr_ux = cr_ux[cams]
    return np.einsum("mab,...b->...ma", cr_ux, np.asarray(g, dtype=float))


def deformed_extrinsics(rig: Rig, g):
    """Bent extrinsics (w_i(g), W_i(g)) of all cameras (docs/CONVENTIONS.md (Bending)).

    g: gravity in the body frame (m/s^2), shape (3,) or a batch (K, 3); used
    as given (the model is linear in g).
    Returns w (M, 3) and W (M, 3, 3), or (K, M, 3) and (K, M, 3, 3) for a batch.
    """
    g = np.asarray(g, dtype=float)
    if g.shape[-1:] != (3,):
        raise ValueError(f"gravity must have shape (3,) or (K, 3), got {g.shape}")
    u, cd, _ = rig.bar_coefficients
    gb = g[..., None, :]  # (..., 1, 3)
    ug = np.sum(u * gb, axis=-1, keepdims=True)  # (..., M, 1)
    delta = cd[:, None] * (gb - ug * u)
    w = rig.positions + delta
    W = exp_so3(bend_rotation_vectors(rig, g)) @ rig.rotations
    return w, W


def deformation_jacobians(rig: Rig, g):
    """Derivatives of the model at gravity g (3,), or at a batch of gravity vectors (K, 3).

    Returns w (M, 3), W (M, 3, 3) (or (K, M, ...) for a batch) and the matrices D (M, 3, 3) and
    K (M, 3, 3) (or (K, M, 3, 3)) with
        d w_i / d g          = D_i                    (constant)
        d (W_i^T y) / d g    = W_i^T [y]_x K_i        for any fixed y.
    (W^T y = V^T Exp(-phi) y; differentiate Exp with its right Jacobian.)
    """
    u, cd, _ = rig.bar_coefficients
    g = np.asarray(g, dtype=float)
    if g.shape[-1:] != (3,) or g.ndim > 2:
        raise ValueError(f"gravity must have shape (3,) or (K, 3), got {g.shape}")
    E, J = exp_and_left_jacobian(bend_rotation_vectors(rig, g))  # J_l(phi) = J_r(-phi)
    W = E @ rig.rotations
    gb = g[..., None, :]
    w = rig.positions + cd[:, None] * (gb - np.sum(u * gb, axis=-1, keepdims=True) * u)
    D, cr_ux = rig.bar_derivatives  # D_i and c_r [u_i]_x, constant
    return w, W, D, J @ cr_ux


def rays(rig: Rig, f, cam, g=None):
    """Ray origins w_j(g) and unit directions W_j(g) f in the body frame, (N, 3) each.

    g=None uses the canonical (unbent) extrinsics.
    """
    if g is None:
        w, W = rig.positions, rig.rotations
    else:
        w, W = deformed_extrinsics(rig, g)
    d = np.einsum("nij,nj->ni", W[cam], f)
    return w[cam], d


def plucker_lines(rig: Rig, f, cam, g=None) -> np.ndarray:
    """Plücker lines l = (d, w x d) of bearings f seen by cameras cam (docs/CONVENTIONS.md (Bending)), (N, 6)."""
    o, d = rays(rig, f, cam, g)
    return np.concatenate([d, cross(o, d)], axis=1)


def gravity_from_camera(rig: Rig, camera_index: int, g_cam) -> np.ndarray:
    """Body-frame gravity from a gravity direction measured in camera i's frame (paper eq. 14).

    Minimises |W_i(g)^T g - g_cam|^2 over g with |g| = gravity_magnitude,
    started from V_i g_cam (docs/CONVENTIONS.md (Gravity measurements)). Only the direction of g_cam is used.
    """
    g_cam = np.asarray(g_cam, dtype=float)
    if g_cam.shape != (3,) or not np.all(np.isfinite(g_cam)) or np.linalg.norm(g_cam) < 1e-12:
        raise InputError("gravity measurement", f"needs a finite non-zero 3-vector, got {g_cam!r}", "g_cam")
    if not 0 <= camera_index < rig.num_cameras:
        raise InputError("gravity measurement", f"camera index {camera_index} out of range", "g_cam_index")
    gm = rig.gravity_magnitude
    target = gm * normalize(g_cam)
    g0 = rig.rotations[camera_index] @ target
    if not rig.cameras[camera_index].is_flexible:
        return g0
    g = g0
    for _ in range(20):  # Gauss-Newton on the sphere; dr/dg = W^T ([g]_x K + I)
        _, W, _, K = deformation_jacobians(rig, g)
        Wi = W[camera_index]
        r = Wi.T @ g - target
        B = gm * tangent_basis(normalize(g))
        J = Wi.T @ (skew(g) @ K[camera_index] + np.eye(3)) @ B
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        g = gm * normalize(g + B @ step)
        if np.linalg.norm(step) < 1e-14:
            break
    return g


def gravity_from_accelerometer(rig: Rig, accel) -> np.ndarray:
    """Body-frame gravity (m/s^2) from a static accelerometer reading a = -g (docs/CONVENTIONS.md, Gravity
    measurements).

    Uses the rig's IMU mount: at the body centre, g = -R_body_imu a; inside a
    camera, the camera-frame gravity goes through :func:`gravity_from_camera`.
    """
    a = np.asarray(accel, dtype=float)
    if rig.imu is None:
        raise InputError(rig.source, "the rig has no 'imu' block, so accelerometer readings cannot be used", "imu")
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-6:
        raise InputError(rig.imu.topic, f"accelerometer reading must be a finite non-zero 3-vector, got {a!r}",
                         "linear_acceleration")
    g_mount = -rig.imu.rotation @ a
    if rig.imu.mount == "body":
        return rig.gravity_magnitude * normalize(g_mount)
    return gravity_from_camera(rig, rig.camera_index(rig.imu.mount), g_mount)
