"""Types of the numeric flags: the range each may take, checked while the command line is parsed.

A value out of range is argparse's one-line error naming the flag
(``nrmpc replay: error: argument --queue-size: must be an integer >= 1, got '0'``,
exit status 2), before any file is read. make-bag checks the values of its
scenario file with the same types, so a file and a flag are held to one rule.
"""

from __future__ import annotations

import argparse
import math

SEED_MAX = 2**63 - 1  # seeds are numpy SeedSequence entropy; the pipeline's seed option has the same bound


def _shown(x) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def number(kind=float, *, lo=None, hi=None, lo_open: bool = False, unit: str = ""):
    """An argparse type: ``kind`` (int or float) with lo <= x <= hi (x > lo when ``lo_open``); floats finite."""
    noun = "an integer" if kind is int else "a finite number"
    bounds = []
    if lo is not None:
        bounds.append(f"{'>' if lo_open else '>='} {_shown(lo)}")
    if hi is not None:
        bounds.append(f"<= {_shown(hi)}")
    rule = " and ".join([noun + (" " + bounds[0] if bounds else "")] + bounds[1:]) + (f" ({unit})" if unit else "")

    def parse(text):
        """``text`` from the command line, or a number from a scenario file (never a bool; no float for an int)."""
        strict = isinstance(text, bool) or (kind is int and isinstance(text, float))
        try:
            if strict:
                raise ValueError
            value = kind(text)
        except (TypeError, ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}") from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}")
        if lo is not None and (value <= lo if lo_open else value < lo):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}")
        if hi is not None and value > hi:
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}")
        return value

    parse.__name__ = kind.__name__  # what argparse and make-bag's scenario check call the type
    return parse


seed = number(int, lo=0, hi=SEED_MAX)
positive_int = number(int, lo=1)
nonnegative_seconds = number(float, lo=0.0, unit="s")
positive_radians = number(float, lo=0.0, lo_open=True, unit="rad")
positive_seconds = number(float, lo=0.0, lo_open=True, unit="s")

__all__ = ["SEED_MAX", "nonnegative_seconds", "number", "positive_int", "positive_radians", "positive_seconds",
           "seed"]
