"""Simulated sequences of static holds of a bending rig: landmark tracks over K views with ground truth.

The rig is held still at K attitudes (world z up, gravity (0, 0, -|g|) in the
world; the tilt of the body z axis from the vertical and the rotation between
consecutive views are drawn as for a rendered bag, see
:func:`nrmpc_ros.render.sequence.sample_attitudes`), at body positions uniform
in a cube. (R_k, t_k) maps view k into view 0 (p_0 = R_k p_k + t_k) and
gravity in view k's body frame is g_k = R_k^T g_0.

Each camera tracks its own landmarks, as a per-camera feature tracker does.
In every view but the last, new landmarks are created for camera i (uniform
over the image, depth along the optical axis uniform in [min_depth,
max_depth] m) until tracks_per_camera of its landmarks are visible and at
least one of them carries on into the next view. A landmark is seen by the
camera that created it for a run of consecutive views drawn in
[min_track_views, max_track_views], cut short when it leaves the image
(behind the camera or outside the pixel area) or the sequence ends;
candidates that would be seen in one view only are not kept, so every track
spans at least two views. When less than about 2 % of a camera's image stays
in view into the next hold, that camera gets fewer new landmarks in that
view; when nothing stays in view (a large step about an axis across the
optical axis, or a large translation) the attitudes are drawn again, so every
camera shares landmarks between every two consecutive views.

Observations use the bent extrinsics of each view (w_i(g_k), W_i(g_k)).
Image noise is Gaussian in pixels (the projected pixel is perturbed and
turned back into a bearing with the camera model); outliers replace a
fraction of the observations by the bearings of random pixels; measured
gravity is the true g_k turned by Gaussian tangent-plane noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..cameras import bearings_to_pixels, pixels_to_bearings
from ..core.deformation import deformed_extrinsics
from ..core.rig import Camera, Rig
from ..core.so3 import normalize
from ..core.tracks import Tracks
from ..errors import InputError
from ..render.sequence import WORLD_GRAVITY, MotionOptions, sample_attitudes
from .synthetic import RigSpec, Scenario, make_rig, perturb_directions

_SOURCE = "sequence scenario"
_MAX_DRAWS = 16  # candidate batches per camera and view: tops up unless under ~2 % of the image stays in view
_MAX_SEQUENCES = 100  # attitude sequences drawn before the step limits are declared infeasible


@dataclass
class SequenceScenario:
    """Everything that defines a random sequence of static views (besides the seed); angles in degrees."""

    rig: RigSpec = field(default_factory=RigSpec)
    num_views: int = 10
    min_step_deg: float = 5.0  # rotation between consecutive views
    max_step_deg: float = 30.0
    min_tilt_deg: float = 10.0  # tilt of the body z axis from the vertical
    max_tilt_deg: float = 40.0
    max_translation: float = 0.3  # m, half-size of the cube of body positions
    tracks_per_camera: int = 120  # landmarks visible per camera per view (kept topped up)
    min_track_views: int = 2  # run of consecutive views a track is seen in (shortened when it leaves the image)
    max_track_views: int = 6
    min_depth: float = 2.0  # m, along the optical axis when the landmark is created
    max_depth: float = 8.0
    pixel_noise: float = 0.3  # px, std of Gaussian image noise per axis
    outlier_fraction: float = 0.05  # of the observations, replaced by random bearings
    gravity_noise_deg: float = 0.3  # std of each tangent-plane component of the measured gravity direction
    gravity_measured: bool = True  # write g_meas

    # plain mapping <-> scenario, the nested rig as a RigSpec mapping, exactly as for two-view scenarios
    to_dict = Scenario.to_dict
    from_dict = classmethod(Scenario.from_dict.__func__)

    def validate(self, source: str = _SOURCE) -> None:
        """Raise InputError(source, ..., field) for values the generator cannot use (the rig spec aside)."""
        def need(ok, name, msg):
            if not ok:
                raise InputError(source, msg, name)

        def integer(x):
            return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))

        def real(x):
            return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))

        need(integer(self.num_views) and self.num_views >= 2, "num_views", "must be an integer >= 2")
        for name in ("min_step_deg", "max_step_deg", "min_tilt_deg", "max_tilt_deg", "max_translation",
                     "min_depth", "max_depth", "pixel_noise", "outlier_fraction", "gravity_noise_deg"):
            need(real(getattr(self, name)) and math.isfinite(getattr(self, name)), name, "must be a finite number")
        need(0 <= self.min_step_deg <= self.max_step_deg <= 120, "max_step_deg",
             "need 0 <= min_step_deg <= max_step_deg <= 120 (deg)")
        need(0 <= self.min_tilt_deg <= self.max_tilt_deg < 90, "max_tilt_deg",
             "need 0 <= min_tilt_deg <= max_tilt_deg < 90 (deg)")
        need(self.max_translation >= 0, "max_translation", "must be >= 0 (m)")
        need(integer(self.tracks_per_camera) and self.tracks_per_camera >= 1, "tracks_per_camera",
             "must be an integer >= 1")
        need(integer(self.min_track_views) and self.min_track_views >= 2, "min_track_views",
             "must be an integer >= 2 (a track seen in one view carries no information)")
        need(integer(self.max_track_views) and self.max_track_views >= self.min_track_views, "max_track_views",
             "must be an integer >= min_track_views")
        need(0 < self.min_depth <= self.max_depth, "max_depth", "need 0 < min_depth <= max_depth (m)")
        need(self.pixel_noise >= 0, "pixel_noise", "must be >= 0 (px)")
        need(0 <= self.outlier_fraction < 1, "outlier_fraction", "must be in [0, 1)")
        need(self.gravity_noise_deg >= 0, "gravity_noise_deg", "must be >= 0 (deg)")
        need(isinstance(self.gravity_measured, (bool, np.bool_)), "gravity_measured", "must be true or false")


@dataclass
class SequenceProblem:
    """One simulated sequence with its ground truth (view 0's body frame is the reference)."""

    rig: Rig
    tracks: Tracks
    R: np.ndarray  # (K, 3, 3) view k -> view 0
    t: np.ndarray  # (K, 3) m, origin of view k in view 0
    gravity: np.ndarray  # (K, 3) m/s^2, true g_k in view k's body frame (g_k = R_k^T g_0)
    points: np.ndarray  # (L, 3) m, landmarks in view 0's body frame, row = track id
    inlier_mask: np.ndarray  # (N,) bool, False for the outlier observations

    def truth_dict(self) -> dict:
        """R, t and gravity of every view, g_0 and the outlier observation indices, as JSON-ready lists."""
        return {
            "num_views": len(self.R), "R": self.R.tolist(), "t": self.t.tolist(), "gravity": self.gravity.tolist(),
            "g0": self.gravity[0].tolist(), "outliers": np.flatnonzero(~self.inlier_mask).tolist(),
        }


def _view_poses(rng, sc: SequenceScenario, gravity_magnitude: float):
    """R (K,3,3) view k -> view 0, t (K,3) and true gravity g_k (K,3) in each view's body frame."""
    opts = MotionOptions(views=sc.num_views, min_tilt=sc.min_tilt_deg, max_tilt=sc.max_tilt_deg,
                         min_step=sc.min_step_deg, max_step=sc.max_step_deg)
    try:
        Rw = sample_attitudes(rng, opts)  # body -> world
    except ValueError as exc:
        raise InputError(_SOURCE, str(exc), "max_step_deg") from None
    pw = rng.uniform(-sc.max_translation, sc.max_translation, size=(sc.num_views, 3))
    R = np.einsum("ba,kbc->kac", Rw[0], Rw)  # R_k = Rw_0^T Rw_k
    R[0] = np.eye(3)  # exactly, not up to rounding
    t = (pw - pw[0]) @ Rw[0]  # Rw_0^T (p_k - p_0)
    g0 = gravity_magnitude * (Rw[0].T @ WORLD_GRAVITY)
    return R, t, np.einsum("kba,b->ka", R, g0)


def _in_image(cam: Camera, P, C, c) -> np.ndarray:
    """(n,) True where points P (n, 3) are in front of the camera with rotation C (camera -> view 0) and
    centre c, and project inside its pixel area [-0.5, w - 0.5) x [-0.5, h - 0.5)."""
    pc = (P - c) @ C  # C^T (P - c)
    f = normalize(pc)
    uv = bearings_to_pixels(cam, f)
    w, h = cam.resolution
    with np.errstate(invalid="ignore"):
        ok = (pc[:, 2] > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < w - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < h - 0.5)
    if np.any(cam.distortion) and ok.any():
        # a distortion polynomial can fold points from far outside the field of view into the image
        back = pixels_to_bearings(cam, uv[ok])
        ok[np.flatnonzero(ok)] = np.einsum("ij,ij->i", back, f[ok]) > math.cos(1e-5)
    return ok


def _random_pixels(rng, cam: Camera, n: int) -> np.ndarray:
    w, h = cam.resolution
    return rng.uniform([-0.5, -0.5], [w - 0.5, h - 0.5], size=(n, 2))


def _new_landmarks(rng, sc, cam: Camera, k: int, C, c, need: int):
    """Up to ``need`` landmarks created by one camera in view k: points (n, 3) in view 0 and their runs (n,),
    each >= 2 views; fewer when too little of the image stays in view into view k + 1.

    C (K, 3, 3), c (K, 3): that camera's rotation (camera -> view 0) and centre in every view.
    """
    K = len(C)
    horizon = min(K - k, sc.max_track_views)
    pts, runs = [], []
    have = 0
    for _ in range(_MAX_DRAWS):
        n = max(4 * need, 64)
        f = pixels_to_bearings(cam, _random_pixels(rng, cam, n))
        depth = rng.uniform(sc.min_depth, sc.max_depth, size=n)
        P = (f * (depth / f[:, 2])[:, None]) @ C[k].T + c[k]
        length = rng.integers(sc.min_track_views, sc.max_track_views + 1, size=n)
        vis = np.stack([_in_image(cam, P, C[j], c[j]) for j in range(k, k + horizon)], axis=1)
        run = np.minimum(np.cumprod(vis, axis=1).sum(axis=1), length)
        keep = np.flatnonzero(run >= 2)[: need - have]
        pts.append(P[keep])
        runs.append(run[keep])
        have += len(keep)
        if have >= need:
            break
    return np.concatenate(pts), np.concatenate(runs)


def _make_landmarks(rng, sc, rig: Rig, C, c):
    """Create the landmarks view by view, camera by camera: points (L, 3), camera, first view, run (L,);
    None when a camera shares no landmark between two consecutive views (the attitudes are then redrawn)."""
    K, M = C.shape[:2]
    P, cam, start, run = [np.zeros((0, 3))], [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for k in range(K - 1):  # a landmark created in the last view would be seen once
        lm_cam, lm_start, lm_run = (np.concatenate(a) for a in (cam, start, run))
        for i in range(M):
            mine = (lm_cam == i) & (lm_start <= k)
            alive = int(np.sum(mine & (lm_start + lm_run > k)))
            goes_on = bool(np.any(mine & (lm_start + lm_run > k + 1)))
            need = max(sc.tracks_per_camera - alive, 0 if goes_on else 1)
            if need == 0:
                continue
            p, r = _new_landmarks(rng, sc, rig.cameras[i], k, C[:, i], c[:, i], need)
            if not (goes_on or len(p)):
                return None
            P.append(p)
            cam.append(np.full(len(p), i, np.int64))
            start.append(np.full(len(p), k, np.int64))
            run.append(r.astype(np.int64))
    return np.concatenate(P), np.concatenate(cam), np.concatenate(start), np.concatenate(run)


def make_sequence(scenario: SequenceScenario | None = None, seed: int = 0, rig: Rig | None = None) -> SequenceProblem:
    """Draw one random sequence of static views with landmark tracks; deterministic for (scenario, seed).

    ``rig`` overrides the rig built from scenario.rig (any pinhole or
    equidistant rig). Observations are ordered by (view, camera, track).
    """
    sc = scenario or SequenceScenario()
    sc.validate()
    rng = np.random.default_rng(seed)
    rig = rig or make_rig(sc.rig)
    gm = rig.gravity_magnitude
    for _ in range(_MAX_SEQUENCES):
        R, t, G = _view_poses(rng, sc, gm)
        w, W = deformed_extrinsics(rig, G)  # (K, M, 3), (K, M, 3, 3): bent camera -> body at each view's gravity
        C = np.einsum("kab,kmbc->kmac", R, W)  # camera -> view 0
        c = np.einsum("kab,kmb->kma", R, w) + t[:, None, :]  # camera centres in view 0
        landmarks = _make_landmarks(rng, sc, rig, C, c)
        if landmarks is not None:
            break
    else:
        raise InputError(_SOURCE, f"no sequence of attitudes found in {_MAX_SEQUENCES} draws in which every camera "
                         "keeps part of its view from one hold to the next; lower max_step_deg", "max_step_deg")
    P, lm_cam, lm_start, lm_run = landmarks

    ids = np.repeat(np.arange(len(P)), lm_run)
    first = np.repeat(np.cumsum(lm_run) - lm_run, lm_run)
    view = lm_start[ids] + np.arange(len(ids)) - first
    cam = lm_cam[ids]
    order = np.lexsort((ids, cam, view))
    view, cam, track = view[order], cam[order], ids[order]
    f = normalize(np.einsum("nba,nb->na", C[view, cam], P[track] - c[view, cam]))  # C^T (P - c)
    N = len(f)
    if sc.pixel_noise > 0:
        for i, camera in enumerate(rig.cameras):
            sel = np.flatnonzero(cam == i)
            uv = bearings_to_pixels(camera, f[sel]) + rng.normal(scale=sc.pixel_noise, size=(len(sel), 2))
            f[sel] = pixels_to_bearings(camera, uv)
    inlier = np.ones(N, dtype=bool)
    n_out = int(round(sc.outlier_fraction * N))
    if n_out:
        bad = rng.choice(N, size=n_out, replace=False)
        inlier[bad] = False
        for i, camera in enumerate(rig.cameras):
            sel = bad[cam[bad] == i]
            f[sel] = pixels_to_bearings(camera, _random_pixels(rng, camera, len(sel)))
    g_meas = None
    if sc.gravity_measured:
        g_meas = gm * perturb_directions(rng, G / gm, math.radians(sc.gravity_noise_deg))
    tracks = Tracks(view, cam, track, f, g_meas, num_views=sc.num_views, source="<simulated sequence>")
    return SequenceProblem(rig=rig, tracks=tracks, R=R, t=t, gravity=G, points=P, inlier_mask=inlier)
