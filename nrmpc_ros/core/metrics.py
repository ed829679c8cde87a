"""Error metrics and success test of docs/CONVENTIONS.md (Errors and success) (paper section 4)."""

from __future__ import annotations

import numpy as np

from .so3 import angle_between, rotation_angle

ROTATION_SUCCESS_RAD = 0.5
TRANSLATION_SUCCESS_RAD = 0.2


def pose_errors(R, t, R_gt, t_gt, g=None, g_gt=None) -> dict:
    """rotation (rad), translation direction (rad), |t - t_gt| (m), gravity (rad, nan if absent), success."""
    if R is None:
        nan = float("nan")
        return {"rotation": nan, "translation": nan, "translation_m": nan, "gravity": nan, "success": False}
    rot = float(rotation_angle(np.asarray(R_gt).T @ np.asarray(R)))
    tra = float(angle_between(np.asarray(t), np.asarray(t_gt)))
    out = {
        "rotation": rot,
        "translation": tra,
        "translation_m": float(np.linalg.norm(np.asarray(t) - np.asarray(t_gt))),
        "gravity": float(angle_between(g, g_gt)) if g is not None and g_gt is not None else float("nan"),
    }
    out["success"] = bool(rot < ROTATION_SUCCESS_RAD and tra < TRANSLATION_SUCCESS_RAD)
    return out
