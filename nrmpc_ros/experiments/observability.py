"""How well can a rig observe gravity? CRLB averaged over gravity directions and motions.

Geometries are drawn by the synthetic generator (uniform gravity direction,
OpenGV-style motion, the paper's point volume); the bound of each geometry
comes from :mod:`.crlb`. ``sweep_ei`` repeats it over bar rigidities with the
same geometries, and ``ei_limit`` finds the EI beyond which the gravity bound
exceeds a required accuracy.

``sequence_observability`` does the same for a recording of K holds
(simulated sequences of :mod:`nrmpc_ros.sim.sequence`): the bound on each
hold's gravity when one gravity is estimated jointly over all holds, beside
the bound of the consecutive pairs on their own (docs/CONVENTIONS.md,
"Sequences"). With several K, every K uses the first K holds of the same
sequences, so the bounds show what recording more holds adds.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..core.rig import Rig
from ..core.tracks import Tracks
from ..sim.sequence import SequenceProblem, SequenceScenario, make_sequence
from ..sim.synthetic import Scenario, make_problem, make_rig
from .crlb import KINDS, Bound, problem_bound, sequence_bound, summarize_bounds
from .runner import task_seed


def geometry_bounds(rig: Rig, scenario: Scenario, samples: int, seed: int = 0,
                    gravity_prior_sigma: float = math.inf) -> list[Bound]:
    """Per-geometry bounds at ``samples`` seeded geometries; noise from scenario.pixel_noise (px)."""
    focal = float(np.mean([c.focal_px for c in rig.cameras]))
    sigma = scenario.pixel_noise / focal
    if not sigma > 0:
        raise ValueError("pixel noise must be > 0 for a Cramér-Rao bound")
    out = []
    for k in range(samples):
        problem = make_problem(scenario, seed=task_seed(seed, k), rig=rig)
        out.append(problem_bound(problem, sigma, gravity_prior_sigma))
    return out


def observability(rig: Rig, scenario: Scenario, samples: int = 30, seed: int = 0,
                  gravity_prior_sigma: float = math.inf) -> dict:
    """{'rotation'|'translation'|'gravity': {'rms', 'median'}} (rad) averaged over the seeded geometries."""
    return summarize_bounds(geometry_bounds(rig, scenario, samples, seed, gravity_prior_sigma), seed=seed)


def rig_at_ei(rig: Rig | None, scenario: Scenario, EI: float) -> Rig:
    """The custom rig with every massive bar at EI, or the scenario's simulated rig built with EI."""
    if rig is not None:
        return rig.with_bar_ei(EI)
    return make_rig(replace(scenario.rig, EI=float(EI)))


def sweep_ei(rig: Rig | None, scenario: Scenario, ei_values, samples: int = 20, seed: int = 0) -> list[dict]:
    """Bounds at each EI on the same geometries: rows {EI, <kind>_rms, <kind>_median} in rad."""
    rows = []
    for ei in ei_values:
        res = observability(rig_at_ei(rig, scenario, ei), scenario, samples, seed)
        row = {"EI": float(ei)}
        for kind in KINDS:
            row[f"{kind}_rms"] = res[kind]["rms"]
            row[f"{kind}_median"] = res[kind]["median"]
        rows.append(row)
    return rows


def ei_limit(ei_values, bound, accuracy_rad: float) -> float | None:
    """Smallest EI where the bound reaches accuracy_rad (log-log interpolation); None if never in the range.

    0.0 means the bound exceeds the accuracy already at the smallest EI swept.
    """
    ei = np.asarray(ei_values, float)
    b = np.asarray(bound, float)
    order = np.argsort(ei)
    ei, b = ei[order], b[order]
    above = b >= accuracy_rad
    if not above.any():
        return None
    k = int(np.argmax(above))
    if k == 0:
        return 0.0
    if not np.isfinite(b[k]):
        return float(ei[k])
    x0, x1 = np.log(ei[k - 1]), np.log(ei[k])
    y0, y1 = np.log(b[k - 1]), np.log(b[k])
    x = x0 + (np.log(accuracy_rad) - y0) * (x1 - x0) / (y1 - y0) if y1 != y0 else x1
    return float(np.exp(x))


def plot_sweep(rows: list[dict], accuracy_rad: float, limit: float | None, path, title: str):
    """PNG: each bound (RMS, and gravity's median) against EI, the required accuracy and the EI limit."""
    from ..plots import draw_limits, draw_series, figure, save_png

    fig, ax = figure(figsize=(5.5, 3.6))
    ei = [r["EI"] for r in rows]
    series = [(ei, np.degrees([r[f"{kind}_rms"] for r in rows]), "-o", colour, f"{kind} (RMS)")
              for kind, colour in zip(KINDS, ("tab:orange", "tab:purple", "tab:blue"))]
    series.append((ei, np.degrees([r["gravity_median"] for r in rows]), "--", "tab:blue", "gravity (median)"))
    draw_series(ax, series, "Cramér-Rao bound (deg)", xlabel="EI (N m^2)", title=title,
                logx=True, logy=True)
    draw_limits(ax, horizontal=(np.degrees(accuracy_rad), "k", f"required {np.degrees(accuracy_rad):g} deg"),
                vertical=(limit, "tab:red", f"EI limit {limit:.3g} N m^2") if limit else None)
    fig.tight_layout()
    save_png(fig, path, "--out", dpi=80)


def first_holds(problem: SequenceProblem, K: int) -> SequenceProblem:
    """The first K holds of a simulated sequence: what a recording stopped after hold K - 1 would hold.

    Observations of later holds are dropped, and so are landmarks then seen in one hold only (they carry no
    information); ground truth and landmark positions (row = track id) are kept.
    """
    tr = problem.tracks
    if not 2 <= K <= tr.num_views:
        raise ValueError(f"K must be in 2..{tr.num_views}, got {K}")
    keep = tr.view < K
    ids, inv = np.unique(tr.track[keep], return_inverse=True)
    first = np.full(len(ids), K)
    last = np.full(len(ids), -1)
    np.minimum.at(first, inv, tr.view[keep])
    np.maximum.at(last, inv, tr.view[keep])
    keep[keep] = (last > first)[inv]
    g = None if tr.g_meas is None else tr.g_meas[:K]
    sub = Tracks(tr.view[keep], tr.cam[keep], tr.track[keep], tr.f[keep], g, num_views=K, source=tr.source)
    return SequenceProblem(rig=problem.rig, tracks=sub, R=problem.R[:K], t=problem.t[:K],
                           gravity=problem.gravity[:K], points=problem.points, inlier_mask=problem.inlier_mask[keep])


def sequence_observability(rig: Rig, scenario: SequenceScenario, samples: int = 30, seed: int = 0,
                           gravity_prior_sigma: float = math.inf, views=None) -> list[dict]:
    """Bounds on each hold's gravity direction over ``samples`` seeded sequences of the scenario.

    One row per number of holds K in ``views`` (default: scenario.num_views; each at most that): the median
    over holds and sequences of the median-angle bound (rad) with one gravity estimated jointly over the K
    holds (``joint``) and with each consecutive pair on its own (``pairwise``), vision only and with every
    hold's measured gravity as a prior of std ``gravity_prior_sigma`` (rad; ``joint_prior``,
    ``pairwise_prior``, None when it is inf). Image noise scenario.pixel_noise (px) over the mean focal length.
    """
    focal = float(np.mean([c.focal_px for c in rig.cameras]))
    sigma = scenario.pixel_noise / focal
    if not sigma > 0:
        raise ValueError("pixel noise must be > 0 for a Cramér-Rao bound")
    views = [scenario.num_views] if views is None else [int(k) for k in views]
    if any(not 2 <= k <= scenario.num_views for k in views):
        raise ValueError(f"every number of holds must be in 2..{scenario.num_views}, got {views}")
    priors = [math.inf] + ([gravity_prior_sigma] if math.isfinite(gravity_prior_sigma) else [])
    # pooled per-hold median angles: (K, prior) -> {"joint": [...], "pair": [...]}
    pooled = {(k, p): {"joint": [], "pair": []} for k in views for p in priors}
    for s in range(samples):
        full = make_sequence(scenario, seed=task_seed(seed, s), rig=rig)
        for k in views:
            problem = full if k == full.tracks.num_views else first_holds(full, k)
            for p in priors:
                b = sequence_bound(problem, sigma, p)
                for which in ("joint", "pair"):
                    pooled[(k, p)][which].append(b.median_angles(which))
    rows = []
    for k in views:
        row = {"views": k}
        for p, suffix in zip(priors, ("", "_prior")):
            for which, name in (("joint", "joint"), ("pair", "pairwise")):
                row[name + suffix] = float(np.median(np.concatenate(pooled[(k, p)][which])))
        if len(priors) == 1:
            row["joint_prior"] = row["pairwise_prior"] = None
        rows.append(row)
    return rows


__all__ = ["ei_limit", "first_holds", "geometry_bounds", "observability", "plot_sweep", "rig_at_ei",
           "sequence_observability", "sweep_ei"]
