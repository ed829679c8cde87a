"""Bad clocks: stamps far in the future are dropped, jumps back in time are confirmed and reported once.

The policy (README, "The ROS 2 node", Time), per input stream (a camera, the IMU):

- **Future.** A stamp more than ``max_future_s`` ahead of the present is
  dropped ("stamp in the future"): the node's clock, or the recording time
  of the message in ``nrmpc replay``. A corrupt stamp such as one in 2038 so
  never becomes the new present. Without a clock (``now`` None) there is no
  such test.
- **Back.** A stamp more than ``jump_back_s`` behind the newest stamp of its
  own stream is a candidate jump back (a bag played again, a clock set
  back). It is held, and adopted as a jump back when a second stream shows
  the same jump, or ``confirm`` messages of its stream do while no other
  stream talks of the old time. A held stamp whose stream goes on at the old
  time was a glitch: it is dropped ("stamp far in the past"). A stream that
  fell behind the others only rejoins them: a candidate within
  ``jump_back_s`` of the other streams' newest stamp is taken as it is.
- **After a jump back** every stream starts afresh; a message that still
  arrives from before the jump (near its stream's old time, ahead of the new
  time) is dropped ("from before a time jump back") until its stream sends
  the new time.

The caller resets what depends on time (synchronizer, IMU buffer, holds)
when :meth:`StampGuard.check` returns a :class:`Jump`, then handles the
messages the jump holds, oldest first.

When a held stamp is confirmed as a jump is one policy, :class:`JumpPolicy`,
shared with the frame grouping (:class:`~nrmpc_ros.frontend.sync.StampSynchronizer`
holds smaller jumps, in frame periods, the same way); the feeder builds it
from its settings (``FeederConfig.jump_policy``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .drops import Drop


@dataclass
class HeldJump:
    """Messages held apart because their stamps jump far from their streams' time, until the jump is confirmed
    or dropped; each message is a tuple whose first item is its stream."""

    messages: list
    others_talked: bool = False  # another stream sent a stamp consistent with the old time meanwhile

    @property
    def streams(self) -> set:
        return {m[0] for m in self.messages}

    def count(self, stream) -> int:
        """Messages of ``stream`` held."""
        return sum(m[0] == stream for m in self.messages)


@dataclass(frozen=True)
class JumpPolicy:
    """When held stamps are a jump of the clock (module docstring, "Back"): a second stream shows the same jump,
    or ``confirm`` messages of one stream do while no other stream talks of the old time. ``jump_back_s`` is how
    far behind its stream's newest a stamp must be for the stamp guard to hold it (s). These defaults are the
    input settings' (``FeederConfig.jump_back_s``, ``jump_confirm``)."""

    jump_back_s: float = 1.0
    confirm: int = 3

    def confirmed(self, held: HeldJump, stream) -> bool:
        """Whether the messages held, the newest of ``stream``, confirm the jump."""
        return bool(held.streams - {stream}) or (held.count(stream) >= self.confirm and not held.others_talked)


@dataclass
class Jump:
    """A confirmed jump back in time: ``stream`` went from ``old`` to ``new`` (seconds)."""

    stream: object
    old: float
    new: float
    held: list  # (stream, stamp, payload) of the new time, in arrival order

    def describe(self, name: str) -> str:
        return (f"detected jump back in time: {name} went from stamp {self.old:.3f} s back to {self.new:.3f} s "
                f"({self.old - self.new:.3f} s back)")


@dataclass
class Verdict:
    """What to do with one message: handle it (``accept``), count ``drops`` ((Drop, message) each), and, on a
    ``jump``, reset and handle its held messages instead."""

    accept: bool
    drops: list = field(default_factory=list)
    jump: Jump | None = None


@dataclass
class _Pending(HeldJump):
    """Held messages: (stream, stamp, payload, old newest of the stream) each."""

    @property
    def latest(self) -> float:
        return max(m[1] for m in self.messages)


class StampGuard:
    """The stamp policy of the module docstring; ``jumps`` when held stamps are a jump back, ``max_held`` bounds
    the messages held for a candidate jump."""

    def __init__(self, max_future_s: float = 10.0, jumps: JumpPolicy | None = None, max_held: int = 64):
        self.max_future_s = float(max_future_s)
        self.policy = jumps or JumpPolicy()
        self.jump_back_s = float(self.policy.jump_back_s)
        self.max_held = int(max_held)
        self.jumps = 0
        self._newest: dict = {}  # stream -> newest accepted stamp
        self._before: dict = {}  # stream -> its newest stamp before the last jump back (until it sends the new time)
        self._old_time = -math.inf  # the newest stamp of any stream before the last jump back
        self._pending: _Pending | None = None

    def newest(self, stream=None) -> float:
        """Newest accepted stamp of ``stream`` (of all streams when None); -inf before any."""
        if stream is not None:
            return self._newest.get(stream, -math.inf)
        return max(self._newest.values(), default=-math.inf)

    def check(self, stream, stamp: float, payload=None, now: float | None = None) -> Verdict:
        """The verdict on one message of ``stream`` stamped ``stamp`` (s); ``now`` is the present (s) or None."""
        if not math.isfinite(stamp):
            return Verdict(False, [(Drop.STAMP_NOT_FINITE, f"stamp {stamp!r} is not a finite number")])
        if now is not None and stamp > now + self.max_future_s:
            return Verdict(False, [(Drop.STAMP_IN_FUTURE, f"stamp {stamp:.3f} s is {stamp - now:.3f} s ahead of "
                                                            f"the clock ({now:.3f} s; max_future_s "
                                                            f"{self.max_future_s:g})")])
        own = self._newest.get(stream, -math.inf)
        if stamp < own - self.jump_back_s and not self._rejoins(stream, stamp):
            return self._hold(stream, stamp, payload, own)
        straggler = self._straggler(stream, stamp)
        if straggler:
            return Verdict(False, [straggler])
        drops = []
        if self._pending is not None:
            if stream in self._pending.streams:  # its stream is back at the old time: the held stamps were a glitch
                drops = self._drop_pending()
            else:
                self._pending.others_talked = True
        self._newest[stream] = max(own, stamp) if stamp >= own - self.jump_back_s else stamp
        self._before.pop(stream, None)
        return Verdict(True, drops)

    def accept_run(self, stream, stamps, now: float | None = None) -> bool:
        """Accept ``stamps`` (an array, arrival order) of ``stream`` at once when every one of them, checked in
        turn, would simply be accepted: finite, increasing, newer than its stream, none in the future, no jump
        held. False changes nothing: then check them one by one."""
        if self._pending is not None or not len(stamps) or (stream not in self._newest and stream in self._before):
            return False
        first, last = float(stamps[0]), float(stamps[-1])
        if not (first > self._newest.get(stream, -math.inf) and math.isfinite(last)
                and (now is None or last <= now + self.max_future_s)):
            return False
        if len(stamps) > 1 and not bool((np.diff(stamps) > 0).all()):
            return False
        self._newest[stream] = last
        return True

    def _rejoins(self, stream, stamp: float) -> bool:
        others = [t for s, t in self._newest.items() if s != stream]
        return bool(others) and stamp >= max(others) - self.jump_back_s

    def _straggler(self, stream, stamp: float):
        old = self._before.get(stream)
        if old is None or stream in self._newest:
            return None
        # an input delivered late (a backlog) still has messages up to the old time of the fastest input
        old = max(old, self._old_time)
        new_time = self.newest()
        if stamp > new_time + self.jump_back_s and stamp <= old + self.jump_back_s:
            return (Drop.BEFORE_JUMP_BACK, f"stamp {stamp:.3f} s is from before the jump back in time "
                                            f"(the new time is {new_time:.3f} s)")
        return None

    def _hold(self, stream, stamp: float, payload, own: float) -> Verdict:
        drops = []
        p = self._pending
        if p is not None and abs(stamp - p.latest) > self.jump_back_s:  # another jump: the first was not confirmed
            drops = self._drop_pending()
            p = None
        if p is None:
            p = self._pending = _Pending([])
        p.messages.append((stream, stamp, payload, own))
        if self.policy.confirmed(p, stream):
            return Verdict(False, drops, self._adopt())
        if len(p.messages) > self.max_held:
            drops.append(self._dropped(p.messages.pop(0)))
        return Verdict(False, drops)

    @staticmethod
    def _dropped(m) -> tuple:
        return (Drop.STAMP_FAR_PAST, f"stamp {m[1]:.3f} s is {m[3] - m[1]:.3f} s behind the newest of its "
                                      "input and no other input confirmed a jump back in time")

    def _drop_pending(self) -> list:
        out = [self._dropped(m) for m in self._pending.messages]
        self._pending = None
        return out

    def _adopt(self) -> Jump:
        p, self._pending = self._pending, None
        first = p.messages[0]
        self._before = {**self._newest, **self._before}
        self._old_time = max(self._newest.values(), default=-math.inf)
        self._newest = {}
        for stream, stamp, _, _ in p.messages:
            self._newest[stream] = max(self._newest.get(stream, -math.inf), stamp)
            self._before.pop(stream, None)
        self.jumps += 1
        return Jump(first[0], first[3], first[1], [(s, t, x) for s, t, x, _ in p.messages])

    def reset(self) -> None:
        """Forget every stream's time (a new start)."""
        self._newest, self._before, self._pending, self._old_time = {}, {}, None, -math.inf


__all__ = ["HeldJump", "Jump", "JumpPolicy", "StampGuard", "Verdict"]
