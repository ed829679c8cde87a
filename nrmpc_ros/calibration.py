"""Bar self-calibration: each bar's compliance m/EI from views whose gravity is measured (an IMU).

One robust bundle adjustment (:func:`nrmpc_ros.core.bundle.adjust_bundle`)
estimates the compliance of every bar (or one shared scalar) together with
the poses, the gravity and the points, over the holds of recorded sequences
(:func:`calibrate_sequences`, what ``nrmpc calibrate-bars`` does with a
bag: one gravity per sequence, and the accelerometer's constant tilt) or
over view pairs from matches files (:func:`calibrate_bars`: each pair its
own gravity). The measured gravity of every view enters as a prior
(docs/CONVENTIONS.md, "Gravity measurements"), so the IMU's noise is
accounted for. The standard deviations come from the
inverse of the reduced information at the optimum; a compliance that is not
significantly different from zero is reported as not observable instead of
as a number. Inliers chosen under a wrong compliance are biased towards it,
so the pairs are re-estimated with the current compliance at a threshold
that starts loose and tightens.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .core.bundle import BundleState, GravityPriors, Observations, adjust_bundle
from .core.estimators import EstimatorOptions, estimate
from .core.rig import Rig
from .core.sequence_steps import triangulated
from .errors import EstimationError


@dataclass
class BarCalibration:
    """Result: compliance (kg / (N m^2)) per calibrated group with its standard deviation."""

    groups: np.ndarray  # (M,) camera -> group index, -1 = rigid mount (not calibrated)
    compliance: np.ndarray  # (G,)
    std: np.ndarray  # (G,) reported std: the larger of the formal and the jackknife one
    observable: np.ndarray  # (G,) bool
    num_sequences: int  # independent sequences (a view pair is a sequence of two views)
    num_views: int
    num_observations: int
    iterations: int
    cost: float
    notes: list = field(default_factory=list)
    std_formal: np.ndarray | None = None  # from the reduced information alone (white pixel noise)
    std_jackknife: np.ndarray | None = None  # delete-a-group jackknife over the holds (NaN: too few holds)

    def calibrated_rig(self, rig: Rig) -> Rig:
        """The rig with EI = mass / compliance for observable bars; other bars keep their values."""
        k = rig.compliance.copy()
        for i, gi in enumerate(self.groups):
            if gi >= 0 and self.observable[gi]:
                k[i] = max(self.compliance[gi], 1e-12)
        return rig.with_compliance(k)


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
    for m in pairs:
        if not m.has_gravity:
            raise EstimationError(f"{m.source}: bar calibration needs gravity measurements in both views")
    base = EstimatorOptions()
    schedule = [8.0, 3.0] + [1.0] * 8  # inlier threshold factors; stops at the first converged round at 1
    it = 0
    res = None
    for rnd, factor in enumerate(schedule):
        rig_k = _apply(rig, groups, kg)
        opts = EstimatorOptions(threshold_px=base.threshold_px * factor)
        parts, R, t, g, meas, skipped = [], [], [], [], [], []
        for n, m in enumerate(pairs):
            est = estimate(rig_k, m, method="4pt-bending", seed=seed + n, options=opts)
            if not est.success or est.num_inliers < 12:
                skipped.append(f"{m.source}: skipped ({est.info.reason or 'too few inliers'})")
                continue
            idx = est.inliers
            parts.append(Observations.two_view(m.f1[idx], m.f2[idx], m.cam[idx]))
            R += [np.eye(3), est.R]
            t += [np.zeros(3), est.t]
            g1, g2 = m.body_gravity(rig_k)
            g.append(est.gravity if est.gravity is not None else g1)
            meas += [g1, g2]
        if progress:
            progress(rnd + 1, len(schedule))
        if not parts:
            raise EstimationError("no usable view pair for bar calibration")
        obs = Observations.concatenate(parts)
        priors = GravityPriors(np.array(meas), gravity_sigma_rad)
        k_before = kg.copy()
        res = adjust_bundle(rig, obs, np.array(R), np.array(t), np.array(g), priors=priors, compliance_groups=groups,
                            compliance=kg, max_iterations=max_iterations)
        kg = res.state.compliance
        it += res.iterations
        converged = np.all(np.abs(kg - k_before) <= 0.01 * np.maximum(np.abs(kg), 1e-12))
        if factor == 1.0 and converged:
            break
    cov = res.covariance[res.layout.compliance, res.layout.compliance]
    std = np.sqrt(np.maximum(np.diag(cov), 0.0)) if np.all(np.isfinite(cov)) else np.full(G, np.inf)
    observable = (kg > significance * std) & np.isfinite(std)
    notes = list(skipped) + _unobservable_notes(rig, groups, kg, std, observable)
    return BarCalibration(groups=groups, compliance=kg, std=std, observable=observable, num_sequences=len(parts),
                          num_views=obs.num_views, num_observations=len(obs), iterations=it, cost=res.cost,
                          notes=notes)


def calibrate_sequences(rig: Rig, sequences: list, shared: bool = False, bias_sigma_rad: float | None = 0.005,
                        max_iterations: int = 50, significance: float = 3.0, threshold_px: float = 2.0,
                        rounds: int = 4, resample_groups: int = 10) -> BarCalibration:
    """Estimate bar compliance from sequences of holds with measured gravity (``SequenceRecord`` each, see
    :meth:`nrmpc_ros.core.incremental.IncrementalSequence.sequences`), started from their poses and gravity.

    The inliers (angular error below ``threshold_px``, 4 times that in the first round) are chosen with the
    current compliance and re-chosen while it changes; each sequence keeps one gravity, every view's
    measurement is a prior of its own std, and the accelerometer's constant tilt is estimated with prior std
    ``bias_sigma_rad`` (None: no tilt).

    The standard deviations: the formal ones (inverse of the reduced information, white pixel noise) and,
    with ``resample_groups`` > 1 and enough holds, the delete-a-group jackknife over the holds (the holds
    split into that many groups, the calibration repeated without each), which also sees errors shared by
    the observations of one hold (its averaged tracks' small biases, a hold not fully settled); the larger
    of the two is reported.
    """
    groups = _groups(rig, shared)
    G = int(groups.max()) + 1
    if G <= 0:
        raise EstimationError(f"{rig.source}: no camera sits on a bar (all at the body centre); nothing to calibrate")
    seqs = [rec for rec in sequences if rec.tracks.g_meas is not None and rec.gravity is not None]
    if not seqs:
        raise EstimationError("no sequence of two holds or more with measured gravity for bar calibration")
    L = np.linalg.norm(rig.positions, axis=1)
    k0 = rig.compliance.copy()
    k0 = np.where(k0 > 0, k0, 2e-3 / (np.maximum(L, 1e-3) ** 2 * rig.gravity_magnitude))
    kg0 = np.array([k0[groups == gi].mean() for gi in range(G)])
    fit = _fit_sequences(rig, seqs, groups, kg0, bias_sigma_rad, max_iterations, threshold_px, rounds)
    kg, res, it = fit["compliance"], fit["result"], fit["iterations"]
    cov = res.covariance[res.layout.compliance, res.layout.compliance]
    std_formal = np.sqrt(np.maximum(np.diag(cov), 0.0)) if np.all(np.isfinite(cov)) else np.full(G, np.inf)
    std_jack = _jackknife_std(rig, seqs, groups, fit, bias_sigma_rad, max_iterations, threshold_px,
                              resample_groups)
    std = np.maximum(std_formal, np.nan_to_num(std_jack, nan=0.0))
    observable = (kg > significance * std) & np.isfinite(std)
    notes = _unobservable_notes(rig, groups, kg, std, observable)
    return BarCalibration(groups=groups, compliance=kg, std=std, observable=observable, num_sequences=len(seqs),
                          num_views=fit["num_views"], num_observations=fit["num_observations"], iterations=it,
                          cost=res.cost, notes=notes, std_formal=std_formal, std_jackknife=std_jack)


def _fit_sequences(rig: Rig, seqs: list, groups, kg, bias_sigma_rad, max_iterations, threshold_px, rounds) -> dict:
    """One calibration from the given compliance and the sequences' poses and gravity (see
    :func:`calibrate_sequences`)."""
    parts, R, t, g, meas, sig = [], [], [], [], [], []
    for rec in seqs:
        tr = rec.tracks
        scale = None if rec.noise_scale is None else np.asarray(rec.noise_scale, float)[tr.view]
        obs, _ = Observations.from_arrays(tr.view, tr.cam, tr.track, tr.f, tr.num_views, scale)
        seen = (np.bincount(obs.point, minlength=obs.num_points) >= 2)[obs.point]
        parts.append(obs.subset(seen)[0])
        R.append(rec.R)
        t.append(rec.t)
        g.append(rec.gravity)
        meas.append(tr.measured_gravity(rig))
        sig.append(rec.measured_sigma)
    obs = Observations.concatenate(parts)
    R, t, g = np.concatenate(R), np.concatenate(t), np.array(g)
    priors = GravityPriors(np.concatenate(meas), np.concatenate(sig), bias_sigma_rad)
    focal = float(np.mean([c.focal_px for c in rig.cameras]))
    res, it, bias = None, 0, None
    for rnd in range(rounds):
        rig_k = _apply(rig, groups, kg)
        state, prob = triangulated(rig_k, obs, BundleState(R, t, g, np.zeros((obs.num_points, 3)),
                                                           view_sequence=obs.view_sequence))
        err = np.linalg.norm(prob.residuals(state), axis=1)
        inl = err < (4.0 if rnd == 0 else 1.0) * threshold_px / focal
        inl &= (np.bincount(obs.point, weights=inl.astype(float), minlength=obs.num_points) >= 2)[obs.point]
        sub, _ = obs.subset(inl)
        k_before = kg.copy()
        res = adjust_bundle(rig, sub, R, t, g, priors=priors, compliance_groups=groups, compliance=kg, bias=bias,
                            max_iterations=max_iterations)
        kg, R, t, g, bias = res.state.compliance, res.state.R, res.state.t, res.state.gravity, res.state.bias
        it += res.iterations
        if rnd >= 1 and np.all(np.abs(kg - k_before) <= 0.01 * np.maximum(np.abs(kg), 1e-12)):
            break
    return {"compliance": kg, "result": res, "iterations": it, "num_views": obs.num_views,
            "num_observations": len(obs), "R": R, "t": t, "gravity": g}


def _without_views(rec, drop: set):
    """The sequence record without the views in ``drop`` (None if fewer than two remain); the first view kept
    becomes the origin: the poses and the origin's gravity are re-expressed in its body frame."""
    from .core.incremental import SequenceRecord

    keep = [k for k in range(rec.tracks.num_views) if k not in drop]
    if len(keep) < 2:
        return None
    R0, t0 = rec.R[keep[0]], rec.t[keep[0]]
    R = np.einsum("ji,njk->nik", R0, rec.R[keep])
    t = np.einsum("ji,nj->ni", R0, rec.t[keep] - t0)
    return SequenceRecord(rec.tracks.views_subset(keep), R, t, R0.T @ rec.gravity,
                          np.asarray(rec.measured_sigma)[keep],
                          None if rec.noise_scale is None else np.asarray(rec.noise_scale)[keep])


def _jackknife_std(rig: Rig, seqs: list, groups, fit: dict, bias_sigma_rad, max_iterations, threshold_px,
                   num_groups: int) -> np.ndarray:
    """Delete-a-group jackknife std of the compliance over the holds (NaN where it cannot be formed)."""
    G = len(fit["compliance"])
    views = [(s, k) for s, rec in enumerate(seqs) for k in range(rec.tracks.num_views)]
    J = min(int(num_groups), len(views))
    if J < 3:
        return np.full(G, np.nan)
    # the full solution's poses and gravity start every replicate (they differ from it by one group of holds)
    start, n = [], 0
    for rec in seqs:
        m = rec.tracks.num_views
        start.append(type(rec)(rec.tracks, fit["R"][n:n + m], fit["t"][n:n + m], fit["gravity"][len(start)],
                               rec.measured_sigma, rec.noise_scale))
        n += m
    order = np.random.default_rng(0).permutation(len(views))  # groups mix holds of every part of the recording
    estimates = []
    for j in range(J):
        drop = {views[i] for i in order[j::J]}
        part = [_without_views(rec, {k for s2, k in drop if s2 == s}) for s, rec in enumerate(start)]
        part = [p for p in part if p is not None]
        if not part:
            continue
        try:
            r = _fit_sequences(rig, part, groups, fit["compliance"].copy(), bias_sigma_rad, max_iterations,
                               threshold_px, rounds=2)
        except EstimationError:
            continue
        estimates.append(r["compliance"])
    if len(estimates) < 3:
        return np.full(G, np.nan)
    est = np.array(estimates)
    m = len(est)
    return np.sqrt((m - 1) / m * np.sum((est - est.mean(axis=0)) ** 2, axis=0))


def _unobservable_notes(rig: Rig, groups, kg, std, observable) -> list:
    """One note per bar group whose compliance is not significantly different from a rigid mount."""
    notes = []
    for gi in np.flatnonzero(~np.asarray(observable)):
        cams = [rig.cameras[i].name for i in np.flatnonzero(groups == gi)]
        notes.append(f"compliance of {', '.join(cams)} not observable: {kg[gi]:.3g} +- {std[gi]:.2g} "
                     f"kg/(N m^2) is not significantly different from a rigid mount")
    return notes


def _apply(rig: Rig, groups, kg) -> Rig:
    k = rig.compliance.copy()
    on = groups >= 0
    k[on] = kg[groups[on]]
    return rig.with_compliance(np.maximum(k, 1e-15) * on + k * ~on)


def describe(cal: BarCalibration, rig: Rig) -> str:
    """Human-readable table of the calibration."""
    lines = [f"bar calibration over {cal.num_views} views in {cal.num_sequences} sequences, {cal.num_observations} "
             "observations, "
             f"{cal.iterations} iterations"]
    for gi in range(len(cal.compliance)):
        cams = [rig.cameras[i] for i in np.flatnonzero(cal.groups == gi)]
        names = ", ".join(c.name for c in cams)
        if cal.observable[gi]:
            k, s = cal.compliance[gi], cal.std[gi]
            eis = ", ".join(f"EI {c.mass / k:.4g} N m^2 (mass {c.mass if c.mass > 0 else 1.0:g} kg)" for c in cams)
            why = ""
            if cal.std_formal is not None and cal.std_jackknife is not None and np.isfinite(cal.std_jackknife[gi]):
                why = f"; formal {cal.std_formal[gi]:.2g}, jackknife over holds {cal.std_jackknife[gi]:.2g}"
            lines.append(f"  {names}: compliance {k:.5g} +- {s:.2g} kg/(N m^2) ({100 * s / k:.1f} %{why}) -> {eis}")
        else:
            lines.append(f"  {names}: not observable ({cal.compliance[gi]:.3g} +- {cal.std[gi]:.2g}); left as in "
                         "the rig file")
    lines += [f"  note: {n}" for n in cal.notes]
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# The bars' dynamics: natural frequency and damping from the ringing in the images
# ---------------------------------------------------------------------------

DISAGREE_SIGMAS = 3.0  # a fitted frequency off the rig file's by more than this many of its stds disagrees


@dataclass
class BarDynamics:
    """One bar's first bending mode identified from the ringing of its camera's image offset after the stops."""

    camera: str
    freq_hz: float
    freq_std_hz: float
    zeta: float
    zeta_std: float
    rig_freq_hz: float  # sqrt(3 EI / (m L^3)) / (2 pi) from the rig file
    num_stops: int  # holds whose offsets entered the fit
    residual_px: float  # RMS of the fit's residual per image axis

    @property
    def disagrees(self) -> bool:
        """The fitted frequency is off the rig file's by more than DISAGREE_SIGMAS of its std."""
        return abs(self.freq_hz - self.rig_freq_hz) > DISAGREE_SIGMAS * self.freq_std_hz


def _few_stops_factor(num_stops: int) -> float:
    """The jackknife std over ``num_stops`` stops is itself estimated from num_stops - 1 degrees of freedom: the
    ratio of Student's t to the normal two-sided 95 % quantile makes +-2 of the published std cover the error
    as often as +-2 of the true std would (1.31 for six stops, 1.15 for ten, 1 for many)."""
    from scipy.stats import norm, t

    return float(t.ppf(0.975, max(num_stops - 1, 1)) / norm.ppf(0.975))


def identify_bar_dynamics(rig: Rig, holds: list, min_frames: int = 8) -> list:
    """Each flexible bar's natural frequency and damping ratio from its camera's image offsets after every stop
    (:attr:`~nrmpc_ros.frontend.holds.Hold.trace`), fitted jointly over the holds (one frequency and damping
    per bar, each hold its own rest offset and ringing amplitude and phase:
    :func:`~nrmpc_ros.frontend.ringing.fit_damped_response`) in the camera's rotation angle (times its
    focal length), started at the rig file's frequency. The stds are the larger of the fit's own (which
    allows for errors correlated within a stop) and the delete-one-stop jackknife's (with three stops or
    more; widened by Student's t for its few degrees of freedom): the offsets' errors are not white
    (docs/PIPELINE.md, "Measuring a hold"). Per camera a :class:`BarDynamics`, or None for a rigid bar or
    one without enough frames."""
    from .core.dynamics import bar_natural_frequencies
    from .frontend.ringing import fit_damped_response

    f_rig = bar_natural_frequencies(rig)
    out = []
    for i, cam in enumerate(rig.cameras):
        if not (np.isfinite(f_rig[i]) and f_rig[i] > 0):
            out.append(None)
            continue
        # the offset of the tracks' median is f tan(rotation since the anchor frame): the ringing is a damped
        # sinusoid in the angle, f atan(offset / f), not in the pixels (tan's cubic term biases the damping up)
        focal = float(cam.focal_px)
        segs = [(h.trace_t - h.start, focal * np.arctan(h.trace[:, i] / focal)) for h in holds
                if h.trace is not None and np.isfinite(h.trace[:, i, 0]).sum() >= min_frames]
        fit = fit_damped_response(segs, float(f_rig[i])) if segs else None
        if fit is None:
            out.append(None)
            continue
        f_std, z_std = fit.freq_std_hz, fit.zeta_std
        if len(segs) >= 3:  # the rendering's or the tracks' errors are not white: the spread over the stops says
            loo = [fit_damped_response(segs[:k] + segs[k + 1:], float(f_rig[i])) for k in range(len(segs))]
            loo = np.array([(r.freq_hz, r.zeta) for r in loo if r is not None])
            if len(loo) >= 3:
                jack = np.sqrt((len(loo) - 1) / len(loo) * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0))
                jack *= _few_stops_factor(len(loo))
                f_std, z_std = max(f_std, float(jack[0])), max(z_std, float(jack[1]))
        out.append(BarDynamics(cam.name, fit.freq_hz, f_std, fit.zeta, z_std, float(f_rig[i]), len(segs),
                               fit.residual_rms))
    return out


def describe_dynamics(dyn: list, rig: Rig) -> str:
    """Human-readable table of :func:`identify_bar_dynamics`."""
    lines = ["bar dynamics from the ringing after the stops (natural frequency, damping ratio):"]
    for cam, d in zip(rig.cameras, dyn):
        if d is None:
            lines.append(f"  {cam.name}: rigid, or too few frames after the stops to fit the ringing")
            continue
        check = (f"DISAGREES with the rig file's {d.rig_freq_hz:.4g} Hz (by "
                 f"{abs(d.freq_hz - d.rig_freq_hz) / max(d.freq_std_hz, 1e-12):.1f} std)" if d.disagrees
                 else f"agrees with the rig file's {d.rig_freq_hz:.4g} Hz")
        lines.append(f"  {d.camera}: {d.freq_hz:.4g} +- {d.freq_std_hz:.2g} Hz ({check}), damping "
                     f"{d.zeta:.4g} +- {d.zeta_std:.2g}, over {d.num_stops} stops (residual {d.residual_px:.3f} px)")
    return "\n".join(lines)


def rig_dict_with_dynamics(rig: Rig, dyn: list) -> dict:
    """The rig file's mapping with each identified bar's ``damping`` and ``frequency_hz`` and their stds
    (docs/CONVENTIONS.md, "The rig in motion"; the dynamics derive the frequency from EI, mass and length, the
    identified one and the stds tell how far a prediction of the ringing can be trusted)."""
    d = rig.to_dict()
    for cd, b in zip(d["cameras"], dyn):
        if b is not None and "bar" in cd:
            cd["bar"]["damping"] = float(round(b.zeta, 6))
            cd["bar"]["frequency_hz"] = float(round(b.freq_hz, 6))
            for key, std in (("damping_std", b.zeta_std), ("frequency_std_hz", b.freq_std_hz)):
                if np.isfinite(std) and std >= 0:
                    cd["bar"][key] = float(f"{std:.3g}")
    return d


__all__ = ["BarCalibration", "BarDynamics", "calibrate_bars", "calibrate_sequences", "describe", "describe_dynamics",
           "identify_bar_dynamics", "rig_dict_with_dynamics"]
