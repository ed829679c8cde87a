"""How an input delivers its messages: the silences it keeps while live, and the spread of its delays.

A camera driver or link that buffers delivers in bursts: seconds of silence, then every frame of them at
once. Neither the feeder's wait for an input nor the liveness check may take such a silence for a stop, so
both measure it (README, "The ROS 2 node"; docs/ARCHITECTURE.md, "The node's two workers"):

- :class:`DeliveryGaps`: the largest advance of another input's stamps between two deliveries of one input,
  or the largest age of a message it delivered (the first burst shows its silence in the age of its oldest
  message, before a second burst shows it as a gap);
- :class:`DelaySpread`: the spread of arrival minus stamp over an input's messages, on any two clocks (their
  offset cancels): a few milliseconds for a steady driver, the burst interval for one that buffers; a stop and a
  restart leave it as it was (fresh frames come as fresh as before); also about the rate the clocks run at
  against each other (a bag played at twice its speed delivers a second of stamps every half second: a trend,
  no burst), which the end of the input is judged by;
- :class:`StampLags`: how far an input's messages came behind the other inputs' newest stamps (one camera
  that buffers, not a stall of the whole process).

Both forget what is older than their window, so a recording that changes its habits is judged by its recent
ones. :data:`BURST_MARGIN` is how much longer than the longest silence seen an input is still waited for.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

DELIVERY_WINDOW_S = 60.0  # how an input delivers is judged over this much of its latest messages: a recording
# that changes its habits is judged by its recent ones
PLAYBACK_RATES = (0.1, 10.0)  # arrival seconds per second of stamps a recording may be played at: a trend of the
# delays inside this range is a playback rate, outside it a burst (a burst's frames arrive together: a rate near 0)
RATE_MIN_MESSAGES = 8  # the trend is fitted over at least this many messages
RATE_REFIT_S = 1.0  # the playback rate is fitted again after this much arrival time (s): a pass over the window's
# messages once a second, not at every message
BURST_MARGIN = 1.5  # an input that delivers in bursts is waited for this many times its longest silence seen:
# its next burst may come somewhat later than the longest one so far


class SlidingMax:
    """The maximum of the values added within ``window_s`` of a time (a monotonic deque: O(1) amortised)."""

    def __init__(self, window_s: float):
        self.window_s = window_s
        self._items: deque = deque()  # (at, value), values decreasing: the candidates for the maximum

    def add(self, at: float, value: float) -> None:
        while self._items and self._items[-1][1] <= value:
            self._items.pop()
        self._items.append((at, value))

    def largest(self, now: float, default: float = 0.0) -> float:
        while self._items and self._items[0][0] < now - self.window_s:
            self._items.popleft()
        return self._items[0][1] if self._items else default


class DeliveryGaps:
    """How long one input has been seen to stay silent while it was live, in another input's stamps, over the
    last ``window_s`` of them (module docstring)."""

    def __init__(self, window_s: float):
        self.first = math.inf  # the other input's newest stamp at the first delivery
        self._last = -math.inf  # the other input's newest stamp at the latest delivery
        self._gaps, self._ages = SlidingMax(window_s), SlidingMax(window_s)

    def delivered(self, other_newest: float, stamp: float) -> None:
        """A message stamped ``stamp`` delivered while the other input's newest stamp was ``other_newest``."""
        if other_newest == -math.inf:
            return
        self.first = min(self.first, other_newest)
        if self._last > -math.inf and other_newest > self._last:
            self._gaps.add(other_newest, other_newest - self._last)
        self._last = max(self._last, other_newest)
        if other_newest > stamp:
            self._ages.add(other_newest, other_newest - stamp)

    @property
    def last(self) -> float:
        """The other input's newest stamp at this input's latest delivery (-inf before one)."""
        return self._last

    def largest(self, other_newest: float) -> float:
        """The longest silence (s) within the window of ``other_newest``: a gap or an age; 0 before any."""
        return max(self._gaps.largest(other_newest), self._ages.largest(other_newest))

    def largest_age(self, other_newest: float) -> float:
        """The largest age (s) of a message delivered within the window: a burst's backlog (a camera that
        stopped and started again delivers fresh messages: a gap, not an age)."""
        return self._ages.largest(other_newest)


class StampLags:
    """How far each input's messages came behind the other inputs' newest stamp (s): the largest over the last
    ``window_s`` of those stamps, per input. A camera whose driver buffers falls behind the others by its burst;
    a stall of the whole process, or of one publisher of every input, delays them all alike and leaves this as
    it was (unlike :class:`DelaySpread`). The caller keeps the newest stamps (it accepts them)."""

    def __init__(self, num_inputs: int, window_s: float):
        self._largest = [SlidingMax(window_s) for _ in range(num_inputs)]

    def delivered(self, i: int, stamp: float, newest: list) -> None:
        """Input ``i`` delivered a message stamped ``stamp`` while ``newest`` were every input's newest stamps."""
        others = max((t for j, t in enumerate(newest) if j != i), default=-math.inf)
        if others > stamp:
            self._largest[i].add(others, others - stamp)

    def largest(self, i: int, newest: list) -> float:
        """Input ``i``'s largest lag (s) within the window of the newest of ``newest``; 0 before any."""
        at = max(newest, default=-math.inf)
        return self._largest[i].largest(at) if at > -math.inf else 0.0


class DelaySpread:
    """The spread (s) of arrival minus stamp over one input's messages of the last ``window_s`` of arrivals, with
    the rate of the stamps against the arrival clock taken out where they run at another (a bag played at
    another speed: arrival = a0 + r stamp, r in :data:`PLAYBACK_RATES`, fitted by least squares). A fit counts
    only where it explains the delays (its residuals spread less than half as much): a driver that buffers
    delivers in a sawtooth that no line explains, and a burst's frames arriving together fit a rate near 0,
    outside the range. The rate is fitted again every :data:`RATE_REFIT_S` of arrivals (a pass over the window's
    messages); between fits both spreads are sliding extremes, O(1) per message, so a burst shows in the spread
    with its first frames."""

    def __init__(self, window_s: float):
        self.window_s = window_s
        self._items: deque = deque()  # (arrival, a, s): arrival and stamp from the first message's
        self._origin: tuple | None = None  # (arrival, stamp) of the first message: differences keep the precision
        self._high, self._low = SlidingMax(window_s), SlidingMax(window_s)  # of a - s and of s - a
        self._rate = 1.0  # the playback rate in use (1: none found)
        self._fit_high, self._fit_low = SlidingMax(window_s), SlidingMax(window_s)  # of a - rate s, and minus
        # (kept only while the rate is not 1)
        self._fitted_at = -math.inf  # the arrival of the last fit

    def add(self, arrival: float, stamp: float) -> None:
        if self._origin is None:
            self._origin = (arrival, stamp)
        a, s = arrival - self._origin[0], stamp - self._origin[1]
        self._items.append((arrival, a, s))
        self._high.add(arrival, a - s)
        self._low.add(arrival, s - a)
        if self._rate != 1.0:  # (at rate 1 the fitted extremes are the raw ones: not kept twice)
            e = a - self._rate * s
            self._fit_high.add(arrival, e)
            self._fit_low.add(arrival, -e)
        if arrival - self._fitted_at >= RATE_REFIT_S:
            self._fit(arrival)

    def _fit(self, now: float) -> None:
        """Fit the rate over the window's messages and rebuild the fitted extremes with it."""
        while self._items and self._items[0][0] < now - self.window_s:
            self._items.popleft()
        self._fitted_at = now
        rate = 1.0
        if len(self._items) >= RATE_MIN_MESSAGES:
            _, a, s = np.array(self._items).T
            sc = s - s.mean()
            ss = float(sc @ sc)
            fitted = float(sc @ (a - a.mean())) / ss if ss > 0 else math.nan
            if PLAYBACK_RATES[0] <= fitted <= PLAYBACK_RATES[1]:
                rate = fitted
        if rate == self._rate:
            return
        self._rate = rate
        self._fit_high, self._fit_low = SlidingMax(self.window_s), SlidingMax(self.window_s)
        if rate == 1.0:
            return
        for arrival, a, s in self._items:
            e = a - rate * s
            self._fit_high.add(arrival, e)
            self._fit_low.add(arrival, -e)

    def spread(self, now: float) -> float:
        """The spread of the delays within the window of ``now``, as they are (a trend included); 0 before a
        message. The frame grouping waits for a missing camera by it: a generous wait costs latency, never a set."""
        return max(0.0, self._high.largest(now) + self._low.largest(now))

    def spread_about_rate(self, now: float) -> float:
        """The spread of the delays within the window of ``now`` about the playback rate fitted (the class
        docstring): the silences of a driver that buffers, not the drift of a recording played faster or slower;
        what the end of the input is judged by. 0 before a message."""
        raw = self.spread(now)
        if self._rate == 1.0:
            return raw
        fitted = max(0.0, self._fit_high.largest(now) + self._fit_low.largest(now))
        return fitted if fitted < 0.5 * raw else raw


__all__ = ["BURST_MARGIN", "DELIVERY_WINDOW_S", "PLAYBACK_RATES", "DelaySpread", "DeliveryGaps", "SlidingMax",
           "StampLags"]
