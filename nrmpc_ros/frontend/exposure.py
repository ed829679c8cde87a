"""A camera's exposure change within a hold, undone before its frames are tracked from the hold's anchor.

Auto-exposure changes a camera's gain and offset while the rig holds still (a gain drifting 0.2 a second is
common). Lucas-Kanade (OpenCV's pyramidal KLT) matches intensities as they are: a brighter frame pulls each
track along its patch's intensity gradient, by a bias the same for every frame of that brightness, which the
hold's average keeps. Here a frame's intensities are mapped back to the anchor's, ``(image - offset) / gain``,
before it is tracked (docs/PIPELINE.md, "Holds").

The change is read from the two images' intensity distributions, not pixel by pixel: within a hold the bars
still ring, so the image shifts by up to pixels against the anchor and a pixelwise regression would read
that shift as a loss of contrast. The 10th and 90th percentiles of a grid of every ``GRID_STEP``-th pixel
(about 19 000 of a VGA image, from their histogram) move with the gain and offset, not with a shift of the
same scene; the median must follow the same map, else the view changed (the rig moved) and nothing is
undone. Where the change moves no intensity by half a grey level (the images' own quantisation) or by three
times the quantiles' own sampling noise, the frame is tracked as it came.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

GRID_STEP = 4  # every 4th pixel of every 4th row: the percentiles of a VGA image from 19 200 pixels
QUANTILES = (10.0, 50.0, 90.0)  # inside the range of most images' intensities: away from saturation at 0 and
# 255; the outer two give the gain and offset, the median tells an exposure change (every quantile mapped
# alike) from a changed view (the rig moved)
NEGLIGIBLE_GREY = 0.5  # a change that moves no intensity by this much is below the images' quantisation
NOISE_SIGMAS = 3.0  # ... nor by this many stds of the quantiles' sampling noise


class ExposureChange(NamedTuple):
    """``image ~ gain * reference + offset`` (grey levels)."""

    gain: float
    offset: float

    def largest_change_grey(self, levels) -> float:
        """The largest change it makes to the given reference intensities (grey levels)."""
        return float(np.max(np.abs((self.gain - 1.0) * np.asarray(levels, float) + self.offset)))


NONE = ExposureChange(1.0, 0.0)


class IntensityLevels(NamedTuple):
    """An image's intensity :data:`QUANTILES` (grey levels) and the std of their sampling noise (grey levels:
    sqrt(p (1 - p) n) over the histogram's count at the quantile)."""

    levels: np.ndarray
    noise: float


def grid_quantiles(image: np.ndarray) -> IntensityLevels:
    """The :data:`QUANTILES` of ``image``'s intensities (uint8) on the :data:`GRID_STEP` grid, from their
    histogram, each grey level spread evenly over its unit bin (sub-level resolution; a histogram costs a tenth
    of a sort), with their sampling noise."""
    counts = np.bincount(image[::GRID_STEP, ::GRID_STEP].ravel(), minlength=256)
    cdf = np.cumsum(counts)
    p = np.asarray(QUANTILES) / 100.0
    rank = p * cdf[-1]
    level = np.minimum(np.searchsorted(cdf, rank, side="right"), len(counts) - 1)
    below = np.where(level > 0, cdf[level - 1], 0)
    per_level = np.maximum(counts[level], 1)
    noise = float(np.max(np.sqrt(p * (1.0 - p) * cdf[-1]) / per_level))
    return IntensityLevels(level - 0.5 + (rank - below) / per_level, noise)


def exposure_change(reference: IntensityLevels, image: np.ndarray) -> tuple[ExposureChange, float]:
    """(the gain and offset that take the reference's intensity quantiles to ``image``'s, identity where the
    reference has no contrast; the sampling noise of the quantiles' difference, grey levels)."""
    q = grid_quantiles(image)
    noise = math.hypot(reference.noise, q.noise)
    ref, got = reference.levels, q.levels
    span = float(ref[-1] - ref[0])
    if span < 1.0:
        return NONE, noise
    gain = float(got[-1] - got[0]) / span
    if not gain > 0.0:
        return NONE, noise
    change = ExposureChange(gain, float(got[0] - gain * ref[0]))
    if abs(gain * ref[1] + change.offset - got[1]) > max(1.0, NOISE_SIGMAS * noise):
        return NONE, noise  # the median does not follow: the view changed, not the exposure
    return change, noise


def undo_exposure(reference: IntensityLevels, image: np.ndarray) -> tuple[np.ndarray, ExposureChange]:
    """(``image`` mapped back to the reference's exposure, the change undone); the image itself (and
    :data:`NONE`) when the change is negligible: it moves no intensity by half a grey level or by
    :data:`NOISE_SIGMAS` times the quantiles' sampling noise (a still scene's quantiles move by that much with
    the image noise and the bars' ringing; read as an exposure change it would pull the tracks for nothing)."""
    change, noise = exposure_change(reference, image)
    if change.largest_change_grey(reference.levels) < max(NEGLIGIBLE_GREY, NOISE_SIGMAS * noise):
        return image, NONE
    back = cv2.convertScaleAbs(image, alpha=1.0 / change.gain, beta=-change.offset / change.gain)
    return back, change


__all__ = ["GRID_STEP", "NEGLIGIBLE_GREY", "NOISE_SIGMAS", "NONE", "QUANTILES", "ExposureChange",
           "IntensityLevels", "exposure_change", "grid_quantiles", "undo_exposure"]
