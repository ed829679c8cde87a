"""Robust two-view bundle adjustment over (R, t, g, points) with the bending model.

Implements the refinement of SPEC section 5 (paper eq. 15): Huber loss on
angular (tangent-plane) residuals of both views, gravity on the sphere
(2 d.o.f., |g| fixed), rotation as a right perturbation R Exp(dr), points in
view 1's body frame. The points are eliminated per correspondence by a Schur
complement of 3x3 blocks, so one Levenberg-Marquardt iteration is O(N).
Optionally, measured gravity in both views enters as a prior (4pt-bending).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .deformation import deformation_jacobians
from .residuals import triangulate_midpoint
from .rig import Rig
from .so3 import cross, exp_so3, normalize, right_jacobian, skew, tangent_basis


@dataclass
class GravityPrior:
    """Measured gravity of both views (body frames) with angular std sigma_rad."""

    g1: np.ndarray
    g2: np.ndarray
    sigma_rad: float


@dataclass
class BundleResult:
    R: np.ndarray
    t: np.ndarray
    g: np.ndarray | None
    points: np.ndarray
    cost: float
    iterations: int
    sigma_rad: float  # robust estimate of the angular noise (rad)
    covariance: np.ndarray  # (nc, nc) over (dr, t[, dg]) in rad, m, rad


class TwoViewProblem:
    """Residuals and Jacobians of the two-view problem for fixed observations."""

    def __init__(self, rig: Rig, f1, f2, cam, optimize_gravity: bool, prior: GravityPrior | None = None,
                 compliance_groups: np.ndarray | None = None):
        """compliance_groups (M,) maps each camera to a compliance parameter (-1: none); those
        Jacobian columns follow (dr, t[, dg]) and are used by the bar calibration."""
        self.rig = rig
        self.f1, self.f2, self.cam = f1, f2, cam
        # residual = T^T p/|p| (2D, tangent plane of f), both views stacked: (N, 2 views, 2, 3)
        self.Tt = np.swapaxes(tangent_basis(np.stack([f1, f2], axis=1)), -1, -2)
        self.optimize_gravity = optimize_gravity
        self.prior = prior
        self.nc = 8 if optimize_gravity else 6
        self.groups = None
        if compliance_groups is not None:
            self.groups = np.asarray(compliance_groups, dtype=int)
            self.nk = int(self.groups.max()) + 1
            self.nc += self.nk
        self.gm = rig.gravity_magnitude
        self._cache = {}
        self.D = rig.bar_derivatives[0][cam]  # d w / d g of each correspondence's camera (constant)
        if prior is not None:
            self.P1 = tangent_basis(normalize(prior.g1))
            self.P2 = tangent_basis(normalize(prior.g2))

    # -- model --------------------------------------------------------------
    @staticmethod
    def _residual_jac(p, Tt, want_jacobian=True):
        """e = T^T p/|p| (N, 4) and de/dp = T^T (I - n n^T)/|p| (N, 2, 2, 3) of both views' points p (N, 2, 3)
        (Tt = T^T, (N, 2, 2, 3))."""
        inv_r = 1.0 / np.maximum(np.sqrt(np.einsum("nvi,nvi->nv", p, p)), 1e-300)
        n = p * inv_r[:, :, None]
        e = np.einsum("nvij,nvj->nvi", Tt, n)
        if not want_jacobian:
            return e.reshape(-1, 4), None
        Je = Tt - e[:, :, :, None] * n[:, :, None, :]
        Je *= inv_r[:, :, None, None]
        return e.reshape(-1, 4), Je

    def _model(self, g):
        """Per correspondence (w, W^T, D, K) of its camera at gravity g (SPEC 3), cached for the last few g
        (each LM step reuses them)."""
        key = np.asarray(g, dtype=float).tobytes()
        hit = self._cache.get(key)
        if hit is None:
            w, W, _, K = deformation_jacobians(self.rig, g)
            c = self.cam
            hit = (w[c], np.swapaxes(W, 1, 2)[c], self.D, K[c])
            if len(self._cache) >= 8:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = hit
        return hit

    def evaluate(self, R, t, g, P, want_jacobian=True):
        """Residuals e (N, 4) and, if asked, Jc (N, 4, nc), Jp (N, 4, 3) (want_jacobian="points": Jp only).

        Uses a^T [y]_x = (a x y)^T row-wise, so the chain rule runs on 2x3 blocks.
        """
        gg = g if g is not None else np.array([0.0, 0.0, -self.gm])
        g2 = R.T @ gg
        z = (P - t) @ R  # R^T (P - t)
        w1, W1t, _, _ = self._model(gg)
        w2, W2t, _, _ = self._model(g2)
        N = len(P)
        y1, y2 = P - w1, z - w2  # points relative to the bent camera centres, each view's body frame
        p = np.empty((N, 2, 3))  # ... in the bent cameras: p = W^T y
        p[:, 0] = np.einsum("nij,nj->ni", W1t, y1)
        p[:, 1] = np.einsum("nij,nj->ni", W2t, y2)
        e, Je = self._residual_jac(p, self.Tt, want_jacobian)
        if not want_jacobian:
            return e, None, None
        Jp = np.empty((N, 4, 3))
        A1 = Je[:, 0] @ W1t  # de1/dP
        A2 = Je[:, 1] @ W2t  # de2/dy2
        Jp[:, :2] = A1
        Jp[:, 2:] = (A2.reshape(-1, 3) @ R.T).reshape(N, 2, 3)  # constant right factors: one 2-D product
        if want_jacobian == "points":
            return e, None, Jp
        Jc = np.zeros((N, 4, self.nc))
        dr2 = skew(z)  # rows a^T [z]_x = (a x z)^T
        Jc[:, 2:, 3:6] = -Jp[:, 2:]
        dy2_dg2 = None
        if self.rig.is_flexible:
            dy2_dg2 = self._dy_dg(y2, g2)
            dr2 += (dy2_dg2.reshape(-1, 3) @ skew(g2)).reshape(N, 3, 3)
        Jc[:, 2:, 0:3] = A2 @ dr2
        if self.groups is not None:
            self._compliance_columns(Jc, Je[:, 0], W1t, y1, gg, Je[:, 1], W2t, y2, g2)
        if self.optimize_gravity and dy2_dg2 is not None:
            B = self.gm * tangent_basis(normalize(gg))
            Jc[:, :2, 6:8] = A1 @ (self._dy_dg(y1, gg).reshape(-1, 3) @ B).reshape(N, 3, 2)
            Jc[:, 2:, 6:8] = A2 @ (dy2_dg2.reshape(-1, 3) @ (R.T @ B)).reshape(N, 3, 2)
        return e, Jc, Jp

    def _dy_dg(self, y, g):
        """d(W^T y)/dg expressed before W^T: [y]_x K - D (N, 3, 3), so de/dg = A ([y]_x K - D) for de/dy = A
        (model derivatives at g, SPEC 3)."""
        _, _, D, K = self._model(g)
        return skew(y) @ K - D

    def _compliance_columns(self, Jc, Je1, W1t, y1, g1, Je2, W2t, y2, g2):
        """d residual / d compliance k_i: d(W^T y)/dk = W^T [y]_x J_r(-phi) phi/k, dw/dk = delta/k."""
        u, _, _ = self.rig.bar_coefficients
        k = self.rig.compliance
        L = np.linalg.norm(self.rig.positions, axis=1)
        cols = self.groups[self.cam]
        has = cols >= 0
        first = self.nc - self.nk
        for Je, Wt, y, g, rows in ((Je1, W1t, y1, g1, slice(0, 2)), (Je2, W2t, y2, g2, slice(2, 4))):
            a = (L**2 / 2.0)[:, None] * cross(u, g[None, :])  # phi / k
            phi = k[:, None] * a
            A = np.einsum("mij,mj->mi", right_jacobian(-phi), a)
            b = (L**3 / 3.0)[:, None] * (g[None, :] - np.sum(u * g, axis=1, keepdims=True) * u)  # delta / k
            dp = np.einsum("nij,nj->ni", Wt, cross(y, A[self.cam]) - b[self.cam])
            de = np.einsum("nij,nj->ni", Je, dp)
            idx = np.flatnonzero(has)
            Jc[idx, rows, first + cols[idx]] = de[idx]

    def triangulate(self, R, t, g):
        """Midpoint triangulation at (R, t, g); points behind a camera or from parallel rays go far along ray 1."""
        gg = g if g is not None else np.array([0.0, 0.0, -self.gm])
        o1, W1t, _, _ = self._model(gg)
        o2, W2t, _, _ = self._model(R.T @ gg)
        d1 = (self.f1[:, None, :] @ W1t)[:, 0]  # W f = (f^T W^T)^T
        d2 = (self.f2[:, None, :] @ W2t)[:, 0]
        P, s, u, par = triangulate_midpoint(o1, d1, o2, d2, R, t)
        bad = par | (s <= 0) | (u <= 0)
        return np.where(bad[:, None], o1 + 1e3 * d1, P)

    def point_chart(self, g, P) -> InverseDepthChart:
        """Inverse-depth chart of the points in their view-1 cameras, bent at g (the linearisation point)."""
        w, Wt, _, _ = self._model(g if g is not None else np.array([0.0, 0.0, -self.gm]))
        return InverseDepthChart(w, Wt, P)

    def prior_terms(self, R, g):
        """Prior residuals (4,) and Jacobian (4, nc), already divided by sigma."""
        pr = self.prior
        gh = normalize(g)
        B = tangent_basis(gh)
        g2h = R.T @ gh
        r = np.concatenate([self.P1.T @ gh, self.P2.T @ g2h]) / pr.sigma_rad
        J = np.zeros((4, self.nc))
        J[2:, 0:3] = self.P2.T @ skew(g2h)  # gravity columns are 6:8 (compliance, if any, after)
        J[:2, 6:8] = self.P1.T @ B
        J[2:, 6:8] = self.P2.T @ (R.T @ B)
        return r, J / pr.sigma_rad

    def update(self, R, t, g, dc):
        """Apply the step of (dr, t[, dg]); compliance steps are applied by the caller, point steps by the chart."""
        R = R @ exp_so3(dc[0:3])
        t = t + dc[3:6]
        if self.optimize_gravity:
            gh = normalize(g)
            g = self.gm * normalize(gh + tangent_basis(gh) @ dc[6:8])
        return R, t, g


class InverseDepthChart:
    """Local coordinates q = (a, b, rho) of each point in its view-1 camera, frozen at the linearisation point:
    P = w + W (a, b, 1) / rho.

    Residuals of distant (low-parallax) points are nearly linear in the inverse
    depth rho but not in P, so Levenberg-Marquardt point steps taken in this
    chart stay valid where Euclidean steps overshoot. The Schur complement, and
    so the covariance of (R, t, g), does not depend on the chart. Points not in
    front of their camera keep Euclidean coordinates.
    """

    def __init__(self, w, Wt, P):
        """w (N, 3), Wt (N, 3, 3): bent centre and W^T of each point's view-1 camera; P (N, 3)."""
        self.w, self.W, self.P = w, np.swapaxes(Wt, 1, 2), P
        X = np.einsum("nij,nj->ni", Wt, P - w)
        z = X[:, 2]
        self.front = z > 1e-9 * np.linalg.norm(X, axis=1) + 1e-12
        zs = np.where(self.front, z, 1.0)
        self.q = np.stack([X[:, 0] / zs, X[:, 1] / zs, 1.0 / zs], axis=1)
        L = np.zeros((len(P), 3, 3))  # d(a/rho, b/rho, 1/rho) / d(a, b, rho)
        L[:, 0, 0] = L[:, 1, 1] = zs
        L[:, 0, 2] = -X[:, 0] * zs
        L[:, 1, 2] = -X[:, 1] * zs
        L[:, 2, 2] = -zs * zs
        self.M = np.where(self.front[:, None, None], self.W @ L, np.eye(3))  # dP/dq

    def retract(self, dq):
        """Points after a step dq in the chart; rho may shrink at most 100-fold per step (no jump through infinity)."""
        q = self.q + dq
        rho = np.maximum(q[:, 2], 1e-2 * self.q[:, 2])
        X = np.stack([q[:, 0], q[:, 1], np.ones(len(q))], axis=1) / rho[:, None]
        P_chart = self.w + np.einsum("nij,nj->ni", self.W, X)
        return np.where(self.front[:, None], P_chart, self.P + dq)


def inv3(A: np.ndarray, diag: np.ndarray | float = 0.0) -> np.ndarray:
    """Inverse of a batch of symmetric positive semi-definite 3x3 matrices (N, 3, 3), with ``diag`` (N, 3)
    or a scalar added to their diagonals first, by the adjugate (much faster than np.linalg.inv).

    Only the upper triangle is read (the normal-equation blocks J^T J are symmetric). A singular block
    gets a huge inverse, not NaN.
    """
    diag = np.broadcast_to(diag, (len(A), 3))
    a, d, f = A[:, 0, 0] + diag[:, 0], A[:, 1, 1] + diag[:, 1], A[:, 2, 2] + diag[:, 2]
    b, c, e = A[:, 0, 1], A[:, 0, 2], A[:, 1, 2]
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * c00 + b * c01 + c * c02
    floor = 1e-14 * np.maximum(np.maximum(a, d), f) ** 3 + 1e-300  # semi-definite: no entry exceeds these
    inv_det = 1.0 / np.where(np.abs(det) > floor, det, floor)
    out = np.empty(A.shape)
    out[:, 0, 0], out[:, 1, 1], out[:, 2, 2] = c00 * inv_det, c11 * inv_det, c22 * inv_det
    out[:, 0, 1] = out[:, 1, 0] = c01 * inv_det
    out[:, 0, 2] = out[:, 2, 0] = c02 * inv_det
    out[:, 1, 2] = out[:, 2, 1] = c12 * inv_det
    return out


def _sum_outer(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """sum_n A_n B_n^T for batches (N, k, 3) -> (k, k)."""
    return np.swapaxes(A, 0, 1).reshape(A.shape[1], -1) @ np.swapaxes(B, 0, 1).reshape(B.shape[1], -1).T


def _view_norms(e: np.ndarray) -> np.ndarray:
    """Norms (N, 2) of each view's 2-D residual in e (N, 4)."""
    e = e.reshape(-1, 2, 2)
    return np.sqrt(np.einsum("nvi,nvi->nv", e, e))


def _huber(r_norm, delta):
    """Huber cost and IRLS weights of residual norms."""
    quad = r_norm <= delta
    cost = np.where(quad, 0.5 * r_norm**2, delta * (r_norm - 0.5 * delta))
    weight = np.divide(delta, r_norm, out=np.ones_like(r_norm), where=~quad)
    return cost, weight


def robust_sigma(e: np.ndarray, num_params: int = 0, floor: float = 1e-9) -> float:
    """MAD-based std (rad) of the angular noise behind residual components e (N, 4).

    Each point absorbs 3 of its 4 residuals, so the residual spread is
    corrected by sqrt(n_res / (n_res - n_params)) with n_params = 3N + num_params.
    """
    n_res = e.size
    dof = max(n_res - 3 * len(e) - num_params, 1)
    med = np.median(np.abs(e))
    return max(1.4826 * float(med) * np.sqrt(n_res / dof), floor)


COST_TOL = 1e-2  # chi^2/2 units: a cost change this small moves the parameters by about 0.1 sigma


class Solver:
    """Levenberg-Marquardt on a TwoViewProblem with Huber weights and residuals scaled by sigma."""

    def __init__(self, prob: TwoViewProblem, sigma: float, huber_k: float):
        self.prob = prob
        self.sigma = sigma
        self.delta = huber_k  # Huber threshold in units of sigma

    point_iterations = 1  # embedded point iterations for a step whose linear point update failed
    initial_damping = 1e-4  # Levenberg-Marquardt lambda (relative to the diagonal) and its factors
    damping_up = 10.0
    damping_down = 10.0

    def refine_points(self, R, t, g, P, iterations, e=None):
        """Gauss-Newton on each point alone for fixed (R, t, g): independent 3x3 systems, vectorised.

        Re-optimising the points after each camera step (embedded point
        iterations) keeps the LM step valid where the linear point update is
        not (low parallax). A point stuck far off (e.g. started at infinity)
        first restarts from triangulation. Returns the points and their
        residuals in units of sigma (``e``: those at P, when the caller has them).
        """
        if e is None:
            e = self.prob.evaluate(R, t, g, P, want_jacobian=False)[0] / self.sigma
        if iterations:
            P_tri = self.prob.triangulate(R, t, g)
            e_tri = self.prob.evaluate(R, t, g, P_tri, want_jacobian=False)[0] / self.sigma
            use_tri = self._point_costs(e_tri) < self._point_costs(e)
            P = np.where(use_tri[:, None], P_tri, P)
            e = np.where(use_tri[:, None], e_tri, e)
        for _ in range(iterations):
            _, _, Jp = self.prob.evaluate(R, t, g, P, want_jacobian="points")
            chart = self.prob.point_chart(g, P)
            c0, wts = _huber(_view_norms(e), self.delta)
            sw = np.sqrt(np.repeat(wts, 2, axis=1))
            Jw = (Jp @ chart.M) * (sw / self.sigma)[:, :, None]
            H = np.swapaxes(Jw, 1, 2) @ Jw
            b = -np.einsum("nki,nk->ni", Jw, e * sw)
            Pn = chart.retract(np.einsum("nij,nj->ni", inv3(H, 1e-12), b))
            en = self.prob.evaluate(R, t, g, Pn, want_jacobian=False)[0] / self.sigma
            better = self._point_costs(en) < c0.sum(axis=1)  # a point keeps its step only if it helps it
            P = np.where(better[:, None], Pn, P)
            e = np.where(better[:, None], en, e)
        return P, e

    def _point_costs(self, e):
        """Huber cost of each point's residuals (in units of sigma)."""
        c, _ = _huber(_view_norms(e), self.delta)
        return c.sum(axis=1)

    def cost(self, R, t, g, P):
        return self._residuals_and_cost(R, t, g, P)[1]

    def _residuals_and_cost(self, R, t, g, P):
        """Residuals in units of sigma (N, 4) and the robust cost (chi^2 / 2 units, prior included)."""
        e = self.prob.evaluate(R, t, g, P, want_jacobian=False)[0] / self.sigma
        return e, self._cost_from(e, R, g)

    def _cost_from(self, e, R, g):
        """Cost of residuals e already in units of sigma."""
        r = _view_norms(e)
        c, _ = _huber(r, self.delta)
        total = float(c.sum())
        if self.prob.prior is not None:
            rp, _ = self.prob.prior_terms(R, g)
            total += 0.5 * float(rp @ rp)
        return total

    def normal_equations(self, R, t, g, P):
        """Cost and normal equations at (R, t, g, P); the point blocks are in the inverse-depth chart
        ``self.chart`` of P (see :meth:`step`)."""
        e, Jc, Jp = self.prob.evaluate(R, t, g, P)
        self.chart = self.prob.point_chart(g, P)
        e = e / self.sigma
        c, wts = _huber(_view_norms(e), self.delta)
        sw = np.sqrt(np.repeat(wts, 2, axis=1))  # (N, 4)
        ew = e * sw
        sw /= self.sigma  # the Jacobians are scaled by 1/sigma like the residuals
        Jcw = Jc * sw[:, :, None]
        Jpw = (Jp @ self.chart.M) * sw[:, :, None]
        Jc2 = Jcw.reshape(-1, Jcw.shape[2])
        Hcc = Jc2.T @ Jc2
        bc = -(ew.reshape(-1) @ Jc2)
        JpT = np.swapaxes(Jpw, 1, 2)
        Hcp = np.swapaxes(Jcw, 1, 2) @ Jpw
        Hpp = JpT @ Jpw
        bp = -np.einsum("nki,nk->ni", Jpw, ew)
        cost = float(c.sum())
        if self.prob.prior is not None:
            rp, Jpr = self.prob.prior_terms(R, g)
            Hcc = Hcc + Jpr.T @ Jpr
            bc = bc - Jpr.T @ rp
            cost += 0.5 * float(rp @ rp)
        return cost, Hcc, bc, Hcp, Hpp, bp

    @staticmethod
    def reduced_system(Hcc, bc, Hcp, Hpp, bp, lam):
        """Damped normal equations with the points eliminated: S dc = rhs (plus what back-substitution needs)."""
        nc = len(bc)
        Hcc_d = Hcc + lam * np.diag(np.diag(Hcc)) + 1e-12 * np.eye(nc)
        dpp = np.diagonal(Hpp, axis1=1, axis2=2)
        Hpp_inv = inv3(Hpp, lam * dpp + 1e-12)
        HcpHi = Hcp @ Hpp_inv  # (N, nc, 3)
        S = Hcc_d - _sum_outer(HcpHi, Hcp)
        rhs = bc - np.swapaxes(HcpHi, 0, 1).reshape(nc, -1) @ bp.reshape(-1)
        return S, rhs, Hpp_inv

    def step(self, R, t, g, dc, dq):
        """State after a step: (dr, t[, dg]) on the cameras, dq in the chart of the last normal equations."""
        return (*self.prob.update(R, t, g, dc), self.chart.retract(dq))

    @staticmethod
    def back_substitute(Hcp, Hpp_inv, bp, dc):
        """Point steps for a camera-block step dc."""
        return (Hpp_inv @ (bp - np.swapaxes(Hcp, 1, 2) @ dc)[:, :, None])[:, :, 0]

    def solve_damped(self, Hcc, bc, Hcp, Hpp, bp, lam):
        """Camera and point steps of the damped system; ``self.camera_decrease`` is the cost decrease the
        camera step alone predicts (points re-fitted: dc^T S dc / 2, chi^2/2 units)."""
        S, rhs, Hpp_inv = self.reduced_system(Hcc, bc, Hcp, Hpp, bp, lam)
        try:
            dc = np.linalg.solve(S, rhs)
        except np.linalg.LinAlgError:
            dc = np.linalg.lstsq(S, rhs, rcond=None)[0]
        self.camera_decrease = 0.5 * float(dc @ S @ dc)
        return dc, self.back_substitute(Hcp, Hpp_inv, bp, dc)

    def reduced_information(self, R=None, t=None, g=None, P=None):
        """Schur complement of the undamped normal equations (Fisher information of the camera block).

        Without arguments, at the point where the last ``run`` stopped.
        """
        if R is None:
            Hcc, _, Hcp, Hpp, _ = self.system
        else:
            _, Hcc, _, Hcp, Hpp, _ = self.normal_equations(R, t, g, P)
        Hpp_inv = inv3(Hpp, 1e-12)
        return Hcc - _sum_outer(Hcp @ Hpp_inv, Hcp)

    def run(self, R, t, g, P, max_iter, tol=1e-6, reestimate_sigma_after: int | None = None):
        """LM iterations; optionally re-estimate sigma (robustly) after that many accepted steps, and again
        whenever it has changed by more than half since (the Huber zone follows the shrinking residuals).

        Stops when a step changes the cost by less than ``COST_TOL`` (or tol relative), or when the camera
        block's part of the step would (``camera_decrease``), i.e. moves the parameters of interest by a
        negligible fraction of their standard deviation. The normal equations at the
        returned point are kept in ``self.system``.
        """
        lam = self.initial_damping
        cost, Hcc, bc, Hcp, Hpp, bp = self.normal_equations(R, t, g, P)
        it = accepted = 0
        while it < max_iter:
            it += 1
            dc, dP = self.solve_damped(Hcc, bc, Hcp, Hpp, bp, lam)
            Rn, tn, gn, Pn = self.step(R, t, g, dc, dP)
            e, new_cost = self._residuals_and_cost(Rn, tn, gn, Pn)
            if not new_cost <= cost and self.point_iterations:
                # the linear point update failed (low parallax is very nonlinear): re-fit the points to the new
                # camera block before judging the step (embedded point iterations)
                Pn, e = self.refine_points(Rn, tn, gn, Pn, self.point_iterations, e)
                new_cost = self._cost_from(e, Rn, gn)
            if not (np.isfinite(new_cost) and new_cost <= cost):
                if new_cost - cost < COST_TOL:
                    break  # at the minimum: the step only sees rounding
                lam = max(lam * self.damping_up, self.initial_damping)  # after many good steps lam may be tiny
                if lam > 1e8:
                    break
                continue
            # converged when the cost barely changes, or when what still changes is only the points (far ones
            # creep along their rays) while the cameras move by a negligible fraction of their uncertainty
            converged = (cost - new_cost < max(tol * cost, COST_TOL) or np.linalg.norm(dc) < tol
                         or self.camera_decrease < COST_TOL)
            R, t, g, P = Rn, tn, gn, Pn
            accepted += 1
            lam = max(lam / self.damping_down, 1e-9)
            if reestimate_sigma_after is not None:
                converged = converged and accepted >= reestimate_sigma_after  # sigma must fit the residuals first
            if reestimate_sigma_after is not None and accepted >= reestimate_sigma_after:
                new_sigma = robust_sigma(e * self.sigma, self.prob.nc)
                if accepted == reestimate_sigma_after or abs(new_sigma / self.sigma - 1.0) > 0.5:
                    converged = converged and abs(new_sigma / self.sigma - 1.0) < tol  # the cost changed meaning
                    self.sigma = new_sigma
            cost, Hcc, bc, Hcp, Hpp, bp = self.normal_equations(R, t, g, P)
            if converged:
                break
        self.system = (Hcc, bc, Hcp, Hpp, bp)
        return R, t, g, P, cost, it


def refine_two_view(
    rig: Rig,
    f1,
    f2,
    cam,
    R,
    t,
    g=None,
    points=None,
    optimize_gravity: bool = True,
    prior: GravityPrior | None = None,
    max_iter: int = 30,
    huber_k: float = 3.0,
    sigma_rad: float | None = None,
    tol: float = 1e-6,
) -> BundleResult:
    """Robust bundle adjustment of (R, t[, g], points) on correspondences (f1, f2, cam).

    g is the starting gravity (body frame of view 1); it is kept with
    |g| = gravity_magnitude. With optimize_gravity=False, g stays fixed (and
    for a rigid rig is irrelevant). ``sigma_rad`` is the angular noise used to
    scale residuals and the Huber threshold (huber_k * sigma); by default it is
    estimated robustly from the residuals at the start and re-estimated as they
    shrink. ``tol``: relative cost decrease below which the iterations stop
    (a loose one suffices to compare starts). Returns the covariance of
    (dr, t[, dg]) from the reduced normal equations.
    """
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    gm = rig.gravity_magnitude
    if g is None:
        optimize_gravity = False
    else:
        g = gm * normalize(np.asarray(g, dtype=float))
    if prior is not None and not optimize_gravity:
        prior = None
    prob = TwoViewProblem(rig, f1, f2, cam, optimize_gravity, prior)
    P = prob.triangulate(R, t, g) if points is None else np.array(points, dtype=float)
    fixed_sigma = sigma_rad is not None
    if not fixed_sigma:  # start at the noise level of the start, re-estimate it once the fit has settled
        e0, _, _ = prob.evaluate(R, t, g, P, want_jacobian=False)
        sigma_rad = robust_sigma(e0, prob.nc)
    solver = Solver(prob, sigma_rad, huber_k)
    R, t, g, P, cost, it = solver.run(R, t, g, P, max_iter, tol=tol,
                                      reestimate_sigma_after=None if fixed_sigma else 2)
    sigma_rad = solver.sigma
    info_mat = solver.reduced_information()
    try:
        cov = np.linalg.inv(info_mat)
    except np.linalg.LinAlgError:
        cov = np.full_like(info_mat, np.inf)
    return BundleResult(R=R, t=t, g=g if optimize_gravity else None, points=P, cost=cost, iterations=it,
                        sigma_rad=float(sigma_rad), covariance=cov)


def gravity_covariance(g, cov_dg) -> np.ndarray:
    """3x3 covariance of g (m^2/s^4) from the 2x2 tangent covariance of the chart (rad^2)."""
    B = np.linalg.norm(g) * tangent_basis(normalize(g))
    return B @ cov_dg @ B.T
