"""The scores of :func:`~nrmpc_ros.frontend.evaluation.evaluate` as a text table and as a PNG of the errors over
time (``nrmpc replay``'s summary, ``nrmpc compare``)."""

from __future__ import annotations

import math

import numpy as np

from .evaluation import METRICS, Evaluation


def format_report(ev: Evaluation, per_estimate: bool = True) -> str:
    """Text table of the estimates and their errors, then statistics per method and the hold coverage."""
    lines = []
    e = ev.errors
    if per_estimate and ev.rows:
        t0 = min(min(r.stamp, r.ref_stamp) for r in ev.rows)
        lines.append(f"{'stamp':>9} {'ref':>9} {'method':<15}{'inl':>5} {'ms':>6} {'g_vs_gt':>8} {'g_vs_imu':>8} "
                     f"{'imu_vs_gt':>9} {'rot':>7} {'t_dir':>6}   (times from {t0:.3f} s, errors in deg)")
        for k, r in enumerate(ev.rows):
            lines.append(f"{r.stamp - t0:9.3f} {r.ref_stamp - t0:9.3f} {r.method:<15}{r.num_inliers:5d} "
                         f"{r.time_ms:6.0f} {e['gravity_vs_gt_deg'][k]:8.3f} {e['gravity_vs_imu_deg'][k]:8.3f} "
                         f"{e['imu_vs_gt_deg'][k]:9.3f} {e['rotation_deg'][k]:7.3f} {e['translation_deg'][k]:6.2f}")
    for method in ev.methods:
        lines.append(f"{method}: {sum(r.method == method for r in ev.rows)} estimates")
        for key, label in METRICS.items():
            s = ev.stats(key, method)
            if s["n"]:
                lines.append(f"  {label:<45} median {s['median']:.3f}  mean {s['mean']:.3f}  p90 {s['p90']:.3f}"
                             f"  (n={s['n']})")
    if ev.truth_apart:
        stamps = [r.stamp for r in ev.rows]
        lines.append(f"the ground truth ({ev.truth_span[0]:.3f}-{ev.truth_span[1]:.3f} s) and the estimates "
                     f"({min(stamps):.3f}-{max(stamps):.3f} s) share no time (is the ground truth on another clock "
                     "than the cameras'?): the estimates are not compared with it")
    elif ev.holds:
        lines.append(f"holds in the ground truth: {ev.holds}; with an estimate (after the first): "
                     f"{ev.holds_with_estimate}/{max(ev.holds - 1, 0)}; estimates outside every hold: "
                     f"{ev.outside_holds}")
    if not ev.rows:
        lines.append("no estimates")
    return "\n".join(lines)


def plot_errors(ev: Evaluation, path, flag: str | None = None) -> None:
    """PNG: gravity error over time (vs IMU and ground truth, and the IMU's own) with the band of twice the
    estimate's standard deviation (an error outside it breaks the published promise), and relative-pose errors.

    Written atomically (:func:`~nrmpc_ros.plots.save_png`); ``flag`` names the option in errors."""
    from ..plots import draw_series, figure, save_png

    fig, axes = figure(2, 1, figsize=(9, 6), sharex=True)
    t = np.array([r.stamp for r in ev.rows])
    t = t - t.min() if len(t) else t
    e = ev.errors
    title = ", ".join(f"{m}: {sum(r.method == m for r in ev.rows)}" for m in ev.methods) or "no estimates"
    draw_series(axes[0], [(t, e[key], style, colour, METRICS[key]) for key, style, colour in (
        ("gravity_vs_gt_deg", "o-", "C0"), ("gravity_vs_imu_deg", "s--", "C0"), ("imu_vs_gt_deg", ":", "C7"))],
        "gravity error (deg)", title=title, fontsize=9)
    band = 2.0 * np.array([float(r.extra.get("gravity_sigma_deg", math.nan)) for r in ev.rows])
    if np.isfinite(band).any():
        axes[0].fill_between(t, 0.0, band, color="C0", alpha=0.15, lw=0, label="2 std of the estimate")
        axes[0].legend(fontsize=8)
    draw_series(axes[1], [(t, e[key], style, None, METRICS[key]) for key, style in (
        ("rotation_deg", "o-"), ("translation_deg", "s--"))], "pose error (deg)", xlabel="time (s)", fontsize=9)
    fig.tight_layout()
    save_png(fig, path, flag, dpi=100)


__all__ = ["format_report", "plot_errors"]
