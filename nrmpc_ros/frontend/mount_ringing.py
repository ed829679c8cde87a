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

import numpy as np

RINGING_PARAMETERS = 4  # per axis: cos, sin, tau cos, tau sin of the mount's ringing


def ringing_moments(x: np.ndarray, t: np.ndarray, i0: np.ndarray, i1: np.ndarray, shift: np.ndarray,
                    frequency_hz: float):
    """Per window [i0, i1) of samples x (n, 3) at stamps t, an oscillation at ``frequency_hz`` whose amplitude
    changes linearly across the window fitted on every axis with the constant: (the fitted constant (W, 3), the
    residual sum of squares with the constant fitted, and without it: about ``shift``). Per window the basis
    is 1, cos u, sin u, v cos u, v sin u, with u the phase and v the phase from the window's centre; its Gram
    matrix and the data's projections are differences of cumulative sums of products with powers of u,
    expanded about the centre. The phase is counted from the start of a chunk of a few windows, so that its
    powers stay small (their cumulative sums exact) whatever the recording's length."""
    x, t = np.asarray(x, float), np.asarray(t, float)
    i0, i1 = np.asarray(i0, np.int64), np.asarray(i1, np.int64)
    W = len(i0)
    mean, ss_const, ss_free = np.zeros((W, 3)), np.zeros(W), np.zeros(W)
    order = np.argsort(i0, kind="stable")
    step = max(4 * int(np.max(i1 - i0, initial=1)), 256)  # windows per chunk
    omega = 2.0 * math.pi * frequency_hz
    for a in range(0, W, step):
        w = order[a:a + step]
        s0, s1 = int(i0[w].min()), int(i1[w].max())
        m, sc, sf = _chunk_moments(x[s0:s1] - shift, omega * (t[s0:s1] - t[s0]), i0[w] - s0, i1[w] - s0)
        mean[w], ss_const[w], ss_free[w] = m + shift, sc, sf
    return mean, ss_const, ss_free


def _chunk_moments(d: np.ndarray, u: np.ndarray, i0: np.ndarray, i1: np.ndarray):
    """:func:`ringing_moments` of samples d (n, 3) about zero at phases u (n,) counted from the chunk's start."""
    N = len(d)
    c, s = np.cos(u), np.sin(u)
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


def mean_under_ringing(t, x, frequency_hz: float) -> tuple:
    """(constant (3,), its std per axis, the samples' per-axis std about the model) of samples x (n, 3) at
    stamps t (n,) on a mount ringing at ``frequency_hz`` (:func:`ringing_moments` over the whole span). Without
    ringing (``frequency_hz`` 0) the plain mean, std over the root of n. Where the samples span less than one
    period (or are too few to fit it) the oscillation stays in the mean, which may then be off by as much as
    the oscillation's own size: the samples' spread is the mean's std (graded, not refused)."""
    t = np.asarray(t, dtype=float).reshape(-1)
    x = np.asarray(x, dtype=float).reshape(-1, 3)
    n = len(t)
    spread = float(np.sqrt(np.mean(np.var(x, axis=0))))
    if not frequency_hz > 0:
        return x.mean(axis=0), spread / math.sqrt(max(n, 1)), spread
    if n <= 2 * (RINGING_PARAMETERS + 1) or t[-1] - t[0] < 1.0 / frequency_hz:
        return x.mean(axis=0), math.hypot(spread, spread / math.sqrt(max(n, 1))), spread
    mean, ss, _ = ringing_moments(x, t, np.array([0]), np.array([n]), np.median(x, axis=0), frequency_hz)
    resid = float(math.sqrt(ss[0] / (3 * (n - 1 - RINGING_PARAMETERS))))
    return mean[0], resid / math.sqrt(n - 1 - RINGING_PARAMETERS), resid


__all__ = ["RINGING_PARAMETERS", "mean_under_ringing", "ringing_moments"]
