"""The IMU's axes as the turns between holds measure them: a rig file whose IMU rotation is wrong.

A rig file written by hand often has the IMU turned otherwise than it sits:
a flight controller mounted sideways or upside down (FRD axes taken for
FLU), an IMU inside a camera module put at the body. Its gravity then points
elsewhere at every hold; the images refute it (:mod:`.imu_agreement`) and
the holds lose the IMU (docs/PIPELINE.md, "IMU gravity that the images
refute"). The turns between holds measure the right axes.

Between two holds the gyro, read through the rig file's IMU rotation, turns
the body by R_g; the images' poses turn it by R_i. Where the IMU's true axes
are the rig file's turned by D (in the body frame), R_i = D R_g D^T, so
their rotation vectors are one rotation apart: r_i = D r_g (hand-eye
calibration of rotations). D is Wahba's problem over the turns
(:func:`wahba`, each turn weighted by its variance: the gyro's std, the
images' floor), its information sum_k (|v_k|^2 I - v_k v_k^T) / s_k^2 with v_k
= D r_g,k: a turn constrains D about every axis but its own, so two turns
about different axes fix it, and turns about one axis only leave the angle
about it unknown (:attr:`MeasuredImuAxes.sigma_rad`, no verdict). The
residuals scale that information where they are larger than the stds say
(the gyro's bias over a long move, its scale error).

The images' turns come from estimates that do not lean on the IMU: the
pair test's images-only estimate (:mod:`.imu_agreement`: on the first
holds of a run, and wherever the IMU's gravity is in doubt) and sequences
without the IMU's gravity. A sequence with it also takes the gyro's turns as
priors and follows them: with axes 38 deg off its poses turned as the gyro
said, its gravity was the IMU's, and it was published 37 deg off at the std
of a good IMU (the pair test's inlier counts let it pass).

The axes are off the rig file's (:attr:`MeasuredImuAxes.off`) where the turns
agree with one rotation (their residuals within :data:`FIT_SPREAD` of their
stds) and D stands out of its std by :data:`WRONG_AXES_CHI2` (chi-square with
3 degrees of freedom at 1e-4) and by more than :data:`AXES_TOLERANCE_DEG`.
Then the IMU's gravity is not used as the rig file reads it: the estimation
stage stops using it as soon as its turns say so (the pair test sees too
little of it). They are taken as measured (:attr:`MeasuredImuAxes.applies`) only
where D's std is within :data:`AXES_PRECISION_DEG` (a worse correction would
tilt every IMU gravity beyond the accelerometer's tilt prior) and the IMU's
gravity, turned by D, agrees with the gravity the
images measured on their own at the holds where they did (within its std,
the accelerometer's tilt prior and the IMU's floor; chi-square at 1e-3).
That last test keeps an IMU that is not where the rig file says out: an IMU
inside a camera on a bar, which the rig file puts at the body, turns with
its bar; the turns measure its mean axes, but its gravity is off by the
bar's changing bend (1-3 deg on a soft bar) at every hold. Where turns about
one axis leave D open about it, the holds' gravities fix it with them (and
the test takes the fit's three degrees of freedom off). Replay then replays
with every IMU sample turned by the correction (``FeederConfig.imu_axes_turn_xyzw``,
``--imu-axes-turn``); the node turns them from then on, a new sequence
starting. Both say the rotation the rig file should carry. Gyro turns exist
for an IMU the rig file puts at the body only (one inside a camera turns
with its bar: :func:`~nrmpc_ros.frontend.gyro.rotation_between`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri

from ..core.bundle import largest_sigma
from ..core.so3 import angle_between, log_so3, matrix_to_quat_xyzw, rotation_angle

IMAGES_TURN_SIGMA_RAD = math.radians(0.05)
"""The least std of the images' turn between two holds, per axis, added to the gyro's: sequences of settled holds
pose them to hundredths of a degree; a floor so the gyro's std alone does not set the weights of long, clean turns.
A two-hold estimate's own is often far larger (snapshots that still ring: 4-15 deg)."""

TURNS_KEPT = 40
"""The latest turns that measure the axes: every pair of them is tried (780 at most, in one array operation), and
older turns add little to forty."""

MIN_TURNS = 2
"""Turns between holds that measure the axes: two about different axes fix them, and their six numbers leave three
degrees of freedom to show whether one rotation fits both."""

FIT_SPREAD = 9.0
"""The residuals' chi-square per degree of freedom above which the turns fit no one rotation (3 times their stds):
an IMU clock seconds off reads other moves, a gyro in other units turns by other angles; no verdict then."""

ONE_TURN_CHI2 = 16.3
"""A turn's own chi-square (3 degrees of freedom, at 1 - 1e-3) within which one rotation fits it: the turns one
rotation fits, at least half of them, measure the axes (:func:`_consensus`); the others are left out (an images'
turn from a two-hold estimate in another basin)."""

SHARED_AXES_MIN_TURNS = 3
"""Turns that each refute the axes needed before one rotation they share puts the axes off: two leave the fit
three degrees of freedom, and two-hold estimates of a snapshot rig 2 deg uncertain, 8 and 16 deg off the gyro
each its own way, fitted one 27 deg rotation within them. Each refuting turn's hold is refused on its own
(:func:`turn_refutes_gyro`), so waiting for a third costs no hold."""

SHARED_AXES_SIGNIFICANCE = 1e-3
"""The significance at which turns that each refute the axes are tested for one rotation together (that of
:data:`ONE_TURN_CHI2`), over the fit's degrees of freedom (:func:`turns_share_axes`)."""

WRONG_AXES_CHI2 = 21.1
"""The squared distance (in its information) of the measured axes from the rig file's beyond which they are wrong:
the chi-square quantile with 3 degrees of freedom at 1 - 1e-4."""

GRAVITY_AGREEMENT_QUANTILE = 0.999
"""The chi-square quantile (degrees of freedom: two per hold) below which the IMU's gravities, turned by the measured
axes, agree with the images' own."""

AXES_PRECISION_DEG = 2.0
"""The largest std (deg, about any direction) of measured axes that replace the rig file's. The stds are
conservative (the gyro's scale error over the whole angle travelled, a two-hold estimate's covariance): on rendered
recordings axes of std 0.4-1.4 deg were 0.02-0.8 deg off, and ones of std 2.6-4.9 deg up to 4.9 deg off, which
would tilt every IMU gravity beyond the accelerometer's tilt prior."""

AXES_TOLERANCE_DEG = 10.0
"""The angle (deg) by which the measured axes may differ from the rig file's and leave it standing. A rig file's
IMU rotation is wrong by a convention or a mounting (tens of degrees: 38, 90, 180), not by a few degrees; a few
degrees of disagreement come as much from the bars' model as from the axes (a rig file whose bars' compliance is
off by two turned the images' two-hold turns by a degree, and the turns then measured the axes a few degrees off
where they were right)."""

TURN_REFUTES_DEG = 3.0
"""The least difference (deg) between the images' and the gyro's rotation vectors by which one turn refutes the rig
file's axes (beside its chi-square): axes 10 deg off differ by 3-5 deg on turns of 20-30 deg, a bars' model off by
two by about 1 deg."""

SAME_ANGLE_CHI2 = 10.8
"""A turn's angle agrees with the gyro's within this chi-square (1 degree of freedom, at 1 - 1e-3) of their
difference in the turn's std per axis: the axes may be off (:func:`turn_refutes_axes`)."""

MAX_AXES_SIGMA_DEG = 5.0
"""The largest std (deg) of the measured axes about any direction that still gives a verdict: turns about one axis
leave the angle about it unknown."""


def wahba(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The rotation D minimising sum_k w_k |a_k - D b_k|^2 (Wahba's problem, by SVD: a proper rotation)."""
    B = (w[:, None, None] * a[:, :, None] * b[:, None, :]).sum(axis=0)
    U, _, Vt = np.linalg.svd(B)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


class AxesVerdict(enum.Enum):
    """What the turns between holds say of the rig file's IMU axes (module docstring)."""

    NOT_MEASURABLE = "the turns do not fix the axes"  # too few, about one axis, or fitting no one rotation
    AGREE = "the rig file's axes stand"  # within their std, or within a calibration's tolerance
    UNCERTAIN = "off the rig file's, but the turns do not fix them to a calibration's tolerance"
    WRONG_UNCHECKED = "the rig file's axes are wrong (no hold's gravity the images measured on their own to check " \
        "the IMU's by)"
    GRAVITY_DISAGREES = "the IMU's gravity, so turned, still disagrees with the images'"
    WRONG = "the rig file's axes are wrong"


@dataclass(frozen=True)
class MeasuredImuAxes:
    """The IMU's axes measured from the turns between holds (module docstring): ``turn`` D, the rotation (body
    frame) from the rig file's IMU axes to the measured ones; ``cov_rad2`` its 3x3 covariance (rad^2, about the
    body's axes; the residuals' spread included); ``turns`` used; ``spread`` the residuals' chi-square per degree
    of freedom; ``gravity_angles_rad`` the angles between the IMU's gravity turned by D and the images' own at the
    holds where they measured it, and ``gravity_chi2`` their chi-square in their stds (the images', the IMU's and
    the measured axes' across each gravity, as the stds alone give it); ``left_out`` the turns that fit no rotation
    the others fit (:data:`ONE_TURN_CHI2`); ``gravity_fitted`` whether the gravities took part in the fit (the
    turns' axes alike)."""

    turn: np.ndarray
    cov_rad2: np.ndarray
    turns: int
    spread: float
    gravity_angles_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gravity_chi2: float = 0.0
    left_out: int = 0
    gravity_fitted: bool = False

    @property
    def angle_rad(self) -> float:
        return float(rotation_angle(self.turn))

    @property
    def axis(self) -> np.ndarray:
        """The unit axis D turns about (x where it does not turn)."""
        phi = log_so3(self.turn)
        n = float(np.linalg.norm(phi))
        return phi / n if n > 0 else np.array([1.0, 0.0, 0.0])

    @property
    def sigma_rad(self) -> float:
        """The largest std about any direction."""
        return largest_sigma(self.cov_rad2)

    @property
    def distance_chi2(self) -> float:
        """D's squared distance from the identity in its information."""
        phi = log_so3(self.turn)
        return float(phi @ np.linalg.solve(self.cov_rad2, phi))

    @property
    def measurable(self) -> bool:
        """Whether the turns fix the axes (about every direction within :data:`MAX_AXES_SIGMA_DEG`) and agree
        with one rotation (:data:`FIT_SPREAD`)."""
        return self.sigma_rad <= math.radians(MAX_AXES_SIGMA_DEG) and self.spread <= FIT_SPREAD

    @property
    def gravity_agrees(self) -> bool:
        """Whether the IMU's gravities turned by D agree with the images' own (module docstring)."""
        n = len(self.gravity_angles_rad)
        return n > 0 and self.gravity_chi2 <= _gravity_bound(n, self.gravity_fitted)

    @property
    def verdict(self) -> AxesVerdict:
        if not self.measurable:
            return AxesVerdict.NOT_MEASURABLE
        if self.distance_chi2 <= WRONG_AXES_CHI2 or self.angle_rad <= math.radians(AXES_TOLERANCE_DEG):
            return AxesVerdict.AGREE
        if self.sigma_rad > math.radians(AXES_PRECISION_DEG):
            return AxesVerdict.UNCERTAIN
        if not len(self.gravity_angles_rad):
            return AxesVerdict.WRONG_UNCHECKED
        return AxesVerdict.WRONG if self.gravity_agrees else AxesVerdict.GRAVITY_DISAGREES

    @property
    def applies(self) -> bool:
        """Whether the measured axes replace the rig file's (:attr:`AxesVerdict.WRONG`, or
        :attr:`AxesVerdict.WRONG_UNCHECKED` where the images measure no gravity of their own: a rig whose images
        cannot tell gravity has only the IMU's)."""
        return self.verdict in (AxesVerdict.WRONG, AxesVerdict.WRONG_UNCHECKED)

    @property
    def off(self) -> bool:
        """Whether the axes are off the rig file's (every verdict but :attr:`AxesVerdict.AGREE` and
        :attr:`AxesVerdict.NOT_MEASURABLE`): the IMU's gravity is not to be used as the rig file reads it."""
        return self.verdict not in (AxesVerdict.AGREE, AxesVerdict.NOT_MEASURABLE)

    def correction(self, mount_rotation: np.ndarray) -> np.ndarray:
        """The rotation C that turns each IMU sample (in the IMU's frame) so that the rig file's IMU rotation M
        reads it right: M C = D M, so C = M^T D M."""
        M = np.asarray(mount_rotation, dtype=float)
        return M.T @ self.turn @ M

    def rig_rotation(self, mount_rotation: np.ndarray) -> np.ndarray:
        """The IMU rotation the rig file should carry (IMU -> body): D M."""
        return self.turn @ np.asarray(mount_rotation, dtype=float)


def imu_axes_from_turns(turns, gravities=(), gravity_sigma_rad: float = 0.0) -> MeasuredImuAxes | None:
    """The IMU's axes from ``turns`` [(R_images, its std rad per axis, GyroRotation)] between holds (module
    docstring; the images' std at least :data:`IMAGES_TURN_SIGMA_RAD`) and ``gravities`` [(IMU gravity, the
    images' gravity, its std rad)] of holds whose gravity the images measured on their own (the IMU's std
    ``gravity_sigma_rad`` beside the images'); None with fewer than :data:`MIN_TURNS` turns."""
    if len(turns) < MIN_TURNS:
        return None
    r_i = np.array([log_so3(np.asarray(R, dtype=float)) for R, _, _ in turns])
    r_g = np.array([log_so3(g.R) for _, _, g in turns])
    w = np.array([_turn_weight(s, g) for _, s, g in turns])
    keep = _consensus(r_i, r_g, w)
    r_i, r_g, w = r_i[keep], r_g[keep], w[keep]
    D, _, spread = _fit(r_i, r_g, w)
    g_imu = _unit(np.array([g for g, _, _ in gravities], dtype=float).reshape(-1, 3))
    g_images = _unit(np.array([g for _, g, _ in gravities], dtype=float).reshape(-1, 3))
    g_var = np.array([s for _, _, s in gravities], dtype=float) ** 2 + gravity_sigma_rad ** 2
    info = _information(r_g @ D.T, w)
    fitted = len(gravities) > 0 and largest_sigma(_inverse(info / max(spread, 1.0))) > math.radians(
        MAX_AXES_SIGMA_DEG)
    if fitted:
        # the turns leave a direction open (their axes alike): the holds' gravities, which turn with D about
        # every axis but their own, fix it with them; the gravity test then checks a fit they took part in
        D = wahba(np.vstack([r_i, g_images]), np.vstack([r_g, g_imu]), np.concatenate([w, 1.0 / g_var]))
        spread = _spread(_turn_chi2(r_i, r_g, w, D))
        info = _information(r_g @ D.T, w) + _information(g_imu @ D.T, 1.0 / g_var)
    # the gravity test takes D's std from the stds alone: the residuals' spread widens it where the IMU turns
    # with something the rig file lacks (a bar it rides on), which is what that test is to catch
    noise_cov = _inverse(info)
    cov = _inverse(info / max(spread, 1.0))
    angles, chi2 = np.zeros(0), 0.0
    if len(gravities):
        u = g_imu @ D.T
        angles = angle_between(u, g_images)
        # per axis across each gravity: the images' std, the IMU's, and the measured axes' own across it
        across = (np.trace(noise_cov) - np.einsum("ki,ij,kj->k", u, noise_cov, u)) / 2.0 \
            if np.all(np.isfinite(noise_cov)) else np.inf
        chi2 = float(np.sum(angles ** 2 / (g_var + across)))
    return MeasuredImuAxes(D, cov, int(keep.sum()), spread, angles, chi2, int((~keep).sum()), fitted)


def turn_refutes_gyro(turn) -> bool:
    """Whether one turn (R_images, its std rad per axis, GyroRotation) refutes the gyro's turn as the rig file
    reads it: the images' rotation vector differs from the gyro's by more than :data:`ONE_TURN_CHI2` in their
    stds and by more than :data:`TURN_REFUTES_DEG` (axes off, a gyro in other units, or an images' estimate in
    another basin: one turn does not tell which)."""
    R, s, g = turn
    residual = log_so3(np.asarray(R, dtype=float)) - log_so3(g.R)
    squared = float(residual @ residual)
    return squared * _turn_weight(s, g) > ONE_TURN_CHI2 and squared > math.radians(TURN_REFUTES_DEG) ** 2


def turn_refutes_axes(turn) -> bool:
    """Whether one turn refutes the rig file's axes: it refutes the gyro's turn (:func:`turn_refutes_gyro`) while
    their angles agree within :data:`SAME_ANGLE_CHI2`. A turn about D's own axis cannot show D; any other shows it
    at once. Axes off turn the rotation vector and keep its length: a turn whose angle differs from the gyro's is
    an images' estimate in another basin, or a gyro in other units, and refutes nothing of the axes."""
    R, s, g = turn
    r_i, r_g = log_so3(np.asarray(R, dtype=float)), log_so3(g.R)
    same_angle = (float(np.linalg.norm(r_i)) - float(np.linalg.norm(r_g))) ** 2 * _turn_weight(s, g) <= \
        SAME_ANGLE_CHI2
    return same_angle and turn_refutes_gyro(turn)


def turns_share_axes(turns) -> bool:
    """Whether turns that each refute the rig file's axes (:func:`turn_refutes_axes`) fit one rotation D: every
    one of them within :data:`ONE_TURN_CHI2` of the D they fit together, and all of them together within the
    chi-square quantile of the fit's degrees of freedom (3 per turn, 3 taken by D) at the same significance. Axes
    off turn every turn by the same D and keep its angle; two-hold estimates in other basins are off each its own
    way (and often by the angle too, which no D changes): they refute the images' turns, not the axes. The joint
    test counts what the fit took: two turns whose angles are each 2-3 stds off the gyro's fit a D at 12 each,
    within the single turn's 16.3, but at 24 over three degrees of freedom no one rotation."""
    if len(turns) < SHARED_AXES_MIN_TURNS:
        return False
    r_i = np.array([log_so3(np.asarray(R, dtype=float)) for R, _, _ in turns])
    r_g = np.array([log_so3(g.R) for _, _, g in turns])
    w = np.array([_turn_weight(s, g) for _, s, g in turns])
    _, chi2_turns, _ = _fit(r_i, r_g, w)
    together = float(chdtri(3 * len(turns) - 3, SHARED_AXES_SIGNIFICANCE))
    return bool(np.all(chi2_turns <= ONE_TURN_CHI2) and float(np.sum(chi2_turns)) <= together)


def _turn_weight(sigma_images_rad: float, gyro) -> float:
    """A turn's weight: one over the variance per axis of its rotation vectors' difference, the gyro's and the
    images' (at least :data:`IMAGES_TURN_SIGMA_RAD`)."""
    return 1.0 / (gyro.sigma_rad ** 2 + max(sigma_images_rad, IMAGES_TURN_SIGMA_RAD) ** 2)


def _turn_chi2(r_i: np.ndarray, r_g: np.ndarray, w: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Each turn's chi-square against r_i = D r_g; D (3, 3), or (P, 3, 3) for P rotations at once (P, n)."""
    return w * np.sum((r_i - r_g @ np.swapaxes(D, -1, -2)) ** 2, axis=-1)


def _spread(chi2_turns: np.ndarray) -> float:
    """The turns' chi-square per degree of freedom (three per turn, three taken by the fit)."""
    return float(np.sum(chi2_turns) / max(3 * len(chi2_turns) - 3, 1))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True) if len(v) else v


def _information(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The information on a small turn of D from vectors ``v`` = D b (rows) of weights ``w``: a vector constrains
    the turn about every axis but its own, by its length squared."""
    return np.sum(w[:, None, None] * (np.sum(v * v, axis=1)[:, None, None] * np.eye(3)
                                      - v[:, :, None] * v[:, None, :]), axis=0)


def _gravity_bound(n: int, fitted: bool = False) -> float:
    """The chi-square of ``n`` holds' gravity angles (two degrees of freedom each, three fewer where they took
    part in the fit) below which they agree."""
    from scipy.stats import chi2

    return float(chi2.ppf(GRAVITY_AGREEMENT_QUANTILE, max(2 * n - 3 * fitted, 1)))


def _inverse(info: np.ndarray) -> np.ndarray:
    """A covariance from its information; infinite where the information leaves a direction open."""
    return np.linalg.pinv(info) if np.linalg.cond(info) < 1e12 else np.full((3, 3), np.inf)


def _consensus(r_i: np.ndarray, r_g: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The turns one rotation fits (mask): the rotation of every pair of turns (at once), each turn within
    :data:`ONE_TURN_CHI2` of it counted, the largest such set (the smallest chi-square among equals) where it holds
    at least half of the turns, else all of them (the spread then tells). A two-hold estimate in another basin can
    be degrees off at a std of a tenth, and in a recording with the axes off, the gravity-bound estimate it is
    weighed against is no better: such turns are left out."""
    n = len(w)
    i, j = np.triu_indices(n, 1)
    pairs = np.stack([i, j], axis=1)  # (P, 2)
    a, b, pw = r_i[pairs], r_g[pairs], w[pairs]
    U, _, Vt = np.linalg.svd(np.einsum("pk,pki,pkj->pij", pw, a, b))
    flip = np.ones((len(pairs), 3))
    flip[:, 2] = np.sign(np.linalg.det(U @ Vt))
    D = (U * flip[:, None, :]) @ Vt  # (P, 3, 3): wahba of each pair
    chi2 = _turn_chi2(r_i[None], r_g[None], w[None], D)  # (P, n)
    inside = chi2 <= ONE_TURN_CHI2
    count = inside.sum(axis=1)
    usable = (2 * count >= n) & (count >= MIN_TURNS)
    if not usable.any():
        return np.ones(n, dtype=bool)
    total = np.where(inside, chi2, 0.0).sum(axis=1)
    best = np.lexsort((total, -count))
    best = best[usable[best]][0]
    return inside[best]


def _fit(r_i: np.ndarray, r_g: np.ndarray, w: np.ndarray) -> tuple:
    """(D, each turn's chi-square, the residuals' chi-square per degree of freedom) of the turns' rotation vectors
    r_i = D r_g (weights ``w``, one per turn)."""
    D = wahba(r_i, r_g, w)
    chi2_turns = _turn_chi2(r_i, r_g, w, D)
    return D, chi2_turns, _spread(chi2_turns)


def imu_axes(pipeline) -> MeasuredImuAxes | None:
    """The IMU's axes as a :class:`~nrmpc_ros.frontend.pipeline.Pipeline`'s turns between holds (the IMU
    gravity test's images-only estimates against the gyro's turns, :attr:`~nrmpc_ros.frontend.estimation.
    HoldEstimator.axes_turns`) measure them; None with fewer than :data:`MIN_TURNS`."""
    turns = list(pipeline.estimator.axes_turns)
    sigma = math.hypot(pipeline.accel_tilt.evidence.prior_sigma_rad,
                       math.radians(pipeline.config.imu_gravity_floor_deg))
    return imu_axes_from_turns(turns, list(pipeline.estimator.images_gravities.values()), sigma)


def describe_imu_axes(axes: MeasuredImuAxes, mount_rotation: np.ndarray) -> str:
    """The measurement and its verdict as the replay summary and the node's warning say them, with the rotation
    the rig file would carry."""
    n, v = axes.axis, axes.verdict
    q = matrix_to_quat_xyzw(axes.rig_rotation(mount_rotation))
    seen = (f"the turns between holds put the IMU's axes {math.degrees(axes.angle_rad):.1f} deg about "
            f"({n[0]:.2f}, {n[1]:.2f}, {n[2]:.2f}) from the rig file's (std {math.degrees(axes.sigma_rad):.2f} deg, "
            f"{axes.turns} turns" + (f"; {axes.left_out} more that fit none left out)" if axes.left_out else ")"))
    if v is AxesVerdict.NOT_MEASURABLE:
        return f"the IMU's axes: {v.value} ({axes.turns} turns, std {math.degrees(axes.sigma_rad):.2g} deg, " \
            f"residuals {math.sqrt(axes.spread):.2g} times their stds)"
    if v is AxesVerdict.GRAVITY_DISAGREES:
        worst = math.degrees(float(np.max(axes.gravity_angles_rad)))
        return (f"{seen}, but the IMU's gravity so turned is still up to {worst:.2f} deg off the images' own at "
                f"{len(axes.gravity_angles_rad)} holds: the IMU is not where the rig file says (inside a camera on a "
                "bar the rig file puts at the body?); not applied, and the IMU's gravity is not used: give the rig "
                "file its mount")
    if v is AxesVerdict.UNCERTAIN:
        return f"{seen}, {v.value}: not applied, and the IMU's gravity is not used"
    if v is AxesVerdict.WRONG_UNCHECKED:
        seen += " (the images measured no gravity of their own to check the IMU's by)"
    return f"{seen}: the rig file's imu rotation_xyzw would be [{', '.join(f'{x:.4f}' for x in q)}]"


class AxesMeasuringPass:
    """A pass over a recording around ``inner`` (a :class:`~nrmpc_ros.frontend.imu_units.UnitsMeasuringPass`:
    called with the IMU clock offset, its ``inputs`` the input settings the passes share): the first pass measures
    the IMU's axes (:func:`imu_axes` of ``pipeline_of(result)``, with the units already measured); where they are
    :attr:`~MeasuredImuAxes.applies` the pass runs again with every IMU sample turned by the correction
    (``imu_axes_turn_xyzw``), which every later pass keeps; ``said(axes, result)`` hears every verdict but
    :attr:`AxesVerdict.AGREE` (the inputs already turned). ``mount_rotation``: the rig
    file's IMU rotation (IMU -> body); ``measure`` False: never measured (the turn was given, or no IMU)."""

    def __init__(self, inner, pipeline_of, mount_rotation: np.ndarray, said=None, measure: bool = True):
        self.inner, self.pipeline_of, self.said = inner, pipeline_of, said
        self.mount_rotation = np.asarray(mount_rotation, dtype=float)
        self._measure = measure

    def __call__(self, offset_s: float):
        result = self.inner(offset_s)
        if self._measure:
            self._measure = False
            axes = imu_axes(self.pipeline_of(result))
            wrong = axes is not None and axes.applies
            if wrong:
                self.inner.inputs = self.inner.inputs.turned_by(axes.correction(self.mount_rotation))
            if axes is not None and axes.verdict is not AxesVerdict.AGREE and self.said is not None:
                self.said(axes, result)
            if wrong:
                result = self.inner(offset_s)
        return result


__all__ = ["AXES_PRECISION_DEG", "AXES_TOLERANCE_DEG", "AxesMeasuringPass", "AxesVerdict", "FIT_SPREAD",
           "GRAVITY_AGREEMENT_QUANTILE", "IMAGES_TURN_SIGMA_RAD", "MAX_AXES_SIGMA_DEG", "MIN_TURNS", "MeasuredImuAxes",
           "ONE_TURN_CHI2", "SAME_ANGLE_CHI2", "TURNS_KEPT", "TURN_REFUTES_DEG", "WRONG_AXES_CHI2", "describe_imu_axes",
           "imu_axes", "imu_axes_from_turns", "turn_refutes_axes", "turn_refutes_gyro", "turns_share_axes", "wahba"]
