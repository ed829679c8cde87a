"""An IMU inside a camera on a flexible bar: its readings turned into the body's motion.

The IMU rides on bar j's tip. Its accelerometer reads the body's specific force
at the tip plus the tip's own acceleration relative to the body; its gyro the
body's rate plus the bar's bending rate (docs/CONVENTIONS.md, "The rig in
motion"). With bar j's load-equivalent state s (the perpendicular part of the
load that would bend the bar as it is bent; x'' + 2 zeta w x' + w^2 x = w^2 l)
the tip's relative acceleration per unit of compliance is s'' / w^2 = l - s -
tau s' with tau = 2 zeta / w: the bar's spring and damper force on the tip
mass. Read as a load (y = -f, its perpendicular part), the accelerometer
therefore gives y_perp = s + tau s': the bar's own state through a first-order
lag of a few ms, whatever the body does. So:

- s = y_perp low-passed at tau (exact for readings linear between samples);
- the body's rigid specific force at the tip is f_tip - s'' / w^2 - 2 omega x
  (c_d s') (the tip's relative acceleration and its Coriolis term);
- the body's rate is omega_tip - J_l(phi) phi' with phi' = c_r u x s';
- each reading is turned into the body with the tip's bend at its own sample.

s' and s'' differentiate the accelerometer's noise (once and twice), so they
are taken from the readings low-passed twice at a cutoff (a critically damped
pair of first-order stages) well above the bar's frequency, where the bars
respond to none of it; the gyro's rate and the reading itself pass the same
stages, so every output is the body's motion delayed by 2 / cutoff, and is
stamped that much earlier. Without this the tip's ringing is read as the
body's load and drives every other bar: on rendered 3 Hz bars, all alike,
with a 200 Hz IMU in one camera, 4.9 deg median extrinsics error, 0.22 deg
with it (docs/RESULTS.md).
"""

from __future__ import annotations

import numpy as np

from .deformation import bend_rotation_vectors
from .recursion import linear_recursion
from .so3 import cross, exp_and_left_jacobian, exp_so3

CUTOFF_BAR_FACTOR = 10.0
"""The low-pass cutoff as a multiple of the mounting bar's natural frequency. Every signal passes the same two
stages, so they delay the body's motion by 2 / cutoff (the outputs are stamped that much earlier) and differ from
that delay at the bar's frequency by (2/3) 10^-3 rad of phase and 1 % of gain; beyond, the twice-differentiated
noise. Rendered 3 Hz bars all alike, a trapezoid motion, the IMU in one camera: the median extrinsics error over
5, 10, 20, 40 times the bar's frequency 0.33, 0.22, 0.25, 0.26 deg at 200 Hz; at 50 Hz 0.86 deg at 10 times,
2.4 at 5 times."""

CUTOFF_NYQUIST_SHARE = 2.0
"""... and at most this multiple of the IMU's Nyquist frequency: far beyond it the stages pass the samples as
they are (exact for readings linear between samples) and a higher cutoff changes nothing."""


BEND_ITERATIONS = 6
"""Fixed-point steps of the tip's bend from its own reading, s = perp(-W(s) f): each shrinks the error by the
bend's turn of the reading, c_r |f| (0.15 on a 3 Hz bar of the rendered rigs, 0.6 on a 1.5 Hz bar that bends
by 0.4 rad under gravity), so six leave 5 % of the bend's change over a block of samples on the softest bar and
far less on the others; the blocks a stream is propagated in then hardly matter."""


def first_order(y: np.ndarray, h: np.ndarray, tau: float, start: np.ndarray, y_start: np.ndarray,
                fresh: np.ndarray) -> np.ndarray:
    """tau s' + s = y(t) for y (K, ..., 3) linear between samples h (K,) apart (h[k] the step that ends at
    sample k), from ``start`` (..., 3) at the sample before the first, whose reading was ``y_start`` (..., 3); at
    samples ``fresh`` (K,) bool the state starts at rest at its reading. Exact, vectorised over the samples and
    the signals (:func:`~.recursion.linear_recursion`)."""
    shape = y.shape
    y = y.reshape(len(y), -1, 3)
    a = np.exp(-h / tau)
    prev = np.concatenate([np.reshape(y_start, (1, -1, 3)), y[:-1]])
    slope = (y - prev) / np.maximum(h, 1e-300)[:, None, None]
    drive = a[:, None, None] * (tau * slope - prev) + y - tau * slope
    P = np.broadcast_to(a[:, None], y.shape[:2])
    out = linear_recursion(P, drive, y, fresh, np.reshape(start, (-1, 3)), h / tau)
    return out.reshape(shape)


class TipImu:
    """The body's specific force and rate from an IMU on bar ``j``'s tip, sample block by sample block (the
    filters' states carried between blocks); see the module docstring. The cutoff is fixed at the first
    block (from its sampling period), and with it the delay every output carries (:attr:`delay_s`)."""

    def __init__(self, rig, j: int, zeta: float, w_rad_s: float):
        self.rig, self.j = rig, int(j)
        self.w = float(w_rad_s)
        self.tau = 2.0 * float(zeta) / self.w
        u, cd, _ = rig.bar_coefficients
        self.u, self.cd = u[self.j], float(cd[self.j])
        self.cutoff_rad_s: float | None = None
        self._t = None  # the last sample's stamp
        self._state = None  # at the last sample: (body-frame reading y, bend s, low-pass stages of y and omega,
        # the bend of the low-passed reading)

    @property
    def delay_s(self) -> float:
        """How late the outputs are: the two low-pass stages' delay 2 / cutoff (their phase differs from a
        pure delay by (2/3) (w / cutoff)^3 rad at frequency w, their gain by (w / cutoff)^2)."""
        return 2.0 / self.cutoff_rad_s if self.cutoff_rad_s else 0.0

    def _rotations(self, s: np.ndarray) -> np.ndarray:
        """Camera j -> body at bend states s (K, 3)."""
        return exp_so3(bend_rotation_vectors(self.rig, s, cams=[self.j])[:, 0]) @ self.rig.rotations[self.j]

    def _perp(self, y: np.ndarray) -> np.ndarray:
        return y - (y @ self.u)[..., None] * self.u

    def shift(self, d_body: np.ndarray) -> None:
        """The samples' specific force shifted by ``d_body`` (body frame, m/s^2; a corrected accelerometer bias):
        the filters' states become what the shifted samples would have left (linear in them), so the next
        samples, shifted too, carry on without a step."""
        if self._state is None:
            return
        y0, w0, s0, u10, u20, o10, o20, sf0 = self._state
        d = np.asarray(d_body, float).reshape(3)
        p = self._perp(d)
        self._state = (y0 - d, w0, s0 - p, u10 - d, u20 - d, o10, o20, sf0 - p)

    def body(self, t: np.ndarray, f_cam: np.ndarray, g_cam: np.ndarray, restart_s: float):
        """The body-frame rigid specific force at the tip, the body's rate and the tip's position (K, 3) each, as
        they were :attr:`delay_s` before the samples' stamps ``t`` (K,), from readings in camera j's frame
        (K, 3). After a gap longer than ``restart_s`` the filters start again at rest."""
        t = np.asarray(t, float)
        K = len(t)
        prev = self._t if self._t is not None else t[0]
        h = np.maximum(np.diff(np.concatenate([[prev], t])), 1e-9)
        if self.cutoff_rad_s is None:
            period = float(np.median(h[1:])) if K > 1 else 0.0
            self.cutoff_rad_s = CUTOFF_BAR_FACTOR * self.w
            if period > 0:
                self.cutoff_rad_s = min(self.cutoff_rad_s, CUTOFF_NYQUIST_SHARE * np.pi / period)
        fresh = h > restart_s
        if self._state is None:
            fresh[0] = True
            z = np.zeros(3)
            self._state = (z,) * 8
        y0, w0, s0, u10, u20, o10, o20, sf0 = self._state
        # the tip's bend at each sample: the reading's own fixed point s = perp(-W(s) f) (the bend without its
        # lag tau, from the last sample's), then the lag through the readings turned with it
        s = np.broadcast_to(s0, (K, 3))
        for _ in range(BEND_ITERATIONS):
            s = self._perp(-np.einsum("kab,kb->ka", self._rotations(s), f_cam))
        y = -np.einsum("kab,kb->ka", self._rotations(s), f_cam)
        s = first_order(self._perp(y), h, self.tau, s0, self._perp(y0), fresh)
        W = self._rotations(s)
        y = -np.einsum("kab,kb->ka", W, f_cam)
        omega = np.einsum("kab,kb->ka", W, g_cam)
        T = 1.0 / self.cutoff_rad_s
        # every signal through the same two stages: one delay (the reading and the rate side by side)
        v1 = first_order(np.stack([y, omega], axis=1), h, T, np.stack([u10, o10]), np.stack([y0, w0]), fresh)
        v2 = first_order(v1, h, T, np.stack([u20, o20]), np.stack([u10, o10]), fresh)
        (u1, o1), (u2, o2) = np.moveaxis(v1, 1, 0), np.moveaxis(v2, 1, 0)
        sf = first_order(self._perp(u2), h, self.tau, sf0, self._perp(u20), fresh)
        sdot = (self._perp(u2) - sf) / self.tau
        sddot = (self._perp(u1 - u2) / T - sdot) / self.tau
        self._t = float(t[-1])
        self._state = (y[-1], omega[-1], s[-1], u1[-1], u2[-1], o1[-1], o2[-1], sf[-1])
        _, J = exp_and_left_jacobian(bend_rotation_vectors(self.rig, sf, cams=[self.j])[:, 0])
        rate = o2 - np.einsum("kab,kb->ka", J, bend_rotation_vectors(self.rig, sdot, cams=[self.j])[:, 0])
        f = -u2 - sddot / self.w**2 - 2.0 * cross(rate, self.cd * sdot)
        return f, rate, self.rig.positions[self.j] + self.cd * sf


__all__ = ["CUTOFF_BAR_FACTOR", "CUTOFF_NYQUIST_SHARE", "TipImu", "first_order"]
