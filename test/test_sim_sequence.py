"""Simulated sequences of static views: exact geometry under the bending model, tracks, noise and outliers."""

from dataclasses import replace

import numpy as np
import pytest

from nrmpc_ros.cameras import bearings_to_pixels
from nrmpc_ros.core.deformation import deformed_extrinsics
from nrmpc_ros.core.so3 import angle_between, rotation_angle
from nrmpc_ros.errors import InputError
from nrmpc_ros.sim.sequence import SequenceScenario, make_sequence
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

RIGS = {
    "line2": RigSpec(num_cameras=2, layout="line"),
    "ring3": RigSpec(num_cameras=3, layout="ring"),
    "cross4": RigSpec(),
}


def _clean(**kw):
    return SequenceScenario(pixel_noise=0.0, outlier_fraction=0.0, gravity_noise_deg=0.0, **kw)


def _fisheye_rig():
    """The cross with distorted equidistant (fisheye) cameras of a wider field of view."""
    rig = make_rig(RigSpec())
    cams = tuple(replace(c, model="equidistant", distortion=(0.02, -0.004, 0.001, 0.0),
                         intrinsics=(320.0, 320.0, 319.5, 239.5)) for c in rig.cameras)
    return replace(rig, cameras=cams)


def _reprojection_angles(p):
    """Angle (rad) between each bearing and the truth: landmark -> view k -> bent camera at g_k."""
    tr = p.tracks
    w, W = deformed_extrinsics(p.rig, p.gravity)
    pk = np.einsum("nba,nb->na", p.R[tr.view], p.points[tr.track] - p.t[tr.view])  # R_k^T (P - t_k)
    pc = np.einsum("nba,nb->na", W[tr.view, tr.cam], pk - w[tr.view, tr.cam])
    return angle_between(pc, tr.f), pc


@pytest.mark.parametrize("name", [*RIGS, "fisheye"])
def test_noise_free_bearings_are_exact_under_the_bending_model(name):
    sc = _clean(rig=RIGS.get(name, RigSpec()), num_views=5)
    p = make_sequence(sc, seed=2, rig=_fisheye_rig() if name == "fisheye" else None)
    err, pc = _reprojection_angles(p)
    assert err.max() < 1e-12 and np.all(pc[:, 2] > 0)
    assert p.rig.is_flexible
    # the first observation of each landmark is at a depth along the optical axis in [min_depth, max_depth]
    first = np.unique(p.tracks.track, return_index=True)[1]
    assert np.all((pc[first, 2] > sc.min_depth - 1e-9) & (pc[first, 2] < sc.max_depth + 1e-9))
    # ... and every observation projects inside the image
    for i, cam in enumerate(p.rig.cameras):
        uv = bearings_to_pixels(cam, p.tracks.f[p.tracks.cam == i])
        assert np.all((uv >= -0.5) & (uv < np.array(cam.resolution) - 0.5))


def test_bending_matters():
    """The same sequence seen through the unbent extrinsics misses by far more than the noise-free error."""
    p = make_sequence(_clean(num_views=3), seed=4)
    err, _ = _reprojection_angles(replace(p, rig=p.rig.as_rigid()))
    assert np.median(err) > 1e-3


@pytest.mark.parametrize("name", list(RIGS))
def test_poses_gravity_and_attitude_limits(name):
    sc = SequenceScenario(rig=RIGS[name])
    p = make_sequence(sc, seed=5)
    K = sc.num_views
    assert p.R.shape == (K, 3, 3) and p.t.shape == (K, 3) and p.gravity.shape == (K, 3)
    assert np.array_equal(p.R[0], np.eye(3)) and np.array_equal(p.t[0], np.zeros(3))
    assert np.allclose(np.einsum("kba,kbc->kac", p.R, p.R), np.eye(3), atol=1e-12)
    assert np.allclose(p.gravity, np.einsum("kba,b->ka", p.R, p.gravity[0]), atol=1e-12)  # g_k = R_k^T g_0
    assert np.allclose(np.linalg.norm(p.gravity, axis=1), p.rig.gravity_magnitude)
    step = np.degrees(rotation_angle(np.einsum("kba,kbc->kac", p.R[:-1], p.R[1:])))
    assert np.all((step >= sc.min_step_deg - 1e-9) & (step <= sc.max_step_deg + 1e-9))
    tilt = np.degrees(angle_between(p.gravity, [0.0, 0.0, -1.0]))  # body z from the vertical
    assert np.all((tilt >= sc.min_tilt_deg - 1e-9) & (tilt <= sc.max_tilt_deg + 1e-9))
    # body positions are drawn in a cube of half-size max_translation: offsets from view 0 span at most its diagonal
    assert np.all(np.linalg.norm(p.t, axis=1) <= 2 * sc.max_translation * np.sqrt(3))
    assert np.linalg.norm(p.t[1:], axis=1).min() > 0


@pytest.mark.parametrize("name", list(RIGS))
@pytest.mark.parametrize("seed", [6, 7])
def test_tracks_cover_every_view_and_camera(name, seed):
    sc = SequenceScenario(rig=RIGS[name])
    p = make_sequence(sc, seed=seed)
    tr, K, M = p.tracks, sc.num_views, p.rig.num_cameras
    per = np.bincount(tr.view * M + tr.cam, minlength=K * M).reshape(K, M)
    # topped up to tracks_per_camera (one more when none would carry on) unless the next view keeps too little
    # of the image in sight; never empty
    assert np.mean(per[:-1] == sc.tracks_per_camera) > 0.9 and per.max() <= sc.tracks_per_camera + 1
    assert per.min() >= 1
    assert tr.num_views == K and len(p.points) == tr.track.max() + 1 == len(np.unique(tr.track))
    # each track: one camera, 2..6 consecutive views
    order = np.lexsort((tr.view, tr.track))
    track, view, cam = tr.track[order], tr.view[order], tr.cam[order]
    start = np.r_[True, track[1:] != track[:-1]]
    n = np.diff(np.r_[np.flatnonzero(start), len(track)])
    assert np.all((n >= sc.min_track_views) & (n <= sc.max_track_views))
    prev = np.flatnonzero(~start) - 1
    assert np.all(view[~start] == view[prev] + 1) and np.all(cam[~start] == cam[prev])
    # consecutive views always share tracks of every camera
    for k in range(K - 1):
        assert np.all(np.bincount(tr.cam[tr.pair_indices(k, k + 1)[0]], minlength=M) >= 1)


def test_two_views_and_track_run_limits():
    sc = SequenceScenario(num_views=2, tracks_per_camera=30, min_track_views=3, max_track_views=4)
    p = make_sequence(sc, seed=1)
    assert p.tracks.num_views == 2 and np.all(np.bincount(p.tracks.track) == 2)  # cut short by the sequence end
    m = p.tracks.pair(0, 1)
    assert len(m) == 4 * 30 and m.has_gravity
    sc = _clean(min_step_deg=2.0, max_step_deg=4.0, min_track_views=3, max_track_views=3)
    lengths = np.bincount(make_sequence(sc, seed=1).tracks.track)
    assert set(lengths.tolist()) <= {2, 3} and np.mean(lengths == 3) > 0.8  # small steps: few leave the image


def test_deterministic_for_a_seed():
    a, b, c = (make_sequence(SequenceScenario(num_views=4), seed=s) for s in (3, 3, 4))
    for key, value in a.tracks.to_npz_dict().items():
        assert np.array_equal(getattr(b.tracks, key), value)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.inlier_mask, b.inlier_mask)
    assert a.truth_dict() == b.truth_dict()
    assert not np.allclose(a.R, c.R)


def test_noise_outliers_and_measured_gravity():
    sc = SequenceScenario(num_views=6, pixel_noise=0.5, outlier_fraction=0.1, gravity_noise_deg=0.5)
    p = make_sequence(sc, seed=7)
    N = len(p.tracks)
    assert np.sum(~p.inlier_mask) == round(0.1 * N)
    assert p.truth_dict()["outliers"] == np.flatnonzero(~p.inlier_mask).tolist()
    err, _ = _reprojection_angles(p)
    focal = 800.0
    # Gaussian pixel noise: the angular error of an inlier is about sigma/f per axis (Rayleigh, mean ~1.25 sigma/f)
    assert 0.8 < np.mean(err[p.inlier_mask]) * focal / (0.5 * np.sqrt(np.pi / 2)) < 1.2
    assert np.median(err[~p.inlier_mask]) > 50 * 0.5 / focal
    for i, cam in enumerate(p.rig.cameras):  # outliers are random bearings inside each camera's field of view
        uv = bearings_to_pixels(cam, p.tracks.f[~p.inlier_mask & (p.tracks.cam == i)])
        assert len(uv) and np.all((uv >= -0.5) & (uv < np.array(cam.resolution) - 0.5))
    g_err = np.degrees(angle_between(p.tracks.g_meas, p.gravity))
    assert np.all(g_err > 0) and np.all(g_err < 5 * 0.5)
    assert np.allclose(np.linalg.norm(p.tracks.g_meas, axis=1), 9.81)
    assert make_sequence(replace(sc, gravity_measured=False), seed=7).tracks.g_meas is None


def test_custom_rig_and_scenario_dict():
    rig = make_rig(RigSpec(num_cameras=5, layout="ring", EI=0.5, focal=500.0))
    sc = SequenceScenario(num_views=3, tracks_per_camera=20)
    p = make_sequence(sc, seed=0, rig=rig)
    assert p.rig is rig and set(np.unique(p.tracks.cam)) == set(range(5))
    assert SequenceScenario.from_dict(sc.to_dict()) == sc
    assert SequenceScenario.from_dict({"rig": {"num_cameras": 2, "layout": "line"}}).rig.num_cameras == 2


@pytest.mark.parametrize("change, field", [
    ({"num_views": 1}, "num_views"),
    ({"num_views": 3.0}, "num_views"),
    ({"min_step_deg": 40.0}, "max_step_deg"),
    ({"max_tilt_deg": 95.0}, "max_tilt_deg"),
    ({"tracks_per_camera": 0}, "tracks_per_camera"),
    ({"min_track_views": 1}, "min_track_views"),
    ({"max_track_views": 1}, "max_track_views"),
    ({"min_depth": 0.0}, "max_depth"),
    ({"pixel_noise": -1.0}, "pixel_noise"),
    ({"outlier_fraction": 1.0}, "outlier_fraction"),
    ({"gravity_noise_deg": float("nan")}, "gravity_noise_deg"),
    ({"max_translation": float("inf")}, "max_translation"),
    ({"gravity_measured": "yes"}, "gravity_measured"),
])
def test_bad_scenario_names_the_field(change, field):
    with pytest.raises(InputError, match=f"'{field}'"):
        make_sequence(SequenceScenario(**change))


def test_infeasible_steps_are_a_clear_error():
    """Steps of 100-120 deg with a 40 deg field of view: no landmark stays in view from one view to the next."""
    with pytest.raises(InputError, match="'max_step_deg'.*no sequence of attitudes"):
        make_sequence(SequenceScenario(num_views=2, min_step_deg=100.0, max_step_deg=120.0, tracks_per_camera=5))


@pytest.mark.parametrize("name", ["line2", "cross4"])
def test_defaults_work_for_many_seeds(name):
    """Large steps can leave a camera nothing in view of the next hold; such attitudes are drawn again."""
    sc = SequenceScenario(rig=RIGS[name], tracks_per_camera=40)
    M = sc.rig.num_cameras
    for seed in range(20):
        tr = make_sequence(sc, seed=seed).tracks
        assert np.all(np.bincount(tr.view * M + tr.cam, minlength=sc.num_views * M) >= 1)
        for k in range(sc.num_views - 1):
            assert len(np.unique(tr.cam[tr.pair_indices(k, k + 1)[0]])) == M
