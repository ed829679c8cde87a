"""Joint estimation over a sequence (core.sequence.estimate_sequence): exact without noise, robust to outliers,
to a hold that shares few tracks and to pairs in the wrong basin, and clear about what it cannot do."""

import math

import numpy as np
import pytest

from nrmpc_ros.core.bundle import Observations
from nrmpc_ros.core.sequence import broken_link, estimate_sequence
from nrmpc_ros.core.so3 import angle_between, rotation_angle
from nrmpc_ros.core.tracks import Tracks
from nrmpc_ros.errors import EstimationError
from nrmpc_ros.sim.sequence import SequenceScenario, make_sequence
from nrmpc_ros.sim.synthetic import RigSpec

RIGS = {
    "line2": RigSpec(num_cameras=2, layout="line", EI=1.0, mass=0.15, bar_length=0.3),
    "ring3": RigSpec(num_cameras=3, layout="ring", EI=1.3),
    "cross4": RigSpec(EI=1.0),
}


def errors(p, est):
    """Largest rotation error over the views (rad), largest gravity error (rad)."""
    rot = max(rotation_angle(Rt.T @ R) for Rt, R in zip(p.R, est.R))
    grav = max(float(angle_between(gt, g)) for gt, g in zip(p.gravity, est.gravity))
    return rot, grav


@pytest.mark.parametrize("name", list(RIGS))
@pytest.mark.parametrize("method", ["6pt-bending", "4pt-bending"])
def test_noise_free_sequences_are_exact(name, method):
    """Every pose and gravity to 1e-6 rad, two cameras on one straight bar included (single pairs there are
    ambiguous)."""
    sc = SequenceScenario(rig=RIGS[name], num_views=6, pixel_noise=0.0, outlier_fraction=0.0, gravity_noise_deg=0.0)
    p = make_sequence(sc, seed=3)
    est = estimate_sequence(p.rig, p.tracks, method=method, seed=0)
    assert est.success, est.reason
    rot, grav = errors(p, est)
    assert rot < 1e-6 and grav < 1e-6, (rot, grav)
    np.testing.assert_allclose(est.t, p.t, atol=1e-6)


def test_twenty_percent_outliers():
    sc = SequenceScenario(rig=RIGS["cross4"], num_views=8, pixel_noise=0.3, outlier_fraction=0.2)
    p = make_sequence(sc, seed=1)
    est = estimate_sequence(p.rig, p.tracks, method="6pt-bending", seed=0)
    rot, grav = errors(p, est)
    assert est.success and math.degrees(grav) < 0.5 and math.degrees(rot) < 0.1, (rot, grav)
    inl = est.inliers
    # outliers are found; good observations whose track lost its other views to outliers carry nothing
    assert np.mean(inl[~p.inlier_mask]) < 0.02 and np.mean(inl[p.inlier_mask]) > 0.6


def test_a_broken_link_is_found():
    """The link between views 4 and 5 keeps a tenth of its common landmarks: view 5 is named."""
    sc = SequenceScenario(rig=RIGS["cross4"], num_views=8, pixel_noise=0.3, outlier_fraction=0.0)
    tr = make_sequence(sc, seed=4).tracks
    obs, _ = Observations.from_arrays(tr.view, tr.cam, tr.track, tr.f, tr.num_views)
    inl = np.ones(len(obs), bool)
    assert broken_link(obs, inl, 0.5, 12) is None
    common = np.intersect1d(obs.point[obs.view == 4], obs.point[obs.view == 5])
    lost = np.isin(obs.point, common[: int(0.9 * len(common))]) & (obs.view == 5)
    assert broken_link(obs, inl & ~lost, 0.5, 12) == 5


def test_views_misplaced_together_are_put_back():
    """A start whose views 5.. sit 3 deg off together (a pair estimate chained on at 20 % outliers): the
    adjustment alone keeps them so; the broken link is repaired."""
    sc = SequenceScenario(rig=RIGS["cross4"], num_views=8, pixel_noise=0.3, outlier_fraction=0.2)
    p = make_sequence(sc, seed=3)
    est = estimate_sequence(p.rig, p.tracks, method="6pt-bending", seed=0)
    rot, grav = errors(p, est)
    assert est.link_repairs >= 1 and math.degrees(rot) < 0.1 and math.degrees(grav) < 0.5, (rot, grav)


def test_a_hold_that_shares_few_tracks():
    """One view keeps only 15 of its observations per camera: the sequence is still right, that view too."""
    sc = SequenceScenario(rig=RIGS["ring3"], num_views=8, pixel_noise=0.3, outlier_fraction=0.05)
    p = make_sequence(sc, seed=2)
    tr = p.tracks
    rng = np.random.default_rng(0)
    keep = np.ones(len(tr.view), bool)
    for c in range(p.rig.num_cameras):
        idx = np.flatnonzero((tr.view == 4) & (tr.cam == c))
        keep[rng.choice(idx, size=len(idx) - 15, replace=False)] = False
    thin = Tracks(tr.view[keep], tr.cam[keep], tr.track[keep], tr.f[keep], tr.g_meas, num_views=tr.num_views)
    est = estimate_sequence(p.rig, thin, method="6pt-bending", seed=0)
    rot, grav = errors(p, est)
    assert est.success and math.degrees(grav) < 1.0 and math.degrees(rot) < 0.2, (rot, grav)


def test_pairs_in_the_wrong_basin_do_not_capture_the_sequence():
    """Two cameras on one straight bar: single pairs often land in the wrong basin (the bending reversed); the
    joint cost over all holds picks the right one on every seed."""
    sc = SequenceScenario(rig=RIGS["line2"], num_views=10, pixel_noise=0.3, outlier_fraction=0.05)
    for seed in range(4):
        p = make_sequence(sc, seed=seed)
        est = estimate_sequence(p.rig, p.tracks, method="6pt-bending", seed=0)
        _, grav = errors(p, est)
        assert est.success and math.degrees(grav) < 2.0, (seed, math.degrees(grav))
        assert est.candidates >= 2  # the pairs' other basins were compared too


def test_measured_gravity_helps_and_nonbending_has_none():
    sc = SequenceScenario(rig=RIGS["line2"], num_views=8, pixel_noise=0.3, outlier_fraction=0.05,
                          gravity_noise_deg=0.3)
    p = make_sequence(sc, seed=5)
    e4 = estimate_sequence(p.rig, p.tracks, method="4pt-bending", seed=0)
    _, g4 = errors(p, e4)
    assert e4.success and math.degrees(g4) < 0.3  # better than one measurement (0.3 deg per axis)
    rigid = estimate_sequence(p.rig, p.tracks, method="6pt-nonbending", seed=0)
    assert rigid.success and rigid.gravity is None


def test_what_it_cannot_do_is_said():
    sc = SequenceScenario(rig=RIGS["cross4"], num_views=3, gravity_measured=False)
    p = make_sequence(sc, seed=0)
    with pytest.raises(EstimationError, match="4pt-bending needs measured gravity"):
        estimate_sequence(p.rig, p.tracks, method="4pt-bending")
    with pytest.raises(EstimationError, match="unknown method"):
        estimate_sequence(p.rig, p.tracks, method="8pt")
    one = p.tracks.views_subset([0])
    res = estimate_sequence(p.rig, one, method="6pt-bending")
    assert not res.success and "two views" in res.reason
