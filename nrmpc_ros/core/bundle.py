"""Robust bundle adjustment over a sequence of static views with the bending model.

The refinement of docs/CONVENTIONS.md (Estimators, "Refinement"; "Sequences"): over K
views of one rig, the unknowns are the poses (R_k, t_k) of the free views
(view k -> view 0, ``p_0 = R_k p_k + t_k``; view 0 is the identity), ONE
gravity g_0 in view 0's body frame (2 d.o.f., |g| fixed; view k sees
``g_k = R_k^T g_0``), the landmarks (in view 0's frame) and, for the bar
calibration, bar compliances. Each observation (view k, camera i, landmark j,
bearing f) has the 2-D tangent-plane residual of f against the landmark seen
from camera i bent at g_k (deformation model, docs/CONVENTIONS.md "Bending");
the loss is Huber on its norm in units of the angular noise sigma. Measured
gravity per view (an accelerometer), optionally with a constant sensor tilt
(bias), and condensed information on g_0 from views no longer in a sliding
window enter as priors. The two-view refinement of the estimators is the K = 2
case (:func:`refine_two_view`).

Rotations are perturbed on the left, in view 0's frame (Exp(dr) R_k); gravity
in the tangent plane of g_0; landmarks in an inverse-depth chart of their first
observation's camera (:class:`InverseDepthChart`). The points are eliminated
by 3x3 Schur blocks (:mod:`.lm`), so an iteration is linear in the number of
observations; the reduced system's inverse is the covariance of the poses,
the gravity and the compliances.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from .deformation import deformation_jacobians
from .lm import LinearSystem, LMOptions, LMStats, SchurStructure, Stop, group_sum, inv3, levenberg_marquardt
from .loss import MAD_TO_STD, HuberLoss
from .rig import Rig
from .so3 import cross, exp_so3, log_so3, normalize, right_jacobian, skew, tangent_basis

POSE_DIM = 6  # dr (3, left perturbation Exp(dr) R_k, in view 0's frame), dt (3, metres)
GRAVITY_DIM = 2  # tangent angles of g_0 (rad)
BIAS_DIM = 3  # constant tilt of the measured gravity directions (unit-vector units ~ rad)


# ---------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Observations:
    """N observations: view (N,), camera (N,), landmark index point (N,) in 0..P-1, unit bearing f (N, 3)."""

    view: np.ndarray
    cam: np.ndarray
    point: np.ndarray
    f: np.ndarray
    num_views: int
    num_points: int
    view_sequence: np.ndarray | None = None  # (K,) sequence of each view (None: one sequence)
    scale: np.ndarray | None = None  # (N,) each observation's noise std over the nominal one (None: all 1)

    def __len__(self) -> int:
        return len(self.view)

    @property
    def num_sequences(self) -> int:
        return 1 if self.view_sequence is None else int(self.view_sequence.max()) + 1

    @property
    def sequence_of_view(self) -> np.ndarray:
        return np.zeros(self.num_views, np.int64) if self.view_sequence is None else self.view_sequence

    @classmethod
    def concatenate(cls, parts: list[Observations]) -> Observations:
        """Independent sequences side by side (views and landmarks renumbered; each keeps its own gravity)."""
        views = np.cumsum([0] + [p.num_views for p in parts])
        points = np.cumsum([0] + [p.num_points for p in parts])
        seqs = np.cumsum([0] + [p.num_sequences for p in parts])
        scale = None if all(p.scale is None for p in parts) else \
            np.concatenate([np.ones(len(p)) if p.scale is None else p.scale for p in parts])
        return cls(np.concatenate([p.view + v for p, v in zip(parts, views)]),
                   np.concatenate([p.cam for p in parts]),
                   np.concatenate([p.point + q for p, q in zip(parts, points)]),
                   np.concatenate([p.f for p in parts]), int(views[-1]), int(points[-1]),
                   np.concatenate([p.sequence_of_view + s for p, s in zip(parts, seqs)]), scale)

    @classmethod
    def from_arrays(cls, view, cam, track, f, num_views: int | None = None, scale=None):
        """Observations with landmark ids ``track`` (any integers) made dense; returns (obs, ids (P,)).
        ``scale`` (N,): each observation's noise std over the nominal one (None: all 1)."""
        view = np.asarray(view, dtype=np.int64)
        ids, point = np.unique(np.asarray(track, dtype=np.int64), return_inverse=True)
        K = int(view.max()) + 1 if num_views is None else int(num_views)
        return cls(view, np.asarray(cam, dtype=np.int64), point.astype(np.int64), normalize(np.asarray(f, float)),
                   K, len(ids), None, None if scale is None else np.asarray(scale, dtype=float)), ids

    @classmethod
    def two_view(cls, f1, f2, cam) -> Observations:
        """Correspondence n of two views as landmark n seen in view 0 (bearing f1) and view 1 (bearing f2)."""
        n = len(cam)
        cam = np.asarray(cam, dtype=np.int64)
        idx = np.arange(n, dtype=np.int64)
        return cls(np.repeat(np.array([0, 1], dtype=np.int64), n), np.concatenate([cam, cam]),
                   np.concatenate([idx, idx]), np.concatenate([f1, f2]).astype(float), 2, n)

    def subset(self, keep) -> tuple[Observations, np.ndarray]:
        """The observations ``keep`` (mask or indices), landmarks renumbered; returns (obs, old landmark index)."""
        keep = np.asarray(keep)
        idx = np.flatnonzero(keep) if keep.dtype == bool else keep
        used, point = np.unique(self.point[idx], return_inverse=True)
        return Observations(self.view[idx], self.cam[idx], point.astype(np.int64), self.f[idx], self.num_views,
                            len(used), self.view_sequence, None if self.scale is None else self.scale[idx]), used


class RotationPrior(NamedTuple):
    """A measured rotation between two views of one sequence: ``rotation`` maps view ``second``'s body frame
    into view ``first``'s (p_first = R p_second; the gyro integrated over the move between them), with its
    angular std (rad, per axis)."""

    first: int
    second: int
    rotation: np.ndarray  # (3, 3)
    sigma_rad: float


@dataclass
class GravityPriors:
    """Measured gravity per view (body frames; NaN rows = none) with angular std per view (rad).

    ``bias_sigma_rad`` adds a constant tilt b of all measured directions (body frame, unit-vector units,
    prior std bias_sigma_rad): an accelerometer bias tilts every reading the same way in the sensor frame.
    ``turns`` (:class:`RotationPrior` each): the rotations the IMU's gyro measured between views. Where the
    images pin the views' relative rotations loosely (a few views, bars still ringing), these do, and with
    the views at several attitudes they separate the accelerometer's tilt from gravity (docs/PIPELINE.md,
    "The joint estimate over the sequence").
    """

    directions: np.ndarray  # (K, 3)
    sigma_rad: np.ndarray  # (K,)
    bias_sigma_rad: float | None = None
    turns: tuple = ()

    def __post_init__(self):
        d = np.asarray(self.directions, dtype=float).reshape(-1, 3)
        self.directions = np.where(np.all(np.isfinite(d), axis=1, keepdims=True), normalize(d), np.nan)
        self.sigma_rad = np.broadcast_to(np.asarray(self.sigma_rad, dtype=float), (len(d),)).copy()

    @property
    def active(self) -> np.ndarray:
        return np.all(np.isfinite(self.directions), axis=1) & np.isfinite(self.sigma_rad) & (self.sigma_rad > 0)

    def direction_residual(self, k: int, g_k: np.ndarray, bias: np.ndarray) -> np.ndarray:
        """Residual (3,) of view k's unit gravity direction g_k (its body frame) against the measured one m,
        over the std: the tangent-plane error of g_k tilted by ``bias`` at m, and 1 - cos of the angle between
        g_k and m. For no bias the two make the chord between g_k and m, which grows to its largest where they
        point opposite ways; the projection alone is zero there too, so a sequence whose images hardly fix
        gravity could settle upside down at no cost. The bias tilts the tangent part only: a component along
        each view's measured direction (which differs from view to view) is nothing a tilt does."""
        m = self.directions[k]
        return np.append(tangent_basis(m).T @ (g_k + bias), 1.0 - float(m @ g_k)) / self.sigma_rad[k]

    def directions_chi2(self, state) -> float:
        """Sum of the squared :meth:`direction_residual` of every active view at a :class:`BundleState` (its
        bias included); 0 without gravity."""
        if state.gravity is None:
            return 0.0
        b = state.bias if state.bias is not None else np.zeros(3)
        g = normalize(np.einsum("kji,kj->ki", state.R, state.origin_gravity()))
        return float(sum(np.sum(self.direction_residual(k, g[k], b) ** 2) for k in np.flatnonzero(self.active)))

    def chi2(self, state) -> float:
        """Sum of the squared prior residuals (measured directions, the bias's prior, the measured rotations)
        at a :class:`BundleState`, in units of their variances: what these priors say of a gravity candidate
        beside the images' cost."""
        total = self.directions_chi2(state)
        b = state.bias if state.bias is not None else np.zeros(3)
        if state.gravity is not None and self.bias_sigma_rad:
            total += float(b @ b) / self.bias_sigma_rad ** 2
        for turn in self.turns:
            r = log_so3(turn.rotation.T @ state.R[turn.first].T @ state.R[turn.second]) / turn.sigma_rad
            total += float(r @ r)
        return total


@dataclass
class GravityInformation:
    """Gaussian information on view 0's gravity direction: Lambda (2, 2) in tangent_basis(direction), rad^-2.

    What views that left a sliding window knew about gravity, condensed with their poses fixed
    (:func:`condense_gravity`).
    """

    direction: np.ndarray  # (3,) unit
    information: np.ndarray  # (2, 2)

    def combined(self, other: GravityInformation | None) -> GravityInformation:
        """Sum of two informations, in the chart of the better-informed one (moved to their weighted mean)."""
        if other is None:
            return self
        a, b = (self, other) if np.trace(self.information) >= np.trace(other.information) else (other, self)
        B = tangent_basis(a.direction)
        T = B.T @ tangent_basis(b.direction)  # b's tangent angles in a's chart (close directions)
        Lb = T @ b.information @ T.T
        info = a.information + Lb
        off = B.T @ (b.direction - a.direction)
        shift = np.linalg.lstsq(info + 1e-12 * np.eye(2), Lb @ off, rcond=None)[0]
        d = normalize(a.direction + B @ shift)
        Bn = tangent_basis(d)
        T2 = Bn.T @ B
        return GravityInformation(d, T2 @ info @ T2.T)


class ParameterLayout:
    """Where each unknown sits in the camera block: poses of the free views (6 each, in view order: dr of
    Exp(dr) R_k in view 0's frame, then t_k), then
    gravity (2), then compliances (one per bar group), then the gravity-measurement bias (3), then the rest
    turns (3 per camera whose rest rotation is estimated, ``rest_turn_cameras`` (M,) bool)."""

    def __init__(self, num_views: int, free_views, gravity: bool, num_compliance: int = 0, bias: bool = False,
                 num_sequences: int = 1, rest_turn_cameras=None):
        free = np.zeros(num_views, bool)
        free[np.asarray(free_views, dtype=int)] = True
        self.num_views = int(num_views)
        self.free = free
        self.pose_offset = np.full(num_views, -1, dtype=np.int64)
        self.pose_offset[free] = POSE_DIM * np.arange(int(free.sum()))
        n = POSE_DIM * int(free.sum())
        self.num_sequences = int(num_sequences)
        self.gravity = slice(n, n + GRAVITY_DIM * self.num_sequences) if gravity else None  # sequence-major
        n += GRAVITY_DIM * self.num_sequences if gravity else 0
        self.compliance = slice(n, n + num_compliance) if num_compliance else None
        n += num_compliance
        self.bias = slice(n, n + BIAS_DIM) if bias else None
        n += BIAS_DIM if bias else 0
        on = None if rest_turn_cameras is None else np.asarray(rest_turn_cameras, bool)
        self.rest_turn_offset = None  # (M,) each camera's first rest-turn column, -1 where not estimated
        self.rest_turn = None
        if on is not None and on.any():
            self.rest_turn_offset = np.where(on, n + 3 * (np.cumsum(on) - 1), -1)
            self.rest_turn = slice(n, n + 3 * int(on.sum()))
            n += 3 * int(on.sum())
        self.size = n

    def pose(self, k: int) -> slice | None:
        o = int(self.pose_offset[k])
        return None if o < 0 else slice(o, o + POSE_DIM)

    def gravity_of(self, sequence: int = 0) -> slice | None:
        """The columns of one sequence's gravity."""
        g = self.gravity
        return None if g is None else slice(g.start + GRAVITY_DIM * sequence, g.start + GRAVITY_DIM * (sequence + 1))

    def local_columns(self, view: np.ndarray, compliance_col: np.ndarray | None,
                      sequence: np.ndarray | None = None, camera: np.ndarray | None = None) -> np.ndarray:
        """Camera-block columns (N, 8 [+1] [+3]) of observations: pose of their view, their sequence's gravity,
        their compliance, their camera's rest turn; ``size`` where a column does not exist (fixed view, fixed
        gravity, rigid camera, a camera whose rest rotation is not estimated)."""
        n = self.size
        off = self.pose_offset[view]
        pose = np.where(off[:, None] >= 0, off[:, None] + np.arange(POSE_DIM), n)
        g = self.gravity
        seq = np.zeros(len(view), np.int64) if sequence is None else sequence
        grav = g.start + GRAVITY_DIM * seq[:, None] + np.arange(GRAVITY_DIM) if g else np.full((len(view), 2), n)
        cols = [pose, grav]
        if compliance_col is not None:
            c = self.compliance
            cols.append(np.where(compliance_col >= 0, c.start + compliance_col, n)[:, None])
        if self.rest_turn_offset is not None and camera is not None:
            off = self.rest_turn_offset[camera]
            cols.append(np.where(off[:, None] >= 0, off[:, None] + np.arange(3), n))
        return np.concatenate(cols, axis=1)


@dataclass
class BundleState:
    """Poses (K, 3, 3), (K, 3) of view k in view 0; gravity of view 0 (m/s^2), (3,) -- or (S, 3), one per
    sequence, for independent sequences -- or None; landmarks (P, 3) in view 0; compliance per group (or None);
    bias (3,) of the measured gravity directions (or None); each camera's rest turn E_i (or None: the rig
    file's rest rotations as given)."""

    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray | None
    points: np.ndarray
    compliance: np.ndarray | None = None
    bias: np.ndarray | None = None
    view_sequence: np.ndarray | None = None  # (K,) with several sequences
    rest_turns: np.ndarray | None = None  # (M, 3, 3): camera i's rest rotation is V_i E_i (its calibration's error)

    def origin_gravity(self) -> np.ndarray | None:
        """(K, 3) gravity of each view's sequence origin (body frame of that sequence's first view)."""
        if self.gravity is None:
            return None
        g = np.asarray(self.gravity).reshape(-1, 3)
        return g[np.zeros(len(self.R), np.int64) if self.view_sequence is None else self.view_sequence]

    @property
    def view_gravity(self) -> np.ndarray | None:
        """(K, 3) gravity in each view's body frame, g_k = R_k^T g_0."""
        return None if self.gravity is None else np.einsum("kji,kj->ki", self.R, self.origin_gravity())


# ---------------------------------------------------------------------------
# The problem
# ---------------------------------------------------------------------------

# No landmark lies nearer to a camera that sees it than this (m): nearer than any lens of such a rig focuses,
# inside the rig's own bars. Two rays of a wrong correspondence (or of a pose the solve has not found yet) can
# meet at a camera's centre, and a landmark's inverse depth can grow without end while its anchor's residual
# stays exactly zero; there its other bearings' derivatives with respect to the cameras' centres grow as one
# over its depth, so a handful of such landmarks would pin the poses and the bending (gravity) with
# information no image holds (docs/PIPELINE.md, "Landmarks at a camera's centre").
NEAR_LIMIT_M = 0.05


class InverseDepthChart:
    """Local coordinates q = (a, b, rho) of each landmark in its anchor camera, frozen at the linearisation
    point: P = c + Q (a, b, 1) / rho (c, Q: the anchor camera's centre and camera -> view-0 rotation).

    Residuals of distant (low-parallax) landmarks are nearly linear in the inverse depth rho but not in P,
    so steps taken in this chart stay valid where Euclidean steps overshoot. The Schur complement, and so the
    covariance of the camera block, does not depend on the chart. Landmarks not in front of their anchor keep
    Euclidean coordinates.
    """

    def __init__(self, c, Q, P):
        """c (P, 3), Q (P, 3, 3): anchor camera centre and rotation (camera -> view 0); P (P, 3) landmarks."""
        self.c, self.Q, self.P = c, Q, P
        X = np.einsum("nji,nj->ni", Q, P - c)
        z = X[:, 2]
        self.front = z > 1e-9 * np.linalg.norm(X, axis=1) + 1e-12
        zs = np.where(self.front, z, 1.0)
        self.q = np.stack([X[:, 0] / zs, X[:, 1] / zs, 1.0 / zs], axis=1)
        L = np.zeros((len(P), 3, 3))  # d(a/rho, b/rho, 1/rho) / d(a, b, rho)
        L[:, 0, 0] = L[:, 1, 1] = zs
        L[:, 0, 2] = -X[:, 0] * zs
        L[:, 1, 2] = -X[:, 1] * zs
        L[:, 2, 2] = -zs * zs
        self.M = np.where(self.front[:, None, None], Q @ L, np.eye(3))  # dP/dq

    def retract(self, dq):
        """Landmarks after a step dq in the chart; rho may shrink at most 100-fold per step (no jump through
        infinity) and grows no further than the anchor's near limit (:data:`NEAR_LIMIT_M`)."""
        q = self.q + dq
        rho = np.clip(q[:, 2], 1e-2 * self.q[:, 2], np.maximum(1.0 / NEAR_LIMIT_M, self.q[:, 2]))
        X = np.stack([q[:, 0], q[:, 1], np.ones(len(q))], axis=1) / rho[:, None]
        P_chart = self.c + np.einsum("nij,nj->ni", self.Q, X)
        return np.where(self.front[:, None], P_chart, self.P + dq)


def robust_sigma(e: np.ndarray, num_points: int, num_params: int = 0, floor: float = 1e-9,
                 huber_k: float = 3.0) -> float:
    """Std (rad) of the angular noise behind residual components e (N, 2), robust to outliers but not blind
    to heavy tails.

    The median absolute residual gives a first scale; the noise is then the RMS of the residual norms
    with the Huber weights of that scale (outliers beyond huber_k count linearly, so they barely weigh): for
    Gaussian noise the two agree, for the heavier tails of real correspondences the RMS is the honest one
    (the MAD alone would make the covariance overconfident). The landmarks and the camera block absorb
    3 P + num_params of the 2 N residual components: the result is scaled by sqrt(n_res / (n_res - n_params)).
    """
    n_res = e.size
    if n_res == 0:
        return math.nan  # no residual: nothing measures the noise
    dof = max(n_res - 3 * num_points - num_params, 1)
    s0 = max(MAD_TO_STD * float(np.median(np.abs(e))), floor)
    r2 = np.einsum("ni,ni->n", e, e) / (s0 * s0)
    w = HuberLoss(huber_k).weight(r2)
    s = s0 * math.sqrt(float(np.sum(w * r2)) / max(float(np.sum(w)), 1e-300) / 2.0)  # per component
    return max(s * math.sqrt(n_res / dof), floor)


def camera_noise_factors(e: np.ndarray, cam: np.ndarray, num_cameras: int, huber_k: float = 3.0) -> np.ndarray:
    """Each camera's angular noise relative to all cameras' (M,), from the residuals e (N, 2) of a solve
    (rad; observation i from camera cam[i]): the square roots of the a posteriori variance factors per
    camera. One noise for all cameras would weigh a fisheye's observations (fewer pixels per radian) or a
    blurrier camera's as much as the sharpest's, and publish a covariance that fits none of them. The same
    robust scale as :func:`robust_sigma` (Huber-weighted RMS); 1 for cameras with fewer than 10
    observations (too few to tell)."""
    e = np.asarray(e, float).reshape(-1, 2)
    cam = np.asarray(cam, np.int64)
    out = np.ones(int(num_cameras))
    if len(e) < 10:
        return out
    s_all = robust_sigma(e, 0, 0, huber_k=huber_k)
    for c in np.unique(cam):  # cameras, not observations: a handful of iterations
        m = cam == c
        if m.sum() >= 10:
            out[c] = robust_sigma(e[m], 0, 0, huber_k=huber_k) / s_all
    return out


@dataclass
class _ViewModel:
    """Per (view, camera), flattened view-major, in view 0's frame: bent centre c, camera -> view 0 rotation Q,
    the model derivatives stacked as (Kw; -Dw) (6, 3), and the gravity g_k of each view (body frames) and g_0."""

    c: np.ndarray
    Q: np.ndarray
    KD: np.ndarray
    gk: np.ndarray
    g0: np.ndarray
    compliance: tuple | None


SIGMA_TOLERANCE = 0.2  # relative change of the robust noise estimate that is adopted (and delays convergence)


class BundleWorkspace:
    """What one bundle adjustment reuses between evaluations, each entry keyed by the state (and rig) it was
    computed for: states are values (a step makes a new one; nothing modifies one in place).

    ``views``: the bent cameras of the last state evaluated (a trial state's cost and its linearisation once
    accepted share them); ``rig``: the rig at the last state's compliances; ``linearization``: residuals,
    Jacobians and landmark chart of the last linearised state (a new noise scale re-weights them, the step
    from that state retracts in its chart); ``trial``: the residuals of the last cost() (re-fitting that
    state's landmarks starts from them). One workspace per adjustment (:func:`adjust_bundle` makes it); the
    problems of one adjustment at different noise scales share it.
    """

    def __init__(self):
        self.views = None  # (state, rig, _ViewModel)
        self.rig = None  # (state, rig with the state's compliances)
        self.linearization = None  # (state, rig, e (rad), Jc, dX, chart)
        self.trial = None  # (state, rig, e (rad))


class SequenceBundleProblem:
    """Residuals, Jacobians and normal equations of the joint bundle adjustment (the LM problem of :mod:`.lm`).

    ``sigma`` (rad) is the noise scale of the cost: residuals are divided by it and the Huber zone is
    ``huber_k`` of it. It is fixed for the problem's life; :meth:`with_sigma` gives the same problem at
    another scale (how :func:`adjust_bundle` re-estimates the noise between LM runs). ``workspace``: where
    evaluations are reused (a new :class:`BundleWorkspace` by default). ``camera_scale`` (M,):
    each camera's noise relative to sigma (its a posteriori variance factor's square root, see
    :func:`camera_noise_factors`; default all 1): camera i's residuals are scaled by sigma * camera_scale[i].
    """

    def __init__(self, rig: Rig, obs: Observations, layout: ParameterLayout, sigma: float, huber_k: float = 3.0,
                 priors: GravityPriors | None = None, gravity_information: GravityInformation | None = None,
                 compliance_groups: np.ndarray | None = None, workspace: BundleWorkspace | None = None,
                 camera_scale: np.ndarray | None = None):
        self.rig, self.obs, self.layout = rig, obs, layout
        self._sigma = float(sigma)
        self.scale = np.ones(len(obs)) if camera_scale is None else np.asarray(camera_scale, float)[obs.cam]
        self.loss = HuberLoss(huber_k)
        self.priors = priors
        self.gravity_information = gravity_information
        self.gm = rig.gravity_magnitude
        self.M = rig.num_cameras
        self.groups = None if compliance_groups is None else np.asarray(compliance_groups, dtype=np.int64)
        comp_col = None if self.groups is None else self.groups[obs.cam]
        self.structure = SchurStructure(layout.local_columns(obs.view, comp_col, obs.sequence_of_view[obs.view],
                                                             obs.cam),
                                        layout.size, obs.point, obs.num_points)
        # the rest turns' prior: each estimated camera's rig-file rotation std (rad per axis)
        self.rest_turn_sigma = np.radians([c.rotation_std_deg for c in rig.cameras])
        self.Tt = np.swapaxes(tangent_basis(obs.f), 1, 2)  # (N, 2, 3): residual = T^T p / |p|
        self._anchor = self._anchors()
        self._vc = obs.view * self.M + obs.cam
        self._single = obs.num_sequences == 1
        self.workspace = BundleWorkspace() if workspace is None else workspace

    @property
    def sigma(self) -> float:
        """The noise scale (rad) of the cost."""
        return self._sigma

    def with_sigma(self, sigma: float) -> SequenceBundleProblem:
        """The same problem at the noise scale ``sigma`` (rad), sharing the structure and the workspace."""
        other = copy.copy(self)
        other._sigma = float(sigma)
        return other

    # -- model -------------------------------------------------------------
    def _anchors(self) -> np.ndarray:
        """Index of each landmark's first observation (lowest view, then camera): its chart's camera."""
        o = self.obs
        order = np.lexsort((o.cam, o.view, o.point))
        first = np.ones(len(order), bool)
        first[1:] = o.point[order][1:] != o.point[order][:-1]
        return order[first]

    def model_rig(self, state: BundleState) -> Rig:
        """The rig with the state's compliances (the given rig when there are none)."""
        if state.compliance is None:
            return self.rig
        hit = self.workspace.rig
        if hit is not None and hit[0] is state:
            return hit[1]
        k = self.rig.compliance.copy()
        on = self.groups >= 0
        k[on] = np.maximum(state.compliance[self.groups[on]], 1e-15)
        rig = self.rig.with_compliance(k)
        self.workspace.rig = (state, rig)
        return rig

    def _views(self, state: BundleState, rig: Rig) -> _ViewModel:
        """The bent cameras of every (view, camera) in view 0's frame with the model's derivatives (the last
        result is reused: a trial state's cost and its linearisation once accepted share it)."""
        hit = self.workspace.views
        if hit is not None and hit[1] is rig and _same_camera_block(hit[0], state):
            return hit[2]
        g0 = state.origin_gravity() if state.gravity is not None else np.tile([0.0, 0.0, -self.gm], (len(state.R), 1))
        gk = np.einsum("kji,kj->ki", state.R, g0)  # g_k = R_k^T g_0 (per view: its sequence's g_0)
        R = state.R[:, None]  # (K, 1, 3, 3)
        RT = np.swapaxes(R, -1, -2)
        w, W, D, Kd = deformation_jacobians(rig, gk)  # (K, M, ...) in each view's body frame
        if state.rest_turns is not None:  # the rest rotation V_i E_i: a turn about the camera's own axes
            W = W @ state.rest_turns[None]
        Q = (R @ W).reshape(-1, 3, 3)  # camera -> view 0
        c = (np.einsum("kaij,kmj->kmi", R, w) + state.t[:, None]).reshape(-1, 3)  # centre in view 0
        # d(W^T y)/dg and dw/dg turned into view 0's frame, stacked (Kw; -Dw) for one product per observation
        KD = np.concatenate([R @ Kd @ RT, -(R @ D[None] @ RT)], axis=-2).reshape(-1, 6, 3)
        vm = _ViewModel(c, Q, KD, gk, g0, None)
        if self.groups is not None:  # d(phi)/dk and d(delta)/dk of each camera, view 0's frame
            u, _, _ = rig.bar_coefficients
            L = np.linalg.norm(rig.positions, axis=1)
            a = (L**2 / 2.0)[:, None] * cross(u, gk[:, None, :])  # phi / k (K, M, 3)
            Ab = np.einsum("kmij,kmj->kmi", right_jacobian(-(rig.compliance[:, None] * a)), a)
            gb = gk[:, None, :]
            b = (L**3 / 3.0)[:, None] * (gb - np.sum(u * gb, axis=-1, keepdims=True) * u)
            vm.compliance = (np.einsum("kij,kmj->kmi", state.R, Ab).reshape(-1, 3),
                             np.einsum("kij,kmj->kmi", state.R, b).reshape(-1, 3))
        self.workspace.views = (state, rig, vm)
        return vm

    def predicted_bearings(self, state: BundleState) -> np.ndarray:
        """Unit bearings (N, 3) the model predicts for every observation at ``state`` (noise-free data)."""
        rig = self.model_rig(state)
        vm = self._views(state, rig)
        d = state.points[self.obs.point] - vm.c[self._vc]
        return normalize(np.einsum("nji,nj->ni", vm.Q[self._vc], d))

    def residuals(self, state: BundleState, rig: Rig | None = None) -> np.ndarray:
        """Angular residuals (N, 2), rad, divided by each observation's ``obs.scale`` (those of the last
        linearisation when it was at ``state``)."""
        rig = rig or self.model_rig(state)
        hit = self.workspace.linearization
        if hit is not None and hit[0] is state and hit[1] is rig:
            return hit[2]
        return self._evaluate(state, rig, jacobians=False)[0]

    def jacobians(self, state: BundleState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residuals e (N, 2), their Jacobian on each observation's local columns ``structure.cols`` (N, 2, L)
        and de/dX (N, 2, 3): what :meth:`linearize` assembles, open to a check against finite differences."""
        return self._evaluate(state, self.model_rig(state))

    def _evaluate(self, state: BundleState, rig: Rig, jacobians: bool = True, camera: bool = True):
        """Residuals e (N, 2) and, if asked, the local camera Jacobian (N, 2, L) (None unless ``camera``) and
        de/dX (N, 2, 3). With ``obs.scale`` all three are divided by each observation's scale (whitened to the
        nominal noise): a noisier observation weighs less in the fit, the noise estimate and the covariance.

        With z = X - t_k and d = X - c (c the bent camera centre) in view 0's frame, p = Q^T d in the camera
        (Q = R_k W_i(g_k)). Rotations are perturbed on the left (R_k <- Exp(dr) R_k), so every derivative is
        a product with view 0's vectors: de/dr = (de/dX [z]_x + de/dg [g_0]_x) for de/dg of the bending at
        g_k expressed in view 0 (Kw, Dw).
        """
        o = self.obs
        vm = self._views(state, rig)
        vc = self._vc
        X = state.points[o.point]
        d = X - vm.c[vc]
        Qn = vm.Q[vc]
        p = np.einsum("nji,nj->ni", Qn, d)
        inv_r = 1.0 / np.maximum(np.sqrt(np.einsum("ni,ni->n", p, p)), 1e-300)
        n = p * inv_r[:, None]
        e = np.einsum("nij,nj->ni", self.Tt, n)
        w = None if o.scale is None else 1.0 / o.scale
        if not jacobians:
            return (e if w is None else e * w[:, None]), None, None
        A = (self.Tt - e[:, :, None] * n[:, None, :]) * inv_r[:, None, None]  # de/dp (N, 2, 3)
        if w is not None:
            e, A = e * w[:, None], A * w[:, None, None]
        dX = np.einsum("nij,nkj->nik", A, Qn)  # de/dX = A Q^T
        if not camera:
            return e, None, dX
        Jc = np.empty((len(e), 2, self.structure.cols.shape[1]))
        Jc[:, :, 3:6] = -dX
        dr = cross(dX, (X - state.t[o.view])[:, None, :])  # rows a^T [z]_x = (a x z)^T
        if rig.is_flexible:
            # de/dg (g in view 0's frame) = (de/dX [d]_x) Kw - de/dX Dw, as one product with the stacked (Kw; -Dw)
            dg = np.concatenate([cross(dX, d[:, None, :]), dX], axis=2) @ vm.KD[vc]
            if self._single:
                dr += cross(dg, vm.g0[0])
                Jc[:, :, 6:8] = (dg.reshape(-1, 3) @ (self.gm * tangent_basis(normalize(vm.g0[0])))).reshape(-1, 2, 2)
            else:
                g0n = vm.g0[o.view]
                dr += cross(dg, g0n[:, None, :])
                Jc[:, :, 6:8] = dg @ (self.gm * tangent_basis(normalize(g0n)))
            if self.groups is not None:
                Aw, bw = vm.compliance
                Jc[:, :, 8] = np.einsum("nij,nj->ni", dX, cross(d, Aw[vc]) - bw[vc])
        else:
            Jc[:, :, 6:] = 0.0
        Jc[:, :, 0:3] = dr
        if self.layout.rest_turn is not None:  # Q <- Q Exp(eps): p <- Exp(-eps) p, dp/deps = [p]_x
            Jc[:, :, -3:] = cross(A, p[:, None, :])
        return e, Jc, dX

    def chart(self, state: BundleState, rig: Rig) -> _ChartByPoint:
        """Inverse-depth chart of the landmarks in their anchor cameras (bent at the anchor view's gravity)."""
        o = self.obs
        a = self._anchor
        vm = self._views(state, rig)
        vc = self._vc[a]
        return _ChartByPoint(InverseDepthChart(vm.c[vc], vm.Q[vc], state.points[o.point[a]]), o.point[a],
                             o.num_points)

    # -- priors ------------------------------------------------------------
    def prior_terms(self, state: BundleState):
        """Prior residuals (k,) and their camera-block Jacobian (k, nc), divided by their std."""
        rows, jacs = [], []
        lay, nc = self.layout, self.layout.size
        pr = self.priors
        if pr is not None and state.gravity is not None and lay.gravity is not None:
            origins = normalize(state.origin_gravity())
            seq = self.obs.sequence_of_view
            b = state.bias if state.bias is not None else np.zeros(3)
            for k in np.flatnonzero(pr.active):  # GravityPriors.direction_residual and its Jacobian
                g0 = origins[k]
                gk = state.R[k].T @ g0
                m = pr.directions[k]
                dg = np.zeros((3, nc))  # d g_k
                sl = lay.pose(k)
                if sl is not None:  # left perturbation: g_k = R_k^T Exp(-dr) g_0
                    dg[:, sl.start:sl.start + 3] = state.R[k].T @ skew(g0)
                dg[:, lay.gravity_of(int(seq[k]))] = state.R[k].T @ tangent_basis(g0)
                P = tangent_basis(m)
                J = np.concatenate([P.T @ dg, -m[None] @ dg])
                if lay.bias is not None:
                    J[:2, lay.bias] = P.T
                rows.append(pr.direction_residual(k, gk, b))
                jacs.append(J / pr.sigma_rad[k])
            if lay.bias is not None:
                J = np.zeros((3, nc))
                J[:, lay.bias] = np.eye(3) / pr.bias_sigma_rad
                rows.append(b / pr.bias_sigma_rad)
                jacs.append(J)
        for turn in () if pr is None else pr.turns:
            sa, sb = lay.pose(turn.first), lay.pose(turn.second)
            if sa is None and sb is None:
                continue
            Rb = state.R[turn.second]
            # r = Log(T^T R_a^T R_b): a left perturbation d of R_b right-multiplies the argument by
            # Exp(R_b^T d), of R_a by Exp(-R_b^T d); r moves by Jr(r)^-1 of that
            r = log_so3(turn.rotation.T @ state.R[turn.first].T @ Rb)
            Jb = np.linalg.solve(right_jacobian(r), Rb.T) / turn.sigma_rad
            J = np.zeros((3, nc))
            if sb is not None:
                J[:, sb.start:sb.start + 3] = Jb
            if sa is not None:
                J[:, sa.start:sa.start + 3] = -Jb
            rows.append(r / turn.sigma_rad)
            jacs.append(J)
        if lay.rest_turn is not None and state.rest_turns is not None:
            for i in np.flatnonzero(lay.rest_turn_offset >= 0):  # the rest turn's prior, N(0, std^2) per axis
                r = log_so3(state.rest_turns[i])
                J = np.zeros((3, nc))
                o = int(lay.rest_turn_offset[i])
                J[:, o:o + 3] = np.linalg.inv(right_jacobian(r)) / self.rest_turn_sigma[i]
                rows.append(r / self.rest_turn_sigma[i])
                jacs.append(J)
        gi = self.gravity_information
        if gi is not None and state.gravity is not None and lay.gravity is not None:
            g0 = normalize(state.origin_gravity()[0])
            Bi = tangent_basis(gi.direction)
            C = _sqrt_psd(gi.information)
            J = np.zeros((2, nc))
            J[:, lay.gravity] = C @ Bi.T @ tangent_basis(g0)
            rows.append(C @ (Bi.T @ g0))
            jacs.append(J)
        if not rows:
            return None, None
        return np.concatenate(rows), np.concatenate(jacs)

    # -- LM interface ------------------------------------------------------
    def _noise(self) -> np.ndarray:
        """(N, 1) angular noise std of each observation (rad): sigma times its camera's scale."""
        return (self.sigma * self.scale)[:, None]

    def _robust(self, e_sigma: np.ndarray):
        r2 = np.einsum("ni,ni->n", e_sigma, e_sigma)
        return self.loss.loss(r2), self.loss.weight(r2)

    def cost(self, state: BundleState) -> float:
        rig = self.model_rig(state)
        e = self.residuals(state, rig)
        self.workspace.trial = (state, rig, e)
        c, _ = self._robust(e / self._noise())
        total = float(c.sum())
        r, _ = self.prior_terms(state)
        if r is not None:
            total += 0.5 * float(r @ r)
        return total

    def linearize(self, state: BundleState) -> LinearSystem:
        rig = self.model_rig(state)
        ws = self.workspace
        hit = ws.linearization
        if hit is not None and hit[0] is state and hit[1] is rig:  # the same state at another noise scale
            e, Jc, dX, chart = hit[2:]
        else:
            e, Jc, dX = self._evaluate(state, rig)
            chart = self.chart(state, rig)
            ws.linearization = (state, rig, e, Jc, dX, chart)
        e = e / self._noise()
        c, wts = self._robust(e)
        sw = np.sqrt(wts)[:, None] / self._noise()
        system = self.structure.accumulate(Jc * sw[:, :, None], e * np.sqrt(wts)[:, None],
                                           (dX @ chart.M[self.obs.point]) * sw[:, :, None])
        system.cost = float(c.sum())
        r, J = self.prior_terms(state)
        if r is not None:
            system.add_dense(J, r)
        return system

    def step(self, state: BundleState, dc: np.ndarray, dp: np.ndarray | None) -> BundleState:
        lay = self.layout
        R, t = state.R.copy(), state.t.copy()
        free = np.flatnonzero(lay.free)
        if len(free):
            d = dc[: POSE_DIM * len(free)].reshape(-1, POSE_DIM)
            R[free] = exp_so3(d[:, :3]) @ R[free]
            t[free] = t[free] + d[:, 3:]
        g = state.gravity
        if lay.gravity is not None and g is not None:
            gh = normalize(np.asarray(g).reshape(-1, 3))
            dg = dc[lay.gravity].reshape(-1, GRAVITY_DIM)
            g = (self.gm * normalize(gh + np.einsum("sij,sj->si", tangent_basis(gh), dg))).reshape(np.shape(g))
        comp = state.compliance
        if lay.compliance is not None and comp is not None:
            comp = np.maximum(comp + dc[lay.compliance], 0.0)
        bias = state.bias
        if lay.bias is not None and bias is not None:
            bias = bias + dc[lay.bias]
        turns = state.rest_turns
        if lay.rest_turn is not None and turns is not None:
            on = np.flatnonzero(lay.rest_turn_offset >= 0)
            turns = turns.copy()
            turns[on] = turns[on] @ exp_so3(dc[lay.rest_turn].reshape(-1, 3))
        P = state.points
        if dp is not None:
            hit = self.workspace.linearization
            chart = hit[5] if hit is not None and hit[0] is state else self.chart(state, self.model_rig(state))
            P = chart.retract(dp)
        return BundleState(R, t, g, P, comp, bias, state.view_sequence, turns)

    def unwhitened(self, e: np.ndarray) -> np.ndarray:
        """Residuals (N, 2) on the nominal noise scale, from which sigma is estimated: times each
        observation's ``obs.scale`` and divided by its camera's ``camera_scale``. The extra noise an
        ``obs.scale`` stands for (a hold's residual ringing: a bias of its cameras that the view's pose
        largely absorbs) need not show in the residuals, so whitened residuals would shrink sigma and
        cancel the penalty; the residuals as measured keep it."""
        e = e if self.obs.scale is None else e * self.obs.scale[:, None]
        return e / self.scale[:, None]

    # -- points alone ------------------------------------------------------
    def triangulate(self, state: BundleState, rig: Rig | None = None) -> np.ndarray:
        """Landmarks closest (least squares) to all rays that observe them; landmarks behind a camera (or
        nearer than :data:`NEAR_LIMIT_M` in front of one) or seen along (nearly) parallel rays go far along their
        anchor's ray."""
        rig = rig or self.model_rig(state)
        o = self.obs
        vm = self._views(state, rig)
        origin = vm.c[self._vc]
        d = np.einsum("nij,nj->ni", vm.Q[self._vc], o.f)  # Q f: the ray in view 0's frame
        Pm = np.eye(3) - d[:, :, None] * d[:, None, :]
        A = group_sum(o.point, Pm, o.num_points)
        b = group_sum(o.point, np.einsum("nij,nj->ni", Pm, origin), o.num_points)
        X = np.einsum("pij,pj->pi", inv3(A, 1e-12), b)
        ev_min = _smallest_eigenvalue(A)
        depth = np.einsum("ni,ni->n", X[o.point] - origin, d)
        behind = np.bincount(o.point, weights=(depth <= NEAR_LIMIT_M).astype(float), minlength=o.num_points) > 0
        bad = behind | (ev_min < 1e-10) | ~np.all(np.isfinite(X), axis=1)
        a = self._anchor
        far = np.empty_like(X)
        far[o.point[a]] = origin[a] + 1e3 * d[a]
        return np.where(bad[:, None], far, X)

    def point_costs(self, state: BundleState, rig: Rig | None = None, residuals: np.ndarray | None = None
                    ) -> np.ndarray:
        """Robust cost of each landmark's observations (P,) (from the state's ``residuals`` when given)."""
        e = self.residuals(state, rig or self.model_rig(state)) if residuals is None else residuals
        c, _ = self._robust(e / self._noise())
        return np.bincount(self.obs.point, weights=c, minlength=self.obs.num_points)

    def refit_points(self, state: BundleState, iterations: int = 1):
        """Gauss-Newton on each landmark alone for a fixed camera block (independent 3x3 systems); a landmark
        stuck far off first restarts from triangulation. Returns (state, cost)."""
        rig = self.model_rig(state)
        trial = self.workspace.trial
        c0 = self.point_costs(state, rig, trial[2] if trial and trial[0] is state and trial[1] is rig else None)
        tri = replace(state, points=self.triangulate(state, rig))
        c_tri = self.point_costs(tri, rig)
        use = c_tri < c0
        state = replace(state, points=np.where(use[:, None], tri.points, state.points))
        c0 = np.where(use, c_tri, c0)
        for _ in range(iterations):
            e, _, dX = self._evaluate(state, rig, camera=False)
            chart = self.chart(state, rig)
            e = e / self._noise()
            _, wts = self._robust(e)
            sw = np.sqrt(wts)[:, None]
            Jp = (dX @ chart.M[self.obs.point]) * (sw / self._noise())[:, :, None]
            H = group_sum(self.obs.point, np.swapaxes(Jp, 1, 2) @ Jp, self.obs.num_points)
            b = -group_sum(self.obs.point, np.einsum("nki,nk->ni", Jp, e * sw), self.obs.num_points)
            new = replace(state, points=chart.retract(np.einsum("pij,pj->pi", inv3(H, 1e-12), b)))
            cn = self.point_costs(new, rig)
            better = cn < c0
            state = replace(state, points=np.where(better[:, None], new.points, state.points))
            c0 = np.where(better, cn, c0)
        r, _ = self.prior_terms(state)  # c0 holds every landmark's cost at the returned state
        return state, float(c0.sum()) + (0.0 if r is None else 0.5 * float(r @ r))


class _ChartByPoint:
    """An InverseDepthChart over the anchors, indexed by landmark."""

    def __init__(self, chart: InverseDepthChart, order: np.ndarray, num_points: int):
        self._chart = chart
        self._order = order
        self.M = np.empty((num_points, 3, 3))
        self.M[order] = chart.M

    def retract(self, dp: np.ndarray) -> np.ndarray:
        out = np.empty_like(dp)
        out[self._order] = self._chart.retract(dp[self._order])
        return out


def _same_camera_block(a: BundleState, b: BundleState) -> bool:
    """Whether two states share their poses, gravity and compliances (the same arrays: landmarks may differ)."""
    return a.R is b.R and a.t is b.t and a.gravity is b.gravity and a.compliance is b.compliance \
        and a.view_sequence is b.view_sequence and a.rest_turns is b.rest_turns


def _smallest_eigenvalue(A: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of symmetric 3x3 matrices (P, 3, 3) in closed form (trigonometric solution of the
    characteristic cubic, Smith 1961); ten times cheaper than a batched eigen-decomposition."""
    a, d, f = A[:, 0, 0], A[:, 1, 1], A[:, 2, 2]
    b, c, e = A[:, 0, 1], A[:, 0, 2], A[:, 1, 2]
    q = (a + d + f) / 3.0
    p = np.sqrt(((a - q) ** 2 + (d - q) ** 2 + (f - q) ** 2 + 2.0 * (b * b + c * c + e * e)) / 6.0)
    s = np.where(p > 0, p, 1.0)  # (A - q I) / p has eigenvalues 2 cos(phi + 2 pi k / 3)
    a, d, f, b, c, e = (a - q) / s, (d - q) / s, (f - q) / s, b / s, c / s, e / s
    half_det = 0.5 * (a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c))
    phi = np.arccos(np.clip(half_det, -1.0, 1.0)) / 3.0
    return np.where(p > 0, q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0), q)


def _sqrt_psd(A: np.ndarray) -> np.ndarray:
    """C with C^T C = A for a symmetric positive semi-definite A."""
    ev, V = np.linalg.eigh(0.5 * (A + A.T))
    return (V * np.sqrt(np.maximum(ev, 0.0))).T


# ---------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------

@dataclass
class BundleResult:
    """The refined state with the optimiser's statistics and the covariance of the camera block (``layout``).

    ``stats``: what the Levenberg-Marquardt did over the whole adjustment (steps tried and accepted, the cost
    at the start -- at the starting noise scale -- and at the end, why it stopped); None where no adjustment
    ran (information at a given state)."""

    state: BundleState
    layout: ParameterLayout
    sigma_rad: float  # the noise scale of the final cost (rad): given, or the robust estimate it settled at
    information: np.ndarray  # (nc, nc), rad / m units, 1/sigma^2 included
    covariance: np.ndarray  # inverse of information (inf where not observable)
    stats: LMStats | None = None

    @property
    def cost(self) -> float:
        """Final cost (chi^2 / 2 at ``sigma_rad``; 0 where no adjustment ran)."""
        return 0.0 if self.stats is None else self.stats.cost

    @property
    def iterations(self) -> int:
        return 0 if self.stats is None else self.stats.iterations

    @property
    def stop(self) -> Stop | None:
        """Why the adjustment ended; None where none ran."""
        return None if self.stats is None else self.stats.stop

    @property
    def R(self) -> np.ndarray:
        return self.state.R

    @property
    def t(self) -> np.ndarray:
        return self.state.t

    @property
    def gravity(self) -> np.ndarray | None:
        return self.state.gravity

    @property
    def points(self) -> np.ndarray:
        return self.state.points

    def gravity_tilt_covariance(self, k: int = 0) -> np.ndarray | None:
        """(5, 5) joint covariance of view k's gravity direction (rad, tangent_basis(g_k)) and the measured
        gravity's tilt (3, ``state.bias``); None without a tilt or gravity, or where they are not observable
        (:mod:`.tilt_mixture`)."""
        lay = self.layout
        if lay.gravity is None or lay.bias is None or self.state.gravity is None or self.state.bias is None:
            return None
        idx, Jm = self._gravity_jacobian(k)
        cols = np.concatenate([idx, np.arange(lay.bias.start, lay.bias.stop)])
        C = self.covariance[np.ix_(cols, cols)]
        if not np.all(np.isfinite(C)):  # the gravity or the tilt not fixed by what was solved
            return None
        J = np.zeros((5, len(cols)))
        J[:2, :len(idx)] = Jm
        J[2:, len(idx):] = np.eye(3)
        return J @ C @ J.T

    def _gravity_jacobian(self, k: int) -> tuple:
        """(columns, J (2, len)): view k's gravity direction in tangent_basis(g_k) per unit of the camera block's
        columns it depends on (the origin's gravity and view k's rotation)."""
        lay = self.layout
        g0 = normalize(self.state.origin_gravity()[k])
        Rk = self.state.R[k]
        Bk = tangent_basis(Rk.T @ g0)
        seq = 0 if self.state.view_sequence is None else int(self.state.view_sequence[k])
        cols = [lay.gravity_of(seq)]
        J = [Bk.T @ Rk.T @ tangent_basis(g0)]
        sl = lay.pose(k)
        if sl is not None:  # g_k = R_k^T g_0 moves with R_k too
            cols.insert(0, slice(sl.start, sl.start + 3))
            J.insert(0, Bk.T @ Rk.T @ skew(g0))
        return np.concatenate([np.arange(s.start, s.stop) for s in cols]), np.concatenate(J, axis=1)

    def gravity_tangent_covariance(self, k: int = 0) -> np.ndarray:
        """(2, 2) covariance (rad^2) of view k's gravity direction in tangent_basis(g_k)."""
        lay = self.layout
        if lay.gravity is None or self.state.gravity is None:
            return np.full((2, 2), np.inf)
        idx, Jm = self._gravity_jacobian(k)
        C = self.covariance[np.ix_(idx, idx)]
        if not np.all(np.isfinite(C)):
            # a singular information (e.g. the yaw and position of holds that only their IMU gravities tie to
            # the others, the images' weight all but gone to ringing) can still fix this direction
            Jfull = np.zeros((2, len(self.information)))
            Jfull[:, idx] = Jm
            return estimable_covariance(self.information, Jfull)
        return Jm @ C @ Jm.T

    def gravity_sigma_rad(self, k: int = 0) -> float:
        """Largest angular std (rad) of view k's gravity."""
        return largest_sigma(self.gravity_tangent_covariance(k))

    def gravity_covariance(self, k: int = 0) -> np.ndarray:
        """(3, 3) covariance (m^2/s^4) of view k's gravity vector (rank 2, tangent to the sphere)."""
        g = self.state.view_gravity[k]
        return gravity_covariance(g, self.gravity_tangent_covariance(k))

    def pose_covariance(self, k: int, body: bool = False) -> np.ndarray:
        """(6, 6) covariance of view k's (dr, t) (dr in view 0's frame, or with ``body`` in view k's: the
        right perturbation R_k Exp(dr)); zeros for a fixed view."""
        sl = self.layout.pose(k)
        if sl is None:
            return np.zeros((6, 6))
        C = self.covariance[sl, sl]
        if body:
            T = np.eye(6)
            T[:3, :3] = self.state.R[k].T
            C = _propagate(T, C)
        return C


def largest_sigma(cov: np.ndarray) -> float:
    """The largest std of a covariance (the root of its largest eigenvalue); inf where it is not finite."""
    if not np.all(np.isfinite(cov)):
        return math.inf
    return float(math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0)))


def gravity_covariance(g, cov_dg) -> np.ndarray:
    """3x3 covariance of g (m^2/s^4) from the 2x2 tangent covariance of the chart (rad^2)."""
    B = np.linalg.norm(g) * tangent_basis(normalize(g))
    return _propagate(B, cov_dg)


def _propagate(J: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """J cov J^T; an unconstrained (non-finite) covariance stays unconstrained (inf) instead of turning NaN."""
    if not np.all(np.isfinite(cov)):
        return np.full((J.shape[0], J.shape[0]), np.inf)
    return J @ cov @ J.T


SINGULAR_EIGENVALUE = 1e-13  # of an information scaled to a unit diagonal, relative to its largest: no information
ESTIMABLE_LEAK = 1e-6  # a function's share (relative to its largest) along a null direction that is rounding only


def _unit_diagonal(info: np.ndarray) -> tuple:
    """(diagonal scale, the information scaled to a unit diagonal, symmetrised)."""
    scale = np.sqrt(np.maximum(np.abs(np.diag(info)), 1e-300))
    A = info / np.outer(scale, scale)
    return scale, 0.5 * (A + A.T)


def _null(ev: np.ndarray) -> np.ndarray:
    return ev <= SINGULAR_EIGENVALUE * max(float(ev.max()), 1e-300)


def covariance_from_information(info: np.ndarray) -> np.ndarray:
    """Inverse of a Fisher information; inf where it is singular (e.g. gravity of a rigid rig)."""
    if info.size == 0:
        return info.copy()
    scale, A = _unit_diagonal(info)
    try:
        if _null(np.linalg.eigvalsh(A)).any():
            raise np.linalg.LinAlgError
        return np.linalg.inv(A) / np.outer(scale, scale)
    except np.linalg.LinAlgError:
        return np.full_like(info, np.inf)


def estimable_covariance(info: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Covariance (m, m) of the functions of the parameters whose Jacobian is J (m, nc), by the pseudo-inverse
    of a singular information: finite where J sees nothing of its null space (the functions are estimable,
    e.g. a hold's gravity direction while the yaw about gravity of holds no image ties is free), inf where it
    does (the gravity of a rigid rig)."""
    m = len(J)
    scale, A = _unit_diagonal(info)
    try:
        ev, V = np.linalg.eigh(A)
    except np.linalg.LinAlgError:
        return np.full((m, m), np.inf)
    null = _null(ev)
    Js = J / scale
    size = max(float(np.abs(Js).max()), 1e-300)
    if null.all() or float(np.abs(Js @ V[:, null]).max(initial=0.0)) > ESTIMABLE_LEAK * size:
        return np.full((m, m), np.inf)
    P = Js @ V[:, ~null]
    return (P / ev[~null]) @ P.T


# ---------------------------------------------------------------------------
# Entry points
# ---------------------------------------------------------------------------

def rest_turns_start(rig: Rig) -> np.ndarray | None:
    """The cameras' rest turns to start an adjustment that estimates them from: the identity (M, 3, 3) where a
    camera's ``rotation_std_deg`` says its rest rotation is known only to a calibration's std, else None."""
    if not any(c.rotation_std_deg > 0 for c in rig.cameras):
        return None
    return np.tile(np.eye(3), (rig.num_cameras, 1, 1))


def adjust_bundle(rig: Rig, obs: Observations, R, t, gravity=None, points=None, *, free_views=None,
                  optimize_gravity: bool = True, priors: GravityPriors | None = None,
                  gravity_information: GravityInformation | None = None, compliance_groups=None,
                  compliance=None, bias=None, huber_k: float = 3.0, sigma_rad: float | None = None,
                  max_iterations: int = 30, tol: float = 1e-6, camera_scale=None, rest_turns=None) -> BundleResult:
    """Robust joint bundle adjustment of the views' poses, one gravity, the landmarks (and compliances).

    R (K, 3, 3), t (K, 3): starting poses of view k in view 0 (view 0 is kept as given: the identity for a
    sequence). ``gravity``: starting gravity in view 0's body frame (kept at |g| = gravity_magnitude); None
    or ``optimize_gravity=False`` keeps it fixed (irrelevant for a rigid rig). ``free_views``: the views whose
    pose is estimated (default all but 0). ``points`` (P, 3) default: triangulated. ``sigma_rad``: the
    angular noise that scales residuals and the Huber threshold (huber_k sigma); by default estimated
    robustly at the start and re-estimated as the fit settles. ``compliance_groups`` (M,) camera -> bar
    group (-1: not estimated) with starting ``compliance`` per group estimates bar compliances too.
    ``priors.bias_sigma_rad`` estimates a constant tilt of the measured gravity; ``bias`` starts it.
    ``camera_scale`` (M,): each camera's angular noise relative to sigma (:func:`camera_noise_factors` of an
    earlier solve; default all 1); the returned ``sigma_rad`` is that of a camera of scale 1. ``rest_turns``
    (M, 3, 3): starting turns E_i of the cameras' rest rotations (V_i E_i), estimated for every camera whose
    ``rotation_std_deg`` is above 0, under that std as their prior (docs/PIPELINE.md, "The rig file's
    calibration"); None: the rest rotations as the rig file gives them.
    """
    K = obs.num_views
    R = np.array(R, dtype=float).reshape(K, 3, 3)
    t = np.array(t, dtype=float).reshape(K, 3)
    gm = rig.gravity_magnitude
    optimize_gravity = optimize_gravity and gravity is not None and (rig.is_flexible or compliance_groups is not None)
    if gravity is not None:
        gravity = gm * normalize(np.asarray(gravity, dtype=float))
        if gravity.size != 3 * obs.num_sequences:
            raise ValueError(f"gravity must have shape (3,) or ({obs.num_sequences}, 3), got {gravity.shape}")
    if free_views is None:  # all views but the first of each sequence
        seq = obs.sequence_of_view
        first = np.r_[True, seq[1:] != seq[:-1]]
        free_views = np.flatnonzero(~first)
    groups = None if compliance_groups is None else np.asarray(compliance_groups, dtype=np.int64)
    num_comp = 0 if groups is None else int(groups.max()) + 1
    use_bias = (priors is not None and priors.bias_sigma_rad is not None and optimize_gravity
                and bool(priors.active.any()))
    if gravity_information is not None and obs.num_sequences > 1:
        raise ValueError("gravity_information applies to a single sequence")
    turned = None if rest_turns is None else np.array([c.rotation_std_deg > 0 for c in rig.cameras])
    layout = ParameterLayout(K, free_views, optimize_gravity, num_comp, use_bias, obs.num_sequences, turned)
    state = BundleState(R, t, gravity, np.zeros((obs.num_points, 3)),
                        None if groups is None else np.asarray(compliance, dtype=float).copy(),
                        (np.zeros(3) if bias is None else np.asarray(bias, float).copy()) if use_bias else None,
                        obs.view_sequence,
                        None if rest_turns is None else np.array(rest_turns, dtype=float).reshape(-1, 3, 3))
    prob = SequenceBundleProblem(rig, obs, layout, 1.0 if sigma_rad is None else sigma_rad, huber_k,
                                 priors if optimize_gravity else None,
                                 gravity_information if optimize_gravity else None, groups,
                                 workspace=BundleWorkspace(), camera_scale=camera_scale)
    state = replace(state, points=prob.triangulate(state) if points is None else np.array(points, dtype=float))
    opts = LMOptions(max_iterations=int(max_iterations), relative_tolerance=tol)
    if sigma_rad is None:  # start at the noise level of the start, re-estimate it as the fit settles
        prob = prob.with_sigma(robust_sigma(prob.unwhitened(prob.residuals(state)), obs.num_points, layout.size))
        state, system, stats, prob = _minimize_reestimating_sigma(prob, state, opts)
    else:
        state, system, stats = levenberg_marquardt(prob, state, opts)
    info = system.information()  # residuals were scaled by 1/sigma: this is the Fisher information
    return BundleResult(state=state, layout=layout, sigma_rad=float(prob.sigma), information=info,
                        covariance=covariance_from_information(info), stats=stats)


def _minimize_reestimating_sigma(prob: SequenceBundleProblem, state: BundleState, options: LMOptions):
    """Levenberg-Marquardt whose noise scale follows the residuals: an outer loop of LM runs of one accepted
    step each at a fixed scale; after each, sigma is re-estimated robustly (:func:`robust_sigma`) from the
    residuals there and adopted after the first step and whenever it moved by more than ``SIGMA_TOLERANCE``
    (the Huber zone follows the shrinking residuals; the fit converges only at a scale that fits them). A run
    resumes from the normal equations and the damping the previous one ended with, so the steps are those of
    one run. Returns (state, LinearSystem there, LMStats of all runs, the problem at the final scale)."""
    one_step = replace(options, max_accepted=1)
    system = damping = initial = None
    iterations = accepted = 0
    while True:
        state, system, st = levenberg_marquardt(prob, state, replace(one_step, max_iterations=options.max_iterations
                                                                     - iterations), system=system, damping=damping)
        initial = st.initial_cost if initial is None else initial
        iterations, accepted, damping, stop = iterations + st.iterations, accepted + st.accepted, st.damping, st.stop
        if st.accepted:
            new = robust_sigma(prob.unwhitened(prob.residuals(state)), prob.obs.num_points, prob.layout.size)
            if accepted == 1 or abs(new / prob.sigma - 1.0) > SIGMA_TOLERANCE:
                prob = prob.with_sigma(new)
                system = prob.linearize(state)
                stop = Stop.MAX_ACCEPTED  # the cost changed meaning: the next step judges convergence
        if stop != Stop.MAX_ACCEPTED:
            break
        if iterations >= options.max_iterations:
            stop = Stop.MAX_ITERATIONS
            break
    return state, system, LMStats(iterations=iterations, accepted=accepted, initial_cost=initial, cost=system.cost,
                                  stop=stop, damping=damping), prob


class _Reduced(NamedTuple):
    """An adjustment's observations at its solution, whitened and robustly weighted as its last step saw them:
    residuals e (N, 2), their Jacobians on the camera block with each landmark eliminated Jr (N, 2, nc), and
    the derivative of each residual by a small turn of its camera about its centre D (N, 2, 3)."""

    e: np.ndarray
    Jr: np.ndarray
    D: np.ndarray
    S: np.ndarray  # ... and by a shift of its camera's rest position, body frame (N, 2, 3)


def _reduced_jacobians(rig: Rig, obs: Observations, res: BundleResult, huber_k: float,
                       priors: GravityPriors | None, gravity_information: GravityInformation | None) -> _Reduced:
    lay, state = res.layout, res.state
    nc = res.covariance.shape[0]
    prob = SequenceBundleProblem(rig, obs, lay, res.sigma_rad, huber_k, priors if lay.gravity is not None else None,
                                 gravity_information if lay.gravity is not None else None)
    mrig = prob.model_rig(state)
    e, Jc, dX = prob._evaluate(state, mrig)
    Jp = dX @ prob.chart(state, mrig).M[obs.point]
    # a turn of the camera about its centre c moves the landmark's ray d = X - c in the camera like the
    # opposite turn of d: de/d(turn) = de/dX [d]_x, rows a^T [d]_x
    D = cross(dX, (state.points[obs.point] - prob._views(state, mrig).c[prob._vc])[:, None, :])
    # a shift s of the camera's rest position (body frame) moves its centre by R_k s: de/ds = -de/dX R_k
    S = -dX @ state.R[obs.view]
    e = e / prob._noise()
    _, wts = prob._robust(e)
    sw = np.sqrt(wts)[:, None] / prob._noise()
    Jc, Jp, e, D, S = (Jc * sw[:, :, None], Jp * sw[:, :, None], e * np.sqrt(wts)[:, None], D * sw[:, :, None],
                       S * sw[:, :, None])
    N = len(Jc)
    cols = prob.structure.cols
    # every observation's Jacobian on the whole camera block (N, 2, nc), the spare column collecting none
    Jfull = np.zeros((N, 2, nc + 1))
    # an observation's existing columns are distinct (only the spare one repeats, and it is dropped)
    Jfull[np.arange(N)[:, None, None], np.arange(2)[None, :, None], cols[:, None, :]] = Jc
    Jfull = Jfull[:, :, :nc]
    JpT = np.swapaxes(Jp, 1, 2)
    P = obs.num_points
    Hpp = group_sum(obs.point, JpT @ Jp, P)
    Hpp += 1e-12 * np.eye(3) * np.maximum(np.trace(Hpp, axis1=1, axis2=2), 1e-300)[:, None, None]
    Hpc = group_sum(obs.point, JpT @ Jfull, P)
    # with the landmark eliminated, an observation also moves the camera block through its landmark
    return _Reduced(e, Jfull - Jp @ np.linalg.solve(Hpp, Hpc)[obs.point], D, S)


def _considered_covariance(Jr: np.ndarray, D: np.ndarray, C: np.ndarray, cl: np.ndarray, s2: np.ndarray
                           ) -> np.ndarray:
    """C (sum_c s2_c A_c A_c^T) C: what random unknowns of 3 per cluster (variance ``s2`` (G,) per axis, ``cl``
    (N,) each observation's cluster 0..G-1, ``D`` (N, 2, 3) the residuals' derivative by them: a camera's turn,
    a shift of its rest position) move the solution by; A_c = sum over the cluster of Jr^T D."""
    if not np.any(s2 > 0):
        return np.zeros_like(C)
    A = group_sum(cl, np.einsum("nrc,nrk->nck", Jr, D), len(s2))  # (G, nc, 3)
    return C @ np.einsum("g,gck,gdk->cd", s2, A, A) @ C


def larger_in_every_direction(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The covariance that is, in every direction, the larger of A and B (B positive definite): B's whitened
    eigenvalues of A raised to 1 where below."""
    try:
        Lb = np.linalg.cholesky(0.5 * (B + B.T))
    except np.linalg.LinAlgError:
        return A
    Li = np.linalg.inv(Lb)
    w, V = np.linalg.eigh(Li @ (0.5 * (A + A.T)) @ Li.T)
    return Lb @ ((V * np.maximum(w, 1.0)) @ V.T) @ Lb.T


def cluster_robust_covariance(rig: Rig, obs: Observations, res: BundleResult, cluster: np.ndarray,
                              huber_k: float = 3.0, priors: GravityPriors | None = None,
                              gravity_information: GravityInformation | None = None,
                              turn_sigma: np.ndarray | None = None) -> np.ndarray:
    """The camera block's covariance of the adjustment ``res`` on ``obs`` that also holds when the errors within
    a cluster of observations (``cluster`` (N,), e.g. one camera of one hold) are correlated: the larger, in
    every direction, of the model's covariance and the jackknife over clusters (docs/PIPELINE.md, "The joint
    estimate over the sequence", step 6). ``priors`` and ``gravity_information``: those the adjustment ran
    with (they stay in every leave-one-out solve).

    The model's covariance assumes every observation's error independent. A correspondence bias shared by a
    hold's camera is not (it is the same in every frame and shifts that camera's landmarks alike), and on a
    rig that observes a component of gravity weakly the model's std can then be several times below the
    error. Leaving cluster c out moves the estimate by (H - H_c)^-1 s_c (one Gauss-Newton step from the
    solution: H the information, s_c and H_c the cluster's score and information, landmarks eliminated); the
    spread of those moves, times (G - 1) / G over G clusters, is the jackknife covariance, whatever the
    correlation within a cluster. A cluster whose removal leaves the problem singular counts with its
    infinitesimal move C s_c.

    ``turn_sigma`` (by cluster id): the std (rad per axis) of an unknown turn of each cluster's camera about its
    centre (a residual ringing nothing measured; 0: none). A turn delta_c moves the residuals by D delta_c and
    the solution by -C A_c delta_c, A_c the sum over the cluster of Jr^T D (landmarks eliminated, as the solve's
    last step weighed them); where a camera's landmarks are seen in two holds only it leaves no residual, and no
    jackknife sees it. The covariance is then in every direction at least the model's plus
    C (sum_c sigma_c^2 A_c A_c^T) C. Each camera's ``position_std_m`` (how well the rig file's calibration knows
    its rest position) is carried alike: a shift of that camera's rest position, the same in every hold, A_i
    summing over all of camera i's observations (docs/PIPELINE.md, "The rig file's calibration")."""
    C = res.covariance
    nc = C.shape[0]
    cluster = np.asarray(cluster, np.int64)
    if nc == 0 or len(obs) != len(cluster) or not np.all(np.isfinite(C)):
        return C
    ids, cl = np.unique(cluster, return_inverse=True)
    G = len(ids)
    s2 = np.zeros(G) if turn_sigma is None else np.asarray(turn_sigma, float)[ids] ** 2
    p2 = np.array([c.position_std_m for c in rig.cameras]) ** 2  # the rest positions' calibration
    if G < 3 and not np.any(s2 > 0) and not np.any(p2 > 0):
        return C
    red = _reduced_jacobians(rig, obs, res, huber_k, priors, gravity_information)
    out = C if G < 3 else _jackknife_covariance(red, cl, G, C, res.information)
    if np.any(s2 > 0) or np.any(p2 > 0):
        out = larger_in_every_direction(out, C + _considered_covariance(red.Jr, red.D, C, cl, s2)
                                        + _considered_covariance(red.Jr, red.S, C, obs.cam, p2))
    return out


def _jackknife_covariance(red: _Reduced, cl: np.ndarray, G: int, C: np.ndarray, H: np.ndarray) -> np.ndarray:
    """The widened jackknife over the G clusters ``cl`` (:func:`cluster_robust_covariance`), in every direction
    at least the model's C."""
    nc = C.shape[0]
    Jr, e = red.Jr, red.e
    s_obs = np.einsum("nrc,nr->nc", Jr, e)
    S = group_sum(cl, s_obs, G)
    Hc = group_sum(cl, np.swapaxes(Jr, 1, 2) @ Jr, G)
    moves = np.empty((G, nc))
    for c in range(G):  # clusters (holds x cameras), not observations
        A = H - Hc[c]
        try:
            ev = np.linalg.eigvalsh(0.5 * (A + A.T))
            if ev.min() <= 1e-9 * max(ev.max(), 1e-300):
                raise np.linalg.LinAlgError
            moves[c] = np.linalg.solve(A, S[c])
        except np.linalg.LinAlgError:
            moves[c] = C @ S[c]
    d = moves - moves.mean(axis=0)
    # the jackknife in the model's whitened coordinates, widened along its principal directions
    try:
        Lc = np.linalg.cholesky(0.5 * (C + C.T))
    except np.linalg.LinAlgError:
        return C
    Li = np.linalg.inv(Lc)
    dw = d @ Li.T  # the moves in the model's whitened coordinates (G, nc)
    A = dw.T @ dw * ((G - 1.0) / G)
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    w = w * jackknife_widening(dw @ V, G, w)
    return larger_in_every_direction(Lc @ ((V * w) @ V.T) @ Lc.T, C)


# The coverage a published std promises and the small-sample widening keeps: an error within two of its std, as
# often as a Gaussian's (two-sided).
JACKKNIFE_COVERAGE_SIGMAS = 2.0


def jackknife_widening(a: np.ndarray, num_clusters: int, ratio: np.ndarray | None = None) -> np.ndarray:
    """Variance factor (>= 1) per direction that makes a jackknife variance from few clusters keep its promise:
    ``a`` (G, n) the clusters' centred moves along n directions; ``ratio`` (n,) the jackknife's variance over
    the model's along them (default: the jackknife alone). The jackknife variance along a direction is a
    sum of G squared moves; when a few clusters carry it, it rests on few degrees of freedom and is itself
    uncertain, so an error over that std follows Student's t, not the normal. The degrees of freedom are
    Satterthwaite's for a sum of unequal squares, (sum a^2)^2 / sum a^4 (G - 1 for equal moves, 1 when one
    cluster carries all), at most G - 1; of the variance the model's share is known (the independent errors'
    part of it), only the excess (ratio - 1) is estimated, so the published variance has ratio^2 / (ratio -
    1)^2 times those degrees of freedom (none to add where the jackknife is the model's). The factor is the
    squared ratio of t's quantile to the normal's at ``JACKKNIFE_COVERAGE_SIGMAS`` (docs/PIPELINE.md, "The
    joint estimate over the sequence", step 6)."""
    from scipy.special import ndtr, stdtrit  # the t quantile without importing scipy.stats (seconds)

    a2 = np.asarray(a, float) ** 2
    s2, s4 = a2.sum(axis=0), (a2**2).sum(axis=0)
    nu = np.where(s4 > 0, s2**2 / np.maximum(s4, 1e-300), num_clusters - 1.0)
    nu = np.clip(nu, 1.0, max(num_clusters - 1.0, 1.0))
    if ratio is not None:
        r = np.asarray(ratio, float)
        excess = np.maximum(r - 1.0, 0.0)
        share = excess / np.maximum(r, 1.0)  # the estimated part of the published variance, in [0, 1)
        nu = np.where(share > 1e-6, nu / np.maximum(share, 1e-6) ** 2, np.inf)
    z = JACKKNIFE_COVERAGE_SIGMAS
    t = np.where(np.isfinite(nu), stdtrit(np.where(np.isfinite(nu), nu, 1.0), float(ndtr(z))), z)
    return (t / z) ** 2


def condense_gravity(rig: Rig, obs: Observations, state: BundleState, sigma_rad: float,
                     huber_k: float = 3.0) -> GravityInformation | None:
    """Information on view 0's gravity from observations whose views keep their poses ``state`` fixed (the
    landmarks eliminated): what views leaving a sliding window knew about gravity, linearised once."""
    if state.gravity is None or not rig.is_flexible or len(obs) == 0:
        return None
    layout = ParameterLayout(obs.num_views, [], True)
    prob = SequenceBundleProblem(rig, obs, layout, sigma_rad, huber_k)
    system = prob.linearize(state)
    info = system.information()
    return GravityInformation(normalize(state.gravity), 0.5 * (info + info.T))


@dataclass
class TwoViewResult:
    """Two-view refinement: (R, t) maps view 2 into view 1, g is view 1's gravity; covariance over
    (dr, t[, dg]) (rad, m, rad)."""

    R: np.ndarray
    t: np.ndarray
    g: np.ndarray | None
    points: np.ndarray
    cost: float
    iterations: int
    sigma_rad: float
    covariance: np.ndarray
    bundle: BundleResult


def refine_two_view(rig: Rig, f1, f2, cam, R, t, g=None, points=None, optimize_gravity: bool = True,
                    prior=None, max_iter: int = 30, huber_k: float = 3.0, sigma_rad: float | None = None,
                    tol: float = 1e-6) -> TwoViewResult:
    """The K = 2 case of :func:`adjust_bundle` on correspondences (f1, f2, cam).

    ``prior``: a :class:`GravityPriors` of both views (measured gravity, 4pt-bending) or None.
    """
    obs = Observations.two_view(f1, f2, cam)
    Rs = np.stack([np.eye(3), np.asarray(R, float)])
    ts = np.stack([np.zeros(3), np.asarray(t, float)])
    res = adjust_bundle(rig, obs, Rs, ts, g, points, optimize_gravity=optimize_gravity and g is not None,
                        priors=prior, huber_k=huber_k, sigma_rad=sigma_rad, max_iterations=max_iter, tol=tol)
    st = res.state
    cov = res.covariance
    if np.all(np.isfinite(cov)):
        T = np.eye(res.layout.size)  # rotation errors in view 2's body frame (right perturbation R Exp(dr))
        T[0:3, 0:3] = st.R[1].T
        cov = T @ cov @ T.T
    return TwoViewResult(R=st.R[1], t=st.t[1], g=st.gravity if res.layout.gravity is not None else None,
                         points=st.points, cost=res.cost, iterations=res.iterations, sigma_rad=res.sigma_rad,
                         covariance=cov, bundle=res)


def two_view_priors(g1, g2, sigma_rad: float) -> GravityPriors:
    """Measured gravity of both views of a pair as priors of angular std sigma_rad."""
    return GravityPriors(np.stack([np.asarray(g1, float), np.asarray(g2, float)]), np.full(2, float(sigma_rad)))


__all__ = ["BundleResult", "BundleState", "BundleWorkspace", "GravityInformation", "GravityPriors", "InverseDepthChart",
           "Observations", "ParameterLayout", "RotationPrior", "SequenceBundleProblem", "TwoViewResult",
           "adjust_bundle", "condense_gravity", "covariance_from_information", "estimable_covariance",
           "gravity_covariance", "inv3", "refine_two_view",
           "robust_sigma", "two_view_priors", "camera_noise_factors", "cluster_robust_covariance",
           "jackknife_widening"]
