"""Tracking: grid bucketing, KLT through streamed frames and inside holds, sub-pixel corners, descriptors across
large rotations, verification."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from texture_views import CAM, F, H, W, make_texture, project, view

from nrmpc_ros.cameras import pixels_to_bearings
from nrmpc_ros.config import from_mapping
from nrmpc_ros.core.rig import Camera
from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.tracking import (
    Features,
    HoldThinning,
    KltTracker,
    TrackingConfig,
    bucket,
    describe,
    match_features,
    turn_pixels,
    verify_correspondences,
)


@pytest.fixture(scope="module")
def texture():
    return make_texture()


def test_bucket_spreads_points(rng):
    uv = np.r_[rng.uniform(0, 80, size=(500, 2)), rng.uniform(0, 640, size=(100, 2)) * [1, 0.75]]
    keep = bucket(uv, (W, H), 6, 8, 60)
    assert len(keep) == 60 and len(np.unique(keep)) == 60
    cells = (uv[keep, 1] * 6 // H).astype(int) * 8 + (uv[keep, 0] * 8 // W).astype(int)
    assert np.bincount(cells).max() <= 3  # the dense corner does not take everything
    assert len(bucket(uv[:10], (W, H), 6, 8, 60)) == 10
    order = np.argsort(-uv[:, 0])
    best = bucket(uv, (W, H), 1, 1, 5, order=order)
    np.testing.assert_array_equal(np.sort(best), np.sort(order[:5]))


def test_bucket_is_round_robin_over_cells(rng):
    """Same picks as taking the best remaining point of every cell in turn (cells in order of their best point)."""
    for trial in range(20):
        n = int(rng.integers(5, 400))
        uv = np.r_[rng.uniform(0, 100, size=(n // 2, 2)), rng.uniform(0, 640, size=(n - n // 2, 2)) * [1, 0.75]]
        order = rng.permutation(n) if trial % 2 else np.arange(n)
        count = int(rng.integers(1, n + 1))
        cell = (uv[:, 1] * 6 // H).astype(int) * 8 + (uv[:, 0] * 8 // W).astype(int)
        queues = {}
        for i in order:  # per cell, best first
            queues.setdefault(cell[i], []).append(i)
        picks, rank = [], 0
        while len(picks) < count:
            rnd = [q[rank] for q in queues.values() if len(q) > rank]  # rank-th best of each cell ...
            rnd.sort(key=lambda i: np.flatnonzero(order == i)[0])  # ... taken in order
            picks += rnd[: count - len(picks)]
            rank += 1
        got = bucket(uv, (W, H), 6, 8, count, order=None if trial % 2 == 0 else order)
        np.testing.assert_array_equal(got, np.sort(picks))


def test_klt_tracks_through_a_stream(texture):
    cfg = TrackingConfig()
    trk = KltTracker(cfg)
    Rs = [exp_so3(np.array([0.0, 1.0, 0.3]) * math.radians(1.5 * k)) for k in range(11)]  # 15 deg in 1.5 deg steps
    step = trk.track(view(texture, Rs[0]))
    assert step.tracks == cfg.max_tracks and math.isnan(step.motion_px) and not step.lost
    ids0, uv0 = trk.positions()
    for R in Rs[1:]:
        step = trk.track(view(texture, R))
        assert not step.lost and step.motion_px > 5.0
    ids1, uv1 = trk.positions()
    _, a, b = np.intersect1d(ids0, ids1, return_indices=True)
    assert len(a) > 100
    err = np.linalg.norm(project(Rs[0], Rs[-1], uv0[a]) - uv1[b], axis=1)
    assert np.median(err) < 0.3 and np.percentile(err, 95) < 1.0


def test_hold_tracks_from_the_anchor_without_drift(texture, rng):
    """Inside a hold every frame is tracked from the anchor: noisy copies of one image give positions within the
    noise of the anchor's, the motion is sub-pixel and no corner is added."""
    trk = KltTracker(TrackingConfig())
    img = view(texture, np.eye(3))
    trk.track(img)
    trk.start_hold()
    assert trk.in_hold
    ids_a, uv_a = trk.positions()
    for _ in range(8):
        noisy = np.clip(img + rng.normal(scale=2.0, size=img.shape), 0, 255).astype(np.uint8)
        step = trk.track(noisy)
        assert step.motion_px < 0.1 and not step.lost
    ids, uv = trk.positions()
    assert set(ids) <= set(ids_a) and len(ids) > 0.9 * len(ids_a)  # nothing new during the hold
    _, a, b = np.intersect1d(ids_a, ids, return_indices=True)
    assert np.median(np.linalg.norm(uv[b] - uv_a[a], axis=1)) < 0.05
    trk.end_hold()
    moved = view(texture, exp_so3(np.array([0.0, 0.02, 0.0])))
    assert trk.track(moved).motion_px > 5.0  # after the hold, frame to frame again


def test_a_hold_that_starts_with_part_of_its_tracks_is_topped_up(texture):
    """The first frame after a move is tracked from the previous hold's anchor; where part of the view
    changed, the rest survives (not lost) and the new hold's anchor is topped up with new corners to the
    full count (they keep no id of the old hold)."""
    cfg = TrackingConfig()
    trk = KltTracker(cfg)
    img = view(texture, np.eye(3))
    trk.track(img)
    trk.start_hold()
    ids_a, _ = trk.positions()
    changed = img.copy()
    cut = int(0.6 * img.shape[1])
    changed[:, :cut] = view(texture, exp_so3(np.array([0.0, 0.5, 0.0])))[:, :cut]  # most of it another scene now
    step = trk.track(changed)
    assert not step.lost and step.tracks < 0.7 * cfg.max_tracks
    trk.end_hold()
    trk.start_hold(top_up=True)
    ids, _ = trk.positions()
    assert len(ids) == cfg.max_tracks and len(np.setdiff1d(ids, ids_a)) > 0.3 * cfg.max_tracks


def test_anchor_moves_tracks_to_the_subpixel_corner():
    """At a hold's anchor a track moves to the corner under it: the corners of a checkerboard drawn at a known
    sub-pixel offset are found to a few hundredths of a pixel."""
    cfg = TrackingConfig(max_tracks=200, min_distance_px=5.0)
    off = np.array([0.37, 0.71])
    sq = 24
    S = 8  # drawn 8x finer and averaged over each pixel's area: the edges carry their sub-pixel position
    yy, xx = (np.mgrid[0:H * S, 0:W * S].astype(np.float64) - (S - 1) / 2) / S  # pixel coordinates
    board = ((np.floor((xx - off[0]) / sq) + np.floor((yy - off[1]) / sq)) % 2).astype(np.float32)
    img = cv2.GaussianBlur(cv2.resize(board * 200 + 30, (W, H), interpolation=cv2.INTER_AREA), (0, 0), 1.0)
    img = img.astype(np.uint8)
    trk = KltTracker(cfg)
    trk.track(img)
    trk.start_hold()
    _, uv = trk.positions()
    corners = np.round((uv - off) / sq) * sq + off  # nearest true corner
    inner = np.all((uv > 30) & (uv < [W - 30, H - 30]), axis=1)
    err = np.linalg.norm(uv - corners, axis=1)[inner]
    near = err < 1.0
    assert near.sum() > 50 and np.median(err[near]) < 0.05
    plain = KltTracker(TrackingConfig(max_tracks=200, min_distance_px=5.0, corner_refinement_px=0.0))
    plain.track(img)
    plain.start_hold()
    _, uv0 = plain.positions()
    err0 = np.linalg.norm(uv0 - (np.round((uv0 - off) / sq) * sq + off), axis=1)
    assert np.median(err0[inner]) > 0.5  # the detector alone sits pixels away, on whole pixels


def _fast_turn(texture):
    """Frames of an abrupt turn: still, then up to 8 deg (65 px) per frame, still again; and each frame's turn
    from the previous one (bearings f_k = R f_k-1), as the gyro and the bars give it."""
    axis = np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1])
    angles = np.cumsum([0, 0, 0, 2, 5, 7, 8, 7, 4, 1, 0, 0, 0])
    Rs = [exp_so3(axis * math.radians(a)) for a in angles]
    return [view(texture, R) for R in Rs], Rs, [None] + [Rs[k].T @ Rs[k - 1] for k in range(1, len(Rs))]


def test_the_cameras_turn_starts_klt_where_the_tracks_went(texture):
    """Through an abrupt turn the start from the camera's turn (the IMU) needs no pyramid and few full
    forward-backward passes, where the image-only prediction (the last frame's motion) misses at every change
    of rate; both track every frame as accurately and keep as many tracks."""
    imgs, Rs, turns = _fast_turn(texture)
    result = {}
    for use in (False, True):
        trk = KltTracker(TrackingConfig(), CAM)
        errs, kept = [], 0
        for k, img in enumerate(imgs):
            ids0, uv0 = trk.positions()
            step = trk.track(img, turns[k] if use else None)
            assert not step.lost
            ids1, uv1 = trk.positions()
            _, a, b = np.intersect1d(ids0, ids1, return_indices=True)
            kept += len(a)
            if k:
                errs.append(np.linalg.norm(project(Rs[k - 1], Rs[k], uv0[a]) - uv1[b], axis=1))
        err = np.concatenate(errs)
        assert np.median(err) < 0.1 and np.percentile(err, 99) < 0.7
        result[use] = (trk.stats, kept)
    (plain, kept_plain), (imu, kept_imu) = result[False], result[True]
    assert imu.turn_frames == len(imgs) - 1 and plain.turn_frames == 0
    first = TrackingConfig().klt_levels  # the first frame pair has no measured deviation yet: all levels
    assert imu.levels == first and plain.levels >= first + 5 * TrackingConfig().klt_levels
    assert imu.full_pass_tracks < 0.3 * plain.full_pass_tracks
    assert kept_imu >= 0.9 * kept_plain


FISHEYE = Camera(name="fish", model="equidistant", intrinsics=(280.0, 281.0, 322.0, 238.0),
                 distortion=(0.02, -0.01, 0.003, -0.001), resolution=(640, 480), position=np.zeros(3),
                 rotation=np.eye(3))
RADTAN = Camera(name="radtan", model="pinhole", intrinsics=(470.0, 468.0, 318.0, 241.0),
                distortion=(-0.2, 0.05, 0.001, -0.0005), resolution=(640, 480), position=np.zeros(3),
                rotation=np.eye(3))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.sampled_from([CAM, FISHEYE, RADTAN]), st.lists(st.floats(-0.05, 0.05), min_size=3, max_size=3),
       st.integers(0, 2**31 - 1))
def test_turn_pixels_follow_the_bearings_through_the_camera_model(cam, phi, seed):
    """A pixel turned by R lies on the turned bearing, and turning back by R^T returns it (every model)."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([80, 60], [560, 420], size=(20, 2))
    R = exp_so3(np.array(phi))
    out = turn_pixels(cam, R, uv)
    f = pixels_to_bearings(cam, uv) @ R.T
    np.testing.assert_allclose(pixels_to_bearings(cam, out), f, atol=1e-7)
    np.testing.assert_allclose(turn_pixels(cam, R.T, out), uv, atol=1e-4)


def test_hold_thinning_tracks_what_the_average_still_needs():
    """A settled hold is thinned once its average reaches half the correspondence floor; then one frame per
    quarter bar period is tracked, and none is skipped while the IMU says the rig moved."""
    th = HoldThinning(0.03)
    assert th.needed_frames(0.1) == 45  # (2 x 0.1 / 0.03)^2 = 44.4
    assert th.needed_frames(0.005) == 1
    period = 0.6

    def skip(settled, since_last, still=True, noise=0.1):
        return th.skip(10.0 + since_last, 10.0, settled, noise, period, 2.0, lambda: still)

    assert not skip(44, 1 / 30) and skip(45, 1 / 30) and skip(45, 0.149)
    assert not skip(45, 0.15)  # a quarter of the bar period since the last tracked frame: track this one
    assert not skip(45, 1 / 30, still=False) and not skip(1000, 1 / 30, noise=math.nan)
    assert th.skipped == 2
    assert th.skip(10.2, 10.0, 45, 0.1, 0.0, 2.0, lambda: True) and not th.skip(10.25, 10.0, 45, 0.1, 0.0, 2.0,
                                                                                lambda: True)  # rigid: measure_s/8


def test_klt_drops_tracks_across_a_large_jump(texture):
    trk = KltTracker(TrackingConfig())
    trk.track(view(texture, np.eye(3)))
    ids0, _ = trk.positions()
    R = exp_so3(np.array([0.1, 0.4, 0.9]) * math.radians(25))
    step = trk.track(view(texture, R))
    ids1, _ = trk.positions()
    assert step.lost and trk.lost == 1
    assert len(np.intersect1d(ids0, ids1)) == 0 and len(ids1) == TrackingConfig().max_tracks  # started afresh


@pytest.mark.parametrize("descriptor", ["orb", "sift"])
def test_descriptors_across_25_degrees(texture, descriptor):
    """Descriptors at corresponding points of two views 25 deg apart (rotation about the optical axis too) match,
    and the essential-matrix check keeps the right ones; points on the border get a descriptor as well."""
    cfg = TrackingConfig(descriptor=descriptor)
    R = exp_so3(np.array([0.2, 0.5, 0.85]) / np.linalg.norm([0.2, 0.5, 0.85]) * math.radians(25))
    trk = KltTracker(cfg)
    img_a, img_b = view(texture, np.eye(3)), view(texture, R)
    trk.track(img_a)
    _, uv_a = trk.positions()
    trk2 = KltTracker(cfg)
    trk2.track(img_b)
    _, uv_b = trk2.positions()
    da, va = describe(img_a, uv_a, cfg)
    db, vb = describe(img_b, uv_b, cfg)
    assert va.mean() > 0.95 and vb.mean() > 0.95
    ia, ib = match_features(Features(uv_a[va], da[va]), Features(uv_b[vb], db[vb]), cfg)
    assert len(np.unique(ib)) == len(ib) and len(ia) > 30
    pa, pb = uv_a[va][ia], uv_b[vb][ib]
    ok = verify_correspondences(CAM, pixels_to_bearings(CAM, pa), pixels_to_bearings(CAM, pb), cfg)
    err = np.linalg.norm(project(np.eye(3), R, pa[ok]) - pb[ok], axis=1)
    assert ok.sum() > 30 and np.median(err) < 1.0 and np.percentile(err, 90) < 2.0


def test_matching_is_ratio_tested_nearest_neighbour_each_used_once(rng):
    """ORB matches equal a brute-force Hamming search: nearest of each a, ratio test, best a kept per b."""
    base = rng.integers(0, 256, size=(150, 32), dtype=np.uint8)
    a = base.copy()
    b = np.r_[base[::-1], rng.integers(0, 256, size=(60, 32), dtype=np.uint8)]
    flip = rng.random(b.shape[:1] + (256,)) < rng.uniform(0.0, 0.35, size=(len(b), 1))
    b ^= np.packbits(flip, axis=1)  # b rows: the a rows (reversed) with 0-35% bits flipped, then random rows
    b[5] = b[7]  # two b rows that are the nearest neighbour of the same a rows
    cfg = TrackingConfig()
    ia, ib = match_features(Features(np.zeros((len(a), 2)), a), Features(np.zeros((len(b), 2)), b), cfg)
    d = np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=2).sum(axis=2)
    srt = np.sort(d, axis=1)
    nn = np.argmin(d, axis=1)
    keep = srt[:, 0] < cfg.ratio * srt[:, 1]
    best = {}
    for i in np.flatnonzero(keep):  # per b row, the a row with the smallest distance (first on ties)
        if nn[i] not in best or d[i, nn[i]] < d[best[nn[i]], nn[i]]:
            best[nn[i]] = i
    want = sorted((j, i) for j, i in best.items())
    assert 50 < len(want) < 150
    assert list(zip(ib, ia)) == want


def test_verification_rejects_outliers(rng):
    R = exp_so3(np.array([0.05, -0.1, 0.02]))
    t = np.array([0.3, 0.0, 0.05])
    P = np.c_[rng.uniform(-3, 3, (300, 2)), rng.uniform(4, 9, 300)]
    uv1 = P[:, :2] / P[:, 2:] * F + [(W - 1) / 2, (H - 1) / 2]
    Q = (P - t) @ R  # R^T (P - t)
    uv2 = Q[:, :2] / Q[:, 2:] * F + [(W - 1) / 2, (H - 1) / 2]
    uv2 += rng.normal(scale=0.2, size=uv2.shape)
    bad = rng.choice(300, 60, replace=False)
    uv2[bad] = rng.uniform([0, 0], [W, H], size=(60, 2))
    cfg = TrackingConfig()
    ok = verify_correspondences(CAM, pixels_to_bearings(CAM, uv1), pixels_to_bearings(CAM, uv2), cfg)
    assert ok[bad].sum() <= 2
    assert ok.sum() >= 220
    assert not verify_correspondences(CAM, pixels_to_bearings(CAM, uv1[:5]), pixels_to_bearings(CAM, uv2[:5]),
                                      cfg).any()


def test_config_errors():
    with pytest.raises(InputError, match="mode"):
        TrackingConfig(mode="magic")
    with pytest.raises(InputError, match="descriptor"):
        TrackingConfig(descriptor="surf")
    with pytest.raises(InputError, match="max_tracks"):
        TrackingConfig(max_tracks=True)
    with pytest.raises(InputError, match="unknown option"):
        from_mapping(TrackingConfig, {"max_trakcs": 3})
    assert from_mapping(TrackingConfig, {"max_tracks": 50}).max_tracks == 50
