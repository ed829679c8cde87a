"""A ringing bar turns its camera: the hold's tracks turned back to the camera's rest (docs/PIPELINE.md, "Settling").

A bar's ringing is mostly a turn of its camera, of several degrees on soft bars. Through the camera's projection
a track's pixel is not linear in that angle: away from the optical axis the mean of an oscillating turn's image
is not the image of its mean (at 13 deg of ringing a track 20 deg off axis is biased by about 1.4 px), and no
oscillation fitted in pixels removes it. Here each frame's turn from the hold's anchor frame is measured from all
the camera's tracks (their bearings through the camera's own model, a least-squares rotation), the damped
response is fitted to the turns' rotation vectors (linear in the bar's load, as the bending model has it), and
every frame's bearings are turned from that frame's measured turn to the fitted rest turn. What remains of the
ringing in the pixels is the bar tip's shift (parallax, small), which the caller fits per track.
"""

from __future__ import annotations

import numpy as np

from ..cameras import bearings_to_pixels, pixels_to_bearings
from ..core.rig import Camera
from ..core.so3 import exp_so3, log_so3
from .ringing import RingingFit, fit_damped_response

OUTLIER_FACTOR = 5.0  # a track further from a frame's turn than this many times the median track is left out of it
MIN_TRACKS = 3  # a frame's turn needs this many tracks


def _bearings(cam: Camera, X: np.ndarray) -> tuple:
    """Bearings (F, n, 3) of pixels X (F, n, 2) (zero where NaN) and where they are seen (F, n)."""
    seen = np.isfinite(X).all(axis=2)
    b = np.zeros(X.shape[:2] + (3,))
    b[seen] = pixels_to_bearings(cam, X[seen])
    seen &= np.isfinite(b).all(axis=2)
    return np.where(seen[..., None], b, 0.0), seen


def frame_turns(cam: Camera, anchor_uv: np.ndarray, X: np.ndarray) -> tuple:
    """Each frame's turn from the anchor, bearings b = R a: (R (F, 3, 3), ok (F,) frames with enough tracks).
    The least-squares rotation of the tracks' bearings (Kabsch), then again without tracks far off it."""
    a = pixels_to_bearings(cam, anchor_uv)  # (n, 3)
    b, seen = _bearings(cam, X)
    w = seen & np.isfinite(a).all(axis=1)[None]
    a = np.nan_to_num(a)
    R = np.broadcast_to(np.eye(3), (len(X), 3, 3)).copy()
    for _ in range(2):
        H = np.einsum("fn,fni,nj->fij", w.astype(float), b, a)
        U, _, Vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(U @ Vt))
        U[:, :, 2] *= d[:, None]
        R = U @ Vt
        r = np.linalg.norm(b - np.einsum("fij,nj->fni", R, a), axis=2)  # (F, n) rad
        med = np.zeros((len(X), 1))  # each frame's median over its own tracks (0 where it has none)
        rows = w.any(axis=1)
        med[rows, 0] = np.nanmedian(np.where(w[rows], r[rows], np.nan), axis=1)
        w = w & (r <= OUTLIER_FACTOR * med + 1e-12)
    return R, w.sum(axis=1) >= MIN_TRACKS


def turn_back(cam: Camera, anchor_uv: np.ndarray, X: np.ndarray, tau: np.ndarray, used: np.ndarray,
              freq_hz: float, min_frames: int) -> tuple | None:
    """The camera's tracks X (F, n, 2) turned to its rest: (X turned (F, n, 2), NaN in frames whose turn is not
    known, and the :class:`RingingFit` of the turns' rotation vectors, rad: its rest_std the rest's std), or
    None when fewer than ``min_frames`` of the frames ``used`` (F,) have a turn or no damped response fits.
    ``tau`` (F,) the frames' times after the stop; ``freq_hz`` starts the fit's frequency."""
    R, ok = frame_turns(cam, np.asarray(anchor_uv, float), X)
    m = ok & np.asarray(used, bool)
    if m.sum() < min_frames:
        return None
    rest = np.eye(3)
    fit: RingingFit | None = None
    for _ in range(2):  # the second fit about the first one's rest: the turns then compose linearly
        r = log_so3(rest.T[None] @ R)
        fit = fit_damped_response([(tau[m], r[m])], freq_hz, None)
        if fit is None:
            return None
        rest = rest @ exp_so3(fit.rest[0])
    b, seen = _bearings(cam, X)
    back = np.einsum("ij,fkj,fnk->fni", rest, R, b)  # rest R_f^T b: each frame from its own turn to the rest
    out = np.full(X.shape, np.nan)
    keep = seen & ok[:, None]
    out[keep] = bearings_to_pixels(cam, back[keep])
    return out, fit


__all__ = ["frame_turns", "turn_back"]
