"""Vectorised ray caster of the textured room (rig geometry per docs/CONVENTIONS.md (Frames, Bending, Files)).

A rig camera's pixels become unit bearings through its own camera model
(:func:`nrmpc_ros.cameras.pixels_to_bearings`, cached per camera); each view
turns them into world rays with the bent extrinsics (w_i, W_i) of the load
that camera's bar carries (one load for the whole rig, or one per camera when
the bars ring), intersects them with all boxes at once (slab test) and
shades the nearest hit by a bilinear texture lookup.
"""

from __future__ import annotations

import numpy as np

from ..cameras import pixels_to_bearings
from ..core.deformation import deformed_extrinsics
from ..core.rig import Rig
from .bars import bent_extrinsics
from .scene import Scene, in_plane_axes

_EPS_T = 1e-6


def cast_rays(scene: Scene, origin, dirs):
    """Nearest hit of rays from one point ``origin`` (3,) inside the room along ``dirs`` (N, 3).

    Returns the distance along each direction ``t`` (N,) float32 (in units of
    |dir|) and the face index (N,) of the hit (see :mod:`nrmpc_ros.render.scene`).
    Vectorised over rays; the short loops run over boxes and axes only.
    """
    d = np.asarray(dirs, dtype=np.float32).reshape(-1, 3)
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    d = np.where(np.abs(d) < 1e-12, np.float32(1e-12), d)
    inv = [np.ascontiguousarray(1.0 / d[:, a]) for a in range(3)]
    pos = [d[:, a] > 0 for a in range(3)]
    lo = scene.lo - o  # (B, 3) box corners relative to the ray origin
    hi = scene.hi - o
    # Room (box 0) seen from inside: the ray leaves through the first slab boundary it meets.
    t = np.full(len(d), np.inf, dtype=np.float32)
    face = np.zeros(len(d), dtype=np.int64)
    for a in range(3):
        ta = np.where(pos[a], np.float32(hi[0, a]), np.float32(lo[0, a])) * inv[a]
        m = ta < t
        t = np.where(m, ta, t)
        face = np.where(m, 2 * a + pos[a], face)
    for b in range(1, scene.num_boxes):
        t_enter = np.full(len(d), -np.inf, dtype=np.float32)
        t_exit = np.full(len(d), np.inf, dtype=np.float32)
        enter_axis = np.zeros(len(d), dtype=np.int64)
        for a in range(3):
            t1 = np.float32(lo[b, a]) * inv[a]
            t2 = np.float32(hi[b, a]) * inv[a]
            near = np.minimum(t1, t2)
            m = near > t_enter
            t_enter = np.where(m, near, t_enter)
            enter_axis = np.where(m, a, enter_axis)
            t_exit = np.minimum(t_exit, np.maximum(t1, t2))
        hit = (t_enter <= t_exit) & (t_enter > _EPS_T) & (t_enter < t)
        if not hit.any():
            continue
        t = np.where(hit, t_enter, t)
        side = ~np.choose(enter_axis, pos)  # moving towards -axis: entering through the high face
        face = np.where(hit, 6 * b + 2 * enter_axis + side, face)
    return t, face


def shade(scene: Scene, points, face) -> np.ndarray:
    """Intensity (N,) float32 in [0, 255] of world points (N, 3) lying on faces (N,): bilinear texture x shade."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    face = np.asarray(face, dtype=np.int64)
    # Per-face tables (a few dozen entries), then one cheap lookup per pixel.
    faces = np.arange(len(scene.face_offset))
    f_box, f_axis = faces // 6, (faces % 6) // 2
    f_b, f_c = in_plane_axes(f_axis)
    tpm = np.float32(scene.texels_per_metre)
    f_lo_b = scene.lo[f_box, f_b].astype(np.float32)
    f_lo_c = scene.lo[f_box, f_c].astype(np.float32)
    flat = p.reshape(-1)
    rows3 = np.arange(0, flat.size, 3)
    w = scene.face_width[face]
    u = (flat[rows3 + f_b[face]] - f_lo_b[face]) * tpm
    v = (flat[rows3 + f_c[face]] - f_lo_c[face]) * tpm
    u = np.clip(u, 0, (scene.face_width - 1.001).astype(np.float32)[face])
    v = np.clip(v, 0, (scene.face_height - 1.001).astype(np.float32)[face])
    u0 = u.astype(np.int64)
    v0 = v.astype(np.int64)
    fu = u - u0
    fv = v - v0
    base = scene.face_offset[face] + v0 * w + u0
    a = scene.atlas
    top = a[base] * (1 - fu) + a[base + 1] * fu
    bottom = a[base + w] * (1 - fu) + a[base + w + 1] * fu
    return ((top * (1 - fv) + bottom * fv) * scene.face_shade[face]).astype(np.float32)


class Renderer:
    """Renders the rig's cameras in a scene; bearings of every pixel are computed once per camera."""

    def __init__(self, rig: Rig, scene: Scene, supersample: int = 1):
        """``supersample``: each pixel integrates supersample x supersample rays spread over its area, as a
        sensor pixel integrates light (1: one ray through the pixel centre)."""
        self.rig = rig
        self.scene = scene
        self.supersample = int(supersample)
        if self.supersample < 1:
            raise ValueError(f"supersample must be >= 1, got {supersample}")
        self._bearings: dict[int, np.ndarray] = {}

    def bearings(self, i: int) -> np.ndarray:
        """(S*S*H*W, 3) float32 unit bearings of camera i's sub-pixel sample points (S = supersample), grouped
        sample-major: S*S row-major images of H*W rays, whose mean is the pixel."""
        if i not in self._bearings:
            cam = self.rig.cameras[i]
            w, h = cam.resolution
            vv, uu = np.mgrid[0:h, 0:w]
            S = self.supersample
            off = (np.arange(S) + 0.5) / S - 0.5  # sample offsets inside the pixel, centred on it
            uv = np.concatenate([np.stack([uu.ravel() + du, vv.ravel() + dv], axis=1)
                                 for dv in off for du in off]).astype(np.float64)
            self._bearings[i] = pixels_to_bearings(cam, uv).astype(np.float32)
        return self._bearings[i]

    def render_camera(self, i: int, R_world_cam, c_world, return_points: bool = False, scene: Scene | None = None):
        """Image (H, W) float32 of camera i with orientation R_world_cam (camera -> world) at c_world.

        With ``return_points`` also the (H*W, 3) world points the pixels see (through the sample nearest each
        pixel centre: the centre itself for an odd ``supersample``). ``scene``: the scene at this instant where
        something in it moves (default: the renderer's).
        """
        scene = self.scene if scene is None else scene
        cam = self.rig.cameras[i]
        w, h = cam.resolution
        # einsum, not a BLAS product: a (H*W, 3) x (3, 3) product gains nothing from threads, and waking
        # BLAS threads on a busy machine costs more than the product itself.
        d = np.einsum("nj,ij->ni", self.bearings(i), np.asarray(R_world_cam, dtype=np.float32))
        c = np.asarray(c_world, dtype=np.float32)
        t, face = cast_rays(scene, c, d)
        pts = c + t[:, None] * d
        img = shade(scene, pts, face).reshape(-1, h, w).mean(axis=0)
        mid = (self.supersample * self.supersample) // 2
        return (img, pts[mid * h * w:(mid + 1) * h * w]) if return_points else img

    def camera_poses(self, R_world_body, p_world_body, g_body=None):
        """World orientation (M, 3, 3) and position (M, 3) of every camera, bent for the load g_body
        (docs/CONVENTIONS.md, Bending).

        g_body: one body-frame load (3,) for all cameras, one per camera (M, 3), or None for the
        canonical extrinsics.
        """
        if g_body is None:
            w, W = self.rig.positions, self.rig.rotations
        elif np.ndim(g_body) == 2:
            w, W = bent_extrinsics(self.rig, g_body)
        else:
            w, W = deformed_extrinsics(self.rig, g_body)
        R = np.asarray(R_world_body, dtype=float)
        return R @ W, w @ R.T + np.asarray(p_world_body, dtype=float)

    def render_rig(self, R_world_body, p_world_body, g_body=None, cameras=None) -> list:
        """One float32 image per camera for the body pose in the world and the bending load g_body (body frame).

        g_body as in :meth:`camera_poses`; ``cameras`` (indices) renders only those, the others are None.
        """
        Rs, cs = self.camera_poses(R_world_body, p_world_body, g_body)
        wanted = range(self.rig.num_cameras) if cameras is None else set(int(i) for i in cameras)
        return [self.render_camera(i, Rs[i], cs[i]) if i in wanted else None for i in range(self.rig.num_cameras)]
