"""Bar dynamics: natural frequencies of the camera bars and their damped response to a changing load.

The static cantilever model (docs/CONVENTIONS.md, "Bending") bends
camera i's bar in proportion to the load x_i it carries: delta_i = c_d,i x_perp
with c_d,i = m_i L_i^3 / (3 EI_i). Treated as a tip mass on a massless spring
of stiffness k_i = 3 EI_i / L_i^3, the bar is a second-order system

    x_i'' + 2 zeta w_i x_i' + w_i^2 x_i = w_i^2 u(t),   w_i = sqrt(3 EI_i / (m_i L_i^3))

whose input u is the quasi-static load (gravity minus the body's linear
acceleration, body frame, m/s^2) and whose output x_i is the load that sets
the bar's bending (unit DC gain: a settled bar bends as the static model
says). zeta is the damping ratio. A rigid bar (EI = inf or m = 0, or a
camera at the body centre) has w_i = inf: it follows the load at once.

:class:`DampedResponse` integrates the system exactly for a load that is
linear between samples and may jump at a sample (an acceleration step), so
the only approximation is the linear interpolation of a smooth load between
samples: an error of order dt^2 |u''| / 8 (for the moves of rendered bags at
0.5 ms steps, below 1e-4 m/s^2, i.e. 1e-5 of gravity).

Between samples t_k and t_{k+1} the load is u(t) = u_k+ + s_k (t - t_k) and
the response is x = u - 2 zeta s_k / w + Re(C_k exp(lambda (t - t_k))): the
ramp's particular solution plus the free ringing, lambda = -zeta w + i w_d,
w_d = w sqrt(1 - zeta^2), with complex amplitude C_k (|C_k| is the ringing
amplitude). x and x' are continuous at a sample while the particular
solution jumps with the load (J_k = u_k+ - u_k-) and changes slope, so

    C_{k+1} = exp(lambda h_k) C_k + kappa (s_{k+1} - s_k) - mu J_{k+1},
    kappa = 2 zeta / w + i (1 - 2 zeta^2) / w_d,   mu = 1 - i zeta w / w_d,

a first-order recursion that runs in :func:`scipy.signal.lfilter` over each
stretch of equal steps. At rest at t_0 (x = u_0, x' = 0): C_0 = kappa s_0.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import OptionError
from .rig import Rig

RINGING_DECAY_RATIO = 1e-3  # "settled": the ringing amplitude is below this fraction of its starting value
# Damping ratio assumed for a bar whose rig file gives none (docs/CONVENTIONS.md, "The rig in motion"). Bars of
# metal or carbon with a camera at the tip ring with zeta ~ 0.01-0.06; the low end is the conservative choice: it
# predicts ringing that lasts longest (a settling decision waits rather than trusts a ringing bar), and a
# predicted ringing that outlasts the true one errs by the ringing amplitude, as one that dies too early does.
UNKNOWN_DAMPING_RATIO = 0.02


def bar_natural_frequencies(rig: Rig) -> np.ndarray:
    """(M,) natural frequency of each camera's bar, Hz: the rig file's identified ``bar.frequency_hz`` when it
    gives one (what ``nrmpc calibrate-bars`` measured from the ringing, to a fraction of a per mille), else
    f_i = sqrt(3 EI_i / (m_i L_i^3)) / (2 pi) (as good as the compliance, a percent or so).

    inf for rigid bars (EI = inf, m = 0) and for cameras at the body centre (L = 0).
    """
    out = np.full(rig.num_cameras, math.inf)
    for i, cam in enumerate(rig.cameras):
        L = float(np.linalg.norm(cam.position))
        if cam.is_flexible and L > 0:
            model = math.sqrt(3.0 * cam.EI / (cam.mass * L**3)) / (2.0 * math.pi)
            out[i] = model if cam.frequency_hz is None else float(cam.frequency_hz)
    return out


def ringing_decay_time(freq_hz, zeta: float, ratio: float = RINGING_DECAY_RATIO) -> np.ndarray:
    """Seconds for a free ringing bar's amplitude to fall to ``ratio`` of its starting value: ln(1/ratio)/(zeta w).

    The amplitude of a free damped oscillation decays as exp(-zeta w t); 0 for rigid bars (w = inf).
    """
    w = 2.0 * math.pi * np.asarray(freq_hz, dtype=float)
    return math.log(1.0 / ratio) / (zeta * w)


def bar_damping_ratios(rig: Rig, default: float | None = None) -> np.ndarray:
    """(M,) damping ratio of each bar: the rig file's ``bar.damping``, else ``default``, else
    :data:`UNKNOWN_DAMPING_RATIO` (rigid bars get it too; they do not ring)."""
    fallback = UNKNOWN_DAMPING_RATIO if default is None else float(default)
    return np.array([fallback if c.damping is None else float(c.damping) for c in rig.cameras])


def check_damping(zeta: float, owner: str = "bar dynamics") -> None:
    """Only under-damped bars ring: the damping ratio (option ``damping`` of ``owner``) must lie in (0, 1)."""
    if not (isinstance(zeta, (int, float)) and 0.0 < zeta < 1.0):
        raise OptionError(owner, "damping", f"damping ratio must be in (0, 1) (under-damped bars ring), got {zeta!r}")




class DampedResponse:
    """Each bar's damped response x_i(t) (and x_i'(t)) to a load u(t) given at sample times, see the module doc.

    t: (N,) increasing sample times (s); u: (N, 3) one load for every bar, or (N, M, 3) each bar's own load, just
    after each sample (body frame, m/s^2); u_before: the same just before each sample where it jumps (default:
    u, a continuous load). freq_hz: (M,) natural frequencies (inf = rigid: x follows the interpolated load);
    zeta: damping ratio in (0, 1), one for all bars or (M,) one per bar. The bars start at rest at t[0]
    (x = u[0], x' = 0). Fast when the steps are piecewise equal (one lfilter call per stretch of equal steps
    and camera).
    """

    def __init__(self, t, u, freq_hz, zeta, u_before=None):
        from scipy.signal import lfilter  # on first use: importing scipy.signal takes about 0.5 s

        self.freq_hz = np.asarray(freq_hz, dtype=float).reshape(-1)
        M = len(self.freq_hz)
        zeta = np.broadcast_to(np.asarray(zeta, dtype=float), (M,)).copy()
        for z in zeta:
            check_damping(float(z))
        self.t = np.asarray(t, dtype=float).reshape(-1)
        u = np.asarray(u, dtype=float)
        before = u if u_before is None else np.asarray(u_before, dtype=float)
        shape = (len(self.t), M, 3)
        try:
            self.u = np.broadcast_to(u[:, None, :] if u.ndim == 2 else u, shape)
            before = np.broadcast_to(before[:, None, :] if before.ndim == 2 else before, shape)
        except (ValueError, IndexError):
            raise ValueError(f"DampedResponse needs loads of shape (N, 3) or (N, {M}, 3), got {u.shape}") from None
        h = np.diff(self.t)
        if len(self.t) < 2 or not np.all(h > 0):
            raise ValueError("DampedResponse needs >= 2 increasing sample times and one load (3,) per sample")
        self.zeta = zeta
        self.rigid = ~np.isfinite(self.freq_hz)
        w = 2.0 * math.pi * np.where(self.rigid, 1.0, self.freq_hz)  # rad/s (dummy 1 for rigid bars)
        wd = w * np.sqrt(1.0 - zeta**2)
        self.w, self.lam = w, -zeta * w + 1j * wd
        kappa = 2.0 * zeta / w + 1j * (1.0 - 2.0 * zeta**2) / wd
        mu = 1.0 - 1j * zeta * w / wd
        self.slope = (before[1:] - self.u[:-1]) / h[:, None, None]  # (N-1, M, 3): s_k of interval k
        jump = self.u[1:-1] - before[1:-1]  # J_k at the inner samples k = 1 .. N-2
        # Stretches of (numerically) equal steps over the transitions C_k -> C_{k+1}, k = 0 .. N-3.
        hk = h[:-1]
        cuts = np.flatnonzero(np.abs(np.diff(hk)) > 1e-9 * hk[1:]) + 1
        bounds = np.concatenate([[0], cuts, [len(hk)]])
        self.C = np.zeros((len(h), M, 3), dtype=complex)  # ringing amplitude at the start of each interval
        for i in np.flatnonzero(~self.rigid):  # a few cameras x a few stretches; the samples run in lfilter
            drive = kappa[i] * np.diff(self.slope[:, i], axis=0) - mu[i] * jump[:, i]  # (N-2, 3): C_{k+1} - p C_k
            self.C[0, i] = kappa[i] * self.slope[0, i]
            for a, b in zip(bounds[:-1], bounds[1:]):
                if b <= a:
                    continue
                p = np.exp(self.lam[i] * hk[a])
                self.C[a + 1:b + 1, i] = lfilter([1.0], [1.0, -p], drive[a:b], axis=0, zi=(p * self.C[a, i])[None])[0]

    def _locate(self, t):
        t = np.clip(np.asarray(t, dtype=float).reshape(-1), self.t[0], self.t[-1])
        k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2)
        return k, (t - self.t[k])[:, None, None]

    def at(self, t):
        """Loads x (K, M, 3) and their rates x' (K, M, 3, per second) at times t (K,) in [t[0], t[-1]]."""
        k, h = self._locate(t)
        s = self.slope[k]
        ring = self.C[k] * np.exp(self.lam[None, :, None] * h)
        ramp = self.u[k] + s * h
        rigid = self.rigid[None, :, None]
        x = np.where(rigid, ramp, ramp - 2.0 * self.zeta[None, :, None] * s / self.w[None, :, None] + ring.real)
        v = np.where(rigid, s, s + (self.lam[None, :, None] * ring).real)
        return x, v

    def amplitude(self, t) -> np.ndarray:
        """(K, M) ringing amplitude of each bar at times t: the norm over the axes of |C exp(lambda h)| (m/s^2)."""
        k, h = self._locate(t)
        return np.linalg.norm(np.abs(self.C[k] * np.exp(self.lam[None, :, None] * h)), axis=-1)
