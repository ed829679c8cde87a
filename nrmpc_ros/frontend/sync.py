"""Approximate-time grouping of per-camera messages by stamp (shared by the replay and the node).

Policy:

- **Sets.** A set holds at most one message per stream (camera). Every stamp
  of a set lies within ``tolerance`` of the set's reference stamp (the median
  of its stamps), and a message joins a set only if it is nearer to the
  set's reference than to the next frames of the set's streams (their median;
  a stream's next frame is its next queued message, else predicted one
  estimated period later): a frame of the next trigger does not fill the gap
  of a dropped frame. Nor does a frame join a set when another camera's
  frame is nearer to it than the set is and cannot join the set too: cameras
  at different rates (15 and 10 Hz) have frames of two instants a third of a
  period apart, and the frames of the later instant stay together. Sets are
  formed from the
  oldest queued message on; among several queued messages of one stream (a
  faster camera) the one nearest the set's reference is taken and the older
  ones are dropped as "unmatched". Stamps are told apart up to a jitter of
  about a quarter period off the trigger (+-8 ms at 30 Hz, +-25 ms at 10 Hz):
  there a trigger's frames may rarely end in two partial sets, but frames of
  two triggers are never mixed. Above it no grouping by stamps is reliable.
- **Tolerance.** Given ``tolerance_s``, it is fixed. Otherwise it follows
  the cameras: each stream's frame period is estimated from its last
  ``period_window`` inter-frame intervals (their median, refined by their mean
  with an interval of k periods -- a dropped frame -- counted k times;
  intervals longer than ``gap_periods`` periods -- pauses between snapshots --
  are left out, and so are intervals shorter than :data:`MIN_FRAME_PERIOD_S`,
  which no camera takes: a burst of stamps microseconds apart from a broken
  driver would otherwise make the period, and the tolerance, zero until the
  window refills) and the tolerance is
  ``period_fraction`` (0.45) of the smallest period, capped by
  ``max_tolerance_s``. Below half a period, a window of +-tolerance holds at
  most one frame of a regular stream. Until a period is known (4 frames of one
  stream) the tolerance is ``initial_tolerance_s`` = 15 ms, 0.45 periods of a
  30 Hz camera. Snapshot streams (one frame per hold, seconds apart) get a
  tolerance of about a second; their synchronised stamps (a few ms apart)
  still group correctly, since the nearest-frame rule decides.
- **Partial sets.** A set missing a stream is emitted, with None for that
  stream, once the missing frame can no longer arrive: the stream has a
  message newer than the set's reference + tolerance, or the streams of the
  set have moved on beyond it by ``wait_periods`` frame periods (a silent or
  unplugged camera) or by the stream's measured backlog, whichever is longer.
  The backlog is :data:`~nrmpc_ros.frontend.delivery.BURST_MARGIN` times the
  larger of how far the stream's own frames have come behind the other
  streams' newest (a camera with a longer steady latency) and the spread of
  arrival minus stamp of any stream (the cameras of a driver or link that
  buffers deliver in bursts, and a burst comes topic by topic: one camera's
  whole second before the next camera's), both over the recent
  :data:`~nrmpc_ros.frontend.delivery.DELIVERY_WINDOW_S`, capped by
  ``max_backlog_s``. The spread needs the arrival times (``add(...,
  arrival=)``); a burst shows its spread with its first frames, so even the
  first burst is waited through. A steady recording's backlog is a few
  milliseconds and changes nothing. Sets with fewer than ``min_streams`` messages are
  dropped ("unmatched"); ``min_streams`` = the number of streams emits
  complete sets only. :meth:`StampSynchronizer.flush` (end of a bag) emits
  what is left, partial sets included.
- **Late and early stamps.** A message not newer than the last message its
  stream contributed is "late". A stamp more than ``jump_periods`` periods
  behind its stream's newest (a bag played again, a clock reset), or more than
  ``jump_periods`` of the largest period ahead of every stream's newest (a
  clock jump, a corrupt stamp such as year 2038), is held apart (once the
  periods are known; before, nothing is a jump). It is adopted
  when another stream's message confirms the new time (or, with no other
  stream talking, ``jumps.confirm`` messages of its own stream do: the stamp guard's policy); else it is
  dropped ("stamp far in the past" / "stamp far in the future") as soon as its
  stream sends a stamp consistent with the old time. Adopting a jump back
  emits the queued sets of the old time (as :meth:`flush` does), clears the
  queues and counts a "time jump back"; a jump ahead counts a "time jump ahead"
  (a pause longer than ``jump_periods`` periods between snapshots counts so
  too; its frames are held until the second camera's frame arrives, not lost).
- **Cost.** Queues are bounded (``queue_size`` per stream, plus, for a
  stream faster than the slowest, what it sends beyond the slowest one's pace
  in ``wait_periods`` + 1 of its periods, plus what it sends in twice the
  largest backlog; the oldest message is dropped as
  "queue overflow"; keep
  ``queue_size`` above ``wait_periods`` + 1 so a silent camera does not
  overflow the others' queues). Every message is
  queued and popped once and each set looks at the queue heads and the
  messages within its window only, so the cost is linear in streams x queue
  depth (times the few streams of a set, for the medians).
"""

from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from dataclasses import dataclass, field
from statistics import median

from ..config import check, option
from ..errors import OptionError
from .delivery import BURST_MARGIN, DELIVERY_WINDOW_S, DelaySpread, StampLags
from .drops import Drop
from .stamps import HeldJump, JumpPolicy

# No camera of a rig takes frames faster than 1 kHz (users' cameras run at 5-60 Hz): a shorter interval between two
# of a stream's stamps is a glitch of its stamps (a burst stamped microseconds apart), not a frame period.
MIN_FRAME_PERIOD_S = 1e-3


@dataclass
class SyncedSet:
    """One message (or None) per stream.

    ``stamp`` is the stamp of the lowest-numbered stream present (stream 0's
    when the set is complete); ``reference`` the median of the set's stamps.
    """

    stamp: float
    stamps: list
    items: list
    reference: float = math.nan
    missing: list = field(default_factory=list)  # indices of the streams without a message

    @property
    def complete(self) -> bool:
        return not self.missing


@dataclass
class SyncConfig:
    """How the frame grouping follows the cameras (module docstring); the input settings' ``grouping`` block."""

    period_fraction: float = option(0.45, "the stamp tolerance derived from the frame rate is this fraction of the "
                                    "smallest camera frame period (below 0.5: a window holds one frame of a "
                                    "regular camera)", lo=0.0, hi=0.5, lo_open=True)
    initial_tolerance_s: float = option(0.015, "the tolerance until a frame period is known (s; 0.45 periods of a "
                                        "30 Hz camera)", lo=0.0, hi=10.0, lo_open=True)
    max_tolerance_s: float = option(math.inf, "cap of the tolerance derived from the frame rate (s); .inf: none",
                                    lo=0.0, lo_open=True)
    min_streams: int = option(1, "cameras a frame set needs (1: partial sets of any size; the number of "
                              "cameras: complete sets only)", lo=1, hi=1000)
    wait_periods: float = option(4.0, "a partial set leaves once the cameras in it moved this many frame periods "
                                 "past it (a silent camera)", lo=0.0, hi=1000.0, lo_open=True)
    max_backlog_s: float = option(5.0, "... or once they moved on by the missing camera's measured backlog "
                                  "(module docstring), at most this long (s): a camera that delivers later is "
                                  "not waited for (the other cameras' frames are held meanwhile)", lo=0.0,
                                  hi=600.0)
    gap_periods: float = option(3.0, "frame intervals longer than this many periods (pauses between snapshots) "
                                "are left out of the period estimate", lo=1.0, hi=1000.0)
    jump_periods: float = option(5.0, "a stamp this many frame periods behind its camera's newest, or ahead of "
                                 "every camera's, is held as a jump of the clock (confirmed as input.jump_confirm "
                                 "says)", lo=1.0, hi=1e6)
    period_window: int = option(30, "inter-frame intervals a camera's frame period is estimated from", lo=3,
                                hi=100000)

    def __post_init__(self):
        check(self, "frame grouping config")


@dataclass
class _Pending(HeldJump):
    """Messages held apart because their stamps jump far from their streams' time: (stream, stamp, item) each."""

    kind: str = "back"  # "back" or "ahead"
    latest: float = math.nan
    threshold: float = 0.0


def _pulled_away(vals: list, h: float, others: list, tol: float) -> bool:
    """Whether the frame stamped ``h`` belongs with another camera's queued frame rather than with the set of
    stamps ``vals``: one of ``others`` (stamps) is nearer to it than the set's median is, and could not join the
    set with it (module docstring, Sets)."""
    gap = abs(h - median(vals))
    for g in others:
        if abs(g - h) < gap:
            trial = vals + [h, g]
            ref = median(trial)
            if max(abs(v - ref) for v in trial) > tol:
                return True
    return False


class StampSynchronizer:
    """Groups messages of ``num_streams`` streams by stamp (see the module docstring for the policy).

    ``dropped`` counts dropped messages by reason (:class:`~nrmpc_ros.frontend.drops.Drop`); :meth:`take_dropped`
    says which they were.

    ``tolerance_s`` None (default): derived from the estimated frame periods;
    a number: fixed (seconds). ``config`` how the tolerance follows the cameras, ``jumps`` when held stamps are
    a jump (the stamp guard's policy). ``names`` label the streams in :meth:`describe`.
    """

    RECENT = 1000  # dropped messages remembered for take_dropped
    MIN_INTERVALS = 3  # a period needs this many intervals: their median outvotes one spanning a dropped frame

    def __init__(self, num_streams: int, tolerance_s: float | None = None, queue_size: int = 10, *,
                 config: SyncConfig | None = None, jumps: JumpPolicy | None = None, names=None):
        cfg = config or SyncConfig()
        if num_streams < 1:
            raise ValueError("num_streams must be >= 1")
        if tolerance_s is not None and not tolerance_s >= 0:
            raise ValueError("tolerance_s must be >= 0 (or None: derived from the frame periods)")
        if queue_size < 1:
            raise ValueError("queue_size must be >= 1")
        if not cfg.period_fraction < 0.5:
            raise OptionError("frame grouping config", "period_fraction", "must be in (0, 0.5)")
        if not 1 <= cfg.min_streams <= num_streams:
            raise OptionError("frame grouping config", "min_streams", f"must be in 1..{num_streams} (the cameras)")
        self.num_streams = int(num_streams)
        self.fixed_tolerance = None if tolerance_s is None else float(tolerance_s)
        self.queue_size = int(queue_size)
        self.max_tolerance_s = cfg.max_tolerance_s
        self.period_fraction = cfg.period_fraction
        self.initial_tolerance_s = cfg.initial_tolerance_s
        self.min_streams = cfg.min_streams
        self.wait_periods = cfg.wait_periods
        self.max_backlog_s = cfg.max_backlog_s
        self.gap_periods = cfg.gap_periods
        self.jump_periods = cfg.jump_periods
        self.policy = jumps or JumpPolicy()
        self.period_window = cfg.period_window
        self.names = list(names) if names is not None else [f"stream {i}" for i in range(self.num_streams)]
        if len(self.names) != self.num_streams:
            raise ValueError(f"{len(self.names)} names for {self.num_streams} streams")
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget every message, period and count."""
        self._intervals = [deque(maxlen=self.period_window) for _ in range(self.num_streams)]
        self._period = [math.nan] * self.num_streams
        self.dropped = Counter()  # Drop -> messages
        self._recent = []  # (stream, stamp, reason) of the latest drops
        self.events = Counter()  # "time jump back" / "time jump ahead" -> count
        self.partial = Counter()  # stream index -> partial sets emitted without it
        self.emitted = 0  # sets emitted
        self.complete = 0  # of which complete
        self.grouped = 0  # messages emitted in sets
        self._restart()

    def _new_delivery(self) -> None:
        """Forget how the streams delivered (a new timeline: the delays of the old one mean nothing there)."""
        self._delays = [DelaySpread(DELIVERY_WINDOW_S) for _ in range(self.num_streams)]  # on the arrival clock
        self._lags = StampLags(self.num_streams, DELIVERY_WINDOW_S)
        self._arrival = -math.inf  # the newest arrival time given

    def _restart(self) -> None:
        """Empty queues and stream times (periods and counts are kept)."""
        self._stamps = [[] for _ in range(self.num_streams)]  # sorted stamps per stream
        self._items = [[] for _ in range(self.num_streams)]
        self._last = [-math.inf] * self.num_streams  # newest stamp that left the queue, per stream
        self._newest = [-math.inf] * self.num_streams  # newest stamp accepted, per stream
        self._pending: _Pending | None = None
        self._new_delivery()

    @property
    def queued(self) -> list:
        return [len(s) for s in self._stamps]

    @property
    def oldest(self) -> float:
        """Stamp of the oldest queued message (inf when the queues are empty): no later set is older."""
        return min((q[0] for q in self._stamps if q), default=math.inf)

    @property
    def periods(self) -> list:
        """Estimated frame period of each stream (s; nan until 3 frames were seen)."""
        return list(self._period)

    @property
    def tolerance(self) -> float:
        """Half-width (s) of the window around a set's reference stamp, in use now."""
        if self.fixed_tolerance is not None:
            return self.fixed_tolerance
        known = [p for p in self._period if p > 0]
        tol = self.period_fraction * min(known) if known else self.initial_tolerance_s
        return min(tol, self.max_tolerance_s)

    def _stream_period(self, i: int) -> float:
        """Stream i's period, else the largest known one, else the start value's period."""
        if self._period[i] > 0:
            return self._period[i]
        known = [p for p in self._period if p > 0]
        return max(known) if known else self.initial_tolerance_s / self.period_fraction

    def _capacity(self, i: int) -> int:
        """Messages stream i may queue: ``queue_size``, plus what it sends beyond the slowest stream's pace while
        a set waits for that stream (``wait_periods`` + 1 of its periods): a 60 Hz camera beside a 5 Hz one
        sends 12 frames before the 5 Hz frame that decides their sets arrives; plus what it sends in twice the
        largest backlog: a missing stream is waited for that long in the stamps of the set's most belated
        stream, which may lag this one by as much."""
        own = self._known_period(i)
        if not own > 0:
            return self.queue_size
        slowest = self._known_period()
        rates = round((self.wait_periods + 1) * (slowest / own - 1.0)) if slowest > own else 0
        return self.queue_size + rates + math.ceil(2.0 * self._backlog_s(range(self.num_streams)) / own)

    def backlog_s(self, i: int) -> float:
        """How far (s, in the other streams' stamps) a frame of stream ``i`` may come behind them: the measured
        backlog of the module docstring (Partial sets); 0 before anything was measured."""
        return self._backlog_s((i,))

    def _backlog_s(self, streams) -> float:
        """The largest backlog of ``streams``: their largest lag and the spread of every stream's delays (shared:
        computed once)."""
        lag = max(self._lags.largest(i, self._newest) for i in streams)
        spread = max(d.spread(self._arrival) for d in self._delays) if self._arrival > -math.inf else 0.0
        return min(BURST_MARGIN * max(lag, spread), self.max_backlog_s)

    def _known_period(self, i: int | None = None) -> float:
        """Stream i's period (i None: the largest of all streams); nan until known."""
        known = [p for p in (self._period if i is None else self._period[i:i + 1]) if p > 0]
        return max(known) if known else math.nan

    # ------------------------------------------------------------------ input
    def add(self, stream: int, stamp: float, item, arrival: float | None = None) -> list:
        """Queue one message; returns the sets (0 or more, oldest first) it completes or makes final.
        ``arrival``: when it arrived (s, any clock, the same for every stream) or None (unknown: the spread of
        delays is not measured, module docstring, Partial sets)."""
        if not 0 <= stream < self.num_streams:
            raise ValueError(f"stream index {stream} out of range (0..{self.num_streams - 1})")
        stamp = float(stamp)
        if not math.isfinite(stamp):
            self._drop(Drop.FRAME_STAMP_NOT_FINITE, stream, stamp)
            return []
        kind, threshold = self._classify(stream, stamp)
        pend = self._pending
        if kind is None:
            if pend is not None and stream in pend.streams:  # its stream is back to the old time: a glitch
                self._drop_pending()
            elif pend is not None:
                pend.others_talked = True
            self._delivered(stream, stamp, arrival)
            return self._accept(stream, stamp, item)
        if pend is not None and (pend.kind != kind or abs(stamp - pend.latest) > pend.threshold):
            self._drop_pending()  # a different jump: the first one was not confirmed
            pend = None
        if pend is None:
            self._pending = pend = _Pending([], kind=kind, latest=stamp, threshold=threshold)
        pend.messages.append((stream, stamp, item))
        pend.latest = max(pend.latest, stamp)
        if self.policy.confirmed(pend, stream):
            return self._adopt()
        if len(pend.messages) > self.queue_size:
            self._count_pending(pend.messages.pop(0))
        return []

    def _delivered(self, i: int, stamp: float, arrival: float | None) -> None:
        """Measure how stream i delivers: how far its message came behind the others' newest stamp, and (given
        the arrival time) its delay."""
        self._lags.delivered(i, stamp, self._newest)
        if arrival is not None and math.isfinite(arrival):
            self._delays[i].add(arrival, stamp)
            self._arrival = max(self._arrival, arrival)

    def _classify(self, i: int, stamp: float):
        """(None, 0) for a stamp consistent with the streams' time, else ("back" | "ahead", threshold)."""
        back = self.jump_periods * self._known_period(i)  # nan (no test) until the stream's period is known
        if stamp < self._newest[i] - back:
            return "back", back
        ahead = self.jump_periods * self._known_period()
        if stamp > max(self._newest) + ahead:
            return "ahead", ahead
        return None, 0.0

    def _count_pending(self, msg) -> None:
        reason = Drop.FRAME_FAR_PAST if self._pending.kind == "back" else Drop.FRAME_FAR_FUTURE
        self._drop(reason, msg[0], msg[1])

    def _drop(self, reason: Drop, stream: int, stamp: float) -> None:
        """Count one dropped message and remember which (see :meth:`take_dropped`)."""
        self.dropped[reason] += 1
        self._recent.append((stream, stamp, reason))
        del self._recent[:-self.RECENT]

    def take_dropped(self) -> list:
        """(stream, stamp, Drop) of the messages dropped since the last call (at most ``RECENT``), oldest first."""
        out, self._recent = self._recent, []
        return out

    def _drop_pending(self) -> None:
        for m in self._pending.messages:
            self._count_pending(m)
        self._pending = None

    def _adopt(self) -> list:
        """The held jump is confirmed: a jump back closes the old time first; then the held messages are queued."""
        pend, self._pending = self._pending, None
        out = []
        if pend.kind == "back":
            out = self._match(final=True)
            self._restart()
            self.events["time jump back"] += 1
        else:
            self._new_delivery()
            self.events["time jump ahead"] += 1
        for stream, stamp, item in pend.messages:
            out += self._accept(stream, stamp, item, jumped=True)
        return out

    def _accept(self, i: int, stamp: float, item, jumped: bool = False) -> list:
        if stamp <= self._last[i]:
            self._drop(Drop.FRAME_LATE, i, stamp)
            return []
        st, it = self._stamps[i], self._items[i]
        k = bisect.bisect_left(st, stamp)
        if k < len(st) and st[k] == stamp:
            self._drop(Drop.FRAME_DUPLICATE, i, stamp)
            return []
        if stamp > self._newest[i]:
            if self._newest[i] > -math.inf and not jumped:
                self._add_interval(i, stamp - self._newest[i])
            self._newest[i] = stamp
        st.insert(k, stamp)
        it.insert(k, item)
        if len(st) > self._capacity(i):
            self._last[i] = st.pop(0)
            it.pop(0)
            self._drop(Drop.FRAME_QUEUE_OVERFLOW, i, self._last[i])
        return self._match(final=False)

    def _add_interval(self, i: int, dt: float) -> None:
        """Record one inter-frame interval; gaps (drops, pauses) longer than gap_periods periods and glitches
        shorter than any camera's frame period are left out."""
        p = self._period[i]
        if dt < MIN_FRAME_PERIOD_S or (p > 0 and dt > self.gap_periods * p):
            return
        iv = self._intervals[i]
        iv.append(dt)
        if len(iv) >= self.MIN_INTERVALS:  # the median, refined by the mean (a dropped frame spans 2 periods)
            m = median(iv)
            self._period[i] = sum(iv) / sum(max(1, round(d / m)) for d in iv)

    # ------------------------------------------------------------------ grouping
    def flush(self) -> list:
        """Emit every queued message as sets (partial ones too), e.g. at the end of a bag; held jumps are dropped."""
        if self._pending is not None:
            self._drop_pending()
        return self._match(final=True)

    def _next_stamp(self, i: int, k: int) -> float:
        """Stamp of stream i's frame after its queued message k: queued, else predicted one period later
        (the start value's period while no period is known: splitting a set is safer than mixing two)."""
        q = self._stamps[i]
        return q[k + 1] if k + 1 < len(q) else q[k] + self._stream_period(i)

    def _candidate_set(self, tol: float):
        """(stream -> queue index of the set grown from the oldest queued message, streams whose head belongs
        to a later set of a member stream)."""
        heads = sorted((q[0], i) for i, q in enumerate(self._stamps) if q)
        t0, a = heads[0]
        members, vals, claimed = {a: 0}, [t0], set()
        for h, j in heads[1:]:
            if h > t0 + 2 * tol:
                break
            trial = vals + [h]
            ref = median(trial)
            if max(abs(v - ref) for v in trial) > tol:
                continue
            nxt = median(self._next_stamp(i, k) for i, k in members.items())
            others = [g for g, i in heads[1:] if i != j and i not in members]
            if h - median(vals) >= nxt - h or _pulled_away(vals, h, others, tol):
                claimed.add(j)  # nearer the next frames of the set's streams, or a later frame: a later set
                continue
            members[j] = 0
            vals = trial
        ref = median(vals)
        for i in members:  # a faster stream: its queued message nearest the set's reference
            q, k = self._stamps[i], 0
            while k + 1 < len(q) and abs(q[k + 1] - ref) < abs(q[k] - ref) and abs(q[k + 1] - ref) <= tol:
                k += 1
            members[i] = k
        return members, claimed

    def _match(self, final: bool) -> list:
        out = []
        while any(self._stamps):
            tol = self.tolerance
            members, claimed = self._candidate_set(tol)
            ref = median(self._stamps[i][k] for i, k in members.items())
            missing = [i for i in range(self.num_streams) if i not in members]
            if missing and not final:
                moved_on = min(self._newest[i] for i in members)
                if not all(i in claimed or self._newest[i] > ref + tol or moved_on > ref + tol + max(
                        self.wait_periods * self._stream_period(i), self.backlog_s(i)) for i in missing):
                    break  # a missing frame may still arrive
            out += self._emit(members, ref, missing)
        return out

    def _emit(self, members: dict, ref: float, missing: list) -> list:
        picked = {}
        for i, k in members.items():
            st, it = self._stamps[i], self._items[i]
            for t in st[:k]:
                self._drop(Drop.FRAME_UNMATCHED, i, t)
            picked[i] = (st[k], it[k])
            self._last[i] = st[k]
            del st[:k + 1], it[:k + 1]
        if len(picked) < self.min_streams:
            for i, (t, _) in picked.items():
                self._drop(Drop.FRAME_UNMATCHED, i, t)
            return []
        stamps = [picked[i][0] if i in picked else None for i in range(self.num_streams)]
        items = [picked[i][1] if i in picked else None for i in range(self.num_streams)]
        self.emitted += 1
        self.grouped += len(picked)
        if missing:
            self.partial.update(missing)
        else:
            self.complete += 1
        return [SyncedSet(picked[min(picked)][0], stamps, items, ref, missing)]

    # ------------------------------------------------------------------ report
    def describe(self) -> str:
        """One line: sets, partial sets per stream, drops by reason, time jumps, tolerance and periods."""
        parts = [f"{self.emitted} sets ({self.complete} complete"]
        if self.emitted > self.complete:
            miss = ", ".join(f"{self.names[i]} {n}" for i, n in sorted(self.partial.items()))
            parts[0] += f", {self.emitted - self.complete} partial; missing: {miss}"
        parts[0] += f"; {self.grouped} messages grouped)"
        drops = "; ".join(f"{k.label} {v}" for k, v in sorted(self.dropped.items(), key=lambda kv: kv[0].label))
        parts.append(f"dropped: {drops}" if drops else "nothing dropped")
        if self.events:
            parts.append(", ".join(f"{k}: {v}" for k, v in sorted(self.events.items())))
        how = "fixed" if self.fixed_tolerance is not None else (
            f"{self.period_fraction:g} x the smallest period" if any(p > 0 for p in self._period) else "start value")
        periods = ", ".join(f"{n} {1e3 * p:.1f}" if p > 0 else f"{n} ?" for n, p in zip(self.names, self._period))
        parts.append(f"tolerance +-{1e3 * self.tolerance:.1f} ms ({how}); periods (ms): {periods}")
        return "; ".join(parts)
