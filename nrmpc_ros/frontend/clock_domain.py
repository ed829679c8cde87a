"""An IMU stamped by another clock than the cameras': seen from when its messages arrive, and moved onto theirs.

A driver may stamp with its device's own counter (seconds since power-on), a
GPS or PTP time the host does not follow, or a clock set to another time
zone. Its stamps are then minutes to decades off the cameras', where no frame
set finds its IMU samples: every hold lacks its IMU gravity and its
stillness test, silently. The measured searches do not reach that far (the
far search and the rotations between holds look up to
:data:`~nrmpc_ros.frontend.imu_clock_holds.MAX_OFFSET_S` either way).

Every message also has a time it arrived: the node's clock, in ``nrmpc
replay`` the recording time. Its arrival minus its stamp is its delivery
delay plus its stamping clock's offset from the arrival clock. Delivery
delays are milliseconds to a few seconds (a driver's buffer, a busy host);
an input whose arrival lag differs from the cameras' by more than
:data:`FAR_CLOCK_S` is on another clock. The smallest lag of a stream over
its recent messages is its clock's offset plus its quickest delivery, so
bursts and queues do not move it.

The cameras' lags are those of the frames the stamp checks accepted (a
corrupt camera stamp never counts). The IMU's stamps are moved by the
difference of the two smallest lags: onto the arrival clock where the
cameras stamp with it (their lag is a delivery delay, within
:data:`FAR_CLOCK_S`; the IMU's samples then sit where they arrived, late by
the quickest delivery among the samples that decided, a millisecond on a
serial or USB link), else onto the cameras' own clock (their smallest lag
taken for the IMU's: late by the difference of their quickest deliveries).
What remains is a lag the near search reads (docs/PIPELINE.md, "IMU gravity
that the images refute"). A rebase needs ``confirm`` IMU samples in a row
beyond :data:`FAR_CLOCK_S` and within it of each other: one corrupt stamp
is the stamp checks' to drop, not a clock. docs/INPUTS.md, "Topics of a
bag".
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from .imu_clock_holds import MAX_OFFSET_S

FAR_CLOCK_S = MAX_OFFSET_S
"""s: arrival lags of the IMU and the cameras further apart than this are two clocks: beyond any delivery delay the
input policy waits for (``imu_max_lag_s`` up to its bound) and beyond the offsets the measured searches reach."""

CAMERA_LAGS_KEPT = 64
"""The cameras' latest arrival lags whose smallest is theirs: a few seconds of frames, so a camera's clock that
changes (a driver restarted) is seen anew."""


@dataclass(frozen=True)
class ClockRebase:
    """The IMU moved onto the cameras' clock: ``offset_s`` added to its stamps; ``imu_lag_s`` and ``camera_lag_s``
    the smallest arrival lags (arrival - stamp, s) it came from; ``onto_arrival``: the cameras stamp with the
    arrival clock, so the IMU's samples now sit where they arrived."""

    offset_s: float
    imu_lag_s: float
    camera_lag_s: float
    onto_arrival: bool

    def describe(self, imu_name: str) -> str:
        """The sentence the replay summary and the node's log show."""
        onto = ("the arrival clock the cameras stamp with" if self.onto_arrival
                else "the cameras' clock, by their arrival times")
        return (f"{imu_name}: stamps {abs(self.offset_s):.3f} s {'behind' if self.offset_s > 0 else 'ahead of'} the "
                f"cameras' (another clock: the IMU's own counter, GPS time, a time zone?); moved onto {onto} "
                f"({self.offset_s:+.3f} s added to its stamps; late by its quickest delivery, which the moves "
                f"measure; input.imu_clock_offset_s or --imu-clock-offset sets it from the start)")


class ClockDomains:
    """The arrival lags of the cameras and the IMU; :meth:`camera` and :meth:`imu` take each message's stamp and
    arrival time and return a :class:`ClockRebase` once the IMU is confirmed on another clock (module docstring)."""

    def __init__(self, confirm: int):
        self.confirm = int(confirm)
        self._camera: deque = deque(maxlen=CAMERA_LAGS_KEPT)
        self._imu: deque = deque(maxlen=self.confirm)

    def reset(self) -> None:
        """Forget the lags (the stamps start a new epoch: a jump of the clock, the IMU moved)."""
        self._camera.clear()
        self._imu.clear()

    def camera(self, stamp: float, now: float | None) -> ClockRebase | None:
        if now is None or not math.isfinite(stamp):
            return None
        self._camera.append(now - stamp)
        return self._decide()

    def imu(self, stamps, now: float | None) -> ClockRebase | None:
        """``stamps``: one IMU stamp or an array of those that arrived at ``now`` (s)."""
        if now is None:
            return None
        lags = now - np.asarray(stamps, dtype=float).reshape(-1)[-self.confirm:]
        self._imu.extend(lags[np.isfinite(lags)].tolist())
        return self._decide()

    def _decide(self) -> ClockRebase | None:
        if len(self._imu) < self.confirm or not self._camera:
            return None
        imu_lag, camera_lag = float(min(self._imu)), float(min(self._camera))
        if abs(imu_lag - camera_lag) <= FAR_CLOCK_S or max(self._imu) - imu_lag > FAR_CLOCK_S:
            return None
        onto_arrival = abs(camera_lag) <= FAR_CLOCK_S
        offset = imu_lag - (0.0 if onto_arrival else camera_lag)
        self.reset()
        return ClockRebase(offset, imu_lag, camera_lag, onto_arrival)


__all__ = ["CAMERA_LAGS_KEPT", "FAR_CLOCK_S", "ClockDomains", "ClockRebase"]
