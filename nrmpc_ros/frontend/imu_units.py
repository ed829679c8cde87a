"""The IMU's units: whether its gyro reads degrees per second (from the moves the images show) and its
accelerometer g (from its still norm).

sensor_msgs/Imu carries rad/s and m/s^2 (REP 103). An accelerometer in g
reads 1 at rest: directions, and so holds and IMU gravities, stand, but the
bars' loads are read at a tenth of their size (:func:`accel_in_g`,
:func:`describe_accel_scale`).

A gyro driver that passes a chip's deg/s on makes every rate 57.3 times its
size: a real gyro's bias of 1-5 deg/s reads as 1-5 rad/s, beyond what the
stillness test takes for a bias (every window moving), and the gyro's turns throw the tracks' predictions off (rendered
recordings with a 0.1 deg/s bias lost up to 5 of 7 holds). The covariances,
where the driver fills them in the same unit, do not tell: the noise they
claim is as large as the noise the samples show.

The images measure the turn's size. Over the frames the gyro shows moving,
the cameras' median image rate is divided by the median rate the body's turn
(the gyro integrated) predicts across their optical axes
(:meth:`~nrmpc_ros.frontend.imu_clock.ImuClockEstimator.moving_rates`). Their
ratio is about 1 where the gyro reads rad/s (0.8-1.7 on rendered recordings of
2-6 cameras on 1.5-8 Hz bars: the parallax of translation and the bars' swing
add motion the body's turn does not have; the frames are the gyro's moves,
not the ringing after a stop) and 1/57.3 of that where it reads deg/s
(0.02-0.07); the gyro reads deg/s where the ratio is nearer 1/57.3 than 1 in log
(below their geometric mean, 0.13) in :data:`~nrmpc_ros.frontend.imu_clock.CONFIDENCE` of
Bayesian-bootstrap resamples of the moves. A clock seconds off would read the
holds' still images against the moves' rates; the frames count only where the
images move where the gyro does
(:data:`~nrmpc_ros.frontend.imu_clock.MOVES_SHOWN_QUANTILE`), and with such a
clock they do not.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

import numpy as np

from ..core.so3 import rotation_angle
from .imu_clock import CONFIDENCE, MIN_MOVES, RESAMPLES

DEGREE = math.pi / 180.0
"""One degree in radians: the scale that turns a gyro's deg/s into rad/s."""

STANDARD_GRAVITY = 9.80665
"""m/s^2 in one g, as drivers convert."""

NO_GRAVITY_SHARE = 0.05
"""Below this share of the rig's gravity the accelerometer's still norm reads no gravity: noise and bias, a few
hundredths of a m/s^2 (an accelerometer in g reads about a tenth of it, 1 / 9.81, and is scaled instead)."""
ACCEL_SCALE_TOLERANCE = 0.1
"""The share by which the accelerometer's still norm may differ from the rig's gravity (in m/s^2, or in g times
:data:`STANDARD_GRAVITY`) and still read as that unit: a MEMS accelerometer's scale error and bias keep it within a
few percent of g."""

DEGREES_BELOW = math.sqrt(DEGREE)
"""The ratio of the images' motion to the gyro's below which the gyro reads deg/s: the geometric mean of 1 (rad/s)
and :data:`DEGREE` (deg/s)."""


class GyroEvidence(enum.Enum):
    """What measured the gyro's unit."""

    MOVES_ON_CAMERA = "moves on camera"  # the images' rate over the gyro's, frame by frame in the moves
    TURNS_BETWEEN_HOLDS = "turns between holds"  # the images' rotation between holds over the gyro's
    # no move on camera and no turn measured (a gyro in deg/s on a ringing mount reads no hold still): its noise
    # at rest beyond any MEMS gyro's, and read as deg/s the recording gave more estimates than as written
    NOISE_AND_ESTIMATES = "noise and estimates"


MIN_TURN_DEG = 2.0
"""The least turn (deg) between two holds that measures the gyro's unit: a turn the images measure to hundredths
of a degree, and one a gyro in rad/s, taken for deg/s, would shrink below 0.04 deg."""


@dataclass(frozen=True)
class GyroUnits:
    """The images' motion over the motion the gyro predicts (the median over the moving frames, or over the turns
    between holds; about 1 in rad/s, :data:`DEGREE` in deg/s), the share of resamples of the moves that read
    deg/s, the frames (0 for turns) and moves used, and what measured it."""

    ratio: float
    confidence: float
    frames: int
    moves: int
    evidence: GyroEvidence = GyroEvidence.MOVES_ON_CAMERA
    estimates: tuple = ()  # NOISE_AND_ESTIMATES: (the pass's estimates with the rates as written, read as deg/s)

    @property
    def in_degrees(self) -> bool:
        """Whether the gyro reads deg/s (module docstring)."""
        return self.confidence >= CONFIDENCE


def gyro_units(imu_clock) -> GyroUnits | None:
    """The gyro's unit as the moves the images show measure it (module docstring), from what the
    :class:`~nrmpc_ros.frontend.imu_clock.ImuClockEstimator` ``imu_clock`` collected; None without enough moves
    on camera (or without a rig file's IMU mount). Medians throughout: a gyro 57 times too large throws the
    tracks' predictions off in the moves, and the images' rates there carry a few tracks that jumped."""
    got = imu_clock.moving_rates()
    if got is None:
        return None
    images, gyro, move, moves = got
    with np.errstate(invalid="ignore", divide="ignore"):
        frame_ratio = np.nanmedian(images, axis=1) / np.median(gyro, axis=1)
    use = np.isfinite(frame_ratio)
    per_move = np.array([np.median(frame_ratio[use & (move == m)]) if np.any(use & (move == m)) else np.nan
                         for m in range(moves)])
    return _verdict(per_move, float(np.median(frame_ratio[use])), int(np.count_nonzero(use)),
                    GyroEvidence.MOVES_ON_CAMERA)


def gyro_units_from_turns(pipeline) -> GyroUnits | None:
    """The gyro's unit as the turns between holds measure it: for each hold whose gyro turn from the hold before
    it the images also measured (both in one sequence; a turn of at least :data:`MIN_TURN_DEG`), the images'
    angle over the gyro's angle as read (not wrapped at pi: a gyro in deg/s reads 57 times the turn); the
    verdict as :func:`gyro_units` takes it. Where the cameras record only the holds (or one snapshot each) the
    moves are off camera, but the holds' poses are not. None with fewer than
    :data:`~nrmpc_ros.frontend.imu_clock.MIN_MOVES` such turns."""
    ratios = []
    for R_images, gyro in pipeline.turns_between_holds():
        images = rotation_angle(R_images)
        if images >= math.radians(MIN_TURN_DEG) and gyro.read_angle_rad > 0:
            ratios.append(images / gyro.read_angle_rad)
    ratios = np.array(ratios)
    return _verdict(ratios, float(np.median(ratios)) if len(ratios) else math.nan, 0,
                    GyroEvidence.TURNS_BETWEEN_HOLDS)


def _verdict(per_move: np.ndarray, ratio: float, frames: int, evidence: GyroEvidence) -> GyroUnits | None:
    """The verdict over the moves' ratios (module docstring): None with fewer than MIN_MOVES."""
    per_move = per_move[np.isfinite(per_move)]
    if len(per_move) < MIN_MOVES:
        return None
    order = np.sort(per_move)
    weights = np.random.default_rng(0).dirichlet(np.ones(len(order)), size=RESAMPLES)  # (B, moves), sorted moves
    resampled = order[np.argmax(np.cumsum(weights, axis=1) >= 0.5, axis=1)]  # each resample's weighted median
    return GyroUnits(ratio=ratio, confidence=float(np.mean(resampled < DEGREES_BELOW)), frames=frames,
                     moves=len(order), evidence=evidence)


def accel_in_g(noise, gravity_m_s2: float) -> bool:
    """Whether the accelerometer reads in units of g: its still norm (of an :class:`~nrmpc_ros.frontend.zupt.
    ImuNoise`, the quietest windows' mean) times :data:`STANDARD_GRAVITY` is the rig's gravity within
    :data:`ACCEL_SCALE_TOLERANCE`, where it reads about 1 where m/s^2 would read 9.8."""
    norm = float(noise.accel_norm)
    return math.isfinite(norm) and gravity_m_s2 > 0 and \
        abs(norm * STANDARD_GRAVITY / gravity_m_s2 - 1.0) <= ACCEL_SCALE_TOLERANCE < abs(norm / gravity_m_s2 - 1.0)


def reads_no_gravity(noise, gravity_m_s2: float) -> bool:
    """Whether the accelerometer's still norm (of an :class:`~nrmpc_ros.frontend.zupt.ImuNoise`) is below
    :data:`NO_GRAVITY_SHARE` of the rig's gravity: it reads no gravity at rest (a fused driver's linear
    acceleration, gravity taken out), so the directions of its still means are its noise and bias, not gravity."""
    norm = float(noise.accel_norm)
    return math.isfinite(norm) and gravity_m_s2 > 0 and norm < NO_GRAVITY_SHARE * gravity_m_s2


def describe_accel_scale(noise, gravity_m_s2: float) -> str | None:
    """A sentence when the accelerometer's still norm (of an :class:`~nrmpc_ros.frontend.zupt.ImuNoise`) is off
    the rig's gravity by more than :data:`ACCEL_SCALE_TOLERANCE`, with "in units of g?" where :func:`accel_in_g`;
    else None. Directions do not depend on the scale, so holds and IMU gravities stand; what takes the magnitude
    (the bars' loads, the tip IMU's bend, the stillness test's noise from the covariances) reads it as it is."""
    norm = float(noise.accel_norm)
    if not (math.isfinite(norm) and gravity_m_s2 > 0) or abs(norm / gravity_m_s2 - 1.0) <= ACCEL_SCALE_TOLERANCE:
        return None
    if reads_no_gravity(noise, gravity_m_s2):
        return (f"the accelerometer reads {norm:.3g} m/s^2 at rest where gravity is {gravity_m_s2:.3g}: gravity "
                f"taken out (a fused driver's linear acceleration?); its gravity is not used (vision only): record "
                f"the raw accelerometer's topic (REP 145: sensor_msgs/Imu carries the specific force)")
    unit = " (in units of g?)" if accel_in_g(noise, gravity_m_s2) else ""
    return (f"the accelerometer reads {norm:.3g} at rest where gravity is {gravity_m_s2:.3g} m/s^2{unit}: "
            f"sensor_msgs/Imu carries m/s^2 (REP 145), and the bars' loads are read at {norm / gravity_m_s2:.3g} "
            f"times their size: scale the driver's output")


@dataclass(frozen=True)
class ImuUnits:
    """What a pass over a recording measured of the IMU's units: the gyro's (None: not measurable) and whether
    the accelerometer reads g (with its still norm)."""

    gyro: GyroUnits | None
    accel_in_g: bool
    accel_norm: float

    @property
    def gyro_scale(self) -> float:
        """The factor that turns the gyro's rates into rad/s."""
        return DEGREE if self.gyro is not None and self.gyro.in_degrees else 1.0

    @property
    def accel_scale(self) -> float:
        """The factor that turns the accelerometer's readings into m/s^2."""
        return STANDARD_GRAVITY if self.accel_in_g else 1.0

    @property
    def wrong(self) -> bool:
        """Whether either reads another unit than sensor_msgs/Imu's."""
        return self.gyro_scale != 1.0 or self.accel_scale != 1.0


def imu_units(pipeline) -> ImuUnits:
    """The IMU's units as a :class:`~nrmpc_ros.frontend.pipeline.Pipeline`'s collected samples and frames measure
    them: the gyro's from the moves (:func:`gyro_units`), else from the turns between holds
    (:func:`gyro_units_from_turns`), the accelerometer's from its still norm (:func:`accel_in_g`)."""
    noise = pipeline.zupt.noise_in_use
    g = noise is not None and accel_in_g(noise, pipeline.rig.gravity_magnitude)
    gyro = gyro_units(pipeline.imu_clock) or gyro_units_from_turns(pipeline)
    return ImuUnits(gyro, g, float(noise.accel_norm) if noise is not None else math.nan)


def describe_units(units: ImuUnits) -> str:
    """What is in another unit, as the replay summary and the node's warning say it."""
    parts = [describe_gyro_units(units.gyro)] if units.gyro_scale != 1.0 else []
    if units.accel_in_g:
        parts.append(f"the accelerometer reads g: {units.accel_norm:.3g} at rest")
    return "; ".join(parts) + "; sensor_msgs/Imu carries rad/s and m/s^2 (REP 103)"


class UnitsMeasuringPass:
    """A pass over a recording, ``run_pass(inputs)`` with the input settings ``inputs`` (a
    :class:`~nrmpc_ros.frontend.feeder.FeederConfig`), called with the IMU clock offset to add
    (:func:`~nrmpc_ros.frontend.imu_clock_check.clock_passes` calls it so): the first pass measures the IMU's units
    (:func:`imu_units` of ``pipeline_of(result)``); where either is not sensor_msgs/Imu's, ``said(units, result)``
    hears it and the pass runs again with ``imu_gyro_scale`` and ``imu_accel_scale`` multiplied by what turns
    them into rad/s and m/s^2, which every later pass keeps (:attr:`inputs`). ``measure`` False: never measured
    (the scales were given)."""

    def __init__(self, run_pass, inputs, pipeline_of, said=None, measure: bool = True):
        self.run_pass, self.inputs, self.pipeline_of, self.said = run_pass, inputs, pipeline_of, said
        self._measure = measure

    def __call__(self, offset_s: float):
        result = self.run_pass(replace(self.inputs, imu_clock_offset_s=offset_s))
        if self._measure:
            self._measure = False
            units = imu_units(self.pipeline_of(result))
            if units.wrong:
                self.inputs = replace(self.inputs, imu_gyro_scale=self.inputs.imu_gyro_scale * units.gyro_scale,
                                      imu_accel_scale=self.inputs.imu_accel_scale * units.accel_scale)
                if self.said is not None:
                    self.said(units, result)
                result = self.run_pass(replace(self.inputs, imu_clock_offset_s=offset_s))
            if units.gyro is None:
                result = self._try_degrees(result, offset_s, units)
        return result

    def _try_degrees(self, result, offset_s: float, units: ImuUnits):
        """Where nothing measured the gyro's unit but its noise at rest is beyond any MEMS gyro's
        (:func:`gyro_noise_beyond_mems`; a gyro in deg/s
        on a ringing mount reads no hold still, so no turn between holds measures it, and cameras that record
        only the holds show no move): a pass with the gyro read as deg/s, kept where it gives more estimates than
        the pass as it was (a gyro 57 times too large keeps the holds from reading still); else that pass."""
        before = self.pipeline_of(result)
        noise = before.zupt.noise_in_use
        beyond = None if noise is None else gyro_noise_beyond_mems(noise)
        if beyond is None:
            return result
        trial = replace(self.inputs, imu_gyro_scale=self.inputs.imu_gyro_scale * DEGREE)
        tried = self.run_pass(replace(trial, imu_clock_offset_s=offset_s))
        counts = (before.stats.estimates, self.pipeline_of(tried).stats.estimates)
        if counts[1] <= counts[0]:
            return result
        self.inputs = trial
        if self.said is not None:
            self.said(replace(units, gyro=GyroUnits(beyond[0] / beyond[1], 1.0, 0, 0,
                                                    GyroEvidence.NOISE_AND_ESTIMATES, counts)), result)
        return tried


NOISIEST_GYRO_DENSITY = 0.1 * DEGREE
"""rad/s/sqrt(Hz): the noisiest MEMS gyros' rate noise density (datasheets give 0.003-0.1 deg/s/sqrt(Hz)). At a
sample rate r its noise per sample is at most this times sqrt(r / 2); a gyro in deg/s reads 57 times its own."""


QUIETEST_GYRO_DENSITY = 0.003 * DEGREE
"""rad/s/sqrt(Hz): the quietest MEMS gyros' rate noise density. In deg/s such a gyro reads
QUIETEST_GYRO_DENSITY / DEGREE / NOISIEST_GYRO_DENSITY = 1.7 times the noisiest one's noise in rad/s."""

DEGREES_NOISE_RATIO = math.sqrt(QUIETEST_GYRO_DENSITY / DEGREE / NOISIEST_GYRO_DENSITY)
"""The gyro's noise at rest over the noisiest MEMS gyro's above which the noise alone stands for deg/s (the
geometric mean of 1, the noisiest gyro in rad/s, and the quietest's 1.7 in deg/s: 1.3); a vibrating mount's
rad/s gyro reads about 1 (the matrix's 80 Hz motor: 1.01)."""


def gyro_noise_beyond_mems(noise) -> tuple:
    """(the gyro's white noise at rest per sample, the noisiest MEMS gyro's at the IMU's rate, the rate Hz) of an
    :class:`~nrmpc_ros.frontend.zupt.ImuNoise` (the samples' own noise, not what the covariances claim) where the
    first is above the second (:data:`NOISIEST_GYRO_DENSITY`) by :data:`DEGREES_NOISE_RATIO`, else None: the hint
    that the gyro reads deg/s (no MEMS gyro in deg/s reads less; a noisy one in rad/s on a vibrating mount reads
    about the noisiest's)."""
    rate_hz = 1.0 / noise.period_s if noise.period_s > 0 else math.nan
    sigma = noise.white[1] if noise.white is not None else noise.gyro_sigma
    limit = NOISIEST_GYRO_DENSITY * math.sqrt(rate_hz / 2.0)
    if not (math.isfinite(limit) and math.isfinite(sigma)) or sigma < DEGREES_NOISE_RATIO * limit:
        return None
    return sigma, limit, rate_hz


def describe_gyro_noise(noise) -> str | None:
    """A sentence where the gyro's noise at rest is beyond any MEMS gyro's (:func:`gyro_noise_beyond_mems`), else
    None: the hint left where nothing measures the unit (cameras that record only the holds, snapshots)."""
    beyond = gyro_noise_beyond_mems(noise)
    if beyond is None:
        return None
    sigma, limit, rate_hz = beyond
    return (f"the gyro's noise at rest, {sigma:.3g} per sample, is {sigma / limit:.3g} times the noisiest MEMS "
            f"gyro's at {rate_hz:.0f} Hz ({limit:.2g} rad/s): is it in deg/s? sensor_msgs/Imu carries rad/s (REP "
            f"103): --imu-gyro-scale {DEGREE:.7f} (the node: input.imu_gyro_scale), or fix the driver")


def describe_gyro_units(units: GyroUnits) -> str:
    """The measurement as the replay summary and the node's warning say it."""
    verdict = "the gyro reads deg/s" if units.in_degrees else "the gyro reads rad/s"
    if units.evidence is GyroEvidence.NOISE_AND_ESTIMATES:
        return (f"{verdict}: no move on camera or turn between holds measures it, but its noise at rest is "
                f"{units.ratio:.3g} times the noisiest MEMS gyro's at its rate, and read as deg/s the recording "
                f"gave {units.estimates[1]} estimates where the rates as written gave {units.estimates[0]}")
    seen = f"the images move {units.ratio:.3g} times as fast as it says over {units.frames} moving frames in " \
        f"{units.moves} moves" if units.evidence is GyroEvidence.MOVES_ON_CAMERA else \
        f"the images turn the rig {units.ratio:.3g} times as far between holds as it says over {units.moves} moves"
    return (f"{verdict}: {seen} (about 1 in rad/s, {DEGREE:.4f} in deg/s; {100 * units.confidence:.0f} % "
            "of resamples of the moves read deg/s)")


__all__ = ["ACCEL_SCALE_TOLERANCE", "DEGREE", "DEGREES_BELOW", "DEGREES_NOISE_RATIO", "MIN_TURN_DEG",
           "NOISIEST_GYRO_DENSITY", "NO_GRAVITY_SHARE", "QUIETEST_GYRO_DENSITY", "STANDARD_GRAVITY", "GyroEvidence",
           "GyroUnits", "ImuUnits", "UnitsMeasuringPass", "accel_in_g", "describe_accel_scale", "describe_gyro_noise",
           "describe_gyro_units", "describe_units", "gyro_noise_beyond_mems", "gyro_units", "gyro_units_from_turns",
           "imu_units", "reads_no_gravity"]
