"""How far the accelerometer's bias may tilt its gravity: the prior of the joint estimate's tilt, measured from the
still holds' norms (docs/PIPELINE.md, "The accelerometer's tilt").

At rest an accelerometer reads a_k = -g_k + b. Its direction is tilted off
gravity by b's part across g_k over |g|, the same vector in the sensor frame
at every hold. A factory-calibrated IMU keeps that within a few mg (0.3 deg:
``imu_bias_sigma_deg``); a raw consumer MEMS chip's zero-g offset is specified
within 50-80 mg per axis (3-5 deg: ``imu_bias_max_deg``, which
:data:`UNCALIBRATED_TILT_DEG` sets). The joint estimate over the sequence
takes the tilt as an unknown under a prior (:class:`~nrmpc_ros.core.bundle.
GravityPriors`); a prior tighter than the tilt is a broken promise: the
estimates land several of their stds off, and where the images pin gravity
loosely (two cameras on one bar) the IMU's tilt itself.

The norms measure it, independently of the directions the joint estimate
uses. To first order in b, |a_k| = |g| + b . u_k (u_k the hold's measured
direction): over holds at several attitudes the norm varies with b,

    |a_k| / median |a| = c + beta . u_k,

beta = b / |g| (rad: the most it tilts any hold), c free (the local gravity
and the accelerometer's scale; b along the holds' mean direction shares c's
regressor until the holds' attitudes spread). A weighted least-squares fit
with beta's prior the uncalibrated chip's: before the holds span attitudes
beta's part across their mean direction is as open as that prior, and the
tilt's prior is wide; once they do, it is measured, and the prior per axis
becomes

    sigma^2 = sigma_calibrated^2 + |beta_hat|^2 + tr(P C_beta P) / 2,

P the projection across the mean direction: the calibrated floor, the bias
the norms show, and what they still leave open across gravity (b along
gravity tilts nothing until the attitudes spread, and then it is measured).
An uncalibrated prior no wider than the calibrated one keeps the calibrated
prior throughout: the user's word for a calibrated IMU.
Unequal scales of the three axes make the norm vary with attitude too, and
tilt the direction alike: they widen the prior, the safe way. But the tilt an
axis reading (1 + s_i) times the truth gives is no constant: P (s * u) turns
with the attitude u (2 % between two axes: 0.3-0.5 deg between holds 30 deg
apart), which the joint estimate's constant tilt cannot follow. Nine holds'
norms do not measure s (the bias's part along gravity varies alike), but a
chip whose norms show a bias beyond the calibrated one
(:attr:`AccelTiltEvidence.shows_bias`) is one nobody calibrated, scales
included: each hold's gravity then carries the tilt such scales may give its
attitude as extra noise (:meth:`AccelTiltEvidence.scale_tilt_rad`). Nothing
here is refused: the evidence only grades how far the IMU's tilt is trusted.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..core.so3 import tangent_basis
from ..core.tilt_mixture import CalibrationOdds

UNCALIBRATED_TILT_DEG = math.degrees(math.atan(0.08))
"""The tilt a raw consumer MEMS accelerometer's zero-g offset may give its gravity (deg): 80 mg per axis, the widest
of the common chips' specifications (50 mg x/y and 80 mg z for one, 20-40 mg for newer ones)."""

UNCALIBRATED_SCALE = 0.02
"""The sensitivity error of an uncalibrated MEMS accelerometer's axis, each within +-this (1-3 % on common chips'
datasheets; uniform: its std is this over sqrt(3))."""

CALIBRATED_LOG_PRIOR_ODDS = 0.0
"""The log prior odds that an IMU is calibrated before its data say (even): drivers of packaged IMUs publish
calibrated readings, raw chips' do not, and neither is assumed."""

SHOWS_BIAS_LOG_BAYES = math.log(20.0)
"""The norms show an uncalibrated chip where their evidence favours its prior of the bias over a calibrated chip's
by more than 20 : 1 (:attr:`AccelTiltEvidence.shows_bias`)."""

TILT_HOLDS = 50
"""The still holds kept for the fit: the recent ones (a bias drifts slowly with temperature)."""


@dataclass(frozen=True)
class TiltEvidence:
    """What the still holds' norms say of the accelerometer's tilt: ``holds`` holds fitted, the bias's size over
    gravity (rad: the most it tilts a hold), the std per axis across the holds' mean direction the fit leaves open
    (rad), and the prior std per axis of the joint estimate's tilt that follows (rad)."""

    holds: int
    tilt_rad: float
    open_rad: float
    prior_sigma_rad: float
    # log of the norms' evidence for a calibrated chip (the bias under the calibrated prior) over an uncalibrated
    # one's (under the uncalibrated prior): 0 before any hold
    log_bayes_calibrated: float = 0.0


class AccelTiltEvidence:
    """The still holds' mean accelerometer vectors (any unit, any frame fixed to the sensor) and the variance of
    each mean's norm, in; :class:`TiltEvidence` out (see the module)."""

    def __init__(self, calibrated_sigma_rad: float, uncalibrated_sigma_rad: float, floor_rad: float = 0.0):
        self.calibrated_sigma_rad = float(calibrated_sigma_rad)
        self.uncalibrated_sigma_rad = float(uncalibrated_sigma_rad)
        self.floor_rad = float(floor_rad)
        self._holds: deque = deque(maxlen=TILT_HOLDS)  # (mean accelerometer (3,), variance of its norm)
        self.evidence = self._fit()

    def observe_still(self, accel_mean, norm_var: float = 0.0) -> TiltEvidence:
        """A still hold's mean accelerometer and the variance of that mean along any axis (its unit squared)."""
        a = np.asarray(accel_mean, dtype=float).reshape(3)
        if np.all(np.isfinite(a)) and np.linalg.norm(a) > 0 and math.isfinite(norm_var) and norm_var >= 0:
            self._holds.append((a, float(norm_var)))
            self.evidence = self._fit()
        return self.evidence

    @property
    def shows_bias(self) -> bool:
        """Whether the norms show an accelerometer whose bias nobody calibrated out (three holds or more): a
        fitted tilt beyond twice the calibrated prior, and their evidence for an uncalibrated chip's prior over
        the calibrated one beyond :data:`SHOWS_BIAS_LOG_BAYES`. The fitted tilt alone is no evidence: its part
        along the holds' mean direction shares the norms' regressor with the scale, and a few holds' noise puts
        it anywhere within the wide prior (five holds 0.008 m/s^2 apart fitted a 1.1 deg tilt to a 0.12 deg
        chip); the evidence weighs what the fit could explain by chance."""
        ev = self.evidence
        return ev.holds >= 3 and ev.tilt_rad > 2.0 * self.calibrated_sigma_rad and \
            ev.log_bayes_calibrated < -SHOWS_BIAS_LOG_BAYES

    def scale_tilt_rad(self, accel_mean) -> float:
        """The std (rad) of the tilt the axes' unequal scales may give a hold whose mean accelerometer is
        ``accel_mean`` (the sensor's axes), on a chip that :attr:`shows_bias` with a graded prior
        (:meth:`axes_scale_tilt_rad`); 0 otherwise (a calibrated chip's scales tilt nothing measurable)."""
        return self.axes_scale_tilt_rad(accel_mean) if self.shows_bias else 0.0

    def axes_scale_tilt_rad(self, accel_mean) -> float:
        """The std (rad) of the tilt uncalibrated axis scales would give a hold whose mean accelerometer is
        ``accel_mean``, with a graded prior (0 without): the axes' errors s_i independent, uniform within
        :data:`UNCALIBRATED_SCALE`, the tilt P (s * u) has variance var(s) sum_i u_i^2 (1 - u_i^2). Kept with each
        hold: a hold measured before the norms showed the chip uncalibrated has the same error."""
        a = np.asarray(accel_mean, dtype=float).reshape(3)
        n = float(np.linalg.norm(a))
        if not (self.graded and n > 0 and math.isfinite(n)):
            return 0.0
        u2 = (a / n) ** 2
        return UNCALIBRATED_SCALE / math.sqrt(3.0) * math.sqrt(float(np.sum(u2 * (1.0 - u2))))

    @property
    def graded(self) -> bool:
        """Whether the evidence grades the prior (an uncalibrated prior wider than the calibrated one)."""
        return self.uncalibrated_sigma_rad > self.calibrated_sigma_rad

    def _fit(self) -> TiltEvidence:
        # the fit's prior: where the calibrated prior is kept, an uncalibrated chip's, so that a tilt beyond it is said
        wide = self.uncalibrated_sigma_rad if self.graded else \
            max(self.calibrated_sigma_rad, math.radians(UNCALIBRATED_TILT_DEG))
        if not self._holds:
            return self._evidence(0, 0.0, wide)
        a = np.array([h[0] for h in self._holds])
        norms = np.linalg.norm(a, axis=1)
        scale = float(np.median(norms))
        var = np.array([h[1] for h in self._holds]) / scale ** 2 + self.floor_rad ** 2
        u = a / norms[:, None]
        design = np.column_stack([np.ones(len(u)), u])
        weight = 1.0 / np.maximum(var, 1e-30)
        data = design.T @ (design * weight[:, None])
        rhs = design.T @ (weight * (norms / scale))
        normal = data.copy()
        normal[1:, 1:] += np.eye(3) / wide ** 2
        cov = np.linalg.pinv(normal)
        theta = cov @ rhs
        beta, c_beta = theta[1:], cov[1:, 1:]
        mean = np.sum(u * weight[:, None], axis=0)
        across = tangent_basis(mean / np.linalg.norm(mean))  # (3, 2)
        open_rad = math.sqrt(max(float(np.trace(across.T @ c_beta @ across)) / 2.0, 0.0))
        # (a calibrated prior of 0, the user's word for a perfect chip, is weighed as the norms' own floor)
        narrow = max(self.calibrated_sigma_rad, self.floor_rad, 1e-9)
        bayes = _log_evidence(data, rhs, narrow) - _log_evidence(data, rhs, wide) if narrow < wide else 0.0
        return self._evidence(len(u), float(np.linalg.norm(beta)), open_rad, bayes)

    def _evidence(self, holds: int, tilt: float, open_rad: float, bayes: float = 0.0) -> TiltEvidence:
        prior = math.sqrt(self.calibrated_sigma_rad ** 2 + tilt ** 2 + open_rad ** 2) if self.graded else \
            self.calibrated_sigma_rad
        return TiltEvidence(holds, tilt, open_rad, prior, bayes)

    def calibration_odds(self) -> CalibrationOdds | None:
        """What the norms say of the chip's calibration, for the joint estimate's two priors of the tilt
        (:mod:`nrmpc_ros.core.tilt_mixture`): a calibrated chip's prior and the log odds calibrated : not (even
        odds before the norms' evidence). None where the prior is not graded (the user's word for a calibrated
        IMU: one prior)."""
        ev = self.evidence
        if not self.graded:
            return None
        return CalibrationOdds(self.calibrated_sigma_rad, CALIBRATED_LOG_PRIOR_ODDS + ev.log_bayes_calibrated)


def _log_evidence(data: np.ndarray, rhs: np.ndarray, sigma: float) -> float:
    """log of the norms' marginal likelihood (up to a constant any prior shares) under beta ~ N(0, sigma^2 I), c
    flat: 1/2 h' N^-1 h - 1/2 log det N - 3 log sigma with N the data's normal matrix plus the prior's."""
    normal = data.copy()
    normal[1:, 1:] += np.eye(3) / sigma ** 2
    sign, logdet = np.linalg.slogdet(normal)
    if sign <= 0:
        return 0.0
    return 0.5 * float(rhs @ np.linalg.solve(normal, rhs)) - 0.5 * logdet - 3.0 * math.log(sigma)


def describe_tilt(tilt: AccelTiltEvidence, extrinsics=None) -> str | None:
    """A sentence where the norms show a tilt beyond twice the calibrated prior and beyond what they leave open
    (an accelerometer whose bias is not calibrated out), else None; with ``extrinsics`` (the pipeline's
    :class:`~nrmpc_ros.frontend.extrinsics.FrameExtrinsics`, None without an IMU) the bias vector to calibrate
    out, where vision's gravity informed its estimate."""
    ev, calibrated = tilt.evidence, tilt.calibrated_sigma_rad
    if not tilt.shows_bias:
        return None
    said = (f"the accelerometer's still norm varies with attitude as a bias that tilts its gravity by up to "
            f"{math.degrees(ev.tilt_rad):.2f} deg would make it ({ev.holds} holds)")
    if tilt.graded:
        said = (f"{said}: the tilt is estimated with a prior of {math.degrees(ev.prior_sigma_rad):.2f} deg, not "
                f"the calibrated {math.degrees(calibrated):.2f} (calibrate the bias out for tighter IMU gravities)")
    else:
        said = (f"{said}, beyond the calibrated prior of {math.degrees(calibrated):.2f} deg that imu_bias_max_deg "
                f"keeps: gravities and their stds lean on it (raise imu_bias_max_deg, or calibrate the bias out)")
    bias = None if extrinsics is None else extrinsics.bias_estimate
    if bias is not None and bias.with_gravity > 0 and np.all(np.isfinite(bias.std_ms2)):
        said += (f"; with the images' gravity the bias reads {np.array2string(bias.bias_ms2, precision=3)} +- "
                 f"{np.array2string(bias.std_ms2, precision=3)} m/s^2 in the IMU's frame ({bias.holds} holds): "
                 f"subtract it from the readings")
    return said
