"""``nrmpc observability``: Cramér-Rao bounds on rotation, translation direction and gravity (issue 3).

Fisher information of the angular residuals at the ground truth of seeded
synthetic geometries (points eliminated by Schur complement), averaged over
gravity directions and motions; see :mod:`nrmpc_ros.experiments.crlb`.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from .simulate import add_scenario_arguments, scenario_from_args


def register(sub):
    p = sub.add_parser(
        "observability", help="Cramér-Rao bounds on rotation, translation and gravity for a rig and noise level",
        description="Bounds (RMS and median angle an efficient estimator reaches, vision only, as in the paper's "
                    "refinement) averaged over --samples random gravity directions and motions. With --sweep-ei: "
                    "the gravity bound against EI (PNG + CSV in --out) and the EI beyond which gravity is not "
                    "observable to --accuracy-deg.")
    p.add_argument("--samples", type=int, default=30, help="geometries (gravity direction + motion) averaged "
                   "(default 30)")
    p.add_argument("--seed", type=int, default=0, help="seed of the geometries (default 0)")
    p.add_argument("--gravity-prior-sigma", type=float, default=math.inf,
                   help="add measured gravity in both views with this angular std (rad), as 4pt-bending's prior "
                        "(default inf: vision only)")
    p.add_argument("--sweep-ei", action="store_true", help="sweep EI and plot the gravity bound against it")
    p.add_argument("--ei-range", default="0.01,1000,21", metavar="MIN,MAX,STEPS",
                   help="log-spaced EI values of the sweep (default 0.01,1000,21)")
    p.add_argument("--accuracy-deg", type=float, default=1.0,
                   help="required gravity accuracy (RMS bound, degrees) for the EI limit (default 1)")
    p.add_argument("--out", default=".", help="directory for the sweep's PNG and CSV (default: .)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_scenario_arguments(p, with_gravity=False)
    p.set_defaults(func=run)


def _ei_values(text: str) -> np.ndarray:
    try:
        lo, hi, n = text.split(",")
        lo, hi, n = float(lo), float(hi), int(n)
    except ValueError:
        raise InputError("--ei-range", f"expected MIN,MAX,STEPS, got {text!r}") from None
    if not (0 < lo < hi < math.inf) or n < 2:
        raise InputError("--ei-range", "needs 0 < MIN < MAX < inf and STEPS >= 2")
    return np.geomspace(lo, hi, n)


def run(args) -> int:
    from ..experiments.observability import ei_limit, observability, plot_sweep, sweep_ei
    from ..sim.synthetic import make_rig

    sc, rig, _ = scenario_from_args(args)
    if sc.pixel_noise <= 0:
        raise InputError("--noise", "must be > 0 for a Cramér-Rao bound")
    if args.samples < 1:
        raise InputError("--samples", f"must be >= 1, got {args.samples}")
    if not args.gravity_prior_sigma > 0:
        raise InputError("--gravity-prior-sigma", "must be > 0 (rad; inf = no prior)")
    the_rig = rig if rig is not None else make_rig(sc.rig)
    if not the_rig.is_flexible:
        note = "the rig has no flexible bar: gravity is unobservable from vision (bound = inf)"
    else:
        note = None
    res = observability(the_rig, sc, args.samples, args.seed, args.gravity_prior_sigma)
    out = {"rig": the_rig.source if rig is not None else "simulated", "cameras": the_rig.num_cameras,
           "pixel_noise": sc.pixel_noise, "points": sc.num_points, "outlier_fraction": sc.outlier_fraction,
           "samples": args.samples, "gravity_prior_sigma": _num(args.gravity_prior_sigma),
           "bounds_rad": {k: {s: _num(v) for s, v in d.items()} for k, d in res.items()}}
    if note:
        out["note"] = note
    if args.sweep_ei:
        if not the_rig.is_flexible and rig is not None and not any(c.mass > 0 for c in rig.cameras):
            raise InputError(rig.source, "no camera has a tip mass, so EI does not change anything", "bar")
        eis = _ei_values(args.ei_range)
        rows = sweep_ei(rig, sc, eis, args.samples, args.seed)
        acc = math.radians(args.accuracy_deg)
        limit = ei_limit(eis, [r["gravity_rms"] for r in rows], acc)
        outdir = Path(args.out)
        outdir.mkdir(parents=True, exist_ok=True)
        png, csv_path = outdir / "observability_ei.png", outdir / "observability_ei.csv"
        with open(csv_path, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows([{k: f"{v:.6g}" for k, v in r.items()} for r in rows])
        plot_sweep(rows, acc, limit, png, f"{the_rig.num_cameras} cameras, {sc.pixel_noise:g} px, "
                   f"{args.samples} geometries")
        out["sweep"] = {"accuracy_deg": args.accuracy_deg, "ei_limit": limit, "png": str(png), "csv": str(csv_path),
                        "rows": [{k: _num(v) for k, v in r.items()} for r in rows]}
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"Cramér-Rao bounds ({out['cameras']} cameras, {sc.pixel_noise:g} px, "
          f"{round(sc.num_points * (1 - sc.outlier_fraction))} inliers, {args.samples} geometries)")
    print(f"{'':12s} {'RMS (rad)':>11s} {'median (rad)':>13s} {'RMS (deg)':>10s}")
    for kind, d in res.items():
        print(f"{kind:12s} {d['rms']:11.3g} {d['median']:13.3g} {math.degrees(d['rms']):10.3g}")
    if note:
        print(note)
    if args.sweep_ei:
        sw = out["sweep"]
        lim = sw["ei_limit"]
        if lim is None:
            msg = f"gravity stays observable to {args.accuracy_deg:g} deg up to EI = {eis[-1]:g} N m^2 (end of sweep)"
        elif lim == 0.0:
            msg = f"gravity is not observable to {args.accuracy_deg:g} deg even at EI = {eis[0]:g} N m^2"
        else:
            msg = f"gravity is not observable to {args.accuracy_deg:g} deg (RMS bound) beyond EI = {lim:.3g} N m^2"
        print(msg)
        print(f"wrote {sw['png']} and {sw['csv']}")
    return 0


def _num(v):
    return v if v is None or math.isfinite(v) else str(v)
