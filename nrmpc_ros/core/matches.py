"""Two-view correspondences of a rig (SPEC section 7, matches .npz)."""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .deformation import gravity_from_camera
from .rig import Rig


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
        """Measured gravity (g1, g2) in the body frames, |g| = gravity_magnitude, or None (SPEC section 4)."""
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


def _bearings(src, name, value) -> np.ndarray:
    a = np.asarray(value)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(src, f"expected shape (N, 3), got {a.shape}", name)
    if not np.issubdtype(a.dtype, np.floating) and not np.issubdtype(a.dtype, np.integer):
        raise InputError(src, f"expected float64 bearings, got dtype {a.dtype}", name)
    a = a.astype(float)
    bad = ~np.all(np.isfinite(a), axis=1)
    if bad.any():
        raise InputError(src, f"{int(bad.sum())} rows contain NaN or inf (first: row {int(np.argmax(bad))})", name)
    n = np.linalg.norm(a, axis=1)
    zero = n < 1e-12
    if zero.any():
        first = int(np.argmax(zero))
        raise InputError(src, f"{int(zero.sum())} zero-length bearing vectors (first: row {first})", name)
    return a / n[:, None]


def _gravity(src, name, value) -> np.ndarray:
    g = np.asarray(value)
    if g.shape != (3,):
        raise InputError(src, f"expected shape (3,), got {g.shape}", name)
    g = g.astype(float)
    if not np.all(np.isfinite(g)) or np.linalg.norm(g) < 1e-12:
        raise InputError(src, f"expected a finite non-zero 3-vector, got {g!r}", name)
    return g


def validate_matches(m: Matches) -> None:
    """Check shapes, dtypes and values in place; normalise bearings (raises InputError)."""
    src = m.source
    m.f1 = _bearings(src, "f1", m.f1)
    m.f2 = _bearings(src, "f2", m.f2)
    if len(m.f1) != len(m.f2):
        raise InputError(src, f"f1 has {len(m.f1)} rows but f2 has {len(m.f2)}", "f2")
    cam = np.asarray(m.cam)
    if cam.ndim != 1 or len(cam) != len(m.f1):
        raise InputError(src, f"expected shape ({len(m.f1)},), got {cam.shape}", "cam")
    if len(cam) and not np.issubdtype(cam.dtype, np.integer):
        if not (np.issubdtype(cam.dtype, np.floating) and np.all(np.isfinite(cam)) and np.all(cam == np.round(cam))):
            raise InputError(src, f"expected integer camera indices, got dtype {cam.dtype}", "cam")
    m.cam = cam.astype(np.int64)
    if len(m.cam) and m.cam.min() < 0:
        raise InputError(src, f"negative camera index at entry {int(np.argmax(m.cam < 0))}", "cam")
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
        idx = np.asarray(m.g_cam_index)
        if idx.shape != () or not np.issubdtype(idx.dtype, np.integer) or int(idx) < 0:
            raise InputError(src, f"expected a non-negative integer, got {m.g_cam_index!r}", "g_cam_index")
        m.g_cam_index = int(idx)


_KEYS = {"f1", "f2", "cam", "g1", "g2", "g1_cam", "g2_cam", "g_cam_index"}


def load_matches(path, rig: Rig | None = None) -> Matches:
    """Load and validate a matches .npz (SPEC section 7); bearings are normalised.

    With ``rig`` the camera indices are also checked against the rig.
    """
    src = str(path)
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise InputError(src, "no such matches file") from None
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(src, f"not a readable .npz file ({exc})") from None
    for key in ("f1", "f2", "cam"):
        if key not in data:
            raise InputError(src, "missing required array", key)
    unknown = sorted(set(data) - _KEYS)
    if unknown:
        raise InputError(src, f"unknown array (allowed: {', '.join(sorted(_KEYS))})", unknown[0])
    gci = data.get("g_cam_index")
    m = Matches(
        data["f1"], data["f2"], data["cam"], data.get("g1"), data.get("g2"), data.get("g1_cam"), data.get("g2_cam"),
        gci if gci is not None else None, source=src,
    )
    if rig is not None:
        m.check_rig(rig)
    return m


def save_matches(m: Matches, path) -> None:
    """Write a matches .npz (SPEC section 7)."""
    np.savez(Path(path), **m.to_npz_dict())
