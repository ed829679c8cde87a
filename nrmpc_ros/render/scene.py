"""A textured box room for rendered test bags.

The scene is the inside of an axis-aligned room (world frame, z up, metres)
with a few axis-aligned boxes standing in it. Every face carries its own
procedural texture (smooth gradients, random rectangles, blobs, strokes and
glyphs at many scales), so no two places look alike and corner detectors,
ORB/SIFT and KLT all find plenty to track. Textures live in one flat uint8
atlas; a face is addressed by ``face = 6 * box + 2 * axis + side`` where box
0 is the room, ``axis`` is the face normal's axis and ``side`` 1 the high
face.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

# Room interior and boxes (lo, hi), world frame, metres. The rig lives near the origin; nothing closer than ~1.5 m.
ROOM = ((-3.0, -2.5, -1.3), (3.4, 2.9, 2.2))
BOXES = (
    ((2.0, 0.6, -1.3), (2.8, 1.6, -0.3)),
    ((-2.6, -1.9, -1.3), (-1.8, -1.0, -0.6)),
    ((-0.5, 2.0, -1.3), (0.6, 2.7, 0.1)),
    ((0.8, -2.3, -1.3), (1.5, -1.6, 0.5)),
    ((-3.0, 0.5, 0.6), (-2.5, 1.8, 1.0)),
    ((1.2, 1.7, 0.9), (2.2, 2.9, 1.3)),
)
_LIGHT = np.array([0.3, -0.5, 0.81])
# A person walking through the room (:func:`walker_offset`): a box of a person's size standing on the floor, its
# nominal place the middle of its lane, which runs along x at y 1.2-1.5 m (clear of the boxes' ranges the rig
# sees most of, and of a rig within 0.6 m of the origin)
WALKER = ((-0.22, 1.2, -1.3), (0.22, 1.5, 0.45))
WALKER_LANE_X = (-2.3, 2.3)  # the x range its middle walks, back and forth


@dataclass(frozen=True)
class Scene:
    """Boxes (box 0 is the room, seen from inside) and their face textures."""

    lo: np.ndarray  # (B, 3) low corners
    hi: np.ndarray  # (B, 3) high corners
    texels_per_metre: float
    atlas: np.ndarray  # flat uint8 texels of all faces
    face_offset: np.ndarray  # (F,) start of each face in the atlas
    face_width: np.ndarray  # (F,) texels along the first in-plane axis
    face_height: np.ndarray  # (F,) texels along the second in-plane axis
    face_shade: np.ndarray  # (F,) float32 brightness factor (fixed light direction)

    @property
    def num_boxes(self) -> int:
        return len(self.lo)


def in_plane_axes(axis):
    """The two in-plane axes (b, c) of faces whose normal is along ``axis`` (0, 1, 2)."""
    axis = np.asarray(axis)
    return (axis + 1) % 3, (axis + 2) % 3


def _texture(rng: np.random.Generator, width: int, height: int, tpm: float) -> np.ndarray:
    """One face texture (height, width) uint8: gradients plus random shapes at many scales."""
    area = width * height / tpm**2  # m^2
    coarse = rng.uniform(40, 215, size=(max(2, int(height / tpm / 0.35) + 2), max(2, int(width / tpm / 0.35) + 2)))
    img = cv2.resize(coarse.astype(np.float32), (width, height), interpolation=cv2.INTER_CUBIC)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    ang = rng.uniform(0, 2 * np.pi)
    img += 50.0 * (np.cos(ang) * xx + np.sin(ang) * yy) / max(width, height)
    img = np.clip(img, 0, 255).astype(np.uint8)

    def sizes(n, lo_m, hi_m):  # log-uniform sizes in texels
        return np.exp(rng.uniform(np.log(lo_m), np.log(hi_m), size=n)) * tpm

    n_rect = int(30 * area) + 4
    c = rng.uniform(0, 1, size=(n_rect, 2)) * (width, height)
    s = np.stack([sizes(n_rect, 0.02, 0.35), sizes(n_rect, 0.02, 0.35)], axis=1)
    grey = rng.integers(0, 256, size=n_rect)
    for (cx, cy), (sx, sy), gv in zip(c, s, grey):
        cv2.rectangle(img, (int(cx - sx / 2), int(cy - sy / 2)), (int(cx + sx / 2), int(cy + sy / 2)), int(gv), -1)
    n_ell = int(18 * area) + 3
    c = rng.uniform(0, 1, size=(n_ell, 2)) * (width, height)
    ax = np.stack([sizes(n_ell, 0.01, 0.15), sizes(n_ell, 0.01, 0.15)], axis=1)
    rot = rng.uniform(0, 180, size=n_ell)
    grey = rng.integers(0, 256, size=n_ell)
    for (cx, cy), (a, b), r, gv in zip(c, ax, rot, grey):
        cv2.ellipse(img, (int(cx), int(cy)), (max(1, int(a)), max(1, int(b))), float(r), 0, 360, int(gv), -1)
    n_line = int(6 * area) + 2
    p0 = rng.uniform(0, 1, size=(n_line, 2)) * (width, height)
    d = rng.normal(size=(n_line, 2)) * sizes(n_line, 0.05, 0.4)[:, None]
    thick = rng.integers(1, 5, size=n_line)
    grey = rng.integers(0, 256, size=n_line)
    for a, b, th, gv in zip(p0, p0 + d, thick, grey):
        cv2.line(img, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), int(gv), int(th))
    n_txt = int(3 * area) + 1
    letters = np.array(list("ABCDEFGHKLMNPRSTUVWXYZ0123456789#%&"))
    p0 = rng.uniform(0, 1, size=(n_txt, 2)) * (width, height)
    scale = sizes(n_txt, 0.03, 0.12) / 22.0
    grey = rng.integers(0, 256, size=n_txt)
    for (x, y), sc, gv in zip(p0, scale, grey):
        text = "".join(rng.choice(letters, size=int(rng.integers(2, 6))))
        cv2.putText(img, text, (int(x), int(y)), cv2.FONT_HERSHEY_SIMPLEX, float(sc), int(gv),
                    max(1, int(round(2 * sc))), cv2.LINE_AA)
    return cv2.GaussianBlur(img, (0, 0), 0.8)


def make_scene(seed: int = 0, texels_per_metre: float = 160.0, room=ROOM, boxes=BOXES) -> Scene:
    """The default textured room; textures depend only on ``seed`` (deterministic)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5CE7E]))
    lo = np.array([room[0]] + [b[0] for b in boxes], dtype=np.float64)
    hi = np.array([room[1]] + [b[1] for b in boxes], dtype=np.float64)
    if np.any(hi <= lo):
        raise ValueError("every box needs hi > lo on all axes")
    ext = hi - lo
    faces, widths, heights, offsets, shades = [], [], [], [], []
    offset = 0
    for box in range(len(lo)):
        for axis in range(3):
            b, c = in_plane_axes(axis)
            w = int(np.ceil(ext[box, b] * texels_per_metre)) + 2
            h = int(np.ceil(ext[box, c] * texels_per_metre)) + 2
            for side in range(2):
                normal = np.zeros(3)
                normal[axis] = 1.0 if side else -1.0
                if box == 0:
                    normal = -normal  # the room is seen from inside
                tex = _texture(rng, w, h, texels_per_metre)
                faces.append(tex.reshape(-1))
                widths.append(w)
                heights.append(h)
                offsets.append(offset)
                shades.append(0.72 + 0.28 * abs(float(normal @ _LIGHT)) / np.linalg.norm(_LIGHT))
                offset += w * h
    return Scene(
        lo=lo, hi=hi, texels_per_metre=float(texels_per_metre), atlas=np.concatenate(faces),
        face_offset=np.array(offsets, dtype=np.int64), face_width=np.array(widths, dtype=np.int64),
        face_height=np.array(heights, dtype=np.int64), face_shade=np.array(shades, dtype=np.float32),
    )


def walker_offset(t_s, speed_m_s: float) -> np.ndarray:
    """(N, 3) shift of the walker from its nominal place at times ``t_s`` (s): back and forth along its lane at
    ``speed_m_s``, turning at the lane's ends, starting from its middle towards +x."""
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    half = 0.5 * (WALKER_LANE_X[1] - WALKER_LANE_X[0])
    phase = np.mod(speed_m_s * t + half, 4.0 * half)  # a triangle wave of amplitude ``half``
    x = np.where(phase < 2.0 * half, phase, 4.0 * half - phase) - half
    return np.stack([x + 0.5 * sum(WALKER_LANE_X), np.zeros_like(x), np.zeros_like(x)], axis=1)


def with_box_moved(scene: Scene, box: int, offset) -> Scene:
    """The scene with box ``box`` shifted by ``offset`` (3,) m; its faces' textures move with it (they are
    addressed from the box's low corner)."""
    d = np.zeros_like(scene.lo)
    d[box] = np.asarray(offset, dtype=float).reshape(3)
    return replace(scene, lo=scene.lo + d, hi=scene.hi + d)


def contains(scene: Scene, points) -> np.ndarray:
    """True for points (N, 3) inside the room and outside every box (where a camera may be)."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    in_room = np.all((p > scene.lo[0]) & (p < scene.hi[0]), axis=1)
    in_box = np.any(np.all((p[:, None, :] > scene.lo[None, 1:]) & (p[:, None, :] < scene.hi[None, 1:]), axis=2), axis=1)
    return in_room & ~in_box
