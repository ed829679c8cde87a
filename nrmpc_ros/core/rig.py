"""The rig: cameras, canonical extrinsics and bars (SPEC sections 2 and 7).

``load_rig`` validates a rig YAML file and returns an immutable :class:`Rig`
whose per-camera quantities are also available as stacked numpy arrays, so
the deformation model can be evaluated for all cameras at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import yaml

from ..errors import InputError
from .so3 import matrix_to_quat_xyzw, quat_xyzw_to_matrix, skew

CAMERA_MODELS = ("pinhole", "equidistant")
_DISTORTION_LENGTHS = {"pinhole": (0, 4, 5), "equidistant": (0, 4)}
_TOP_KEYS = {"body_frame", "gravity_magnitude", "imu", "cameras"}
_IMU_KEYS = {"topic", "mount", "rotation_xyzw"}
_CAMERA_KEYS = {
    "name", "image_topic", "info_topic", "model", "intrinsics", "distortion",
    "resolution", "position", "rotation_xyzw", "bar",
}
_BAR_KEYS = {"mass", "EI"}


@dataclass(frozen=True)
class Camera:
    """One camera: intrinsics and canonical (unbent) extrinsics (v_i, V_i)."""

    name: str
    model: str
    intrinsics: tuple  # fx, fy, cx, cy (pixels)
    distortion: tuple
    resolution: tuple  # width, height (pixels)
    position: np.ndarray  # v_i (m) in the body frame
    rotation: np.ndarray  # V_i: camera -> body
    mass: float = 0.0  # tip mass m_i (kg)
    EI: float = math.inf  # flexural rigidity (N m^2)
    image_topic: str = ""
    info_topic: str = ""

    @property
    def is_flexible(self) -> bool:
        return self.mass > 0.0 and math.isfinite(self.EI)

    @property
    def focal_px(self) -> float:
        return 0.5 * (self.intrinsics[0] + self.intrinsics[1])


@dataclass(frozen=True)
class ImuMount:
    """Where the IMU sits: at the body centre or inside a camera (SPEC section 4)."""

    topic: str = "/imu/data"
    mount: str = "body"
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # IMU -> mount frame


@dataclass(frozen=True)
class Rig:
    """A non-rigid multi-perspective camera."""

    cameras: tuple
    body_frame: str = "base_link"
    gravity_magnitude: float = 9.81
    imu: ImuMount | None = None
    source: str = "<rig>"

    # Stacked views used by the vectorised model (computed once; read-only) ---
    @property
    def num_cameras(self) -> int:
        return len(self.cameras)

    @cached_property
    def positions(self) -> np.ndarray:
        """(M, 3) canonical positions v_i."""
        return _frozen(np.array([c.position for c in self.cameras], dtype=float).reshape(-1, 3))

    @cached_property
    def rotations(self) -> np.ndarray:
        """(M, 3, 3) canonical rotations V_i (camera -> body)."""
        return _frozen(np.array([c.rotation for c in self.cameras], dtype=float).reshape(-1, 3, 3))

    @cached_property
    def compliance(self) -> np.ndarray:
        """(M,) m_i / EI_i in kg/(N m^2); 0 for rigid mounts."""
        return _frozen(np.array([c.mass / c.EI if c.is_flexible else 0.0 for c in self.cameras], dtype=float))

    @cached_property
    def bar_coefficients(self):
        """u_i (M, 3), c_d = m L^3/(3 EI) and c_r = m L^2/(2 EI) (M,), SPEC section 3.

        delta_i = c_d g_perp (m per m/s^2), phi_i = c_r (u_i x g) (rad per m/s^2).
        """
        v = self.positions
        L = np.linalg.norm(v, axis=1)
        u = np.where(L[:, None] > 0, v / np.maximum(L, 1e-300)[:, None], 0.0)
        k = self.compliance
        return _frozen(u), _frozen(k * L**3 / 3.0), _frozen(k * L**2 / 2.0)

    @cached_property
    def bar_derivatives(self):
        """Constant parts of the model's derivatives (SPEC section 3), (M, 3, 3) each: D_i = d delta_i / d g =
        c_d (I - u_i u_i^T) and c_r [u_i]_x (see :func:`.deformation.deformation_jacobians`)."""
        u, cd, cr = self.bar_coefficients
        D = cd[:, None, None] * (np.eye(3) - u[:, :, None] * u[:, None, :])
        return _frozen(D), _frozen(cr[:, None, None] * skew(u))

    @property
    def is_flexible(self) -> bool:
        return any(c.is_flexible for c in self.cameras)

    def camera_index(self, name: str) -> int:
        for i, c in enumerate(self.cameras):
            if c.name == name:
                return i
        raise KeyError(name)

    def as_rigid(self) -> Rig:
        """The same rig with every bar rigid (what a rigid-rig user assumes)."""
        return replace(self, cameras=tuple(replace(c, mass=0.0, EI=math.inf) for c in self.cameras))

    def with_compliance(self, compliance) -> Rig:
        """The rig with bar compliance m/EI set per camera, keeping each mass (EI = m / c)."""
        comp = np.broadcast_to(np.asarray(compliance, dtype=float), (self.num_cameras,))
        cams = []
        for c, k in zip(self.cameras, comp):
            mass = c.mass if c.mass > 0 else 1.0
            ei = mass / k if k > 0 else math.inf
            cams.append(replace(c, mass=mass if k > 0 else c.mass, EI=ei))
        return replace(self, cameras=tuple(cams))

    def to_dict(self) -> dict:
        """The rig as the SPEC section 7 mapping (round-trips through load_rig)."""
        out = {"body_frame": self.body_frame, "gravity_magnitude": float(self.gravity_magnitude)}
        if self.imu is not None:
            out["imu"] = {
                "topic": self.imu.topic,
                "mount": self.imu.mount,
                "rotation_xyzw": [float(x) for x in matrix_to_quat_xyzw(self.imu.rotation)],
            }
        cams = []
        for c in self.cameras:
            d = {
                "name": c.name,
                "image_topic": c.image_topic,
                "model": c.model,
                "intrinsics": [float(x) for x in c.intrinsics],
                "distortion": [float(x) for x in c.distortion],
                "resolution": [int(x) for x in c.resolution],
                "position": [float(x) for x in c.position],
                "rotation_xyzw": [float(x) for x in matrix_to_quat_xyzw(c.rotation)],
            }
            if c.info_topic and c.info_topic != _default_info_topic(c.image_topic):
                d["info_topic"] = c.info_topic
            if c.mass > 0 or math.isfinite(c.EI):
                d["bar"] = {"mass": float(c.mass), "EI": float(c.EI)}
            cams.append(d)
        out["cameras"] = cams
        return out


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _default_info_topic(image_topic: str) -> str:
    head, _, _ = image_topic.rpartition("/")
    return f"{head}/camera_info"


def save_rig(rig: Rig, path, header: str | None = None) -> None:
    """Write a rig YAML file (SPEC section 7); ``header`` lines become comments."""
    text = yaml.safe_dump(rig.to_dict(), sort_keys=False, default_flow_style=None)
    if header:
        text = "".join(f"# {line}\n" for line in header.splitlines()) + text
    Path(path).write_text(text)


# ---------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------

def _vector(src, field_name, value, length=None, lengths=None) -> np.ndarray:
    if not isinstance(value, (list, tuple)):
        raise InputError(src, f"expected a list of numbers, got {value!r}", field_name)
    try:
        arr = np.array([float(x) for x in value], dtype=float)
    except (TypeError, ValueError):
        raise InputError(src, f"expected numbers, got {value!r}", field_name) from None
    if length is not None and arr.shape != (length,):
        raise InputError(src, f"expected {length} numbers, got {len(arr)}", field_name)
    if lengths is not None and len(arr) not in lengths:
        raise InputError(src, f"expected one of {lengths} numbers, got {len(arr)}", field_name)
    if not np.all(np.isfinite(arr)):
        raise InputError(src, f"must be finite, got {value!r}", field_name)
    return arr


def _rotation(src, field_name, value) -> np.ndarray:
    q = _vector(src, field_name, value, length=4)
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > 1e-3:
        raise InputError(src, f"quaternion (x, y, z, w) must have unit norm, got norm {n:.6g}", field_name)
    return quat_xyzw_to_matrix(q)


def _check_keys(src, prefix, mapping, allowed, required=()):
    if not isinstance(mapping, dict):
        raise InputError(src, f"expected a mapping, got {type(mapping).__name__}", prefix or None)
    unknown = sorted(set(mapping) - allowed)
    if unknown:
        name = f"{prefix}.{unknown[0]}" if prefix else unknown[0]
        raise InputError(src, f"unknown key (allowed: {', '.join(sorted(allowed))})", name)
    for key in required:
        if key not in mapping:
            raise InputError(src, "missing required field", f"{prefix}.{key}" if prefix else key)


def _number(src, field_name, value, allow_inf=False) -> float:
    if allow_inf and isinstance(value, str) and value.strip().lower().lstrip("+.") in ("inf", "infinity"):
        return math.inf  # YAML reads a bare `inf` as a string; `.inf` is the YAML float
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(src, f"expected a number, got {value!r}", field_name) from None
    if math.isnan(x) or (math.isinf(x) and not allow_inf):
        raise InputError(src, f"must be a finite number, got {value!r}", field_name)
    return x


def _parse_camera(src, i, d) -> Camera:
    p = f"cameras[{i}]"
    _check_keys(src, p, d, _CAMERA_KEYS, ("name", "model", "intrinsics", "resolution", "position", "rotation_xyzw"))
    name = str(d["name"])
    model = d["model"]
    if model not in CAMERA_MODELS:
        raise InputError(src, f"unknown camera model {model!r} (supported: {', '.join(CAMERA_MODELS)})", f"{p}.model")
    intr = _vector(src, f"{p}.intrinsics", d["intrinsics"], length=4)
    if intr[0] <= 0 or intr[1] <= 0:
        raise InputError(src, "focal lengths fx, fy must be positive", f"{p}.intrinsics")
    dist = _vector(src, f"{p}.distortion", d.get("distortion", []) or [], lengths=_DISTORTION_LENGTHS[model])
    res = _vector(src, f"{p}.resolution", d["resolution"], length=2)
    if np.any(res <= 0) or np.any(res != np.round(res)):
        raise InputError(src, "width and height must be positive integers", f"{p}.resolution")
    pos = _vector(src, f"{p}.position", d["position"], length=3)
    rot = _rotation(src, f"{p}.rotation_xyzw", d["rotation_xyzw"])
    mass, ei = 0.0, math.inf
    bar = d.get("bar")
    if bar is not None:
        _check_keys(src, f"{p}.bar", bar, _BAR_KEYS, ("mass", "EI"))
        mass = _number(src, f"{p}.bar.mass", bar["mass"])
        ei = _number(src, f"{p}.bar.EI", bar["EI"], allow_inf=True)
        if mass < 0:
            raise InputError(src, f"tip mass must be >= 0 kg, got {mass}", f"{p}.bar.mass")
        if ei <= 0:
            raise InputError(src, f"flexural rigidity must be > 0 N m^2 (.inf for rigid), got {ei}", f"{p}.bar.EI")
        if mass > 0 and math.isfinite(ei) and np.linalg.norm(pos) < 1e-9:
            raise InputError(src, "a flexible bar needs a camera away from the body centre (bar length 0)",
                             f"{p}.position")
    image_topic = str(d.get("image_topic", f"/{name}/image_raw"))
    info_topic = str(d.get("info_topic", _default_info_topic(image_topic)))
    return Camera(
        name=name, model=model, intrinsics=tuple(intr), distortion=tuple(dist), resolution=tuple(int(x) for x in res),
        position=pos, rotation=rot, mass=mass, EI=ei, image_topic=image_topic, info_topic=info_topic,
    )


def rig_from_dict(data, source: str = "<rig>") -> Rig:
    """Validate a SPEC section 7 mapping and build a :class:`Rig`."""
    src = source
    _check_keys(src, "", data, _TOP_KEYS, ("cameras",))
    cams_raw = data["cameras"]
    if not isinstance(cams_raw, list) or not cams_raw:
        raise InputError(src, "expected a non-empty list of cameras", "cameras")
    cameras = tuple(_parse_camera(src, i, d) for i, d in enumerate(cams_raw))
    seen = set()
    for i, c in enumerate(cameras):
        if c.name in seen:
            raise InputError(src, f"duplicate camera name {c.name!r}", f"cameras[{i}].name")
        seen.add(c.name)
    gm = _number(src, "gravity_magnitude", data.get("gravity_magnitude", 9.81))
    if gm <= 0:
        raise InputError(src, f"must be > 0 m/s^2, got {gm}", "gravity_magnitude")
    imu = None
    if data.get("imu") is not None:
        d = data["imu"]
        _check_keys(src, "imu", d, _IMU_KEYS)
        mount = str(d.get("mount", "body"))
        if mount != "body" and mount not in seen:
            raise InputError(src, f"mount must be 'body' or a camera name, got {mount!r}", "imu.mount")
        rot = _rotation(src, "imu.rotation_xyzw", d.get("rotation_xyzw", [0, 0, 0, 1]))
        imu = ImuMount(topic=str(d.get("topic", "/imu/data")), mount=mount, rotation=rot)
    return Rig(
        cameras=cameras, body_frame=str(data.get("body_frame", "base_link")), gravity_magnitude=gm, imu=imu, source=src,
    )


def load_rig(path) -> Rig:
    """Load and validate a rig YAML file (SPEC section 7).

    Raises :class:`~nrmpc_ros.errors.InputError` naming the file and the field
    for unknown keys, missing fields, negative mass or EI, non-unit
    quaternions, unknown camera models and duplicate camera names.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise InputError(str(path), f"cannot read rig file ({exc.strerror})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputError(str(path), f"not valid YAML ({exc})") from None
    if data is None:
        raise InputError(str(path), "the rig file is empty")
    return rig_from_dict(data, source=str(path))
