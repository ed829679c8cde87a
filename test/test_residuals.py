import numpy as np

from nrmpc_ros.core import generalized_epipolar_residuals, plucker_lines, rays, two_view_angular_errors
from nrmpc_ros.core.residuals import triangulate_midpoint
from nrmpc_ros.sim.synthetic import Scenario, make_problem


def _noise_free(seed=0):
    return make_problem(Scenario(pixel_noise=0, outlier_fraction=0.2, gravity_noise_px=0), seed=seed)


def test_generalized_epipolar_constraint_holds_with_bent_lines():
    pb = _noise_free()
    m = pb.matches
    l1 = plucker_lines(pb.rig, m.f1, m.cam, pb.gravity)
    l2 = plucker_lines(pb.rig, m.f2, m.cam, pb.R.T @ pb.gravity)
    r = generalized_epipolar_residuals(l1, l2, pb.R, pb.t)
    assert np.abs(r[pb.inlier_mask]).max() < 1e-12
    assert np.median(np.abs(r[~pb.inlier_mask])) > 1e-3
    # with canonical lines the constraint is visibly violated (EI = 0.1 bends a lot)
    l1c = plucker_lines(pb.rig, m.f1, m.cam, None)
    l2c = plucker_lines(pb.rig, m.f2, m.cam, None)
    assert np.median(np.abs(generalized_epipolar_residuals(l1c, l2c, pb.R, pb.t)[pb.inlier_mask])) > 1e-3


def test_triangulation_and_angular_errors():
    pb = _noise_free(1)
    m = pb.matches
    o1, d1 = rays(pb.rig, m.f1, m.cam, pb.gravity)
    o2, d2 = rays(pb.rig, m.f2, m.cam, pb.R.T @ pb.gravity)
    P, s, u, par = triangulate_midpoint(o1, d1, o2, d2, pb.R, pb.t)
    inl = pb.inlier_mask
    assert np.abs(P[inl] - pb.points[inl]).max() < 1e-8
    err = two_view_angular_errors(o1, d1, o2, d2, pb.R, pb.t)
    assert err[inl].max() < 1e-9 and np.median(err[~inl]) > 0.05
    # batched over hypotheses: the same numbers for the same pose
    Rb = np.stack([pb.R, np.eye(3)])
    tb = np.stack([pb.t, np.zeros(3)])
    eb = two_view_angular_errors(o1, d1, o2, d2, Rb, tb)
    assert eb.shape == (2, len(m)) and np.allclose(eb[0], err)


def test_points_behind_get_the_error_at_infinity():
    o1 = np.zeros((1, 3))
    d1 = np.array([[0.0, 0.0, 1.0]])
    o2 = np.zeros((1, 3))
    d2 = np.array([[0.0, 0.01, -1.0]])
    d2 /= np.linalg.norm(d2)
    err = two_view_angular_errors(o1, d1, o2, d2, np.eye(3), np.array([0.0, 0.0, 1.0]))
    assert err[0] > 1.5  # the rays point away from each other
