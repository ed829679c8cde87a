"""A ringing camera's tracks turned back to its rest (frontend.ringing_turns): the per-frame turn from all tracks,
the damped response of the turns, and every track at its rest pixel where a fit in pixels stays biased."""

import math

import numpy as np
import pytest

from nrmpc_ros.cameras import bearings_to_pixels, pixels_to_bearings
from nrmpc_ros.core.so3 import exp_so3, rotation_angle
from nrmpc_ros.frontend.ringing import fit_damped_response
from nrmpc_ros.frontend.ringing_turns import frame_turns, turn_back
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

F_BAR, ZETA, RATE = 1.5, 0.03, 30.0


def ringing_camera(seed, amp_deg, frames=55, jitter_s=0.0, noise_px=0.05):
    """Camera 0 of a 320x240 rig turning about a tilted axis by a damped ringing of ``amp_deg`` about its rest
    (the identity): (camera, rest pixels (n, 2), anchor pixels (n, 2), X (F, n, 2) with NaN out of view,
    the frames' stamps tau (F,), the true turns (F, 3, 3)); stamps off their exposures by up to ``jitter_s``."""
    rng = np.random.default_rng(seed)
    cam = make_rig(RigSpec(num_cameras=2, layout="line", focal=235.0, resolution=(320, 240))).cameras[0]
    rest_uv = rng.uniform([20, 20], [300, 220], size=(120, 2))
    a = pixels_to_bearings(cam, rest_uv)
    tau = 0.15 + np.arange(frames) / RATE
    true_t = tau + rng.uniform(-jitter_s, jitter_s, frames)
    w = 2 * math.pi * F_BAR
    axis = np.array([0.6, 0.8, 0.1]) / np.linalg.norm([0.6, 0.8, 0.1])
    angle = math.radians(amp_deg) * np.exp(-ZETA * w * true_t) * np.cos(w * true_t + 0.3)
    R = exp_so3(angle[:, None] * axis)
    X = np.stack([bearings_to_pixels(cam, a @ Rf.T) for Rf in R]) + rng.normal(scale=noise_px, size=(frames, 120, 2))
    W, H = cam.resolution
    out = (X[..., 0] < 0) | (X[..., 1] < 0) | (X[..., 0] > W - 1) | (X[..., 1] > H - 1)
    X[out] = np.nan
    return cam, rest_uv, X[0].copy(), X, tau, R


def test_each_frames_turn_is_measured_from_its_tracks():
    cam, _, anchor, X, _, R = ringing_camera(0, 13.0)
    ok_anchor = np.isfinite(anchor).all(axis=1)
    turns, ok = frame_turns(cam, anchor[ok_anchor], X[:, ok_anchor])
    assert ok.all()
    for Rf, truth in zip(turns, R):  # from the anchor (frame 0) to frame f
        assert rotation_angle((truth @ R[0].T).T @ Rf) < math.radians(0.01)


@pytest.mark.parametrize("amp_deg", [3.0, 13.0])
@pytest.mark.parametrize("jitter_s", [0.0, 0.003])
def test_tracks_turned_back_sit_at_their_rest_where_a_fit_in_pixels_is_biased(amp_deg, jitter_s):
    """At 13 deg of ringing the mean of a turn's image is not the image of its mean: a damped response fitted
    to each track's pixels leaves its rest off by up to about 1.5 px; turned back through the camera's model the
    tracks sit at their rest to the noise, with a damped response of the turns at the bar's frequency."""
    cam, rest_uv, anchor, X, tau, _ = ringing_camera(1, amp_deg, jitter_s=jitter_s)
    keep = np.isfinite(X).all(axis=2).all(axis=0)  # tracks seen in every frame
    X, anchor, rest_uv = X[:, keep], anchor[keep], rest_uv[keep]
    used = np.ones(len(X), bool)
    back, fit = turn_back(cam, anchor, X, tau, used, F_BAR, 8)
    assert fit.freq_hz == pytest.approx(F_BAR, rel=0.02) and fit.zeta == pytest.approx(ZETA, abs=0.01)
    err_turned = np.linalg.norm(np.nanmean(back, axis=0) - rest_uv, axis=1)
    median_offset = np.nanmedian(X - anchor[None], axis=1)
    pixel_fit = fit_damped_response([(tau, median_offset)], F_BAR, None)
    own, _ = pixel_fit.track_oscillations(tau, X, used, 8)
    err_pixels = np.linalg.norm(np.mean(X - own, axis=0) - rest_uv, axis=1)
    # the rest turn is as good as its fit: stamps 3 ms off a 120 deg/s ringing are 0.2 deg a frame
    bound = 3.0 * float(np.max(fit.rest_std)) * cam.focal_px + 0.05
    assert np.max(err_turned) < bound < 0.5, (np.max(err_turned), bound)
    if jitter_s == 0.0:
        assert np.max(err_turned) < 0.05, np.max(err_turned)
    if amp_deg > 10:
        assert np.max(err_pixels) > 0.5, np.max(err_pixels)


def test_too_few_frames_with_a_turn_give_none():
    cam, _, anchor, X, tau, _ = ringing_camera(2, 5.0, frames=6)
    ok_anchor = np.isfinite(anchor).all(axis=1)
    assert turn_back(cam, anchor[ok_anchor], X[:, ok_anchor], tau, np.ones(6, bool), F_BAR, 8) is None
