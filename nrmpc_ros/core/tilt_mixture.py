"""A view's gravity when nobody says whether the accelerometer is calibrated: the two answers weighed by evidence.

The joint estimate takes the accelerometer's constant tilt b (its bias across gravity, the same vector at every
hold) as an unknown under one zero-mean prior, as wide as the still holds' norms leave it
(docs/PIPELINE.md, "The accelerometer's tilt"). Until the holds span attitudes in two directions the norms leave
part of b as open as an uncalibrated chip's offset (4.6 deg), and a wide prior hands the IMU's absolute gravity
over to the images: where they pin gravity loosely (three cameras, snapshots, a 50 Hz IMU in a ringing camera)
the estimate is then the images' 1 deg where the IMU alone was 0.3 deg off.

But most IMUs that publish ``sensor_msgs/Imu`` are calibrated, and the data say which kind this one is: a
calibrated chip's tilt is small in the directions the norms resolve, and the images' gravity agrees with the
IMU's within their stds. So the tilt's prior is a mixture of two, a calibrated chip's (``calibrated_sigma``) and
the wide one the norms leave (``wide_sigma``), and each view's gravity is the mixture's posterior
(docs/PIPELINE.md, "Calibrated or not: the tilt's two priors"):

- the joint solve under the wide prior gives the tilt's estimate b^ with its marginal covariance C_bb and the
  view's gravity jointly with it (Laplace: a Gaussian about the solution). Dividing the wide prior out leaves the
  images' (and IMU gravities') likelihood of b, information L = C_bb^-1 - I / wide^2;
- under a prior N(0, s^2 I) the tilt's posterior has information L + I / s^2 and mean (L + I/s^2)^-1 C_bb^-1 b^,
  and the data's evidence for that prior is, up to a constant both share,
  1/2 h' (L + I/s^2)^-1 h - 1/2 log det(L + I/s^2) - 3 log s, h = C_bb^-1 b^;
- the view's gravity moves with the tilt as the joint solution ties them (its conditional on b), so each prior
  gives the view's gravity a mean and covariance, and the published ones are the mixture's: weights from the
  prior odds times both evidences (the norms' own, :mod:`nrmpc_ros.frontend.accel_tilt`, and the images'
  above), the spread between the two means counted in the covariance.

Where the images agree with a calibrated IMU the calibrated prior wins and the IMU's gravity counts at a
calibrated chip's std; where they do not (a biased chip), the wide one wins and nothing changes. In between the
std carries both answers. Nothing is refused: the evidence only grades how far the IMU's tilt is trusted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CalibrationOdds:
    """What the accelerometer's norms say of its calibration: the tilt's prior std were the chip calibrated (rad)
    and the log odds calibrated : not calibrated, the prior odds times the norms' evidence
    (:class:`nrmpc_ros.frontend.accel_tilt.TiltEvidence`)."""

    calibrated_sigma_rad: float
    log_odds: float


@dataclass(frozen=True)
class MixedGravity:
    """A view's gravity under the mixture: the shift of its direction from the wide prior's solution (rad, in the
    tangent basis of that solution's direction), its covariance there (rad^2), the calibrated prior's weight, and
    the log of the solve's own evidence (its images and IMU gravities) for the calibrated prior over the wide one
    (before any cap)."""

    shift: np.ndarray  # (2,)
    covariance: np.ndarray  # (2, 2)
    calibrated_weight: float
    images_log_bayes: float


def prior_sigma_rad(wide_sigma_rad: float, odds: CalibrationOdds | None) -> float:
    """The std (rad per axis) of the tilt under the two priors where nothing but the norms weighs them (a hold
    no images tell): the mixture's, sqrt(w narrow^2 + (1 - w) wide^2) at the calibrated prior's weight w from the
    odds; the wide prior's without them."""
    wide = float(wide_sigma_rad)
    if odds is None or not (0.0 < odds.calibrated_sigma_rad < wide) or not math.isfinite(odds.log_odds):
        return wide
    w = _weight(odds.log_odds)
    return math.sqrt(w * odds.calibrated_sigma_rad ** 2 + (1.0 - w) * wide ** 2)


def prior_weight(odds: CalibrationOdds | None) -> float | None:
    """The calibrated prior's weight where nothing but the norms weighs the two (None without odds)."""
    return None if odds is None or not math.isfinite(odds.log_odds) else _weight(odds.log_odds)


def _weight(log_odds: float) -> float:
    """The first of two weights at log odds ``log_odds`` of the first over the second."""
    return 1.0 / (1.0 + math.exp(-log_odds)) if log_odds > -700 else 0.0


def _posterior(L: np.ndarray, h: np.ndarray, sigma: float) -> tuple:
    """(mean, covariance, log evidence up to a shared constant) of the tilt under the prior N(0, sigma^2 I)."""
    A = L + np.eye(3) / sigma ** 2
    cov = np.linalg.inv(A)
    mean = cov @ h
    log_z = 0.5 * float(h @ mean) - 0.5 * float(np.linalg.slogdet(A)[1]) - 3.0 * math.log(sigma)
    return mean, cov, log_z


def mixed_gravity(tilt: np.ndarray, covariance: np.ndarray, wide_sigma_rad: float,
                  odds: CalibrationOdds, images_log_bayes_cap: float = math.inf) -> MixedGravity | None:
    """The view's gravity under the two priors (see the module). ``tilt`` (3,) is the wide prior's solution b^,
    ``covariance`` (5, 5) the joint covariance of the view's gravity direction (2, its tangent basis) and the
    tilt (3), in that order, from that solve. ``images_log_bayes_cap``: the most this solve's own evidence may
    favour the calibrated prior (an earlier solve of the same chip that refuted it: a window of loose holds
    does not forget what sharp ones showed). None where nothing changes (the calibrated prior no tighter than
    the wide one) or the covariance is not finite."""
    wide, narrow = float(wide_sigma_rad), float(odds.calibrated_sigma_rad)
    C = np.asarray(covariance, float)
    b = np.asarray(tilt, float).reshape(3)
    if not (0.0 < narrow < wide and math.isfinite(wide)) or not np.all(np.isfinite(C)) or \
            not np.all(np.isfinite(b)) or not math.isfinite(odds.log_odds):
        return None
    C = 0.5 * (C + C.T)
    C_gg, C_gb, C_bb = C[:2, :2], C[:2, 2:], C[2:, 2:]
    try:
        P = np.linalg.inv(C_bb)
    except np.linalg.LinAlgError:
        return None
    # the data's information on the tilt: the posterior's less the wide prior's (never below none)
    w, V = np.linalg.eigh(0.5 * (P + P.T) - np.eye(3) / wide ** 2)
    L = (V * np.maximum(w, 0.0)) @ V.T
    h = P @ b
    K = C_gb @ P  # the view's gravity per unit of tilt, as the solution ties them
    conditional = C_gg - K @ C_gb.T
    parts = []
    for sigma in (narrow, wide):
        mean, cov, log_z = _posterior(L, h, sigma)
        parts.append((K @ (mean - b), conditional + K @ cov @ K.T, log_z))
    own = parts[0][2] - parts[1][2]
    calibrated = _weight(odds.log_odds + min(own, images_log_bayes_cap))
    weights = (calibrated, 1.0 - calibrated)
    shift = sum(wt * p[0] for wt, p in zip(weights, parts))
    cov = sum(wt * (p[1] + np.outer(p[0] - shift, p[0] - shift)) for wt, p in zip(weights, parts))
    return MixedGravity(np.asarray(shift), 0.5 * (cov + cov.T), calibrated, own)


__all__ = ["CalibrationOdds", "MixedGravity", "mixed_gravity", "prior_sigma_rad", "prior_weight"]
