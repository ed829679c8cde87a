"""What ``~/markers`` shows, without ROS: the rig's bars, bent cameras, gravity with its uncertainty, and its state.

The node turns :func:`build_markers` into a visualization_msgs/MarkerArray
(:func:`marker_array_fields`), all in the body frame (README, "The ROS 2 node"):

- ``bars_rest`` / ``bars_bent``: one line per bar from the body origin to its
  camera's rest position (the canonical extrinsics, grey) and to its bent
  position at the published gravity (orange);
- ``cameras``: a frustum per camera at its bent pose (OpenCV optical axes:
  z forward, x right, y down) with the camera's field of view;
- ``gravity``: an arrow along gravity, and ``gravity_cone`` the cone of its
  2-standard-deviation uncertainty (the ellipse of the 2x2 angular covariance
  of its direction, docs/CONVENTIONS.md "Frames");
- ``state``: the rig's state (moving, settling, measuring hold N, hold N
  estimated) and the last estimate.

The bending model is linear in gravity (docs/CONVENTIONS.md "Bending"), so the
bend drawn with ``bend_scale`` is the model's at ``bend_scale * g``: positions
and rotations of the cameras exaggerated alike, so millimetres of bending
show at the scale of the rig. Sizes follow the rig: the frustum depth and the
arrow length are fractions of the median bar (camera distance from the origin).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from ..core.attitude import tangent_covariance
from ..core.deformation import deformed_extrinsics
from ..core.rig import Rig
from ..core.so3 import normalize, tangent_basis
from .outputs import HoldOutput
from .pipeline import RigStatus

CONE_SIGMAS = 2.0  # the cone's half-angle in standard deviations of gravity's direction
CONE_SEGMENTS = 24  # triangles around the cone
FRUSTUM_DEPTH = 0.25  # frustum depth as a share of the median bar
ARROW_LENGTH = 0.75  # gravity arrow as a share of the median bar
DEFAULT_SIZE_M = 0.1  # the rig's size when every camera sits at the origin


class MarkerKind(enum.IntEnum):
    """visualization_msgs/Marker types used here (the message's own numbers)."""

    ARROW = 0
    LINE_LIST = 5
    TRIANGLE_LIST = 11
    TEXT_VIEW_FACING = 9


@dataclass
class MarkerSpec:
    """One marker: namespace and id (unique together), kind, points (N, 3) in the body frame (m), RGBA colour,
    scale (line width, arrow shaft/head diameters or text height, m) and text."""

    ns: str
    id: int
    kind: MarkerKind
    points: np.ndarray
    color: tuple
    scale: tuple
    text: str = ""
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the marker's pose (text anchor)


@dataclass
class RigMarkers:
    """Every marker of one state of the rig; ``replaces_all``: a MarkerArray starts with DELETEALL so what the
    previous state showed (a gravity arrow, say) does not linger."""

    markers: list
    replaces_all: bool = True

    def by_ns(self, ns: str) -> list:
        return [m for m in self.markers if m.ns == ns]


GREY = (0.6, 0.6, 0.6, 1.0)
ORANGE = (1.0, 0.55, 0.0, 1.0)
BLUE = (0.2, 0.5, 1.0, 1.0)
RED = (0.9, 0.1, 0.1, 1.0)
CONE = (0.9, 0.1, 0.1, 0.3)
WHITE = (1.0, 1.0, 1.0, 1.0)


def rig_size_m(rig: Rig) -> float:
    """The median camera distance from the body origin (m): the scale the markers are drawn at."""
    d = np.linalg.norm(rig.positions, axis=1)
    d = d[d > 0]
    return float(np.median(d)) if len(d) else DEFAULT_SIZE_M


def _frustum_lines(rig: Rig, w: np.ndarray, W: np.ndarray, depth: float) -> np.ndarray:
    """(M * 16, 3) line-list points: apex to the four image corners at ``depth`` and the rectangle between them."""
    out = []
    for cam, c, R in zip(rig.cameras, w, W):
        fx, fy, cx, cy = cam.intrinsics
        width, height = cam.resolution
        u = np.array([0.0, width, width, 0.0])
        v = np.array([0.0, 0.0, height, height])
        rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones(4)], axis=1) * depth  # camera frame
        corners = c + rays @ R.T
        ring = np.roll(corners, -1, axis=0)
        segs = np.concatenate([np.stack([np.repeat(c[None], 4, 0), corners], 1), np.stack([corners, ring], 1)])
        out.append(segs.reshape(-1, 3))
    return np.concatenate(out) if out else np.zeros((0, 3))


def gravity_cone(direction: np.ndarray, cov_tangent: np.ndarray, length: float, sigmas: float = CONE_SIGMAS,
                 segments: int = CONE_SEGMENTS) -> np.ndarray:
    """(segments * 3, 3) triangle-list points of the cone from the origin around unit ``direction`` whose rim is
    the ``sigmas`` ellipse of the 2x2 angular covariance (rad^2, in :func:`tangent_basis` axes), at ``length``."""
    B = tangent_basis(direction)
    vals, vecs = np.linalg.eigh(0.5 * (cov_tangent + cov_tangent.T))
    L = vecs * (sigmas * np.sqrt(np.clip(vals, 0.0, None)))  # ellipse axes (rad)
    a = np.linspace(0.0, 2 * math.pi, segments + 1)
    ang = (L @ np.stack([np.cos(a), np.sin(a)])).T  # (segments + 1, 2) angular offsets
    theta = np.linalg.norm(ang, axis=1, keepdims=True)
    dirs = np.where(theta > 0, np.cos(theta) * direction + np.sin(theta) * (ang / np.maximum(theta, 1e-300)) @ B.T,
                    direction)
    rim = length * dirs
    apex = np.zeros((segments, 3))
    return np.stack([apex, rim[:-1], rim[1:]], axis=1).reshape(-1, 3)


def status_text(status: RigStatus | None, out: HoldOutput | None) -> str:
    """The state line and, once there is one, the last estimate."""
    lines = [status.describe() if status is not None else "waiting"]
    if out is not None:
        e = out.estimate
        g = (f"gravity +-{e.gravity_sigma_deg:.2f} deg" if out.gravity is not None and math.isfinite(
            e.gravity_sigma_deg) else "no gravity")
        lines.append(f"last: sequence {e.sequence} hold {e.hold_index}, {e.method}, {g}")
    return "\n".join(lines)


def build_markers(rig: Rig, out: HoldOutput | None, status: RigStatus | None, bend_scale: float = 1.0) -> RigMarkers:
    """The markers of the rig at its last estimate ``out`` (None: none yet, the rig at rest) in ``status``.

    ``bend_scale`` exaggerates the bend (1: as estimated). The gravity arrow and its cone are left out without
    gravity (6pt-nonbending, no estimate yet); the cone also without a finite covariance.
    """
    size = rig_size_m(rig)
    g = None if out is None or out.gravity is None else np.asarray(out.gravity, dtype=float)
    rest = rig.positions
    w, W = deformed_extrinsics(rig, bend_scale * g if g is not None else np.zeros(3))
    origin = np.zeros((rig.num_cameras, 3))
    width = 0.01 * size
    ms = [MarkerSpec("bars_rest", 0, MarkerKind.LINE_LIST, np.stack([origin, rest], 1).reshape(-1, 3), GREY,
                     (width, 0.0, 0.0)),
          MarkerSpec("bars_bent", 0, MarkerKind.LINE_LIST, np.stack([origin, w], 1).reshape(-1, 3), ORANGE,
                     (width, 0.0, 0.0)),
          MarkerSpec("cameras", 0, MarkerKind.LINE_LIST, _frustum_lines(rig, w, W, FRUSTUM_DEPTH * size), BLUE,
                     (0.5 * width, 0.0, 0.0))]
    if g is not None and np.linalg.norm(g) > 0:
        n = normalize(g)
        length = ARROW_LENGTH * size
        ms.append(MarkerSpec("gravity", 0, MarkerKind.ARROW, np.stack([np.zeros(3), length * n]), RED,
                             (2 * width, 4 * width, 6 * width)))
        cov = out.gravity_covariance
        if cov is not None and np.all(np.isfinite(cov)):
            ct = tangent_covariance(g, cov)
            ms.append(MarkerSpec("gravity_cone", 0, MarkerKind.TRIANGLE_LIST, gravity_cone(n, ct, length), CONE,
                                 (1.0, 1.0, 1.0)))
    ms.append(MarkerSpec("state", 0, MarkerKind.TEXT_VIEW_FACING, np.zeros((0, 3)), WHITE, (0.0, 0.0, 0.15 * size),
                         status_text(status, out), position=np.array([0.0, 0.0, 0.6 * size])))
    return RigMarkers(ms)


def _point(p) -> dict:
    x, y, z = (float(v) for v in p)
    return {"x": x, "y": y, "z": z}


def marker_array_fields(markers: RigMarkers, frame: str, stamp: tuple) -> dict:
    """The fields of a visualization_msgs/MarkerArray (see :func:`~nrmpc_ros.frontend.outputs.fill_message`):
    a DELETEALL first when ``markers.replaces_all``, then every marker with ``frame`` and ``stamp`` (sec, nanosec)
    in its header; ADD, no lifetime (kept until replaced)."""
    header = {"stamp": {"sec": int(stamp[0]), "nanosec": int(stamp[1])}, "frame_id": frame}
    out = [{"header": header, "action": 3}] if markers.replaces_all else []  # Marker.DELETEALL
    for m in markers.markers:
        r, g, b, a = (float(c) for c in m.color)
        out.append({"header": header, "ns": m.ns, "id": int(m.id), "type": int(m.kind), "action": 0,
                    "pose": {"position": _point(m.position), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                    "scale": dict(zip("xyz", (float(s) for s in m.scale))),
                    "color": {"r": r, "g": g, "b": b, "a": a}, "points": [_point(p) for p in m.points],
                    "text": m.text, "frame_locked": True})
    return {"markers": out}


__all__ = ["CONE_SIGMAS", "MarkerKind", "MarkerSpec", "RigMarkers", "build_markers", "gravity_cone",
           "marker_array_fields", "rig_size_m", "status_text"]
