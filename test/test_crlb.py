"""The bound of a sequence's joint gravity from its observed tracks at the true geometry
(:func:`nrmpc_ros.experiments.crlb.observed_sequence_bound`): against the bound at the true landmarks, its
scaling with the landmarks and the noise, and a seeded Monte Carlo of the adjustment."""

import math

import numpy as np
import pytest

from nrmpc_ros.core.bundle import GravityPriors, Observations, adjust_bundle
from nrmpc_ros.core.so3 import angle_between, normalize, tangent_basis
from nrmpc_ros.experiments.crlb import observed_sequence_bound, sequence_bound
from nrmpc_ros.sim.sequence import SequenceScenario, make_sequence
from nrmpc_ros.sim.synthetic import RigSpec

RIG = RigSpec(num_cameras=3, layout="ring", EI=0.5)


def _problem(pixel_noise=0.1, outliers=0.0, views=4, tracks=60, seed=1):
    sc = SequenceScenario(rig=RIG, num_views=views, tracks_per_camera=tracks, pixel_noise=pixel_noise,
                          outlier_fraction=outliers, gravity_noise_deg=0.0)
    return make_sequence(sc, seed), sc


def _obs(p, scale=None):
    tr = p.tracks
    return Observations.from_arrays(tr.view, tr.cam, tr.track, tr.f, tr.num_views, scale)[0]


def test_tracks_at_the_truth_give_the_bound_of_the_true_landmarks_and_mismatches_carry_nothing():
    p, sc = _problem(pixel_noise=0.05, outliers=0.1)
    sigma = sc.pixel_noise / p.rig.cameras[0].focal_px
    want = sequence_bound(p, sigma).median_angles()
    got = observed_sequence_bound(p.rig, _obs(p), p.R, p.t, p.gravity[0], sigma, outlier_rad=20 * sigma)
    inl = _obs(p).subset(p.inlier_mask)[0]
    views = np.zeros((inl.num_points, inl.num_views), bool)
    views[inl.point, inl.view] = True
    # a landmark whose mismatch pulled its triangulation off may lose an inlier with it
    assert got.observations == pytest.approx(np.count_nonzero(views.sum(axis=1)[inl.point] >= 2), rel=0.02)
    np.testing.assert_allclose(got.median_angles(), want, rtol=0.03)
    # the bearings' error at the truth is their noise (per axis, three dof per landmark used up)
    dof = 2 * got.observations - 3 * got.landmarks
    assert math.sqrt(np.sum(got.residual_rad**2) / dof) == pytest.approx(sigma, rel=0.1)
    assert np.all(p.inlier_mask[got.used])
    # the outliers kept in: the same tracks give a different (wrong) bound
    kept = observed_sequence_bound(p.rig, _obs(p), p.R, p.t, p.gravity[0], sigma)
    assert kept.observations == len(p.tracks.view)


def test_bound_falls_as_one_over_the_root_of_the_landmarks_and_rises_with_the_noise():
    p, sc = _problem(pixel_noise=0.0, tracks=80)
    sigma = 0.1 / p.rig.cameras[0].focal_px
    obs = _obs(p)
    full = observed_sequence_bound(p.rig, obs, p.R, p.t, p.gravity[0], sigma).median_angles()
    # every landmark seen twice over: exactly twice the information
    twice = Observations(np.tile(obs.view, 2), np.tile(obs.cam, 2), np.r_[obs.point, obs.point + obs.num_points],
                         np.tile(obs.f, (2, 1)), obs.num_views, 2 * obs.num_points)
    b2 = observed_sequence_bound(p.rig, twice, p.R, p.t, p.gravity[0], sigma).median_angles()
    np.testing.assert_allclose(b2, full / math.sqrt(2), rtol=1e-6)
    # a random half of the landmarks: sqrt(2) larger, up to how informative the dropped half was
    rng = np.random.default_rng(3)
    half = rng.random(obs.num_points) < 0.5
    sub, _ = obs.subset(half[obs.point])
    bh = observed_sequence_bound(p.rig, sub, p.R, p.t, p.gravity[0], sigma).median_angles()
    assert np.median(bh / full) == pytest.approx(math.sqrt(2), rel=0.2)
    # the noise per observation: all twice as noisy is twice the bound
    scaled = Observations(obs.view, obs.cam, obs.point, obs.f, obs.num_views, obs.num_points, None,
                          np.full(len(obs), 2.0))
    bs = observed_sequence_bound(p.rig, scaled, p.R, p.t, p.gravity[0], sigma).median_angles()
    np.testing.assert_allclose(bs, 2 * full, rtol=1e-6)


def test_measured_gravity_lowers_the_bound_to_at_most_its_own_std():
    p, _ = _problem(pixel_noise=0.0)
    sigma = 0.3 / p.rig.cameras[0].focal_px
    obs = _obs(p)
    vision = observed_sequence_bound(p.rig, obs, p.R, p.t, p.gravity[0], sigma).median_angles()
    prior_sigma = math.radians(0.2)
    for bias in (None, math.radians(1.0)):
        pr = GravityPriors(p.gravity, prior_sigma, bias)
        fused = observed_sequence_bound(p.rig, obs, p.R, p.t, p.gravity[0], sigma, priors=pr).median_angles()
        assert np.all(fused < vision)
        # median angle of a 2-D Gaussian of std s per axis: s sqrt(2 ln 2)
        assert np.all(fused < prior_sigma * math.sqrt(2 * math.log(2)))


def test_the_adjustment_from_the_truth_reaches_the_bound():
    """Seeded Monte Carlo on one small sequence: the RMS gravity error of the adjustment started at the truth
    over 40 noise draws is within 20 % of the RMS bound, for the origin and the last view."""
    p, _ = _problem(pixel_noise=0.0, views=3, tracks=40, seed=2)
    focal = p.rig.cameras[0].focal_px
    sigma = 0.5 / focal
    obs = _obs(p)
    b = observed_sequence_bound(p.rig, obs, p.R, p.t, p.gravity[0], sigma)
    rms_bound = np.sqrt([np.trace(c) for c in b.gravity])
    rng = np.random.default_rng(7)
    T = tangent_basis(obs.f)  # (N, 3, 2)
    errors = []
    for _ in range(40):
        f = normalize(obs.f + sigma * np.einsum("nij,nj->ni", T, rng.standard_normal((len(obs), 2))))
        noisy = Observations(obs.view, obs.cam, obs.point, f, obs.num_views, obs.num_points)
        res = adjust_bundle(p.rig, noisy, p.R, p.t, p.gravity[0], sigma_rad=sigma, huber_k=1e6, max_iterations=20)
        g = res.state.view_gravity
        errors.append([angle_between(g[k], p.gravity[k]) for k in range(len(p.R))])
    rms_err = np.sqrt(np.mean(np.square(errors), axis=0))
    ratio = rms_err / rms_bound
    assert np.all(np.abs(ratio - 1.0) < 0.2), ratio
