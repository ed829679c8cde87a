"""Landmark ids across holds: KLT identity kept and verified, drifted tracks split off, descriptors link holds
whose tracks did not survive the move."""

import math

import numpy as np
import pytest
from texture_views import CAM, make_texture, project, view

from nrmpc_ros.cameras import bearings_to_pixels
from nrmpc_ros.core.rig import Rig
from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.frontend.holds import CameraHold, Hold
from nrmpc_ros.frontend.linking import HoldLinker
from nrmpc_ros.frontend.patch_align import PatchAlignConfig
from nrmpc_ros.frontend.tracking import KltTracker, TrackingConfig

RIG = Rig(cameras=(CAM,))


@pytest.fixture(scope="module")
def texture():
    return make_texture(3)


def hold_of(img, ids, uv):
    """A one-camera hold measured at these track positions (their anchor too)."""
    ch = CameraHold(np.asarray(ids), np.asarray(uv, float), np.asarray(uv, float), 10, 0.02)
    return Hold(start=0.0, end=1.0, settled_start=0.5, settled_end=1.0, stamp=0.7, frames=10, settled_frames=5,
                residual_px=0.0, cameras=[ch], anchor_images=[img])


def tracked(texture, R):
    trk = KltTracker(TrackingConfig())
    img = view(texture, R)
    trk.track(img)
    ids, uv = trk.positions()
    return img, ids, uv


def test_klt_identity_is_kept_and_drifted_tracks_split_off(rng):
    """Tracks followed through the move keep their landmark when they fit the camera's epipolar geometry; a
    track that slid off its point (moved across its epipolar line) gets a new landmark."""
    from nrmpc_ros.cameras import bearings_to_pixels

    P = np.c_[rng.uniform(-3, 3, (150, 2)), rng.uniform(4, 9, 150)]
    R = exp_so3(np.array([0.02, 0.1, -0.03]))
    t = np.array([0.3, -0.05, 0.1])
    uv0 = bearings_to_pixels(CAM, P)
    uv1 = bearings_to_pixels(CAM, (P - t) @ R) + rng.normal(scale=0.05, size=uv0.shape)
    ids = np.arange(150)
    drift = np.arange(0, 150, 10)
    e = np.cross(R.T @ t, (P - t) @ R)[:, :2]  # across the epipolar line, roughly
    uv1[drift] += 6.0 * e[drift] / np.linalg.norm(e[drift], axis=1, keepdims=True)
    linker = HoldLinker(RIG, TrackingConfig())
    a = linker.link(hold_of(None, ids, uv0))
    b = linker.link(hold_of(None, ids, uv1))
    assert len(np.unique(a.landmark)) == len(a.landmark)
    same = np.isin(b.landmark, a.landmark)
    good = np.setdiff1d(ids, drift)
    assert same[good].mean() > 0.97  # identity kept where the track is right
    assert not same[drift].any()  # a new landmark where it is not
    assert b.links["klt"] == same.sum() and b.links["rejected"] >= len(drift)
    assert b.links["descriptor"] == 0  # enough tracks survived: no descriptor search


def test_descriptors_link_holds_after_a_jump(texture):
    """Tracks that did not survive the move (new tracker ids) are linked by descriptors to the same landmarks."""
    R1 = exp_so3(np.array([0.2, 0.9, 0.4]) / np.linalg.norm([0.2, 0.9, 0.4]) * math.radians(20))
    img0, ids0, uv0 = tracked(texture, np.eye(3))
    img1, ids1, uv1 = tracked(texture, R1)
    linker = HoldLinker(RIG, TrackingConfig())
    a = linker.link(hold_of(img0, ids0, uv0))
    b = linker.link(hold_of(img1, ids1 + 10000, uv1))  # other ids: nothing shared by identity
    assert b.links["descriptor"] >= 25
    linked = np.isin(b.landmark, a.landmark)
    pos_a = dict(zip(a.landmark.tolist(), uv0))
    err = [np.linalg.norm(project(np.eye(3), R1, pos_a[lm][None])[0] - uv) for lm, uv in zip(b.landmark[linked],
                                                                                          uv1[linked])]
    assert np.median(err) < 1.0 and np.percentile(err, 90) < 3.0  # the same points
    klt_only = HoldLinker(RIG, TrackingConfig(mode="klt"))
    klt_only.link(hold_of(img0, ids0, uv0))
    c = klt_only.link(hold_of(img1, ids1 + 10000, uv1))
    assert c.links["descriptor"] == 0 and not np.isin(c.landmark, a.landmark).any()


def test_ids_follow_the_tracker_into_the_next_hold(texture):
    """A track linked by descriptor keeps that landmark in later holds through its tracker id."""
    R1 = exp_so3(np.array([0.0, 1.0, 0.0]) * math.radians(15))
    img0, ids0, uv0 = tracked(texture, np.eye(3))
    img1, ids1, uv1 = tracked(texture, R1)
    linker = HoldLinker(RIG, TrackingConfig())
    linker.link(hold_of(img0, ids0, uv0))
    b = linker.link(hold_of(img1, ids1 + 500, uv1))
    R2 = R1 @ exp_so3(np.array([0.0, 0.0, 1.0]) * math.radians(3))
    uv2 = project(R1, R2, uv1)
    c = linker.link(hold_of(view(texture, R2), ids1 + 500, uv2))
    keep = np.isin(b.landmark, c.landmark)
    assert keep.mean() > 0.9
    linker.reset()
    d = linker.link(hold_of(img1, ids1 + 500, uv1))
    assert sum(d.links.values()) == 0  # after a reset nothing links to the holds before it


def test_a_hold_back_at_an_older_view_links_to_that_hold(texture):
    """The previous hold saw another scene: the tracks of a hold back near an older view take over that older
    hold's landmarks (descriptor store, verified per camera); without the store they start new landmarks. The
    older hold kept its reference patches (``patch_align.older_holds``), so those links are aligned like the
    previous hold's, nearer the true points than the corners found in this hold; a store that keeps none leaves
    them at those corners, marked so (the estimate weighs them with the corner's bias), and nothing else is."""
    other = make_texture(11)
    R2 = exp_so3(np.array([0.3, 1.0, 0.1]) / np.linalg.norm([0.3, 1.0, 0.1]) * math.radians(12))
    img0, ids0, uv0 = tracked(texture, np.eye(3))
    img1, ids1, uv1 = tracked(other, np.eye(3))
    img2, ids2, uv2 = tracked(texture, R2)
    median_error = {}
    for store, patches in ((200, 20), (200, 0), (0, 20)):
        linker = HoldLinker(RIG, TrackingConfig(link_store_holds=store), PatchAlignConfig(older_holds=patches))
        a = linker.link(hold_of(img0, ids0, uv0))
        b = linker.link(hold_of(img1, ids1 + 10000, uv1))
        c = linker.link(hold_of(img2, ids2 + 20000, uv2))
        assert not np.isin(b.landmark, a.landmark).any()
        linked = np.isin(c.landmark, a.landmark)
        assert a.corner is None and b.corner is None
        if store == 0:
            assert c.links["older"] == 0 and not linked.any() and c.corner is None
            continue
        assert linked.sum() >= 25 and linked.sum() == c.links["older"] - c.links["alignment failed"]
        if patches:
            assert c.corner is None and c.links["aligned"] == linked.sum()
        else:
            np.testing.assert_array_equal(c.corner, linked)
            assert c.links["corner"] == c.links["older"] and c.links["aligned"] == 0
        pos_a = dict(zip(a.landmark.tolist(), uv0))
        truth = np.array([project(np.eye(3), R2, pos_a[lm][None])[0] for lm in c.landmark[linked]])
        err = np.linalg.norm(bearings_to_pixels(CAM, c.f[linked]) - truth, axis=1)
        assert np.median(err) < 1.0 and np.percentile(err, 90) < 3.0  # the same points
        median_error[patches] = np.median(err)
    assert median_error[20] < 0.5 * median_error[0]
