"""Whether the IMU's stamps are off the cameras' clock by more than a lag, from what a whole recording shows.

An IMU stamped by another clock (its own microcontroller's, a driver that
stamps on receipt after a buffer, another computer's) puts every hold's IMU
samples at another moment: the stillness test, the holds' IMU gravities and
the gyro's turns all read another attitude (docs/PIPELINE.md, "IMU gravity
that the images refute"). Two measurements see it, each where the other
cannot:

- moves on camera: each camera's image rate against the rate the gyro
  predicts across its optical axis, over lags of up to ``MAX_OFFSET_S``
  (:meth:`~nrmpc_ros.frontend.imu_clock.ImuClockEstimator.far_offset`), taken
  when the recording's moves single the lag out;
- holds without moves on camera: the rotations between holds, gyro against
  images (:func:`~nrmpc_ros.frontend.imu_clock_holds.offset_from_turns`),
  taken when their plateau of agreeing lags excludes zero and the stamps as
  read disagree with the images clearly more than the offset does
  (:attr:`~nrmpc_ros.frontend.imu_clock_holds.HoldsClockOffset.refutes_stamps`).

A lag within ``MAX_LAG_S`` (a stamping or transport delay, a low-pass
filter's group delay) is the near search's to read, against the bent
cameras (:meth:`~nrmpc_ros.frontend.imu_clock.ImuClockEstimator.estimate`),
and applied too where it stands out of its std: an IMU stamped 0.15 s late
holds every hold's IMU stillness 0.15 s into the next move, whose first
frames the images show moving, and 4 of 6 holds of such a recording were
refused as never settled.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from .imu_clock import MAX_LAG_S, ClockOffset, FarClockOffset
from .imu_clock_holds import MAX_OFFSET_S, HoldsClockOffset, offset_from_turns


class ClockEvidence(Enum):
    """What measured the offset."""

    MOVES = "the gyro's rate against the images' motion"
    LAG = "the gyro's rate against the images' motion, within a quarter second"
    HOLDS = "the rotations between holds"


@dataclass(frozen=True)
class MeasuredClockOffset:
    """The offset to add to the IMU's stamps (s, beyond any already added), what measured it, and that
    measurement's own result."""

    offset_s: float
    source: ClockEvidence
    detail: FarClockOffset | ClockOffset | HoldsClockOffset


def measure_imu_clock(pipeline, ref, rig, estimates: list) -> MeasuredClockOffset | None:
    """The IMU clock offset a pass of ``pipeline`` over a recording shows (module docstring), or None where the
    stamps as read agree with the images or nothing measures them. ``ref`` holds the IMU's samples as the pipeline
    read them (:class:`~nrmpc_ros.frontend.reference.Reference`), ``estimates`` the pass's hold estimates."""
    if rig.imu is None or not ref.has_imu:
        return None
    far = pipeline.imu_clock.far_offset(MAX_OFFSET_S)
    found = _from_moves(far) if far is not None and far.unique else None
    if found is not None:
        return found
    lag = lag_from_moves(pipeline.imu_clock)
    if lag is not None:
        return lag
    if far is not None and far.unique:
        return None  # the moves single out no offset: the holds are not asked
    turns = _turns_between_holds(estimates, bool(pipeline.estimator.imu_check.refuted))
    # the gyro's bias taken out (the stillness test's, from the IMU's own still samples: no clock in it): over a
    # hold, a move and a hold, a bias of 0.5 deg/s turns the integral by degrees, beyond the pairs' agreement,
    # and some shift of seconds then agreed better than the stamps
    noise = pipeline.zupt.noise_in_use
    w = ref.imu_w if noise is None else ref.imu_w - np.asarray(noise.gyro_bias, float).reshape(1, 3)
    found = offset_from_turns(ref.imu_t, w, rig.imu, turns)
    if found is not None and found.refutes_stamps:
        return MeasuredClockOffset(found.offset_s, ClockEvidence.HOLDS, found)
    return None


LAG_ASKS_GROWTH = 1.25
"""A running node asks the near search for a lag (:func:`lag_from_moves`) once the holds ended have as many
moves between them as the search needs, then each time the holds ended have grown by this factor: the search
reads the whole kept stream (a tenth of a second to a second of CPU), so its cost over a run grows with the log
of the holds, while a lag is still found within a quarter again the holds that first show it."""

CLOCK_PASSES = 3
"""Passes over a recording whose IMU clock is measured off the cameras' (the first included): the first pass's
holds, placed with the wrong IMU, measure the offset coarsely (tenths of a second from the holds' slack); the
second's, placed right, measure what remains finer."""


def clock_passes(run_pass, measure, offset_s: float = 0.0, said=None, applied=None) -> tuple:
    """A recording replayed until its IMU clock agrees with the cameras': ``run_pass(offset_s)`` replays it with
    that offset added to the IMU's stamps and returns its result, ``measure(result)`` the offset that result still
    shows (:func:`measure_imu_clock`) or None; while one is measured, up to :data:`CLOCK_PASSES` passes, the
    next pass adds it to what the last one ended with: ``applied(result)``, the offset its feeder had at the end
    (an IMU on another clock is moved as it arrives, :mod:`~nrmpc_ros.frontend.clock_domain`), or the one it was
    given. ``said(measured, result, passes)`` hears each offset applied. Returns (the last pass's result, what it
    still measures or None, the offset it ran with)."""
    result = run_pass(offset_s)
    measured, passes = measure(result), 1
    while measured is not None and passes < CLOCK_PASSES:
        if said is not None:
            said(measured, result, passes)
        offset_s = (offset_s if applied is None else applied(result)) + measured.offset_s
        result = run_pass(offset_s)
        measured, passes = measure(result), passes + 1
    return result, measured, offset_s


def _turns_between_holds(estimates, refuted: bool) -> list:
    """The pairs of holds [(span_a, span_b, R)] of :func:`~nrmpc_ros.frontend.imu_clock_holds.offset_from_turns`
    from hold estimates (their settled
    spans and rotations): the images' own rotations only where the IMU's gravity was refuted (the others lean on
    it)."""
    spans = {e.stamp: (e.hold.settled_start, e.hold.settled_end) for e in estimates}
    return [(spans.get(e.ref_stamp, (e.ref_stamp, e.ref_stamp)), spans[e.stamp], e.R) for e in estimates
            if not refuted or e.method != "4pt-bending"]


def offset_from_moves(imu_clock) -> MeasuredClockOffset | None:
    """The offset the moves alone show (the far search of the :class:`~nrmpc_ros.frontend.imu_clock.
    ImuClockEstimator` ``imu_clock``, where they single it out), or None: what a running node can measure."""
    far = imu_clock.far_offset(MAX_OFFSET_S)
    return _from_moves(far) if far is not None and far.unique else None


def lag_from_moves(imu_clock) -> MeasuredClockOffset | None:
    """The lag within ``MAX_LAG_S`` the moves show beyond its std (the near search of the :class:`~nrmpc_ros.
    frontend.imu_clock.ImuClockEstimator` ``imu_clock``, :attr:`~nrmpc_ros.frontend.imu_clock.ClockOffset.
    significant`), or None: a stamping or transport delay, a filter's group delay."""
    lag = imu_clock.estimate()
    return MeasuredClockOffset(lag.offset_s, ClockEvidence.LAG, lag) if lag is not None and lag.significant else None


def _from_moves(far: FarClockOffset) -> MeasuredClockOffset | None:
    return MeasuredClockOffset(far.offset_s, ClockEvidence.MOVES, far) if abs(far.offset_s) > MAX_LAG_S else None


def describe_clock(clock: MeasuredClockOffset) -> str:
    """The measured offset as the replay summary says it."""
    d = clock.detail
    late = f"the IMU's stamps are {-clock.offset_s:+.3f} s off the cameras'"
    if isinstance(d, ClockOffset):
        return (f"{late} +- {1e3 * d.std_s:.1f} ms (correlation {d.correlation:.2f} over {d.frames} frames in "
                f"{d.moves} moves)")
    if isinstance(d, FarClockOffset):
        return (f"{late} (correlation {d.correlation:.2f} over {d.moves} moves, the best other lag's "
                f"{d.rival_correlation:.2f}; the peak won {100 * d.confidence:.1f} % of resamples of the moves)")
    return (f"{late} +- {d.half_width_s:.2f} s ({d.pairs} pairs of holds: the gyro's rotations "
            f"{d.as_stamped_deg:.1f} deg off the images' as stamped, {d.residual_deg:.2f} deg shifted so)")


__all__ = ["CLOCK_PASSES", "LAG_ASKS_GROWTH", "ClockEvidence", "MeasuredClockOffset", "clock_passes", "describe_clock",
           "lag_from_moves", "measure_imu_clock", "offset_from_moves"]
