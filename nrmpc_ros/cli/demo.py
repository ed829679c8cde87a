"""``nrmpc demo``: one synthetic two-view problem through all three estimators, as a table."""

from __future__ import annotations

import numpy as np

from ..core import METHODS, estimate, pose_errors
from ..sim.synthetic import RigSpec, Scenario, default_layout, make_problem
from .argtypes import positive_int, seed


def register(sub):
    p = sub.add_parser("demo", help="run the three estimators on a synthetic problem (paper set-up) and print errors",
                       description="Draws seeded problems of the paper's nominal case (4 cameras on a cross, "
                                   "EI 0.1, 0.1 px noise, 5%% outliers) and prints errors and times per method.")
    p.add_argument("--runs", type=positive_int, default=5, help="number of seeded problems (default 5)")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--EI", type=float, default=0.1, help="flexural rigidity of every bar (N m^2)")
    p.add_argument("--cameras", type=int, default=4)
    p.set_defaults(func=run)


def run(args) -> int:
    sc = Scenario(rig=RigSpec(num_cameras=args.cameras, layout=default_layout(args.cameras), EI=args.EI))
    rows = {m: [] for m in METHODS}
    for k in range(args.runs):
        pb = make_problem(sc, seed=args.seed + k)
        for m in METHODS:
            est = estimate(pb.rig, pb.matches, method=m, seed=args.seed + k)
            e = pose_errors(est.R, est.t, pb.R, pb.t, est.gravity, pb.gravity)
            rows[m].append((e["rotation"], e["translation"], e["gravity"], e["success"], est.time_s))
    print(f"{args.runs} problems, {args.cameras} cameras, EI {args.EI} N m^2 (median over runs)")
    print(f"{'method':<16}{'success':>9}{'rot [deg]':>12}{'t dir [deg]':>13}{'gravity [deg]':>15}{'time [ms]':>11}")
    for m, r in rows.items():
        a = np.array(r, dtype=float)
        grav = "-" if np.all(np.isnan(a[:, 2])) else f"{np.degrees(np.nanmedian(a[:, 2])):.4f}"
        print(f"{m:<16}{a[:, 3].mean():>9.0%}{np.degrees(np.median(a[:, 0])):>12.4f}"
              f"{np.degrees(np.median(a[:, 1])):>13.4f}{grav:>15}{1000 * np.median(a[:, 4]):>11.1f}")
    return 0
