import math

import numpy as np

from nrmpc_ros.core.fusion import GravityFusion, roll_pitch_from_gravity, sphere_exp, sphere_log
from nrmpc_ros.core.so3 import angle_between, exp_so3, normalize, tangent_basis


def _noisy(rng, g, sigma):
    B = tangent_basis(normalize(g))
    d = normalize(g) + B @ rng.normal(scale=sigma, size=2)
    cov = 9.81**2 * sigma**2 * (B @ B.T)
    return 9.81 * normalize(d), cov


def test_sphere_chart_round_trip(rng):
    m = normalize(rng.normal(size=3))
    d = rng.normal(scale=0.3, size=2)
    assert np.allclose(sphere_log(m, sphere_exp(m, d)), d)


def test_fusion_through_rotating_frames_beats_single_estimates():
    rng = np.random.default_rng(0)
    g_world = np.array([0.0, 0.0, -9.81])
    R_wb = np.eye(3)  # orientation of the body in the world
    f = GravityFusion(process_sigma_rad=1e-4)
    raw, fused = [], []
    for k in range(40):
        R_delta = exp_so3(rng.normal(scale=0.2, size=3))  # new body in old body
        R_wb = R_wb @ R_delta
        f.propagate(R_delta, cov_rotation=np.eye(3) * 1e-8)
        g_true = R_wb.T @ g_world
        sigma = 0.01
        g_meas, cov = _noisy(rng, g_true, sigma)
        if k == 20:  # a gross outlier is rejected
            assert not f.update(-g_meas, cov)
        assert f.update(g_meas, cov)
        raw.append(angle_between(g_meas, g_true))
        fused.append(angle_between(f.state.gravity, g_true))
    assert np.median(fused[10:]) < 0.5 * np.median(raw[10:])
    assert f.state.num_rejected == 1 and f.state.num_fused == 40
    assert f.state.sigma_rad < 0.01 / math.sqrt(10)


def test_challenger_with_more_support_takes_over():
    """Rejected estimates build a challenger; it replaces the state once it has more support, even when the
    state keeps accepting some (interleaved wrong estimates, as from sign-ambiguous pairs)."""
    cov = np.eye(3) * 1e-6
    down, side = np.array([0, 0, -9.81]), np.array([0, 9.81, 0])
    f = GravityFusion(max_rejections=10)
    assert f.update(down, cov)  # a wrong first estimate
    assert not f.update(side, cov)  # challenger: 1 vs 1
    assert f.update(down, cov)  # the state: 2
    assert not f.update(side, cov)  # challenger: 2 vs 2
    assert f.update(side, cov)  # challenger: 3 > 2, takes over
    assert np.allclose(f.state.gravity, side) and f.state.num_fused == 3
    assert not f.update(down, cov)


def test_fusion_restarts_after_repeated_rejections():
    """max_rejections mutually inconsistent rejections in a row: the most precise of them takes over."""
    f = GravityFusion(max_rejections=3)
    cov = np.eye(3) * 1e-6
    f.update(np.array([0, 0, -9.81]), cov)
    f.update(np.array([0, 0, -9.81]), cov)
    assert not f.update(np.array([0, 9.81, 0]), cov)
    assert not f.update(np.array([9.81, 0, 0]), cov)
    assert f.update(np.array([0, -9.81, 0]), 0.5 * cov)  # third in a row: the state was wrong, restart
    assert np.allclose(f.state.gravity, [0, -9.81, 0]) and f.state.num_fused == 1
    for _ in range(2):  # the old state, kept as a challenger, comes back with more support
        f.update(np.array([0, 0, -9.81]), cov)
    assert np.allclose(f.state.gravity, [0, 0, -9.81]) and f.state.num_fused == 4


def test_roll_pitch():
    r, p, q, cov = roll_pitch_from_gravity(np.array([0, 0, -9.81]), np.eye(2) * 1e-4)
    assert abs(r) < 1e-12 and abs(p) < 1e-12 and np.allclose(q, [0, 0, 0, 1])
    assert np.allclose(np.diag(cov), 1e-4, rtol=1e-3)
    # body pitched nose-up by 0.2 rad: gravity in the body gains a -x component... and roll 0
    R_wb = exp_so3(np.array([0.0, -0.2, 0.0]))
    g_body = R_wb.T @ np.array([0, 0, -9.81])
    r, p, q, _ = roll_pitch_from_gravity(g_body)
    assert abs(r) < 1e-12 and math.isclose(abs(p), 0.2, rel_tol=1e-9)


def test_agrees_and_carried_change_nothing():
    rng = np.random.default_rng(3)
    f = GravityFusion()
    cov = np.eye(3) * 1e-4
    for _ in range(3):
        f.update(np.array([0.0, 0.0, -9.81]) + rng.normal(scale=0.01, size=3), cov)
    before = (f.state.gravity.copy(), f.state.cov_tangent.copy(), f.state.num_fused, f.state.num_rejected)
    R_delta = exp_so3(np.array([0.3, -0.1, 0.2]))
    carried = f.carried(R_delta, np.eye(3) * 1e-6)
    g_new = R_delta.T @ np.array([0.0, 0.0, -9.81])
    assert angle_between(carried.gravity, g_new) < 0.01
    assert f.agrees(g_new, cov, R_delta) and not f.agrees(-g_new, cov, R_delta)
    assert not f.agrees(g_new, cov)  # not carried: the old frame's gravity is ~20 deg away
    after = (f.state.gravity, f.state.cov_tangent, f.state.num_fused, f.state.num_rejected)
    assert all(np.array_equal(a, b) for a, b in zip(before, after))
    f.propagate(R_delta, np.eye(3) * 1e-6)  # what carried() predicted
    assert np.allclose(f.state.gravity, carried.gravity) and np.allclose(f.state.cov_tangent, carried.cov_tangent)


def test_takeover_by_another_challenger_leaves_the_estimate_out():
    """The rejection that ends a run of max_rejections hands the state to the best challenger; an estimate
    that is not part of that challenger is still reported as rejected."""
    cov = np.eye(3) * 1e-6
    f = GravityFusion(max_rejections=3)
    f.update(np.array([0, 0, -9.81]), cov)
    assert not f.update(np.array([0, 9.81, 0]), 0.1 * cov)  # the most precise challenger
    assert not f.update(np.array([9.81, 0, 0]), cov)
    assert not f.update(np.array([-9.81, 0, 0]), cov)  # third in a row: the precise challenger takes over
    assert np.allclose(f.state.gravity, [0, 9.81, 0])
