"""Synthetic two-view problems of a bending rig (the paper's section 4 set-up).

Defaults follow the paper: VGA cameras with f = 800 px at the tips of a
regular cross, bars 0.4 m long with a 0.1 kg tip mass and EI = 0.1 N m^2,
points in [-2, 2] x [-2, 2] x [4, 8] m in front of each camera in view 1,
N = 1000, Gaussian pixel noise, a fraction of outliers with random bearings
and gravity measured in a camera's frame with noise given in pixels.
The motion follows the OpenGV generators the paper's authors use: rotation
from three random angles in [-max_rotation, max_rotation], translation
uniform in a cube of half-size max_translation.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ..core.deformation import deformed_extrinsics
from ..core.matches import Matches
from ..core.rig import Camera, ImuMount, Rig
from ..core.so3 import exp_so3, normalize, tangent_basis
from ..errors import OptionError

LAYOUTS = ("cross", "line", "ring")
LOOKING = ("outward", "forward")
GRAVITY_FRAMES = ("camera", "body", "none")


def default_layout(num_cameras: int) -> str:
    """The layout a simulated rig takes when none is given: the paper's cross for 4 cameras, else a ring."""
    return "cross" if num_cameras == 4 else "ring"


@dataclass
class RigSpec:
    """Geometry of a simulated rig: layout, camera count, bars and optics."""

    num_cameras: int = 4
    layout: str = "cross"
    looking: str = "outward"
    bar_length: float = 0.4  # m
    mass: float = 0.1  # kg
    EI: float = 0.1  # N m^2 (inf = rigid)
    focal: float = 800.0  # px
    resolution: tuple = (640, 480)

    def validate(self):
        """Raises OptionError (a ValueError) naming the field that is wrong."""
        if self.layout not in LAYOUTS:
            raise OptionError("rig spec", "layout", f"layout must be one of {LAYOUTS}, got {self.layout!r}")
        if self.looking not in LOOKING:
            raise OptionError("rig spec", "looking", f"looking must be one of {LOOKING}, got {self.looking!r}")
        if self.num_cameras < 1:
            raise OptionError("rig spec", "num_cameras", "num_cameras must be >= 1")
        if self.layout == "cross" and self.num_cameras != 4:
            raise OptionError("rig spec", "num_cameras",
                              "layout 'cross' has 4 cameras; use 'ring' or 'line' for other counts")


@dataclass
class Scenario:
    """Everything that defines a random two-view problem (besides the seed)."""

    rig: RigSpec = field(default_factory=RigSpec)
    num_points: int = 1000
    pixel_noise: float = 0.1  # px, std of Gaussian image noise
    outlier_fraction: float = 0.05
    gravity_noise_px: float = 0.01  # px-equivalent angular std of gravity measurements
    gravity_frame: str = "camera"  # where gravity is measured: camera | body | none
    max_rotation: float = 0.5  # rad, per random angle
    max_translation: float = 2.0  # m, half-size of the translation cube

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Scenario:
        d = dict(d)
        rig = RigSpec(**d.pop("rig", {}))
        return cls(rig=rig, **d)


def _camera_rotation(z_axis: np.ndarray) -> np.ndarray:
    """V (camera -> body) for an optical axis z_axis with image-down as close to body -z as possible."""
    z = normalize(z_axis)
    down = np.array([0.0, 0.0, -1.0])
    if abs(float(z @ down)) > 0.99:
        down = np.array([1.0, 0.0, 0.0])
    y = normalize(down - (down @ z) * z)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=1)


def make_rig(spec: RigSpec | None = None, imu: bool = True) -> Rig:
    """A rig of spec.num_cameras cameras on bars, body frame at the centre (z up)."""
    spec = spec or RigSpec()
    spec.validate()
    M, L = spec.num_cameras, spec.bar_length
    if spec.layout in ("cross", "ring"):
        ang = 2.0 * np.pi * np.arange(M) / M
        pos = L * np.stack([np.cos(ang), np.sin(ang), np.zeros(M)], axis=1)
    else:
        ys = np.linspace(-L, L, M) if M > 1 else np.array([L])
        pos = np.stack([np.zeros(M), ys, np.zeros(M)], axis=1)
    w, h = spec.resolution
    cams = []
    for i in range(M):
        p = pos[i]
        if spec.looking == "forward" or np.linalg.norm(p) < 1e-9:
            axis = np.array([1.0, 0.0, 0.0])
        else:
            axis = p
        flexible = np.linalg.norm(p) > 1e-9 and math.isfinite(spec.EI) and spec.mass > 0
        cams.append(Camera(
            name=f"cam{i}", model="pinhole", intrinsics=(spec.focal, spec.focal, (w - 1) / 2.0, (h - 1) / 2.0),
            distortion=(), resolution=(int(w), int(h)), position=p.copy(), rotation=_camera_rotation(axis),
            mass=spec.mass if flexible else 0.0, EI=spec.EI if flexible else math.inf,
            image_topic=f"/cam{i}/image_raw", info_topic=f"/cam{i}/camera_info",
        ))
    return Rig(cameras=tuple(cams), body_frame="base_link", gravity_magnitude=9.81,
               imu=ImuMount() if imu else None, source="<simulated rig>")


def random_rotation(rng: np.random.Generator, max_angle: float) -> np.ndarray:
    """OpenGV-style: product of rotations about x, y, z by angles uniform in [-max, max]."""
    a = rng.uniform(-max_angle, max_angle, size=3)
    return exp_so3(np.array([a[0], 0, 0])) @ exp_so3(np.array([0, a[1], 0])) @ exp_so3(np.array([0, 0, a[2]]))


def perturb_directions(rng: np.random.Generator, f: np.ndarray, sigma_rad: float) -> np.ndarray:
    """Unit vectors f (N, 3) moved by Gaussian tangent-plane noise of std sigma_rad per axis."""
    if sigma_rad <= 0:
        return normalize(f)
    T = tangent_basis(f)
    n = rng.normal(scale=sigma_rad, size=(len(f), 2))
    return normalize(f + np.einsum("nij,nj->ni", T, n))


@dataclass
class Problem:
    """One synthetic problem with its ground truth."""

    rig: Rig
    matches: Matches
    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray  # view-1 body frame
    inlier_mask: np.ndarray
    points: np.ndarray  # view-1 body frame

    def truth_dict(self) -> dict:
        return {
            "R": self.R.tolist(), "t": self.t.tolist(), "gravity": self.gravity.tolist(),
            "gravity2": (self.R.T @ self.gravity).tolist(), "outliers": np.flatnonzero(~self.inlier_mask).tolist(),
        }


def make_problem(scenario: Scenario | None = None, seed: int = 0, rig: Rig | None = None,
                 gravity: np.ndarray | None = None) -> Problem:
    """Draw one random two-view problem; deterministic for (scenario, seed).

    ``rig`` overrides the rig built from scenario.rig (e.g. a custom rig file);
    ``gravity`` fixes view-1 gravity (default: uniform random direction).
    """
    sc = scenario or Scenario()
    rng = np.random.default_rng(seed)
    rig = rig or make_rig(sc.rig)
    M, N = rig.num_cameras, sc.num_points
    gm = rig.gravity_magnitude
    g1 = gm * normalize(rng.normal(size=3)) if gravity is None else gm * normalize(np.asarray(gravity, float))
    R = random_rotation(rng, sc.max_rotation)
    t = rng.uniform(-sc.max_translation, sc.max_translation, size=3)
    g2 = R.T @ g1
    w1, W1 = deformed_extrinsics(rig, g1)
    w2, W2 = deformed_extrinsics(rig, g2)
    cam = np.sort(np.arange(N) % M)
    pc = np.stack([rng.uniform(-2, 2, N), rng.uniform(-2, 2, N), rng.uniform(4, 8, N)], axis=1)
    P = np.einsum("nij,nj->ni", W1[cam], pc) + w1[cam]
    f1 = normalize(pc)
    P2 = (P - t) @ R  # R^T (P - t)
    f2 = normalize(np.einsum("nji,nj->ni", W2[cam], P2 - w2[cam]))
    focal = float(np.mean([c.focal_px for c in rig.cameras]))
    f1 = perturb_directions(rng, f1, sc.pixel_noise / focal)
    f2 = perturb_directions(rng, f2, sc.pixel_noise / focal)
    n_out = int(round(sc.outlier_fraction * N))
    inlier = np.ones(N, dtype=bool)
    if n_out:
        idx = rng.choice(N, size=n_out, replace=False)
        inlier[idx] = False
        f2[idx] = normalize(rng.normal(size=(n_out, 3)))
    m = Matches(f1, f2, cam, source="<simulated>")
    gs = sc.gravity_noise_px / focal
    if sc.gravity_frame == "body":
        m.g1 = gm * perturb_directions(rng, g1[None] / gm, gs)[0]
        m.g2 = gm * perturb_directions(rng, g2[None] / gm, gs)[0]
    elif sc.gravity_frame == "camera":
        m.g1_cam = gm * perturb_directions(rng, (W1[0].T @ g1)[None] / gm, gs)[0]
        m.g2_cam = gm * perturb_directions(rng, (W2[0].T @ g2)[None] / gm, gs)[0]
        m.g_cam_index = 0
    elif sc.gravity_frame != "none":
        raise ValueError(f"gravity_frame must be one of {GRAVITY_FRAMES}")
    return Problem(rig=rig, matches=m, R=R, t=t, gravity=g1, inlier_mask=inlier, points=P)
