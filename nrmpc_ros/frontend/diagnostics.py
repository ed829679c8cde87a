"""The node's reports without ROS: one diagnostic status per part (cameras, IMU, estimation) and the shutdown
summary, read from an :class:`~nrmpc_ros.frontend.service.EstimatorService` (README, "The ROS 2 node",
Drops and logs; docs/ARCHITECTURE.md).

A part's level is WARN when something of it was dropped since the previous report (the counts themselves are
totals), ERROR when an estimation failed since then. The estimation part reports both workers of the service:
frame sets waiting for the intake and holds waiting for the estimation stage, the latency of frame sets
(arrival to the end of their intake) and of holds (arrival of the frame set that completed the hold to its
estimate published).
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import numpy as np

from ..core.so3 import rotation_angle
from .accel_tilt import describe_tilt
from .drops import Drop, sorted_counts
from .feeder import IMU
from .imu import describe_gaps
from .imu_agreement import describe_check
from .imu_clock_check import describe_clock
from .imu_units import describe_accel_scale, describe_gyro_noise
from .zupt import NoiseSource, describe_noise

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels


@dataclass
class Status:
    """One diagnostic_msgs/DiagnosticStatus: part name, level (OK / WARN / ERROR), message, key-values."""

    name: str
    level: int
    message: str
    values: dict


def _median(values) -> str:
    return f"{statistics.median(values):.1f}" if values else ""


def _quantile(values, q: float) -> str:
    return f"{float(np.quantile(values, q)):.1f}" if values else ""


class ServiceDiagnostics:
    """The reports of one service (see the module docstring); keeps what the previous report saw."""

    def __init__(self, service):
        self.s = service
        self._reported: dict = {}  # part -> drop count at the last diagnostics
        self._rates: dict = {}  # topic -> (count, clock) at the last diagnostics

    def _rate(self, topic: str, now: float) -> float:
        n = self.s.received[topic]
        n0, t0 = self._rates.get(topic, (n, now))
        self._rates[topic] = (n, now)
        return (n - n0) / (now - t0) if now > t0 else 0.0

    def _drops_of(self, sources) -> tuple:
        counts = {k: v for k, v in self.s.drops.counts().items() if k[0] in sources}
        return sum(counts.values()), {f"dropped: {s}: {r.message}": n for (s, r), n in sorted_counts(counts)}

    def _new_drops(self, part: str, total: int) -> int:
        new = total - self._reported.get(part, 0)
        self._reported[part] = total
        return new

    def statuses(self) -> list:
        """One :class:`Status` per part: cameras, IMU, estimation."""
        now = self.s.clock()
        return [self._camera_status(now), self._imu_status(now), self._estimation_status()]

    def fields(self, node_name: str) -> dict:
        """:meth:`statuses` as the fields of a diagnostic_msgs/DiagnosticArray (one status per part, named
        ``<node name>: <part>``, hardware_id the body frame)."""
        return {"status": [{"level": bytes([st.level]), "name": f"{node_name}: {st.name}", "message": st.message,
                            "hardware_id": self.s.rig.body_frame,
                            "values": [{"key": k, "value": str(v)} for k, v in st.values.items()]}
                           for st in self.statuses()]}

    def _camera_status(self, now: float) -> Status:
        s = self.s
        values = {}
        for i, topic in enumerate(s.camera_topics):
            values[f"{topic}: images"] = s.received[topic]
            values[f"{topic}: rate (Hz)"] = f"{self._rate(topic, now):.2f}"
            values[f"{topic}: state"] = "input ended" if s.watch.ended is not None else s.watch.state[i]
            values[f"{topic}: camera_info"] = s.camera_info.get(i, "none received")
            moved = s.feeder.camera_clock_offset_s(i)
            if s.feeder.stamped_by_arrival(i):
                values[f"{topic}: clock"] = "stamped by arrival (its stamps do not advance: header.stamp unset?)"
            elif moved:
                values[f"{topic}: clock"] = f"{moved:+.3f} s added to its stamps (another clock; arrival times)"
        total, dropped = self._drops_of(set(s.camera_topics))
        values.update(dropped)
        values["frame sets"] = s.feeder.events["frame sets"]
        values["frame grouping"] = s.feeder.sync.describe()
        new = self._new_drops("cameras", total)
        silent = s.watch.silent()
        if silent:
            level, message = WARN, f"no images from {', '.join(silent)}"
        elif new:
            level, message = WARN, f"{new} images dropped in the last period (see dropped: *)"
        elif s.watch.ended is not None:
            level, message = OK, f"the input ended {now - s.watch.ended:.0f} s ago"
        elif s.watch.first_any is None:
            level, message = OK, "waiting for the first images"
        else:
            level, message = OK, f"{len(s.camera_topics)} cameras publishing"
        return Status("cameras", level, message, values)

    def _imu_status(self, now: float) -> Status:
        s = self.s
        if s.imu_topic is None:
            why = "the rig file has no imu block" if s.rig.imu is None else "use_imu is false"
            return Status("IMU", OK, f"no IMU ({why}): vision only", {})
        topic = s.imu_topic
        total, dropped = self._drops_of({topic})
        values = {"topic": topic, "samples": s.received[topic], "rate (Hz)": f"{self._rate(topic, now):.2f}",
                  **dropped}
        new = self._new_drops("imu", total)
        if s.runner.pipeline.zupt.covariance_distrusted:
            values["covariances"] = ("not used: the images held still where the noise they claim read every window "
                                     "as motion (the samples' own noise since)")
        alike = s.feeder.events["imu samples stamped alike"]
        if alike:
            values["samples stamped alike"] = f"{alike} (read in batches: spread over each batch's interval)"
        noise = s.runner.pipeline.zupt.noise_in_use
        scale = None
        if noise is not None:
            values["stillness test"] = describe_noise(noise, s.runner.pipeline.zupt.config)
            scale = describe_accel_scale(noise, s.rig.gravity_magnitude)
            if scale:
                values["accelerometer scale"] = scale
            tilt = describe_tilt(s.runner.pipeline.accel_tilt, s.runner.pipeline.extrinsics)
            if tilt:
                values["accelerometer bias"] = tilt
            gyro_noise = describe_gyro_noise(noise) if s.feeder.config.imu_gyro_scale == 1.0 else None
            if gyro_noise:
                values["gyro noise"] = gyro_noise
        refuted = describe_check(s.runner.pipeline.estimator.imu_check)
        if refuted:
            values["gravity check"] = refuted
        gaps = describe_gaps(s.runner.pipeline.imu)
        if gaps:
            values["gaps"] = gaps
        shift = s.feeder.config.imu_clock_offset_s
        applied = s.counts["IMU clock offsets applied"]
        if s.feeder.stamped_by_arrival(IMU):
            values["stamps"] = "stamped by arrival (its stamps do not advance: header.stamp unset?)"
        rebased = sum(r.stream == IMU for r in s.feeder.rebases)
        if shift or applied or rebased:
            how = [f"{applied} measured off the cameras' and applied"] if applied else []
            how += [f"{rebased} from the arrival times: another clock"] if rebased else []
            how = "; ".join(how) or "input.imu_clock_offset_s"
            values["clock offset"] = f"{shift:+.3f} s added to the IMU's stamps ({how})"
        scales = (s.feeder.config.imu_gyro_scale, s.feeder.config.imu_accel_scale)
        if scales != (1.0, 1.0) or s.counts["IMU units applied"]:
            values["units"] = (f"the gyro's rates multiplied by {scales[0]:.7g}, the specific force by "
                               f"{scales[1]:.7g}" + (" (measured and applied)" if s.counts["IMU units applied"]
                                                     else " (input.imu_gyro_scale, input.imu_accel_scale)"))
        turn = s.feeder.config.imu_axes_turn
        if turn is not None:
            values["axes"] = (f"every sample turned by {math.degrees(float(rotation_angle(turn))):.1f} deg "
                              f"(x, y, z, w {[round(x, 4) for x in s.feeder.config.imu_axes_turn_xyzw]}"
                              + ("; measured and applied)" if s.counts["IMU axes applied"] else ")"))
        clock = s.runner.pipeline.imu_clock_off
        if clock is not None and s.runner.pipeline is not s.measured_from:
            values["clock check"] = (f"{describe_clock(clock)}: set input.imu_clock_offset_s to "
                                     f"{s.feeder.config.imu_clock_offset_s + clock.offset_s:.3f}, or fix the IMU's "
                                     "clock")
        if new:
            level, message = WARN, f"{new} IMU samples dropped in the last period (see dropped: *)"
        elif refuted:
            level, message = WARN, "the images refute the IMU's gravity (see gravity check" + (
                "; its clock is seconds off the cameras': see clock check)" if clock is not None else ")")
        elif scale:
            level, message = WARN, "the accelerometer's scale is off gravity's (see accelerometer scale)"
        elif noise is not None and "gyro noise" in values:
            level, message = WARN, "the gyro's noise is beyond any MEMS gyro's: deg/s? (see gyro noise)"
        elif noise is not None and noise.source is NoiseSource.VIBRATION:
            level, message = OK, (f"{s.received[topic]} samples; the IMU vibrates (a motor?): the stillness test "
                                  "takes the vibration as noise (see stillness test)")
        elif noise is not None and noise.source is NoiseSource.WHITE_NOISE:
            level, message = WARN, ("the Imu covariances claim less noise than the samples show: the stillness "
                                    "test uses the samples' (see stillness test)")
        elif not s.received[topic] and s.watch.first_any is not None:
            level, message = WARN, f"no IMU sample on {topic} yet while the cameras publish"
        else:
            level, message = OK, f"{s.received[topic]} samples"
        return Status("IMU", level, message, values)

    def _estimation_status(self) -> Status:
        s = self.s
        with s._lock:
            counts, last, st = dict(s.counts), s.last, s.stats
            latency, process, sets = list(s.latency_ms), list(s.process_ms), list(s.set_latency_ms)
            estimate = list(s.hold_ms)
        holds_waiting = s.holds_waiting()
        values = {"method": s.config.method, "frame sets processed": counts.get("processed frame sets", 0),
                  "frame sets waiting": s.queue.frames(), "holds waiting": holds_waiting,
                  "work waiting": s.work_waiting(), "holds": st.holds,
                  "estimates": counts.get("estimates", 0), "time jumps back": s.feeder.events["time jumps back"],
                  "resets": counts.get("resets", 0), "latency median (ms)": _median(latency),
                  "processing median (ms)": _median(process), "frame set latency median (ms)": _median(sets),
                  "frame set latency p95 (ms)": _quantile(sets, 0.95),
                  "hold latency median (ms)": _median(latency), "hold latency p95 (ms)": _quantile(latency, 0.95),
                  "hold estimate median (ms)": _median(estimate)}
        values.update({f"methods: {m}": n for m, n in sorted(st.methods.items())})
        values.update({f"not estimated: {k.message}": n for k, n in sorted_counts(st.dropped)})
        values.update({f"estimated without gravity: {k.value}": n for k, n in sorted_counts(st.gravity_withheld)})
        inputs = set(s.camera_topics) | {s.imu_topic}
        total, dropped = self._drops_of({src for src, _ in s.drops.counts()} - inputs)
        values.update(dropped)
        if last is not None:
            e = last.estimate
            values.update({"last: stamp": f"{e.stamp:.6f}", "last: sequence": e.sequence, "last: hold": e.hold_index,
                           "last: method": e.method, "last: gravity sigma (deg)": f"{e.gravity_sigma_deg:.3f}",
                           "last: inliers": e.num_inliers,
                           "last: residual ringing (px)": f"{e.hold.ringing_px:.3f} ({e.hold.ringing_source.value})",
                           "last: noise scale": f"{e.noise_scale:.3f}"})
        values["holds carrying residual ringing"] = st.penalized_holds
        turns = s.runner.pipeline.sequence.rest_turns  # the rig file stated rotation_std_deg: estimated
        if turns is not None:
            values.update({f"rest turn: {c.name} (deg)": f"{math.degrees(rotation_angle(E)):.3f}"
                           for c, E in zip(s.rig.cameras, turns) if c.rotation_std_deg > 0})
        failed = sum(n for (src, r), n in s.drops.counts().items() if r is Drop.ESTIMATION_FAILED)
        if self._new_drops("failed", failed):
            level, message = ERROR, "estimation failed (see dropped: pipeline: *)"
        elif self._new_drops("estimation", total):
            level, message = WARN, "frame sets dropped in the last period (see dropped: *)"
        elif last is not None:
            e = last.estimate
            level, message = OK, (f"sequence {e.sequence}, hold {e.hold_index}: {e.method}, gravity +-"
                                  f"{e.gravity_sigma_deg:.2f} deg")
        else:
            level, message = OK, "waiting for holds"
        return Status("estimation", level, message, values)

    def summary(self) -> str:
        """The shutdown summary: what came in, what was estimated, every drop by reason."""
        s = self.s
        with s._lock:
            counts, latency, st, sets = dict(s.counts), list(s.latency_ms), s.stats, list(s.set_latency_ms)
        images = sum(s.received[t] for t in s.camera_topics)
        imu = s.received[s.imu_topic] if s.imu_topic else 0
        return (f"{images} images, {imu} IMU samples; {s.feeder.events['frame sets']} frame sets, "
                f"{counts.get('processed frame sets', 0)} processed; {st.holds} holds, "
                f"{counts.get('estimates', 0)} estimates; {s.feeder.events['time jumps back']} time jumps back; "
                f"median latency {_median(latency) or 'n/a'} ms (frame sets: median {_median(sets) or 'n/a'} ms, p95 "
                f"{_quantile(sets, 0.95) or 'n/a'} ms; holds: p95 {_quantile(latency, 0.95) or 'n/a'} ms); "
                f"dropped: {s.drops.summary()}")


__all__ = ["ERROR", "OK", "ServiceDiagnostics", "Status", "WARN"]
