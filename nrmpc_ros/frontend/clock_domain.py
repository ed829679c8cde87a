"""Inputs stamped by another clock than the others': seen from when their messages arrive, and moved onto theirs.

A driver may stamp with its device's own counter (seconds since power-on: an
IMU's microcontroller, a camera's hardware timestamps), a GPS or PTP time the
host does not follow, or a clock set to another time zone. Its stamps are
then minutes to decades off the other inputs': a camera's frames never group
with the others' (that camera is lost), an IMU's samples are found by no
frame set (every hold lacks its IMU gravity and its stillness test), or they
are dropped as stamps in the future; silently, or said as something else.
The measured IMU clock searches do not reach that far (the far search and
the rotations between holds look up to
:data:`~nrmpc_ros.frontend.imu_clock_holds.MAX_OFFSET_S` either way).

Every message also has a time it arrived: the node's clock, in ``nrmpc
replay`` the recording time. Its arrival minus its stamp (its lag) is its
delivery delay plus its stamping clock's offset from the arrival clock.
Delivery delays are milliseconds to a few seconds (a driver's buffer, a busy
host); inputs whose lags differ by more than :data:`FAR_CLOCK_S` are on two
clocks. An input's lag is the smallest of its latest ``confirm`` messages,
taken once those agree within :data:`FAR_CLOCK_S` (one corrupt stamp is the
stamp checks' to drop, not a clock).

The clock the others are moved onto: the arrival clock, where an input
stamps with it (its lag within :data:`FAR_CLOCK_S`: a driver on the host's
clock; an input moved onto it then sits where it arrived, late by its
quickest delivery among the messages that decided, a millisecond for an IMU
on a serial or USB link, tens for a camera); else the first camera's (a bag
played into the node without its clock: every input days behind the
arrival clock), the others late by the difference of their quickest
deliveries. What remains of an IMU's offset is the near search's to measure
(docs/PIPELINE.md, "IMU gravity that the images refute"). docs/INPUTS.md,
"Topics of a bag".
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .imu_clock_holds import MAX_OFFSET_S

FAR_CLOCK_S = MAX_OFFSET_S
"""s: arrival lags further apart than this are two clocks: beyond any delivery delay the input policy waits for
(``imu_max_lag_s`` up to its bound) and beyond the offsets the measured IMU clock searches reach."""


@dataclass(frozen=True)
class ClockRebase:
    """Input ``stream`` (a camera index, or the IMU's stream id) moved onto the others' clock: ``offset_s`` added
    to its stamps; ``onto_arrival``: onto the arrival clock another input stamps with (its samples now sit where
    they arrived), else onto the first camera's."""

    stream: object
    offset_s: float
    onto_arrival: bool

    def describe(self, name: str) -> str:
        """The sentence the replay summary and the node's log show."""
        onto = ("the arrival clock the other inputs stamp with" if self.onto_arrival
                else "the first camera's clock, by the arrival times")
        return (f"{name}: stamps {abs(self.offset_s):.3f} s {'behind' if self.offset_s > 0 else 'ahead of'} the "
                f"others' (another clock: the device's own counter, GPS time, a time zone?); moved onto {onto} "
                f"({self.offset_s:+.3f} s added to its stamps; late by its quickest delivery)")


class ClockDomains:
    """The arrival lags of the inputs ``streams`` (camera indices first, in rig order; the IMU's id last if
    any); :meth:`seen` takes each message's stamps and arrival time and returns the inputs to move onto the
    others' clock (module docstring)."""

    def __init__(self, streams: list, confirm: int):
        self.streams = list(streams)
        self.confirm = int(confirm)
        self._lags = {s: deque(maxlen=self.confirm) for s in self.streams}

    def reset(self, streams=None) -> None:
        """Forget the lags of ``streams`` (default: all): their stamps start anew (a jump of the clock, moved)."""
        for s in self.streams if streams is None else streams:
            self._lags[s].clear()

    def seen(self, stream, stamps, now: float | None) -> list:
        """``stamps``: one stamp or an array of those that arrived at ``now`` (s). Returns the
        :class:`ClockRebase` of every input found on another clock, each forgotten as it is returned."""
        if now is None:
            return []
        lags = now - np.asarray(stamps, dtype=float).reshape(-1)[-self.confirm:]
        self._lags[stream].extend(lags[np.isfinite(lags)].tolist())
        return self._decide()

    def lag(self, stream) -> float | None:
        """The input's lag (s): the smallest of its latest messages once they agree, else None."""
        q = self._lags[stream]
        if len(q) < self.confirm or max(q) - min(q) > FAR_CLOCK_S:
            return None
        return float(min(q))

    def apart(self, stream) -> bool:
        """Whether the input's latest lag is more than :data:`FAR_CLOCK_S` off another input's latest: perhaps on
        another clock (undecided while :meth:`lag` is None)."""
        q = self._lags[stream]
        if not q:
            return False
        return any(abs(q[-1] - o[-1]) > FAR_CLOCK_S for s, o in self._lags.items() if s != stream and o)

    def _decide(self) -> list:
        known = {s: lag for s in self.streams if (lag := self.lag(s)) is not None}
        if len(known) < 2:
            return []
        if any(abs(lag) <= FAR_CLOCK_S for lag in known.values()):
            reference, onto_arrival = 0.0, True
        elif any(self._lags[s] and s not in known for s in self.streams):
            return []  # an input that spoke may still show the arrival clock: wait for it
        else:
            first = next(s for s in self.streams if s in known)  # the first camera with a lag (or the IMU alone)
            reference, onto_arrival = known[first], False
        out = [ClockRebase(s, lag - reference, onto_arrival) for s, lag in known.items()
               if abs(lag - reference) > FAR_CLOCK_S]
        self.reset([r.stream for r in out])
        return out


FROZEN_SPAN_S = 0.1
"""s: a stamp that stays the same over messages arriving this far apart is frozen (a driver that leaves
``header.stamp`` unset, or sets it once): samples a host read at once share a stamp but arrive together."""


class FrozenStamps:
    """Inputs whose stamps do not advance while their messages keep arriving: ``confirm`` messages in a row with
    one stamp, arriving over more than :data:`FROZEN_SPAN_S`. Their messages are then stamped by when they
    arrive (the feeder's policy; docs/INPUTS.md, "Topics of a bag")."""

    def __init__(self, confirm: int):
        self.confirm = int(confirm)
        self._runs: dict = {}  # stream -> (stamp, first arrival, messages)

    def seen(self, stream, stamps, now: float | None) -> bool:
        """``stamps``: one stamp or an array of those that arrived at ``now`` (s). Whether the input's stamps are
        frozen (its run of one stamp is long enough)."""
        if now is None:
            return False
        for t in np.asarray(stamps, dtype=float).reshape(-1).tolist():
            stamp, first, n = self._runs.get(stream, (None, now, 0))
            self._runs[stream] = (stamp, first, n + 1) if t == stamp else (t, now, 1)
        stamp, first, n = self._runs[stream]
        return n >= self.confirm and now - first > FROZEN_SPAN_S

    def repeating(self, stream) -> bool:
        """Whether the input's latest stamp repeats the one before (frozen, or samples read at once): its lags
        tell no clock."""
        return self._runs.get(stream, (None, 0.0, 0))[2] > 1


__all__ = ["FAR_CLOCK_S", "FROZEN_SPAN_S", "ClockDomains", "ClockRebase", "FrozenStamps"]
