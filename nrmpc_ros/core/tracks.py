"""Observations of landmarks over a sequence of static views of one rig, and the tracks .npz file that holds them.

Over K static views, (R_k, t_k) maps view k into view 0 (p_0 = R_k p_k + t_k)
and gravity in view k's body frame is g_k = R_k^T g_0. A *track* is one
landmark (one 3D point): all observations with the same track id see it,
from one or more cameras in one or more views. Each observation is a unit
bearing f in the frame of the camera that made it. A track seen in a single
view carries no information about the motion or gravity; it is allowed and
the estimators ignore it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..safeio import MiB, atomic_write, load_npz
from .matches import Matches, _bearings
from .rig import Rig

_REQUIRED = ("view", "cam", "track", "f")
_KEYS = set(_REQUIRED) | {"g_meas"}
_INT64_MAX = np.iinfo(np.int64).max
TRACKS_MAX_BYTES = 1024 * MiB  # a recording of hundreds of holds with ~1000 tracks each is ~100 MB
TRACKS_MAX_ARRAY_BYTES = 256 * MiB  # one array, uncompressed: ~11 million bearings


@dataclass
class Tracks:
    """N observations of landmarks in K static views of one rig.

    view, cam, track: (N,) int64 view index 0..K-1, camera index (into the
    rig's camera list) and landmark id (any non-negative integers) of each
    observation; f: (N, 3) unit bearings in that camera's frame (renormalised
    on construction). g_meas: optional (K, 3) measured gravity per view in the
    body frame, pointing to the ground (any norm; only the direction is used);
    a row of NaN means that view has no measurement. num_views: K, by default
    max(view) + 1. Every view 0..K-1 must have at least one observation, and a
    camera sees a track at most once per view.
    """

    view: np.ndarray
    cam: np.ndarray
    track: np.ndarray
    f: np.ndarray
    g_meas: np.ndarray | None = None
    num_views: int | None = None
    source: str = "<tracks>"

    def __post_init__(self):
        """Validate and normalise in place (see :func:`validate_tracks`); sets num_views to K."""
        validate_tracks(self)

    def __len__(self) -> int:
        """N, the number of observations."""
        return len(self.view)

    def check_rig(self, rig: Rig) -> None:
        """Raise if camera indices do not fit the rig."""
        if int(self.cam.max()) >= rig.num_cameras:
            bad = int(np.argmax(self.cam >= rig.num_cameras))
            raise InputError(self.source, f"observation {bad} has camera index {int(self.cam[bad])}, but the rig "
                             f"{rig.source} has {rig.num_cameras} cameras", "cam")

    def measured_gravity(self, rig: Rig) -> np.ndarray | None:
        """Measured gravity (K, 3) in each view's body frame scaled to |g| = rig.gravity_magnitude (m/s^2);
        rows of views without a measurement stay NaN. None when the tracks hold no g_meas."""
        if self.g_meas is None:
            return None
        return rig.gravity_magnitude * self.g_meas / np.linalg.norm(self.g_meas, axis=1, keepdims=True)

    def subset(self, mask_or_idx) -> Tracks:
        """The observations selected by a boolean mask (N,) or an index array; views keep their numbering,
        so every view must keep at least one observation (InputError otherwise)."""
        idx = np.asarray(mask_or_idx)
        if idx.dtype == bool and idx.shape != (len(self),):
            raise ValueError(f"a boolean mask must have shape ({len(self)},), got {idx.shape}")
        return Tracks(self.view[idx], self.cam[idx], self.track[idx], self.f[idx], self.g_meas,
                      num_views=self.num_views, source=self.source)

    def views_subset(self, views) -> Tracks:
        """The observations of ``views`` (distinct view indices), renumbered 0..len(views)-1 in the order given
        (so views[0] becomes the new view 0, the reference of the poses); g_meas rows follow."""
        v = self._view_indices(views)
        new = np.full(self.num_views, -1, dtype=np.int64)
        new[v] = np.arange(len(v))
        keep = new[self.view] >= 0
        g = None if self.g_meas is None else self.g_meas[v]
        return Tracks(new[self.view[keep]], self.cam[keep], self.track[keep], self.f[keep], g,
                      num_views=len(v), source=self.source)

    def pair_indices(self, k1: int, k2: int) -> tuple[np.ndarray, np.ndarray]:
        """Observation indices (i1, i2) of the tracks seen by the same camera in views k1 and k2:
        view[i1] == k1, view[i2] == k2, cam[i1] == cam[i2], track[i1] == track[i2]; ordered by (cam, track)."""
        k1, k2 = self._view_indices([k1, k2])
        i1 = np.flatnonzero(self.view == k1)
        i2 = np.flatnonzero(self.view == k2)
        keys = np.concatenate([np.stack([self.cam[i1], self.track[i1]], axis=1),
                               np.stack([self.cam[i2], self.track[i2]], axis=1)])
        _, code = np.unique(keys, axis=0, return_inverse=True)
        code = code.reshape(-1)
        # (cam, track) is unique within a view (validated), so the codes of each view are distinct
        _, a, b = np.intersect1d(code[: len(i1)], code[len(i1):], assume_unique=True, return_indices=True)
        return i1[a], i2[b]

    def pair(self, k1: int, k2: int) -> Matches:
        """Two-view correspondences between views k1 (view 1) and k2 (view 2), in pair_indices order;
        g1/g2 are the g_meas rows of k1 and k2 when both are measured."""
        i1, i2 = self.pair_indices(k1, k2)
        g1 = g2 = None
        if self.g_meas is not None and np.all(np.isfinite(self.g_meas[[k1, k2]])):
            g1, g2 = self.g_meas[k1], self.g_meas[k2]
        return Matches(self.f[i1], self.f[i2], self.cam[i1], g1, g2, source=f"{self.source} (views {k1}, {k2})")

    def to_npz_dict(self) -> dict:
        out = {"view": self.view, "cam": self.cam, "track": self.track, "f": self.f}
        if self.g_meas is not None:
            out["g_meas"] = self.g_meas
        return out

    def _view_indices(self, views) -> np.ndarray:
        v = np.asarray(views)
        if v.ndim != 1 or len(v) == 0 or not np.issubdtype(v.dtype, np.integer):
            raise InputError(self.source, f"expected a non-empty list of integer view indices, got {views!r}", "view")
        if v.min() < 0 or v.max() >= self.num_views:
            raise InputError(self.source, f"view indices {v.tolist()} out of range 0..{self.num_views - 1}", "view")
        if len(np.unique(v)) != len(v):
            raise InputError(self.source, f"view indices {v.tolist()} repeat a view", "view")
        return v.astype(np.int64)


def _indices(src, key, value, n) -> np.ndarray:
    """(n,) non-negative int64 from an integer array (or a float array holding whole numbers)."""
    a = np.asarray(value)
    if a.ndim != 1 or len(a) != n:
        raise InputError(src, f"expected shape ({n},), got {a.shape}", key)
    is_int = np.issubdtype(a.dtype, np.integer)
    if not (is_int or np.issubdtype(a.dtype, np.floating)):
        raise InputError(src, f"expected integers, got dtype {a.dtype}", key)
    if not is_int:
        bad = ~np.isfinite(a) | (a != np.round(a))
        if bad.any():
            first = int(np.argmax(bad))
            raise InputError(src, f"expected integers, got dtype {a.dtype} with {int(bad.sum())} non-integer "
                             f"values (first: entry {first} = {a[first].item()!r})", key)
        a = a.astype(np.float64)  # float16 cannot hold the bound below: compare in float64
    if n and a.min() < 0:
        first = int(np.argmax(a < 0))
        raise InputError(src, f"negative index at entry {first} ({a[first].item()!r})", key)
    if n and a.max() > _INT64_MAX // 2:
        first = int(np.argmax(a > _INT64_MAX // 2))
        raise InputError(src, f"index too large at entry {first} ({a[first].item()!r})", key)
    return a.astype(np.int64)


def _gravity_rows(src, value, K) -> np.ndarray:
    """(K, 3) float64 measured gravity: rows finite and non-zero, or all NaN (no measurement)."""
    g = np.asarray(value)
    if g.shape != (K, 3):
        raise InputError(src, f"expected shape ({K}, 3), one row per view 0..{K - 1}, got {g.shape}", "g_meas")
    if not (np.issubdtype(g.dtype, np.floating) or np.issubdtype(g.dtype, np.integer)):
        raise InputError(src, f"expected float64, got dtype {g.dtype}", "g_meas")
    g = g.astype(float)
    nan = np.isnan(g)
    bad = np.isinf(g).any(axis=1) | (nan.any(axis=1) & ~nan.all(axis=1))
    if bad.any():
        raise InputError(src, f"row {int(np.argmax(bad))} is neither finite nor all NaN (NaN = no measurement)",
                         "g_meas")
    zero = ~nan.any(axis=1) & (np.linalg.norm(np.where(nan, 0.0, g), axis=1) < 1e-12)
    if zero.any():
        raise InputError(src, f"row {int(np.argmax(zero))} is a zero vector (use NaN for no measurement)", "g_meas")
    return g


def _num_views(src, t: Tracks) -> int:
    if t.num_views is None:
        return int(t.view.max()) + 1
    k = t.num_views
    if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or k < 1:
        raise InputError(src, f"expected an integer >= 1, got {k!r}", "num_views")
    return int(k)


def validate_tracks(t: Tracks) -> None:
    """Check shapes, dtypes and values in place; normalise dtypes and bearings (raises InputError).

    Sets t.num_views to K. A track seen in only one view is allowed (it carries
    no information; the estimators ignore it).
    """
    src = t.source
    f = np.asarray(t.f)
    if f.ndim == 2 and f.shape[1] == 3 and not np.issubdtype(f.dtype, np.floating):
        raise InputError(src, f"expected float64 bearings, got dtype {f.dtype}", "f")
    t.f = _bearings(src, "f", f)
    n = len(t.f)
    if n == 0:
        raise InputError(src, "no observations", "f")
    t.view = _indices(src, "view", t.view, n)
    t.cam = _indices(src, "cam", t.cam, n)
    t.track = _indices(src, "track", t.track, n)
    K = _num_views(src, t)
    if t.view.max() >= K:
        bad = int(np.argmax(t.view >= K))
        raise InputError(src, f"entry {bad} has view index {int(t.view[bad])}, but num_views is {K}", "view")
    empty = np.flatnonzero(np.bincount(t.view, minlength=K) == 0)
    if len(empty):
        raise InputError(src, f"{len(empty)} of the {K} views have no observations (first: view {int(empty[0])}); "
                         "views must be numbered 0..K-1 without gaps", "view")
    if t.g_meas is not None:
        t.g_meas = _gravity_rows(src, t.g_meas, K)
    order = np.lexsort((t.track, t.cam, t.view))
    vct = np.stack([t.view, t.cam, t.track], axis=1)[order]
    dup = np.all(vct[1:] == vct[:-1], axis=1)
    if dup.any():
        j = int(np.argmax(dup))
        v, c, k = vct[j].tolist()
        raise InputError(src, f"track {k} is seen twice by camera {c} in view {v} (observations "
                         f"{int(order[j])} and {int(order[j + 1])})", "track")
    t.num_views = K


def load_tracks(path) -> Tracks:
    """Load and validate a tracks .npz (keys view, cam, track, f and optional g_meas); bearings are normalised.

    Read through :func:`nrmpc_ros.safeio.load_npz` (size limits checked before anything is unpacked, no
    pickle, only the known keys); every problem is one InputError naming the file and the key.
    """
    src = str(path)
    data = load_npz(path, what="tracks file", max_bytes=TRACKS_MAX_BYTES, max_array_bytes=TRACKS_MAX_ARRAY_BYTES,
                    allowed_keys=_KEYS)
    for key in _REQUIRED:
        if key not in data:
            raise InputError(src, "missing required array", key)
    return Tracks(data["view"], data["cam"], data["track"], data["f"], data.get("g_meas"), source=src)


def save_tracks(t: Tracks, path, flag: str | None = None) -> None:
    """Write a tracks .npz (the arrays of :meth:`Tracks.to_npz_dict`) atomically
    (:func:`~nrmpc_ros.safeio.atomic_write`); ``flag`` names the option in errors."""
    with atomic_write(path, "wb", flag=flag) as fh:
        np.savez(fh, **t.to_npz_dict())
