"""Minimal solvers from PoseLib behind our frame conventions.

PoseLib's CameraPose maps rig 1 into rig 2 (x2 = R_pl x1 + t_pl); our (R, t)
maps view 2 into view 1 (docs/CONVENTIONS.md, "Frames"), so R = R_pl^T and
t = -R_pl^T t_pl. The upright solver assumes rotation about y only.
"""

from __future__ import annotations

import numpy as np
import poselib

from .so3 import rotation_aligning

_Y = np.array([0.0, 1.0, 0.0])


def _convert(poses) -> list:
    out = []
    for p in poses:
        Rp = np.asarray(p.R)
        tp = np.asarray(p.t)
        if not (np.all(np.isfinite(Rp)) and np.all(np.isfinite(tp))):
            continue
        out.append((Rp.T, -Rp.T @ tp))
    return out


def solve_6pt(o1, d1, o2, d2) -> list:
    """Generalized relative pose from 6 rays per view (Stewenius-type); list of (R, t)."""
    return _convert(poselib.gen_relpose_6pt(o1, d1, o2, d2))


class UprightFrames:
    """Rotations that make measured gravity point along +y in both views."""

    def __init__(self, g1, g2):
        self.A1 = rotation_aligning(np.asarray(g1, dtype=float), _Y)
        self.A2 = rotation_aligning(np.asarray(g2, dtype=float), _Y)

    def solve(self, o1, d1, o2, d2) -> list:
        """Upright 4-point solver (Sweeney et al.) on rays in the body frames; list of (R, t)."""
        A1, A2 = self.A1, self.A2
        sols = poselib.gen_relpose_upright_4pt(o1 @ A1.T, d1 @ A1.T, o2 @ A2.T, d2 @ A2.T)
        return [(A1.T @ Ra @ A2, A1.T @ ta) for Ra, ta in _convert(sols)]
