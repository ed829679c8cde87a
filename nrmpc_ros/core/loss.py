"""Robust loss functions, written once and used wherever a robust cost appears.

Each loss works on squared residual norms ``r2`` (one per observation, in
units of the noise sigma or in rad^2, as the caller decides), PoseLib-style:

- ``loss(r2)``: the cost of each residual (for the quadratic part, r2 / 2);
- ``weight(r2)``: the iteratively-reweighted-least-squares weight
  rho'(r2) * 2, i.e. the factor that multiplies J^T J and J^T r.

``HuberLoss`` is the refinement's loss (docs/CONVENTIONS.md, Estimators,
"Refinement"); ``msac_score`` is the MSAC score that RANSAC and the comparison
of starts use: min(e^2, threshold^2) summed over all correspondences.
"""

from __future__ import annotations

import numpy as np

MAD_TO_STD = 1.4826  # a normal distribution's std over its median absolute deviation (1 / Phi^-1(3/4))


class HuberLoss:
    """Quadratic up to ``delta``, linear beyond: cost r2/2 or delta (r - delta/2) with r = sqrt(r2).
    ``delta`` is one number, or an array that broadcasts against ``r2`` (one per batch of problems)."""

    def __init__(self, delta):
        d = np.asarray(delta, dtype=float)
        if not np.all(d > 0):
            raise ValueError(f"Huber delta must be > 0, got {delta}")
        self.delta = float(d) if d.ndim == 0 else d

    def loss(self, r2: np.ndarray) -> np.ndarray:
        r2 = np.asarray(r2, dtype=float)
        d = self.delta
        r = np.sqrt(r2)
        return np.where(r <= d, 0.5 * r2, d * (r - 0.5 * d))

    def weight(self, r2: np.ndarray) -> np.ndarray:
        r2 = np.asarray(r2, dtype=float)
        r = np.sqrt(r2)
        return np.divide(self.delta, r, out=np.ones_like(r), where=r > self.delta)


def msac_score(errors: np.ndarray, threshold: float, axis=None) -> np.ndarray | float:
    """Sum of min(e^2, threshold^2) of angular errors ``errors`` (rad) along ``axis`` (all by default); an error
    that is not a number (a landmark no ray intersection places) counts as an outlier, threshold^2."""
    e = np.asarray(errors, dtype=float)
    s = np.minimum(np.nan_to_num(e * e, nan=np.inf), threshold * threshold).sum(axis=axis)
    return float(s) if axis is None else s


__all__ = ["HuberLoss", "MAD_TO_STD", "msac_score"]
