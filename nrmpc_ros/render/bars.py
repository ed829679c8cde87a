"""Each camera's bending load over a rendered trajectory: quasi-static bars, or bars that ring.

Quasi-static (no damping given): every bar carries the body's load
u = R^T (g_world - a) at once (:meth:`Trajectory.load_body`), so all cameras
bend for the same load. Ringing (a damping ratio zeta): bar i's load x_i is
the damped second-order response of :mod:`nrmpc_ros.core.dynamics` to u at
the bar's natural frequency, integrated exactly from rest at the first hold
on a grid of at most 0.5 ms steps whose nodes include every instant where the
acceleration jumps (:meth:`Trajectory.breakpoints`), so the jumps are exact;
each camera then bends for its own load.
"""

from __future__ import annotations

import numpy as np

from ..core.deformation import deformed_extrinsics
from ..core.dynamics import DampedResponse, bar_natural_frequencies, check_damping, ringing_decay_time
from ..core.rig import Rig
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
    """Bending loads (body frame, m/s^2) of every camera's bar along a trajectory; see the module docstring."""

    def __init__(self, rig: Rig, traj: Trajectory, damping: float | None = None,
                 step_ns: int = DYNAMICS_STEP_NS):
        self.rig = rig
        self.traj = traj
        self.damping = damping
        self.frequencies = bar_natural_frequencies(rig)  # (M,) Hz, inf = rigid
        self.response = None
        if damping is not None:
            check_damping(damping)
            self._t0 = traj.start_ns
            t, at_break = self._grid(step_ns)
            t_ns = self._t0 + np.rint(t).astype(np.int64)
            after = self.quasi_static(t_ns + at_break)  # one-sided loads at a jump, 1 ns off it
            before = self.quasi_static(t_ns - at_break)
            self.response = DampedResponse(t * 1e-9, after, self.frequencies, damping, u_before=before)

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
        """(N, 3) quasi-static body load u at times t_ns."""
        R, _, _, acc = self.traj.state(t_ns)
        return self.traj.load_body(R, acc)

    def state(self, t_ns):
        """Loads x (N, M, 3), their rates x' (N, M, 3, m/s^3; None when quasi-static) and u (N, 3) at t_ns."""
        u = self.quasi_static(t_ns)
        if self.response is None:
            return np.broadcast_to(u[:, None, :], (len(u), self.rig.num_cameras, 3)), None, u
        t = (np.asarray(t_ns, dtype=np.int64).reshape(-1) - self._t0).astype(float) * 1e-9
        x, v = self.response.at(t)
        rigid = ~np.isfinite(self.frequencies)[None, :, None]
        return np.where(rigid, u[:, None, :], x), v, u

    def at(self, t_ns) -> np.ndarray:
        """(N, M, 3) load of each camera's bar at times t_ns."""
        return self.state(t_ns)[0]

    def settle_times_ns(self) -> np.ndarray | None:
        """(V,) time each hold's ringing has decayed to 1e-3 of its amplitude at the hold's start (ns).

        The slowest flexible bar decides; the first hold starts at rest. None without ringing.
        """
        if not self.ringing:
            return None
        decay = float(np.max(ringing_decay_time(self.frequencies[np.isfinite(self.frequencies)], self.damping)))
        out = self.traj.hold_start + int(round(decay * 1e9))
        out[0] = self.traj.hold_start[0]
        return out
