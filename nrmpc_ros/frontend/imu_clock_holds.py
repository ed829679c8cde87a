"""The IMU's clock against the cameras' from the rotations between holds: seconds of offset, where no move is on
camera.

The gyro-image correlation (:mod:`.imu_clock`) reads a lag of up to a quarter second from moves both sensors
see. A recording of holds has no moves on camera, and an IMU stamped by another clock can be seconds off; every
hold then averages the accelerometer of another attitude (docs/PIPELINE.md, "IMU gravity that the images
refute"). But each estimate gives the body's rotation between two hold stamps, and the gyro gives the rotation
between any two instants: at the right lag the two agree for every pair of holds, at a wrong one the gyro's
instants fall in other holds or in the moves. The median angle between them over the pairs is searched over
lags of up to ``MAX_OFFSET_S`` either way. Near the right lag both shifted stamps stay inside their holds, where
the body does not turn, so the agreement is a plateau as wide as the holds' slack around their stamps: the
offset is its centre and its half width the uncertainty (enough to put each hold's IMU samples in the right
hold; the gyro-image correlation refines a stream's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.rig import ImuMount
from ..core.so3 import exp_so3

MAX_OFFSET_S = 10.0
"""Offsets searched either way (s): an IMU stamped by its own clock, or a driver's buffering, not a
transport lag."""

STEP_S = 0.01
"""Grid of the search (s): finer than any hold's slack around its stamp, which is what resolves the offset."""

MIN_PAIRS = 3
"""Pairs of holds needed: fewer can agree at a wrong lag by chance (a move and its return)."""

AGREE_DEG = 1.0
"""A pair agrees at a lag when the gyro's rotation is within this of the images' (deg): the gyro's bias over a
few seconds and the images' error are a few tenths."""

EVIDENCE_RATIO = 2.0
"""An offset refutes the stamps as read only where they disagree with the images (median over the pairs) at
least this many times as much as the offset does: a lag is chosen as the one where most pairs agree, and where
the images' turns are a degree off (vision alone on two cameras of one bar, snapshots) a shift that catches the
end of a move can bring one more pair within ``AGREE_DEG`` by chance, at the same median disagreement; an IMU
clock really off puts the gyro's instants in other holds or in the moves, degrees to tens of degrees away."""


@dataclass(frozen=True)
class HoldsClockOffset:
    """The offset to add to the IMU's stamps (s) and its half width, the pairs of holds it rests on, and the
    median disagreement of the gyro with the images at it and at the stamps as they are (deg)."""

    offset_s: float
    half_width_s: float
    pairs: int
    residual_deg: float
    as_stamped_deg: float

    @property
    def refutes_stamps(self) -> bool:
        """Whether the pairs show the IMU's stamps off: zero lies outside the offset's interval, and the stamps as
        read disagree with the images beyond ``AGREE_DEG`` and ``EVIDENCE_RATIO`` times the offset's residual."""
        return abs(self.offset_s) > self.half_width_s and \
            self.as_stamped_deg > max(AGREE_DEG, EVIDENCE_RATIO * self.residual_deg)


def orientations(t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N, 3, 3) the IMU's orientation at each sample in its frame at the first one (p_first = C p_i): the
    rates held from each sample to the next, prefix products in log2 N array products."""
    dt = np.diff(np.asarray(t, float))
    C = np.concatenate([np.eye(3)[None], exp_so3(np.asarray(w, float)[:-1] * dt[:, None])])
    k = 1
    while k < len(C):  # Hillis-Steele scan: after the step with k, C[i] holds the product of the last 2k factors
        C[k:] = C[:-k] @ C[k:]
        k *= 2
    return C


def offset_from_turns(t: np.ndarray, w: np.ndarray, mount: ImuMount, pairs: list) -> HoldsClockOffset | None:
    """The IMU clock offset from ``pairs`` = [(span_a, span_b, R)]: the still spans (t0, t1) of two holds in the
    cameras' clock (s; a stamp alone as (t, t)) and the body's rotation the images gave between them
    (p_a = R p_b), with the gyro samples (IMU stamps ``t``, rates ``w`` rad/s in the IMU frame) and the IMU's
    mount. A pair agrees at a lag where the gyro's rotation from either end of one span to either end of the
    other is the images' (the body stood still through both spans and turned as the images say between them).
    None with fewer than ``MIN_PAIRS`` pairs inside the samples' span, an IMU inside a camera (it turns with its
    bar), or no lag where more than half of the pairs agree."""
    t = np.asarray(t, float)
    if mount.mount != "body" or len(t) < 2 or len(pairs) < MIN_PAIRS:
        return None
    spans_a = np.array([p[0] for p in pairs], float).reshape(-1, 2)
    spans_b = np.array([p[1] for p in pairs], float).reshape(-1, 2)
    R = np.array([p[2] for p in pairs], float).reshape(-1, 3, 3)
    C = orientations(t, w)
    M = mount.rotation  # IMU -> body
    lags = np.arange(-MAX_OFFSET_S, MAX_OFFSET_S + STEP_S / 2, STEP_S)

    def at(times):  # the sample holding at each shifted time: (lags, pairs)
        return np.clip(np.searchsorted(t, times[None, :] + lags[:, None]) - 1, 0, len(t) - 1)

    inside = (spans_a[None, :, 0] + lags[:, None] >= t[0]) & (spans_b[None, :, 1] + lags[:, None] <= t[-1])
    angle = np.zeros(inside.shape)
    for ea in (0, 1):  # either end of each span: four rotations per pair and lag
        Ca = np.swapaxes(C[at(spans_a[:, ea])], -1, -2)
        for eb in (0, 1):
            gyro = M @ Ca @ C[at(spans_b[:, eb])] @ M.T  # p_a = gyro p_b, body frame
            cos = (np.einsum("pij,lpij->lp", R, gyro) - 1.0) / 2.0  # trace(R^T gyro)
            angle = np.maximum(angle, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    angle = np.where(inside, angle, np.inf)
    counted = inside.sum(axis=1)
    agreeing = np.where(counted >= MIN_PAIRS, np.sum(angle <= AGREE_DEG, axis=1), 0)
    best = int(agreeing.max())
    plateau = np.flatnonzero(agreeing == best)
    if best < MIN_PAIRS or 2 * best <= counted[plateau].min():
        return None
    # the widest run of lags at the best agreement: the holds' slack around the right one; where the stamps as
    # they are agree as well as any shift, the run that holds zero (a rig turning back and forth between two
    # attitudes agrees again at a shift of two holds, as widely: no evidence of an offset)
    runs = np.split(plateau, np.flatnonzero(np.diff(plateau) > 1) + 1)
    zero = int(np.argmin(np.abs(lags)))
    run = next((r for r in runs if zero in r), max(runs, key=len))
    lo, hi = float(lags[run[0]]), float(lags[run[-1]])
    centre = int(run[len(run) // 2])
    finite = np.isfinite(angle[zero])
    return HoldsClockOffset(offset_s=-0.5 * (lo + hi), half_width_s=0.5 * (hi - lo) + STEP_S / 2,
                            pairs=int(inside[centre].sum()),
                            residual_deg=float(np.median(angle[centre][np.isfinite(angle[centre])])),
                            as_stamped_deg=float(np.median(angle[zero][finite])) if finite.any() else math.nan)


__all__ = ["AGREE_DEG", "EVIDENCE_RATIO", "HoldsClockOffset", "MAX_OFFSET_S", "MIN_PAIRS", "STEP_S",
           "offset_from_turns", "orientations"]
