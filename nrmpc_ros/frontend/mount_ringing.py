"""An IMU mount that rings: least squares of samples with an oscillation at the mount's frequency taken out.

An IMU inside a camera rides on that camera's bar and rings with it after
every stop (docs/PIPELINE.md, Holds): its samples carry, besides the
constant the rig's stillness gives them, an oscillation at the bar's
natural frequency whose amplitude decays. Over a span of one period or more,
each axis is fitted with its constant and cos u, sin u, v cos u, v sin u (u the
phase, v the phase from the span's centre: an amplitude that changes
linearly, i.e. a decay and a frequency a few percent off, to first order).
:func:`ringing_moments` does it for every sliding window of the stillness
test at once, by cumulative sums; :func:`mean_under_ringing` for one span (a
hold's accelerometer mean, its gravity).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.so3 import exp_so3, right_jacobian

RINGING_PARAMETERS = 4  # per axis: cos, sin, tau cos, tau sin of the mount's ringing
# fixed-point steps of the static bend psi = K exp(psi) f: the bend changes the frame the accelerometer measures the
# load in by tenths of a radian on a soft bar, which moves psi by a few percent; each step divides that error by
# |K f| again
STATIC_BEND_STEPS = 4
# the decay (damping x phase) a chunk of sliding windows of :func:`ringing_moments` spans at most: its basis
# ranges over [exp(-CHUNK_DECAY), 1], its squares over e^-8, well inside what differences of cumulative sums keep
# exact
CHUNK_DECAY = 4.0


def ringing_moments(x: np.ndarray, t: np.ndarray, i0: np.ndarray, i1: np.ndarray, shift: np.ndarray,
                    frequency_hz: float, damping: float = 0.0):
    """Per window [i0, i1) of samples x (n, 3) at stamps t, an oscillation at ``frequency_hz`` decaying at the
    damping ratio ``damping`` (its amplitude falls as exp(-damping u) with the phase u), whose amplitude
    changes besides linearly across the window, fitted on every axis with the constant: (the fitted constant
    (W, 3), the residual sum of squares with the constant fitted, and without it: about ``shift``). Per window
    the basis is 1, e cos u, e sin u, v e cos u, v e sin u, with e = exp(-damping u), u the phase and v the
    phase from the window's centre: the linear change takes a damping off the bar's and a frequency a few
    percent off to first order, the decay itself exactly (over one period of a bar damped at 0.03 a linear
    amplitude alone leaves 0.3 % of the swing, a DC that the gyro's test without a constant reads as a turn,
    several times a gyro's noise on a swing of tens of degrees per second). The Gram matrix and the data's
    projections are differences of cumulative sums of products with powers of u, expanded about the centre.
    The phase is counted from the start of a chunk of a few windows, so that its powers stay small (their
    cumulative sums exact) whatever the recording's length, and the decay within a chunk bounded
    (:data:`CHUNK_DECAY`)."""
    x, t = np.asarray(x, float), np.asarray(t, float)
    i0, i1 = np.asarray(i0, np.int64), np.asarray(i1, np.int64)
    W = len(i0)
    mean, ss_const, ss_free = np.zeros((W, 3)), np.zeros(W), np.zeros(W)
    order = np.argsort(i0, kind="stable")
    longest = int(np.max(i1 - i0, initial=1))
    step = max(4 * longest, 256)  # windows per chunk
    omega = 2.0 * math.pi * frequency_hz
    if damping > 0 and len(t) > 1 and t[-1] > t[0]:  # a chunk spans at most CHUNK_DECAY of decay (and one window)
        per_sample = omega * (t[-1] - t[0]) / (len(t) - 1)
        step = max(min(step, int(CHUNK_DECAY / (damping * per_sample)) - longest), 1)
    for a in range(0, W, step):
        w = order[a:a + step]
        s0, s1 = int(i0[w].min()), int(i1[w].max())
        m, sc, sf = _chunk_moments(x[s0:s1] - shift, omega * (t[s0:s1] - t[s0]), i0[w] - s0, i1[w] - s0, damping)
        mean[w], ss_const[w], ss_free[w] = m + shift, sc, sf
    return mean, ss_const, ss_free


def _chunk_moments(d: np.ndarray, u: np.ndarray, i0: np.ndarray, i1: np.ndarray, damping: float):
    """:func:`ringing_moments` of samples d (n, 3) about zero at phases u (n,) counted from the chunk's start."""
    N = len(d)
    decay = np.exp(-damping * u) if damping > 0 else 1.0  # at most 1: no overflow over a long single window
    c, s = decay * np.cos(u), decay * np.sin(u)
    one = np.ones(N)
    base = {"1": one, "c": c, "s": s, "cc": c * c, "ss": s * s, "cs": c * s}
    cols = [base[k] * u ** p for p in range(3) for k in base]  # sums of u^p g, g a product of two basis factors
    cols += [d[:, a] * g * u ** p for p in range(2) for g in (one, c, s) for a in range(3)]
    cols.append(np.einsum("ij,ij->i", d, d))
    cum = np.zeros((N + 1, len(cols)))
    np.cumsum(np.column_stack(cols), axis=0, out=cum[1:])
    S = cum[i1] - cum[i0]
    n = len(base)

    def g_sum(key, p):  # sum over the window of (u - uc)^p g
        k = list(base).index(key)
        s0, s1, s2 = S[:, k], S[:, n + k], S[:, 2 * n + k]
        return s0 if p == 0 else (s1 - uc * s0 if p == 1 else s2 - 2.0 * uc * s1 + uc * uc * s0)

    def d_sum(g, p, a):  # sum of (u - uc)^p g d_a
        j = 3 * n + {"1": 0, "c": 1, "s": 2}[g] * 3 + a
        s0, s1 = S[:, j], S[:, j + 9]
        return s0 if p == 0 else s1 - uc * s0

    last = np.maximum(i1 - 1, i0)
    uc = 0.5 * (u[np.minimum(i0, N - 1)] + u[np.minimum(last, N - 1)]) if N else np.empty(0)
    # the basis 1, c, s, vc, vs (v = u - uc): the Gram matrix's entries as sums of (u - uc)^p g
    terms = {(0, 0): ("1", 0), (0, 1): ("c", 0), (0, 2): ("s", 0), (0, 3): ("c", 1), (0, 4): ("s", 1),
             (1, 1): ("cc", 0), (1, 2): ("cs", 0), (1, 3): ("cc", 1), (1, 4): ("cs", 1),
             (2, 2): ("ss", 0), (2, 3): ("cs", 1), (2, 4): ("ss", 1),
             (3, 3): ("cc", 2), (3, 4): ("cs", 2), (4, 4): ("ss", 2)}
    G = np.empty((len(i0), 5, 5))
    for (a, b), (key, p) in terms.items():
        G[:, a, b] = G[:, b, a] = g_sum(key, p)
    P = np.empty((len(i0), 5, 3))
    for row, (g, p) in enumerate((("1", 0), ("c", 0), ("s", 0), ("c", 1), ("s", 1))):
        for a in range(3):
            P[:, row, a] = d_sum(g, p, a)
    ss_shift = S[:, -1]
    ridge = 1e-12 * np.maximum(np.trace(G, axis1=1, axis2=2), 1.0)[:, None, None] * np.eye(5)
    full = np.linalg.solve(G + ridge, P)  # (W, 5, 3): the constant and the oscillation, per axis
    osc = np.linalg.solve(G[:, 1:, 1:] + ridge[:, 1:, 1:], P[:, 1:])  # the oscillation alone, about zero
    ss_const = np.maximum(ss_shift - np.einsum("wka,wka->w", full, P), 0.0)
    ss_free = np.maximum(ss_shift - np.einsum("wka,wka->w", osc, P[:, 1:]), 0.0)
    return full[:, 0, :], ss_const, ss_free


def mount_turn(t: np.ndarray, gyro: np.ndarray, bias) -> np.ndarray:
    """The mount's rotation vector (n, 3) since the first sample: the gyro's rate less ``bias``, integrated over
    the stamps t (trapezoid). Over a ringing's span it is the ringing's rotation about its mean to first order
    (the rotations are tenths of a radian at most; a move's, which is large, is a motion the gyro test sees)."""
    rate = np.asarray(gyro, float).reshape(-1, 3) - np.asarray(bias, float).reshape(3)
    turn = np.zeros_like(rate)
    if len(t) > 1:
        np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t)[:, None], axis=0, out=turn[1:])
    return turn


def turned_back(x: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Vectors x (n, 3) turned by the rotation vectors phi (n, 3), row by row: an accelerometer's samples in the
    frame the mount had at the turn's reference."""
    return np.einsum("nij,nj->ni", exp_so3(np.asarray(phi, float)), np.asarray(x, float))


@dataclass(frozen=True)
class MountBar:
    """The bar the IMU rides on, beyond its frequency: how its ringing decays and how it bends at rest."""

    damping: float  # damping ratio of its first bending mode: the rig file's, else UNKNOWN_DAMPING_RATIO
    # K (3, 3), rad per m/s^2: the static bend's rotation vector per unit specific force, both in the IMU's frame
    # (psi = K f to first order); None: not known
    compliance: np.ndarray | None = None


def mount_bar(rig) -> MountBar | None:
    """The :class:`MountBar` of the flexible bar the rig file mounts the IMU on (docs/CONVENTIONS.md (Bending): the
    bar bends with the load u = -f, phi = C_r,i (u_i x u) in the body frame); None for an IMU on the body, on a
    rigid camera, or none."""
    imu = getattr(rig, "imu", None)
    if imu is None or imu.mount == "body" or not mount_ringing_hz(rig):
        return None
    from ..core.dynamics import bar_damping_ratios

    i = rig.camera_index(imu.mount)
    to_body = rig.rotations[i] @ np.asarray(imu.rotation, float)  # IMU -> body, unbent
    K = -to_body.T @ np.asarray(rig.bar_derivatives[1][i], float) @ to_body
    return MountBar(float(bar_damping_ratios(rig)[i]), K if np.isfinite(K).all() and np.any(K) else None)


def static_bend(compliance: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """The mount's rotation vectors (n, 3) at rest under the mean specific forces ``accel`` (n, 3) its IMU reads
    (IMU frame): psi = K exp(psi) f, the load measured in the bent frame (:data:`STATIC_BEND_STEPS` steps)."""
    f = np.asarray(accel, float).reshape(-1, 3)
    psi = np.zeros_like(f)
    for _ in range(STATIC_BEND_STEPS):
        psi = np.einsum("ij,nj->ni", compliance, np.einsum("nij,nj->ni", exp_so3(psi), f))
    return psi


def mount_ringing_hz(rig) -> float:
    """The natural frequency (Hz) of the flexible bar the rig file mounts the IMU on (inside that bar's camera),
    or 0 for an IMU on the body, on a rigid camera, or none."""
    imu = getattr(rig, "imu", None)
    if imu is None or imu.mount == "body":
        return 0.0
    from ..core.dynamics import bar_natural_frequencies

    f = float(bar_natural_frequencies(rig)[rig.camera_index(imu.mount)])
    return f if math.isfinite(f) and f > 0 else 0.0


class MountTurn:
    """The windows of the stillness test on a ringing mount, with the mount's rotation the gyro saw.

    A mount that turns by phi reads gravity turned by -phi: to first order an oscillation like the rest (which
    the fit takes out), but to second order 1/2 phi x (phi x g), a constant and a second harmonic that no fit
    at the ringing's frequency takes out; at tenths of a radian several times an accelerometer's noise, for a
    second after a large stop. Its gyro reads the rate J_r(phi) phi' = phi' - 1/2 phi x phi' + ..., whose second
    term is a second harmonic too where the tip's swing is not in one plane. :meth:`accel_moments` turns the
    accelerometer's samples back by the turn, :meth:`gyro_moments` turns the rates into phi' (J_r(phi)^-1 w): what
    remains is an oscillation at the mount's frequency (the tip's own acceleration, its bending rate).

    The gyro's turn is relative: it starts from wherever the mount was. A soft bar's mount rests bent by tenths
    of a radian under the load (its static bend psi_s), and the rate of a swing r about that bend reads
    J_r(psi_s + r) r': the products of psi_s with r are a second harmonic too, several times a gyro's noise on a
    swing of tens of degrees per second. With the bar's compliance (:func:`mount_bar`) and the
    accelerometer's samples, each block's static bend comes from its mean specific force (:func:`static_bend`)
    and the swing is taken about it: psi = psi_s + J_r(psi_s)^-1 phi (phi the turn from the block's reference;
    to first order the swing the turn integrates).

    Each window is turned about one reference, the mount's mean turn over the period around its block
    (windows grouped by their centre, one period per block): a reference that differs from a window's own
    mean by a constant only adds terms linear in the ringing, which the fit takes out, and keeps the turns
    small. The blocks' samples are laid end to end (each window within its block's) so that one pass of
    cumulative sums serves all windows."""

    def __init__(self, t: np.ndarray, gyro: np.ndarray, gyro_bias, i0: np.ndarray, i1: np.ndarray,
                 frequency_hz: float, accel: np.ndarray | None = None, bar: MountBar | None = None):
        t = np.asarray(t, float)
        i0, i1 = np.asarray(i0, np.int64), np.asarray(i1, np.int64)
        self.t, self.frequency_hz, self.bias = t, float(frequency_hz), np.asarray(gyro_bias, float).reshape(3)
        self.damping = bar.damping if bar is not None else 0.0
        compliance = bar.compliance if bar is not None else None
        period = 1.0 / frequency_hz
        turn = mount_turn(t, gyro, self.bias)
        n = len(t)
        centre = 0.5 * (t[np.clip(i0, 0, n - 1)] + t[np.clip(i1 - 1, 0, n - 1)]) if n else np.zeros(len(i0))
        # blocks on the clock's own grid: a stretch of samples is tested alike whatever came before it
        blocks, block_of = np.unique(np.floor(centre / period).astype(np.int64), return_inverse=True)
        lo = np.minimum(np.searchsorted(t, blocks * period, side="left"), max(n - 1, 0))
        hi = np.minimum(np.maximum(np.searchsorted(t, (blocks + 1) * period, side="left"), lo + 1), n)
        cum = np.zeros((n + 1, 3))
        np.cumsum(turn, axis=0, out=cum[1:])
        reference = (cum[hi] - cum[lo]) / np.maximum(hi - lo, 1)[:, None]
        # per block J_r(psi_s)^-1 and psi_s: the swing phi about the block's reference is psi_s + J_r(psi_s)^-1 phi
        to_swing, rest = np.broadcast_to(np.eye(3), (len(blocks), 3, 3)), np.zeros((len(blocks), 3))
        if compliance is not None and accel is not None and n:
            np.cumsum(np.asarray(accel, float), axis=0, out=cum[1:])
            rest = static_bend(compliance, (cum[hi] - cum[lo]) / np.maximum(hi - lo, 1)[:, None])
            to_swing = np.linalg.inv(right_jacobian(rest))
        start = np.full(len(blocks), np.iinfo(np.int64).max)
        end = np.zeros(len(blocks), np.int64)
        np.minimum.at(start, block_of, i0)
        np.maximum.at(end, block_of, i1)
        length = np.maximum(end - start, 0)
        offset = np.concatenate([[0], np.cumsum(length)])
        self.index = np.arange(offset[-1]) - np.repeat(offset[:-1] - start, length)  # the blocks' samples
        of_sample = np.repeat(np.arange(len(blocks)), length)
        self.turn = turn[self.index] - reference[of_sample]
        self.swing = rest[of_sample] + np.einsum("nij,nj->ni", to_swing[of_sample], self.turn)
        moved = offset[:-1][block_of] - start[block_of]
        self.i0, self.i1 = i0 + moved, i1 + moved

    def accel_moments(self, accel: np.ndarray, shift: np.ndarray):
        """:func:`ringing_moments` of the accelerometer's samples turned back by the mount's turn."""
        x = turned_back(np.asarray(accel, float)[self.index], self.turn)
        return ringing_moments(x, self.t[self.index], self.i0, self.i1, shift, self.frequency_hz, self.damping)

    def gyro_moments(self, gyro: np.ndarray):
        """:func:`ringing_moments` of the gyro's rates less their bias turned into the swing's rate
        (J_r(psi)^-1 w), about the bias."""
        rate = np.asarray(gyro, float)[self.index] - self.bias
        x = np.linalg.solve(right_jacobian(self.swing), rate[:, :, None])[:, :, 0] + self.bias
        return ringing_moments(x, self.t[self.index], self.i0, self.i1, self.bias, self.frequency_hz, self.damping)


def mean_under_ringing(t, x, frequency_hz: float, gyro=None, keep=None, damping: float = 0.0) -> tuple:
    """(constant (3,), its std per axis, the samples' per-axis std about the model) of samples x (n, 3) at
    stamps t (n,) on a mount ringing at ``frequency_hz`` (:func:`ringing_moments` over the whole span). Without
    ringing (``frequency_hz`` 0) the plain mean, std over the root of n. Where the samples span less than one
    period (or are too few to fit it) the oscillation stays in the mean, which may then be off by as much as
    the oscillation's own size: the samples' spread is the mean's std (graded, not refused). With the gyro's
    samples ``gyro`` (n, 3) the accelerometer's are first turned back by the mount's turn about the swing's
    centre (:class:`MountTurn`; the centre and the gyro's bias are the constants of their own ringing fits): the
    constant is then the reading at the mount's rest. ``keep`` (n,)
    selects the samples that enter the fit (the still ones); the turn is integrated over all. ``damping``: the
    bar's damping ratio, at which every fit's oscillation decays (:func:`ringing_moments`)."""
    t = np.asarray(t, dtype=float).reshape(-1)
    x = np.asarray(x, dtype=float).reshape(-1, 3)
    w = None if gyro is None else np.asarray(gyro, dtype=float).reshape(-1, 3)
    used = np.ones(len(t), dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    if frequency_hz > 0 and w is not None and np.count_nonzero(used) > 2 * (RINGING_PARAMETERS + 1):
        k = np.count_nonzero(used)
        bias = ringing_moments(w[used], t[used], np.array([0]), np.array([k]), np.median(w[used], axis=0),
                               frequency_hz, damping)[0][0]
        turn = mount_turn(t, w, bias)
        rest = ringing_moments(turn[used], t[used], np.array([0]), np.array([k]), np.median(turn[used], axis=0),
                               frequency_hz, damping)[0][0]  # the swing's centre, not its mean over a decaying span
        x = turned_back(x, turn - rest)
    if keep is not None:
        t, x = t[keep], x[keep]
    n = len(t)
    spread = float(np.sqrt(np.mean(np.var(x, axis=0))))
    if not frequency_hz > 0:
        return x.mean(axis=0), spread / math.sqrt(max(n, 1)), spread
    if n <= 2 * (RINGING_PARAMETERS + 1) or t[-1] - t[0] < 1.0 / frequency_hz:
        return x.mean(axis=0), math.hypot(spread, spread / math.sqrt(max(n, 1))), spread
    mean, ss, _ = ringing_moments(x, t, np.array([0]), np.array([n]), np.median(x, axis=0), frequency_hz, damping)
    resid = float(math.sqrt(ss[0] / (3 * (n - 1 - RINGING_PARAMETERS))))
    return mean[0], resid / math.sqrt(n - 1 - RINGING_PARAMETERS), resid


__all__ = ["MountBar", "MountTurn", "RINGING_PARAMETERS", "mean_under_ringing", "mount_bar", "mount_ringing_hz",
           "mount_turn", "ringing_moments", "static_bend", "turned_back"]
