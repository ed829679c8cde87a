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

import sys
from collections.abc import Callable, Iterator

import numpy as np

from ..bag.reader import BagReader
from ..core.rig import Rig
from ..errors import InputError
from .images import decode_image, stamp_seconds
from .pipeline import FrameSet, Pipeline, PipelineConfig
from .sync import StampSynchronizer
from .topics import CAMERA_INFO_TYPE, IMU_TYPE, bag_image_topics, check_topic_type


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
    topic = requested or rig.imu.topic
    if not bag.has_topic(topic):
        if required:
            raise InputError(bag.source, f"IMU topic {topic!r} (rig file {rig.source}) not in the bag, but an IMU "
                             f"is needed here (topics: {bag.describe_topics()})", topic)
        warn(f"IMU topic {topic!r} not in the bag (topics: {bag.describe_topics()}); running without IMU")
        return None
    source, field = ("--imu-topic", None) if requested else (rig.source, "imu.topic")
    check_topic_type(bag, topic, IMU_TYPE, source, "the IMU", field)
    return topic


def check_camera_info(bag: BagReader, rig: Rig, warn: Callable = _stderr_warn) -> None:
    """Report CameraInfo messages that disagree with the rig file (the rig file wins)."""
    topics = [c.info_topic for c in rig.cameras if c.info_topic and bag.has_topic(c.info_topic)]
    for i, cam in enumerate(rig.cameras):
        if cam.info_topic in topics:
            check_topic_type(bag, cam.info_topic, CAMERA_INFO_TYPE, rig.source, f"camera {cam.name}'s CameraInfo",
                             f"cameras[{i}].info_topic")
    seen = set()
    for topic, _, msg in bag.messages(topics):
        if topic in seen:
            continue
        seen.add(topic)
        cam = next(c for c in rig.cameras if c.info_topic == topic)
        K = np.asarray(msg.k, dtype=float).reshape(3, 3)
        fx, fy, cx, cy = cam.intrinsics
        if (int(msg.width), int(msg.height)) != tuple(cam.resolution):
            warn(f"{topic}: CameraInfo says {msg.width}x{msg.height}, the rig file {cam.resolution[0]}x"
                 f"{cam.resolution[1]} (using the rig file)")
        elif not np.allclose([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], [fx, fy, cx, cy], atol=0.5):
            warn(f"{topic}: CameraInfo intrinsics {K[0, 0]:.1f} {K[1, 1]:.1f} {K[0, 2]:.1f} {K[1, 2]:.1f} differ "
                 f"from the rig file's {fx:.1f} {fy:.1f} {cx:.1f} {cy:.1f} (using the rig file)")
        if len(seen) == len(topics):
            break


def replay_bag(bag: BagReader, rig: Rig, pipe: Pipeline, imu_topic: str | None = None,
               sync: StampSynchronizer | None = None, warn: Callable = _stderr_warn,
               progress: bool = False, image_topics: list | None = None) -> Iterator[list]:
    """Feed a bag's images (synchronised) and IMU samples through ``pipe`` in bag order.

    Yields the list of estimates of every frame set handed to the pipeline
    (usually empty), and last those of the hold still open at the end of the
    bag. Undecodable images and bad frame sets are counted in
    ``pipe.stats.dropped`` and warned about once per topic. ``image_topics``
    (from :func:`~nrmpc_ros.frontend.topics.bag_image_topics`) defaults to the
    rig's cameras' topics, raw or compressed, as the bag has them. A frame set
    missing a camera (a dropped frame) is counted and used without it.
    """
    if image_topics is None:
        image_topics = bag_image_topics(bag, rig, warn)
    cam_topics = [t.topic for t in image_topics]
    sync = sync or StampSynchronizer(rig.num_cameras, names=[c.name for c in rig.cameras])
    topics = cam_topics + ([imu_topic] if imu_topic else [])
    index = {t: i for i, t in enumerate(cam_topics)}
    warned = set()
    bar = None

    def frame_sets(groups) -> Iterator[list]:
        for group in groups:
            if not group.complete:
                pipe.stats.dropped["frame set missing a camera (used without it)"] += 1
            try:
                ests = pipe.add_frames(FrameSet(group.stamp, group.items))
            except InputError as exc:
                pipe.stats.dropped["bad frame set"] += 1
                if exc.source not in warned:
                    warned.add(exc.source)
                    warn(str(exc))
                continue
            yield ests

    if progress:
        from tqdm import tqdm

        bar = tqdm(total=bag.count(topics), unit="msg", desc="replay", file=sys.stderr, leave=False)
    try:
        for topic, _, msg in bag.messages(topics):
            if bar is not None:
                bar.update(1)
            if topic == imu_topic:
                a, w = msg.linear_acceleration, msg.angular_velocity
                pipe.add_imu(stamp_seconds(msg), (a.x, a.y, a.z), (w.x, w.y, w.z),
                             (msg.linear_acceleration_covariance, msg.angular_velocity_covariance))
                continue
            try:
                img = decode_image(msg, topic)
            except InputError as exc:
                pipe.stats.dropped[f"image not decoded ({topic})"] += 1
                if topic not in warned:
                    warned.add(topic)
                    warn(str(exc))
                continue
            yield from frame_sets(sync.add(index[topic], stamp_seconds(msg), img))
        yield from frame_sets(sync.flush())
        yield pipe.flush()
    finally:
        if bar is not None:
            bar.close()


def collect_sequences(bag, rig: Rig, config: PipelineConfig | None = None, imu_topic: str | None = None,
                      warn: Callable = _stderr_warn, progress: bool = False, stats: dict | None = None) -> list:
    """The sequences of holds a bag holds, with the IMU's gravity of every hold (for
    :func:`nrmpc_ros.calibration.calibrate_sequences`): one ``SequenceRecord`` per sequence.

    ``bag`` is a path or an open :class:`BagReader`. The poses and gravity start the calibration; the rig's bar
    values may be wrong (what the holds and their tracks are does not depend on them). Raises
    :class:`InputError` when the bag or rig has no IMU, or no sequence of two holds has IMU gravity.
    """
    if not isinstance(bag, BagReader):
        with BagReader(bag) as reader:
            return collect_sequences(reader, rig, config, imu_topic, warn, progress, stats)
    topic = resolve_imu_topic(bag, rig, imu_topic, required=True, warn=warn)
    pipe = Pipeline(rig, config, method="4pt-bending")
    pipe.sequence.keep_history = True
    for _ in replay_bag(bag, rig, pipe, topic, warn=warn, progress=progress):
        pass
    if stats is not None:
        stats.update(pipe.stats.as_dict())
    seqs = [s for s in pipe.sequence.sequences() if s.tracks.g_meas is not None and s.gravity is not None]
    if not seqs:
        st = pipe.stats
        dropped = "; ".join(f"{k}: {v}" for k, v in sorted(st.dropped.items())) or "nothing dropped"
        raise InputError(bag.source, f"no sequence of holds with IMU gravity on {topic!r} ({st.frames} frame "
                         f"sets, {st.holds} holds, {st.estimates} estimates; dropped: {dropped})", topic)
    return seqs


__all__ = ["check_camera_info", "collect_sequences", "replay_bag", "resolve_imu_topic"]
