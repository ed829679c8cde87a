"""Does a hold's IMU gravity agree with the images? A pair test before the gravity enters the joint estimate.

The IMU's gravity of two holds and the images between them must tell one motion: with both gravities fixed,
the two-view estimate (``4pt-bending``) explains the correspondences about as well as the images alone do
(``6pt-bending``, gravity free). A misconfigured IMU breaks that for every hold: a rig file's IMU rotation that
is wrong (axes of another convention), or an IMU clock seconds off the cameras' (each hold then gets the
accelerometer of another attitude). The joint estimate cannot see it, since it trusts the gravities to their
std: with them its poses are tens of degrees off, its gravity the IMU's, its std that of a good IMU
(docs/PIPELINE.md, "IMU gravity that the images refute").

The test runs on the correspondences (same camera, same landmark) between the hold and the reference: the
latest hold with a gravity to trust, its accepted IMU gravity or, without one, the gravity the images gave it.
When the gravity-bound estimate explains at least ``AGREEING_SHARE`` of them, the gravity agrees (the usual
case: one ``4pt-bending`` solve). Otherwise the images alone are asked; when they explain more than
``REFUTING_RATIO`` times as many (and at least the pair minimum), the images refute the gravity: the hold is
linked without it and not published (the window solve placed it with the earlier holds' gravities of the same
IMU). The first gravity after holds without any (an IMU that starts late) waits for the next hold's
test before it is used. After a refutation a gravity that cannot be tested (too few shared landmarks) is not
used either, until one agrees again. ``UNUSABLE_AFTER`` refutations in a row are no accident of one hold: the
IMU's gravity is not used again (until a reset), and the report says how to fix the configuration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ..core.incremental import IncrementalSequence
from ..core.matches import Matches
from ..core.so3 import log_so3

AGREEING_SHARE = 0.5
"""A gravity-bound pair estimate explaining at least this share of the correspondences needs no second look: a
wrong gravity leaves a few percent of them (the rest cannot be placed), a right one most."""

REFUTING_RATIO = 2.0
"""The images refute a pair of gravities when, without them, they explain more than this many times the
correspondences the gravity-bound estimate explains."""

UNUSABLE_AFTER = 2
"""Refutations in a row after which the IMU's gravity is not used again: a configuration error, not a hold."""

MIN_CORRESPONDENCES = 12
"""Fewer correspondences with the reference hold leave the test undecided (the gravity is used)."""

AUDITED_HOLDS = 4
"""Holds of a run whose test also asks the images alone where the IMU's gravity agrees: their turn and gravity
measure the IMU's axes (:mod:`.imu_mount`). A gravity-bound pair estimate can explain most correspondences with
gravities tens of degrees off (the solve refines gravity), and the joint estimate then bends its poses to the
IMU's gravities and the gyro's turns: axes 38 deg off were published at the std of a good IMU, 37 deg off."""

REFERENCE_MAX_SIGMA_RAD = math.radians(30.0)
"""An images' gravity serves as the reference of the next test only with a std below this: the IMU faults the
test must catch put gravity tens of degrees off (axes of another convention, the attitude of another hold), and a
reference as uncertain as that (bars ringing by tens of pixels in every snapshot: stds of hundreds of degrees)
would refute a sound IMU on its own error."""


class Agreement(Enum):
    """The outcome of the pair test of a hold's IMU gravity; the value is the phrase shown."""

    AGREES = "agrees with the images"
    UNTESTED = "not tested (no earlier hold with a gravity shares enough landmarks)"
    PENDING = "not used until the next hold tests it (the holds before it have no gravity)"
    DOUBTED = "not tested since the images refuted an earlier one"
    REFUTED = "refuted by the images"
    UNUSABLE = "not used: the images refuted the IMU's gravity on consecutive holds"
    AXES_OFF = "not used: the turns between holds put the IMU's axes off the rig file's"


@dataclass(frozen=True)
class PairEvidence:
    """The correspondences of the latest refuting test and how many each estimate explained."""

    correspondences: int
    with_gravity: int
    without_gravity: int


class ImuGravityCheck:
    """The pair test of each hold's IMU gravity (see the module docstring), with what it keeps between holds:
    the reference hold (its observations and gravity), the refutations in a row, and whether the IMU's gravity
    is still used. ``tested``, ``refuted`` count holds; ``evidence`` is the latest refutation's."""

    def __init__(self, sequence: IncrementalSequence, seed: int = 0):
        self.sequence = sequence
        self.seed = seed
        self.tested = 0
        self.refuted = 0
        self.usable = True
        self.axes_off = False  # the turns between holds put the IMU's axes off the rig file's (.imu_mount)
        self.evidence: PairEvidence | None = None
        # (keys, f, cam, gravity, offset, hold key, whether the gravity is the IMU's) of the latest hold with a
        # gravity to trust
        self._reference = None
        # (reference's hold key, hold key, R: p_reference = R p_hold, its std rad per axis) of the latest test's
        # images-only estimate, where the test made one: the body's turn between the holds without the IMU (its
        # axes, :mod:`.imu_mount`)
        self.images_turn: tuple | None = None
        self.audits_left = AUDITED_HOLDS
        self._in_row = 0
        self._doubt = False  # an earlier gravity was refuted and none has agreed since

    def reset(self) -> None:
        """Forget the reference hold and trust the IMU again (a reset on request: the user may have fixed it)."""
        self._reference = None
        self._in_row = 0
        self._doubt = False
        self.usable = True
        self.axes_off = False

    def refuse_axes(self) -> None:
        """The IMU's axes are off the rig file's (the turns between holds measured them): its gravity is not used
        again (until a reset); the next :data:`AUDITED_HOLDS` holds' images-only estimates measure them on."""
        self.axes_off = True
        self.usable = False
        self.audits_left = max(self.audits_left, AUDITED_HOLDS)  # the next holds' turns measure them

    def remember(self, cam: np.ndarray, landmark: np.ndarray, f: np.ndarray, gravity: np.ndarray,
                 sigma_rad: float, offset_rad: float = 0.0, key=None) -> None:
        """A hold whose gravity came from the images (its IMU gravity absent or not used), of std ``sigma_rad``:
        the next reference where that std is below :data:`REFERENCE_MAX_SIGMA_RAD`."""
        if sigma_rad < REFERENCE_MAX_SIGMA_RAD:
            self._reference = self._observations(cam, landmark, f, gravity, offset_rad, key, False)

    @staticmethod
    def _observations(cam, landmark, f, gravity, offset_rad, key=None, from_imu=True) -> tuple:
        keys = np.asarray(cam, np.int64) * (1 << 40) + np.asarray(landmark, np.int64)
        return (keys, np.asarray(f, float), np.asarray(cam, np.int64), np.asarray(gravity, float), float(offset_rad),
                key, from_imu)

    def check(self, cam: np.ndarray, landmark: np.ndarray, f: np.ndarray, gravity: np.ndarray,
              follows_holds: bool = False, offset_rad: float = 0.0, key=None) -> Agreement:
        """The verdict on ``gravity`` (body frame) of the hold observed as (camera, landmark id, bearing).
        ``follows_holds``: the hold joins holds already estimated; then a first gravity, with nothing to test it
        against, would set the gravity of them all on its own word: it waits for the next hold's test.
        ``offset_rad``: how far the hold's residual ringing may move all of a camera's bearings alike (both
        estimates of the test take it in, with the reference's). ``key`` names the hold (:attr:`images_turn`)."""
        self.images_turn = None
        if self.axes_off:  # its turns measure the axes: a few more holds' images-only estimates
            current = self._observations(cam, landmark, f, gravity, offset_rad, key)
            left = self.audits_left
            if left > 0 and self._reference is not None:
                self._pair_test(current, counted=False)
                self.audits_left = left - 1
            self._reference = current
            return Agreement.AXES_OFF
        if not self.usable:
            return Agreement.UNUSABLE
        current = self._observations(cam, landmark, f, gravity, offset_rad, key)
        if self._reference is None and follows_holds:
            self._reference = current
            return Agreement.PENDING
        verdict = self._pair_test(current)
        if verdict is Agreement.REFUTED:
            self.refuted += 1
            self._in_row += 1
            self._doubt = True
            if self._in_row >= UNUSABLE_AFTER:
                self.usable = False
            return verdict
        if verdict is Agreement.UNTESTED and self._doubt:
            return Agreement.DOUBTED
        if verdict is Agreement.AGREES:
            self._in_row, self._doubt = 0, False
        self._reference = current
        return verdict

    def _pair_test(self, current, counted: bool = True) -> Agreement:
        if self._reference is None:
            return Agreement.UNTESTED
        keys_a, f_a, cam_a, g_a, offset_a, key_a, imu_a = self._reference
        keys_b, f_b, _, g_b, offset_b, key_b, _ = current
        shared, ia, ib = np.intersect1d(keys_a, keys_b, assume_unique=False, return_indices=True)
        n = len(shared)
        if n < MIN_CORRESPONDENCES:
            return Agreement.UNTESTED
        self.tested += counted
        seed = self.seed + self.tested
        offsets = (offset_a, offset_b)
        bound = self.sequence.two_view(Matches(f_a[ia], f_b[ib], cam_a[ia], g_a, g_b, source="IMU gravity test"),
                                       "4pt-bending", seed, offsets)
        with_g = bound.num_inliers if bound.success else 0
        agrees = with_g >= AGREEING_SHARE * n
        if agrees and self.audits_left <= 0:
            return Agreement.AGREES
        self.audits_left -= agrees
        free = self.sequence.two_view(Matches(f_a[ia], f_b[ib], cam_a[ia], source="IMU gravity test"),
                                      "6pt-bending", seed, offsets)
        without = free.num_inliers if free.success else 0
        if free.success and key_a is not None and key_b is not None:
            cov = free.info.cov_rotation
            sigma = math.sqrt(float(np.trace(cov)) / 3.0) if cov is not None and np.all(np.isfinite(cov)) else math.inf
            if _measures_turn(free, bound, sigma):
                self.images_turn = (key_a, key_b, free.R, sigma)
        if agrees:
            return Agreement.AGREES
        if without > REFUTING_RATIO * with_g and without >= MIN_CORRESPONDENCES:
            self.evidence = PairEvidence(n, with_g, without)
            return Agreement.REFUTED
        return Agreement.AGREES


TURN_AGREEMENT_CHI2 = 16.3
"""The chi-square (3 degrees of freedom at 1 - 1e-3, in the images-only estimate's std) within which its rotation
agrees with the gravity-bound estimate's."""


def _measures_turn(free, bound, sigma_rad: float) -> bool:
    """Whether the images-only estimate ``free`` measures the turn between the two holds: it explains more
    correspondences than the gravity-bound estimate ``bound``, or as many with the same rotation (within
    :data:`TURN_AGREEMENT_CHI2`). Two holds' estimate without gravity can settle in another basin, 2-4 deg off at a
    std of a tenth, and explain as many or fewer: a right IMU would then look turned. IMU axes off the rig file's
    leave the bound estimate fewer, or, a few degrees off, as many with the free one's rotation."""
    with_g = bound.num_inliers if bound.success else 0
    if free.num_inliers != with_g:
        return free.num_inliers > with_g
    residual = log_so3(free.R.T @ bound.R)
    return math.isfinite(sigma_rad) and float(residual @ residual) <= TURN_AGREEMENT_CHI2 * max(sigma_rad, 1e-9) ** 2


def describe_check(check: ImuGravityCheck) -> str | None:
    """One line on the pair tests where the images refuted an IMU gravity (None where none was): how often, the
    latest evidence, and what to check."""
    if not check.refuted:
        return None
    e = check.evidence
    evidence = (f"; the latest pair: of {e.correspondences} correspondences {e.with_gravity} fit the IMU's "
                f"gravities, {e.without_gravity} the images alone") if e is not None else ""
    state = "not used since (the turns between holds put its axes off the rig file's)" if check.axes_off else \
        "not used since (consecutive refutations)" if not check.usable else "left out of those holds"
    return (f"the images refuted the IMU's gravity on {check.refuted} of {check.tested} tested holds{evidence}; "
            f"the IMU's gravity is {state}, and a refuted hold is not published: check the rig file's imu rotation "
            f"and the IMU's clock against the cameras' (input.imu_clock_offset_s, replay --imu-clock-offset)")


__all__ = ["AGREEING_SHARE", "Agreement", "ImuGravityCheck", "MIN_CORRESPONDENCES", "PairEvidence",
           "REFUTING_RATIO", "TURN_AGREEMENT_CHI2", "UNUSABLE_AFTER",
           "describe_check"]
