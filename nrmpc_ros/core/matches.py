"""Two-view correspondences of a rig (docs/CONVENTIONS.md (Files), matches .npz)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..safeio import MiB, atomic_write, load_npz
from .deformation import gravity_from_camera
from .rig import MAX_CAMERAS, Rig

# --- Limits of a matches file (see docs/INPUTS.md) ---------------------------
MATCHES_MAX_BYTES = 1024 * MiB  # a two-view pair has thousands of correspondences (~50 B each): 1 GiB is generous
MATCHES_MAX_ARRAY_BYTES = 256 * MiB  # one array, uncompressed: 11 million bearings of 3 float64
# Bearings are unit vectors; the loader renormalises rounding, and homogeneous rays (x, y, 1) of normalised
# image coordinates are accepted too. A norm outside this range is not a direction any camera measured (a
# norm of 1e308 overflows to inf and normalises to a zero vector).
BEARING_NORM_RANGE = (1e-6, 1e6)
GRAVITY_NORM_RANGE = (1e-6, 1e6)  # m/s^2 or unit: only the direction of a gravity measurement is used


@dataclass
class Matches:
    """N correspondences: bearings f1 (view 1), f2 (view 2) and the camera index that saw both.

    Optional gravity measurements (pointing to the ground) either in the body
    frames (g1, g2) or in camera ``g_cam_index``'s frames (g1_cam, g2_cam).
    """

    f1: np.ndarray
    f2: np.ndarray
    cam: np.ndarray
    g1: np.ndarray | None = None
    g2: np.ndarray | None = None
    g1_cam: np.ndarray | None = None
    g2_cam: np.ndarray | None = None
    g_cam_index: int | None = None
    source: str = "<matches>"

    def __post_init__(self):
        validate_matches(self)

    def __len__(self) -> int:
        return len(self.cam)

    @property
    def has_gravity(self) -> bool:
        return self.g1 is not None or self.g1_cam is not None

    def check_rig(self, rig: Rig) -> None:
        """Raise if camera indices do not fit the rig."""
        if len(self.cam) and int(self.cam.max()) >= rig.num_cameras:
            bad = int(np.argmax(self.cam >= rig.num_cameras))
            raise InputError(self.source, f"entry {bad} has camera index {int(self.cam[bad])}, but the rig "
                             f"{rig.source} has {rig.num_cameras} cameras", "cam")
        if self.g_cam_index is not None and self.g_cam_index >= rig.num_cameras:
            raise InputError(self.source, f"camera index {self.g_cam_index} out of range for the rig", "g_cam_index")

    def body_gravity(self, rig: Rig):
        """Measured gravity (g1, g2) in the body frames, |g| = gravity_magnitude, or None (docs/CONVENTIONS.md,
        Gravity measurements)."""
        gm = rig.gravity_magnitude
        if self.g1 is not None:
            return (gm * self.g1 / np.linalg.norm(self.g1), gm * self.g2 / np.linalg.norm(self.g2))
        if self.g1_cam is not None:
            return (gravity_from_camera(rig, self.g_cam_index, self.g1_cam),
                    gravity_from_camera(rig, self.g_cam_index, self.g2_cam))
        return None

    def subset(self, idx) -> Matches:
        return Matches(self.f1[idx], self.f2[idx], self.cam[idx], self.g1, self.g2, self.g1_cam, self.g2_cam,
                       self.g_cam_index, self.source)

    def to_npz_dict(self) -> dict:
        out = {"f1": self.f1, "f2": self.f2, "cam": self.cam}
        for key in ("g1", "g2", "g1_cam", "g2_cam"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.g_cam_index is not None:
            out["g_cam_index"] = np.int64(self.g_cam_index)
        return out


def _real_array(src, name, value) -> np.ndarray:
    """``value`` as float64 if its dtype is real (integer or float); a bool, string, complex dtype is an error."""
    a = np.asarray(value)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise InputError(src, f"expected float64 numbers, got dtype {a.dtype}", name)
    return a.astype(float)


def _unit_rows(src, name, a, norm_range, what) -> np.ndarray:
    """Rows of ``a`` (K, 3) divided by their norms; NaN/inf rows and norms outside ``norm_range`` are errors."""
    lo, hi = norm_range
    bad = ~np.all(np.isfinite(a), axis=1)
    if bad.any():
        raise InputError(src, f"{int(bad.sum())} {what} contain NaN or inf (first: row {int(np.argmax(bad))})", name)
    huge = np.any(np.abs(a) > hi, axis=1)  # before the norm, which would overflow
    if huge.any():
        first = int(np.argmax(huge))
        raise InputError(src, f"{int(huge.sum())} {what} have an entry beyond {hi:g} (first: row {first}): not "
                              f"directions", name)
    scale = np.max(np.abs(a), axis=1, initial=0.0)
    n = scale * np.linalg.norm(a / np.where(scale > 0, scale, 1.0)[:, None], axis=1)  # scaled: 1e-300 stays > 0
    small = n < lo
    if small.any():
        first = int(np.argmax(small))
        kind = "zero-length" if n[first] == 0 else f"tiny (norm {n[first]:.3g} < {lo:g})"
        raise InputError(src, f"{int(small.sum())} {what} are zero-length or tiny (first: row {first}, {kind})",
                         name)
    large = n > hi
    if large.any():
        first = int(np.argmax(large))
        raise InputError(src, f"{int(large.sum())} {what} have a norm beyond {hi:g} (first: row {first})", name)
    return a / n[:, None]


def _bearings(src, name, value) -> np.ndarray:
    a = _real_array(src, name, value)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(src, f"expected shape (N, 3), got {a.shape}", name)
    return _unit_rows(src, name, a, BEARING_NORM_RANGE, "bearing vectors")


def _gravity(src, name, value) -> np.ndarray:
    g = _real_array(src, name, value)
    if g.shape != (3,):
        raise InputError(src, f"expected shape (3,), got {g.shape}", name)
    _unit_rows(src, name, g[None], GRAVITY_NORM_RANGE, "gravity vectors")
    return g


def _camera_indices(src, cam, n) -> np.ndarray:
    cam = np.asarray(cam)
    if cam.ndim != 1 or len(cam) != n:
        raise InputError(src, f"expected shape ({n},), got {cam.shape}", "cam")
    if cam.dtype == bool or not (np.issubdtype(cam.dtype, np.integer) or np.issubdtype(cam.dtype, np.floating)):
        raise InputError(src, f"expected integer camera indices, got dtype {cam.dtype}", "cam")
    if not len(cam):
        return cam.astype(np.int64)
    if np.issubdtype(cam.dtype, np.floating):
        whole = np.isfinite(cam) & (cam == np.round(cam))
        if not whole.all():
            first = int(np.argmin(whole))
            raise InputError(src, f"camera indices must be integers, entry {first} is {cam[first]}", "cam")
    neg = cam < 0
    if neg.any():
        raise InputError(src, f"negative camera index at entry {int(np.argmax(neg))}", "cam")
    big = cam >= MAX_CAMERAS  # compared before the int64 cast, which would wrap uint64 and huge floats
    if big.any():
        first = int(np.argmax(big))
        raise InputError(src, f"entry {first} has camera index {cam[first]}, beyond the {MAX_CAMERAS} cameras a rig "
                              f"may have", "cam")
    return cam.astype(np.int64)


def _camera_index(src, value) -> int:
    idx = np.asarray(value)
    if idx.shape != () or idx.dtype == bool or not np.issubdtype(idx.dtype, np.integer):
        raise InputError(src, f"expected a scalar integer camera index, got {value!r}", "g_cam_index")
    if not 0 <= int(idx) < MAX_CAMERAS:
        raise InputError(src, f"expected a camera index in [0, {MAX_CAMERAS}), got {int(idx)}", "g_cam_index")
    return int(idx)


def validate_matches(m: Matches) -> None:
    """Check shapes, dtypes and values in place; normalise bearings (raises InputError)."""
    src = m.source
    m.f1 = _bearings(src, "f1", m.f1)
    m.f2 = _bearings(src, "f2", m.f2)
    if len(m.f1) != len(m.f2):
        raise InputError(src, f"f1 has {len(m.f1)} rows but f2 has {len(m.f2)}", "f2")
    m.cam = _camera_indices(src, m.cam, len(m.f1))
    body = m.g1 is not None or m.g2 is not None
    incam = m.g1_cam is not None or m.g2_cam is not None
    if body and incam:
        raise InputError(src, "holds both body-frame (g1/g2) and camera-frame (g1_cam/g2_cam) gravity", "g1_cam")
    if body:
        if m.g1 is None or m.g2 is None:
            raise InputError(src, "g1 and g2 must be given together", "g2" if m.g2 is None else "g1")
        m.g1, m.g2 = _gravity(src, "g1", m.g1), _gravity(src, "g2", m.g2)
    if incam:
        if m.g1_cam is None or m.g2_cam is None or m.g_cam_index is None:
            missing = [k for k in ("g1_cam", "g2_cam", "g_cam_index") if getattr(m, k) is None]
            raise InputError(src, "camera-frame gravity needs g1_cam, g2_cam and g_cam_index", missing[0])
        m.g1_cam, m.g2_cam = _gravity(src, "g1_cam", m.g1_cam), _gravity(src, "g2_cam", m.g2_cam)
    if m.g_cam_index is not None:
        if not incam:
            raise InputError(src, "g_cam_index without g1_cam and g2_cam", "g_cam_index")
        m.g_cam_index = _camera_index(src, m.g_cam_index)


_KEYS = {"f1", "f2", "cam", "g1", "g2", "g1_cam", "g2_cam", "g_cam_index"}


def load_matches(path, rig: Rig | None = None) -> Matches:
    """Load and validate a matches .npz (docs/CONVENTIONS.md (Files)); bearings are normalised.

    Read through :func:`nrmpc_ros.safeio.load_npz` (size limits, no pickle,
    only the known keys). With ``rig`` the camera indices are also checked
    against the rig. Every problem is an InputError naming the file and the key.
    """
    src = str(path)
    data = load_npz(path, what="matches file", max_bytes=MATCHES_MAX_BYTES, max_array_bytes=MATCHES_MAX_ARRAY_BYTES,
                    allowed_keys=_KEYS)
    for key in ("f1", "f2", "cam"):
        if key not in data:
            raise InputError(src, "missing required array", key)
    m = Matches(
        data["f1"], data["f2"], data["cam"], data.get("g1"), data.get("g2"), data.get("g1_cam"), data.get("g2_cam"),
        data.get("g_cam_index"), source=src,
    )
    if rig is not None:
        m.check_rig(rig)
    return m


def save_matches(m: Matches, path, flag: str | None = None) -> None:
    """Write a matches .npz (docs/CONVENTIONS.md (Files)) atomically (:func:`~nrmpc_ros.safeio.atomic_write`);
    ``flag`` names the option in errors."""
    with atomic_write(path, "wb", flag=flag) as fh:
        np.savez(fh, **m.to_npz_dict())
