"""Messages taken from several inputs at once, handed over in the order of their stamps.

The node takes every message waiting in its camera and IMU subscriptions
together (docs/ARCHITECTURE.md, "The node's two workers"). Handed over input
by input, a stall of the process (the machine busy, the estimator holding the
interpreter) would come out as one input running ahead of the others by the
length of the stall: IMU samples half a second newer than every camera's
last frame make the feeder judge the cameras stopped and let the IMU go on
without them, and the frames taken a moment later meet the pipeline after
newer samples. Merged by stamp, the feeder sees the messages of a stall as
the recording orders them. Each input keeps its own arrival order: a jump of
its clock stays where it came.
"""

from __future__ import annotations

import heapq
from typing import NamedTuple

from .feeder import IMU


class Run(NamedTuple):
    """Consecutive messages of one input, handed over together: ``stream`` a camera index or :data:`IMU`,
    messages ``start`` to ``stop`` (exclusive) of what was taken from it, in arrival order."""

    stream: int | str
    start: int
    stop: int


def stamp_order(image_stamps: list, imu_stamps) -> list[Run]:
    """The hand-over order of messages taken together: ``image_stamps[i]`` the stamps (s) of camera ``i``'s
    images as taken, ``imu_stamps`` those of the IMU's samples. Merged by stamp, each input in its arrival
    order; an IMU sample goes before an image of the same stamp; consecutive IMU samples form one run."""
    streams = [[(float(t), 0, IMU, k) for k, t in enumerate(imu_stamps)]]
    streams += [[(float(t), 1, i, k) for k, t in enumerate(stamps)] for i, stamps in enumerate(image_stamps)]
    runs: list[Run] = []
    for _, _, stream, k in heapq.merge(*streams, key=lambda e: e[:2]):
        if stream == IMU and runs and runs[-1].stream == IMU and runs[-1].stop == k:
            runs[-1] = runs[-1]._replace(stop=k + 1)
        else:
            runs.append(Run(stream, k, k + 1))
    return runs


__all__ = ["Run", "stamp_order"]
