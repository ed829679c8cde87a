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

from .deformation import bend_rotation_vectors, deformed_extrinsics, rays
from .epipolar import essential_matrix, in_front
from .loss import MAD_TO_STD, HuberLoss, msac_score
from .matches import Matches
from .residuals import two_view_angular_errors
from .rig import Rig
from .so3 import angle_between, cross, exp_so3, fibonacci_sphere, normalize, tangent_basis

MIN_POINTS_PER_CAMERA = 12
CHEIRALITY_POINTS = 40  # inliers that choose among the four decompositions of a camera's essential matrix
FAR = 1e9  # recoverPose drops points beyond this many baselines; rotation-dominant motion puts most of them far


def _svd_projection(A: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(A)
    D = np.ones(A.shape[:-1])
    D[..., -1] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt


def _inverse_transpose_and_det(X: np.ndarray):
    """X^-T and det X of a batch (K, 3, 3) by the adjugate (the cofactor matrix is det X * X^-T)."""
    a, b, c = X[:, 0, 0], X[:, 0, 1], X[:, 0, 2]
    d, e, f = X[:, 1, 0], X[:, 1, 1], X[:, 1, 2]
    g, h, i = X[:, 2, 0], X[:, 2, 1], X[:, 2, 2]
    cof = np.empty(X.shape)
    cof[:, 0, 0], cof[:, 0, 1], cof[:, 0, 2] = e * i - f * h, f * g - d * i, d * h - e * g
    cof[:, 1, 0], cof[:, 1, 1], cof[:, 1, 2] = c * h - b * i, a * i - c * g, b * g - a * h
    cof[:, 2, 0], cof[:, 2, 1], cof[:, 2, 2] = b * f - c * e, c * d - a * f, a * e - b * d
    det = a * cof[:, 0, 0] + b * cof[:, 0, 1] + c * cof[:, 0, 2]
    safe = np.where(np.abs(det) > 1e-300, det, 1.0)
    return cof / safe[:, None, None], det


def project_to_so3(A: np.ndarray, iterations: int = 3) -> np.ndarray:
    """Nearest rotation (Frobenius) of a batch (..., 3, 3).

    The polar factor by scaled Newton iterations X <- (g X + X^-T / g) / 2
    (Higham, 1986), about half the cost of a batched SVD on the
    near-rotations this is used for (weighted means of rotations: three
    iterations bring them to orthogonality within 1e-15); matrices with
    det <= 0 or not converged go through the SVD.
    """
    A = np.asarray(A, dtype=float)
    X = A.reshape(-1, 3, 3)
    det = np.ones(len(X))
    for k in range(iterations):
        Xit, det = _inverse_transpose_and_det(X)
        gamma = 1.0
        if k < 2:  # Frobenius-norm scaling speeds up the first steps of matrices far from orthogonal
            gamma = np.sqrt(np.sqrt(np.sum(Xit * Xit, axis=(1, 2)) / np.maximum(np.sum(X * X, axis=(1, 2)), 1e-300)))
            gamma = np.where(gamma > 1e-150, gamma, 1.0)[:, None, None]  # singular: left to the SVD below
        X = 0.5 * (gamma * X + Xit / gamma)
    off = np.abs(np.swapaxes(X, 1, 2) @ X - np.eye(3)).reshape(len(X), -1).max(axis=1)
    bad = ~((off < 1e-8) & (det > 0))
    if bad.any():
        X[bad] = _svd_projection(A.reshape(-1, 3, 3)[bad])
    return X.reshape(A.shape)


def camera_rotations(m: Matches, num_cameras: int, threshold_rad: float, seed: int = 0):
    """Relative rotation of each camera (maps its view-2 frame into its view-1 frame) and inlier masks.

    Returns (cams, Rc, counts, inlier_mask) for the cameras where a 5-point
    essential matrix (:func:`~nrmpc_ros.core.epipolar.essential_matrix`) was found with enough inliers.
    """
    cams, rots, counts = [], [], []
    inlier = np.zeros(len(m), dtype=bool)
    cv2.setRNGSeed(int(seed))
    for j in range(num_cameras):
        idx = np.flatnonzero((m.cam == j) & in_front(m.f1, m.f2))
        if len(idx) < MIN_POINTS_PER_CAMERA:
            continue
        found = essential_matrix(m.f1[idx], m.f2[idx], threshold_rad)
        if found is None or found[0].shape != (3, 3):
            continue
        E, ok, p1, p2 = found
        if ok.sum() < MIN_POINTS_PER_CAMERA:
            continue
        # the decomposition with the points in front: a spread sample of the inliers decides it
        sub = np.flatnonzero(ok)
        sub = sub[np.linspace(0, len(sub) - 1, min(len(sub), CHEIRALITY_POINTS)).astype(int)]
        n_in, Rcv, _, _, _ = cv2.recoverPose(E, p1[sub], p2[sub], np.eye(3), distanceThresh=FAR)  # far points count too
        if n_in < len(sub) // 2:
            continue
        cams.append(j)
        rots.append(Rcv.T)  # OpenCV: x2 = Rcv x1 + t
        counts.append(float(ok.sum()))
        inlier[idx[ok]] = True
    return np.array(cams, dtype=int), np.array(rots).reshape(-1, 3, 3), np.array(counts), inlier


def body_rotation_from_cameras(rig: Rig, cams: np.ndarray, Rc: np.ndarray, weights: np.ndarray, g1: np.ndarray,
                               R0: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """For each gravity hypothesis g1 (K, 3): the body rotation agreeing best with all cameras (K, 3, 3), and
    the cost (K,); cams, Rc, weights as :func:`camera_rotations` gives them (weights summing to 1), R0 the
    rotation the iterations start from.

    With W_j(g) = Exp(phi_j(g)) V_j (docs/CONVENTIONS.md (Bending)), each camera's estimate of R is
    W_j(g1) Rc_j W_j(R^T g1)^T = Exp(phi_j(g1)) (V_j Rc_j V_j^T) Exp(phi_j(R^T g1))^T.
    """
    V = rig.rotations[cams]
    A = V @ Rc @ np.swapaxes(V, -1, -2)  # (J, 3, 3)
    E1A = exp_so3(bend_rotation_vectors(rig, g1, cams)) @ A  # (K, J, 3, 3), fixed over the iterations
    R = np.broadcast_to(R0, (len(g1), 3, 3)).copy()
    for _ in range(iterations):
        g2 = np.einsum("kji,kj->ki", R, g1)
        E2 = exp_so3(bend_rotation_vectors(rig, g2, cams))
        Rj = E1A @ np.swapaxes(E2, -1, -2)  # (K, J, 3, 3), each an estimate of R
        R = project_to_so3(np.einsum("j,kjab->kab", weights, Rj))
    cost = np.einsum("j,kj->k", weights, np.sum((Rj - R[:, None]) ** 2, axis=(-1, -2)))
    return R, cost


def gravity_rotation_hypotheses(rig: Rig, cams, Rc, weights, num_hypotheses=200, num_starts=3, scoring=None):
    """Best distinct (g, R, cost) consistent with the per-camera rotations, from a grid of gravity directions.

    The grid (Fibonacci sphere, ~14 deg apart for 200) is ranked by how well
    the per-camera rotations agree, or, with ``scoring = (matches, idx,
    threshold)``, by the MSAC score of each hypothesis' full two-view pose
    (:func:`pose_hypothesis_scores`), which also uses the translations and
    so tells apart gravity directions the rotations alone barely do (parallel
    bars). Each of the best distinct directions is refined by two finer local
    grids (coarse-to-fine, vectorised).
    """
    gm = rig.gravity_magnitude
    weights, R_canonical = _weights_and_rigid_rotation(rig, cams, Rc, weights)
    hyp = gm * fibonacci_sphere(num_hypotheses)
    R_h, cost = body_rotation_from_cameras(rig, cams, Rc, weights, hyp, R_canonical)
    rank = cost if scoring is None else pose_hypothesis_scores(rig, *scoring, hyp, R_h)
    spacing = 2.0 * np.sqrt(np.pi / num_hypotheses)  # typical angle between grid neighbours
    picked = []
    for k in np.argsort(rank):
        if all(angle_between(hyp[k], hyp[j]) >= 2.5 * spacing for j in picked):
            picked.append(k)
            if len(picked) >= num_starts:
                break
    g, R, c = _refine_locally(rig, cams, Rc, weights, hyp[picked], R_h[picked], cost[picked], spacing)
    return sorted(zip(g, R, c.tolist()), key=lambda x: x[2])


def _weights_and_rigid_rotation(rig: Rig, cams, Rc, weights):
    """Normalised camera weights and the body rotation the cameras agree on with canonical extrinsics."""
    weights = np.asarray(weights, dtype=float) / np.sum(weights)
    V = rig.rotations[cams]
    return weights, project_to_so3(np.einsum("j,jab->ab", weights, V @ Rc @ np.swapaxes(V, -1, -2)))


def hinted_hypothesis(rig: Rig, cams, Rc, weights, gravity_hint):
    """[(g, R, cost)] for a gravity known roughly from elsewhere (view 1's body frame): the hint and the body
    rotation agreeing best with the per-camera rotations when the bars bend under it."""
    weights, R_canonical = _weights_and_rigid_rotation(rig, cams, Rc, weights)
    g = rig.gravity_magnitude * normalize(np.asarray(gravity_hint, dtype=float))[None]
    R, cost = body_rotation_from_cameras(rig, cams, Rc, weights, g, R_canonical)
    return [(g[0], R[0], float(cost[0]))]


_OFFSETS = np.stack(np.meshgrid(np.linspace(-1, 1, 7), np.linspace(-1, 1, 7)), -1).reshape(-1, 2)


def _refine_locally(rig, cams, Rc, weights, g, R, cost, spacing, levels=3):
    """Coarse-to-fine search around each start g (S, 3): 7x7 tangent grids shrinking by 3 per level,
    all starts in one vectorised evaluation per level."""
    gm = rig.gravity_magnitude
    g, R, cost = g.copy(), R.copy(), np.asarray(cost, dtype=float).copy()
    S, C = len(g), len(_OFFSETS)
    radius = spacing
    for _ in range(levels):
        B = tangent_basis(g / gm)  # (S, 3, 2)
        cand = gm * normalize(g[:, None, :] / gm + radius * np.einsum("sij,cj->sci", B, _OFFSETS))
        R_c, c = body_rotation_from_cameras(rig, cams, Rc, weights, cand.reshape(-1, 3), np.repeat(R, C, axis=0))
        c = c.reshape(S, C)
        k = np.argmin(c, axis=1)
        better = c[np.arange(S), k] < cost
        pick = np.arange(S) * C + k
        g = np.where(better[:, None], cand.reshape(-1, 3)[pick], g)
        R = np.where(better[:, None, None], R_c[pick], R)
        cost = np.where(better, c[np.arange(S), k], cost)
        radius /= 3.0
    return g, R, cost


def pose_hypothesis_scores(rig: Rig, m: Matches, idx, threshold, hyp, R_h):
    """MSAC score (rad^2) of each gravity hypothesis hyp (K, 3) with its rotation R_h (K, 3, 3) and the
    least-squares translation, on correspondences idx; vectorised over hypotheses."""
    f1, f2, cam = m.f1[idx], m.f2[idx], m.cam[idx]
    w1, W1 = deformed_extrinsics(rig, hyp)
    w2, W2 = deformed_extrinsics(rig, np.einsum("kji,kj->ki", R_h, hyp))  # R^T g
    o1, d1 = w1[:, cam], np.einsum("knij,nj->kni", W1[:, cam], f1)
    o2, d2 = w2[:, cam], np.einsum("knij,nj->kni", W2[:, cam], f2)
    t = least_squares_translations(o1, d1, o2, d2, R_h)
    err = two_view_angular_errors(o1, d1, o2, d2, R_h, t)
    return msac_score(err, threshold, axis=-1)


def least_squares_translations(o1: np.ndarray, d1: np.ndarray, o2: np.ndarray, d2: np.ndarray, R: np.ndarray,
                               rounds: int = 3) -> np.ndarray:
    """Least-squares t from the generalized epipolar constraint, linear in t for fixed R and rays,
    batched over leading dimensions (rays (..., N, 3), R (..., 3, 3)).

    l1^T G l2 = t . (R d2 x d1) + d1 . (R m2) + m1 . (R d2) = 0 (docs/CONVENTIONS.md (Bending));
    re-weighting rounds damp the influence of residual outliers.
    """
    RT = np.swapaxes(R, -1, -2)
    Rd2 = d2 @ RT
    Rm2 = cross(o2, d2) @ RT
    A = cross(Rd2, d1)
    b = -(np.sum(d1 * Rm2, axis=-1) + np.sum(cross(o1, d1) * Rd2, axis=-1))
    w = np.ones(b.shape)
    for _ in range(rounds):
        Aw = A * w[..., None]
        H = np.swapaxes(Aw, -1, -2) @ Aw + 1e-12 * np.eye(3)
        t = np.linalg.solve(H, np.swapaxes(Aw, -1, -2) @ (b * w)[..., None])[..., 0]
        r = np.abs((A @ t[..., None])[..., 0] - b)
        s = MAD_TO_STD * np.median(r, axis=-1, keepdims=True) + 1e-15
        w = HuberLoss(2.0 * s).weight(r * r)
    return t


def translation_given_rotation(rig: Rig, m: Matches, idx, R, g):
    """Least-squares t for fixed R and gravity g on correspondences idx (see :func:`least_squares_translations`)."""
    o1, d1 = rays(rig, m.f1[idx], m.cam[idx], g)
    o2, d2 = rays(rig, m.f2[idx], m.cam[idx], None if g is None else R.T @ g)
    return least_squares_translations(o1, d1, o2, d2, R)


def start_translation(rig: Rig, m: Matches, idx, R, g, threshold):
    """Translation of a start (R, g) on correspondences idx, and the angular errors (rad) of idx at that pose.

    The least-squares t of :func:`least_squares_translations`, with its sign checked: the part of the
    constraint that fixes the sign (the moments, i.e. the cameras' offsets from the body centre) is weak when
    the cameras hardly see across the rig (parallel bars), and there noise or a wrong gravity can flip it. Of
    t and -t the one with the smaller MSAC score at ``threshold`` (rad) is kept; the angular errors punish
    points behind a camera.
    """
    o1, d1 = rays(rig, m.f1[idx], m.cam[idx], g)
    o2, d2 = rays(rig, m.f2[idx], m.cam[idx], R.T @ g)
    t = least_squares_translations(o1, d1, o2, d2, R)
    both = np.stack([t, -t])
    err = two_view_angular_errors(o1, d1, o2, d2, R, both)  # (2, n)
    k = int(np.argmin(msac_score(err, threshold, axis=1)))
    return both[k], err[k]
