"""The rig: cameras, canonical extrinsics and bars (docs/CONVENTIONS.md (Frames, Files)).

``load_rig`` validates a rig YAML file and returns an immutable :class:`Rig`
whose per-camera quantities are also available as stacked numpy arrays, so
the deformation model can be evaluated for all cameras at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import yaml

from ..errors import InputError
from ..safeio import YAML_MAX_BYTES, atomic_write, load_yaml
from .so3 import exp_so3, matrix_to_quat_xyzw, quat_xyzw_to_matrix, skew

CAMERA_MODELS = ("pinhole", "equidistant")

# --- Plausibility bounds of a rig file (see docs/INPUTS.md) ------------------
# Values beyond these are typing errors or garbage; they would otherwise reach the
# estimator and fail deep inside it (singular systems, divisions by ~0).
MAX_CAMERAS = 1000  # a multi-camera rig has a handful of cameras; this bounds the stacked per-camera arrays
MAX_TIP_ROTATION_DEG = 60.0  # c_r |g| = m L^2 |g| / (2 EI) under 1 g; the small-deflection cantilever model is
#   meaningless far beyond (the paper's nominal rig, m 0.1 kg, L 0.4 m, EI 0.1 N m^2, bends 45 deg)
MAX_RESOLUTION_PX = 20_000  # per image side; the largest sensors in use are ~15 000 px wide
MIN_FOCAL_PX, MAX_FOCAL_PX = 1.0, 1e5  # below 1 px/rad an image holds no geometry; 1e5 px is a long telephoto
PRINCIPAL_POINT_MARGIN = 1.0  # cx, cy may lie outside the image by at most this many image sizes (cropped sensors)
MAX_DISTORTION_COEFF = 1e3  # real lenses calibrate to coefficients of order 1 (wide angles: tens at most)
MAX_POSITION_M = 100.0  # |v_i|: a rig carried by a robot is a few metres across
MAX_MASS_KG = 1000.0  # tip mass of one camera; a camera with its mount weighs a few kg
GRAVITY_RANGE = (0.1, 100.0)  # m/s^2: 9.81 on Earth, 1.62 on the Moon; outside is a unit or typing error
QUATERNION_NORM_TOLERANCE = 1e-3  # printed quaternions are rounded; further from unit norm is not a rotation
MAX_NAME_CHARS = 255  # ROS 2 limit on a node name; applied to camera names and frame ids
MAX_TOPIC_CHARS = 247  # ROS 2 limit on a topic name (255 less the 8 characters DDS prefixes take)
EI_INF_SPELLINGS = ("inf", "+inf", ".inf", "+.inf", "infinity", "+infinity")  # EI written as a string, any case
_DISTORTION_LENGTHS = {"pinhole": (0, 4, 5), "equidistant": (0, 4)}
_TOP_KEYS = {"body_frame", "gravity_magnitude", "imu", "cameras"}
_IMU_KEYS = {"topic", "mount", "rotation_xyzw"}
_CAMERA_KEYS = {
    "name", "image_topic", "info_topic", "model", "intrinsics", "distortion",
    "resolution", "position", "rotation_xyzw", "rotation_std_deg", "position_std_m", "bar",
}
MAX_ROTATION_STD_DEG = 10.0  # a calibration of a camera's rotation worse than this is no calibration
MAX_POSITION_STD_M = 0.1  # ... of its position
_BAR_KEYS = {"mass", "EI", "damping", "frequency_hz", "damping_std", "frequency_std_hz"}  # all but mass, EI:
# section 13 (the dynamics; nrmpc calibrate-bars writes them)


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
    damping: float | None = None  # damping ratio zeta_i of the bar's first bending mode; None: unknown
    damping_std: float | None = None  # its std (the bar calibration's); None: not given
    frequency_hz: float | None = None  # the bar's identified natural frequency (Hz); None: not given
    frequency_std_hz: float | None = None  # its std (Hz); None: not given
    rotation_std_deg: float = 0.0  # std per axis (deg) of the calibration of V_i: how well it is known; 0: exact
    position_std_m: float = 0.0  # std per axis (m) of the calibration of v_i; 0: exact
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
    """Where the IMU sits: at the body centre or inside a camera (docs/CONVENTIONS.md (Gravity measurements))."""

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
        """u_i (M, 3), c_d = m L^3/(3 EI) and c_r = m L^2/(2 EI) (M,), docs/CONVENTIONS.md (Bending).

        delta_i = c_d g_perp (m per m/s^2), phi_i = c_r (u_i x g) (rad per m/s^2).
        """
        v = self.positions
        L = np.linalg.norm(v, axis=1)
        u = np.where(L[:, None] > 0, v / np.maximum(L, 1e-300)[:, None], 0.0)
        k = self.compliance
        return _frozen(u), _frozen(k * L**3 / 3.0), _frozen(k * L**2 / 2.0)

    @cached_property
    def bar_derivatives(self):
        """Constant parts of the model's derivatives (docs/CONVENTIONS.md, Bending), (M, 3, 3) each:
        D_i = d delta_i / d g =
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

    def with_imu_in(self, camera: str, rotation=None) -> Rig:
        """The same rig with its IMU inside camera ``camera`` (``rotation``: IMU -> camera, default the camera's
        axes, as in a camera module with an IMU): it rides on that camera's bar."""
        self.camera_index(camera)  # KeyError for a camera the rig does not have
        imu = self.imu if self.imu is not None else ImuMount()
        return replace(self, imu=replace(imu, mount=camera,
                                         rotation=np.eye(3) if rotation is None else np.asarray(rotation, float)))

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

    def with_rotation_errors(self, std_deg: float, rng: np.random.Generator) -> Rig:
        """The rig as a calibration good to ``std_deg`` (per axis) gives it: each camera's rest rotation V_i turned
        about the camera's own axes by a random rotation of that std per axis, and ``rotation_std_deg`` saying
        so (the rig file of a real rig: never exact, at best with its std)."""
        cams = []
        for c in self.cameras:
            turn = exp_so3(rng.normal(scale=math.radians(std_deg), size=3))
            cams.append(replace(c, rotation=_frozen(c.rotation @ turn), rotation_std_deg=float(std_deg)))
        return replace(self, cameras=tuple(cams))

    def with_position_errors(self, std_m: float, rng: np.random.Generator) -> Rig:
        """The rig as a calibration good to ``std_m`` (per axis) gives it: each camera's rest position v_i moved by
        a random shift of that std per axis (body frame), and ``position_std_m`` saying so."""
        cams = tuple(replace(c, position=_frozen(c.position + rng.normal(scale=std_m, size=3)),
                             position_std_m=float(std_m)) for c in self.cameras)
        return replace(self, cameras=cams)

    def with_bar_ei(self, EI: float) -> Rig:
        """The rig with every bar that has a tip mass set to flexural rigidity EI (N m^2); inf = rigid."""
        return replace(self, cameras=tuple(replace(c, EI=float(EI)) if c.mass > 0 else c for c in self.cameras))

    def to_dict(self) -> dict:
        """The rig as the docs/CONVENTIONS.md (Files) mapping (round-trips through load_rig)."""
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
            for key in ("rotation_std_deg", "position_std_m"):
                if getattr(c, key) > 0:
                    d[key] = float(getattr(c, key))
            if c.info_topic and c.info_topic != _default_info_topic(c.image_topic):
                d["info_topic"] = c.info_topic
            if c.mass > 0 or math.isfinite(c.EI):
                d["bar"] = {"mass": float(c.mass), "EI": float(c.EI)}
                for key in ("damping", "damping_std", "frequency_hz", "frequency_std_hz"):
                    if getattr(c, key) is not None:
                        d["bar"][key] = float(getattr(c, key))
            cams.append(d)
        out["cameras"] = cams
        return out


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _default_info_topic(image_topic: str) -> str:
    """``camera_info`` beside the image topic: /cam0/image_raw -> /cam0/camera_info, image -> camera_info."""
    head, sep, _ = image_topic.rpartition("/")
    return f"{head}{sep}camera_info"


def save_rig(rig: Rig, path, header: str | None = None, flag: str | None = None) -> None:
    """Write a rig YAML file (docs/CONVENTIONS.md (Files)) atomically (:func:`~nrmpc_ros.safeio.atomic_write`);
    ``header`` lines become comments, ``flag`` names the option in errors."""
    text = yaml.safe_dump(rig.to_dict(), sort_keys=False, default_flow_style=None)
    if header:
        text = "".join(f"# {line}\n" for line in header.splitlines()) + text
    with atomic_write(path, flag=flag) as fh:
        fh.write(text)


# ---------------------------------------------------------------------------
# Validation (accepted values and bounds: docs/INPUTS.md)
# ---------------------------------------------------------------------------

def _type_name(value) -> str:
    if isinstance(value, bool):
        return "a boolean (YAML reads yes/no/on/off/true/false as booleans)"
    if value is None:
        return "null (nothing)"
    if isinstance(value, str):
        return f"the string {value!r}"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return "a list"
    return f"{type(value).__name__} {value!r}"


def _number(src, field_name, value, allow_inf=False) -> float:
    """A YAML int or float as float; a bool, a string (but EI's inf spellings) or anything else is an error."""
    if allow_inf and isinstance(value, str) and value.strip().lower() in EI_INF_SPELLINGS:
        return math.inf  # YAML reads a bare `inf` as a string; `.inf` is the YAML float
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        hint = " (.inf for infinity)" if allow_inf else ""
        raise InputError(src, f"expected a number{hint}, got {_type_name(value)}", field_name)
    try:
        x = float(value)
    except OverflowError:  # an int beyond the float range (do not print it: it may have thousands of digits)
        raise InputError(src, "integer too large to be a number of this file", field_name) from None
    if math.isnan(x) or (math.isinf(x) and not (allow_inf and x > 0)):
        raise InputError(src, f"must be a finite number, got {x}", field_name)
    return x


def _in_range(src, field_name, x, lo, hi, unit="", label=None) -> float:
    """``x`` if lo <= x <= hi, else an InputError giving the plausible range (``label`` names the entry)."""
    if not lo <= x <= hi:
        u = f" {unit}" if unit else ""
        what = f"{label} = " if label else ""
        raise InputError(src, f"{what}{x:.6g}{u} is outside the plausible range [{lo:g}, {hi:g}]{u}", field_name)
    return x


def _vector(src, field_name, value, length=None, lengths=None) -> np.ndarray:
    if not isinstance(value, (list, tuple)):
        raise InputError(src, f"expected a list of numbers, got {_type_name(value)}", field_name)
    if length is not None and len(value) != length:
        raise InputError(src, f"expected {length} numbers, got {len(value)}", field_name)
    if lengths is not None and len(value) not in lengths:
        raise InputError(src, f"expected one of {lengths} numbers, got {len(value)}", field_name)
    return np.array([_number(src, f"{field_name}[{j}]", x) for j, x in enumerate(value)], dtype=float)


def _rotation(src, field_name, value) -> np.ndarray:
    q = _vector(src, field_name, value, length=4)
    n = math.hypot(*q)  # no overflow for absurd entries
    if abs(n - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise InputError(src, f"quaternion (x, y, z, w) must have unit norm, got norm {n:.6g}", field_name)
    return quat_xyzw_to_matrix(q)


def _check_keys(src, prefix, mapping, allowed, required=()):
    if not isinstance(mapping, dict):
        raise InputError(src, f"expected a mapping, got {_type_name(mapping)}", prefix or None)
    unknown = sorted((k for k in mapping if k not in allowed), key=repr)
    if unknown:
        key = unknown[0] if isinstance(unknown[0], str) else repr(unknown[0])
        name = f"{prefix}.{key}" if prefix else key
        raise InputError(src, f"unknown key (allowed: {', '.join(sorted(allowed))})", name)
    for key in required:
        if key not in mapping:
            raise InputError(src, "missing required field", f"{prefix}.{key}" if prefix else key)


def _string(src, field_name, value) -> str:
    if not isinstance(value, str):
        raise InputError(src, f"expected a string, got {_type_name(value)}", field_name)
    return value


_NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_")


def _ros_name(src, field_name, value) -> str:
    """A ROS 2 base name (camera name, frame id): letters, digits and underscores, not starting with a digit."""
    name = _string(src, field_name, value)
    if not name:
        raise InputError(src, "must not be empty", field_name)
    if len(name) > MAX_NAME_CHARS:
        raise InputError(src, f"longer than {MAX_NAME_CHARS} characters", field_name)
    bad = sorted(set(name) - _NAME_CHARS)
    if bad:
        raise InputError(src, f"{name!r} is not a valid ROS name: only letters, digits and underscores "
                              f"(found {bad[0]!r})", field_name)
    if name[0].isdigit():
        raise InputError(src, f"{name!r} is not a valid ROS name: must not start with a digit", field_name)
    return name


def _ros_topic(src, field_name, value) -> str:
    """A ROS 2 topic name, absolute (/a/b) or relative (a/b, ~/a): tokens of letters, digits and underscores
    that do not start with a digit, separated by single slashes, no trailing slash, ``~`` only as the first
    token. Substitutions ({node}) are not accepted in a rig file."""
    topic = _string(src, field_name, value)

    def bad(why):
        raise InputError(src, f"{topic!r} is not a valid ROS 2 topic name: {why}", field_name)

    if not topic:
        bad("empty")
    if len(topic) > MAX_TOPIC_CHARS:
        bad(f"longer than {MAX_TOPIC_CHARS} characters")
    if "{" in topic or "}" in topic:
        bad("substitutions ({...}) are not supported in a rig file")
    if "~" in topic[1:]:
        bad("'~' may only be the first character")
    if topic.endswith("/"):
        bad("must not end with '/'")
    rest = topic[1:] if topic.startswith("~") else topic  # "~" alone is the node's private namespace
    if topic.startswith("~") and rest and not rest.startswith("/"):
        bad("'~' must be followed by '/'")
    chars = sorted(set(rest) - _NAME_CHARS - {"/"})
    if chars:
        bad(f"only letters, digits, underscores and '/' (found {chars[0]!r})")
    tokens = rest.split("/") if rest else []
    for tok in tokens[1:] if rest.startswith("/") else tokens:
        if not tok:
            bad("empty token (repeated '/')")
        if tok[0].isdigit():
            bad(f"token {tok!r} starts with a digit")
    return topic


def _bar(src, p, name, bar, pos, gm) -> tuple[float, float]:
    """(m_i in kg, EI_i in N m^2) of a ``bar`` block, refused where the cantilever model stops holding."""
    _check_keys(src, f"{p}.bar", bar, _BAR_KEYS, ("mass", "EI"))
    mass = _number(src, f"{p}.bar.mass", bar["mass"])
    ei = _number(src, f"{p}.bar.EI", bar["EI"], allow_inf=True)
    _in_range(src, f"{p}.bar.mass", mass, 0.0, MAX_MASS_KG, "kg", "tip mass")
    if ei <= 0:
        raise InputError(src, f"flexural rigidity must be > 0 N m^2 (.inf for rigid), got {ei}", f"{p}.bar.EI")
    if mass == 0 or math.isinf(ei):
        return mass, ei
    L = math.hypot(*pos)
    if L < 1e-9:
        raise InputError(src, "a flexible bar needs a camera away from the body centre (bar length 0)",
                         f"{p}.position")
    # Under 1 g transverse: tip displacement c_d |g| = m L^3 |g| / (3 EI) (m), rotation c_r |g| = m L^2 |g| / (2 EI).
    load = mass * gm / ei  # 1/m^2
    disp, rot = load * L**3 / 3.0, load * L**2 / 2.0
    if disp > L:
        raise InputError(src, f"camera {name!r}: tip displacement under 1 g, m L^3 g / (3 EI) = {disp:.3g} m, "
                              f"exceeds the bar length {L:.3g} m: check bar.mass, bar.EI and position", f"{p}.bar")
    if math.degrees(rot) > MAX_TIP_ROTATION_DEG:
        raise InputError(src, f"camera {name!r}: tip rotation under 1 g, m L^2 g / (2 EI) = {math.degrees(rot):.3g} "
                              f"deg, exceeds {MAX_TIP_ROTATION_DEG:g} deg where the small-deflection bar model "
                              f"stops holding: check bar.mass, bar.EI and position", f"{p}.bar")
    return mass, ei


def _damping(src, p, bar) -> float | None:
    """The bar's damping ratio zeta_i (docs/CONVENTIONS.md, "The rig in motion"): in (0, 1), or None if absent."""
    if bar.get("damping") is None:
        return None
    zeta = _number(src, f"{p}.bar.damping", bar["damping"])
    if not 0.0 < zeta < 1.0:
        raise InputError(src, f"damping ratio must be in (0, 1) (an under-damped bar rings), got {zeta}",
                         f"{p}.bar.damping")
    return zeta


def _dynamics_numbers(src, p, bar) -> dict:
    """The bar's optional ``damping_std``, ``frequency_hz`` and ``frequency_std_hz`` (docs/CONVENTIONS.md, "The
    rig in motion"): finite, the frequency positive, the stds not negative; None where absent."""
    out = {}
    for key, positive in (("damping_std", False), ("frequency_hz", True), ("frequency_std_hz", False)):
        if bar.get(key) is None:
            out[key] = None
            continue
        v = _number(src, f"{p}.bar.{key}", bar[key])
        if v < 0 or (positive and v == 0):
            raise InputError(src, f"must be {'positive' if positive else 'zero or positive'}, got {v}",
                             f"{p}.bar.{key}")
        out[key] = v
    return out


def _intrinsics(src, p, d, model):
    intr = _vector(src, f"{p}.intrinsics", d["intrinsics"], length=4)
    for j, axis in enumerate(("fx", "fy")):
        if intr[j] <= 0:
            raise InputError(src, "focal lengths fx, fy must be positive", f"{p}.intrinsics")
        _in_range(src, f"{p}.intrinsics", intr[j], MIN_FOCAL_PX, MAX_FOCAL_PX, "px", axis)
    res = _vector(src, f"{p}.resolution", d["resolution"], length=2)
    if np.any(res <= 0) or np.any(res != np.round(res)):
        raise InputError(src, "width and height must be positive integers", f"{p}.resolution")
    for j, axis in enumerate(("width", "height")):
        _in_range(src, f"{p}.resolution", res[j], 1, MAX_RESOLUTION_PX, "px", axis)
        m = PRINCIPAL_POINT_MARGIN * res[j]
        _in_range(src, f"{p}.intrinsics", intr[j + 2], -m, res[j] + m, "px", "cx" if j == 0 else "cy")
    dist = d.get("distortion")
    dist = _vector(src, f"{p}.distortion", [] if dist is None else dist, lengths=_DISTORTION_LENGTHS[model])
    for j, k in enumerate(dist):
        _in_range(src, f"{p}.distortion[{j}]", k, -MAX_DISTORTION_COEFF, MAX_DISTORTION_COEFF)
    return intr, dist, res


def _parse_camera(src, i, d, gm) -> Camera:
    p = f"cameras[{i}]"
    _check_keys(src, p, d, _CAMERA_KEYS, ("name", "model", "intrinsics", "resolution", "position", "rotation_xyzw"))
    name = _ros_name(src, f"{p}.name", d["name"])
    model = d["model"]
    if not isinstance(model, str) or model not in CAMERA_MODELS:
        raise InputError(src, f"unknown camera model {model!r} (supported: {', '.join(CAMERA_MODELS)})", f"{p}.model")
    intr, dist, res = _intrinsics(src, p, d, model)
    pos = _vector(src, f"{p}.position", d["position"], length=3)
    if math.hypot(*pos) > MAX_POSITION_M:  # hypot: no overflow for absurd entries
        raise InputError(src, f"|position| = {math.hypot(*pos):.3g} m is beyond the plausible "
                              f"{MAX_POSITION_M:g} m from the body centre", f"{p}.position")
    rot = _rotation(src, f"{p}.rotation_xyzw", d["rotation_xyzw"])
    stds = {}
    for key, top, unit in (("rotation_std_deg", MAX_ROTATION_STD_DEG, "deg"), ("position_std_m", MAX_POSITION_STD_M,
                                                                                "m")):
        stds[key] = 0.0 if d.get(key) is None else _in_range(src, f"{p}.{key}", _number(src, f"{p}.{key}", d[key]),
                                                             0.0, top, unit)
    mass, ei, damping, dyn = 0.0, math.inf, None, {}
    if d.get("bar") is not None:
        mass, ei = _bar(src, p, name, d["bar"], pos, gm)
        damping = _damping(src, p, d["bar"])
        dyn = _dynamics_numbers(src, p, d["bar"])
    image_topic = _ros_topic(src, f"{p}.image_topic", d.get("image_topic", f"/{name}/image_raw"))
    info_topic = _ros_topic(src, f"{p}.info_topic", d.get("info_topic", _default_info_topic(image_topic)))
    return Camera(
        name=name, model=model, intrinsics=tuple(intr), distortion=tuple(dist), resolution=tuple(int(x) for x in res),
        position=pos, rotation=rot, mass=mass, EI=ei, damping=damping, image_topic=image_topic, info_topic=info_topic,
        **stds, **dyn,
    )


def _check_unique(src, cameras, imu) -> None:
    """Names and topics that must not be shared: a topic read as two things would mix their messages."""
    names, images, infos = {}, {}, {}
    for i, c in enumerate(cameras):
        if c.name in names:
            raise InputError(src, f"duplicate camera name {c.name!r} (also cameras[{names[c.name]}])",
                             f"cameras[{i}].name")
        names[c.name] = i
        if c.image_topic in images:
            raise InputError(src, f"image topic {c.image_topic!r} is also the image topic of "
                                  f"cameras[{images[c.image_topic]}]", f"cameras[{i}].image_topic")
        images[c.image_topic] = i
        if c.info_topic in infos:
            raise InputError(src, f"info topic {c.info_topic!r} is also the info topic of "
                                  f"cameras[{infos[c.info_topic]}]", f"cameras[{i}].info_topic")
        infos[c.info_topic] = i
    for i, c in enumerate(cameras):
        if c.info_topic in images:
            raise InputError(src, f"info topic {c.info_topic!r} is the image topic of "
                                  f"cameras[{images[c.info_topic]}]", f"cameras[{i}].info_topic")
    if imu is not None:
        if imu.topic in images:
            raise InputError(src, f"IMU topic {imu.topic!r} is the image topic of cameras[{images[imu.topic]}]",
                             "imu.topic")
        if imu.topic in infos:
            raise InputError(src, f"IMU topic {imu.topic!r} is the info topic of cameras[{infos[imu.topic]}]",
                             "imu.topic")


def _parse_imu(src, d, camera_names) -> ImuMount:
    _check_keys(src, "imu", d, _IMU_KEYS)
    mount = _string(src, "imu.mount", d.get("mount", "body"))
    if mount != "body" and mount not in camera_names:
        raise InputError(src, f"mount must be 'body' or a camera name, got {mount!r}", "imu.mount")
    rot = _rotation(src, "imu.rotation_xyzw", d.get("rotation_xyzw", [0, 0, 0, 1]))
    return ImuMount(topic=_ros_topic(src, "imu.topic", d.get("topic", "/imu/data")), mount=mount, rotation=rot)


def rig_from_dict(data, source: str = "<rig>") -> Rig:
    """Validate a docs/CONVENTIONS.md (Files) mapping and build a :class:`Rig`.

    Types are strict (a YAML boolean is not a number, a name is a string),
    names and topics follow the ROS 2 rules, and values beyond the
    plausibility bounds of this module are refused (see docs/INPUTS.md).
    Every error is an :class:`~nrmpc_ros.errors.InputError` naming ``source``
    and the field.
    """
    src = source
    _check_keys(src, "", data, _TOP_KEYS, ("cameras",))
    gm = _number(src, "gravity_magnitude", data.get("gravity_magnitude", 9.81))
    _in_range(src, "gravity_magnitude", gm, *GRAVITY_RANGE, "m/s^2")
    body_frame = _ros_name(src, "body_frame", data.get("body_frame", "base_link"))
    cams_raw = data["cameras"]
    if not isinstance(cams_raw, list) or not cams_raw:
        raise InputError(src, "expected a non-empty list of cameras", "cameras")
    if len(cams_raw) > MAX_CAMERAS:
        raise InputError(src, f"{len(cams_raw)} cameras, more than the {MAX_CAMERAS} a rig may have", "cameras")
    cameras = tuple(_parse_camera(src, i, d, gm) for i, d in enumerate(cams_raw))
    imu = None
    if data.get("imu") is not None:
        imu = _parse_imu(src, data["imu"], {c.name for c in cameras})
    _check_unique(src, cameras, imu)
    return Rig(cameras=cameras, body_frame=body_frame, gravity_magnitude=gm, imu=imu, source=src)


def load_rig(path) -> Rig:
    """Load and validate a rig YAML file (docs/CONVENTIONS.md (Files)).

    The file is read through :func:`nrmpc_ros.safeio.load_yaml` (UTF-8, at most
    ``YAML_MAX_BYTES``, bounded aliases and nesting) and validated by
    :func:`rig_from_dict`. Raises :class:`~nrmpc_ros.errors.InputError` naming
    the file and the field for anything it cannot use.
    """
    data = load_yaml(path, what="rig file", max_bytes=YAML_MAX_BYTES)
    if data is None:
        raise InputError(str(path), "the rig file is empty")
    return rig_from_dict(data, source=str(path))
