"""Approximate-time synchronisation of per-camera messages by stamp (shared by the replay and the node).

Each stream keeps a bounded queue sorted by stamp. A set is emitted when every
stream has a message within ``tolerance_s`` of the others; messages that can
no longer be part of any set are dropped and counted. Every message is queued
and popped once and each matching step looks at the queue heads only, so the
cost is linear in streams x queue depth (unlike a combinatorial search).
"""

from __future__ import annotations

import bisect
from collections import Counter
from dataclasses import dataclass


@dataclass
class SyncedSet:
    """One message per stream; ``stamp`` is the stamp of stream 0's message."""

    stamp: float
    stamps: list
    items: list


class StampSynchronizer:
    """Groups messages of ``num_streams`` streams whose stamps lie within ``tolerance_s`` of each other."""

    def __init__(self, num_streams: int, tolerance_s: float = 0.005, queue_size: int = 10):
        if num_streams < 1:
            raise ValueError("num_streams must be >= 1")
        if not tolerance_s >= 0:
            raise ValueError("tolerance_s must be >= 0")
        if queue_size < 1:
            raise ValueError("queue_size must be >= 1")
        self.num_streams = int(num_streams)
        self.tolerance = float(tolerance_s)
        self.queue_size = int(queue_size)
        self.reset()

    def reset(self) -> None:
        self._stamps = [[] for _ in range(self.num_streams)]  # sorted stamps per stream
        self._items = [[] for _ in range(self.num_streams)]
        self._last = [-float("inf")] * self.num_streams  # stamp of the last emitted message per stream
        self.dropped = Counter()  # reason -> count
        self.emitted = 0

    @property
    def queued(self) -> list:
        return [len(s) for s in self._stamps]

    def _pop(self, i: int, reason: str | None) -> tuple:
        if reason:
            self.dropped[reason] += 1
        return self._stamps[i].pop(0), self._items[i].pop(0)

    def add(self, stream: int, stamp: float, item) -> list:
        """Queue one message; returns the sets (0 or more, oldest first) it completes."""
        if not 0 <= stream < self.num_streams:
            raise ValueError(f"stream index {stream} out of range (0..{self.num_streams - 1})")
        stamp = float(stamp)
        if stamp <= self._last[stream]:
            self.dropped["late"] += 1
            return []
        st, it = self._stamps[stream], self._items[stream]
        k = bisect.bisect_right(st, stamp)
        st.insert(k, stamp)
        it.insert(k, item)
        if len(st) > self.queue_size:
            self._pop(stream, "queue overflow")
        return self._match()

    def _match(self) -> list:
        out = []
        tol = self.tolerance
        qs = self._stamps
        while all(qs):
            t_max = max(q[0] for q in qs)
            for i, q in enumerate(qs):  # heads too old to meet the newest head never will
                while q and q[0] < t_max - tol:
                    self._pop(i, "unmatched")
            if not all(qs):
                break
            heads = [q[0] for q in qs]
            if max(heads) - min(heads) > tol:
                continue
            t_ref, t_lim = max(heads), min(heads) + tol
            for i, q in enumerate(qs):  # a later queued message may be closer to the set's newest stamp
                while len(q) > 1 and q[1] <= t_lim and abs(q[1] - t_ref) < abs(q[0] - t_ref):
                    self._pop(i, "unmatched")
            picked = [self._pop(i, None) for i in range(self.num_streams)]
            stamps = [p[0] for p in picked]
            self._last = stamps
            self.emitted += 1
            out.append(SyncedSet(stamps[0], stamps, [p[1] for p in picked]))
        return out
