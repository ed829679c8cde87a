"""Fused gravity on the sphere, and roll/pitch from gravity (issue: fused gravity with uncertainty).

Each two-view estimate gives gravity in the current body frame with a 3x3
covariance from the bundle adjustment. The filter carries its estimate into
each new body frame with the estimated relative rotation (inflating the
covariance by that rotation's uncertainty), rejects estimates whose
Mahalanobis distance on the tangent plane is too large, and fuses the rest
with an information-weighted (Kalman) update in the tangent plane at the
current estimate. Angles are in radians; gravity vectors in m/s^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .so3 import exp_so3, matrix_to_quat_xyzw, normalize, tangent_basis

CHI2_2DOF_999 = 13.8155  # 99.9 % quantile of chi-square with 2 d.o.f.
MAX_CHALLENGERS = 3  # states built from rejected estimates that are kept


def tangent_covariance(g: np.ndarray, cov_g: np.ndarray) -> np.ndarray:
    """2x2 angular covariance (rad^2) of a gravity vector's direction from its 3x3 covariance (m^2/s^4)."""
    B = tangent_basis(normalize(g)) / np.linalg.norm(g)
    return B.T @ cov_g @ B


def sphere_log(mean_dir: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Tangent coordinates (rad) of unit vector x in the chart at unit vector mean_dir."""
    B = tangent_basis(mean_dir)
    c = float(np.clip(mean_dir @ x, -1.0, 1.0))
    v = x - c * mean_dir
    s = np.linalg.norm(v)
    if s < 1e-15:  # x = mean_dir, or its antipode (any direction, pi away)
        return np.zeros(2) if c > 0 else np.array([math.pi, 0.0])
    return B.T @ (v / s) * math.atan2(s, c)


def sphere_exp(mean_dir: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Unit vector reached from mean_dir along tangent coordinates d (rad)."""
    B = tangent_basis(mean_dir)
    v = B @ d
    a = np.linalg.norm(v)
    if a < 1e-15:
        return mean_dir
    return math.cos(a) * mean_dir + math.sin(a) * v / a


@dataclass
class FusedGravity:
    gravity: np.ndarray  # current body frame, m/s^2
    cov_tangent: np.ndarray  # 2x2 rad^2, in the chart tangent_basis(gravity)
    num_fused: int
    num_rejected: int

    @property
    def sigma_rad(self) -> float:
        return float(math.sqrt(max(np.linalg.eigvalsh(self.cov_tangent).max(), 0.0)))


class GravityFusion:
    """Recursive fusion of gravity estimates carried through the body frames of successive views.

    process_sigma_rad is added (in quadrature) per propagation to account for
    errors of the relative rotation that the covariance does not cover.

    Estimates the state rejects are not thrown away: those that agree build a
    challenger state (up to MAX_CHALLENGERS), carried along the same way.
    When a challenger has gathered more estimates than the state, or the
    state has rejected ``max_rejections`` in a row (then the best supported
    challenger), it takes over and the old state becomes a challenger: a state
    started from a wrong first estimate (e.g. a sign-ambiguous pair on
    two-camera bars) is replaced as soon as the consistent majority disagrees.
    """

    def __init__(self, gravity_magnitude: float = 9.81, gate: float = CHI2_2DOF_999, process_sigma_rad: float = 1e-3,
                 max_rejections: int = 3, min_sigma_rad: float = 1e-5):
        self.gm = gravity_magnitude
        self.gate = gate
        self.q = process_sigma_rad**2
        self.max_rejections = max_rejections
        self.min_var = min_sigma_rad**2
        self.reset()

    def reset(self):
        self.dir: np.ndarray | None = None
        self.P = np.eye(2)
        self.num_fused = 0
        self.num_rejected = 0
        self._consecutive = 0
        self._challengers: list = []  # [dir, P, num_fused] of states built from rejected estimates

    @property
    def state(self) -> FusedGravity | None:
        if self.dir is None:
            return None
        return FusedGravity(self.gm * self.dir, self.P.copy(), self.num_fused, self.num_rejected)

    def _propagated(self, d, P, R_delta, cov_rotation):
        B_old = tangent_basis(d)
        new_dir = normalize(R_delta.T @ d)
        B_new = tangent_basis(new_dir)
        T = B_new.T @ R_delta.T @ B_old  # chart change (2x2 rotation)
        P = T @ P @ T.T + self.q * np.eye(2)
        if cov_rotation is not None:
            J = B_new.T @ _skew(new_dir)  # d(R^T g)/d(dr) = [R^T g]_x for R -> R Exp(dr)
            P = P + J @ np.asarray(cov_rotation) @ J.T
        return new_dir, P

    def propagate(self, R_delta: np.ndarray, cov_rotation: np.ndarray | None = None) -> None:
        """Move the estimate (and the challenger) into a new body frame whose orientation in the old one is
        R_delta.

        g_new = R_delta^T g_old; the rotation's covariance (3x3 rad^2, right perturbation
        R_delta Exp(dr)) projects onto the tangent plane of g_new.
        """
        if self.dir is None:
            return
        self.dir, self.P = self._propagated(self.dir, self.P, R_delta, cov_rotation)
        for c in self._challengers:
            c[0], c[1] = self._propagated(c[0], c[1], R_delta, cov_rotation)

    def carried(self, R_delta: np.ndarray, cov_rotation: np.ndarray | None = None) -> FusedGravity | None:
        """The state as :meth:`propagate` would make it, without changing anything."""
        if self.dir is None:
            return None
        d, P = self._propagated(self.dir, self.P, R_delta, cov_rotation)
        return FusedGravity(self.gm * d, P, self.num_fused, self.num_rejected)

    def agrees(self, gravity: np.ndarray, cov_gravity: np.ndarray, R_delta: np.ndarray | None = None,
               cov_rotation: np.ndarray | None = None) -> bool:
        """Whether the state (carried by R_delta first, if given) would accept this estimate; changes nothing."""
        if self.dir is None:
            return True
        d, P = (self.dir, self.P) if R_delta is None else self._propagated(self.dir, self.P, R_delta, cov_rotation)
        g = normalize(np.asarray(gravity, dtype=float))
        Rm = tangent_covariance(self.gm * g, np.asarray(cov_gravity, dtype=float)) + self.min_var * np.eye(2)
        return self._gated_update(d, P, g, Rm) is not None

    def _gated_update(self, d, P, g, Rm):
        """Kalman update of (d, P) with direction g (covariance Rm in g's chart); None if outside the gate."""
        z = sphere_log(d, g)
        S = P + _chart_change(g, d) @ Rm @ _chart_change(g, d).T
        if float(z @ np.linalg.solve(S, z)) > self.gate:
            return None
        K = P @ np.linalg.inv(S)
        new_dir = sphere_exp(d, K @ z)
        T = tangent_basis(new_dir).T @ tangent_basis(d)
        P = (np.eye(2) - K) @ P
        return new_dir, T @ P @ T.T

    def update(self, gravity: np.ndarray, cov_gravity: np.ndarray) -> bool:
        """Fuse one estimate (current body frame) with its 3x3 covariance; False if rejected as an outlier
        (True also when the challenger it joined has just taken over)."""
        g = normalize(np.asarray(gravity, dtype=float))
        Rm = tangent_covariance(self.gm * g, np.asarray(cov_gravity, dtype=float)) + self.min_var * np.eye(2)
        if self.dir is None:
            self.dir, self.P = g, Rm
            self.num_fused = 1
            return True
        fused = self._gated_update(self.dir, self.P, g, Rm)
        if fused is not None:
            self.dir, self.P = fused
            self.num_fused += 1
            self._consecutive = 0
            return True
        self.num_rejected += 1
        self._consecutive += 1
        for c in self._challengers:
            joined = self._gated_update(c[0], c[1], g, Rm)
            if joined is not None:
                c[0], c[1], c[2] = joined[0], joined[1], c[2] + 1
                mine = c
                break
        else:
            mine = [g, Rm, 1]
            self._challengers.append(mine)
            if len(self._challengers) > MAX_CHALLENGERS:  # forget the least supported (the oldest of those)
                del self._challengers[min(range(len(self._challengers)), key=lambda i: self._challengers[i][2])]
        ch = self._challengers
        k = max(range(len(ch)), key=lambda i: (ch[i][2], -np.trace(ch[i][1])))  # most support, then most precise
        best = ch[k]
        if best[2] > self.num_fused or self._consecutive >= self.max_rejections:
            self._challengers[k] = [self.dir, self.P, self.num_fused]  # the old state may come back
            self.dir, self.P, self.num_fused = best[0], best[1], best[2]
            self.num_rejected, self._consecutive = 0, 0
            return best is mine  # a takeover by another challenger still leaves this estimate out
        return False


def _chart_change(src_dir, dst_dir):
    """2x2 map from tangent coordinates at src_dir to those at dst_dir (first order)."""
    return tangent_basis(dst_dir).T @ tangent_basis(src_dir)


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def roll_pitch_from_gravity(gravity: np.ndarray, cov_tangent: np.ndarray | None = None):
    """Roll and pitch (rad) of the body (x forward, y left, z up) from gravity in the body frame.

    A level body has gravity (0, 0, -|g|). Returns (roll, pitch, quaternion xyzw of
    R_z(0) R_y(pitch) R_x(roll), 2x2 covariance of (roll, pitch) in rad^2 or None).
    """
    gx, gy, gz = normalize(np.asarray(gravity, dtype=float))
    roll = math.atan2(-gy, -gz)
    pitch = math.atan2(gx, math.hypot(gy, gz))
    Rb = exp_so3(np.array([0.0, pitch, 0.0])) @ exp_so3(np.array([roll, 0.0, 0.0]))
    q = matrix_to_quat_xyzw(Rb)
    cov = None
    if cov_tangent is not None:
        n = np.array([gx, gy, gz])
        eps = 1e-7
        J = np.zeros((2, 2))
        for k in range(2):
            d = np.zeros(2)
            d[k] = eps
            gp = sphere_exp(n, d)
            gm_ = sphere_exp(n, -d)
            rp = np.array([math.atan2(-gp[1], -gp[2]), math.atan2(gp[0], math.hypot(gp[1], gp[2]))])
            rm = np.array([math.atan2(-gm_[1], -gm_[2]), math.atan2(gm_[0], math.hypot(gm_[1], gm_[2]))])
            J[:, k] = (rp - rm) / (2 * eps)
        cov = J @ np.asarray(cov_tangent) @ J.T
    return roll, pitch, q, cov
