"""A snapshot's ringing predicted from the IMU and removed from its bearings (docs/PIPELINE.md, "Settling").

A snapshot taken shortly after a stop sees each camera on a bar that still rings. With an IMU the bars' state
is propagated from its samples (:class:`~nrmpc_ros.core.bar_state.BarPropagator`, docs/CONVENTIONS.md "The
rig in motion"): camera i sits where the static model puts it at its bar's effective load x_i (the load
through the bar's damped response), not at the load of the still rig l (its averaged specific force). The
difference dx_i = x_i - l is the ringing; the camera is turned by

    R_i = W(l)_i^T W(x_i)_i   (W(x) = Exp(c_r,i u_i x x) V_i, docs/CONVENTIONS.md "Bending")

against the static model, so its bearings f become the static model's R_i f. The accelerometer's constant bias
is in x_i and l alike (the loads are linear in the samples, and a constant passes the bar's response
unchanged): it cancels in dx_i, and R_i depends on l only to second order. The translation of the camera
(c_d,i times dx_i across the bar) is not removed: its bearing change depends on each point's depth, which a
snapshot does not know; it is (2 L / 3) / depth of the rotation's (a bar of length L, points at that depth).

What is left is the prediction's own error, which the snapshot carries as its residual ringing
(:func:`residual_px`): the ringing's envelope at the image times its relative error from the bar's damping
and frequency uncertainties over the time since the stop and from the stamps' uncertainty, and the IMU's
noise through the bar's response.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..cameras import bearings_to_pixels, pixels_to_bearings
from ..core.bar_state import BarPropagator, bent_extrinsics_at_loads
from ..core.dynamics import bar_natural_frequencies
from ..core.rig import Rig


@dataclass(frozen=True)
class RingingPrediction:
    """The ringing of the cameras of one frame set, predicted from the IMU: for the rig's cameras ``cams`` (K,)
    at their image ``stamps`` (K,), each bar's effective load ``load`` (K, 3) and the still rig's ``still_load``
    (K, 3) (body frame, m/s^2), the complex ringing about the still load ``ringing`` (K, 3) (its modulus the
    envelope: :meth:`~nrmpc_ros.core.bar_state.BarPropagator.ringing_about`),
    and ``elapsed_s`` since the stop (the IMU's still onset)."""

    cams: np.ndarray
    stamps: np.ndarray
    load: np.ndarray
    still_load: np.ndarray
    ringing: np.ndarray
    elapsed_s: float

    @property
    def deflection(self) -> np.ndarray:
        """dx (K, 3): each bar's load away from the still rig's (the bias cancels)."""
        return self.load - self.still_load


def predict(bars: BarPropagator, stamps, cams, still_from: float, still_to: float,
            stop: float) -> RingingPrediction | None:
    """The ringing of cameras ``cams`` at their image ``stamps`` from the propagated bars: the still load is
    the mean over the samples in [still_from, still_to] (the IMU still there), ``stop`` the still onset. None
    before the propagator has samples or without samples in the still window."""
    cams = np.asarray(cams, dtype=int).reshape(-1)
    q = np.asarray(stamps, dtype=float).reshape(-1)
    still = bars.mean_load(still_from, still_to)
    x = bars.loads_at(q, cams)
    if still is None or x is None:
        return None
    ring = bars.ringing_about(q, cams, still[cams])
    return RingingPrediction(cams, q, x, still[cams], ring, max(float(np.min(q)) - float(stop), 0.0))


def correction_rotations(rig: Rig, p: RingingPrediction) -> np.ndarray:
    """R_i (K, 3, 3) turning camera cams[i]'s bearings at its ringing load into the static model's at the still
    rig's load (see the module docstring)."""
    _, W_act = bent_extrinsics_at_loads(rig, p.load, p.cams)
    _, W_ref = bent_extrinsics_at_loads(rig, p.still_load, p.cams)
    return np.swapaxes(W_ref, -1, -2) @ W_act


def correct_pixels(cam, uv, R) -> np.ndarray:
    """Pixels uv (N, 2) of a camera turned by R (its bearings f -> R f): where the static model sees them."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    if not len(uv):
        return uv.copy()
    return bearings_to_pixels(cam, pixels_to_bearings(cam, uv) @ np.asarray(R, dtype=float).T)


@dataclass(frozen=True)
class PredictionUncertainty:
    """What the prediction does not know: each bar's damping ratio std (absolute) and its frequency's relative
    std, the stamps' std (s, where inside an IMU period the load really changed), the accelerometer's noise
    per sample (m/s^2) at its sample period (s), and the gyro's (rad/s)."""

    damping_std: np.ndarray  # (M,)
    frequency_rel_std: np.ndarray  # (M,)
    clock_std_s: float
    accel_sigma: float
    imu_period_s: float
    gyro_sigma: float = 0.0


def uncertainty(rig: Rig, damping_rel_std: float, unknown_damping_std: float, frequency_rel_std: float,
                accel_sigma: float, imu_period_s: float, gyro_sigma: float = 0.0) -> PredictionUncertainty:
    """Per bar, the damping's std: the rig file's ``damping_std`` (the bar calibration's), else
    ``damping_rel_std`` of its ``damping``, else ``unknown_damping_std`` (the propagator then assumes a default
    ratio); the frequency's: the rig file's ``frequency_std_hz`` with its identified ``frequency_hz`` (the
    frequency the propagator then uses), else ``frequency_rel_std`` (of sqrt(3 EI / (m L^3)) / (2 pi)).
    The stamps: uniform over an IMU period (the propagated load is linear between samples; an acceleration
    that changes inside one is smeared over it), std period / sqrt(12)."""
    f = bar_natural_frequencies(rig)
    zs, fs = [], []
    for c, fi in zip(rig.cameras, f):
        if c.damping is None:
            zs.append(unknown_damping_std)
        else:
            zs.append(c.damping_std if c.damping_std is not None else damping_rel_std * float(c.damping))
        if c.frequency_hz is not None and c.frequency_std_hz is not None and math.isfinite(fi) and fi > 0:
            fs.append(c.frequency_std_hz / fi)
        else:
            fs.append(frequency_rel_std)
    def positive(x):  # an unknown (NaN) or absent noise or period counts as none
        return float(x) if math.isfinite(x) and x > 0 else 0.0

    period = positive(imu_period_s)
    return PredictionUncertainty(np.array(zs, dtype=float), np.array(fs, dtype=float), period / math.sqrt(12.0),
                                 positive(accel_sigma), period, positive(gyro_sigma))


def residual_px(rig: Rig, zeta, p: RingingPrediction, u: PredictionUncertainty,
                depth_m: float = math.inf) -> np.ndarray:
    """Each camera's expected error of its predicted ringing (px, (K,)): the ringing's envelope at the image
    (its rotation through the focal length) times its relative error, and the IMU's noise through the bar.

    - a damping ratio off by s_zeta decays the envelope by exp(-s_zeta w t) more or less over the time t since
      the stop: relative error w t s_zeta;
    - a frequency off by s_f shifts the ringing's phase by 2 pi s_f t: relative error 2 pi t s_f;
    - a stamp off by s_t shifts it by w s_t;
    - white accelerometer noise of std sigma per sample at period h drives each transverse axis of the bar's
      load to a std sigma sqrt(h w / (4 zeta)) (the second-order response's noise bandwidth, w / (4 zeta));
      the gyro's, differenced into the angular acceleration at the tip's lever |v|, to |v| sigma_w sqrt(h w^3
      / (4 zeta)) (the response's rate has w^2 times its variance);
    - the camera's translation by the ringing, c_d (x - l) across the bar, is not removed: it turns the
      bearing of a point ``depth_m`` away by up to its length over that depth.
    """
    cams = p.cams
    f = bar_natural_frequencies(rig)[cams]
    flex = np.isfinite(f) & (f > 0)
    f = np.where(flex, f, 0.0)
    w = 2.0 * math.pi * f
    zeta = np.asarray(zeta, dtype=float)[cams]
    cr = rig.bar_derivatives[1][cams]  # (K, 3, 3) bend rotation per unit load
    focal = np.array([rig.cameras[i].focal_px for i in cams])
    phi = np.einsum("kab,kb->ka", cr, p.ringing)  # complex rotation ringing
    env = focal * np.sqrt(np.sum(np.abs(phi) ** 2, axis=1))
    t = p.elapsed_s
    rel = np.sqrt((w * t * u.damping_std[cams]) ** 2 + (w * u.frequency_rel_std[cams] * t) ** 2
                  + (w * u.clock_std_s) ** 2)
    per_load = focal * np.linalg.norm(cr, ord=2, axis=(1, 2))
    band = u.imu_period_s * w / (4.0 * np.maximum(zeta, 1e-6))
    lever = np.linalg.norm(rig.positions[cams], axis=1)
    noise = np.sqrt(band * (u.accel_sigma ** 2 + (lever * w * u.gyro_sigma) ** 2))
    u_dir, cd, _ = rig.bar_coefficients
    dx = p.deflection
    perp = dx - np.sum(dx * u_dir[cams], axis=1, keepdims=True) * u_dir[cams]
    shift = focal * cd[cams] * np.linalg.norm(perp, axis=1) / depth_m if depth_m > 0 else np.full(len(cams), np.inf)
    out = np.sqrt((env * np.where(flex, rel, 0.0)) ** 2 + 2.0 * (per_load * noise) ** 2 + shift ** 2)
    return np.where(flex, out, 0.0)


__all__ = ["PredictionUncertainty", "RingingPrediction", "correct_pixels", "correction_rotations", "predict",
           "residual_px", "uncertainty"]
