"""Cramér-Rao lower bounds on rotation, translation direction and gravity (``nrmpc observability``).

The measurement model is the one the refinement uses (docs/CONVENTIONS.md (Estimators), paper
eq. 15): the tangent-plane (angular) residuals of both bearings of every
inlier, each component with Gaussian noise of std ``sigma_rad`` = pixel
noise / focal length, which is exactly how :mod:`nrmpc_ros.sim.synthetic`
perturbs bearings. The Fisher information of (dr, t, dg, points) is
J^T J / sigma^2 with the analytic Jacobians of the bundle adjustment
(:class:`~nrmpc_ros.core.bundle.SequenceBundleProblem`) at the ground truth;
the points are eliminated by the Schur complement, leaving the 8x8
information of the camera block (rotation as a right perturbation
R Exp(dr), t in metres, gravity as a 2-d.o.f. tangent angle).

The bound of an angle is reported two ways: ``rms`` = sqrt(trace) of the
relevant covariance (what the RMS error of an efficient unbiased estimator
reaches) and ``median`` = the median angle of a Gaussian error with that
covariance (what the median error of an efficient estimator reaches), so an
estimator's median error divided by the median bound is ~1 when efficient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..core.bundle import (
    BundleResult,
    BundleState,
    GravityPriors,
    Observations,
    ParameterLayout,
    SequenceBundleProblem,
    covariance_from_information,
    two_view_priors,
)
from ..core.deformation import deformed_extrinsics
from ..core.rig import Rig
from ..core.sequence_steps import triangulated
from ..core.so3 import normalize

KINDS = ("rotation", "translation", "gravity")


@dataclass
class Bound:
    """Covariances (rad^2) of the three angles at one geometry; inf where not observable."""

    cov_rotation: np.ndarray  # (3, 3) over dr
    cov_translation_dir: np.ndarray  # (2, 2) translation direction, tangent plane of t
    cov_gravity: np.ndarray  # (2, 2) over dg; inf if gravity is unobservable

    def rms(self, kind: str) -> float:
        return float(math.sqrt(max(np.trace(getattr(self, _COV[kind])), 0.0)))


_COV = {"rotation": "cov_rotation", "translation": "cov_translation_dir", "gravity": "cov_gravity"}


def noise_free_bearings(rig: Rig, P: np.ndarray, cam: np.ndarray, R: np.ndarray, t: np.ndarray, g: np.ndarray):
    """Exact bearings (f1, f2) of body-frame points P under the bending model (docs/CONVENTIONS.md (Bending))."""
    w1, W1 = deformed_extrinsics(rig, g)
    w2, W2 = deformed_extrinsics(rig, R.T @ g)
    f1 = normalize(np.einsum("nji,nj->ni", W1[cam], P - w1[cam]))
    P2 = (P - t) @ R
    f2 = normalize(np.einsum("nji,nj->ni", W2[cam], P2 - w2[cam]))
    return f1, f2


def fisher_information(rig: Rig, P, cam, R, t, g, sigma_rad: float, gravity_prior_sigma: float = math.inf):
    """8x8 Fisher information of (dr, t, dg) with the points eliminated (Schur complement).

    ``gravity_prior_sigma`` (rad) adds measured gravity in both views as a
    prior of that angular std (as 4pt-bending does, docs/CONVENTIONS.md (Estimators, Gravity measurements)); inf =
    vision only.
    """
    P = np.asarray(P, dtype=float)
    cam = np.asarray(cam)
    f1, f2 = noise_free_bearings(rig, P, cam, R, t, g)
    prior = None
    if math.isfinite(gravity_prior_sigma):
        prior = two_view_priors(np.asarray(g, float), R.T @ g, float(gravity_prior_sigma))
    # Huber threshold far out: plain least-squares information (residuals are zero at the truth anyway)
    prob = SequenceBundleProblem(rig, Observations.two_view(f1, f2, cam), ParameterLayout(2, [1], True),
                                 float(sigma_rad), huber_k=1e6, priors=prior)
    state = BundleState(np.stack([np.eye(3), R]), np.stack([np.zeros(3), t]), np.asarray(g, float), P)
    info = prob.linearize(state).information()
    T = np.eye(8)  # rotation errors in view 2's body frame (right perturbation)
    T[:3, :3] = R.T
    return T @ info @ T.T


def _marginal(info: np.ndarray, idx) -> np.ndarray:
    """Covariance block of the parameters idx from an information matrix; inf if (near) singular."""
    n = info.shape[0]
    other = np.setdiff1d(np.arange(n), idx)
    A = info[np.ix_(idx, idx)]
    if len(other):
        B = info[np.ix_(idx, other)]
        C = info[np.ix_(other, other)]
        try:
            A = A - B @ np.linalg.solve(C, B.T)
        except np.linalg.LinAlgError:
            A = A - B @ np.linalg.pinv(C) @ B.T
    A = 0.5 * (A + A.T)
    ev = np.linalg.eigvalsh(A)
    scale = max(float(np.abs(np.diag(info)).max()), 1e-300)
    if ev.min() <= 1e-13 * scale:
        return np.full(A.shape, np.inf)
    return np.linalg.inv(A)


def bound_from_information(info: np.ndarray, t: np.ndarray, gravity_observable: bool = True) -> Bound:
    """Angle covariances from the 8x8 information of (dr, t, dg)."""
    if not gravity_observable:  # a rigid rig: the gravity columns are zero; bound the pose alone
        info6 = info[:6, :6]
        cov_r = _marginal(info6, np.arange(3))
        cov_t = _marginal(info6, np.arange(3, 6))
        cov_g = np.full((2, 2), np.inf)
    else:
        cov_r = _marginal(info, np.arange(3))
        cov_t = _marginal(info, np.arange(3, 6))
        cov_g = _marginal(info, np.arange(6, 8))
    tn = float(np.linalg.norm(t))
    if not np.all(np.isfinite(cov_t)) or tn < 1e-12:
        cov_dir = np.full((2, 2), np.inf)
    else:
        from ..core.so3 import tangent_basis

        T = tangent_basis(np.asarray(t, float) / tn)  # (3, 2): direction error = T^T dt / |t|
        cov_dir = T.T @ cov_t @ T / tn**2
    return Bound(cov_rotation=cov_r, cov_translation_dir=cov_dir, cov_gravity=cov_g)


def problem_bound(problem, sigma_rad: float | None = None, gravity_prior_sigma: float = math.inf) -> Bound:
    """CRLB at a synthetic problem's ground truth, over its inliers only (outliers carry no information)."""
    rig = problem.rig
    if sigma_rad is None:
        raise ValueError("sigma_rad is required")
    keep = np.asarray(problem.inlier_mask, bool)
    info = fisher_information(rig, problem.points[keep], problem.matches.cam[keep], problem.R, problem.t,
                              problem.gravity, sigma_rad, gravity_prior_sigma)
    return bound_from_information(info, problem.t, gravity_observable=rig.is_flexible)


def angle_samples(cov: np.ndarray, rng: np.random.Generator, n: int = 4000) -> np.ndarray:
    """Norms of Gaussian draws with covariance cov: the angle error an efficient estimator makes."""
    if not np.all(np.isfinite(cov)):
        return np.full(n, np.inf)
    L = np.linalg.cholesky(0.5 * (cov + cov.T) + 1e-300 * np.eye(len(cov)))
    return np.linalg.norm(rng.standard_normal((n, len(cov))) @ L.T, axis=1)


def summarize_bounds(bounds: list[Bound], seed: int = 0, draws: int = 4000) -> dict:
    """Pool per-geometry bounds: for each angle the RMS bound sqrt(mean trace) and the median-angle bound."""
    rng = np.random.default_rng(seed)
    out = {}
    for kind in KINDS:
        covs = [getattr(b, _COV[kind]) for b in bounds]
        if not covs or any(not np.all(np.isfinite(c)) for c in covs):
            out[kind] = {"rms": math.inf, "median": math.inf}
            continue
        traces = np.array([np.trace(c) for c in covs])
        pooled = np.concatenate([angle_samples(c, rng, draws) for c in covs])
        out[kind] = {"rms": float(math.sqrt(traces.mean())), "median": float(np.median(pooled))}
    return out


@dataclass
class SequenceBound:
    """Bounds on each view's gravity direction over a sequence: joint (all views, one gravity) and, for view
    k >= 1, from the pair (k-1, k) on its own (its shared tracks, two-view estimate); tangent covariances
    (K, 2, 2) in rad^2 (view 0 of the pairwise bound is the pair (0, 1)'s view 0)."""

    joint: np.ndarray
    pairwise: np.ndarray

    def median_angles(self, which: str = "joint", rng: np.random.Generator | None = None) -> np.ndarray:
        """(K,) median angle (rad) an efficient estimator of each view's gravity reaches."""
        rng = rng or np.random.default_rng(0)
        covs = self.joint if which == "joint" else self.pairwise
        return np.array([float(np.median(angle_samples(c, rng, 2000))) for c in covs])


def _bound_result(rig, obs, state, sigma_rad, priors=None) -> BundleResult:
    """Information and covariance of the camera block at ``state`` for noise-free observations."""
    free = np.arange(1, obs.num_views)
    layout = ParameterLayout(obs.num_views, free, True)
    prob = SequenceBundleProblem(rig, obs, layout, float(sigma_rad), huber_k=1e6, priors=priors)
    info = prob.linearize(state).information()
    return BundleResult(state=state, layout=layout, sigma_rad=float(sigma_rad), information=info,
                        covariance=covariance_from_information(info))


def sequence_bound(problem, sigma_rad: float, gravity_prior_sigma: float = math.inf) -> SequenceBound:
    """Cramér-Rao bounds of a simulated sequence (:class:`nrmpc_ros.sim.sequence.SequenceProblem`) over its
    inlier observations, joint and pair by pair; ``gravity_prior_sigma`` (rad) adds each view's measured
    gravity as a prior (4pt-bending)."""
    rig, tr = problem.rig, problem.tracks.subset(problem.inlier_mask)
    K = tr.num_views
    obs, ids = Observations.from_arrays(tr.view, tr.cam, tr.track, tr.f, K)
    truth = BundleState(problem.R, problem.t, problem.gravity[0], problem.points[ids])
    exact = SequenceBundleProblem(rig, obs, ParameterLayout(K, [], False), 1.0).predicted_bearings(truth)
    obs = Observations(obs.view, obs.cam, obs.point, exact, K, obs.num_points)
    finite = math.isfinite(gravity_prior_sigma)
    priors = GravityPriors(problem.gravity, gravity_prior_sigma) if finite else None
    joint = _bound_result(rig, obs, truth, sigma_rad, priors)
    jcov = np.array([joint.gravity_tangent_covariance(k) for k in range(K)])
    pair = np.full((K, 2, 2), np.inf)
    for k in range(1, K):
        sub, used = obs.subset(np.isin(obs.view, [k - 1, k]))
        sub = Observations(np.where(sub.view == k, 1, 0), sub.cam, sub.point, sub.f, 2, sub.num_points)
        Rk = problem.R[k - 1].T @ problem.R[k]
        tk = problem.R[k - 1].T @ (problem.t[k] - problem.t[k - 1])
        P = (problem.points[ids][used] - problem.t[k - 1]) @ problem.R[k - 1]
        st = BundleState(np.stack([np.eye(3), Rk]), np.stack([np.zeros(3), tk]), problem.gravity[k - 1], P)
        pr = GravityPriors(problem.gravity[[k - 1, k]], gravity_prior_sigma) if finite else None
        res = _bound_result(rig, sub, st, sigma_rad, pr)
        pair[k] = res.gravity_tangent_covariance(1)
        if k == 1:
            pair[0] = res.gravity_tangent_covariance(0)
    return SequenceBound(joint=jcov, pairwise=pair)


@dataclass
class ObservedBound:
    """Joint bound on each view's gravity direction from a sequence's observed tracks at a known true geometry:
    tangent covariances (K, 2, 2) in rad^2, the observations and landmarks that carried it, which observations
    those were (indices into the given ones) and their angular distance (rad) from their landmarks
    triangulated at the truth (the measured bearings' error at the truth, three dof per landmark used up)."""

    gravity: np.ndarray
    observations: int
    landmarks: int
    used: np.ndarray | None = None
    residual_rad: np.ndarray | None = None

    def median_angles(self, rng: np.random.Generator | None = None, draws: int = 2000) -> np.ndarray:
        """(K,) median angle (rad) an efficient estimator of each view's gravity reaches."""
        rng = rng or np.random.default_rng(0)
        return np.array([float(np.median(angle_samples(c, rng, draws))) for c in self.gravity])


_MISMATCH_ROUNDS = 5  # a landmark seen by up to this many mismatched observations is cleaned


def _multi_view(obs: Observations, keep: np.ndarray) -> np.ndarray:
    """Indices of the observations in ``keep`` whose landmark ``keep`` sees in two views or more."""
    seen = np.zeros((obs.num_points, obs.num_views), bool)
    seen[obs.point[keep], obs.view[keep]] = True
    return np.flatnonzero(keep & (seen.sum(axis=1) >= 2)[obs.point])


def observed_sequence_bound(rig: Rig, obs: Observations, R, t, gravity, sigma_rad: float,
                            priors: GravityPriors | None = None, outlier_rad: float = math.inf) -> ObservedBound:
    """Cramér-Rao bound of the joint gravity over the views of ``obs`` at the true poses ``R``, ``t`` (view k in
    view 0, p_0 = R_k p + t_k) and view 0's true gravity ``gravity``, for the landmarks those observations track.

    The landmarks are not known: each is triangulated from its observed bearings at the true geometry, and
    the bearings are then replaced by the model's exact ones (the information is that of noise-free data at the
    truth). An observation farther than ``outlier_rad`` from its truth-triangulated landmark is a mismatched
    correspondence and carries no information (each landmark's worst such observation is dropped and the landmark
    triangulated again, until none is left); landmarks
    seen in fewer than two views carry none either. ``sigma_rad`` is the nominal noise, ``obs.scale`` each
    observation's std over it (per hold and camera). ``priors`` (measured gravity per view at its std, with
    ``bias_sigma_rad`` a constant tilt estimated alongside) is what 4pt-bending adds; their directions should be
    the true ones (the information does not depend on them, the residuals at the truth then vanish).
    """
    R, t = np.asarray(R, float), np.asarray(t, float)
    K = obs.num_views
    g0 = np.asarray(gravity, float)
    idx = _multi_view(obs, np.ones(len(obs), bool))
    for _ in range(_MISMATCH_ROUNDS):  # each landmark's worst observation off the truth, one per round
        if len(idx) == 0:
            break
        sub, _ = obs.subset(idx)
        state, prob = triangulated(rig, sub, BundleState(R, t, g0, np.zeros((sub.num_points, 3))))
        err = np.linalg.norm(prob.residuals(state), axis=1)
        if sub.scale is not None:
            err = err * sub.scale  # the residuals come whitened by the scale: the raw angle decides
        err = np.where(np.isfinite(err), err, np.inf)
        if not np.any(err > outlier_rad):
            break
        worst = np.full(sub.num_points, -1.0)
        np.maximum.at(worst, sub.point, err)
        drop = (err > outlier_rad) & (err == worst[sub.point])
        keep = np.zeros(len(obs), bool)
        keep[idx[~drop]] = True
        idx = _multi_view(obs, keep)
    if len(idx) == 0:
        return ObservedBound(np.full((K, 2, 2), np.inf), 0, 0, idx, np.zeros(0))
    sub, _ = obs.subset(idx)
    state, prob = triangulated(rig, sub, BundleState(R, t, g0, np.zeros((sub.num_points, 3))))
    residual = np.linalg.norm(prob.residuals(state), axis=1) * (1.0 if sub.scale is None else sub.scale)
    exact = Observations(sub.view, sub.cam, sub.point, prob.predicted_bearings(state), K, sub.num_points,
                         None, sub.scale)
    bias = priors is not None and priors.bias_sigma_rad is not None
    if bias:
        state = replace(state, bias=np.zeros(3))
    layout = ParameterLayout(K, np.arange(1, K), True, bias=bias)
    info = SequenceBundleProblem(rig, exact, layout, float(sigma_rad), huber_k=1e6,
                                 priors=priors).linearize(state).information()
    res = BundleResult(state=state, layout=layout, sigma_rad=float(sigma_rad), information=info,
                       covariance=covariance_from_information(info))
    cov = np.array([res.gravity_tangent_covariance(k) for k in range(K)])
    return ObservedBound(cov, len(sub), sub.num_points, idx, residual)


__all__ = ["Bound", "KINDS", "ObservedBound", "SequenceBound", "angle_samples", "bound_from_information",
           "fisher_information", "noise_free_bearings", "observed_sequence_bound", "problem_bound", "sequence_bound",
           "summarize_bounds"]
