"""One Levenberg-Marquardt for every least-squares problem of the project, with a Schur hook for points.

A problem has a small dense *camera block* (poses, gravity, bar compliances,
...) and, optionally, many *points* of 3 parameters each, every observation
touching one point and a few camera columns. The normal equations are
accumulated per observation (:class:`SchurStructure`), the points are
eliminated by a Schur complement of 3x3 blocks, so an iteration costs
O(observations x track length) and never forms a matrix of points x points
(docs/ARCHITECTURE.md, "The estimation core").

A problem plugs in with four methods (PoseLib's pattern of writing the loop
once)::

    linearize(state) -> LinearSystem      # cost and normal equations at state
    cost(state) -> float                  # cost only (step acceptance)
    step(state, dc, dp) -> state          # apply a camera step dc and point steps dp (P, 3)
    refit_points(state) -> (state, cost)  # optional: re-fit points alone after a failed step

The cost's meaning (its noise scale, its weights) is fixed for one run; a
caller that re-estimates the noise does so between runs (the bundle
adjustment runs one accepted step at a time while it does,
``LMOptions.max_accepted``, and resumes with the normal equations and the
damping the previous run ended with). Nothing is kept between calls:
:func:`levenberg_marquardt` returns the final state, the normal equations
there (for covariances) and its statistics whole (:class:`LMStats`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np


def inv3(A: np.ndarray, diag: np.ndarray | float = 0.0) -> np.ndarray:
    """Inverse of a batch of symmetric positive semi-definite 3x3 matrices (N, 3, 3), with ``diag`` (N, 3)
    or a scalar added to their diagonals first.

    Well-conditioned blocks go through the adjugate (much faster than np.linalg.inv); the few
    ill-conditioned ones (a landmark whose depth the data hardly fix) through a symmetric pseudo-inverse,
    where the adjugate's cancellation would corrupt the Schur complement. A block with a NaN or an infinite
    entry has a NaN inverse (its callers drop such landmarks). Only the upper triangle is read.
    """
    with np.errstate(invalid="ignore"):  # a block with NaN or infinite entries gives NaN, then set so
        return _inv3(A, np.broadcast_to(diag, (len(A), 3)))


def _inv3(A: np.ndarray, diag: np.ndarray) -> np.ndarray:
    a, d, f = A[:, 0, 0] + diag[:, 0], A[:, 1, 1] + diag[:, 1], A[:, 2, 2] + diag[:, 2]
    # each block scaled by its largest diagonal entry (semi-definite: no entry exceeds it), so that the cofactors
    # and the determinant neither overflow nor underflow whatever the block's scale (a landmark next to a
    # camera's centre has entries beyond 1e100); the inverse is the scaled block's over that scale
    scale = np.maximum(np.maximum(a, d), f)
    scale = np.where(scale > 0, scale, 1.0)
    a, d, f = a / scale, d / scale, f / scale
    b, c, e = A[:, 0, 1] / scale, A[:, 0, 2] / scale, A[:, 1, 2] / scale
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * c00 + b * c01 + c * c02
    floor = 1e-14  # of the scaled block, whose largest entry is 1
    inv_det = 1.0 / (np.where(np.abs(det) > floor, det, floor) * scale)
    out = np.empty(A.shape)
    out[:, 0, 0], out[:, 1, 1], out[:, 2, 2] = c00 * inv_det, c11 * inv_det, c22 * inv_det
    out[:, 0, 1] = out[:, 1, 0] = c01 * inv_det
    out[:, 0, 2] = out[:, 2, 0] = c02 * inv_det
    out[:, 1, 2] = out[:, 2, 1] = c12 * inv_det
    finite = np.isfinite(det)  # not a block with NaN or infinite entries (a ray from a failed pose): NaN out
    out[~finite] = np.nan
    ill = finite & (np.abs(det) < ILL_CONDITIONED)
    if ill.any():
        B = np.array(A[ill])
        idx = np.arange(3)
        B[:, idx, idx] += diag[ill]
        B = np.triu(B) + np.swapaxes(np.triu(B, 1), 1, 2)
        out[ill] = np.linalg.pinv(B, rcond=1e-12, hermitian=True)
    return out


ILL_CONDITIONED = 1e-9  # det below this share of the largest diagonal entry cubed: eigen-decomposition instead


DENSE_COST_RATIO = 20.0  # a GEMM flop costs about this much less than a scattered (bincount) entry
DENSE_JACOBIAN_ENTRIES = 1 << 20  # observations x (camera parameters + 1) up to which J^T J comes from a GEMM
# ... when the camera block has at most this many columns per local column: a GEMM over a wider, mostly zero
# Jacobian (many views) costs more than scattering each observation's local products
DENSE_JACOBIAN_WIDTH = 3


class SchurStructure:
    """Which camera columns and which point every observation touches (constant over the iterations).

    ``cols`` (N, L): the camera-block columns of each observation's local Jacobian (the value
    ``num_params`` marks a column that does not exist for it, e.g. the pose of a fixed view);
    ``point`` (N,): its point index in 0..num_points-1, or None for a problem without points.
    The scatter indices of J^T J (per observation) and of the Schur complement (per pair of observations
    of one point) are computed once here.
    """

    def __init__(self, cols: np.ndarray, num_params: int, point: np.ndarray | None = None,
                 num_points: int = 0):
        self.cols = np.asarray(cols, dtype=np.int64)
        self.nc = int(num_params)
        n1 = self.nc + 1  # one spare row/column collects the non-existing entries
        self._n1 = n1
        N, L = self.cols.shape
        # J^T J: from a dense (rows, nc) Jacobian when it is small, else scattered per observation
        self._dense_jacobian = N * n1 <= DENSE_JACOBIAN_ENTRIES and n1 <= DENSE_JACOBIAN_WIDTH * L
        if self._dense_jacobian:
            self._jc = (np.arange(N)[:, None] * n1 + self.cols).reshape(-1)
        else:
            self._cc = (self.cols[:, :, None] * n1 + self.cols[:, None, :]).reshape(-1)
        self.point = None if point is None else np.asarray(point, dtype=np.int64)
        self.num_points = int(num_points)
        self.dense = False
        if self.point is None:
            return
        sizes = np.bincount(self.point, minlength=self.num_points)
        # The coupling of the camera block with each point, Hcp (P, nc, 3), is formed densely when that is
        # cheaper than scattering the products of every pair of observations of a point
        self.dense = self.num_points * n1 * n1 * 3 <= DENSE_COST_RATIO * float(np.sum(sizes**2)) * L * L
        if self.dense:
            self._pc = ((self.point[:, None] * n1 + self.cols)[:, :, None] * 3 + np.arange(3)).reshape(-1)
            return
        order = np.argsort(self.point, kind="stable")
        starts = np.cumsum(sizes) - sizes
        ps = self.point[order]
        rep = sizes[ps]  # each observation pairs with every observation of its point, itself included
        self.pair_a = np.repeat(order, rep)
        within = np.arange(int(rep.sum())) - np.repeat(np.cumsum(rep) - rep, rep)
        self.pair_b = order[np.repeat(starts[ps], rep) + within]
        ca, cb = self.cols[self.pair_a], self.cols[self.pair_b]
        self._pair_cc = (ca[:, :, None] * n1 + cb[:, None, :]).reshape(-1)

    def _square(self, flat_index: np.ndarray, values: np.ndarray) -> np.ndarray:
        n1 = self._n1
        H = np.bincount(flat_index, weights=values.reshape(-1), minlength=n1 * n1).reshape(n1, n1)
        return H[: self.nc, : self.nc]

    def _vector(self, values: np.ndarray) -> np.ndarray:
        return np.bincount(self.cols.reshape(-1), weights=values.reshape(-1), minlength=self._n1)[: self.nc]

    def accumulate(self, Jc: np.ndarray, e: np.ndarray, Jp: np.ndarray | None = None) -> LinearSystem:
        """Normal equations of weighted residuals e (N, r) with camera Jacobians Jc (N, r, L) and point
        Jacobians Jp (N, r, 3) (already multiplied by the square roots of the robust weights)."""
        JcT = np.swapaxes(Jc, 1, 2)
        if self._dense_jacobian:
            N, r, L = Jc.shape
            n1 = self._n1
            J = np.zeros((N * n1, r))
            J[self._jc] = JcT.reshape(-1, r)  # an observation's existing columns are distinct; the spare is dropped
            J = J.reshape(N, n1, r).transpose(0, 2, 1).reshape(N * r, n1)[:, : self.nc]
            Hcc = J.T @ J
            bc = -(e.reshape(-1) @ J)
        else:
            Hcc = self._square(self._cc, JcT @ Jc)
            bc = -self._vector(np.einsum("nlr,nr->nl", JcT, e))
        if Jp is None or self.point is None:
            return LinearSystem(cost=0.0, Hcc=Hcc, bc=bc)
        JpT = np.swapaxes(Jp, 1, 2)
        P = self.num_points
        Hpp = group_sum(self.point, JpT @ Jp, P)
        bp = -group_sum(self.point, np.einsum("nkr,nr->nk", JpT, e), P)
        W = JcT @ Jp  # (N, L, 3) coupling of each observation's camera columns with its point
        return LinearSystem(cost=0.0, Hcc=Hcc, bc=bc, Hpp=Hpp, bp=bp, W=W, structure=self)

    def _coupling(self, W: np.ndarray) -> np.ndarray:
        """Dense Hcp (P, nc, 3) from the per-observation couplings W (N, L, 3)."""
        n1 = self._n1
        Hcp = np.bincount(self._pc, weights=W.reshape(-1), minlength=self.num_points * n1 * 3)
        return Hcp.reshape(self.num_points, n1, 3)[:, : self.nc]

    def reduce(self, system: LinearSystem, lam: float):
        """Damped reduced camera system S dc = rhs with the points eliminated, and what back-substitution
        needs."""
        Hcc = system.Hcc
        nc = self.nc
        Hcc_d = Hcc + lam * np.diag(np.diag(Hcc)) + 1e-12 * np.eye(nc)
        if system.Hpp is None:
            return Hcc_d, system.bc.copy(), None
        dpp = np.diagonal(system.Hpp, axis1=1, axis2=2)
        Hpp_inv = inv3(system.Hpp, lam * dpp + 1e-12)
        if nc == 0:  # points only (every camera parameter fixed)
            return Hcc_d, system.bc.copy(), Hpp_inv
        if self.dense:
            if system.Hcp is None:
                system.Hcp = self._coupling(system.W)
            Hcp = system.Hcp
            Y = Hcp @ Hpp_inv  # (P, nc, 3)
            S = Hcc_d - np.swapaxes(Y, 0, 1).reshape(nc, -1) @ np.swapaxes(Hcp, 0, 1).reshape(nc, -1).T
            rhs = system.bc - np.swapaxes(Y, 0, 1).reshape(nc, -1) @ system.bp.reshape(-1)
            return S, rhs, Hpp_inv
        W = system.W
        V = W @ Hpp_inv[self.point]  # (N, L, 3)
        S = Hcc_d - self._square(self._pair_cc, V[self.pair_a] @ np.swapaxes(W[self.pair_b], 1, 2))
        rhs = system.bc - self._vector(np.einsum("nlk,nk->nl", V, system.bp[self.point]))
        return S, rhs, Hpp_inv

    def back_substitute(self, system: LinearSystem, Hpp_inv: np.ndarray, dc: np.ndarray) -> np.ndarray:
        """Point steps (P, 3) for a camera step dc."""
        if self.nc == 0:
            rhs = system.bp
        elif self.dense:
            rhs = system.bp - np.einsum("pci,c->pi", system.Hcp, dc)
        else:
            dce = np.append(dc, 0.0)[self.cols]  # (N, L), zero for non-existing columns
            rhs = system.bp - group_sum(self.point, np.einsum("nlk,nl->nk", system.W, dce), self.num_points)
        return np.einsum("pij,pj->pi", Hpp_inv, rhs)

    def reduced_information(self, system: LinearSystem) -> np.ndarray:
        """Undamped Schur complement of the camera block: the Fisher information of the camera parameters
        (in units of 1/sigma^2 of the residuals) with the points eliminated."""
        S, _, _ = self.reduce(system, 0.0)
        return S - 1e-12 * np.eye(self.nc)


def group_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum of ``values`` (N, ...) grouped by ``index`` (N,) into (n, ...)."""
    shape = values.shape[1:]
    k = int(np.prod(shape)) if shape else 1
    flat = (index[:, None] * k + np.arange(k)).reshape(-1)
    return np.bincount(flat, weights=values.reshape(-1), minlength=n * k).reshape((n,) + shape)


@dataclass
class LinearSystem:
    """Normal equations J^T J dx = J^T (-r) of a camera block, and of points when there are any."""

    cost: float
    Hcc: np.ndarray  # (nc, nc)
    bc: np.ndarray  # (nc,)
    Hpp: np.ndarray | None = None  # (P, 3, 3)
    bp: np.ndarray | None = None  # (P, 3)
    W: np.ndarray | None = None  # (N, L, 3) per-observation coupling (SchurStructure.accumulate)
    Hcp: np.ndarray | None = None  # (P, nc, 3) the same per point, when the structure forms it densely
    structure: SchurStructure | None = None

    def add_dense(self, J: np.ndarray, r: np.ndarray) -> None:
        """Add residuals r (k,) with camera Jacobian J (k, nc) (priors; no point columns)."""
        self.Hcc = self.Hcc + J.T @ J
        self.bc = self.bc - J.T @ r
        self.cost += 0.5 * float(r @ r)

    def solve(self, lam: float):
        """(dc, dp, camera_decrease, decrease): camera and point steps of the damped system, the cost decrease
        the camera step predicts with the points re-fitted (dc^T S dc / 2) and the decrease the damped model
        predicts for the whole step (h^T b / 2 + lam h^T D h / 2, D the damped diagonal: the model's gain, the
        denominator of the gain ratio that steers the damping)."""
        if self.structure is None:
            S = self.Hcc + lam * np.diag(np.diag(self.Hcc)) + 1e-12 * np.eye(len(self.bc))
            rhs, Hpp_inv = self.bc, None
        else:
            S, rhs, Hpp_inv = self.structure.reduce(self, lam)
        try:
            dc = np.linalg.solve(S, rhs) if len(rhs) else rhs.copy()
        except np.linalg.LinAlgError:
            dc = np.linalg.lstsq(S, rhs, rcond=None)[0]
        dp = None if Hpp_inv is None else self.structure.back_substitute(self, Hpp_inv, dc)
        decrease = 0.5 * float(dc @ self.bc) + 0.5 * lam * float(np.diag(self.Hcc) @ (dc * dc))
        if dp is not None:
            dpp = np.diagonal(self.Hpp, axis1=1, axis2=2)
            decrease += 0.5 * float(np.sum(dp * self.bp)) + 0.5 * lam * float(np.sum(dpp * dp * dp))
        return dc, dp, 0.5 * float(dc @ S @ dc), decrease

    def information(self) -> np.ndarray:
        """Fisher information of the camera block, points eliminated (undamped)."""
        if self.structure is None or self.Hpp is None:
            return self.Hcc
        return self.structure.reduced_information(self)


# An accepted step the model predicted well divides lambda by up to this. Nielsen's rule has 3; with 3 the
# adjustments stayed damped longer and some stopped short of the minimum (docs/RESULTS.md, "One hold's estimate").
ACCEPTED_MIN_FACTOR = 0.1


@dataclass
class LMOptions:
    """Stopping and damping of :func:`levenberg_marquardt`; costs are in chi^2/2 units (residuals / sigma)."""

    max_iterations: int = 30
    relative_tolerance: float = 1e-6  # stop when a step decreases the cost by less than this share
    cost_tolerance: float = 1e-2  # ... or by less than this (about 0.1 sigma of movement in the parameters)
    # ... or the camera step alone would gain less than cost_tolerance while the step gains less than this: only
    # points still creep along their rays (a larger gain means the linearised camera block is not to be trusted)
    creep_tolerance: float = 1.0
    initial_damping: float = 1e-4  # lambda relative to the diagonal
    # Damping follows the gain ratio rho (actual over predicted decrease; Nielsen 1999, in Madsen, Nielsen & Tingleff
    # 2004, "Methods for non-linear least squares problems", section 3.2): an accepted step multiplies lambda by
    # max(1/10, 1 - (2 rho - 1)^3) (a step the model predicted well shrinks it, a poorly predicted one keeps it),
    # a rejected one by damping_factor, doubled on every further rejection in a row. A fixed factor down after
    # every accepted step makes LM alternate between a rejected and an accepted step wherever the model is only
    # fair (low-parallax landmarks), paying a failed step and a re-fit of the points for every step it takes.
    damping_factor: float = 2.0  # first factor up on a rejected step
    max_damping: float = 1e8  # give up beyond this
    max_accepted: int | None = None  # stop after this many accepted steps (None: no limit)


class Stop(str, Enum):
    """Why a Levenberg-Marquardt run ended; the value is the phrase shown."""

    CONVERGED = "converged"  # a step decreased the cost by less than the tolerances
    MAX_ITERATIONS = "max iterations"
    MAX_ACCEPTED = "max accepted"  # LMOptions.max_accepted steps were accepted (a run to be resumed)
    DAMPING = "damping"  # the damping grew beyond LMOptions.max_damping
    MINIMUM = "minimum"  # a rejected step whose cost only rose by rounding

    def __str__(self) -> str:
        return self.value


@dataclass
class LMStats:
    """What one run did: steps tried and accepted, the cost at the start and at the end, why it stopped and
    the damping it ended with (to resume from)."""

    iterations: int
    accepted: int
    initial_cost: float
    cost: float
    stop: Stop
    damping: float = 0.0


def levenberg_marquardt(problem, state, options: LMOptions | None = None, *, system: LinearSystem | None = None,
                        damping: float | None = None):
    """Minimise problem's cost from ``state``; returns (state, LinearSystem at that state, LMStats).

    ``system``: the problem's normal equations at ``state`` when the caller has them (else linearised here);
    ``damping``: the damping to start from (default ``options.initial_damping``, which stays the floor a
    rejected step raises it to).

    Converged when a step decreases the cost by less than ``cost_tolerance`` (or ``relative_tolerance`` of
    it), or by less than ``creep_tolerance`` while the camera step's predicted decrease is below
    ``cost_tolerance`` (only far points still creep along their rays). A rejected step whose cost only rose
    by rounding ends the run at the minimum.
    """
    opts = options or LMOptions()
    lam = opts.initial_damping if damping is None else float(damping)
    system = problem.linearize(state) if system is None else system
    cost = initial = system.cost
    refit = getattr(problem, "refit_points", None)
    it = accepted = 0
    up = opts.damping_factor
    stop = Stop.MAX_ITERATIONS
    while it < opts.max_iterations:
        it += 1
        dc, dp, camera_decrease, predicted = system.solve(lam)
        new_state = problem.step(state, dc, dp)
        new_cost = problem.cost(new_state)
        if not new_cost <= cost and refit is not None and dp is not None:
            # the linear point update failed (low parallax is very non-linear): re-fit the points to the new
            # camera block before judging the step (embedded point iterations)
            new_state, new_cost = refit(new_state)
        if not (np.isfinite(new_cost) and new_cost <= cost):
            if np.isfinite(new_cost) and new_cost - cost < opts.cost_tolerance:
                stop = Stop.MINIMUM
                break
            lam = max(lam * up, opts.initial_damping)
            up *= 2.0
            if lam > opts.max_damping:
                stop = Stop.DAMPING
                break
            continue
        decrease = cost - new_cost
        converged = (decrease < max(opts.relative_tolerance * cost, opts.cost_tolerance)
                     or camera_decrease < opts.cost_tolerance and decrease < opts.creep_tolerance)
        state = new_state
        accepted += 1
        rho = decrease / predicted if predicted > 0 else 1.0
        lam = max(lam * max(ACCEPTED_MIN_FACTOR, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-9)
        up = opts.damping_factor
        system = problem.linearize(state)
        cost = system.cost
        if converged:
            stop = Stop.CONVERGED
            break
        if opts.max_accepted is not None and accepted >= opts.max_accepted:
            stop = Stop.MAX_ACCEPTED
            break
    return state, system, LMStats(iterations=it, accepted=accepted, initial_cost=initial, cost=cost, stop=stop,
                                  damping=lam)


__all__ = ["LMOptions", "LMStats", "LinearSystem", "SchurStructure", "Stop", "group_sum", "inv3",
           "levenberg_marquardt"]
