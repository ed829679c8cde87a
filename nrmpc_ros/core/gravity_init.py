"""Vision-only starting points for gravity: per-camera rotations and cheap hypothesis scoring.

Each camera's own relative rotation Rc_j = W_j(g)^T R W_j(R^T g) is
measurable from its correspondences alone (a 5-point essential matrix) and
does not depend on the rig model. Bending makes Rc_j differ between cameras
in a way that depends on gravity, so scoring many gravity directions against
these rotations (vectorised over hypotheses and cameras) finds good starts
for the bundle adjustment, even when the bars bend so much that a rigid
6-point fit of the whole rig is far off.
"""

from __future__ import annotations

import cv2
import numpy as np

from .deformation import deformed_extrinsics, rays
from .matches import Matches
from .rig import Rig
from .so3 import angle_between, fibonacci_sphere, normalize, tangent_basis

MIN_POINTS_PER_CAMERA = 12


def project_to_so3(A: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) of a batch (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(A)
    D = np.ones(A.shape[:-1])
    D[..., -1] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt


def camera_rotations(m: Matches, num_cameras: int, threshold_rad: float, seed: int = 0):
    """Relative rotation of each camera (maps its view-2 frame into its view-1 frame) and inlier masks.

    Returns (cams, Rc, counts, inlier_mask) for the cameras where a 5-point
    essential matrix (OpenCV RANSAC) was found with enough inliers.
    """
    cams, rots, counts = [], [], []
    inlier = np.zeros(len(m), dtype=bool)
    cv2.setRNGSeed(int(seed))
    for j in range(num_cameras):
        idx = np.flatnonzero((m.cam == j) & (m.f1[:, 2] > 0.05) & (m.f2[:, 2] > 0.05))
        if len(idx) < MIN_POINTS_PER_CAMERA:
            continue
        p1 = m.f1[idx, :2] / m.f1[idx, 2:3]
        p2 = m.f2[idx, :2] / m.f2[idx, 2:3]
        E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), method=cv2.RANSAC, prob=0.999, threshold=threshold_rad)
        if E is None or E.shape != (3, 3) or mask is None:
            continue
        n_in, Rcv, _, mask2 = cv2.recoverPose(E, p1, p2, np.eye(3), mask=mask.copy())
        ok = mask.ravel().astype(bool)
        if n_in < MIN_POINTS_PER_CAMERA // 2 or ok.sum() < MIN_POINTS_PER_CAMERA:
            continue
        cams.append(j)
        rots.append(Rcv.T)  # OpenCV: x2 = Rcv x1 + t
        counts.append(float(ok.sum()))
        inlier[idx[ok]] = True
    return np.array(cams, dtype=int), np.array(rots).reshape(-1, 3, 3), np.array(counts), inlier


def _body_rotation_from_cameras(rig: Rig, cams, Rc, weights, g1, R0, iterations=4):
    """For each gravity hypothesis g1 (K, 3): the body rotation agreeing best with all cameras, and the cost."""
    _, W1 = deformed_extrinsics(rig, g1)
    W1 = W1[:, cams]
    R = np.broadcast_to(R0, (len(g1), 3, 3)).copy()
    for _ in range(iterations):
        g2 = np.einsum("kji,kj->ki", R, g1)
        _, W2 = deformed_extrinsics(rig, g2)
        Rj = W1 @ Rc @ np.swapaxes(W2[:, cams], -1, -2)  # (K, J, 3, 3), each an estimate of R
        R = project_to_so3(np.einsum("j,kjab->kab", weights, Rj))
    cost = np.einsum("j,kj->k", weights, np.sum((Rj - R[:, None]) ** 2, axis=(-1, -2)))
    return R, cost


def gravity_rotation_hypotheses(rig: Rig, cams, Rc, weights, num_hypotheses=200, num_starts=3):
    """Best distinct (g, R, cost) consistent with the per-camera rotations, from a grid of gravity directions.

    Each of the best distinct grid directions (Fibonacci sphere, ~14 deg apart
    for 200) is refined by two finer local grids (coarse-to-fine, vectorised).
    """
    gm = rig.gravity_magnitude
    weights = np.asarray(weights, dtype=float) / np.sum(weights)
    V = rig.rotations[cams]
    R_canonical = project_to_so3(np.einsum("j,jab->ab", weights, V @ Rc @ np.swapaxes(V, -1, -2)))
    hyp = gm * fibonacci_sphere(num_hypotheses)
    R_h, cost = _body_rotation_from_cameras(rig, cams, Rc, weights, hyp, R_canonical)
    spacing = 2.0 * np.sqrt(np.pi / num_hypotheses)  # typical angle between grid neighbours
    out = []
    for k in np.argsort(cost):
        if any(angle_between(hyp[k], g) < 2.5 * spacing for g, _, _ in out):
            continue
        out.append(_refine_locally(rig, cams, Rc, weights, hyp[k], R_h[k], float(cost[k]), spacing))
        if len(out) >= num_starts:
            break
    out.sort(key=lambda x: x[2])
    return out


_OFFSETS = np.stack(np.meshgrid(np.linspace(-1, 1, 7), np.linspace(-1, 1, 7)), -1).reshape(-1, 2)


def _refine_locally(rig, cams, Rc, weights, g, R, cost, spacing, levels=3):
    """Coarse-to-fine search around g: 7x7 tangent grids shrinking by 3 per level."""
    gm = rig.gravity_magnitude
    radius = spacing
    for _ in range(levels):
        B = tangent_basis(g / gm)
        cand = gm * normalize(g / gm + radius * _OFFSETS @ B.T)
        R_c, c = _body_rotation_from_cameras(rig, cams, Rc, weights, cand, R)
        k = int(np.argmin(c))
        if c[k] < cost:
            g, R, cost = cand[k], R_c[k], float(c[k])
        radius /= 3.0
    return g, R, cost


def translation_given_rotation(rig: Rig, m: Matches, idx, R, g):
    """Least-squares t from the generalized epipolar constraint, linear in t for fixed R and rays.

    l1^T G l2 = t . (R d2 x d1) + d1 . (R m2) + m1 . (R d2) = 0 (SPEC section 3);
    two re-weighting rounds damp the influence of residual outliers.
    """
    o1, d1 = rays(rig, m.f1[idx], m.cam[idx], g)
    o2, d2 = rays(rig, m.f2[idx], m.cam[idx], None if g is None else R.T @ g)
    Rd2 = d2 @ R.T
    Rm2 = np.cross(o2, d2) @ R.T
    A = np.cross(Rd2, d1)
    b = -(np.sum(d1 * Rm2, axis=1) + np.sum(np.cross(o1, d1) * Rd2, axis=1))
    w = np.ones(len(b))
    t = np.zeros(3)
    for _ in range(3):
        t = np.linalg.lstsq(A * w[:, None], b * w, rcond=None)[0]
        r = np.abs(A @ t - b)
        s = 1.4826 * np.median(r) + 1e-15
        w = np.divide(2 * s, r, out=np.ones_like(r), where=r >= 2 * s)
    return t
