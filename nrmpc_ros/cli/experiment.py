"""``nrmpc experiment noise-ei|outliers|gravity-noise``: the paper's section 4 Monte Carlo studies."""

from __future__ import annotations

from ..errors import InputError
from ..experiments.runner import default_workers
from ..experiments.sweeps import EXPERIMENTS, QUICK_RUNS, run_experiment
from .argtypes import positive_int, seed
from .common import flag_of


def float_list(text: str) -> tuple:
    """'0,0.1,inf' -> (0.0, 0.1, inf)."""
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise InputError("command line", f"expected comma-separated numbers, got {text!r}") from None


def register(sub):
    p = sub.add_parser(
        "experiment", help="Monte Carlo experiments of the paper's section 4 (CSV + PNG + markdown)",
        description="Runs a grid of seeded synthetic problems through the estimators and writes "
                    "<name>-<M>cam_runs.csv (one row per run and method), <name>-<M>cam_summary.csv (success rate, "
                    "mean/median errors over successful and over all runs), PNG plots and a markdown summary "
                    "into --out. Deterministic for a --seed (except run times).")
    p.add_argument("name", choices=sorted(EXPERIMENTS), help="noise-ei (Figs. 4/5/8), outliers (Figs. 6/9), "
                   "gravity-noise (Figs. 7/10)")
    p.add_argument("--out", default="experiments", help="output directory (default: ./experiments)")
    p.add_argument("--cameras", type=positive_int, default=4, help="number of cameras: 4 = cross, otherwise a ring "
                   "(default 4; the paper also uses 2)")
    p.add_argument("--rig", help="use this rig file instead of the simulated one (EI values then set every "
                   "bar that has a tip mass)")
    p.add_argument("--runs", type=positive_int, default=QUICK_RUNS,
                   help=f"runs per grid cell (default {QUICK_RUNS}, a quick look; the paper uses 1000)")
    p.add_argument("--seed", type=seed, default=0, help="base seed (default 0)")
    p.add_argument("--workers", type=positive_int, default=None, help="local worker processes (default: one per core)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the tasks on this Dask scheduler (tcp://host:8786) instead of local processes; "
                        "needs dask.distributed")
    p.add_argument("--methods", help="comma-separated subset of methods (default: the experiment's)")
    p.add_argument("--points", type=positive_int, help="correspondences per problem (default 1000)")
    p.add_argument("--noise", type=float_list, metavar="LIST", help="pixel-noise values (noise-ei), e.g. 0,0.1,0.2")
    p.add_argument("--ei", type=float_list, metavar="LIST", help="EI values (noise-ei), e.g. 0.1,1,10")
    p.add_argument("--outlier-levels", type=float_list, metavar="LIST", help="outlier fractions (outliers)")
    p.add_argument("--gravity-noise", type=float_list, metavar="LIST", help="gravity noise in px (gravity-noise)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run, field_flags={"num_points": "--points",
                                          **{axis: flag_of(dest) for dest, axis in _AXIS_FLAGS.items()}})


_AXIS_FLAGS = {"noise": "pixel_noise", "ei": "EI", "outlier_levels": "outlier_fraction",
               "gravity_noise": "gravity_noise_px"}


def _command(args, axes: dict, workers: int) -> str:
    """The command line that reproduces this run (for the markdown summary)."""
    parts = ["nrmpc experiment", args.name, f"--cameras {args.cameras}", f"--runs {args.runs}", f"--seed {args.seed}"]
    if args.rig:
        parts.append(f"--rig {args.rig}")
    if args.methods:
        parts.append(f"--methods {args.methods}")
    if args.points:
        parts.append(f"--points {args.points}")
    flags = {axis: flag for flag, axis in _AXIS_FLAGS.items()}
    for axis, values in axes.items():
        parts.append(f"{flag_of(flags[axis])} " + ",".join(f"{v:g}" for v in values))
    parts.append(f"--scheduler {args.scheduler}" if args.scheduler else f"--workers {workers}")
    return " ".join(parts)


def run(args) -> int:
    from ..core import load_rig

    exp = EXPERIMENTS[args.name]
    axes = dict(exp.axes)
    for flag, axis in _AXIS_FLAGS.items():
        value = getattr(args, flag)
        if value is None:
            continue
        if axis not in axes:
            raise InputError(flag_of(flag), f"is not an axis of {args.name} "
                             f"(its axes: {', '.join(axes)})")
        axes[axis] = value
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip()) if args.methods else None
    rig = load_rig(args.rig) if args.rig else None
    workers = args.workers if args.workers is not None else default_workers()
    res = run_experiment(args.name, args.out, cameras=args.cameras, runs=args.runs, seed=args.seed, workers=workers,
                         scheduler=args.scheduler, axes=axes, methods=methods, rig=rig, num_points=args.points,
                         progress=not args.no_progress, command=_command(args, axes, workers),
                         inputs={"--rig": args.rig})
    print(f"{args.name}: {len(res['rows'])} estimates in {res['wall_s']:.1f} s")
    for path in [*res["csv"], *res["images"], res["markdown"]]:
        print(f"  wrote {path}")
    return 0
