"""Whether the IMU's gyro reads degrees per second, from the moves the images show.

sensor_msgs/Imu carries rad/s (REP 103). A driver that passes a chip's deg/s
on makes every rate 57.3 times its size: the stillness test reads the gyro's
bias as a steady turn and its noise as motion, the gyro's turns throw the
tracks' predictions off, and on a rendered recording of 9 holds none was
estimated. The covariances, where the driver fills them in the same unit, do
not tell: the noise they claim is as large as the noise the samples show.

The images measure the turn's size. Over the frames the images show moving,
each camera's image rate is summed against the rate the body's turn (the
gyro integrated) predicts across its optical axis
(:meth:`~nrmpc_ros.frontend.imu_clock.ImuClockEstimator.moving_rates`). Their
ratio is about 1 where the gyro reads rad/s (1.3-3.1 on rendered recordings of
2-6 cameras on 1.5-8 Hz bars: the parallax of translation and the bars' swing
add motion the body's turn does not have; the frames are those both show
moving, not the ringing after a stop) and 1/57.3 of that where it reads deg/s
(0.04); the gyro reads deg/s where the ratio is nearer 1/57.3 than 1 in log
(below their geometric mean, 0.13) in :data:`~nrmpc_ros.frontend.imu_clock.CONFIDENCE` of
Bayesian-bootstrap resamples of the moves. A clock seconds off cannot fake it:
the frames are chosen by the images' motion, and the gyro, read at the wrong
moments, predicts less motion there, not more.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .imu_clock import CONFIDENCE, RESAMPLES

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
    on camera (or without a rig file's IMU mount)."""
    got = imu_clock.moving_rates()
    if got is None:
        return None
    images, gyro, move, moves = got
    use = np.isfinite(images) & np.isfinite(gyro)
    per_move = np.zeros((2, moves))
    rows = np.broadcast_to(move[:, None], images.shape)[use]
    np.add.at(per_move[0], rows, images[use])
    np.add.at(per_move[1], rows, gyro[use])
    if not per_move[1].sum() > 0:
        return None
    weights = np.random.default_rng(0).dirichlet(np.ones(moves), size=RESAMPLES)  # (B, moves)
    resampled = (weights @ per_move[0]) / np.maximum(weights @ per_move[1], 1e-300)
    return GyroUnits(ratio=float(per_move[0].sum() / per_move[1].sum()),
                     confidence=float(np.mean(resampled < DEGREES_BELOW)), frames=int(np.count_nonzero(use.any(1))),
                     moves=int(moves))


def describe_gyro_units(units: GyroUnits) -> str:
    """The measurement as the replay summary and the node's warning say it."""
    verdict = "the gyro reads deg/s" if units.in_degrees else "the gyro reads rad/s"
    return (f"{verdict}: the images move {units.ratio:.3g} times as fast as it says over {units.frames} moving "
            f"frames in {units.moves} moves (about 1 in rad/s, {DEGREE:.4f} in deg/s; {100 * units.confidence:.0f} % "
            "of resamples of the moves read deg/s); sensor_msgs/Imu carries rad/s (REP 103)")


__all__ = ["DEGREE", "DEGREES_BELOW", "GyroUnits", "describe_gyro_units", "gyro_units"]
