"""The vectorised first-order linear recursion against its definition, restarts and long decays included."""

import numpy as np

from nrmpc_ros.core.recursion import linear_recursion


def test_the_vectorised_recursion_is_the_step_by_step_one():
    rng = np.random.default_rng(3)
    K, M = 400, 2
    P = np.exp(-0.2 + 1j * rng.uniform(0.1, 0.5, (K, M)))  # decays fast enough to need several blocks
    D = rng.normal(size=(K, M, 3)) + 1j * rng.normal(size=(K, M, 3))
    rest = rng.normal(size=(K, M, 3)).astype(complex)
    fresh = np.zeros(K, bool)
    fresh[[0, 123, 124, 300]] = True
    C_prev = np.zeros((M, 3), complex)
    out = linear_recursion(P, D, rest, fresh, C_prev, np.full(K, 0.2))
    C = C_prev
    for k in range(K):
        C = rest[k] if fresh[k] else P[k][:, None] * C + D[k]
        assert np.allclose(out[k], C, rtol=1e-9, atol=1e-12)
