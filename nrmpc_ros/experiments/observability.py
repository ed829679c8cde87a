"""How well can a rig observe gravity? CRLB averaged over gravity directions and motions (issue 3).

Geometries are drawn by the synthetic generator (uniform gravity direction,
OpenGV-style motion, the paper's point volume); the bound of each geometry
comes from :mod:`.crlb`. ``sweep_ei`` repeats it over bar rigidities with the
same geometries, and ``ei_limit`` finds the EI beyond which the gravity bound
exceeds a required accuracy.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..core.rig import Rig
from ..sim.synthetic import Scenario, make_problem, make_rig
from .crlb import KINDS, Bound, problem_bound, set_bar_ei, summarize_bounds
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
        return set_bar_ei(rig, EI)
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ei = np.array([r["EI"] for r in rows])
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for kind, colour in zip(KINDS, ("tab:orange", "tab:purple", "tab:blue")):
        ax.plot(ei, np.degrees([r[f"{kind}_rms"] for r in rows]), "-o", ms=3, color=colour, label=f"{kind} (RMS)")
    ax.plot(ei, np.degrees([r["gravity_median"] for r in rows]), "--", color="tab:blue", label="gravity (median)")
    ax.axhline(np.degrees(accuracy_rad), color="k", lw=0.8, ls=":", label=f"required {np.degrees(accuracy_rad):g} deg")
    if limit:
        ax.axvline(limit, color="tab:red", lw=0.8, ls=":", label=f"EI limit {limit:.3g} N m^2")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("EI (N m^2)")
    ax.set_ylabel("Cramér-Rao bound (deg)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, which="both", lw=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


__all__ = ["ei_limit", "geometry_bounds", "observability", "plot_sweep", "rig_at_ei", "sweep_ei"]
