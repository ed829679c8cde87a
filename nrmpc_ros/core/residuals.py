"""Two-view residuals: generalized epipolar constraint, triangulation, angular errors.

All functions broadcast over leading dimensions, so one call scores every
correspondence against a batch of pose (or gravity) hypotheses.
Rays are given as origins o and unit directions d in each view's body frame;
(R, t) maps view 2 into view 1 (docs/CONVENTIONS.md (Frames)).
"""

from __future__ import annotations

import numpy as np

from .so3 import cross


def generalized_epipolar_residuals(l1, l2, R, t) -> np.ndarray:
    """l1^T G l2 with G = [[[t]_x R, R], [R, 0]] (docs/CONVENTIONS.md (Bending)), for Plücker lines (..., N, 6)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    d1, m1 = l1[..., :3], l1[..., 3:]
    d2, m2 = l2[..., :3], l2[..., 3:]
    Rd2 = np.einsum("...ij,...nj->...ni", R, d2)
    Rm2 = np.einsum("...ij,...nj->...ni", R, m2)
    tx_Rd2 = cross(t[..., None, :], Rd2)
    return np.sum(d1 * (tx_Rd2 + Rm2), axis=-1) + np.sum(m1 * Rd2, axis=-1)


def _closest_points(o1, d1, o2, d2, R, t):
    """Closest points of the two rays in view 1's body frame: X1 = o1 + s d1 and X2 = c2 + u e2 (ray 2 moved
    into view 1: c2 = R o2 + t, e2 = R d2), with the depths s, u, k = d1 . e2, e2 and a mask of (near)
    parallel rays."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    c2 = np.einsum("...ij,...nj->...ni", R, o2) + t[..., None, :]
    e2 = np.einsum("...ij,...nj->...ni", R, d2)
    b = c2 - o1
    k = np.sum(d1 * e2, axis=-1)
    p = np.sum(d1 * b, axis=-1)
    q = np.sum(e2 * b, axis=-1)
    denom = 1.0 - k * k
    parallel = denom < 1e-12
    denom = np.where(parallel, 1.0, denom)
    s = (p - k * q) / denom
    u = (k * p - q) / denom
    return o1 + s[..., None] * d1, c2 + u[..., None] * e2, s, u, k, e2, parallel


def triangulate_midpoint(o1, d1, o2, d2, R, t):
    """Midpoint of the common perpendicular of the two rays, in view 1's body frame.

    Returns (P, s, u, parallel): points (..., N, 3), depths along d1 and along
    the view-2 ray, and a mask of (near) parallel rays.
    """
    X1, X2, s, u, _, _, parallel = _closest_points(o1, d1, o2, d2, R, t)
    return 0.5 * (X1 + X2), s, u, parallel


def two_view_angular_errors(o1, d1, o2, d2, R, t) -> np.ndarray:
    """RMS over both views of the angular reprojection error (rad) of the triangulated point.

    The midpoint P of the common perpendicular w = X2 - X1 (from ray 1 at
    depth s to ray 2 at depth u) is seen from either camera at
    atan2(|w|/2, depth) off its ray, because w is orthogonal to both unit
    directions: closed form, no point needed. Points that triangulate behind
    either camera, or from parallel rays, get the error of the best point at
    infinity (half the angle between the rays), so far points are not
    punished and wrong poses are.
    """
    X1, X2, s, u, k, e2, parallel = _closest_points(o1, d1, o2, d2, R, t)
    w = X2 - X1
    h = 0.5 * np.sqrt(np.sum(w * w, axis=-1))
    err1 = np.arctan2(h, s)
    err2 = np.arctan2(h, u)
    rms = np.sqrt(0.5 * (err1 * err1 + err2 * err2))
    at_inf = 0.5 * np.arctan2(np.sqrt(np.sum(cross(d1, e2) ** 2, axis=-1)), k)
    bad = parallel | (s <= 0) | (u <= 0)
    return np.where(bad, at_inf, rms)
