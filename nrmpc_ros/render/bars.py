"""Each camera's bending load over a rendered trajectory: quasi-static bars, or bars that ring.

Bar i carries the specific force at its tip mass (docs/CONVENTIONS.md, "The
rig in motion"): l_i = u - alpha x v_i - omega x (omega x v_i), with u =
R^T (g_world - a) the body's load (:meth:`Trajectory.load_body`) and omega,
alpha the body's angular velocity and acceleration; at rest l_i = g_b.
Quasi-static (no damping anywhere): every bar bends for l_i at once. Ringing
(a damping ratio: the rig file's ``bar.damping`` per bar, the bag's
``damping`` for the others): bar i's load x_i is the damped second-order
response of :mod:`nrmpc_ros.core.dynamics` to l_i at the bar's natural
frequency and damping, integrated exactly from rest at the first hold on a
grid of at most 0.5 ms steps whose nodes include every instant where the
acceleration jumps (:meth:`Trajectory.breakpoints`), so the jumps are exact.
"""

from __future__ import annotations

import numpy as np

from ..core.deformation import deformed_extrinsics
from ..core.dynamics import (
    DampedResponse,
    bar_damping_ratios,
    bar_natural_frequencies,
    check_damping,
    ringing_decay_time,
)
from ..core.rig import Rig
from ..core.so3 import cross
from .sequence import Trajectory

DYNAMICS_STEP_NS = 500_000  # longest step of the bar dynamics' grid, ns


def bent_extrinsics(rig: Rig, loads):
    """Deformed extrinsics of each camera at its OWN load: loads (..., M, 3) -> w (..., M, 3), W (..., M, 3, 3)."""
    loads = np.asarray(loads, dtype=float)
    if loads.shape[-2:] != (rig.num_cameras, 3):
        raise ValueError(f"per-camera loads must have shape (..., {rig.num_cameras}, 3), got {loads.shape}")
    w, W = deformed_extrinsics(rig, loads)  # (..., M loads, M cameras, ...): keep camera i at load i
    i = np.arange(rig.num_cameras)
    return w[..., i, i, :], W[..., i, i, :, :]


class CameraLoads:
    """Bending loads (body frame, m/s^2) of every camera's bar along a trajectory; see the module docstring.

    damping: the damping ratio of bars whose rig file gives none (None: quasi-static unless the rig file gives
    one); ``zeta`` (M,) the ratio of every bar (None when quasi-static).
    """

    def __init__(self, rig: Rig, traj: Trajectory, damping: float | None = None,
                 step_ns: int = DYNAMICS_STEP_NS):
        self.rig = rig
        self.traj = traj
        self.damping = damping
        self.frequencies = bar_natural_frequencies(rig)  # (M,) Hz, inf = rigid
        self.response = None
        self.zeta = None
        if damping is not None or any(c.damping is not None for c in rig.cameras):
            if damping is not None:
                check_damping(damping)
            self.zeta = bar_damping_ratios(rig, damping)
            self._t0 = traj.start_ns
            t, at_break = self._grid(step_ns)
            t_ns = self._t0 + np.rint(t).astype(np.int64)
            after = self.quasi_static(t_ns + at_break)  # one-sided loads at a jump, 1 ns off it
            before = self.quasi_static(t_ns - at_break)
            self.response = DampedResponse(t * 1e-9, after, self.frequencies, self.zeta, u_before=before)

    def _grid(self, step_ns: int):
        """Node times (ns after the start, float) of equal steps <= step_ns between breakpoints; 1 at breakpoints."""
        b = self.traj.breakpoints() - self._t0
        n = np.maximum(1, -(-np.diff(b) // step_ns))  # steps per stretch
        piece = np.repeat(np.arange(len(n)), n)
        j = np.arange(len(piece)) - np.repeat(np.cumsum(n) - n, n)
        t = np.append(b[piece] + np.diff(b)[piece] * (j / n[piece]), float(b[-1]))
        return t, np.append(j == 0, True).astype(np.int64)

    @property
    def ringing(self) -> bool:
        """True when at least one bar has dynamics (a damping ratio and a flexible bar)."""
        return self.response is not None and bool(np.isfinite(self.frequencies).any())

    def quasi_static(self, t_ns) -> np.ndarray:
        """(N, M, 3) quasi-static load l_i of each bar at times t_ns (the specific force at its tip mass)."""
        R, _, omega, acc = self.traj.state(t_ns)
        u = self.traj.load_body(R, acc)[:, None, :]
        if not np.any(omega):  # no rotation: every bar carries the body's load (bit for bit)
            return np.broadcast_to(u, (len(u), self.rig.num_cameras, 3))
        alpha = self.traj.angular_acceleration(t_ns)[:, None, :]
        v = self.rig.positions[None]
        w = omega[:, None, :]
        return u - cross(alpha, v) - cross(w, cross(w, v))

    def state(self, t_ns):
        """Loads x (N, M, 3), their rates x' (N, M, 3, m/s^3; None when quasi-static) and the quasi-static
        loads l (N, M, 3) at t_ns."""
        u = self.quasi_static(t_ns)
        if self.response is None:
            return u, None, u
        t = (np.asarray(t_ns, dtype=np.int64).reshape(-1) - self._t0).astype(float) * 1e-9
        x, v = self.response.at(t)
        rigid = ~np.isfinite(self.frequencies)[None, :, None]
        return np.where(rigid, u, x), v, u

    def at(self, t_ns) -> np.ndarray:
        """(N, M, 3) load of each camera's bar at times t_ns."""
        return self.state(t_ns)[0]

    def settle_times_ns(self) -> np.ndarray | None:
        """(V,) time each hold's ringing has decayed to 1e-3 of its amplitude at the hold's start (ns).

        The slowest-decaying flexible bar decides; the first hold starts at rest. None without ringing.
        """
        if not self.ringing:
            return None
        flex = np.isfinite(self.frequencies)
        decay = float(np.max(ringing_decay_time(self.frequencies[flex], self.zeta[flex])))
        out = self.traj.hold_start + int(round(decay * 1e9))
        out[0] = self.traj.hold_start[0]
        return out
