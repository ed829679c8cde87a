"""Each bar's state propagated from the IMU stream: every camera's bent extrinsics at any instant.

docs/CONVENTIONS.md ("The rig in motion") fixes the model. Camera i's bar carries
the specific force at its tip mass, l_i = g_b - a_b - alpha x v_i - omega x (omega x v_i),
and bends for its effective load x_i = l~_i, the response of the bar's first
bending mode (natural frequency w_i, damping ratio zeta_i) to l_i:

    x_i'' + 2 zeta_i w_i x_i' + w_i^2 x_i = w_i^2 l_i.

The IMU gives g_b - a_b = -R_body_imu f (f its specific force; at the body
origin, or moved there from a camera's tip by the lever arm) and omega;
alpha is omega differenced between samples. Between two samples omega is
taken linear, so alpha is constant over the step and the load l_i linear
(it may jump at a sample, where alpha changes). For such a load the response
is exact (:mod:`.dynamics`): x = ramp - 2 zeta s / w + Re(C e^{lambda tau}),
with the complex ringing amplitude C carried from step to step:

    C_{k+1} = e^{lambda h_k} C_k + kappa (s_{k+1} - s_k) - mu J_{k+1}

(s the load's slope over a step, J its jump at a sample). So the only
approximation is that the load is linear between samples: at 200 Hz and
more, for the moves of a hand or a robot, far below the IMU's own noise; an
acceleration step between two samples is smeared over one IMU period.

- Gaps: a step longer than ``GAP_PERIODS`` IMU periods (the median step of the
  recent samples) holds the last sample's load over the gap (no alpha), counted
  in ``stats.gaps_held``; one longer than the slowest bar's period as well
  restarts the bars at rest at the load after the gap (``stats.reinitialised``):
  after a full period without data the phase of the ringing is unknown.
- Start: the bars start at rest (as after a long gap) at the first sample's
  load without its angular acceleration. One sample's alpha is the gyro's
  noise differenced over one IMU period, sqrt(2) sigma_w / h: about 1 m/s^2
  at a 0.4 m lever for a MEMS gyro at 1 kHz. Running, the bars filter it (a
  few mm/s^2); a bar started at rest at it would ring at that for seconds.
- Queries: :meth:`BarPropagator.loads_at` / :meth:`BarPropagator.extrinsics_at`
  at any stamp inside the kept history (``history_s``), between samples exactly;
  beyond the newest sample the last load is held (``stats.extrapolated``).
- An IMU inside camera j (its ``imu.mount``) reads in that camera's bent frame
  at its bent position w_j, and its readings carry the tip's own motion
  relative to the body (bar j's ringing): :class:`~.tip_imu.TipImu` turns them
  into the body's specific force and rate through bar j's model, each sample
  with the tip's bend at it, delayed by its filters (the samples are stamped
  that much earlier); the lever arm is w_j at each sample. Rendered 3 Hz
  bars all alike (the others resonate with the tip's ringing), noise-free IMU
  at 2 kHz in one camera: 2.8 deg median extrinsics error before, 0.075 deg
  with it; on a 9 Hz mounting bar 0.04 -> 0.0004 deg.
- ``imu_time_offset_s`` is added to every IMU stamp (the IMU's clock against
  the cameras').
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .dynamics import bar_damping_ratios, bar_natural_frequencies, check_damping
from .recursion import linear_recursion
from .rig import ImuMount, Rig
from .so3 import exp_so3, skew
from .tip_imu import TipImu

GAP_PERIODS = 5.0  # a step longer than this many IMU periods is a gap (the load is held over it)
PERIOD_WINDOW = 64  # steps the IMU period (their median) is taken from
FLUSH_SAMPLES = 256  # pending samples propagated in one block even when nobody asks
DEFAULT_HISTORY_S = 2.0  # how far back queries can go (s): the delay of a frame set behind the IMU


def bent_extrinsics_at_loads(rig: Rig, loads, cams=None):
    """Each camera bent for its OWN load: loads (..., M, 3) -> w (..., M, 3), W (..., M, 3, 3); with ``cams``
    (K,) camera indices, loads (K, 3) of those cameras -> w (K, 3), W (K, 3, 3).

    Section 3 of docs/CONVENTIONS.md with x_i in place of g: w_i = v_i + c_d,i (x_i - (u_i . x_i) u_i),
    W_i = Exp(c_r,i u_i x x_i) V_i.
    """
    x = np.asarray(loads, dtype=float)
    m = slice(None) if cams is None else np.asarray(cams, dtype=int).reshape(-1)
    n = rig.num_cameras if cams is None else len(m)
    if x.shape[-2:] != (n, 3):
        raise ValueError(f"per-camera loads must have shape (..., {n}, 3), got {x.shape}")
    u, cd, _ = rig.bar_coefficients
    u, cd = u[m], cd[m]
    perp = x - np.sum(x * u, axis=-1, keepdims=True) * u
    w = rig.positions[m] + cd[:, None] * perp
    phi = np.einsum("mab,...mb->...ma", rig.bar_derivatives[1][m], x)
    return w, exp_so3(phi) @ rig.rotations[m]


def tip_loads(specific_force, omega, alpha, lever) -> np.ndarray:
    """Each bar's load (K, M, 3) at K samples: the body's specific force (K, 3) at the IMU, angular rate and
    angular acceleration (K, 3), tips at ``lever`` (M, 3), or (K, M, 3) per sample, from the IMU, all in the
    body frame (docs/CONVENTIONS.md,
    "The rig in motion"): l = -f - alpha x r - omega x (omega x r), written ([alpha]_x + omega omega^T -
    |omega|^2 I) r."""
    w = np.asarray(omega, dtype=float)
    A = skew(alpha) + w[:, :, None] * w[:, None, :] - np.sum(w * w, axis=1)[:, None, None] * np.eye(3)
    r = np.asarray(lever, dtype=float)
    return -np.asarray(specific_force, dtype=float)[:, None, :] - np.einsum(
        "kij,mj->kmi" if r.ndim == 2 else "kij,kmj->kmi", A, r)


class _Steps:
    """The kept steps in preallocated arrays: appending moves an end index, trimming a start index (compacted or
    grown only when the end is reached), so a block of samples costs no copy of the history."""

    def __init__(self, M: int, capacity: int = 1024):
        self.M = M
        self.i0 = self.n = 0
        self.buf = self._alloc(capacity)

    def _alloc(self, cap: int) -> dict:
        M = self.M
        return {"t0": np.zeros(cap), "h": np.zeros(cap), "a": np.zeros((cap, M, 3)), "s": np.zeros((cap, M, 3)),
                "C": np.zeros((cap, M, 3), dtype=complex)}

    def view(self, key: str) -> np.ndarray:
        return self.buf[key][self.i0:self.n]

    def append(self, keep_from: float, **rows) -> None:
        """Add the rows (same keys as the buffers); drop the steps that start before ``keep_from``."""
        K = len(rows["t0"])
        self.i0 += int(np.searchsorted(self.view("t0"), keep_from, side="left"))
        live = self.n - self.i0
        cap = len(self.buf["t0"])
        if self.n + K > cap:
            new = self._alloc(max(cap, 2 * (live + K))) if live + K > cap // 2 else self.buf
            for k, b in self.buf.items():
                new[k][:live] = b[self.i0:self.n]
            self.buf, self.i0, self.n = new, 0, live
        for k, v in rows.items():
            self.buf[k][self.n:self.n + K] = v
        self.n += K


@dataclass
class BarStateStats:
    """What the propagator did with its input (counts)."""

    samples: int = 0  # IMU samples used
    rejected: int = 0  # non-finite or not newer than the last one
    gaps_held: int = 0  # gaps the last load was held over
    reinitialised: int = 0  # gaps long enough to restart the bars at rest
    extrapolated: int = 0  # queries beyond the newest sample (last load held)
    too_old: int = 0  # queries before the kept history (answered at its start)


class BarPropagator:
    """Streaming state of every bar, driven by IMU samples; see the module docstring.

    rig: the rig (its ``imu`` block: mount and rotation; cameras' bars and ``bar.damping``); damping: the
    damping ratio of bars whose rig file gives none (default :data:`~.dynamics.UNKNOWN_DAMPING_RATIO`).
    """

    def __init__(self, rig: Rig, damping: float | None = None, imu_time_offset_s: float = 0.0,
                 history_s: float = DEFAULT_HISTORY_S):
        if damping is not None:
            check_damping(damping, "bar state")
        self.rig = rig
        self.mount = rig.imu or ImuMount()
        self.mount_camera = None if self.mount.mount == "body" else rig.camera_index(self.mount.mount)
        self.offset_s = float(imu_time_offset_s)
        self.history_s = float(history_s)
        self.freq_hz = bar_natural_frequencies(rig)
        self.zeta = bar_damping_ratios(rig, damping)
        self.rigid = ~np.isfinite(self.freq_hz)
        w = 2.0 * math.pi * np.where(self.rigid, 1.0, self.freq_hz)
        wd = w * np.sqrt(1.0 - self.zeta**2)
        self.w, self.lam = w, -self.zeta * w + 1j * wd
        self.kappa = np.where(self.rigid, 0.0, 2.0 * self.zeta / w + 1j * (1.0 - 2.0 * self.zeta**2) / wd)
        self.mu = np.where(self.rigid, 0.0, 1.0 - 1j * self.zeta * w / wd)
        flexible = self.freq_hz[~self.rigid]
        self.long_gap_s = float(1.0 / flexible.min()) if flexible.size else math.inf  # slowest bar's period
        self.stats = BarStateStats()
        self._pending: list = []  # (t, f (3,), omega (3,)) in the body's clock, IMU frame
        self._last = None  # the newest propagated sample: (t, f_body (3,), omega_body (3,))
        self._last_at = np.zeros(3)  # ... and the IMU's position then (body frame)
        self._newest_flushed = -math.inf  # the newest propagated sample's own stamp
        self._steps: list = []  # recent step lengths (s)
        M = rig.num_cameras
        # the kept steps: start t0, length h, load a at the start, slope s, ringing amplitude C at the start
        self._hist = _Steps(M)
        j = self.mount_camera
        self._tip = None if j is None or self.rigid[j] else TipImu(rig, j, float(self.zeta[j]), float(self.w[j]))

    # ------------------------------------------------------------------ input
    def add_imu(self, stamp: float, accel, gyro) -> None:
        """One IMU sample: stamp (s, the IMU's clock), specific force (m/s^2) and angular rate (rad/s), IMU frame.

        Cheap (no numpy per sample): the samples are propagated in blocks (:meth:`flush`)."""
        try:
            (ax, ay, az), (gx, gy, gz) = accel, gyro
            row = (float(stamp) + self.offset_s, float(ax), float(ay), float(az), float(gx), float(gy), float(gz))
        except (TypeError, ValueError):
            row = (math.nan,)
        newest = self._pending[-1][0] if self._pending else self._newest_flushed
        if not math.isfinite(sum(row)) or row[0] <= newest:  # the sum is finite only when every value is
            self.stats.rejected += 1
            return
        self._pending.append(row)
        if len(self._pending) >= FLUSH_SAMPLES:
            self.flush()

    @property
    def ready(self) -> bool:
        """True once two samples have arrived (one step: the loads are known)."""
        return len(self._t0) > 0 or (len(self._pending) + (self._last is not None)) >= 2

    def shift_specific_force(self, delta_imu) -> None:
        """Add ``delta_imu`` (IMU frame, m/s^2) to every sample's specific force, those propagated already included:
        the bars' state becomes what it would be had the samples always carried it (the loads are linear in the
        samples: the kept loads move by the same constant, the ringing stays). Pending samples are propagated
        first. For a corrected accelerometer bias."""
        d = np.asarray(delta_imu, dtype=float).reshape(1, 3)
        if not np.any(d):
            return
        self.flush()
        if self._last is None:
            return
        d_body = self._to_body(d, np.zeros((1, 3)))[0][0]  # (the IMU's frame: at the newest state)
        self._hist.buf["a"][self._hist.i0:self._hist.n] -= d_body  # the load is minus the specific force
        if self._tip is not None:
            self._tip.shift(d_body)
        t, f, g = self._last
        self._last = (t, f + d_body, g)

    def _to_body(self, f, g):
        """IMU readings (N, 3) -> body-frame specific force at the IMU and angular rate, and the IMU's position."""
        f = f @ self.mount.rotation.T
        g = g @ self.mount.rotation.T
        if self.mount_camera is None:
            return f, g, np.zeros(3)
        j = self.mount_camera
        if len(self._t0):  # bar j's bent state at the newest propagated sample
            x = self._evaluate(np.array([self._t0[-1] + self._h[-1]]), np.array([j]))[0]
        else:
            x = -self.rig.rotations[j] @ f[0]
        loads = np.zeros((self.rig.num_cameras, 3))
        loads[j] = x
        w, W = bent_extrinsics_at_loads(self.rig, loads)
        return f @ W[j].T, g @ W[j].T, w[j]

    def _tip_body(self, t, f, g):
        """An IMU on a flexible bar's tip (:class:`~.tip_imu.TipImu`): the stamps the outputs hold at (the
        samples' less the filters' delay), body-frame rigid specific force at the tip, body rate and the tip's
        position (K, 3) each."""
        f_body, omega, at = self._tip.body(t, f @ self.mount.rotation.T, g @ self.mount.rotation.T, self.long_gap_s)
        return t - self._tip.delay_s, f_body, omega, at

    def flush(self) -> None:
        """Propagate the pending samples (queries do this themselves)."""
        if not self._pending:
            return
        rows = np.array(self._pending)
        t = rows[:, 0]
        if self._tip is not None:
            t, f, g, at = self._tip_body(t, rows[:, 1:4], rows[:, 4:7])
        else:
            f, g, at = self._to_body(rows[:, 1:4], rows[:, 4:7])
        self._newest_flushed = float(rows[-1, 0])
        self._pending = []
        self.stats.samples += len(t)
        if self._last is not None:
            t = np.concatenate([[self._last[0]], t])
            f = np.concatenate([self._last[1][None], f])
            g = np.concatenate([self._last[2][None], g])
            if self._tip is not None:  # the tip's position at each sample (else the IMU's: one for all)
                at = np.concatenate([self._last_at[None], at])
        self._last = (float(t[-1]), f[-1].copy(), g[-1].copy())
        self._last_at = at[-1].copy() if at.ndim == 2 else at
        if len(t) < 2:
            return
        h = np.diff(t)
        self._steps = (self._steps + h.tolist())[-PERIOD_WINDOW:]
        period = sorted(self._steps)[len(self._steps) // 2]  # the median step (a short list: no numpy)
        gap = h > GAP_PERIODS * period
        restart = gap & (h > self.long_gap_s)
        self.stats.gaps_held += int(gap.sum())
        self.stats.reinitialised += int(restart.sum())
        alpha = np.where(gap[:, None], 0.0, np.diff(g, axis=0) / h[:, None])  # (K, 3) over each step
        # each tip from the IMU: (M, 3), or (K + 1, M, 3) at each sample for an IMU on a bar's tip
        lever = self.rig.positions - at if at.ndim == 1 else self.rig.positions[None] - at[:, None]

        def load(k, a_k):  # (K, M, 3) load of every bar at samples k with the angular acceleration a_k
            return tip_loads(f[k], g[k], a_k, lever if lever.ndim == 2 else lever[k])

        K = len(h)
        a = load(np.arange(K), alpha)
        b = np.where(gap[:, None, None], a, load(np.arange(1, K + 1), alpha))
        s = (b - a) / h[:, None, None]
        # Drives of the recursion: C_k = P_{k-1} C_{k-1} + D_k (D_0 joins the kept history).
        fresh = np.concatenate([[not len(self._t0)], restart[:-1]])  # steps that start at rest
        if len(self._t0):
            s0, b0, h0, C_prev = self._s[-1], self._a[-1] + self._s[-1] * self._h[-1], self._h[-1], self._C[-1]
        else:
            s0, b0, h0, C_prev = s[0], a[0], h[0], None  # unused: the first step starts at rest
        s_prev = np.concatenate([s0[None], s[:-1]])
        b_prev = np.concatenate([b0[None], b[:-1]])
        h_prev = np.concatenate([[h0], h[:-1]])
        D = self.kappa[None, :, None] * (s - s_prev) - self.mu[None, :, None] * (a - b_prev)
        P = np.exp(self.lam[None, :] * h_prev[:, None])
        # A step that starts at rest starts at its load without the angular acceleration (module docstring,
        # "Start"): at rest at a - d with d = -alpha x lever (x' = 0 there): C = kappa s - mu d.
        d = -np.cross(alpha[:, None, :], lever if lever.ndim == 2 else lever[:-1])  # (K, M, 3)
        rest = self.kappa[None, :, None] * s - self.mu[None, :, None] * d
        decay = np.max(-self.lam.real) * h_prev
        C = linear_recursion(P, D, rest, fresh, C_prev, decay)
        self._hist.append(t[-1] - self.history_s, t0=t[:-1], h=h, a=a, s=s, C=C)

    _t0 = property(lambda self: self._hist.view("t0"))
    _h = property(lambda self: self._hist.view("h"))
    _a = property(lambda self: self._hist.view("a"))
    _s = property(lambda self: self._hist.view("s"))
    _C = property(lambda self: self._hist.view("C"))

    # ------------------------------------------------------------------ queries
    def loads_at(self, stamps, cams=None):
        """Effective loads (body frame, m/s^2) at stamps (K,) (body clock, s): of every bar (K, M, 3), or with
        ``cams`` (K,) of bar cams[j] at stamps[j] only (K, 3). None before two samples have arrived."""
        self.flush()
        if not len(self._t0):
            return None
        return self._evaluate(np.asarray(stamps, dtype=float).reshape(-1), cams)

    def _evaluate(self, q, cams, rates: bool = False):
        """:meth:`loads_at` on the steps propagated so far (no flush); with ``rates`` also the loads' rates x'
        (m/s^3, same shape)."""
        m = slice(None) if cams is None else np.asarray(cams, dtype=int).reshape(-1)
        one = cams is not None

        def per_bar(v):  # (M, ...) per-bar constants -> broadcastable against the (K, M, 3) or (K, 3) loads
            return v[m][:, None] if one else v[None, :, None]

        t0, h = self._t0, self._h
        end = t0[-1] + h[-1]
        beyond = q > end
        self.stats.too_old += int(np.count_nonzero(q < t0[0]))
        self.stats.extrapolated += int(np.count_nonzero(beyond))
        k = np.clip(np.searchsorted(t0, q, side="right") - 1, 0, len(t0) - 1)
        tau = np.clip(q - t0[k], 0.0, h[k])
        tau = tau[:, None] if one else tau[:, None, None]
        rows = (k, m) if one else (k,)
        a, s, C = self._a[rows], self._s[rows], self._C[rows]
        rigid, lam = per_bar(self.rigid), per_bar(self.lam)
        ramp = a + s * tau
        free = C * np.exp(lam * tau)
        x = np.where(rigid, ramp, ramp - 2.0 * per_bar(self.zeta) * s / per_bar(self.w) + free.real)
        v = np.where(rigid, s, s + (lam * free).real) if rates else None
        if beyond.any():  # the last load held from the newest sample on
            b = self._a[-1] + self._s[-1] * h[-1]
            C_end = np.exp(self.lam * h[-1])[:, None] * self._C[-1] - self.kappa[:, None] * self._s[-1]
            if one:
                b, C_end = b[m], C_end[m]
            dt = q - end
            dt = dt[:, None] if one else dt[:, None, None]
            held = C_end * np.exp(lam * dt)
            x[beyond] = np.where(rigid, np.broadcast_to(b, x.shape), b + held.real)[beyond]
            if rates:
                v[beyond] = np.where(rigid, 0.0, (lam * held).real)[beyond]
        return (x, v) if rates else x

    def ringing_about(self, stamps, cams, rest):
        """Complex free ringing Z (K, 3) of bar cams[j] at stamps[j] about the load ``rest`` (K, 3) (body frame,
        m/s^2): the damped oscillation the bar would go on with were its load ``rest`` from then on, Re(Z) =
        x - rest and Re(lambda Z) = x' (its envelope the modulus; zero for rigid bars). From the bar's state,
        not from the step's amplitude C: C is taken about the current step's load line, whose slope and
        angular-acceleration jump carry the IMU's noise differenced over one period (a phantom of up to
        |s| / w). None before two samples have arrived."""
        self.flush()
        if not len(self._t0):
            return None
        m = np.asarray(cams, dtype=int).reshape(-1)
        x, v = self._evaluate(np.asarray(stamps, dtype=float).reshape(-1), m, rates=True)
        lam = self.lam[m][:, None]
        zr = x - np.asarray(rest, dtype=float).reshape(-1, 3)
        Z = zr + 1j * (lam.real * zr - v) / lam.imag
        return np.where(self.rigid[m][:, None], 0.0, Z)

    def mean_load(self, t0: float, t1: float):
        """Mean load (M, 3) of every bar over the propagated samples stamped in [t0, t1] (body clock, s): the
        load the rig sits at while still, with the accelerometer's noise averaged; None without such samples."""
        self.flush()
        t = self._t0
        sel = (t >= t0) & (t <= t1)
        if not sel.any():
            return None
        return self._a[sel].mean(axis=0)

    def extrinsics_at(self, stamps, cams=None):
        """Bent extrinsics w, W (camera -> body) at stamps (K,): of every camera (K, M, 3), (K, M, 3, 3), or with
        ``cams`` (K,) of camera cams[j] at stamps[j] only (K, 3), (K, 3, 3). None before two samples."""
        x = self.loads_at(stamps, cams)
        return None if x is None else bent_extrinsics_at_loads(self.rig, x, cams)


__all__ = ["BarPropagator", "BarStateStats", "bent_extrinsics_at_loads", "GAP_PERIODS", "tip_loads"]
