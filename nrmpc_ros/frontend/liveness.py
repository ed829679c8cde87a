"""Which cameras publish: "stopped publishing" and "publishing again", and the end of the input.

Times are arrival times on one monotonic clock (never ROS time). Each camera
is given two timeouts, ``timeout_s`` or longer for a driver or link that
delivers in bursts (measured over the last ``DELIVERY_WINDOW_S``,
:mod:`~nrmpc_ros.frontend.delivery`):

- its **stop timeout**, against the other cameras: ``BURST_MARGIN`` times
  how far its frames have come behind the other cameras' newest stamps (a
  frame period for cameras that deliver alike, the burst interval for one
  that buffers while the others do not). A stall of the whole process, or
  of a publisher of every camera, delays every camera alike and leaves it
  as it was: a camera that stops on a busy machine is still found;
- its **end timeout**, against the clock: ``BURST_MARGIN`` times the
  spread of its delays (arrival minus the stamps of the frames the feeder
  accepted) about the rate the stamps advance at against the arrivals (a bag
  played at another speed: :meth:`~.delivery.DelaySpread.spread_about_rate`):
  a few milliseconds for a steady camera, the burst interval for cameras that
  all buffer together, and, on a busy machine, its stalls.

With those timeouts:

- a camera is **stopped** when it has been silent for its stop timeout while
  another camera went on publishing for as long after its last image
  (a camera that fails while the others run);
- a camera that never sent an image is **missing** once another camera has
  been publishing for ``timeout_s`` (wrong topic or transport?); until then
  the first images may simply still be on their way;
- when every camera has been silent for its end timeout the **input ended**
  (a bag ended, a driver stopped): not a fault, and nothing is "stopped";
- a stopped or missing camera that sends an image again is **publishing
  again**; so is the input after it ended.

:meth:`CameraWatch.seen` and :meth:`CameraWatch.check` return the events as
(level, message) pairs to log; each change of state is reported once.

With ``check_period_s`` (the period of the timer that calls
:meth:`CameraWatch.check`), a check that comes more than 1.5 periods after
the previous one came late: the process itself was stalled (a busy
machine), and the images that arrived meanwhile wait in its subscriptions'
queues, unseen. Such a check judges only what the stall cannot have hidden:
a camera already silent for its stop timeout at the previous check, while
another camera published for as long after its last image. No end and no
missing camera is judged late; the next check on time judges the rest. On a
machine busy for good, where every check comes late, a camera that stops is
still found.
"""

from __future__ import annotations

import math

from .delivery import BURST_MARGIN, DELIVERY_WINDOW_S, DelaySpread, StampLags

STALL_PERIODS = 1.5  # a check this many timer periods after the previous one came late: the process was stalled


class CameraWatch:
    """State of every camera's input (see the module docstring)."""

    def __init__(self, names: list, timeout_s: float, check_period_s: float | None = None):
        self.names = list(names)
        self.timeout_s = float(timeout_s)
        self.late_check_s = math.inf if check_period_s is None else STALL_PERIODS * float(check_period_s)
        self.last_check: float | None = None  # when check() last ran
        self.stalls = 0  # checks that came late: they judged only silences older than the previous check
        self.last = [None] * len(self.names)  # arrival of the newest image
        self.first_any: float | None = None  # arrival of the first image of any camera
        self.state = ["waiting"] * len(self.names)  # waiting | live | stopped | missing
        self.ended: float | None = None  # when the input ended (arrival of its last image)
        self.ends = 0
        self._epoch = 0
        self._new_timeline()

    def _new_timeline(self) -> None:
        """Delays and lags start afresh (stamps of another timeline)."""
        self._delays = [DelaySpread(DELIVERY_WINDOW_S) for _ in self.names]  # arrival minus stamp
        self._lags = StampLags(len(self.names), DELIVERY_WINDOW_S)
        self._newest = [-math.inf] * len(self.names)  # stamp of the newest accepted frame

    def stop_timeout(self, i: int) -> float:
        """Camera ``i``'s stop timeout (s): ``timeout_s``, or longer for a camera whose frames come behind the
        other cameras' (module docstring)."""
        return max(self.timeout_s, BURST_MARGIN * self._lags.largest(i, self._newest))

    def end_timeout(self, i: int, now: float) -> float:
        """Camera ``i``'s end timeout (s): ``timeout_s``, or longer for a camera whose delays spread (module
        docstring)."""
        return max(self.timeout_s, BURST_MARGIN * self._delays[i].spread_about_rate(now))

    def seen(self, i: int, now: float, stamp: float | None = None, epoch: int = 0) -> list:
        """Camera ``i`` sent an image at ``now``; ``stamp``: its stamp (s) when the input accepted it (its
        delay measures how the camera delivers), else None; ``epoch``: the input's count of changes in how it
        reads the cameras' stamps (:attr:`~nrmpc_ros.frontend.feeder.Feeder.timeline`: a jump back in time, a
        camera moved onto the others' clock or stamped by its arrival): the stamps of another epoch are on
        another timeline, and the delays start afresh."""
        if epoch != self._epoch:
            self._epoch = epoch
            self._new_timeline()
        if stamp is not None:
            self._delays[i].add(now, stamp)
            self._lags.delivered(i, stamp, self._newest)
            self._newest[i] = max(self._newest[i], stamp)
        events = []
        if self.ended is not None:
            events.append(("info", f"the input resumed after {now - self.ended:.1f} s of silence: "
                                   f"{self.names[i]} is publishing again"))
            self.ended = None
        elif self.state[i] == "stopped":
            events.append(("info", f"camera {self.names[i]} is publishing again (silent for "
                                   f"{now - self.last[i]:.1f} s)"))
        elif self.state[i] == "missing":
            events.append(("info", f"camera {self.names[i]} is publishing (its first image, "
                                   f"{now - self.first_any:.1f} s after the other cameras' first)"))
        self.state[i] = "live"
        self.last[i] = now
        if self.first_any is None:
            self.first_any = now
        return events

    def check(self, now: float) -> list:
        """Events of the states that changed by ``now``; ("ended", ...) when the input ended."""
        previous, self.last_check = self.last_check, now
        late = previous is not None and now - previous > self.late_check_s
        if late:
            self.stalls += 1
        if self.first_any is None or self.ended is not None:
            return []
        if late:
            return self._stops(previous)
        newest = max(t for t in self.last if t is not None)
        ends = [self.end_timeout(i, now) for i in range(len(self.names))]
        if all(t is None or now - t > limit for t, limit in zip(self.last, ends)):
            self.ended = newest
            self.ends += 1
            return [("ended", f"no images for {now - newest:.1f} s on any camera: the input ended (the open hold "
                              "is estimated now)")]
        events = []
        for i, name in enumerate(self.names):
            if self.last[i] is None and self.state[i] != "missing" and newest - self.first_any > self.timeout_s:
                self.state[i] = "missing"
                events.append(("warn", f"camera {name}: no image yet while the other cameras publish for "
                                       f"{newest - self.first_any:.1f} s (wrong topic or transport?)"))
        return events + self._stops(now)

    def _stops(self, at: float) -> list:
        """Events of the live cameras silent at ``at`` for their stop timeouts while another camera published
        for as long after their last images."""
        newest = max(t for t in self.last if t is not None)
        events = []
        for i, name in enumerate(self.names):
            t, limit = self.last[i], self.stop_timeout(i)
            if t is not None and self.state[i] == "live" and at - t > limit and newest - t > limit:
                self.state[i] = "stopped"
                events.append(("warn", f"camera {name} stopped publishing (nothing for {at - t:.1f} s while the "
                                       "other cameras publish)"))
        return events

    def is_silent(self, i: int) -> bool:
        """Whether camera ``i`` is stopped or missing, or the input ended."""
        return self.ended is not None or self.state[i] in ("stopped", "missing")

    def silent(self) -> list:
        """Names of the cameras stopped or missing now."""
        return [n for n, s in zip(self.names, self.state) if s in ("stopped", "missing")]

    def age(self, i: int, now: float) -> float:
        """Seconds since camera i's newest image (inf before the first)."""
        return math.inf if self.last[i] is None else now - self.last[i]


__all__ = ["CameraWatch"]
