"""Gravity starts from per-camera rotations (core/gravity_init.py)."""

import numpy as np

from nrmpc_ros.core import deformed_extrinsics
from nrmpc_ros.core.gravity_init import (
    camera_rotations,
    gravity_rotation_hypotheses,
    project_to_so3,
    translation_given_rotation,
)
from nrmpc_ros.core.so3 import angle_between, exp_so3, rotation_angle
from nrmpc_ros.sim.synthetic import Scenario, make_problem


def test_project_to_so3(rng):
    R = exp_so3(rng.normal(size=3))
    P = project_to_so3(R + 1e-3 * rng.normal(size=(3, 3)))
    assert np.allclose(P @ P.T, np.eye(3)) and np.isclose(np.linalg.det(P), 1.0)
    assert rotation_angle(P.T @ R) < 1e-2


def test_project_to_so3_matches_the_svd_projection(rng):
    """Newton's polar iteration agrees with the SVD on means of rotations near and far apart, and on
    matrices it cannot handle (det < 0, singular) the SVD fallback gives the nearest rotation."""
    R = exp_so3(rng.normal(size=(50, 3)))
    for spread in (0.01, 0.5, 2.0):
        A = np.mean([R @ exp_so3(spread * rng.normal(size=(50, 3))) for _ in range(4)], axis=0)
        U, _, Vt = np.linalg.svd(A)
        D = np.ones((50, 3))
        D[:, 2] = np.sign(np.linalg.det(U @ Vt))
        assert np.abs(project_to_so3(A) - (U * D[:, None, :]) @ Vt).max() < 1e-7
    bad = np.stack([np.diag([1.0, 1.0, -1.0]), np.diag([1.0, 0.0, 0.0]), -np.eye(3)])
    P = project_to_so3(bad)
    assert np.allclose(np.swapaxes(P, 1, 2) @ P, np.eye(3)) and np.allclose(np.linalg.det(P), 1.0)
    assert project_to_so3(np.eye(3)).shape == (3, 3)


def test_camera_rotations_are_the_bent_camera_rotations():
    pb = make_problem(Scenario(pixel_noise=0.0, outlier_fraction=0.1), seed=4)
    cams, Rc, counts, inl = camera_rotations(pb.matches, pb.rig.num_cameras, 1e-3)
    _, W1 = deformed_extrinsics(pb.rig, pb.gravity)
    _, W2 = deformed_extrinsics(pb.rig, pb.R.T @ pb.gravity)
    assert len(cams) >= 3
    for j, c in enumerate(cams):
        assert rotation_angle((W1[c].T @ pb.R @ W2[c]).T @ Rc[j]) < 1e-5  # rad: the solver's last fit, not exact
    assert inl[pb.inlier_mask].mean() > 0.9 and inl[~pb.inlier_mask].mean() < 0.1


def test_hypotheses_start_near_the_truth_and_translation_is_linear():
    pb = make_problem(Scenario(pixel_noise=0.0, outlier_fraction=0.0), seed=5)
    cams, Rc, counts, _ = camera_rotations(pb.matches, pb.rig.num_cameras, 1e-3)
    starts = gravity_rotation_hypotheses(pb.rig, cams, Rc, counts, 200, 3)
    g0, R0, cost = starts[0]
    assert angle_between(g0, pb.gravity) < 0.05 and rotation_angle(R0.T @ pb.R) < 0.01
    assert [s[2] for s in starts] == sorted(s[2] for s in starts)
    t = translation_given_rotation(pb.rig, pb.matches, np.arange(len(pb.matches)), pb.R, pb.gravity)
    assert np.allclose(t, pb.t, atol=1e-8)


def test_pose_scores_rank_the_truth_first_on_parallel_bars():
    """On a 2-camera line rig (parallel bars) the full-pose MSAC score puts the true gravity ahead of its
    mirror about the bar axis and of distant directions; batched translations equal the single ones."""
    from nrmpc_ros.core.gravity_init import body_rotation_from_cameras, pose_hypothesis_scores
    from nrmpc_ros.core.so3 import fibonacci_sphere
    from nrmpc_ros.sim.synthetic import RigSpec

    pb = make_problem(Scenario(rig=RigSpec(num_cameras=2, layout="line"), pixel_noise=0.1, outlier_fraction=0.05),
                      seed=7)
    m, rig, g = pb.matches, pb.rig, pb.gravity
    cams, Rc, counts, inl = camera_rotations(m, rig.num_cameras, 1e-3)
    axis = rig.positions[0] / np.linalg.norm(rig.positions[0])
    mirror = g - 2 * (axis @ g) * axis
    far = 9.81 * fibonacci_sphere(50)
    far = far[[angle_between(h, g) > 0.5 and angle_between(h, mirror) > 0.2 for h in far]]
    hyp = np.vstack([g, mirror, far])
    R_h, _ = body_rotation_from_cameras(rig, cams, Rc, counts / counts.sum(), hyp, pb.R)
    idx = np.flatnonzero(inl)
    scores = pose_hypothesis_scores(rig, m, idx, 6.0 / 800.0, hyp, R_h)
    assert scores[0] < scores[1] and scores[0] < scores[2:].min()
    t_single = translation_given_rotation(rig, m, idx, R_h[1], hyp[1])
    from nrmpc_ros.core.deformation import rays
    from nrmpc_ros.core.gravity_init import least_squares_translations
    o1, d1 = rays(rig, m.f1[idx], m.cam[idx], hyp[1])
    o2, d2 = rays(rig, m.f2[idx], m.cam[idx], R_h[1].T @ hyp[1])
    assert np.allclose(least_squares_translations(o1[None], d1[None], o2[None], d2[None], R_h[1:2])[0], t_single)


def test_start_translation_checks_the_sign_of_the_least_squares_translation():
    """On one bar the constraint's moments barely fix the sign of t: with gravity 0.2 rad off the least
    squares flip it (seeds 5 and 7), and of t and -t the start keeps the one whose angular errors fit, near the
    true direction; at the true pose it is the least-squares t and its errors are the noise's."""
    from nrmpc_ros.core.gravity_init import start_translation
    from nrmpc_ros.sim.synthetic import RigSpec

    sc = Scenario(rig=RigSpec(num_cameras=2, layout="line"), pixel_noise=0.1, outlier_fraction=0.0, num_points=300)
    for seed in (5, 7):
        pb = make_problem(sc, seed=seed)
        idx = np.arange(len(pb.matches))
        g = exp_so3(np.array([0.2, 0.0, 0.0])) @ pb.gravity
        t_ls = translation_given_rotation(pb.rig, pb.matches, idx, pb.R, g)
        t, err = start_translation(pb.rig, pb.matches, idx, pb.R, g, 0.025)
        assert angle_between(t_ls, pb.t) > np.pi / 2 and np.allclose(t, -t_ls)
        assert angle_between(t, pb.t) < 0.25 and err.shape == (len(idx),)
        t, err = start_translation(pb.rig, pb.matches, idx, pb.R, pb.gravity, 0.025)
        assert np.allclose(t, translation_given_rotation(pb.rig, pb.matches, idx, pb.R, pb.gravity))
        assert angle_between(t, pb.t) < 1e-2 and np.median(err) < 3 * 0.1 / 800
