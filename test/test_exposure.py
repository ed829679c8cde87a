"""Exposure changes within a hold: read from the intensity distributions (not from a shifted image), undone
before KLT, skipped where negligible."""

import numpy as np
import pytest
from texture_views import make_texture, view

from nrmpc_ros.frontend.exposure import GRID_STEP, NONE, QUANTILES, exposure_change, grid_quantiles, undo_exposure
from nrmpc_ros.frontend.tracking import KltTracker, TrackingConfig


@pytest.fixture(scope="module")
def image():
    return view(make_texture(), np.eye(3)).astype(np.float64)


def exposed(img, gain, offset, rng, shift=(0, 0)):
    out = gain * np.roll(img, shift, axis=(0, 1)) + offset + rng.normal(scale=1.0, size=img.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("gain, offset", [(1.25, 8.0), (0.8, -6.0), (1.1, 0.0)])
def test_a_gain_and_offset_are_read_through_a_shift_of_the_image(image, rng, gain, offset):
    """Bars that ring shift the image by pixels against the anchor: the percentiles do not see it."""
    ref = grid_quantiles(exposed(image, 1.0, 0.0, rng))
    change, noise = exposure_change(ref, exposed(image, gain, offset, rng, shift=(3, -2)))
    assert change.gain == pytest.approx(gain, rel=0.02) and 0.0 < noise < 1.0
    assert change.largest_change_grey(ref.levels) == pytest.approx(
        max(abs((gain - 1) * q + offset) for q in ref.levels), abs=1.5)


def test_a_negligible_change_leaves_the_frame_as_it_came(image, rng):
    ref = exposed(image, 1.0, 0.0, rng)
    frame = exposed(image, 1.0, 0.0, rng, shift=(1, 0))
    back, change = undo_exposure(grid_quantiles(ref), frame)
    assert back is frame and change is NONE


def test_klt_inside_a_hold_is_not_pulled_by_the_exposure(image, rng):
    """Frames of a still rig whose gain drifts 1.0 -> 1.3 (and offset to +10): tracked from the anchor as they
    came, each track's average over the hold is pulled along its patch's gradient (0.9 px rms); with the change
    undone it stays at the anchor's within the noise."""
    ref = exposed(image, 1.0, 0.0, rng)
    frames = [exposed(image, 1.0 + 0.3 * k / 9, 10.0 * k / 9, rng) for k in range(1, 10)]

    def bias_px(undo: bool) -> float:
        trk = KltTracker(TrackingConfig(undo_exposure=undo))
        trk.track(ref)
        trk.start_hold()
        ids_a, uv_a = trk.positions()
        shifts = np.full((len(frames), len(ids_a), 2), np.nan)
        for k, f in enumerate(frames):
            trk.track(f)
            ids, uv = trk.positions()
            _, a, b = np.intersect1d(ids_a, ids, return_indices=True)
            shifts[k, a] = uv[b] - uv_a[a]
        assert trk.stats.exposure_frames == (len(frames) if undo else 0)
        average = np.nanmean(shifts, axis=0)  # each track's average over the hold, from the anchor
        return float(np.sqrt(np.nanmean(np.sum(average**2, axis=1))))

    undone, as_came = bias_px(True), bias_px(False)
    assert undone < 0.05 and as_came > 0.3


def test_the_histogram_quantiles_are_the_percentiles_within_half_a_grey_level(image, rng):
    frame = exposed(image, 1.1, 3.0, rng)
    direct = np.percentile(frame[::GRID_STEP, ::GRID_STEP], QUANTILES)
    assert np.allclose(grid_quantiles(frame).levels, direct, atol=0.5)



def test_an_intensity_map_that_is_no_gain_and_offset_is_not_undone(image, rng):
    """The median must follow the map the outer quantiles give: where it does not (here a gamma curve; in a
    hold, a view that changed because the rig moved; here the brighter half of the intensities 40 levels
    brighter) nothing is undone."""
    ref = exposed(image, 1.0, 0.0, rng)
    curved = np.where(ref < np.median(ref), ref, np.minimum(ref.astype(int) + 40, 255)).astype(np.uint8)
    back, change = undo_exposure(grid_quantiles(ref), curved)
    assert change is NONE and back is curved
    assert exposure_change(grid_quantiles(ref), exposed(image, 1.2, 4.0, rng))[0] is not NONE
