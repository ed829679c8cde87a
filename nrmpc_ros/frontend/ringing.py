"""Ringing bars in the images: the damped response of a camera's image offset after a stop (docs/PIPELINE.md,
"Settling").

After the rig stops, each bar rings in its first bending mode (docs/CONVENTIONS.md, "The rig in motion"), so the
image offset of its camera (the median displacement of its tracks from the hold's anchor frame) follows

    o(tau) = r + exp(-zeta w tau) (a cos(w_d tau) + b sin(w_d tau)),   w_d = w sqrt(1 - zeta^2),

tau the time since the stop, r the rest offset (2,), a, b (2,) the oscillation's coefficients, w = 2 pi f the bar's
natural frequency and zeta its damping ratio. :func:`fit_damped_response` fits it by nonlinear least squares (the
project's Levenberg-Marquardt, :mod:`nrmpc_ros.core.lm`) over any number of *segments* (one camera in one hold, or
one camera in every hold of a recording) that share f and zeta while each has its own r, a, b. The linear
parameters are eliminated for each trial (f, zeta) (variable projection), so the search runs over two numbers only;
a grid over the frequency band and a few damping ratios starts it, so an aliased frame rate (a bar faster than half
the frame rate) finds the right branch within the band. The standard deviations come from the full Jacobian (the
two nonlinear and all linear parameters) at the solution, scaled by the residual's RMS; those of the frequency and
damping are raised to a sandwich (Newey-West) one when the residuals are correlated from frame to frame within a
stop (the tracks' errors move together; the white-noise std is then several times too small), and the damping's to
a floor for the smooth misfit every stop shares (docs/PIPELINE.md, "Measuring a hold").

The rest offset r is where the ringing converges, not the mean over whole periods of a decaying oscillation
(which is off by the decay within the window): a hold whose bars ring throughout is measured at r.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.lm import LinearSystem, LMOptions, Stop, levenberg_marquardt

ZETA_BOUNDS = (1e-3, 0.7)  # damping ratios searched: lightly damped metal to strongly damped composite bars
FREQ_BAND = (0.6, 1.6)  # the frequency is searched within this factor of its start (the rig file's)
FREQ_GRID = 41  # frequencies of the coarse grid over FREQ_BAND (geometric: about 2.5 % apart)
ZETA_GRID = (0.01, 0.03, 0.1, 0.3)  # damping ratios of the coarse grid when the rig file gives none
ZETA_START = (1.1e-3, 0.69)  # the refinement starts strictly inside ZETA_BOUNDS
# The refinement: the project's LM from the grid's best, until a step gains less than 1e-6 of chi^2 / 2 (the
# parameters then within about a thousandth of their std of the minimum)
REFINEMENT = LMOptions(max_iterations=100, relative_tolerance=1e-12, cost_tolerance=1e-6)
CONVERGED_STOPS = (Stop.CONVERGED, Stop.MINIMUM)
DIFFERENCE_STEP = 1.5e-8  # forward differences: about the square root of the double precision, times max(1, |x|)


@dataclass
class RingingFit:
    """A damped response fitted to one or more segments sharing the bar's frequency and damping."""

    freq_hz: float
    zeta: float
    freq_std_hz: float
    zeta_std: float
    rest: np.ndarray  # (S, D) rest offset of each segment
    rest_std: np.ndarray  # (S,) std of each rest offset (per axis, px)
    coef: np.ndarray  # (S, 2, D) cos and sin coefficients at tau = 0
    residual_rms: float  # per component, px
    num_samples: int
    success: bool

    def amplitude(self, segment: int, tau) -> np.ndarray:
        """Envelope of the ringing (norm over the axes, px) of ``segment`` at times tau after the stop."""
        tau = np.asarray(tau, dtype=float)
        a0 = float(np.linalg.norm(self.coef[segment]))
        return a0 * np.exp(-self.zeta * 2.0 * math.pi * self.freq_hz * np.maximum(tau, 0.0))

    def oscillation(self, segment: int, tau) -> np.ndarray:
        """The ringing part o(tau) - r of ``segment`` at times tau (K, D)."""
        A = _design(np.asarray(tau, dtype=float), self.freq_hz, self.zeta)
        return A[:, 1:] @ self.coef[segment]

    def drift(self, tau, y: np.ndarray) -> tuple:
        """How fast the rest itself moves: the damped response at this fit's frequency and damping refitted to y
        (K, D) at times tau (K,) with a rest that drifts linearly. Returns (velocity (D,), its std (D,)), units of y
        per second; a rest that stays put gives a velocity within its std. The std allows for residuals correlated
        from frame to frame (what the model does not follow is smooth): the white-noise variance times
        (1 + rho) / (1 - rho), rho their lag-one autocorrelation (an AR(1) process's effective sample size)."""
        tau = np.asarray(tau, dtype=float)
        return rest_drift(tau, y, _design(tau, self.freq_hz, self.zeta))

    def track_oscillations(self, tau, X: np.ndarray, used: np.ndarray, min_frames: int) -> tuple:
        """Each track's own ringing at this fit's frequency and damping: X (F, n, D) the tracks' positions at
        times tau (F,) (NaN: not seen), ``used`` (F,) the frames to fit on. A camera's ringing is a turn and a
        shift of its bar's tip: tracks at different places of the image (and depths) ring with different
        amplitudes and phases, which one oscillation of their median does not remove. Returns ((F, n, D) the
        oscillation part of each track at every frame, (n,) bool the tracks fitted: those seen in at least
        ``min_frames`` used frames; the others' oscillation is zero)."""
        A = _design(np.asarray(tau, dtype=float), self.freq_hz, self.zeta)  # (F, 3)
        seen = np.isfinite(X).all(axis=2) & np.asarray(used, bool)[:, None]  # (F, n)
        fitted = seen.sum(axis=0) >= min_frames
        w = seen[:, fitted].T[:, :, None]  # (n', F, 1): a track's unseen frames take no part in its fit
        Y = np.where(w, np.swapaxes(X[:, fitted], 0, 1), 0.0)
        coef = _solve(w * A[None], Y)  # (n', 3, D)
        out = np.zeros(X.shape)
        out[:, fitted] = np.einsum("fa,nad->fnd", A[:, 1:], coef[:, 1:])
        return out, fitted


def rest_drift(tau, y: np.ndarray, design: np.ndarray) -> tuple:
    """(velocity (D,), its std (D,)) of a rest that drifts linearly under y (K, D) at times tau (K,), the other
    columns of the model in ``design`` (K, P) (a constant rest: a column of ones; a ringing about it: the damped
    response's three); the std as in :meth:`RingingFit.drift`, infinite with no residual degree of freedom."""
    tau = np.asarray(tau, dtype=float)
    y = np.asarray(y, dtype=float).reshape(len(tau), -1)
    A = np.concatenate([np.asarray(design, float).reshape(len(tau), -1), (tau - tau.mean())[:, None]], axis=1)
    if len(tau) <= A.shape[1]:
        return np.zeros(y.shape[1]), np.full(y.shape[1], np.inf)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    s2 = np.sum(r * r, axis=0) / (len(tau) - A.shape[1])
    rho = min(max(float(np.sum(r[1:] * r[:-1]) / max(float(np.sum(r * r)), 1e-300)), 0.0), 0.95)
    try:
        var = np.linalg.inv(A.T @ A)[-1, -1] * s2 * (1.0 + rho) / (1.0 - rho)
    except np.linalg.LinAlgError:
        return np.zeros(y.shape[1]), np.full(y.shape[1], np.inf)
    return coef[-1], np.sqrt(var)


def _design(tau: np.ndarray, f: float, zeta: float) -> np.ndarray:
    """Columns 1, exp(-zeta w tau) cos(w_d tau), exp(-zeta w tau) sin(w_d tau) (K, 3)."""
    w = 2.0 * math.pi * f
    wd = w * math.sqrt(max(1.0 - zeta * zeta, 1e-12))
    e = np.exp(-zeta * w * tau)
    return np.stack([np.ones_like(tau), e * np.cos(wd * tau), e * np.sin(wd * tau)], axis=1)


def _clean(segments):
    out = []
    for tau, y in segments:
        tau = np.asarray(tau, dtype=float).reshape(-1)
        y = np.asarray(y, dtype=float).reshape(len(tau), -1)
        ok = np.isfinite(tau) & np.isfinite(y).all(axis=1) & (tau >= 0)
        if ok.sum() >= 4:
            out.append((tau[ok], y[ok]))
        else:
            out.append((tau[:0], y[:0]))
    return out


def _solve(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of y (..., K, D) on the columns of A (..., K, 3) by the normal equations
    (three well-scaled columns), batched over leading axes; a tiny ridge keeps a vanished oscillation solvable."""
    AtA = np.swapaxes(A, -1, -2) @ A
    AtA = AtA + 1e-12 * np.trace(AtA, axis1=-2, axis2=-1)[..., None, None] * np.eye(3)
    return np.linalg.solve(AtA, np.swapaxes(A, -1, -2) @ y)


def _projected(theta, segs):
    """Residuals (stacked) after the linear parameters of every segment are solved for at (f, zeta) = theta."""
    f, zeta = float(theta[0]), float(theta[1])
    res = []
    for tau, y in segs:
        if not len(tau):
            continue
        A = _design(tau, f, zeta)
        res.append((y - A @ _solve(A, y)).ravel())
    return np.concatenate(res) if res else np.zeros(0)


class _ProjectedProblem:
    """The two nonlinear parameters (f, zeta) of the damped response as a problem of the project's
    Levenberg-Marquardt (:mod:`nrmpc_ros.core.lm`): residuals of :func:`_projected` over ``scale`` (the grid's
    best RMS, so the costs are about chi^2 / 2 and the LM's tolerances mean what they say), the Jacobian by
    forward differences (each column one more projection), steps kept within the bounds."""

    def __init__(self, segs, lower, upper, scale: float):
        self.segs = segs
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.scale = scale

    def residuals(self, theta) -> np.ndarray:
        return _projected(theta, self.segs) / self.scale

    def cost(self, theta) -> float:
        r = self.residuals(theta)
        return 0.5 * float(r @ r)

    def linearize(self, theta) -> LinearSystem:
        r = self.residuals(theta)
        J = np.empty((len(r), 2))
        for p, h in enumerate(DIFFERENCE_STEP * np.maximum(np.abs(theta), 1.0)):
            up = np.array(theta, float)
            up[p] += h if up[p] + h <= self.upper[p] else -h
            J[:, p] = (self.residuals(up) - r) / (up[p] - theta[p])
        H, b = J.T @ J, -(J.T @ r)
        # a parameter on its bound that the descent would push beyond it stays there (active set): its row and
        # column leave the step, which the other parameter then takes alone
        held = ((theta <= self.lower) & (b < 0)) | ((theta >= self.upper) & (b > 0))
        H[held, :] = 0.0
        H[:, held] = 0.0
        H[held, held] = 1.0
        b[held] = 0.0
        return LinearSystem(cost=0.5 * float(r @ r), Hcc=H, bc=b)

    def step(self, theta, dc, dp):
        return np.clip(np.asarray(theta, float) + dc, self.lower, self.upper)


def _grid_solve(tau: np.ndarray, y: np.ndarray, f: np.ndarray, z: np.ndarray) -> tuple:
    """The linear parameters (G, 3, D) and residuals (G, K, D) of y (K, D) at every grid point (f[g], z[g])."""
    w = 2.0 * math.pi * f[:, None]
    wd = w * np.sqrt(1.0 - z[:, None] ** 2)
    e = np.exp(-z[:, None] * w * tau[None])
    A = np.stack([np.ones_like(e), e * np.cos(wd * tau[None]), e * np.sin(wd * tau[None])], axis=2)  # (G, K, 3)
    coef = _solve(A, np.broadcast_to(y, (len(f),) + y.shape))
    return coef, y[None] - A @ coef


def _grid_costs(segs, fgrid: np.ndarray, zgrid: np.ndarray) -> np.ndarray:
    """Sum of squared projected residuals at every (f, zeta) of the grid (G,), all grid points at once."""
    f = np.repeat(fgrid, len(zgrid))
    z = np.tile(zgrid, len(fgrid))
    cost = np.zeros(len(f))
    for tau, y in segs:
        if not len(tau):
            continue
        r = _grid_solve(tau, y, f, z)[1]
        cost += np.einsum("gkd,gkd->g", r, r)
    return cost


def best_on_grid(tau: np.ndarray, y: np.ndarray, freqs_hz: np.ndarray, zetas: np.ndarray) -> tuple:
    """The damped response at the best of a grid of frequencies and damping ratios, without refinement (cheap
    enough for every frame): (residual RMS per component, rest offset (D,)) of y (K, D) at times tau (K,)."""
    f = np.repeat(np.asarray(freqs_hz, float), len(zetas))
    z = np.tile(np.asarray(zetas, float), len(freqs_hz))
    coef, r = _grid_solve(np.asarray(tau, float), np.asarray(y, float), f, z)
    cost = np.einsum("gkd,gkd->g", r, r)
    g = int(np.argmin(cost))
    return math.sqrt(float(cost[g]) / max(y.size, 1)), coef[g, 0]


def lag_window(resid: np.ndarray, sizes: list, D: int) -> int:
    """Bartlett lag window (samples) for the residuals' correlation within a stop: the AR(1) plug-in rule
    (Andrews 1991) with the lag-one autocorrelation pooled over the segments and axes, at most a segment's
    length. Zero for white residuals."""
    num = den = 0.0
    r0 = 0
    lengths = []
    for size in sizes:
        r = resid[r0:r0 + size].reshape(-1, D)
        r0 += size
        lengths.append(len(r))
        num += float(np.sum(r[1:] * r[:-1]))
        den += float(np.sum(r * r))
    if den <= 0 or not lengths:
        return 0
    rho = min(max(num / den, 0.0), 0.97)
    if rho <= 0:
        return 0
    alpha = 4.0 * rho ** 2 / (1.0 - rho ** 2) ** 2
    K = float(np.mean(lengths))
    return int(min(math.ceil(1.1447 * (alpha * K) ** (1.0 / 3.0)), max(lengths) - 1))


def _correlated_scores(J: np.ndarray, resid: np.ndarray, sizes: list, D: int) -> np.ndarray:
    """Middle of the sandwich covariance: sum over segments of the scores J^T r of the samples (all axes of one
    frame together), each pair within :func:`lag_window` frames weighted by the Bartlett kernel (Newey-West)."""
    L = lag_window(resid, sizes, D)
    P = J.shape[1]
    meat = np.zeros((P, P))
    r0 = 0
    for size in sizes:
        Js, rs = J[r0:r0 + size], resid[r0:r0 + size]
        r0 += size
        u = (Js * rs[:, None]).reshape(-1, D, P).sum(axis=1)  # (K, P) score of each frame
        meat += u.T @ u
        for lag in range(1, min(L, len(u) - 1) + 1):
            c = u[lag:].T @ u[:-lag]
            meat += (1.0 - lag / (L + 1.0)) * (c + c.T)
    return meat


def resolvable_bands(segments, lo: float, hi: float) -> list:
    """The parts [(a, b), ...] of the frequency band [lo, hi] (Hz) whose ringing the frames of ``segments``
    [(tau, y), ...] tell from a slow drift of the rest. Sampled at the frame rate fs, a ringing at f shows at its
    alias, the distance from f to the nearest multiple of fs; an alias of less than one cycle over the longest
    segment is a partial swing that a slowly moving rest (a creep) fits as well. So a band of 1 / span either side
    of every multiple of fs is left out (fs from the median frame interval; nothing is left out with fewer than
    two frames in every segment)."""
    steps = [np.median(np.diff(tau)) for tau, _ in segments if len(tau) >= 2]
    spans = [float(np.ptp(tau)) for tau, _ in segments if len(tau) >= 2]
    if not steps or not (float(np.median(steps)) > 0) or not (max(spans) > 0):
        return [(lo, hi)] if hi > lo else []
    fs, half = 1.0 / float(np.median(steps)), 1.0 / max(spans)
    out, a = [], lo
    for k in range(max(1, math.floor((lo - half) / fs)), math.ceil((hi + half) / fs) + 1):
        z0, z1 = k * fs - half, k * fs + half
        if z1 <= a or z0 >= hi:
            continue
        if z0 > a:
            out.append((a, z0))
        a = max(a, z1)
    if a < hi:
        out.append((a, hi))
    return out


def in_bands(freqs_hz: np.ndarray, parts: list) -> np.ndarray:
    """Which of ``freqs_hz`` lie in one of the bands ``parts`` [(a, b), ...] (:func:`resolvable_bands`)."""
    f = np.asarray(freqs_hz, float)
    return np.any([(f >= a) & (f <= b) for a, b in parts], axis=0) if parts else np.zeros(f.shape, bool)


def fit_damped_response(segments, freq_hz: float, zeta: float | None = None,
                        band: tuple = FREQ_BAND) -> RingingFit | None:
    """The damped response o(tau) (module docstring) fitted to ``segments`` [(tau (K,), y (K, D)), ...] that
    share the frequency and damping; ``freq_hz`` starts the frequency (searched within ``band`` times it),
    ``zeta`` the damping (searched over ZETA_BOUNDS when None or as a start). None when the data cannot
    determine the model (fewer samples than parameters, or the solver fails)."""
    if not (freq_hz > 0 and math.isfinite(freq_hz)):
        return None
    segs = _clean(segments)
    D = max((y.shape[1] for _, y in segs if len(y)), default=0)
    n = sum(y.size for _, y in segs)
    used = [s for s in segs if len(s[0])]
    if not used or n < 3 * D * len(used) + 4:
        return None
    lo, hi = band[0] * freq_hz, band[1] * freq_hz
    parts = resolvable_bands(used, lo, hi)
    if not parts:
        return None  # every frequency of the band looks like a slow drift at this frame rate
    fgrid = np.geomspace(lo, hi, FREQ_GRID)
    fgrid = np.concatenate([fgrid[in_bands(fgrid, parts)], [math.sqrt(a * b) for a, b in parts]])
    zgrid = [zeta] if zeta is not None else list(ZETA_GRID)
    zgrid = np.asarray(zgrid, dtype=float)
    costs = _grid_costs(segs, fgrid, zgrid)
    grid = [(float(c), float(f), float(z)) for c, (f, z) in zip(costs, ((f, z) for f in fgrid for z in zgrid))]
    lowest = min(g[0] for g in grid)
    # an aliased frame rate makes f and its alias fit alike: of the (near) ties, the one nearest the start wins
    best = min((g for g in grid if g[0] <= lowest * (1.0 + 1e-3) + 1e-300), key=lambda g: abs(math.log(g[1] / freq_hz)))
    start = np.array([best[1], min(max(best[2], ZETA_START[0]), ZETA_START[1])])
    lo, hi = next((a, b) for a, b in parts if a <= best[1] <= b)  # the refinement stays in the grid's best part
    problem = _ProjectedProblem(segs, (lo, ZETA_BOUNDS[0]), (hi, ZETA_BOUNDS[1]),
                                math.sqrt(max(lowest, 1e-300) / max(n, 1)))
    theta, _, lm_stats = levenberg_marquardt(problem, start, REFINEMENT)
    if not np.all(np.isfinite(theta)):
        return None
    f, z = float(theta[0]), float(theta[1])
    # full Jacobian (f, zeta and every segment's linear parameters) at the solution for the standard deviations
    betas, cols_lin = [], 3 * D * len(segs)
    for tau, y in segs:
        betas.append(_solve(_design(tau, f, z), y) if len(tau) else np.zeros((3, D)))
    J = np.zeros((n, 2 + cols_lin))
    r0, k = 0, 0
    resid = []
    osc2 = lag1 = 0.0  # the ringing's energy and the residuals' lag-one autocovariance (sums)
    for s, (tau, y) in enumerate(segs):
        if not len(tau):
            continue
        A = _design(tau, f, z)
        model = A @ betas[s]
        resid.append((y - model).ravel())
        osc2 += float(np.sum((A[:, 1:] @ betas[s][1:]) ** 2))
        lag1 += float(np.sum((y - model)[1:] * (y - model)[:-1]))
        for p, h in ((0, 1e-6 * f), (1, 1e-6)):
            th = [f, z]
            th[p] += h
            J[r0:r0 + y.size, p] = ((_design(tau, *th) @ betas[s]) - model).ravel() / h
        for d in range(D):  # y.ravel() is row-major: sample-major, axis-minor
            J[r0 + d:r0 + y.size:D, 2 + 3 * D * s + 3 * d:2 + 3 * D * s + 3 * d + 3] = A
        r0 += y.size
        k += 1
    resid = np.concatenate(resid)
    dof = max(n - 2 - 3 * D * k, 1)
    s2 = float(resid @ resid) / dof
    JtJ = J.T @ J
    keep = np.flatnonzero(np.abs(JtJ).sum(axis=0) > 0)
    cov = np.full((J.shape[1], J.shape[1]), np.nan)
    try:
        bread = np.linalg.inv(JtJ[np.ix_(keep, keep)])
    except np.linalg.LinAlgError:
        return None
    cov[np.ix_(keep, keep)] = s2 * bread
    # (f, zeta) from the sandwich whose middle sums the scores of samples within a lag window of each other
    # (errors correlated within a stop, module docstring); the white one when that is smaller
    meat = _correlated_scores(J[:, keep], resid, [y.size for _, y in segs if len(y)], D) * n / dof
    cov_nl = (bread @ meat @ bread)[:2, :2] if keep[0] == 0 and keep[1] == 1 else np.full((2, 2), np.nan)
    var_nl = np.maximum(np.diag(cov[:2, :2]), np.nan_to_num(np.diag(cov_nl), nan=0.0))
    # what the model leaves out (smooth, so it shows in the lag-one autocovariance, which white noise does not
    # have) is common to every stop; a misfit of relative size eps in the ringing's shape moves its decay rate
    # by about that relative amount: the damping's std is at least zeta * eps
    eps = math.sqrt(max(lag1, 0.0) / osc2) if osc2 > 0 else 0.0
    var_nl[1] = max(var_nl[1], (z * eps) ** 2)
    S = len(segs)
    rest = np.array([b[0] for b in betas])
    coef = np.array([b[1:] for b in betas])
    var_rest = np.array([np.nanmean([cov[2 + 3 * D * s + 3 * d, 2 + 3 * D * s + 3 * d] for d in range(D)])
                         for s in range(S)])
    return RingingFit(freq_hz=f, zeta=z, freq_std_hz=float(math.sqrt(max(var_nl[0], 0.0))),
                      zeta_std=float(math.sqrt(max(var_nl[1], 0.0))), rest=rest,
                      rest_std=np.sqrt(np.maximum(var_rest, 0.0)), coef=coef,
                      residual_rms=math.sqrt(s2), num_samples=n, success=lm_stats.stop in CONVERGED_STOPS)


__all__ = ["FREQ_BAND", "RingingFit", "ZETA_BOUNDS", "ZETA_GRID", "best_on_grid", "fit_damped_response",
           "in_bands", "resolvable_bands", "rest_drift"]
