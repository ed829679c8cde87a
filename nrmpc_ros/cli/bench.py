"""``nrmpc bench``: times and errors of the three methods and PoseLib's rigid pipeline on the same problems.

With ``--sequence``: the joint estimation over sequences of holds against the
pairwise route on four simulated rigs (:mod:`nrmpc_ros.experiments.sequence_bench`).
"""

from __future__ import annotations

import json

from ..core import METHODS
from ..errors import InputError
from .common import SCENARIO_FLAGS, add_scenario_arguments, flag_of, jsonable, scenario_from_args

# flags of the two-view benchmark only, and of the sequence benchmark only (dest names)
_PAIR_ONLY = ("no_poselib", "poselib_threshold", "scenario", "rig", *SCENARIO_FLAGS)
_SEQUENCE_ONLY = ("rigs", "workers")


def register(sub):
    p = sub.add_parser(
        "bench", help="benchmark the estimators against poselib.estimate_generalized_relative_pose",
        description="Runs 6pt-nonbending, 6pt-bending, 4pt-bending and PoseLib's rigid generalized relative pose "
                    "one after the other on the same seeded problems (default: the paper's nominal case, 4 "
                    "cameras, N=1000, EI 0.1, 0.1 px, 5% outliers, gravity noise 0.01 px) and prints per method: "
                    "median time, time ratio to PoseLib, success rate, median errors and error/CRLB.")
    p.add_argument("--runs", type=int, help="problems (default 100), or with --sequence sequences per rig "
                   "(default 20)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--methods", help="comma-separated methods (default: all three; with --sequence "
                   "6pt-bending,4pt-bending)")
    p.add_argument("--no-poselib", action="store_true", default=None,
                   help="leave PoseLib out (time ratios are then absent)")
    p.add_argument("--poselib-threshold", type=float, default=None,
                   help="PoseLib max_epipolar_error (px; default: the estimators' loose threshold, 20 px, since "
                        "the rigid model must tolerate the bending)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_scenario_arguments(p)
    g = p.add_argument_group(
        "sequences of holds", "--sequence: on simulated sequences of 10 holds (0.3 px, 5 % outliers, measured "
        "gravity 0.3 deg) of each rig, the joint estimate of every hold's gravity (nrmpc solve-sequence) against "
        "the consecutive pairs on their own (nrmpc solve), both beside their Cramér-Rao bounds; prints a "
        "markdown table (the scenario flags above do not apply).")
    g.add_argument("--sequence", action="store_true", help="benchmark the joint estimation over sequences of holds")
    g.add_argument("--rigs", help="comma-separated rigs (default: all of line2-ei1, ring3-ei1.3, cross4-ei1, "
                   "cross4-ei0.1)")
    g.add_argument("--workers", type=int, help="worker processes, one BLAS thread each, so the numbers do not "
                   "depend on how many (default: one per core)")
    p.set_defaults(func=run)


def _names(text: str | None, default) -> tuple:
    """Comma-separated names, or the defaults when the flag is not given."""
    if text is None:
        return tuple(default)
    return tuple(m.strip() for m in text.split(",") if m.strip())


def run_sequence(args) -> int:
    """``--sequence``: the sequence benchmark."""
    from ..experiments.runner import default_workers
    from ..experiments.sequence_bench import METHODS as SEQUENCE_METHODS
    from ..experiments.sequence_bench import RIGS, format_sequence_table, run_sequence_bench

    for dest in _PAIR_ONLY:
        if getattr(args, dest, None) is not None:
            raise InputError(flag_of(dest), "applies to the two-view benchmark only, not with --sequence")
    rigs = _names(args.rigs, RIGS)
    res = run_sequence_bench(20 if args.runs is None else args.runs, args.seed, rigs,
                             _names(args.methods, SEQUENCE_METHODS),
                             default_workers() if args.workers is None else args.workers,
                             progress=not (args.no_progress or args.json))
    if args.json:
        print(json.dumps(jsonable(res), allow_nan=False))  # an unbounded bound is "inf"
    else:
        print(format_sequence_table(res))
    return 0


def run(args) -> int:
    from ..experiments.bench import format_table, run_bench

    if args.sequence:
        return run_sequence(args)
    for dest in _SEQUENCE_ONLY:
        if getattr(args, dest, None) is not None:
            raise InputError(flag_of(dest), "applies to the sequence benchmark only (add --sequence)")
    methods = _names(args.methods, METHODS)
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise InputError("--methods", f"unknown method {bad[0] if bad else ''!r} (choose from {', '.join(METHODS)})")
    if args.poselib_threshold is not None and not args.poselib_threshold > 0:
        raise InputError("--poselib-threshold", "must be > 0 (px)")
    sc, rig, _ = scenario_from_args(args)
    if "4pt-bending" in methods and sc.gravity_frame == "none":
        raise InputError("--gravity-frame", "4pt-bending needs gravity measurements; drop it from --methods")
    res = run_bench(100 if args.runs is None else args.runs, args.seed, sc, rig, methods, poselib=not args.no_poselib,
                    poselib_threshold_px=args.poselib_threshold, progress=not (args.no_progress or args.json))
    if args.json:
        print(json.dumps(res, default=str))
    else:
        print(format_table(res))
    return 0
