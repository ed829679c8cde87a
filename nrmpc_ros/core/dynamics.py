"""Bar dynamics: natural frequencies of the camera bars and their damped response to a changing load.

The static cantilever model (docs/CONVENTIONS.md, "Deformation model") bends
camera i's bar in proportion to the load x_i it carries: delta_i = c_d,i x_perp
with c_d,i = m_i L_i^3 / (3 EI_i). Treated as a tip mass on a massless spring
of stiffness k_i = 3 EI_i / L_i^3, the bar is a second-order system

    x_i'' + 2 zeta w_i x_i' + w_i^2 x_i = w_i^2 u(t),   w_i = sqrt(3 EI_i / (m_i L_i^3))

whose input u is the quasi-static load (gravity minus the body's linear
acceleration, body frame, m/s^2) and whose output x_i is the load that sets
the bar's bending (unit DC gain: a settled bar bends as the static model
says). zeta is the damping ratio. A rigid bar (EI = inf or m = 0, or a
camera at the body centre) has w_i = inf: it follows the load at once.

:class:`DampedResponse` integrates the system exactly for a load sampled on a
fine time grid and linear between samples (first-order hold), so the only
approximation is that interpolation: an error of order dt^2 |u''| / 8, about
1e-5 m/s^2 (1e-6 of gravity) at 1 ms steps for the moves of rendered bags.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter, lfilter_zi

from ..errors import InputError
from .rig import Rig

RINGING_DECAY_RATIO = 1e-3  # "settled": the ringing amplitude is below this fraction of its starting value


def bar_natural_frequencies(rig: Rig) -> np.ndarray:
    """(M,) natural frequency f_i = sqrt(3 EI_i / (m_i L_i^3)) / (2 pi) of each camera's bar, Hz.

    inf for rigid bars (EI = inf, m = 0) and for cameras at the body centre (L = 0).
    """
    out = np.full(rig.num_cameras, math.inf)
    for i, cam in enumerate(rig.cameras):
        L = float(np.linalg.norm(cam.position))
        if cam.is_flexible and L > 0:
            out[i] = math.sqrt(3.0 * cam.EI / (cam.mass * L**3)) / (2.0 * math.pi)
    return out


def ringing_decay_time(freq_hz, zeta: float, ratio: float = RINGING_DECAY_RATIO) -> np.ndarray:
    """Seconds for a free ringing bar's amplitude to fall to ``ratio`` of its starting value: ln(1/ratio)/(zeta w).

    The amplitude of a free damped oscillation decays as exp(-zeta w t); 0 for rigid bars (w = inf).
    """
    w = 2.0 * math.pi * np.asarray(freq_hz, dtype=float)
    return math.log(1.0 / ratio) / (zeta * w)


def check_damping(zeta: float, source: str = "--damping") -> None:
    """Only under-damped bars ring: the damping ratio must lie in (0, 1)."""
    if not (isinstance(zeta, (int, float)) and 0.0 < zeta < 1.0):
        raise InputError(source, f"damping ratio must be in (0, 1) (under-damped bars ring), got {zeta!r}")


def _propagate(x0, v0, u0, u1, h, dt, w, zeta):
    """State (x, x') after time h from (x0, v0) for an input linear from u0 (at 0) with slope (u1 - u0) / dt.

    Exact: x = x_p + y with the particular solution x_p(tau) = u0 + s tau - 2 zeta s / w of the ramp
    u0 + s tau and y the free under-damped oscillation from y(0) = x0 - x_p(0), y'(0) = v0 - s.
    All arguments broadcast; w must be finite.
    """
    s = (u1 - u0) / dt
    xp0 = u0 - 2.0 * zeta * s / w
    y0 = x0 - xp0
    yd0 = v0 - s
    sigma = zeta * w
    wd = w * math.sqrt(1.0 - zeta * zeta)
    e = np.exp(-sigma * h)
    c, sn = np.cos(wd * h), np.sin(wd * h)
    y = e * (y0 * c + (yd0 + sigma * y0) / wd * sn)
    yd = e * (yd0 * c - (w * w * y0 + sigma * yd0) / wd * sn)
    return xp0 + s * h + y, s + yd


def _step_filters(dt: float, w: float, zeta: float):
    """IIR coefficients (b_x, b_v, a) of the exact one-step recursion, for x and x' driven by the sampled input.

    The step is z_{k+1} = A z_k + B0 u_k + B1 u_{k+1} with z = (x, x'); as transfer functions in z^-1
    (C adj(zI - A) (B0 + z B1) / det(zI - A)) it runs through :func:`scipy.signal.lfilter` in C.
    """
    basis = np.eye(4)
    cols = np.array(_propagate(basis[0], basis[1], basis[2], basis[3], dt, dt, w, zeta))  # (2, 4)
    A, B0, B1 = cols[:, :2], cols[:, 2], cols[:, 3]
    a = np.array([1.0, -np.trace(A), np.linalg.det(A)])
    b_x = np.array([B1[0], B0[0] - A[1, 1] * B1[0] + A[0, 1] * B1[1], -A[1, 1] * B0[0] + A[0, 1] * B0[1]])
    b_v = np.array([B1[1], A[1, 0] * B1[0] + B0[1] - A[0, 0] * B1[1], A[1, 0] * B0[0] - A[0, 0] * B0[1]])
    return b_x, b_v, a


class DampedResponse:
    """Each bar's damped response x_i(t) (and x_i'(t)) to a load u(t) sampled every ``dt`` seconds.

    u: (N, 3) input samples at t = 0, dt, ..., (N - 1) dt (body frame, m/s^2); the bars start at rest
    at the first sample (x = u[0], x' = 0). freq_hz: (M,) natural frequencies (inf = rigid);
    zeta: damping ratio in (0, 1). :meth:`at` evaluates the exact state at any times in [0, (N - 1) dt].
    """

    def __init__(self, u, dt: float, freq_hz, zeta: float):
        check_damping(zeta)
        self.u = np.asarray(u, dtype=float).reshape(-1, 3)
        if len(self.u) < 2 or not dt > 0:
            raise ValueError("DampedResponse needs at least two input samples and a positive step")
        self.dt = float(dt)
        self.zeta = float(zeta)
        self.freq_hz = np.asarray(freq_hz, dtype=float).reshape(-1)
        self.rigid = ~np.isfinite(self.freq_hz)
        self.w = np.where(self.rigid, 1.0, 2.0 * math.pi * np.where(self.rigid, 1.0, self.freq_hz))  # rad/s
        N, M = len(self.u), len(self.freq_hz)
        self.x = np.broadcast_to(self.u[:, None, :], (N, M, 3)).copy()
        self.v = np.zeros((N, M, 3))
        for i in np.flatnonzero(~self.rigid):  # a few cameras; the samples run inside lfilter
            b_x, b_v, a = _step_filters(self.dt, float(self.w[i]), self.zeta)
            at_rest = self.u[0][None, :]  # steady state of a constant input u[0] before t = 0
            self.x[:, i] = lfilter(b_x, a, self.u, axis=0, zi=lfilter_zi(b_x, a)[:, None] * at_rest)[0]
            self.v[:, i] = lfilter(b_v, a, self.u, axis=0, zi=lfilter_zi(b_v, a)[:, None] * at_rest)[0]

    @property
    def duration(self) -> float:
        return (len(self.u) - 1) * self.dt

    def at(self, t):
        """Loads x (K, M, 3) and their rates x' (K, M, 3, per second) at times t (K,) in seconds from the start."""
        t = np.clip(np.asarray(t, dtype=float).reshape(-1), 0.0, self.duration)
        j = np.clip(np.floor(t / self.dt).astype(np.int64), 0, len(self.u) - 2)
        h = (t - j * self.dt)[:, None, None]
        u0, u1 = self.u[j][:, None, :], self.u[j + 1][:, None, :]
        w = self.w[None, :, None]
        x, v = _propagate(self.x[j], self.v[j], u0, u1, h, self.dt, w, self.zeta)
        rigid = self.rigid[None, :, None]
        s = (u1 - u0) / self.dt
        x = np.where(rigid, u0 + s * h, x)
        v = np.where(rigid, s, v)
        return x, v
