"""The first-order linear recursion C_k = P_k C_{k-1} + D_k over a block of samples, vectorised: what the bars'
exact steps (:mod:`.bar_state`) and the tip IMU's low-pass stages (:mod:`.tip_imu`) both are."""

from __future__ import annotations

import numpy as np

RECURSION_DECAY = 10.0  # log of the largest decay within one vectorised block of samples


def linear_recursion(P, D, rest, fresh, C_prev, decay):
    """C_k = P_k C_{k-1} + D_k (C_k = rest_k where ``fresh``), k = 0 .. K-1, vectorised over k.

    Within a block C_k = G_k (C_{a-1} + sum_{j=a..k} D_j / G_j) with G_k = P_a ... P_k; a block ends before its
    ringing decays by more than exp(RECURSION_DECAY) (``decay`` the log-decay per step), so dividing by G_j
    loses at most that factor of the precision (1e-12 of the amplitude).
    """
    C = np.empty_like(D)
    K, a = len(D), 0
    while a < K:
        if fresh[a]:
            C_prev = C[a] = rest[a]
            a += 1
            continue
        b = a + max(1, int(np.searchsorted(np.cumsum(decay[a:]), RECURSION_DECAY, side="right")))
        starts = np.flatnonzero(fresh[a:b])
        b = a + starts[0] if starts.size else b
        G = np.cumprod(P[a:b], axis=0)[:, :, None]
        C[a:b] = G * (C_prev[None] + np.cumsum(D[a:b] / G, axis=0))
        C_prev = C[b - 1]
        a = b
    return C


__all__ = ["RECURSION_DECAY", "linear_recursion"]
