"""Benchmark of the three estimators against PoseLib's rigid generalized relative pose.

All methods run one after the other in this process on the same seeded
problems (the paper's nominal case by default), so their times are
comparable: ``time_s`` is the wall time of :func:`nrmpc_ros.core.estimate`
and, for PoseLib, of ``poselib.estimate_generalized_relative_pose`` alone
(the conversion of its inputs is not timed). Errors are docs/CONVENTIONS.md (Errors and success);
error/CRLB divides the median error by the median-angle Cramér-Rao bound of
the same problems (:mod:`.crlb`), so an efficient estimator scores ~1.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..core import METHODS, EstimatorOptions, estimate, pose_errors
from ..core.matches import Matches
from ..core.rig import Rig
from ..errors import OptionError
from ..sim.synthetic import Scenario, make_problem
from .crlb import problem_bound, summarize_bounds
from .runner import ERROR_KINDS, task_seed

POSELIB = "poselib-rigid"
MIN_PAIR_MATCHES = 5


def nominal_scenario(cameras: int = 4) -> Scenario:
    """The paper's nominal case: N = 1000, EI 0.1, 0.1 px, 5% outliers, gravity noise 0.01 px."""
    from .sweeps import base_scenario

    return base_scenario(cameras)


def poselib_inputs(rig: Rig, m: Matches):
    """PoseLib's (matches, camera1_ext, cameras1, camera2_ext, cameras2) from the rig's canonical extrinsics.

    Bearings become ideal pinhole pixels of each camera (fx, fy, cx, cy);
    correspondences behind either camera (z <= 0, only outliers or extreme
    motions) cannot be pixels and are left out. PoseLib 2.0.5 loops forever
    with fewer than two camera pairs or no pair with 5 matches, so this raises
    ValueError unless at least two cameras keep >= 5 matches each.
    """
    import poselib

    exts, cams, pairs = [], [], []
    for j, c in enumerate(rig.cameras):
        V, v = rig.rotations[j], rig.positions[j]
        pose = poselib.CameraPose()
        pose.R = V.T  # PoseLib: rig -> camera, x_c = R x_rig + t
        pose.t = -V.T @ v
        exts.append(pose)
        fx, fy, cx, cy = (float(x) for x in c.intrinsics)
        cams.append({"model": "PINHOLE", "width": int(c.resolution[0]), "height": int(c.resolution[1]),
                     "params": [fx, fy, cx, cy]})
        sel = (m.cam == j) & (m.f1[:, 2] > 1e-6) & (m.f2[:, 2] > 1e-6)
        if not sel.any():
            continue
        f1, f2 = m.f1[sel], m.f2[sel]
        pm = poselib.PairwiseMatches()
        pm.cam_id1 = j
        pm.cam_id2 = j
        pm.x1 = np.stack([fx * f1[:, 0] / f1[:, 2] + cx, fy * f1[:, 1] / f1[:, 2] + cy], axis=1)
        pm.x2 = np.stack([fx * f2[:, 0] / f2[:, 2] + cx, fy * f2[:, 1] / f2[:, 2] + cy], axis=1)
        pairs.append(pm)
    usable = sum(1 for p in pairs if len(p.x1) >= MIN_PAIR_MATCHES)
    if usable < 2:
        raise ValueError(f"PoseLib needs two camera pairs with >= {MIN_PAIR_MATCHES} matches, got {usable}")
    return pairs, exts, cams, exts, cams


def run_poselib(rig: Rig, m: Matches, threshold_px: float, seed: int = 0):
    """(R, t, time_s) of PoseLib's rigid pipeline in our frames (docs/CONVENTIONS.md, Frames); (None, None, 0) if
    the input is invalid."""
    import poselib

    try:
        args = poselib_inputs(rig, m)
    except ValueError:
        return None, None, 0.0
    ransac_opt = {"max_epipolar_error": float(threshold_px), "seed": int(seed) % (2**31)}
    t0 = time.perf_counter()
    pose, _info = poselib.estimate_generalized_relative_pose(*args, ransac_opt, {})
    elapsed = time.perf_counter() - t0
    Rp, tp = np.asarray(pose.R), np.asarray(pose.t)  # rig 1 -> rig 2
    if not (np.all(np.isfinite(Rp)) and np.all(np.isfinite(tp))):
        return None, None, elapsed
    return Rp.T, -Rp.T @ tp, elapsed


def run_bench(runs: int = 100, seed: int = 0, scenario: Scenario | None = None, rig: Rig | None = None,
              methods=METHODS, poselib: bool = True, poselib_threshold_px: float | None = None,
              progress: bool = True) -> dict:
    """Time and score each method (and PoseLib) on ``runs`` seeded problems; per-method summary dict."""
    from tqdm import tqdm

    if runs < 1:
        raise OptionError("benchmark", "runs", f"must be >= 1, got {runs}")
    sc = scenario or nominal_scenario()
    if sc.pixel_noise <= 0:
        raise OptionError("benchmark", "pixel_noise", "must be > 0 (the Cramér-Rao bound needs noise)")
    opts = EstimatorOptions()
    if poselib_threshold_px is None:
        poselib_threshold_px = opts.loose_threshold_px  # the same rigid-model tolerance as 6pt-nonbending
    names = list(methods) + ([POSELIB] if poselib else [])
    rec = {n: {"time": [], "success": [], "produced": [], **{k: [] for k in ERROR_KINDS}} for n in names}
    bounds = []
    for k in tqdm(range(runs), desc="bench", unit="problem", disable=not progress, dynamic_ncols=True):
        s = task_seed(seed, k)
        p = make_problem(sc, seed=s, rig=rig)
        focal = float(np.mean([c.focal_px for c in p.rig.cameras]))
        bounds.append(problem_bound(p, sc.pixel_noise / focal))
        for name in names:
            if name == POSELIB:
                R, t, dt = run_poselib(p.rig, p.matches, poselib_threshold_px, s)
                g, produced = None, R is not None
            else:
                est = estimate(p.rig, p.matches, name, seed=s, options=opts)
                R, t, g, dt, produced = est.R, est.t, est.gravity, est.time_s, est.success
            err = pose_errors(R, t, p.R, p.t, g, p.gravity)
            r = rec[name]
            r["time"].append(dt)
            r["success"].append(err["success"])
            r["produced"].append(produced)
            for kind in ERROR_KINDS:
                r[kind].append(err[kind])
    crlb = summarize_bounds(bounds, seed=seed)
    out = {}
    for name in names:
        r = rec[name]
        ok = np.array(r["success"], bool)
        produced = np.array(r["produced"], bool)
        d = {"runs": runs, "median_time_s": float(np.median(r["time"])), "success_rate": float(ok.mean())}
        for kind in ERROR_KINDS:
            v = np.array(r[kind], float)
            if kind == "gravity" and not np.isfinite(v[produced]).any():
                d[f"median_{kind}"] = d[f"median_{kind}_success"] = d[f"{kind}_over_crlb"] = None
                continue
            allv = np.where(produced, v, math.pi)  # a run without a pose counts as the worst angle
            d[f"median_{kind}"] = float(np.median(allv))
            d[f"median_{kind}_success"] = float(np.median(v[ok])) if ok.any() else None
            b = crlb[kind]["median"]
            d[f"{kind}_over_crlb"] = float(d[f"median_{kind}"] / b) if math.isfinite(b) and b > 0 else None
        out[name] = d
    if poselib:
        base = out[POSELIB]["median_time_s"]
        for d in out.values():
            d["time_ratio_poselib"] = float(d["median_time_s"] / base) if base > 0 else None
    return {"scenario": sc.to_dict(), "runs": runs, "seed": seed, "poselib_threshold_px": poselib_threshold_px,
            "crlb_rad": crlb, "methods": out}


def format_table(res: dict) -> str:
    """The human-readable table of ``nrmpc bench``."""
    head = (f"{'method':16s} {'time ms':>8s} {'xPoseLib':>8s} {'success':>8s} {'rot mrad':>9s} {'trans mrad':>10s} "
            f"{'grav mrad':>9s} {'rot/CRLB':>8s} {'trans/CRLB':>10s} {'grav/CRLB':>9s}")
    lines = [head, "-" * len(head)]

    def f(v, scale=1.0, fmt="{:.3g}"):
        return "-" if v is None else fmt.format(v * scale)

    for name, d in res["methods"].items():
        cells = [f(d["median_time_s"], 1e3, "{:.1f}"), f(d.get("time_ratio_poselib"), 1, "{:.2f}"),
                 f(d["success_rate"], 100, "{:.0f}%"), f(d["median_rotation"], 1e3),
                 f(d["median_translation"], 1e3), f(d["median_gravity"], 1e3),
                 f(d["rotation_over_crlb"], 1, "{:.2f}"), f(d["translation_over_crlb"], 1, "{:.2f}"),
                 f(d["gravity_over_crlb"], 1, "{:.2f}")]
        widths = (8, 8, 8, 9, 10, 9, 8, 10, 9)
        lines.append(f"{name:16s} " + " ".join(c.rjust(w) for c, w in zip(cells, widths)))
    c = res["crlb_rad"]
    bound = ", ".join(f"{k} {1e3 * c[k]['median']:.3g}" for k in ERROR_KINDS)
    lines.append("")
    lines.append(f"medians over all {res['runs']} runs (a run without a pose counts as pi); success: rotation < 0.5 "
                 "rad and translation < 0.2 rad (docs/CONVENTIONS.md (Errors and success))")
    lines.append(f"CRLB (median angle of an efficient estimator, mrad): {bound}")
    return "\n".join(lines)


__all__ = ["POSELIB", "format_table", "nominal_scenario", "poselib_inputs", "run_bench", "run_poselib"]
