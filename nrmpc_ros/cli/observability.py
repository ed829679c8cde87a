"""``nrmpc observability``: Cramér-Rao bounds on rotation, translation direction and gravity.

Fisher information of the angular residuals at the ground truth of seeded
synthetic geometries (points eliminated by Schur complement), averaged over
gravity directions and motions; see :mod:`nrmpc_ros.experiments.crlb`.
With ``--sequence``: the bound on each hold's gravity for a recording of K
holds, one gravity estimated jointly over all of them beside each
consecutive pair on its own (docs/CONVENTIONS.md, "Sequences"), vision only
and with an accelerometer prior.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..safeio import atomic_write, check_output
from .argtypes import seed
from .common import (
    add_scenario_arguments,
    add_sequence_arguments,
    check_mode_flags,
    scenario_from_args,
    sequence_scenario_from_args,
)


def register(sub):
    p = sub.add_parser(
        "observability", help="Cramér-Rao bounds on rotation, translation and gravity for a rig and noise level",
        description="Bounds (RMS and median angle an efficient estimator reaches, vision only, as in the paper's "
                    "refinement) averaged over --samples random gravity directions and motions. With --sweep-ei: "
                    "the gravity bound against EI (PNG + CSV in --out) and the EI beyond which gravity is not "
                    "observable to --accuracy-deg.")
    p.add_argument("--samples", type=int, default=30, help="geometries (gravity direction + motion) averaged "
                   "(default 30)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the geometries (default 0)")
    p.add_argument("--gravity-prior-sigma", type=float, default=None,
                   help="add measured gravity in both views with this angular std (rad), as 4pt-bending's prior "
                        "(default inf: vision only; with --sequence the scenario's gravity noise, 0.3 deg, and the "
                        "bounds are shown with and without it)")
    p.add_argument("--sweep-ei", action="store_true", help="sweep EI and plot the gravity bound against it")
    p.add_argument("--ei-range", default="0.01,1000,21", metavar="MIN,MAX,STEPS",
                   help="log-spaced EI values of the sweep (default 0.01,1000,21)")
    p.add_argument("--accuracy-deg", type=float, default=1.0,
                   help="required gravity accuracy (RMS bound, degrees) for the EI limit (default 1)")
    p.add_argument("--out", default=".", help="directory for the sweep's PNG and CSV (default: .; each written "
                   "atomically)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_scenario_arguments(p, with_gravity=False)
    add_sequence_arguments(p, sequence_help="bounds of each hold's gravity over a recording of K holds (joint "
                           "and pairwise) instead of two-view bounds", views_type=_holds,
                           views_help="holds K of the recording (default 10), or K1,K2,... to show how the "
                                      "joint bound falls with K (the first K holds of the same sequences)")
    p.set_defaults(func=run)


def _holds(text: str) -> list[int]:
    """--views: one K or a comma-separated list, each an integer >= 2."""
    try:
        ks = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected K or K1,K2,... (integers), got {text!r}") from None
    if not ks or min(ks) < 2:
        raise argparse.ArgumentTypeError(f"every number of holds must be an integer >= 2, got {text!r}")
    return sorted(set(ks))


def _ei_values(text: str) -> np.ndarray:
    try:
        lo, hi, n = text.split(",")
        lo, hi, n = float(lo), float(hi), int(n)
    except ValueError:
        raise InputError("--ei-range", f"expected MIN,MAX,STEPS, got {text!r}") from None
    if not (0 < lo < hi < math.inf) or n < 2:
        raise InputError("--ei-range", "needs 0 < MIN < MAX < inf and STEPS >= 2")
    return np.geomspace(lo, hi, n)


def _check_common(args, pixel_noise: float) -> None:
    if pixel_noise <= 0:
        raise InputError("--noise", "must be > 0 for a Cramér-Rao bound")
    if args.samples < 1:
        raise InputError("--samples", f"must be >= 1, got {args.samples}")
    if args.gravity_prior_sigma is not None and not args.gravity_prior_sigma > 0:
        raise InputError("--gravity-prior-sigma", "must be > 0 (rad; inf = no prior)")


def run(args) -> int:
    from ..experiments.observability import ei_limit, observability, plot_sweep, sweep_ei
    from ..sim.synthetic import make_rig

    check_mode_flags(args, args.sequence)
    if args.sequence:
        return run_sequence(args)
    sc, rig, extras = scenario_from_args(args)
    _check_common(args, sc.pixel_noise)
    outdir = Path(args.out)
    png, csv_path = outdir / "observability_ei.png", outdir / "observability_ei.csv"
    if args.sweep_ei:
        inputs = {"--rig": args.rig, "--scenario": args.scenario, "rig_file of --scenario": extras.get("rig_file")}
        check_output(outdir, inputs, "--out", directory=True)
        for path in (png, csv_path):
            check_output(path, inputs, "--out")
    if args.gravity_prior_sigma is None:
        args.gravity_prior_sigma = math.inf
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
        with atomic_write(csv_path, newline="", flag="--out") as fh:
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


def run_sequence(args) -> int:
    """``--sequence``: joint and pairwise bounds of each hold's gravity, with and without the prior."""
    from ..experiments.observability import sequence_observability
    from ..sim.synthetic import make_rig

    if args.sweep_ei:
        raise InputError("--sweep-ei", "applies to two-view bounds only, not with --sequence")
    holds = args.views
    sc, rig, _ = sequence_scenario_from_args(argparse.Namespace(**{**vars(args), "views": holds and max(holds)}))
    _check_common(args, sc.pixel_noise)
    prior = args.gravity_prior_sigma
    if prior is None:
        prior = math.radians(sc.gravity_noise_deg) if sc.gravity_measured and sc.gravity_noise_deg > 0 else math.inf
    the_rig = rig if rig is not None else make_rig(sc.rig)
    rows = sequence_observability(the_rig, sc, args.samples, args.seed, prior, holds)
    out = {"rig": the_rig.source if rig is not None else "simulated", "cameras": the_rig.num_cameras,
           "pixel_noise": sc.pixel_noise, "views": sc.num_views, "tracks_per_camera": sc.tracks_per_camera,
           "outlier_fraction": sc.outlier_fraction, "samples": args.samples, "gravity_prior_sigma": _num(prior),
           "bounds_rad": [{k: _num(v) for k, v in r.items()} for r in rows]}
    if not the_rig.is_flexible:
        out["note"] = "the rig has no flexible bar: gravity is unobservable from vision (bound = inf)"
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"Cramér-Rao bounds on each hold's gravity direction ({out['cameras']} cameras, {sc.pixel_noise:g} px, "
          f"{sc.tracks_per_camera} tracks per camera, {args.samples} sequences; median over holds and sequences, "
          "deg)")
    with_prior = math.isfinite(prior)
    head = f"{'holds':>5s} {'joint':>9s} {'pairwise':>9s} {'pair/joint':>10s}"
    if with_prior:
        head += f" {'joint+prior':>12s} {'pairwise+prior':>15s}"
    print(head)
    for r in rows:
        line = (f"{r['views']:5d} {_deg(r['joint']):>9s} {_deg(r['pairwise']):>9s} "
                f"{_ratio(r['pairwise'], r['joint']):>10s}")
        if with_prior:
            line += f" {_deg(r['joint_prior']):>12s} {_deg(r['pairwise_prior']):>15s}"
        print(line)
    if with_prior:
        print(f"prior: measured gravity in every hold with angular std {math.degrees(prior):.3g} deg")
    if "note" in out:
        print(out["note"])
    return 0


def _deg(rad: float) -> str:
    return f"{math.degrees(rad):.3g}" if math.isfinite(rad) else "inf"


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}" if math.isfinite(a) and math.isfinite(b) and b > 0 else "-"
