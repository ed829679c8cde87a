"""``nrmpc report``: the recording's report, one self-contained HTML page (nrmpc_ros/report.py), from the replay's
pipeline run (the same as ``nrmpc replay BAG --rig RIG --out OUT.csv --report OUT.html``, without the CSV)."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from ..errors import InputError
from ..frontend.pipeline import PIPELINE_METHODS
from . import replay
from .argtypes import seed


def register(sub):
    p = sub.add_parser("report", help="one self-contained HTML page of a recording: holds, settling, gravity "
                                      "against the IMU, refusals",
                       description="Runs the node's pipeline on a bag (as nrmpc replay) and writes one HTML page "
                                   "that opens from a file without a network: the timeline with the holds and the "
                                   "IMU stillness statistic; per hold the settling of the bars and the measurement; "
                                   "gravity per hold against the IMU and ground truth with its 2-std band; the holds "
                                   "seen from above; every refused input, frame and hold by reason.")
    p.add_argument("bag", metavar="BAG", help="rosbag2 directory or ROS 1 .bag file")
    p.add_argument("--rig", required=True, help="rig YAML file (docs/CONVENTIONS.md (Files))")
    p.add_argument("--out", default="report.html", help="the HTML page (default: report.html)")
    p.add_argument("--method", default="auto", choices=PIPELINE_METHODS,
                   help="auto: 4pt-bending when IMU gravity is available for both views, else 6pt-bending")
    p.add_argument("--config", help="pipeline settings YAML (keys of PipelineConfig)")
    p.add_argument("--imu-topic", help="IMU topic (default: the rig file's imu.topic)")
    p.add_argument("--no-imu", action="store_true", help="ignore the IMU (auto then runs 6pt-bending)")
    p.add_argument("--calibrate-bars", action="store_true", help="also calibrate the bars' compliance from the holds "
                   "(needs the IMU; as nrmpc calibrate-bars) and show it")
    p.add_argument("--seed", type=seed, default=0, help="RANSAC seed")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def replay_arguments(args, csv_path: str) -> argparse.Namespace:
    """The ``nrmpc replay`` arguments that run the same pipeline and write the report to ``args.out``."""
    parser = argparse.ArgumentParser(prog="nrmpc")
    replay.register(parser.add_subparsers())
    argv = ["replay", str(args.bag), "--rig", str(args.rig), "--out", csv_path, "--report", str(args.out),
            "--method", args.method, "--seed", str(args.seed), "--quiet"]
    for flag, value in (("--config", args.config), ("--imu-topic", args.imu_topic)):
        if value:
            argv += [flag, str(value)]
    argv += ["--no-imu"] * args.no_imu + ["--no-progress"] * args.no_progress
    argv += ["--calibrate-bars"] * args.calibrate_bars
    ns = parser.parse_args(argv)
    ns.scratch_out = True  # the CSV is not kept: replay does not announce it
    return ns


def run(args) -> int:
    with tempfile.TemporaryDirectory(prefix="nrmpc_report_") as tmp:
        try:
            return replay.run(replay_arguments(args, str(Path(tmp) / "estimates.csv")))
        except InputError as exc:
            if exc.source == "--report":  # the page is this command's --out
                raise InputError("--out", exc.message, exc.field) from None
            raise
