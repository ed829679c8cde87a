"""Scoring estimates against the IMU and a bag's ground truth: per-estimate errors and their statistics.

One implementation for ``nrmpc replay``'s summary, ``nrmpc compare``, the report and the benchmarks:
:func:`evaluate` computes per-estimate errors (gravity vs IMU and vs ground truth, relative pose vs ground
truth), which ground-truth holds got an estimate and which estimates lie outside every hold. The rows come
from :mod:`.estimates_csv`, the reference data from :mod:`.reference`, the IMU's gravity from
:mod:`.imu_reference`; :mod:`.evaluation_report` prints and draws the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.metrics import pose_errors
from ..core.rig import Rig
from ..core.so3 import angle_between
from .imu_reference import WINDOW_S, ImuReference
from .reference import STAMP_TOLERANCE_S, Reference, nearest_stamp
from .zupt import ZuptConfig

METRICS = {
    "gravity_vs_gt_deg": "gravity vs ground truth (deg)",
    "gravity_vs_imu_deg": "gravity vs IMU (deg)",
    "imu_vs_gt_deg": "IMU gravity vs ground truth (deg)",
    "rotation_deg": "relative rotation vs ground truth (deg)",
    "translation_deg": "translation direction vs ground truth (deg)",
    "translation_m": "|t - t_gt| (m)",
}


@dataclass
class Evaluation:
    """Per-estimate errors of the rows (one array per :data:`METRICS` key) and the ground truth's holds."""

    rows: list  # EstimateRow
    errors: dict  # metric -> (N,) array, NaN where not available
    holds: int = 0  # holds (still intervals) found in the ground truth
    holds_with_estimate: int = 0
    outside_holds: int = 0  # estimates stamped outside every ground-truth hold
    truth_span: tuple | None = None  # (first, last) stamp of the ground truth (s); None without any

    @property
    def truth_apart(self) -> bool:
        """Whether the estimates and the ground truth share no time at all (each stamp outside the other's span):
        the ground truth is on another clock than the cameras (a recording whose cameras stamp by a counter),
        and nothing here compares them."""
        if self.truth_span is None or not self.rows:
            return False
        lo, hi = self.truth_span
        return not any(lo - STAMP_TOLERANCE_S <= r.stamp <= hi + STAMP_TOLERANCE_S for r in self.rows)

    def stats(self, metric: str, method: str | None = None) -> dict:
        """n, median, mean, p90 of one metric (optionally for one method), ignoring NaN."""
        x = self.errors[metric]
        if method is not None:
            x = x[np.array([r.method == method for r in self.rows], dtype=bool)]
        x = x[np.isfinite(x)]
        if len(x) == 0:
            return {"n": 0, "median": math.nan, "mean": math.nan, "p90": math.nan}
        return {"n": int(len(x)), "median": float(np.median(x)), "mean": float(np.mean(x)),
                "p90": float(np.percentile(x, 90))}

    @property
    def methods(self) -> list:
        return sorted({r.method for r in self.rows})

    @property
    def coverage(self) -> float:
        """Fraction of the ground-truth holds (after the first) that got an estimate."""
        return self.holds_with_estimate / (self.holds - 1) if self.holds > 1 else math.nan


SAME_INSTANT_S = 1e-6  # ground-truth stamps closer than this are one instant (cameras' roundings of one trigger)


def static_holds(ref: Reference, tol_deg: float = 0.01, tol_m: float = 1e-4) -> list:
    """(start, end) stamps of runs of identical ground-truth poses (the rig held still). Poses repeated at one
    stamp (a recording that writes the ground truth at every camera's trigger, cameras at different rates) count
    once: two cameras at one instant of a move are not a hold. Two instants closer than the recording's typical
    interval (cameras a few ms apart in phase) are the same pose only within that share of ``tol_deg`` and
    ``tol_m``: the end of a move, slow as it is, still turns the rig by 0.01 deg in 3 ms, and is no hold."""
    if not ref.has_pose:
        return []
    new = np.r_[True, np.diff(ref.pose_t) > SAME_INSTANT_S]
    pose_t, pose_R, pose_p = ref.pose_t[new], ref.pose_R[new], ref.pose_p[new]
    dR = np.einsum("nji,njk->nik", pose_R[:-1], pose_R[1:])
    ang = np.degrees(np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    dt = np.diff(pose_t)
    share = np.minimum(1.0, dt / np.median(dt)) if len(dt) else dt  # of the tolerances, for closer instants
    same = (ang < tol_deg * share) & (np.linalg.norm(np.diff(pose_p, axis=0), axis=1) < tol_m * share)
    cut = np.flatnonzero(~same) + 1  # first pose of every run after the first
    first, last = np.r_[0, cut], np.r_[cut - 1, len(pose_t) - 1]
    min_len = 2 if np.any(last > first) else 1
    keep = last - first + 1 >= min_len
    return [(float(pose_t[a]), float(pose_t[b])) for a, b in zip(first[keep], last[keep])]


def evaluate(rows: list, ref: Reference, rig: Rig | None = None, imu_window_s: float = WINDOW_S,
             zupt: ZuptConfig | None = None) -> Evaluation:
    """Per-estimate errors against the IMU (:class:`~nrmpc_ros.frontend.imu_reference.ImuReference` over
    +-``imu_window_s``, stillness by ``zupt``) and the ground truth (NaN where unavailable)."""
    n = len(rows)
    err = {k: np.full(n, np.nan) for k in METRICS}
    imu = ImuReference(ref, rig, zupt) if ref.has_imu else None
    for k, r in enumerate(rows):
        g_imu = imu.gravity_at(r.stamp, imu_window_s) if imu is not None else None
        j = nearest_stamp(ref.grav_t, r.stamp)
        g_gt = ref.grav_g[j] if j is not None else None
        if r.gravity is not None and g_imu is not None:
            err["gravity_vs_imu_deg"][k] = math.degrees(float(angle_between(r.gravity, g_imu)))
        if r.gravity is not None and g_gt is not None:
            err["gravity_vs_gt_deg"][k] = math.degrees(float(angle_between(r.gravity, g_gt)))
        if g_imu is not None and g_gt is not None:
            err["imu_vs_gt_deg"][k] = math.degrees(float(angle_between(g_imu, g_gt)))
        i1, i2 = nearest_stamp(ref.pose_t, r.ref_stamp), nearest_stamp(ref.pose_t, r.stamp)
        if i1 is not None and i2 is not None:
            R1, R2 = ref.pose_R[i1], ref.pose_R[i2]
            R_gt = R1.T @ R2
            t_gt = R1.T @ (ref.pose_p[i2] - ref.pose_p[i1])
            pe = pose_errors(r.R, r.t, R_gt, t_gt)
            err["rotation_deg"][k] = math.degrees(pe["rotation"])
            err["translation_deg"][k] = math.degrees(pe["translation"])
            err["translation_m"][k] = pe["translation_m"]
    truth = np.concatenate([ref.grav_t, ref.pose_t])
    ev = Evaluation(rows, err, truth_span=(float(truth.min()), float(truth.max())) if len(truth) else None)
    holds = static_holds(ref)
    ev.holds = len(holds)
    stamps = np.array([r.stamp for r in rows])
    inside = np.zeros(len(stamps), bool)
    for a, b in holds:
        inside |= (stamps >= a - STAMP_TOLERANCE_S) & (stamps <= b + STAMP_TOLERANCE_S)
    ev.holds_with_estimate = sum(
        1 for a, b in holds[1:] if np.any((stamps >= a - STAMP_TOLERANCE_S) & (stamps <= b + STAMP_TOLERANCE_S)))
    ev.outside_holds = int(np.count_nonzero(~inside)) if holds else 0
    return ev


__all__ = ["METRICS", "Evaluation", "evaluate", "static_holds"]
