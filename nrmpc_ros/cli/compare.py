"""``nrmpc compare``: a replay CSV's gravity against the IMU and ground truth of a bag, its poses against the ground
truth (relative, and in the sequence origin), and the trajectories as TUM files for evo."""

from __future__ import annotations

import json
import math
import sys

from ..bag.reader import BagReader, bag_root
from ..core import load_rig
from ..errors import InputError
from ..frontend.estimates_csv import read_csv
from ..frontend.evaluation import evaluate
from ..frontend.evaluation_report import format_report, plot_errors
from ..frontend.imu_reference import WINDOW_S as IMU_WINDOW_S
from ..frontend.reference import read_reference
from ..frontend.topics import IMU_TYPE, bag_topic, check_topic_type
from ..frontend.trajectory import describe as describe_trajectories
from ..frontend.trajectory import sequence_errors, write_trajectories
from ..safeio import atomic_write, check_outputs
from .argtypes import positive_seconds
from .common import add_trajectory_arguments


def register(sub):
    p = sub.add_parser("compare", help="score a replay CSV against the bag's IMU and /ground_truth/*",
                       description="Angle between each hold's estimated gravity and the IMU's (accelerometer "
                                   "averaged over still samples around each stamp) and /ground_truth/gravity when "
                                   "present; relative pose errors against /ground_truth/pose, and the absolute "
                                   "error of the poses in each sequence's origin frame; median/mean/p90 per "
                                   "method.")
    p.add_argument("csv", metavar="OUT.csv", help="estimates written by nrmpc replay (docs/CONVENTIONS.md (Bags))")
    p.add_argument("--bag", required=True, help="the bag the estimates came from")
    p.add_argument("--imu-topic", help="IMU topic (default: the rig file's imu.topic, else /imu/data; a relative "
                   "name lies in the root namespace; ignored if absent)")
    p.add_argument("--rig", help="rig file: its imu mount turns readings into body gravity (default: IMU = body)")
    p.add_argument("--imu-window", type=positive_seconds, default=IMU_WINDOW_S,
                   help="average the IMU samples the stillness test passes within +- this (s)")
    p.add_argument("--plot", metavar="OUT.png", help="write a PNG of the errors over time")
    add_trajectory_arguments(p, "the bag's /ground_truth/pose")
    p.add_argument("--json", metavar="OUT.json", help="write the statistics as JSON (null where a statistic has no "
                   "samples)")
    p.add_argument("--quiet", action="store_true", help="statistics only, not every estimate")
    p.set_defaults(func=run)


def _warn(msg: str) -> None:
    print(f"nrmpc compare: warning: {msg}", file=sys.stderr)


def _json_value(v):
    """NaN and infinities (a statistic without samples) as null: the file stays standard JSON."""
    if isinstance(v, dict):
        return {k: _json_value(x) for k, x in v.items()}
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def run(args) -> int:
    check_outputs({"--plot": args.plot, "--json": args.json, "--tum": args.tum, "--tum-gt": args.tum_gt},
                  {"OUT.csv": args.csv, "--bag": bag_root(args.bag), "--rig": args.rig})
    rows = read_csv(args.csv)
    rig = load_rig(args.rig) if args.rig else None
    with BagReader(args.bag) as bag:
        wanted = bag_topic(args.imu_topic or (rig.imu.topic if rig is not None and rig.imu else "/imu/data"))
        imu_topic = wanted if bag.has_topic(wanted) else None
        if imu_topic is None:
            print(f"nrmpc compare: note: IMU topic {wanted!r} not in the bag; comparing with ground truth only")
        else:
            source, field = ("--imu-topic", None) if args.imu_topic or rig is None else (rig.source, "imu.topic")
            check_topic_type(bag, imu_topic, IMU_TYPE, source, "the IMU", field)
        ref = read_reference(bag, imu_topic, _warn)
    if not ref.has_imu and not ref.has_gravity and not ref.has_pose:
        raise InputError(args.bag, "the bag has neither the IMU topic nor /ground_truth/*: nothing to compare with")
    ev = evaluate(rows, ref, rig, args.imu_window)
    print(format_report(ev, per_estimate=not args.quiet))
    if args.tum_gt and not (args.tum and ref.has_pose):
        raise InputError("--tum-gt", "needs --tum and /ground_truth/pose in the bag")
    if args.tum:
        print(describe_trajectories(write_trajectories(rows, args.tum, ref, args.tum_gt)))
    else:
        print(describe_trajectories(sequence_errors(rows, ref)))
    if args.plot:
        plot_errors(ev, args.plot, flag="--plot")
        print(f"wrote {args.plot}")
    if args.json:
        out = {m: {k: ev.stats(k, m) for k in ev.errors} for m in ev.methods}
        out["static_attitudes"] = ev.holds
        out["attitudes_with_estimate"] = ev.holds_with_estimate
        with atomic_write(args.json, flag="--json") as f:
            json.dump(_json_value(out), f, indent=1, allow_nan=False)
        print(f"wrote {args.json}")
    return 0
