"""``nrmpc bench``: times and errors of the three methods and PoseLib's rigid pipeline on the same problems."""

from __future__ import annotations

import json

from ..core import METHODS
from ..errors import InputError
from .simulate import add_scenario_arguments, scenario_from_args


def register(sub):
    p = sub.add_parser(
        "bench", help="benchmark the estimators against poselib.estimate_generalized_relative_pose",
        description="Runs 6pt-nonbending, 6pt-bending, 4pt-bending and PoseLib's rigid generalized relative pose "
                    "one after the other on the same seeded problems (default: the paper's nominal case, 4 "
                    "cameras, N=1000, EI 0.1, 0.1 px, 5% outliers, gravity noise 0.01 px) and prints per method: "
                    "median time, time ratio to PoseLib, success rate, median errors and error/CRLB.")
    p.add_argument("--runs", type=int, default=100, help="problems (default 100)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods (default: all three)")
    p.add_argument("--no-poselib", action="store_true", help="leave PoseLib out (time ratios are then absent)")
    p.add_argument("--poselib-threshold", type=float, default=None,
                   help="PoseLib max_epipolar_error (px; default: the estimators' loose threshold, 20 px, since "
                        "the rigid model must tolerate the bending)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_scenario_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..experiments.bench import format_table, run_bench

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise InputError("--methods", f"unknown method {bad[0] if bad else ''!r} (choose from {', '.join(METHODS)})")
    if args.poselib_threshold is not None and not args.poselib_threshold > 0:
        raise InputError("--poselib-threshold", "must be > 0 (px)")
    sc, rig, _ = scenario_from_args(args)
    if "4pt-bending" in methods and sc.gravity_frame == "none":
        raise InputError("--gravity-frame", "4pt-bending needs gravity measurements; drop it from --methods")
    res = run_bench(args.runs, args.seed, sc, rig, methods, poselib=not args.no_poselib,
                    poselib_threshold_px=args.poselib_threshold, progress=not (args.no_progress or args.json))
    if args.json:
        print(json.dumps(res, default=str))
    else:
        print(format_table(res))
    return 0
