import numpy as np

from nrmpc_ros.core.bundle import GravityPrior, TwoViewProblem, inv3, refine_two_view
from nrmpc_ros.core.deformation import deformed_extrinsics
from nrmpc_ros.core.so3 import angle_between, exp_so3, rotation_angle
from nrmpc_ros.sim.synthetic import Scenario, make_problem


def _perturbed_start(pb, rng, rot=0.01, tra=0.01, grav=0.2):
    R = pb.R @ exp_so3(rng.normal(size=3) * rot)
    t = pb.t + tra * rng.normal(size=3)
    g = pb.gravity + grav * 9.81 * rng.normal(size=3)
    return R, t, 9.81 * g / np.linalg.norm(g)


def test_jacobians_match_finite_differences(rng):
    pb = make_problem(Scenario(num_points=60, outlier_fraction=0), seed=3)
    m = pb.matches
    prob = TwoViewProblem(pb.rig, m.f1, m.f2, m.cam, True, GravityPrior(pb.gravity, pb.R.T @ pb.gravity, 0.01))
    R, t, g = _perturbed_start(pb, rng)
    P = pb.points + 0.01 * rng.normal(size=pb.points.shape)
    e, Jc, Jp = prob.evaluate(R, t, g, P)
    eps = 1e-7
    for k in range(8):
        dc = np.zeros(8)
        dc[k] = eps
        e2, _, _ = prob.evaluate(*prob.update(R, t, g, dc), P, want_jacobian=False)
        assert np.abs((e2 - e) / eps - Jc[:, :, k]).max() < 1e-5 * max(1.0, np.abs(Jc[:, :, k]).max())
    for k in range(3):
        dP = np.zeros_like(P)
        dP[:, k] = eps
        e2, _, _ = prob.evaluate(R, t, g, P + dP, want_jacobian=False)
        assert np.abs((e2 - e) / eps - Jp[:, :, k]).max() < 1e-5
    r, J = prob.prior_terms(R, g)
    for k in range(8):
        dc = np.zeros(8)
        dc[k] = eps
        R2, _, g2 = prob.update(R, t, g, dc)
        r2, _ = prob.prior_terms(R2, g2)
        assert np.abs((r2 - r) / eps - J[:, k]).max() < 1e-3 * max(1.0, np.abs(J[:, k]).max())


def test_inverse_depth_chart(rng):
    """dP/dq of the chart matches finite differences, a zero step keeps the points, points behind stay Euclidean."""
    pb = make_problem(Scenario(num_points=50, outlier_fraction=0), seed=4)
    m = pb.matches
    prob = TwoViewProblem(pb.rig, m.f1, m.f2, m.cam, True)
    P = pb.points.copy()
    w, W = deformed_extrinsics(pb.rig, pb.gravity)
    P[:5] = 2 * w[m.cam[:5]] - P[:5]  # mirrored through the camera centre: behind it
    chart = prob.point_chart(pb.gravity, P)
    assert not chart.front[:5].any() and chart.front[5:].all()
    assert np.allclose(chart.retract(np.zeros_like(P)), P, atol=1e-9)
    eps = 1e-7
    for k in range(3):
        dq = np.zeros_like(P)
        dq[:, k] = eps
        num = (chart.retract(dq) - chart.retract(-dq)) / (2 * eps)
        assert np.allclose(num, chart.M[:, :, k], rtol=1e-5, atol=1e-6 * np.abs(chart.M).max())
    far = chart.retract(np.tile([0.0, 0.0, -10.0], (len(P), 1)))  # rho would turn negative: at most 100x farther
    d_old = np.linalg.norm(P - w[m.cam], axis=1)
    d_new = np.linalg.norm(far - w[m.cam], axis=1)
    assert np.all(d_new[5:] <= 100.0 * d_old[5:] * (1 + 1e-9) + 1e-9) and np.all(np.isfinite(far))


def test_noise_free_refinement_is_exact(rng):
    pb = make_problem(Scenario(pixel_noise=0, outlier_fraction=0), seed=1)
    m = pb.matches
    R, t, g = _perturbed_start(pb, rng)
    res = refine_two_view(pb.rig, m.f1, m.f2, m.cam, R, t, g)
    assert rotation_angle(res.R.T @ pb.R) < 1e-9
    assert np.linalg.norm(res.t - pb.t) < 1e-8
    assert angle_between(res.g, pb.gravity) < 1e-9
    assert np.isclose(np.linalg.norm(res.g), 9.81)


def test_covariance_predicts_the_gravity_error():
    """Over seeded noisy problems the normalised gravity error follows the reported covariance."""
    z = []
    for seed in range(12):
        pb = make_problem(Scenario(pixel_noise=0.5, outlier_fraction=0), seed=seed)
        m = pb.matches
        res = refine_two_view(pb.rig, m.f1, m.f2, m.cam, pb.R, pb.t, pb.gravity)
        sigma = np.sqrt(np.trace(res.covariance[6:8, 6:8]) / 2)
        z.append(angle_between(res.g, pb.gravity) / sigma)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.6 < rms < 1.8, rms  # Rayleigh-distributed 2D error: RMS of |e|/sigma is sqrt(2)


def test_huber_limits_a_gross_outlier(rng):
    pb = make_problem(Scenario(pixel_noise=0.1, outlier_fraction=0), seed=2)
    m = pb.matches
    f2 = m.f2.copy()
    f2[:5] = np.roll(f2[:5], 1, axis=0)  # five wrong correspondences left in
    res = refine_two_view(pb.rig, m.f1, f2, m.cam, pb.R, pb.t, pb.gravity)
    assert rotation_angle(res.R.T @ pb.R) < 1e-3


def test_inv3(rng):
    J = rng.normal(size=(20, 4, 3))
    A = np.swapaxes(J, 1, 2) @ J  # symmetric, as the normal-equation blocks
    assert np.allclose(inv3(A), np.linalg.inv(A))
    singular = np.zeros((1, 3, 3))
    singular[0, 0, 0] = 1.0
    assert np.all(np.isfinite(inv3(singular)))
