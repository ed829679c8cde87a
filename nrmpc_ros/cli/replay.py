"""``nrmpc replay``: run the node's pipeline on a bag and write one CSV row per estimate (SPEC section 11)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import yaml

from ..bag.reader import BagReader
from ..core import load_rig
from ..errors import InputError
from ..frontend.evaluation import CsvWriter, evaluate, format_report, read_reference, row_from_estimate
from ..frontend.images import decode_image, stamp_seconds
from ..frontend.pipeline import PIPELINE_METHODS, FrameSet, Pipeline, PipelineConfig
from ..frontend.sync import StampSynchronizer


def register(sub):
    p = sub.add_parser("replay", help="run the estimator pipeline on a bag, write estimates to CSV",
                       description="Runs the same pipeline as the ROS 2 node on a rosbag2 (sqlite3/mcap) or ROS 1 "
                                   "bag and writes one CSV row per estimate the node would publish; prints the "
                                   "estimates and their errors against the IMU and /ground_truth/* at the end.")
    p.add_argument("bag", metavar="BAG", help="rosbag2 directory or ROS 1 .bag file")
    p.add_argument("--rig", required=True, help="rig YAML file (SPEC section 7)")
    p.add_argument("--method", default="auto", choices=PIPELINE_METHODS,
                   help="auto: 4pt-bending when IMU gravity is available for both views, else 6pt-bending")
    p.add_argument("--out", required=True, help="output CSV")
    p.add_argument("--config", help="pipeline settings YAML (keys of PipelineConfig: tracking, static, imu, ...)")
    p.add_argument("--imu-topic", help="IMU topic (default: the rig file's imu.topic)")
    p.add_argument("--no-imu", action="store_true", help="ignore the IMU (auto then runs 6pt-bending)")
    p.add_argument("--sync-tolerance", type=float, default=0.01, help="camera stamps of one set lie within this (s)")
    p.add_argument("--queue-size", type=int, default=10, help="synchronizer queue depth per camera")
    p.add_argument("--seed", type=int, default=0, help="RANSAC seed")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--quiet", action="store_true", help="print only the statistics, not every estimate")
    p.set_defaults(func=run)


def load_config(path, seed: int) -> PipelineConfig:
    d = {}
    if path:
        try:
            d = yaml.safe_load(Path(path).read_text()) or {}
        except OSError as exc:
            raise InputError(str(path), f"cannot read ({exc.strerror})") from None
        except yaml.YAMLError as exc:
            raise InputError(str(path), f"not valid YAML ({exc})") from None
        if not isinstance(d, dict):
            raise InputError(str(path), "expected a mapping of pipeline settings")
    d.setdefault("seed", seed)
    return PipelineConfig.from_dict(d, source=str(path or "pipeline config"))


def check_camera_info(bag: BagReader, rig, warn) -> None:
    """Report CameraInfo messages that disagree with the rig file (the rig file wins)."""
    topics = [c.info_topic for c in rig.cameras if c.info_topic and bag.has_topic(c.info_topic)]
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


def replay(bag: BagReader, rig, pipe: Pipeline, sync: StampSynchronizer, imu_topic: str | None, on_estimate,
           warn, progress: bool = True) -> None:
    """Feed a bag's images (synchronised) and IMU samples through ``pipe`` in bag order."""
    cam_topics = [c.image_topic for c in rig.cameras]
    bag.require(cam_topics)
    topics = cam_topics + ([imu_topic] if imu_topic else [])
    index = {t: i for i, t in enumerate(cam_topics)}
    warned = set()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=bag.count(topics), unit="msg", desc="replay", file=sys.stderr, leave=False)
    try:
        for topic, _, msg in bag.messages(topics):
            if bar is not None:
                bar.update(1)
            if topic == imu_topic:
                a, w = msg.linear_acceleration, msg.angular_velocity
                pipe.add_imu(stamp_seconds(msg), (a.x, a.y, a.z), (w.x, w.y, w.z))
                continue
            try:
                img = decode_image(msg, topic)
            except InputError as exc:
                pipe.stats.dropped[f"image not decoded ({topic})"] += 1
                if topic not in warned:
                    warned.add(topic)
                    warn(str(exc))
                continue
            for group in sync.add(index[topic], stamp_seconds(msg), img):
                try:
                    for est in pipe.add_frames(FrameSet(group.stamp, group.items)):
                        on_estimate(est)
                except InputError as exc:
                    pipe.stats.dropped["bad frame set"] += 1
                    key = exc.source
                    if key not in warned:
                        warned.add(key)
                        warn(str(exc))
    finally:
        if bar is not None:
            bar.close()


def run(args) -> int:
    rig = load_rig(args.rig)
    cfg = load_config(args.config, args.seed)
    t_start = time.perf_counter()

    def warn(msg):
        print(f"nrmpc replay: warning: {msg}", file=sys.stderr)

    with BagReader(args.bag) as bag:
        bag.require([c.image_topic for c in rig.cameras])
        imu_topic = None
        if not args.no_imu:
            imu_topic = args.imu_topic or (rig.imu.topic if rig.imu is not None else None)
            if imu_topic and rig.imu is None:
                raise InputError(args.rig, "--imu-topic given but the rig file has no imu block (mount unknown)",
                                 "imu")
            if imu_topic and not bag.has_topic(imu_topic):
                warn(f"IMU topic {imu_topic!r} not in the bag (topics: {bag.describe_topics()}); running without IMU")
                imu_topic = None
        check_camera_info(bag, rig, warn)
        pipe = Pipeline(rig, cfg, method=args.method)
        sync = StampSynchronizer(rig.num_cameras, args.sync_tolerance, args.queue_size)
        writer = CsvWriter(args.out)
        rows = []

        def on_estimate(est):
            row = row_from_estimate(est)
            writer.write(row)
            rows.append(row)

        try:
            replay(bag, rig, pipe, sync, imu_topic, on_estimate, warn, progress=not args.no_progress)
        finally:
            writer.close()
        ref = read_reference(bag, imu_topic)
    elapsed = time.perf_counter() - t_start
    ev = evaluate(rows, ref, rig)
    st = pipe.stats
    print(format_report(ev, per_estimate=not args.quiet))
    dropped = dict(st.dropped)
    for k, v in sync.dropped.items():
        dropped[f"sync: {k}"] = v
    print(f"frames {st.frames}, static views {st.static_views}, pairs {st.pairs}, estimates {st.estimates} "
          f"({', '.join(f'{m}: {n}' for m, n in sorted(st.methods.items())) or 'none'}), "
          f"reference changes {st.reference_changes}")
    if dropped:
        print("dropped: " + "; ".join(f"{k}: {v}" for k, v in sorted(dropped.items())))
    if st.static_views > 1:
        print(f"static views with an estimate (after the first): {st.estimates}/{st.static_views - 1} "
              f"({100.0 * st.estimates / (st.static_views - 1):.0f}%)")
    times = [r.time_ms for r in rows]
    if times:
        print(f"pair time (matching + estimation): median {np.median(times):.0f} ms; wall time {elapsed:.1f} s")
    print(f"wrote {len(rows)} estimates to {args.out}")
    return 0
