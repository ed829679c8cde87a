"""PoseLib's minimal solvers behind our conventions (docs/CONVENTIONS.md (Frames): p1 = R p2 + t)."""

import numpy as np

from nrmpc_ros.core.minimal import UprightFrames, solve_6pt
from nrmpc_ros.core.so3 import exp_so3, normalize, rotation_angle


def _random_rays(rng, R, t, n):
    o1 = rng.normal(scale=0.5, size=(n, 3))
    P = rng.normal(size=(n, 3)) * 2 + rng.choice([-6, 6], size=(n, 1)) * normalize(rng.normal(size=(n, 3)))
    d1 = normalize(P - o1)
    o2 = rng.normal(scale=0.5, size=(n, 3))
    P2 = (P - t) @ R  # R^T (P - t)
    return o1, d1, o2, normalize(P2 - o2)


def _best_error(sols, R, t):
    if not sols:
        return np.inf
    return min(max(rotation_angle(Rs.T @ R), np.linalg.norm(ts - t)) for Rs, ts in sols)


def test_six_point_noise_free_recovery_rate():
    rng = np.random.default_rng(7)
    errs = []
    for _ in range(200):
        R = exp_so3(rng.normal(scale=0.5, size=3))
        t = rng.normal(size=3)
        errs.append(_best_error(solve_6pt(*_random_rays(rng, R, t, 6)), R, t))
    errs = np.array(errs)
    failure_rate = float(np.mean(errs > 1e-8))
    print(f"gen_relpose_6pt numerical failure rate (error > 1e-8): {failure_rate:.3f}")
    assert failure_rate <= 0.05


def test_upright_four_point_in_gravity_aligned_frames():
    rng = np.random.default_rng(8)
    errs = []
    for _ in range(200):
        R = exp_so3(rng.normal(scale=0.5, size=3))
        t = rng.normal(size=3)
        g1 = 9.81 * normalize(rng.normal(size=3))
        g2 = R.T @ g1
        frames = UprightFrames(g1, g2)
        assert np.allclose(frames.A1 @ normalize(g1), [0, 1, 0]) and np.allclose(frames.A2 @ normalize(g2), [0, 1, 0])
        errs.append(_best_error(frames.solve(*_random_rays(rng, R, t, 4)), R, t))
    errs = np.array(errs)
    print(f"gen_relpose_upright_4pt: error > 1e-8 in {np.mean(errs > 1e-8):.3f}, > 1e-6 in {np.mean(errs > 1e-6):.3f}"
          f" of samples; 95th percentile {np.percentile(errs, 95):.1e}")
    # The upright solver's polynomial is less well conditioned than the 6-point one: ~1e-8 for most samples,
    # a few 1e-7 .. 1e-6 (the bundle adjustment removes that); real failures (> 1e-6) stay rare.
    assert np.mean(errs > 1e-6) <= 0.05
    assert np.median(errs) < 1e-9
