"""Bar self-calibration: each bar's compliance m/EI from many view pairs with known gravity.

Joint Gauss-Newton (Levenberg-Marquardt) over the compliance of every bar
(or one shared scalar) and, per view pair, (R, t, g) and the 3D points: the
points are eliminated per correspondence (3x3 Schur blocks, as in the
two-view bundle adjustment), then each pair's (R, t, g) block (8x8), leaving
a small system in the compliances. The measured gravity of both views
enters as a prior (SPEC section 5, like 4pt-bending), so IMU noise is
accounted for. The standard deviation comes from the inverse of the reduced
information at the optimum; a compliance that is not significantly
different from zero (or whose deviation is large relative to it) is
reported as not observable instead of as a number.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from .core.bundle import GravityPrior, Solver, TwoViewProblem
from .core.estimators import EstimatorOptions, estimate
from .core.matches import Matches
from .core.rig import Rig
from .errors import EstimationError


@dataclass
class BarCalibration:
    """Result: compliance (kg / (N m^2)) per calibrated group with its standard deviation."""

    groups: np.ndarray  # (M,) camera -> group index, -1 = rigid mount (not calibrated)
    compliance: np.ndarray  # (G,)
    std: np.ndarray  # (G,)
    observable: np.ndarray  # (G,) bool
    num_pairs: int
    num_correspondences: int
    iterations: int
    cost: float
    notes: list = field(default_factory=list)

    def calibrated_rig(self, rig: Rig) -> Rig:
        """The rig with EI = mass / compliance for observable bars; other bars keep their values."""
        k = rig.compliance.copy()
        for i, gi in enumerate(self.groups):
            if gi >= 0 and self.observable[gi]:
                k[i] = max(self.compliance[gi], 1e-12)
        return rig.with_compliance(k)


class _Pair:
    """One view pair: its current (R, t, g, points) and problem."""

    def __init__(self, m: Matches, est, g1, g2, sigma_prior):
        idx = est.inliers
        self.f1, self.f2, self.cam = m.f1[idx], m.f2[idx], m.cam[idx]
        self.R, self.t, self.g = est.R, est.t, (est.gravity if est.gravity is not None else g1)
        self.prior = GravityPrior(g1, g2, sigma_prior)
        self.sigma = float(est.info.get("sigma_rad", 1e-3))
        self.P = None


def _groups(rig: Rig, shared: bool) -> np.ndarray:
    """Camera -> compliance parameter: one per camera on a bar, or one shared; -1 at the body centre."""
    on_bar = np.linalg.norm(rig.positions, axis=1) > 1e-9
    if shared:
        return np.where(on_bar, 0, -1)
    return np.where(on_bar, np.cumsum(on_bar) - 1, -1)


def calibrate_bars(rig: Rig, pairs: list, shared: bool = False, gravity_sigma_rad: float = 0.005,
                   max_iterations: int = 30, initial_compliance=None, seed: int = 0,
                   significance: float = 3.0, progress=None) -> BarCalibration:
    """Estimate bar compliance from view pairs whose matches carry gravity measurements (g1/g2).

    ``rig`` gives the geometry and the starting compliance (bars missing or
    rigid start from a small compliance). Pairs where 4pt-bending fails are
    skipped with a note.
    """
    groups = _groups(rig, shared)
    G = int(groups.max()) + 1
    if G <= 0:
        raise EstimationError(f"{rig.source}: no camera sits on a bar (all at the body centre); nothing to calibrate")
    L = np.linalg.norm(rig.positions, axis=1)
    k0 = rig.compliance.copy()
    # a start that bends the tip by ~1 mrad where the file says rigid
    k0 = np.where(k0 > 0, k0, 2e-3 / (np.maximum(L, 1e-3) ** 2 * rig.gravity_magnitude))
    if initial_compliance is not None:
        k0 = np.broadcast_to(np.asarray(initial_compliance, dtype=float), k0.shape).copy()
    kg = np.array([k0[groups == gi].mean() for gi in range(G)])
    notes = []
    base = EstimatorOptions()
    # Inliers chosen under a wrong compliance are biased towards it: start loose and tighten as k converges.
    schedule = [8.0, 3.0] + [1.0] * 8  # stops at the first converged round at the final threshold
    it = 0
    for rnd, factor in enumerate(schedule):
        rig_k = _apply(rig, groups, kg)
        opts = EstimatorOptions(threshold_px=base.threshold_px * factor)
        states = []
        skipped = []
        for n, m in enumerate(pairs):
            if not m.has_gravity:
                raise EstimationError(f"{m.source}: bar calibration needs gravity measurements in both views")
            est = estimate(rig_k, m, method="4pt-bending", seed=seed + n, options=opts)
            if not est.success or est.num_inliers < 12:
                skipped.append(f"{m.source}: skipped ({est.info.get('reason', 'too few inliers')})")
                continue
            g1, g2 = m.body_gravity(rig_k)
            states.append(_Pair(m, est, g1, g2, gravity_sigma_rad))
        if progress:
            progress(rnd + 1, len(schedule))
        if not states:
            raise EstimationError("no usable view pair for bar calibration")
        k_before = kg.copy()
        kg, states, systems, cost, n_it = _optimize(rig, states, groups, kg, max_iterations)
        it += n_it
        converged = np.all(np.abs(kg - k_before) <= 0.01 * np.maximum(np.abs(kg), 1e-12))
        if factor == 1.0 and converged:
            break
    notes += skipped
    info = _information(systems, G)
    try:
        cov = np.linalg.inv(info)
        std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        std = np.full(G, np.inf)
    observable = (kg > significance * std) & np.isfinite(std)
    for gi in range(G):
        if not observable[gi]:
            cams = [rig.cameras[i].name for i in np.flatnonzero(groups == gi)]
            notes.append(f"compliance of {', '.join(cams)} not observable: {kg[gi]:.3g} +- {std[gi]:.2g} "
                         f"kg/(N m^2) is not significantly different from a rigid mount")
    return BarCalibration(groups=groups, compliance=kg, std=std, observable=observable, num_pairs=len(states),
                          num_correspondences=int(sum(len(s.cam) for s in states)), iterations=it, cost=cost,
                          notes=notes)


def _optimize(rig, states, groups, kg, max_iterations):
    """Levenberg-Marquardt over compliances and every pair's (R, t, g, points) for fixed inliers."""
    G = len(kg)
    lam = 1e-3
    rig_k = _apply(rig, groups, kg)
    cost, systems = _linearize(rig_k, states, groups)
    it = 0
    while it < max_iterations:
        it += 1
        dk, steps = _solve(systems, G, lam)
        k_new = np.maximum(kg + dk, 0.0)
        trial = [_stepped(s, st) for s, st in zip(states, steps)]
        rig_new = _apply(rig, groups, k_new)
        new_cost = _total_cost(rig_new, trial, groups)
        if np.isfinite(new_cost) and new_cost <= cost:
            rel = (cost - new_cost) / max(cost, 1e-300)
            kg, states = k_new, trial
            lam = max(lam / 10, 1e-9)
            cost, systems = _linearize(rig_new, states, groups)
            if rel < 1e-8:
                break
        else:
            lam *= 10
            if lam > 1e8:
                break
    return kg, states, systems, cost, it


def _apply(rig: Rig, groups, kg) -> Rig:
    k = rig.compliance.copy()
    on = groups >= 0
    k[on] = kg[groups[on]]
    return rig.with_compliance(np.maximum(k, 1e-15) * on + k * ~on)


def _problem(rig, s: _Pair, groups):
    return TwoViewProblem(rig, s.f1, s.f2, s.cam, True, s.prior, compliance_groups=groups)


def _linearize(rig, states, groups):
    """Per pair: reduced (points eliminated) system over (dr, t, dg, k). Returns total cost and the systems."""
    total = 0.0
    systems = []
    for s in states:
        prob = _problem(rig, s, groups)
        if s.P is None:
            s.P = prob.triangulate(s.R, s.t, s.g)
        solver = Solver(prob, s.sigma, 3.0)
        cost, Hcc, bc, Hcp, Hpp, bp = solver.normal_equations(s.R, s.t, s.g, s.P)
        total += cost
        systems.append((solver, Hcc, bc, Hcp, Hpp, bp))
    return total, systems


def _solve(systems, G, lam):
    """Eliminate points and each pair's 8 local parameters; solve for the compliance step."""
    S_k = np.zeros((G, G))  # damping is already in each pair's reduced system
    b_k = np.zeros(G)
    parts = []
    for solver, Hcc, bc, Hcp, Hpp, bp in systems:
        S, rhs, Hpp_inv = solver.reduced_system(Hcc, bc, Hcp, Hpp, bp, lam)
        Sll, Slk, Skk = S[:8, :8], S[:8, 8:], S[8:, 8:]
        Sll_inv = np.linalg.inv(Sll)
        S_k += Skk - Slk.T @ Sll_inv @ Slk
        b_k += rhs[8:] - Slk.T @ Sll_inv @ rhs[:8]
        parts.append((solver, Hcp, bp, Hpp_inv, Sll_inv, Slk, rhs))
    dk = np.linalg.lstsq(S_k + 1e-30 * np.eye(G), b_k, rcond=None)[0]
    steps = []
    for solver, Hcp, bp, Hpp_inv, Sll_inv, Slk, rhs in parts:
        dl = Sll_inv @ (rhs[:8] - Slk @ dk)
        dc = np.concatenate([dl, dk])
        steps.append((solver, dc, solver.back_substitute(Hcp, Hpp_inv, bp, dc)))
    return dk, steps


def _stepped(s: _Pair, step) -> _Pair:
    solver, dc, dP = step
    new = copy.copy(s)
    new.R, new.t, new.g, new.P = solver.step(s.R, s.t, s.g, dc[:8], dP)
    return new


def _total_cost(rig, states, groups) -> float:
    return float(sum(Solver(_problem(rig, s, groups), s.sigma, 3.0).cost(s.R, s.t, s.g, s.P) for s in states))


def _information(systems, G) -> np.ndarray:
    """Fisher information of the compliances with everything else eliminated (undamped)."""
    info = np.zeros((G, G))
    for solver, Hcc, bc, Hcp, Hpp, bp in systems:
        S, _, _ = solver.reduced_system(Hcc, bc, Hcp, Hpp, bp, 0.0)
        Sll, Slk, Skk = S[:8, :8], S[:8, 8:], S[8:, 8:]
        info += Skk - Slk.T @ np.linalg.solve(Sll, Slk)
    return info


def describe(cal: BarCalibration, rig: Rig) -> str:
    """Human-readable table of the calibration."""
    lines = [f"bar calibration over {cal.num_pairs} view pairs, {cal.num_correspondences} correspondences, "
             f"{cal.iterations} iterations"]
    for gi in range(len(cal.compliance)):
        cams = [rig.cameras[i] for i in np.flatnonzero(cal.groups == gi)]
        names = ", ".join(c.name for c in cams)
        if cal.observable[gi]:
            k, s = cal.compliance[gi], cal.std[gi]
            eis = ", ".join(f"EI {c.mass / k:.4g} N m^2 (mass {c.mass if c.mass > 0 else 1.0:g} kg)" for c in cams)
            lines.append(f"  {names}: compliance {k:.5g} +- {s:.2g} kg/(N m^2) ({100 * s / k:.1f} %) -> {eis}")
        else:
            lines.append(f"  {names}: not observable ({cal.compliance[gi]:.3g} +- {cal.std[gi]:.2g}); left as in "
                         "the rig file")
    lines += [f"  note: {n}" for n in cal.notes]
    return "\n".join(lines)


__all__ = ["BarCalibration", "calibrate_bars", "describe"]
