"""Whether the IMU's gyro reads degrees per second, from the moves the images show.

sensor_msgs/Imu carries rad/s (REP 103). A driver that passes a chip's deg/s
on makes every rate 57.3 times its size: the stillness test reads the gyro's
bias as a steady turn and its noise as motion, the gyro's turns throw the
tracks' predictions off, and on a rendered recording of 9 holds none was
estimated. The covariances, where the driver fills them in the same unit, do
not tell: the noise they claim is as large as the noise the samples show.

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

import math
from dataclasses import dataclass

import numpy as np

from .imu_clock import CONFIDENCE, MIN_MOVES, RESAMPLES

DEGREE = math.pi / 180.0
"""One degree in radians: the scale that turns a gyro's deg/s into rad/s."""

DEGREES_BELOW = math.sqrt(DEGREE)
"""The ratio of the images' motion to the gyro's below which the gyro reads deg/s: the geometric mean of 1 (rad/s)
and :data:`DEGREE` (deg/s)."""


@dataclass(frozen=True)
class GyroUnits:
    """The images' motion over the motion the gyro predicts (summed over the moving frames; about 1 in rad/s,
    :data:`DEGREE` in deg/s), the share of resamples of the moves that read deg/s, and the frames and moves
    used."""

    ratio: float
    confidence: float
    frames: int
    moves: int

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
    per_move = per_move[np.isfinite(per_move)]
    if len(per_move) < MIN_MOVES:
        return None
    order = np.sort(per_move)
    weights = np.random.default_rng(0).dirichlet(np.ones(len(order)), size=RESAMPLES)  # (B, moves), sorted moves
    resampled = order[np.argmax(np.cumsum(weights, axis=1) >= 0.5, axis=1)]  # each resample's weighted median
    return GyroUnits(ratio=float(np.median(frame_ratio[use])), confidence=float(np.mean(resampled < DEGREES_BELOW)),
                     frames=int(np.count_nonzero(use)), moves=len(order))


NOISIEST_GYRO_DENSITY = 0.1 * DEGREE
"""rad/s/sqrt(Hz): the noisiest MEMS gyros' rate noise density (datasheets give 0.003-0.1 deg/s/sqrt(Hz)). At a
sample rate r its noise per sample is at most this times sqrt(r / 2); a gyro in deg/s reads 57 times its own."""


def describe_gyro_noise(noise) -> str | None:
    """A sentence where the gyro's white noise at rest (the samples' own, of an
    :class:`~nrmpc_ros.frontend.zupt.ImuNoise`: not what the covariances claim) is above the noisiest MEMS gyro's
    at the IMU's rate (:data:`NOISIEST_GYRO_DENSITY`), else None: the hint left where the moves cannot measure the
    unit (cameras that record only the holds, snapshots)."""
    rate_hz = 1.0 / noise.period_s if noise.period_s > 0 else math.nan
    sigma = noise.white[1] if noise.white is not None else noise.gyro_sigma
    limit = NOISIEST_GYRO_DENSITY * math.sqrt(rate_hz / 2.0)
    if not (math.isfinite(limit) and math.isfinite(sigma)) or sigma <= limit:
        return None
    return (f"the gyro's noise at rest, {sigma:.3g} per sample, is {sigma / limit:.3g} times the noisiest MEMS "
            f"gyro's at {rate_hz:.0f} Hz ({limit:.2g} rad/s): is it in deg/s? sensor_msgs/Imu carries rad/s (REP "
            f"103): --imu-gyro-scale {DEGREE:.7f} (the node: input.imu_gyro_scale), or fix the driver")


def describe_gyro_units(units: GyroUnits) -> str:
    """The measurement as the replay summary and the node's warning say it."""
    verdict = "the gyro reads deg/s" if units.in_degrees else "the gyro reads rad/s"
    return (f"{verdict}: the images move {units.ratio:.3g} times as fast as it says over {units.frames} moving "
            f"frames in {units.moves} moves (about 1 in rad/s, {DEGREE:.4f} in deg/s; {100 * units.confidence:.0f} % "
            "of resamples of the moves read deg/s); sensor_msgs/Imu carries rad/s (REP 103)")


__all__ = ["DEGREE", "DEGREES_BELOW", "GyroUnits", "NOISIEST_GYRO_DENSITY", "describe_gyro_noise",
           "describe_gyro_units", "gyro_units"]
