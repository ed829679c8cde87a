"""``nrmpc replay``: the node's pipeline on a bag, one CSV row per estimate (docs/CONVENTIONS.md, Bags)."""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from ..bag.reader import BagReader, bag_root
from ..config import from_mapping, load_mapping
from ..core import load_rig
from ..errors import InputError
from ..frontend.droplog import DropLog
from ..frontend.evaluation import CsvWriter, batch_rows, evaluate, format_report, read_reference, row_from_estimate
from ..frontend.feeder import FeederConfig
from ..frontend.pipeline import PIPELINE_METHODS, PipelineConfig
from ..frontend.replay import BagReplay, check_camera_info, resolve_imu_topic
from ..frontend.runner import PipelineRunner
from ..frontend.topics import bag_image_topics
from ..frontend.trajectory import describe as describe_trajectories
from ..frontend.trajectory import sequence_errors, write_trajectories
from ..safeio import check_outputs
from .argtypes import nonnegative_seconds, positive_int, seed
from .common import add_trajectory_arguments


def register(sub):
    p = sub.add_parser("replay", help="run the estimator pipeline on a bag, write estimates to CSV",
                       description="Runs the same pipeline as the ROS 2 node on a rosbag2 (sqlite3/mcap) or ROS 1 "
                                   "bag and writes one CSV row per estimate the node would publish; prints the "
                                   "estimates and their errors against the IMU and /ground_truth/* at the end.")
    p.add_argument("bag", metavar="BAG", help="rosbag2 directory or ROS 1 .bag file")
    p.add_argument("--rig", required=True, help="rig YAML file (docs/CONVENTIONS.md (Files))")
    p.add_argument("--method", default="auto", choices=PIPELINE_METHODS,
                   help="auto: 4pt-bending when IMU gravity is available for both views, else 6pt-bending")
    p.add_argument("--out", required=True, help="output CSV: one row per hold as the node publishes it")
    p.add_argument("--batch", metavar="BATCH.csv", help="also write the joint solution of all holds at once "
                   "(each hold relative to the one before it)")
    add_trajectory_arguments(p, "the bag's /ground_truth/pose")
    p.add_argument("--config", help="pipeline settings YAML (keys of PipelineConfig: tracking, holds, imu, zupt, "
                   "sequence, ...)")
    p.add_argument("--imu-topic", help="IMU topic (default: the rig file's imu.topic)")
    p.add_argument("--no-imu", action="store_true", help="ignore the IMU (auto then runs 6pt-bending)")
    p.add_argument("--sync-tolerance", type=nonnegative_seconds, default=None,
                   help="camera stamps of one set lie within +- this (s) of the set's median stamp (default: 0.45 "
                        "of the smallest camera frame period, estimated from the stamps)")
    p.add_argument("--queue-size", type=positive_int, default=None,
                   help=f"synchronizer queue depth per camera (default {FeederConfig().queue_size})")
    p.add_argument("--seed", type=seed, default=0, help="RANSAC seed")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--quiet", action="store_true", help="print only the statistics, not every estimate")
    p.set_defaults(func=run)


def check_tum_flags(args, bag) -> None:
    """--tum-gt needs --tum (the holds and origins it is written at) and ground truth in the bag."""
    from ..frontend.evaluation import GT_POSE_TOPIC

    if args.tum_gt and not args.tum:
        raise InputError("--tum-gt", "needs --tum: the ground truth is written at the estimated holds")
    if args.tum_gt and not bag.has_topic(GT_POSE_TOPIC):
        raise InputError("--tum-gt", f"{bag.source} has no {GT_POSE_TOPIC} topic")


def load_config(path, seed: int) -> PipelineConfig:
    """The pipeline settings of the --config file (errors name the file and the key); its seed wins over --seed."""
    d = dict(load_mapping(path, "pipeline settings file")) if path else {}
    d.setdefault("seed", seed)
    return from_mapping(PipelineConfig, d, str(path or "--seed"))


def input_config(args) -> FeederConfig:
    """The input settings: the node's defaults, the synchronizer's from the flags when given."""
    d = {}
    if args.sync_tolerance is not None:
        d["sync_tolerance_s"] = args.sync_tolerance
    if args.queue_size is not None:
        d["queue_size"] = args.queue_size
    flags = {"sync_tolerance_s": "--sync-tolerance", "queue_size": "--queue-size"}
    try:
        return from_mapping(FeederConfig, d, "flags")
    except InputError as exc:
        raise InputError(flags.get(exc.field, "flags"), str(exc).split(": ", 2)[-1]) from None


def run(args) -> int:
    check_outputs({"--out": args.out, "--batch": args.batch, "--tum": args.tum, "--tum-gt": args.tum_gt},
                  {"BAG": bag_root(args.bag), "--rig": args.rig, "--config": args.config})
    rig = load_rig(args.rig)
    cfg = load_config(args.config, args.seed)
    t_start = time.perf_counter()

    def warn(msg):
        print(f"nrmpc replay: warning: {msg}", file=sys.stderr)

    def note(msg):
        print(f"images: {msg}")

    with BagReader(args.bag) as bag:
        check_tum_flags(args, bag)
        image_topics = bag_image_topics(bag, rig, note)
        imu_topic = resolve_imu_topic(bag, rig, args.imu_topic, use_imu=not args.no_imu, warn=warn)
        check_camera_info(bag, rig, warn)
        runner = PipelineRunner(rig, cfg, method=args.method, drops=DropLog(math.inf))  # counts, first ones warned
        replay = BagReplay(bag, rig, runner, imu_topic, input_config(args), warn, image_topics)
        rows = []
        with CsvWriter(args.out, "--out") as writer:  # becomes --out only when the whole run succeeds
            for estimates in replay.run(progress=not args.no_progress):
                for est in estimates:
                    row = row_from_estimate(est)
                    writer.write(row)
                    rows.append(row)
            ref = read_reference(bag, imu_topic, warn)
            batch = []
            if args.batch:
                method = rows[-1].method if rows else args.method
                batch = batch_rows(runner.pipeline.batch(), method)
                with CsvWriter(args.batch, "--batch") as bw:
                    for row in batch:
                        bw.write(row)
    elapsed = time.perf_counter() - t_start
    ev = evaluate(rows, ref, rig)
    st = runner.stats
    print(format_report(ev, per_estimate=not args.quiet))
    if batch:
        evb = evaluate(batch, ref, rig)
        gb = evb.stats("gravity_vs_gt_deg")
        gi = evb.stats("gravity_vs_imu_deg")
        parts = [f"vs ground truth median {gb['median']:.3f} deg (n={gb['n']})" if gb["n"] else "",
                 f"vs IMU median {gi['median']:.3f} deg (n={gi['n']})" if gi["n"] else ""]
        print(f"batch (all holds at once, {args.batch}): gravity " + ("; ".join(p for p in parts if p) or
                                                                       f"of {len(batch)} holds written"))
    seqs = write_trajectories(rows, args.tum, ref, args.tum_gt) if args.tum else sequence_errors(rows, ref)
    print(describe_trajectories(seqs))
    d = st.as_dict()
    print(f"frames {st.frames}, holds {st.holds}, estimates {st.estimates} "
          f"({', '.join(f'{m}: {n}' for m, n in sorted(st.methods.items())) or 'none'}), sequences {st.sequences}")
    if st.holds:
        print(f"holds: median settle {d['median_settle_s']:.2f} s after the stop (slowest bar period "
              f"{runner.pipeline.bar_period_s:.3f} s), residual motion {d['median_residual_px']:.3f} px, track noise "
              f"{d['median_noise_px']:.3f} px per frame -> {d['median_averaged_noise_px']:.3f} px averaged over "
              f"{np.median(st.settled_frames):.0f} settled frames"
              + (f"; {st.ringing_holds} of {st.holds} still ringing at their end (averaged over whole bar periods)"
                 if st.ringing_holds else ""))
    if st.dropped:
        print("not estimated: " + "; ".join(f"{k}: {v}" for k, v in sorted(st.dropped.items())))
    if not st.holds:
        print(runner.pipeline.no_hold_report() or "no hold found: no frame set reached the pipeline")
    print(f"inputs dropped: {replay.drops.summary()}")
    jumps = replay.feeder.events["time jumps back"]
    if jumps:
        print(f"time jumps back: {jumps} (each started a new sequence)")
    print(f"camera sync: {replay.feeder.sync.describe()}")
    times = [r.time_ms for r in rows]
    if times:
        print(f"hold time (linking + estimation): median {np.median(times):.0f} ms; wall time {elapsed:.1f} s")
    print(f"wrote {len(rows)} estimates to {args.out}")
    return 0
