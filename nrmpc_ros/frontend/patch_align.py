"""A landmark's position in every hold from one reference patch (docs/PIPELINE.md, "Patch alignment").

A corner found afresh in each hold is a different patch seen from another viewpoint: its sub-pixel position
moves with the viewpoint by a bias the same in every frame of the hold, which averaging does not remove. Here
a landmark keeps ONE reference patch, sampled in the first hold that saw it, and its position in every later
hold is where that patch aligns with the hold's image under the local warp the viewpoint change induces
(featuremetric keypoint refinement in the sense of Lindenberger et al., ICCV 2021, on image intensities).

Every camera works in its own model (pinhole or equidistant fisheye, :mod:`nrmpc_ros.cameras`): a patch is
sampled on a square grid of the plane tangent to the unit sphere at the point's bearing, with a grid step of
about one pixel there. Between two views of a locally planar surface the tangent planes are related by a
homography (8 parameters; its perspective part matters for wide-angle cameras at large viewpoint changes),
fitted together with a gain and an offset of the intensities (2) by Gauss-Newton (Lucas-Kanade, forward
additive) on bicubic interpolated intensities, batched over the landmarks as (N, P) arrays: one polynomial
projection and one gather per iteration for all patches. The cost is linear in the observations aligned.

The warp starts from the affine map the neighbouring links imply (:func:`neighbour_affine`), composed with
the local warp found for the landmark in its previous hold (:class:`ReferencePatches` keeps both).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cameras import bearings_to_pixels, camera_matrix, pixels_to_bearings
from ..config import check, option
from ..core.rig import Camera


@dataclass
class PatchAlignConfig:
    """Alignment of a hold's image to the landmarks' reference patches (tangent-plane pixels of each camera)."""

    enabled: bool = option(True, "positions of linked landmarks come from aligning their reference patch (off: "
                           "the tracks' own positions, found again in each hold)")
    half_size_px: int = option(10, "half side of the square patch (px); the patch is 2 h + 1 pixels wide", lo=2,
                               hi=30)
    iterations: int = option(30, "most Gauss-Newton iterations per alignment", lo=1, hi=500)
    tolerance_px: float = option(1e-3, "an alignment has converged when its step moves the point less (px)",
                                 lo=0.0, hi=1.0, lo_open=True)
    tolerance_std: float = option(0.1, "an alignment has also converged when its step moves the point less than "
                                  "this share of the point's standard deviation from the fit (a step adding 0.1 "
                                  "sigma in quadrature changes the error by 0.5 %)", lo=0.0, hi=1.0)
    # The track's corner and the aligned reference patch mark the same point up to the corner's viewpoint-
    # dependent bias, a fraction of a pixel (shifts of about 0.5 px rms on rendered bags). A move of 2-3 px is
    # the patch locking onto a neighbouring structure; kept as the same landmark in every later hold, such
    # points bend the cameras of a rig whose gravity rests on sub-pixel bending (vision only on one bar: 10-15
    # deg of gravity error at a 0.3 deg std with 3 px allowed; 0.1-0.25 deg with 1, 1.5 or 2 px).
    max_shift_px: float = option(1.5, "an alignment that moves the point further than this from where the track "
                                 "put it failed (px): the patch found something else (the corner's own "
                                 "viewpoint bias is a fraction of a pixel)", lo=0.0, hi=50.0, lo_open=True)
    min_correlation: float = option(0.9, "an aligned patch must correlate at least this well with its reference "
                                    "(normalised cross-correlation after the warp)", lo=0.0, hi=1.0)
    weight_sigma_px: float = option(5.0, "samples weigh exp(-d^2 / 2 s^2) by their distance d from the point "
                                    "(px; 0: all the same)", lo=0.0, hi=100.0)
    min_coverage: float = option(0.6, "share of a patch's weight that must lie inside both images (patches "
                                 "near the image border use the part inside)", lo=0.0, hi=1.0, lo_open=True)
    neighbours: int = option(8, "neighbouring links whose positions give the starting affine warp", lo=3, hi=100)
    older_holds: int = option(20, "older holds per camera whose reference patches are kept, so that a link to "
                              "one of them is aligned too (beyond them such a link stays at the corner found in "
                              "its hold, weighed as one); about 2.2 kB per landmark of each", lo=0, hi=10000)

    def __post_init__(self):
        check(self, "patch alignment config")


def grid(half: int) -> np.ndarray:
    """(P, 2) tangent-plane offsets of the patch samples (row-major, x fastest)."""
    r = np.arange(-half, half + 1, dtype=np.float64)
    yy, xx = np.meshgrid(r, r, indexing="ij")
    return np.stack([xx.ravel(), yy.ravel()], axis=1)


@dataclass
class TangentFrames:
    """Per point: unit bearing f (N, 3), tangent axes e1, e2 (N, 3) (image x and y near the optical axis) and
    the step (rad) that moves the point's projection by about one pixel."""

    f: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    step: np.ndarray

    def rays(self, xy: np.ndarray) -> np.ndarray:
        """Rays (N, P, 3) through tangent coordinates xy ((P, 2) shared or (N, P, 2), in steps)."""
        xy = np.broadcast_to(xy, (len(self.f),) + xy.shape[-2:])
        s = self.step[:, None, None]
        return self.f[:, None, :] + s * (xy[..., 0:1] * self.e1[:, None, :] + xy[..., 1:2] * self.e2[:, None, :])

    def coords(self, g: np.ndarray) -> np.ndarray:
        """Tangent coordinates (N, K, 2) (in steps) of bearings g (N, K, 3) (central projection)."""
        d = np.einsum("nkj,nj->nk", g, self.f)
        q = g / np.where(d > 1e-9, d, np.nan)[..., None]
        return np.stack([np.einsum("nkj,nj->nk", q, self.e1), np.einsum("nkj,nj->nk", q, self.e2)], -1) / \
            self.step[:, None, None]


def tangent_frames(cam: Camera, uv: np.ndarray) -> TangentFrames:
    """Tangent frames at pixels uv (N, 2) of camera ``cam``, step from the camera model's local scale."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    f = pixels_to_bearings(cam, uv)
    x = np.zeros_like(f)
    x[:, 0] = 1.0
    e1 = x - f * f[:, :1]
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(f, e1)
    eps = 1e-4
    p1 = bearings_to_pixels(cam, f + eps * e1)
    p2 = bearings_to_pixels(cam, f + eps * e2)
    J = np.stack([p1 - uv, p2 - uv], axis=2) / eps  # (N, 2, 2) pixels per radian
    step = 1.0 / np.sqrt(np.abs(np.linalg.det(J)))
    return TangentFrames(f, e1, e2, step)


def _cubic_weights(t: np.ndarray) -> np.ndarray:
    """Keys cubic convolution weights (a = -0.5) of the 4 taps at -1, 0, 1, 2 for fractions t (M,) -> (4, M),
    one contiguous row per tap."""
    t = t.astype(np.float32)
    out = np.empty((4,) + t.shape, np.float32)
    t2 = t * t
    t3 = t2 * t
    out[0] = -0.5 * t3 + t2 - 0.5 * t
    out[1] = 1.5 * t3 - 2.5 * t2 + 1
    out[2] = -1.5 * t3 + 2 * t2 + 0.5 * t
    out[3] = 0.5 * t3 - 0.5 * t2
    return out


def sample_pixels(image: np.ndarray, uv: np.ndarray) -> tuple:
    """Bicubic intensities (...) of ``image`` (float32) at pixels uv (..., 2), and where they are inside it.

    Cubic convolution, not bilinear: bilinear interpolation low-passes by an amount that changes with the
    sub-pixel position, which biases a sub-pixel alignment by a few hundredths of a pixel. Single precision
    (intensities and tap weights; ~1e-5 of the intensity range) halves the memory traffic of the gather.
    """
    shape = uv.shape[:-1]
    uv = uv.reshape(-1, 2)
    h, w = image.shape
    x, y = uv[:, 0], uv[:, 1]
    inside = np.isfinite(x) & np.isfinite(y) & (x >= 1) & (y >= 1) & (x < w - 2) & (y < h - 2)
    x = np.where(inside, x, 1.0)
    y = np.where(inside, y, 1.0)
    x0 = np.minimum(x.astype(np.intp), w - 3)
    y0 = np.minimum(y.astype(np.intp), h - 3)
    wx = _cubic_weights(x - x0)  # (4, M)
    wy = _cubic_weights(y - y0)
    base = (y0 - 1) * w + (x0 - 1)  # top-left tap
    flat = image.reshape(-1)
    idx = np.empty_like(base)
    tap = np.empty(len(base), image.dtype)
    out = None
    for i in range(4):  # the 4 x 4 taps, separable: along x within each row, then across the rows
        np.add(base, i * w, out=idx)
        r = np.take(flat, idx) * wx[0]
        for j in range(1, 4):  # in place: no temporaries of M values per tap
            idx += 1
            np.take(flat, idx, out=tap)
            tap *= wx[j]
            r += tap
        if out is None:
            out = wy[0] * r
        else:
            r *= wy[i]
            out += r
    return out.reshape(shape), inside.reshape(shape)


def sample(cam: Camera, image: np.ndarray, rays: np.ndarray) -> tuple:
    """Bicubic intensities (N, P) of ``image`` (float) along rays (N, P, 3) of camera ``cam``, and where they
    are inside it."""
    uv = bearings_to_pixels(cam, rays.reshape(-1, 3)).reshape(rays.shape[:-1] + (2,))
    return sample_pixels(image, uv)


_DEGREE = 5  # of the local projection polynomial: ~2e-4 px at most over 30 px of a 150 px-focal fisheye


_TERMS = np.array([(i, d - i) for d in range(_DEGREE + 1) for i in range(d + 1)])  # powers of s and t


def _powers(q: np.ndarray) -> tuple:
    """Powers 0.._DEGREE of the two coordinates of q (..., 2): two lists of arrays (...)."""
    sp, tp = [np.ones(q.shape[:-1])], [np.ones(q.shape[:-1])]
    for _ in range(_DEGREE):
        sp.append(sp[-1] * q[..., 0])
        tp.append(tp[-1] * q[..., 1])
    return sp, tp


def _basis(q: np.ndarray) -> np.ndarray:
    """Monomials s^i t^j, i + j <= _DEGREE, of q (..., 2) -> (..., 21)."""
    sp, tp = _powers(q)
    return np.stack([sp[i] * tp[j] for i, j in _TERMS], -1)


class LocalProjection:
    """Each point's tangent plane -> pixels within ``radius`` steps of it, as a quintic polynomial per point
    fitted once to the camera model's exact projection of a 13 x 13 grid (the models are smooth over a
    patch: the fit is exact to ~1e-5 px on pinhole and ~2e-4 px on fisheye cameras over 30 px; ``fit_px``
    is its largest residual on the grid per point). Projecting through OpenCV's camera models at every
    iteration would cost most of an alignment. A pinhole camera without distortion maps each tangent plane
    to the image by a homography (the ray f + s (x e1 + y e2) through K): that one is used as it is, exact
    and a few times cheaper than the polynomial's 21 terms."""

    def __init__(self, cam: Camera, tf: TangentFrames, radius: np.ndarray):
        self.radius = np.asarray(radius, np.float64)
        self.homography = None
        if cam.model == "pinhole" and not np.any(np.asarray(cam.distortion, float)):
            s = tf.step[:, None]
            self.homography = camera_matrix(cam) @ np.stack([s * tf.e1, s * tf.e2, tf.f], axis=2)  # (N, 3, 3)
            self.fit_px = np.zeros(len(tf.f))
            return
        r = np.linspace(-1.0, 1.0, 13)
        q = np.stack(np.meshgrid(r, r, indexing="ij"), -1).reshape(-1, 2)  # (K, 2) in units of radius
        uv = bearings_to_pixels(cam, tf.rays(q[None] * self.radius[:, None, None]).reshape(-1, 3))
        uv = uv.reshape(len(tf.f), len(q), 2)
        phi = _basis(q)
        self.coef = np.linalg.pinv(phi) @ np.nan_to_num(uv, nan=0.0)  # (N, 21, 2)
        fit = np.abs(phi @ self.coef - uv).max(axis=(1, 2))
        self.fit_px = np.where(np.isfinite(fit), fit, np.inf)

    def pixels(self, idx: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Pixels (m, P, 2) of tangent coordinates w (m, P, 2) of points idx (m,); NaN beyond the radius (and
        behind the camera)."""
        if self.homography is not None:
            H = self.homography[idx]
            x, y = w[..., 0], w[..., 1]
            z = H[:, 2, 0, None] * x + H[:, 2, 1, None] * y + H[:, 2, 2, None]
            r = self.radius[idx, None]
            ok = (np.abs(x) <= r) & (np.abs(y) <= r) & (z > 1e-9)
            z = np.where(ok, z, np.nan)
            out = np.empty(w.shape)
            out[..., 0] = (H[:, 0, 0, None] * x + H[:, 0, 1, None] * y + H[:, 0, 2, None]) / z
            out[..., 1] = (H[:, 1, 0, None] * x + H[:, 1, 1, None] * y + H[:, 1, 2, None]) / z
            return out
        q = w / self.radius[idx, None, None]
        sp, tp = _powers(q)
        basis = np.empty((len(idx), len(_TERMS)) + q.shape[1:-1])  # (m, 21, P): each term a contiguous row
        for k, (i, j) in enumerate(_TERMS):
            np.multiply(sp[i], tp[j], out=basis[:, k])
        uv = np.matmul(self.coef[idx].transpose(0, 2, 1), basis).transpose(0, 2, 1)  # (m, 2, 21) @ (m, 21, P)
        inside = (np.abs(q[..., 0]) <= 1.0) & (np.abs(q[..., 1]) <= 1.0)
        return np.where(inside[..., None], uv, np.nan)


@dataclass
class ReferencePatches:
    """Reference patches of landmarks: intensities (N, P) on the tangent grid at their reference position,
    and per landmark the affine map (N, 2, 2) from reference-patch coordinates to the tangent coordinates of
    the latest hold it was aligned in (identity in its reference hold)."""

    values: np.ndarray
    valid: np.ndarray  # (N, P) the samples that lay inside the reference image
    affine: np.ndarray

    def take(self, idx) -> ReferencePatches:
        return ReferencePatches(self.values[idx], self.valid[idx], self.affine[idx])


def reference_patches(cam: Camera, image, uv, cfg: PatchAlignConfig) -> ReferencePatches:
    """Patches of ``image`` (camera ``cam``) at pixels uv (N, 2): the landmarks' references."""
    img = np.asarray(image, np.float32)
    tf = tangent_frames(cam, uv)
    vals, inside = sample(cam, img, tf.rays(grid(cfg.half_size_px)))
    n = len(vals)
    return ReferencePatches(vals, inside, np.broadcast_to(np.eye(2), (n, 2, 2)).copy())


def neighbour_affine(f_prev: np.ndarray, f_cur: np.ndarray, tf_prev: TangentFrames, tf_cur: TangentFrames,
                     k: int) -> np.ndarray:
    """Affine maps (N, 2, 2) from tangent coordinates at each link's previous-hold bearing to those at its
    current bearing, least squares over its ``k`` nearest links (by angle in the previous hold); the identity
    where the neighbours do not determine a well-conditioned map.

    f_prev, f_cur: (N, 3) bearings of the same N landmarks in the two holds; tf_*: the tangent frames at them.
    """
    n = len(f_prev)
    out = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    k = min(int(k), n - 1)
    if k < 3:
        return out
    from scipy.spatial import cKDTree

    _, nb = cKDTree(f_prev).query(f_prev, k=k + 1)
    nb = nb[:, 1:]
    X = tf_prev.coords(f_prev[nb])  # (N, k, 2)
    Y = tf_cur.coords(f_cur[nb])
    ok = np.all(np.isfinite(X), axis=(1, 2)) & np.all(np.isfinite(Y), axis=(1, 2))
    X = np.where(ok[:, None, None], X, 0.0)
    Y = np.where(ok[:, None, None], Y, 0.0)
    XX = np.einsum("nki,nkj->nij", X, X)
    YX = np.einsum("nki,nkj->nij", Y, X)
    good = ok & (np.linalg.cond(XX) < 1e4)
    A = np.einsum("nij,njk->nik", YX[good], np.linalg.inv(XX[good]))
    s = np.linalg.svd(A, compute_uv=False)
    sane = (s[:, 1] > 0.3) & (s[:, 0] < 3.0) & (np.linalg.det(A) > 0)  # foreshortening below ~70 deg
    idx = np.flatnonzero(good)[sane]
    out[idx] = A[sane]
    return out


@dataclass
class Alignment:
    """Result of aligning reference patches in one image: pixels (N, 2), affine maps from reference-patch to
    tangent coordinates at the aligned point (N, 2, 2), success, normalised correlation, iterations used, and
    the position's standard deviation from the fit (px, the residual's spread over the patch's information)."""

    uv: np.ndarray
    affine: np.ndarray
    ok: np.ndarray
    correlation: np.ndarray
    iterations: int
    std_px: np.ndarray


def _warp(x: np.ndarray, A: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple:
    """Homography of tangent coordinates x (P, 2) -> w (n, P, 2), w = (A x + b) / (1 + c.x), and D (n, P)."""
    D = 1.0 + x @ c.T  # (P, n)
    return (x @ A.transpose(0, 2, 1) + b[:, None, :]) / D.T[..., None], D.T


def align(cam: Camera, image, ref: ReferencePatches, uv0, affine0, cfg: PatchAlignConfig) -> Alignment:
    """Align reference patches ``ref`` with ``image`` of camera ``cam`` near pixels uv0 (N, 2), starting from
    affine maps affine0 (N, 2, 2) (reference-patch to tangent coordinates at uv0).

    Gauss-Newton on r(x) = (1 + a) I(W(x)) + o - T(x), with W the homography (A x + b) / (1 + c.x) from the
    reference patch's tangent plane to the one at uv0 (a locally planar surface seen from two viewpoints;
    it starts as the affine map affine0); the aligned point is W(0) = b. Batched over the N patches; the
    loop runs over iterations only. The returned affine is W's derivative at the point.
    """
    img = np.asarray(image, np.float32)
    uv0 = np.asarray(uv0, np.float64).reshape(-1, 2)
    n = len(uv0)
    half = cfg.half_size_px
    x = grid(half)  # (P, 2)
    xb = grid(half + 1)  # with a one-sample border for the gradients
    side, sideb = 2 * half + 1, 2 * half + 3
    tf = tangent_frames(cam, uv0)
    A = np.asarray(affine0, np.float64).reshape(n, 2, 2).copy()
    reach = (half + 1) * np.sqrt(2) * np.linalg.norm(A, ord=2, axis=(1, 2))
    proj = LocalProjection(cam, tf, 1.25 * reach + cfg.max_shift_px + 1.0)  # room for the warp to change
    b = np.zeros((n, 2))
    c = np.zeros((n, 2))
    gain = np.ones(n)
    off = np.zeros(n)
    T = ref.values
    d2 = (x * x).sum(axis=1)
    wgt = np.exp(-0.5 * d2 / cfg.weight_sigma_px ** 2) if cfg.weight_sigma_px > 0 else np.ones(len(x))
    need = cfg.min_coverage * wgt.sum()
    active = ((ref.valid * wgt).sum(axis=1) >= need) & (proj.fit_px < cfg.tolerance_px)  # (else the patch
    # reaches too far out of the local model)
    conv = np.zeros(n, bool)
    inside_all = np.ones(n, bool)
    used = 0
    std = np.full(n, np.nan)
    dof = max(side * side - 10, 1)
    for _ in range(cfg.iterations):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        used += 1
        m = len(idx)
        Ai, bi, ci = A[idx], b[idx], c[idx]
        wb, Db = _warp(xb, Ai, bi, ci)
        Ib, inside = sample_pixels(img, proj.pixels(idx, wb))
        ins = inside.reshape(-1, sideb, sideb)
        ins = ins[:, 1:-1, 1:-1] & ins[:, 1:-1, 2:] & ins[:, 1:-1, :-2] & ins[:, 2:, 1:-1] & ins[:, :-2, 1:-1]
        Wm = wgt * (ins.reshape(m, -1) & ref.valid[idx])  # samples inside both images, with their gradients
        inside_all[idx] = Wm.sum(axis=1) >= need
        Ib = Ib.reshape(-1, sideb, sideb)
        Iw = Ib[:, 1:-1, 1:-1].reshape(m, -1)
        gx = 0.5 * (Ib[:, 1:-1, 2:] - Ib[:, 1:-1, :-2]).reshape(m, -1)
        gy = 0.5 * (Ib[:, 2:, 1:-1] - Ib[:, :-2, 1:-1]).reshape(m, -1)
        # the patch (xb without its border), each coordinate a contiguous (m, P) array
        w0 = wb[..., 0].reshape(m, sideb, sideb)[:, 1:-1, 1:-1].reshape(m, -1)
        w1 = wb[..., 1].reshape(m, sideb, sideb)[:, 1:-1, 1:-1].reshape(m, -1)
        D = Db.reshape(m, sideb, sideb)[:, 1:-1, 1:-1].reshape(m, -1)
        # dW/dx = (A - w c^T) / D entry by entry, and the gradient in W's plane g_x (dW/dx)^-1
        c0, c1 = ci[:, 0, None], ci[:, 1, None]
        m00, m01 = (Ai[:, 0, 0, None] - w0 * c0) / D, (Ai[:, 0, 1, None] - w0 * c1) / D
        m10, m11 = (Ai[:, 1, 0, None] - w1 * c0) / D, (Ai[:, 1, 1, None] - w1 * c1) / D
        det = m00 * m11 - m01 * m10
        g = gain[idx, None] / D  # (m, P)
        # the Jacobian parameter-major (m, 10, P): b, A (row-major), c, gain, offset; every row contiguous
        J = np.empty((m, 10, len(x)))
        np.multiply((gx * m11 - gy * m10) / det, g, out=J[:, 0])
        np.multiply((gy * m00 - gx * m01) / det, g, out=J[:, 1])
        np.multiply(J[:, 0], x[:, 0], out=J[:, 2])
        np.multiply(J[:, 0], x[:, 1], out=J[:, 3])
        np.multiply(J[:, 1], x[:, 0], out=J[:, 4])
        np.multiply(J[:, 1], x[:, 1], out=J[:, 5])
        s_ = -(J[:, 0] * w0 + J[:, 1] * w1)
        np.multiply(s_, x[:, 0], out=J[:, 6])
        np.multiply(s_, x[:, 1], out=J[:, 7])
        J[:, 8] = Iw
        J[:, 9] = 1.0
        r = gain[idx, None] * Iw + off[idx, None] - T[idx]
        Jw = J * Wm[:, None, :]
        H = Jw @ J.transpose(0, 2, 1)
        rhs = (Jw @ r[..., None])[..., 0]
        H += 1e-9 * np.trace(H, axis1=1, axis2=2)[:, None, None] * np.eye(10)
        # one solve for the step and the first two columns of H^-1 (the point's covariance, below)
        B = np.zeros((m, 10, 3))
        B[:, :, 0] = rhs
        B[:, 0, 1] = B[:, 1, 2] = 1.0
        sol = np.linalg.solve(H, B)
        delta = -sol[:, :, 0]
        big = np.linalg.norm(delta[:, :2], axis=1)
        scale = np.minimum(1.0, 1.0 / np.maximum(big, 1e-12))  # at most one step (px) per iteration
        delta *= scale[:, None]
        b[idx] += delta[:, :2]
        A[idx] += delta[:, 2:6].reshape(-1, 2, 2)
        c[idx] += delta[:, 6:8]
        gain[idx] += delta[:, 8]
        off[idx] += delta[:, 9]
        sigma2 = (Wm * r * r).sum(axis=1) / (dof * Wm.mean(axis=1))
        std[idx] = np.sqrt(sigma2 * (sol[:, 0, 1] + sol[:, 1, 2]) / 2)
        # tangent steps are about one pixel; a step well inside the point's own uncertainty changes nothing
        done = big * scale < np.maximum(cfg.tolerance_px, cfg.tolerance_std * np.nan_to_num(std[idx]))
        far = np.linalg.norm(b[idx], axis=1) > cfg.max_shift_px
        conv[idx[done]] = True
        active[idx[done | far | ~inside_all[idx]]] = False
    uv = bearings_to_pixels(cam, tf.rays(b[:, None, :])[:, 0])  # the exact model for the result
    w, _ = _warp(x, A, b, c)  # final correlation of the warped patch with its reference
    Iw, inside = sample_pixels(img, proj.pixels(np.arange(n), w))
    Wm = wgt * (inside & ref.valid)
    sw = np.maximum(Wm.sum(axis=1, keepdims=True), 1e-12)
    a = Iw - (Wm * Iw).sum(axis=1, keepdims=True) / sw
    t = T - (Wm * T).sum(axis=1, keepdims=True) / sw
    corr = (Wm * a * t).sum(axis=1) / np.sqrt(np.maximum((Wm * a * a).sum(axis=1) * (Wm * t * t).sum(axis=1), 1e-24))
    shift = np.linalg.norm(uv - uv0, axis=1)
    ok = conv & (sw[:, 0] >= need) & (shift <= cfg.max_shift_px) & (corr >= cfg.min_correlation)
    ok &= np.all(np.isfinite(uv), axis=1)
    local = A - b[:, :, None] * c[:, None, :]  # dW/dx at x = 0
    return Alignment(uv, local, ok, corr, used, std)


__all__ = ["Alignment", "PatchAlignConfig", "ReferencePatches", "TangentFrames", "align", "grid",
           "neighbour_affine", "reference_patches", "sample", "sample_pixels", "tangent_frames", "LocalProjection"]
