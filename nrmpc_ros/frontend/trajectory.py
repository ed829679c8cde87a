"""Hold trajectories in each sequence's origin frame, as TUM files for evo, and their absolute errors.

A sequence of holds is estimated in its origin frame: the body frame of its first hold
(docs/CONVENTIONS.md, Sequences). Its trajectory is the pose of every hold's body frame in that
origin (``p_origin = R p + t``), the origin itself at the identity. The ground truth of a bag is
expressed the same way, in the body frame of the ground truth at the origin hold, so the two files
share one frame: ``evo_ape tum GT.txt EST.txt`` compares them without alignment (``--align`` still
works and only lowers the error), ``evo_rpe`` works on either.

TUM format: one line per pose, ``stamp tx ty tz qx qy qz qw`` (seconds, metres, Hamilton unit
quaternion of the body-to-origin rotation, scalar last), space separated.

A bag may hold several sequences (the front end starts a new one when no landmark links a hold to
the previous ones); their origins are unrelated, so each goes to its own file:
:func:`sequence_paths`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.so3 import matrix_to_quat_xyzw, rotation_angle
from ..errors import InputError
from .reference import Reference, nearest_stamp


@dataclass
class Trajectory:
    """Poses of the holds of one sequence in its origin frame, origin first (identity)."""

    origin_stamp: float
    stamps: np.ndarray  # (n,) seconds
    R: np.ndarray  # (n, 3, 3) body -> origin
    t: np.ndarray  # (n, 3) body origin in the origin frame (m)

    def __len__(self) -> int:
        return len(self.stamps)


def trajectories(rows: list) -> list:
    """One :class:`Trajectory` per sequence of the estimate rows that carry their pose in the sequence origin
    (in order of first appearance); a hold estimated twice keeps its last pose."""
    seqs: dict = {}
    for r in rows:
        if r.origin is None:
            continue
        s0, R, t = r.origin
        seqs.setdefault(float(s0), {})[float(r.stamp)] = (np.asarray(R, float), np.asarray(t, float))
    out = []
    for s0, poses in seqs.items():
        stamps = [s0] + sorted(s for s in poses if s != s0)
        R = np.array([np.eye(3)] + [poses[s][0] for s in stamps[1:]])
        t = np.array([np.zeros(3)] + [poses[s][1] for s in stamps[1:]])
        out.append(Trajectory(s0, np.array(stamps), R, t))
    return out


def ground_truth_trajectory(traj: Trajectory, ref: Reference) -> Trajectory | None:
    """The ground truth at the stamps of ``traj``, in the body frame of the ground truth at its origin hold;
    stamps without ground truth are left out. None when the origin hold has no ground truth."""
    i0 = nearest_stamp(ref.pose_t, traj.origin_stamp)
    if i0 is None:
        return None
    R0, p0 = ref.pose_R[i0], ref.pose_p[i0]
    keep, R, t = [], [], []
    for k, s in enumerate(traj.stamps):
        i = nearest_stamp(ref.pose_t, float(s))
        if i is None:
            continue
        keep.append(k)
        R.append(R0.T @ ref.pose_R[i])
        t.append(R0.T @ (ref.pose_p[i] - p0))
    return Trajectory(traj.origin_stamp, traj.stamps[keep], np.array(R), np.array(t))


def absolute_errors(traj: Trajectory, gt: Trajectory) -> dict:
    """Absolute pose errors of ``traj`` against ``gt`` (same frame, matched by stamp, no alignment): RMSE of the
    position error (m) and of the rotation error (deg) over the matched poses, origin included (as
    ``evo_ape`` computes them on the TUM files), and the number of poses matched."""
    index = {float(s): k for k, s in enumerate(gt.stamps)}
    pairs = [(k, index[float(s)]) for k, s in enumerate(traj.stamps) if float(s) in index]
    if not pairs:
        return {"n": 0, "position_rmse_m": math.nan, "rotation_rmse_deg": math.nan}
    a, b = np.array(pairs).T
    dp = np.linalg.norm(traj.t[a] - gt.t[b], axis=1)
    dr = np.degrees([rotation_angle(gt.R[j].T @ traj.R[i]) for i, j in zip(a, b)])
    return {"n": len(pairs), "position_rmse_m": float(np.sqrt(np.mean(dp ** 2))),
            "rotation_rmse_deg": float(np.sqrt(np.mean(dr ** 2)))}


def sequence_paths(path, count: int) -> list:
    """File of each of ``count`` sequences: ``path`` for the first, ``<stem>_seq<k><suffix>`` beside it for
    the k-th (k >= 1)."""
    p = Path(path)
    return [p] + [p.with_name(f"{p.stem}_seq{k}{p.suffix}") for k in range(1, count)]


def tum_text(traj: Trajectory) -> str:
    """The TUM lines of a trajectory."""
    lines = []
    for s, R, t in zip(traj.stamps, traj.R, traj.t):
        q = matrix_to_quat_xyzw(R)
        lines.append(" ".join([f"{float(s):.9f}"] + [f"{float(x):.9g}" for x in (*t, *q)]))
    return "\n".join(lines) + "\n"


def write_tum(path, traj: Trajectory, flag: str | None = None) -> None:
    """Write one trajectory as a TUM file (atomically: :func:`nrmpc_ros.safeio.atomic_write`)."""
    from ..safeio import atomic_write

    with atomic_write(path, flag=flag) as f:
        f.write(tum_text(traj))


def read_tum(path) -> Trajectory:
    """A TUM file as a trajectory (first pose taken as the origin stamp); InputError naming the file and line."""
    from ..core.so3 import quat_xyzw_to_matrix
    from ..safeio import read_text

    text = read_text(path, what="TUM trajectory", max_bytes=64 << 20)
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            v = [float(x) for x in line.split()]
        except ValueError:
            raise InputError(str(path), f"line {n}: not numbers: {line[:60]!r}") from None
        if len(v) != 8 or not all(math.isfinite(x) for x in v):
            raise InputError(str(path), f"line {n}: expected 8 finite numbers (stamp tx ty tz qx qy qz qw)")
        q = np.array(v[4:8])
        if abs(np.linalg.norm(q) - 1.0) > 1e-3:
            raise InputError(str(path), f"line {n}: quaternion not of unit norm ({np.linalg.norm(q):.4f})")
        rows.append(v)
    if not rows:
        raise InputError(str(path), "no poses")
    a = np.array(rows)
    R = np.array([quat_xyzw_to_matrix(q / np.linalg.norm(q)) for q in a[:, 4:8]])
    return Trajectory(float(a[0, 0]), a[:, 0], R, a[:, 1:4])


def sequence_errors(rows: list, ref: Reference | None) -> list:
    """(trajectory, ground truth or None, absolute errors or None) of every sequence in ``rows``."""
    out = []
    for traj in trajectories(rows):
        gt = ground_truth_trajectory(traj, ref) if ref is not None and ref.has_pose else None
        out.append((traj, gt, None if gt is None else absolute_errors(traj, gt)))
    return out


def write_trajectories(rows: list, path, ref: Reference | None = None, gt_path=None,
                       flags=("--tum", "--tum-gt")) -> list:
    """TUM files of the sequences in ``rows`` (:func:`sequence_paths` of ``path``) and, with ``gt_path``, the
    ground truth in each sequence's origin frame (:func:`sequence_paths` of ``gt_path``; a sequence whose
    holds have no ground truth gets none). Returns :func:`sequence_errors` with the files written:
    [(trajectory, ground truth, errors, estimate file, ground-truth file or None)]."""
    seqs = sequence_errors(rows, ref)
    paths = sequence_paths(path, len(seqs))
    gt_paths = sequence_paths(gt_path, len(seqs)) if gt_path else [None] * len(seqs)
    out = []
    for (traj, gt, err), p, gp in zip(seqs, paths, gt_paths):
        write_tum(p, traj, flags[0])
        if gp is not None and gt is not None and len(gt):
            write_tum(gp, gt, flags[1])
        else:
            gp = None
        out.append((traj, gt, err, p, gp))
    return out


def describe(results: list) -> str:
    """Lines with the absolute errors of each sequence (:func:`sequence_errors`) and the files written
    (:func:`write_trajectories`)."""
    lines = []
    for k, res in enumerate(results):
        traj, _, err = res[:3]
        line = f"sequence {k} ({len(traj)} holds from {traj.origin_stamp:.3f} s)"
        if err and err["n"]:
            line += (f": pose in the origin vs ground truth ({err['n']} holds, origin included): position RMSE "
                     f"{err['position_rmse_m']:.4f} m, rotation RMSE {err['rotation_rmse_deg']:.3f} deg")
        if len(res) > 3:
            line += f"; wrote {res[3]}" + (f" and ground truth {res[4]}" if res[4] else "")
        lines.append(line)
    return "\n".join(lines)


__all__ = ["Trajectory", "absolute_errors", "describe", "ground_truth_trajectory", "read_tum", "sequence_errors",
           "sequence_paths",
           "trajectories", "tum_text", "write_trajectories", "write_tum"]
