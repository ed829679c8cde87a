"""Every dropped input counted by where it came from and why, and log lines that say so without flooding.

A drop is (source, reason, message): the topic (or "pipeline", "worker"),
the reason, a :class:`~nrmpc_ros.frontend.drops.Drop` (its message names the
kind: "stamp in the future", ...), and a message with the numbers of this
occurrence. The first drop of each
(source, reason) is logged with its message; later ones are counted and
logged as one line per ``every_s`` seconds ("12 more ... in the last 10 s"),
also when the burst has ended (:meth:`DropLog.due`, from a timer); with
``every_s`` infinite (offline) they are only counted. Thread
safe: the node's callbacks and its worker both report here.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from dataclasses import dataclass

from .drops import Drop, sorted_counts


@dataclass
class _Kind:
    total: int = 0
    unreported: int = 0  # drops since the last line logged
    last_log: float = 0.0  # clock of that line
    message: str = ""  # of the newest drop


class DropLog:
    """Counts of dropped inputs and the rate-limited lines to log about them (see the module docstring)."""

    def __init__(self, every_s: float = 10.0, clock=time.monotonic):
        self.every_s = float(every_s)
        self.clock = clock
        self._kinds: dict = {}
        self._lock = threading.Lock()

    def drop(self, source: str, reason: Drop, message: str, count: int = 1) -> str | None:
        """Count ``count`` drops; returns the line to log now, or None (counted for a later line)."""
        now = self.clock()
        with self._lock:
            k = self._kinds.setdefault((source, reason), _Kind())
            k.total += count
            k.message = message
            if k.total == count:
                k.last_log = now
                later = "counted" if math.isinf(self.every_s) else \
                    f"counted and logged every {self.every_s:g} s"
                return f"{message} (dropped; later drops of this kind are {later})"
            k.unreported += count
            return self._line(source, reason, k, now) if now - k.last_log >= self.every_s else None

    def due(self) -> list:
        """Lines for the kinds with drops not logged yet whose last line is ``every_s`` old."""
        now = self.clock()
        with self._lock:
            return [self._line(s, r, k, now) for (s, r), k in self._kinds.items()
                    if k.unreported and now - k.last_log >= self.every_s]

    @staticmethod
    def _line(source: str, reason: Drop, k: _Kind, now: float) -> str:
        line = f"{source}: {k.unreported} more dropped ({reason.message}) in the last {now - k.last_log:.0f} s, " \
               f"{k.total} in all; the newest: {k.message}"
        k.unreported, k.last_log = 0, now
        return line

    def counts(self) -> dict:
        """(source, Drop) -> number of drops."""
        with self._lock:
            return {key: k.total for key, k in self._kinds.items()}

    def by_reason(self) -> Counter:
        """Drop -> number of drops over all sources."""
        out = Counter()
        for (_, reason), n in self.counts().items():
            out[reason] += n
        return out

    def total(self) -> int:
        return sum(self.counts().values())

    def summary(self) -> str:
        """One line: every (source, reason) with its count, or "nothing dropped"."""
        items = sorted_counts(self.counts())
        return "; ".join(f"{source}: {reason.message} {n}" for (source, reason), n in items) or "nothing dropped"


__all__ = ["DropLog"]
