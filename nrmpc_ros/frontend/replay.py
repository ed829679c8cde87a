"""Bag -> pipeline: the one loop over a bag's messages, shared by ``nrmpc replay`` and ``nrmpc calibrate-bars``.

    with BagReader(path) as bag:
        imu_topic = resolve_imu_topic(bag, rig)
        pipe = Pipeline(rig, PipelineConfig(), method="auto")
        for estimates in replay_bag(bag, rig, pipe, imu_topic):
            ...                                   # one list per processed frame set (often empty)

:func:`collect_pairs` runs 4pt-bending over a bag with an IMU and returns
every estimated pair's matches with the IMU gravity of both views (for
:func:`nrmpc_ros.calibration.calibrate_bars`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterator

from ..bag.reader import BagReader
from ..core.rig import Rig
from ..errors import InputError
from .camera_info import camera_info_mismatch
from .droplog import DropLog
from .drops import sorted_counts
from .feeder import Feeder, FeederConfig
from .imu_clock_check import clock_passes, describe_clock, measure_imu_clock
from .imu_mount import AxesMeasuringPass, describe_imu_axes
from .imu_units import UnitsMeasuringPass, describe_units
from .pipeline import Pipeline, PipelineConfig
from .reference import read_reference
from .runner import PipelineRunner
from .topics import CAMERA_INFO_TYPE, IMU_TYPE, bag_image_topics, bag_topic, check_topic_type
from .work import WorkKind


def _stderr_warn(msg: str) -> None:
    print(f"nrmpc: warning: {msg}", file=sys.stderr)


def resolve_imu_topic(bag: BagReader, rig: Rig, requested: str | None = None, use_imu: bool = True,
                      required: bool = False, warn: Callable = _stderr_warn) -> str | None:
    """The IMU topic to feed: ``requested`` or the rig file's ``imu.topic``, if the bag has it.

    With ``required`` a missing IMU is an :class:`InputError` naming the rig file or
    the bag; otherwise it is a warning and None (run without IMU).
    """
    if not use_imu:
        return None
    if rig.imu is None:
        if requested or required:
            why = (f"but the IMU topic {requested!r} was given" if requested
                   else "but an IMU is needed here (gravity of every view)")
            raise InputError(rig.source, f"the rig file has no imu block (the IMU's topic and mount), {why}", "imu")
        return None
    topic = bag_topic(requested or rig.imu.topic)
    if not bag.has_topic(topic):
        if required:
            raise InputError(bag.source, f"IMU topic {topic!r} (rig file {rig.source}) not in the bag, but an IMU "
                             f"is needed here (topics: {bag.describe_topics()})", topic)
        warn(f"IMU topic {topic!r} not in the bag (topics: {bag.describe_topics()}); running without IMU")
        return None
    source, field = ("--imu-topic", None) if requested else (rig.source, "imu.topic")
    check_topic_type(bag, topic, IMU_TYPE, source, "the IMU", field)
    return topic


def check_camera_info(bag: BagReader, rig: Rig, warn: Callable = _stderr_warn) -> list:
    """Warn about each camera whose first CameraInfo in the bag disagrees with the rig file (the rig file wins);
    returns the warnings. A CameraInfo topic of another type is an error naming the rig file's key."""
    topics = {bag_topic(c.info_topic): c for c in rig.cameras if c.info_topic}
    topics = {t: c for t, c in topics.items() if bag.has_topic(t)}
    for i, cam in enumerate(rig.cameras):
        if cam.info_topic and bag_topic(cam.info_topic) in topics:
            check_topic_type(bag, bag_topic(cam.info_topic), CAMERA_INFO_TYPE, rig.source,
                             f"camera {cam.name}'s CameraInfo", f"cameras[{i}].info_topic")
    seen, out = set(), []
    for topic, _, msg in bag.messages(list(topics)):
        if topic in seen:
            continue
        seen.add(topic)
        problem = camera_info_mismatch(topics[topic], msg, rig.source)
        if problem:
            out.append(f"{topic}: {problem}")
            warn(out[-1])
        if len(seen) == len(topics):
            break
    return out


class BagReplay:
    """A bag's images and IMU samples through a pipeline in bag order, as the node runs what it receives.

    The messages go through a :class:`~nrmpc_ros.frontend.feeder.Feeder` (the node's input policy: checks,
    stamps against the recording time, frame grouping, IMU order; ``inputs`` its settings) and the work it
    makes through a :class:`~nrmpc_ros.frontend.runner.PipelineRunner` (``pipe``, or one around it: after a
    jump back in time it runs a fresh pipeline). Dropped inputs are counted in ``drops`` and warned about
    once per kind. ``image_topics`` (from :func:`~nrmpc_ros.frontend.topics.bag_image_topics`) defaults to
    the rig's cameras' topics, raw or compressed, as the bag has them.
    """

    def __init__(self, bag: BagReader, rig: Rig, pipe: Pipeline | PipelineRunner, imu_topic: str | None = None,
                 inputs: FeederConfig | None = None, warn: Callable = _stderr_warn, image_topics: list | None = None,
                 drops: DropLog | None = None):
        if image_topics is None:
            image_topics = bag_image_topics(bag, rig, warn)
        self.bag = bag
        self.runner = pipe if isinstance(pipe, PipelineRunner) else PipelineRunner.around(
            pipe, drops=drops if drops is not None else DropLog(math.inf))
        self.drops = self.runner.drops
        self.topics = [t.topic for t in image_topics]
        self.imu_topic = imu_topic
        self._work: list = []
        self.feeder = Feeder(rig, inputs, self._work.append, self.drops, self.topics, imu_topic,
                             log=lambda level, line: warn(line))

    def run(self, progress: bool = False) -> Iterator[list]:
        """Yields the estimates of every frame set handed to the pipeline (usually an empty list) and of every
        flush (the end of the bag, a jump back in time)."""
        topics = self.topics + ([self.imu_topic] if self.imu_topic else [])
        index = {t: i for i, t in enumerate(self.topics)}
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=self.bag.count(topics), unit="msg", desc="replay", file=sys.stderr, leave=False)
        try:
            for topic, t_ns, msg in self.bag.messages(topics):
                if bar is not None:
                    bar.update(1)
                if topic == self.imu_topic:
                    self.feeder.imu_msg(msg, now=t_ns * 1e-9)
                else:
                    self.feeder.image(index[topic], msg, now=t_ns * 1e-9)
                yield from self._run_work()
            self.feeder.end()
            yield from self._run_work()
        finally:
            if bar is not None:
                bar.close()

    def _run_work(self) -> Iterator[list]:
        for item in self._work:
            estimates = self.runner.run(item)
            if item.kind in (WorkKind.FRAMES, WorkKind.FLUSH):
                yield estimates
        self._work.clear()


def replay_bag(bag: BagReader, rig: Rig, pipe: Pipeline | PipelineRunner, imu_topic: str | None = None,
               inputs: FeederConfig | None = None, warn: Callable = _stderr_warn, progress: bool = False,
               image_topics: list | None = None) -> Iterator[list]:
    """:meth:`BagReplay.run` of a :class:`BagReplay` made from the same arguments."""
    yield from BagReplay(bag, rig, pipe, imu_topic, inputs, warn, image_topics).run(progress)


def collect_sequences(bag, rig: Rig, config: PipelineConfig | None = None, imu_topic: str | None = None,
                      warn: Callable = _stderr_warn, progress: bool = False, stats: dict | None = None,
                      holds: list | None = None) -> list:
    """The sequences of holds a bag holds, with the IMU's gravity of every hold (for
    :func:`nrmpc_ros.calibration.calibrate_sequences`): one ``SequenceRecord`` per sequence.

    ``bag`` is a path or an open :class:`BagReader`. The poses and gravity start the calibration; the rig's bar
    values may be wrong (what the holds and their tracks are does not depend on them). Raises
    :class:`InputError` when the bag or rig has no IMU, or no sequence of two holds has IMU gravity. ``holds``:
    a list that receives every measured :class:`~nrmpc_ros.frontend.holds.Hold` (their ringing traces). An IMU
    clock measured seconds off the cameras' is applied as ``nrmpc replay`` applies it (said through ``warn``).
    """
    if not isinstance(bag, BagReader):
        with BagReader(bag) as reader:
            return collect_sequences(reader, rig, config, imu_topic, warn, progress, stats, holds)
    topic = resolve_imu_topic(bag, rig, imu_topic, required=True, warn=warn)
    ref = read_reference(bag, topic, warn)

    def one_pass(inputs):  # the gyro's unit, the IMU's axes and its clock measured and applied, as nrmpc replay does
        pipe = Pipeline(rig, config, method="4pt-bending")
        pipe.sequence.keep_history = True
        pipe.measured_holds = [] if holds is not None else None
        runner = PipelineRunner.around(pipe, drops=DropLog(math.inf))
        replay = BagReplay(bag, rig, runner, topic, inputs, warn)
        ests = [e for es in replay.run(progress) for e in es]
        return runner, ests, replay.feeder.as_read(ref), replay.feeder.config.imu_clock_offset_s

    def units_said(units, result):
        warn(f"IMU units: {describe_units(units)}; replaying in rad/s and m/s^2")

    def axes_said(axes, result):
        warn(f"IMU axes: {describe_imu_axes(axes, rig.imu.rotation)}"
             + ("; replaying with the samples turned" if axes.applies else ""))

    run_pass = AxesMeasuringPass(UnitsMeasuringPass(one_pass, FeederConfig(), lambda result: result[0].pipeline,
                                                    units_said),
                                 lambda result: result[0].pipeline, rig.imu.rotation, axes_said)

    def measure(result):
        runner, ests, shifted, _ = result
        return measure_imu_clock(runner.pipeline, shifted, rig, ests)

    def said(measured, result, passes):
        warn(f"IMU clock against the cameras ({measured.source.value}): {describe_clock(measured)}; replaying "
             "with that offset added to the IMU's stamps")

    (runner, *_), _, _ = clock_passes(run_pass, measure, said=said, applied=lambda result: result[3])
    if holds is not None:
        holds.extend(runner.pipeline.measured_holds)
    st = runner.stats
    if stats is not None:
        stats.update(st.as_dict())
    seqs = [s for s in runner.sequences() if s.tracks.g_meas is not None and s.gravity is not None]
    if not seqs:
        dropped = "; ".join(f"{k.message}: {v}" for k, v in sorted_counts(st.dropped)) or "nothing dropped"
        why = runner.pipeline.no_hold_report()
        raise InputError(bag.source, f"no sequence of holds with IMU gravity on {topic!r} ({st.frames} frame "
                         f"sets, {st.holds} holds, {st.estimates} estimates; dropped: {dropped})"
                         + (f"\n{why}" if why else ""), topic)
    return seqs


__all__ = ["BagReplay", "check_camera_info", "collect_sequences", "replay_bag", "resolve_imu_topic"]
