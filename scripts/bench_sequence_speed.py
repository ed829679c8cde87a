#!/usr/bin/env python3
"""Speed of the joint estimation over a sequence of holds against the pairwise route, on one core.

    python scripts/bench_sequence_speed.py [--seeds 5] [--holds 10] [--window 10] [--stream-holds 14]
        [--methods 6pt-bending,4pt-bending] [--cameras 3] [--tracks 120] [--json OUT]

On simulated sequences (:mod:`nrmpc_ros.sim.sequence`: a ring of ``--cameras`` cameras, ``--tracks`` landmarks
per camera and hold, 0.3 px image noise, 5 % outliers, measured gravity with 0.3 deg noise, as ``nrmpc bench
--sequence``), per method and seed:

- **batch**: :func:`nrmpc_ros.core.sequence.estimate_sequence` on the ``--holds`` holds;
- **update**: :class:`nrmpc_ros.core.incremental.IncrementalSequence` (window ``--window``) fed the holds of a
  longer sequence (``--stream-holds``) one by one, as the node does; the time of each ``add_view`` once the
  window is full;
- **pairs**: the two-view estimator :func:`nrmpc_ros.core.estimate` on each consecutive pair of the
  ``--holds`` holds (the pairwise route of ``nrmpc bench --sequence``), in total and per pair.

Times are CPU seconds of this process (``time.process_time``, BLAS and OpenMP limited to one thread), medians
over the seeds; the ratios are batch / pairs (whole sequence) and update / one pair. The median per-hold
gravity error of the batch solve and of the last update is printed beside them, as a check that speed did
not cost accuracy (``nrmpc bench --sequence`` is the accuracy benchmark).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from nrmpc_ros.core import EstimatorOptions, estimate  # noqa: E402
from nrmpc_ros.core.incremental import IncrementalSequence, ViewEstimate  # noqa: E402
from nrmpc_ros.core.sequence import SequenceOptions, estimate_sequence  # noqa: E402
from nrmpc_ros.core.so3 import angle_between  # noqa: E402
from nrmpc_ros.sim.sequence import SequenceScenario, make_sequence  # noqa: E402
from nrmpc_ros.sim.synthetic import RigSpec  # noqa: E402

METHODS = ("6pt-bending", "4pt-bending")


def scenario(cameras: int, tracks: int, holds: int) -> SequenceScenario:
    """The benchmark's sequences: a ring of cameras (two on a line), 0.3 px, 5 % outliers."""
    spec = RigSpec(num_cameras=cameras, layout="ring", EI=1.3) if cameras >= 3 else \
        RigSpec(num_cameras=cameras, layout="line", EI=1.0, mass=0.15, bar_length=0.3)
    return SequenceScenario(rig=spec, num_views=holds, tracks_per_camera=tracks, pixel_noise=0.3,
                            outlier_fraction=0.05)


def _median_error_deg(gravity, truth) -> float:
    if gravity is None:
        return math.nan
    return float(np.degrees(np.median([angle_between(g, t) for g, t in zip(gravity, truth)])))


def _timed(fn, *args, **kwargs):
    t0 = time.process_time()
    out = fn(*args, **kwargs)
    return out, time.process_time() - t0


def run_batch(problem, method: str, seed: int, opts: SequenceOptions) -> dict:
    est, dt = _timed(estimate_sequence, problem.rig, problem.tracks, method, seed=seed, options=opts)
    return {"time_s": dt, "error_deg": _median_error_deg(est.gravity if est.success else None, problem.gravity)}


def run_pairs(problem, method: str, seed: int, opts) -> dict:
    tracks = problem.tracks
    total = 0.0
    for k in range(1, tracks.num_views):
        _, dt = _timed(estimate, problem.rig, tracks.pair(k - 1, k), method, seed=seed + k, options=opts)
        total += dt
    return {"time_s": total, "pair_s": total / (tracks.num_views - 1)}


def run_updates(problem, method: str, seed: int, opts: SequenceOptions, window: int, sigma: float) -> dict:
    """Per-hold update times (s) once the window is full, and the error of the last hold's gravity (deg)."""
    tr = problem.tracks
    seq = IncrementalSequence(problem.rig, method, opts, window=window, seed=seed)
    times, last = [], None
    for k in range(tr.num_views):
        m = tr.view == k
        g = None if tr.g_meas is None else tr.g_meas[k]
        out, dt = _timed(seq.add_view, tr.cam[m], tr.track[m], tr.f[m], g, sigma)
        if isinstance(out, ViewEstimate):
            last = out
            if out.window >= window:
                times.append(dt)
    err = math.nan
    if last is not None and last.gravity is not None:
        err = math.degrees(float(angle_between(last.gravity, problem.gravity[last.view])))
    return {"update_s": times, "error_deg": err}


def _med(values) -> float:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if len(v) else math.nan


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=5, help="seeded sequences per method (default 5)")
    p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--holds", type=int, default=10, help="holds of the batch solve and the pairs (default 10)")
    p.add_argument("--window", type=int, default=10, help="window of the incremental update (default 10)")
    p.add_argument("--stream-holds", type=int, default=14,
                   help="holds fed to the incremental update; those after the window fills are timed (default 14)")
    p.add_argument("--cameras", type=int, default=3, help="cameras of the rig (default 3)")
    p.add_argument("--tracks", type=int, default=120, help="landmarks per camera and hold (default 120)")
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    p.add_argument("--no-updates", action="store_true", help="skip the incremental updates")
    p.add_argument("--json", help="also write the results as JSON")
    args = p.parse_args(argv)
    if args.stream_holds <= args.window and not args.no_updates:
        p.error("--stream-holds must exceed --window (the update is timed once the window is full)")
    methods = args.methods.split(",")
    sc_batch = scenario(args.cameras, args.tracks, args.holds)
    sc_stream = scenario(args.cameras, args.tracks, args.stream_holds)
    prior = math.radians(sc_batch.gravity_noise_deg)
    est_opts = EstimatorOptions(gravity_prior_sigma=prior)
    seq_opts = SequenceOptions(estimator=est_opts)
    seeds = range(args.seed, args.seed + args.seeds)
    rows = {m: {"batch_s": [], "pairs_s": [], "pair_s": [], "update_s": [], "batch_error_deg": [],
                "update_error_deg": []} for m in methods}
    bar = tqdm(total=len(methods) * args.seeds, desc="sequence speed", unit="sequence", dynamic_ncols=True,
               disable=not sys.stderr.isatty())
    for seed in seeds:
        batch_problem = make_sequence(sc_batch, seed=seed)
        stream_problem = None if args.no_updates else make_sequence(sc_stream, seed=seed)
        for m in methods:
            r = rows[m]
            b = run_batch(batch_problem, m, seed, seq_opts)
            pr = run_pairs(batch_problem, m, seed, est_opts)
            r["batch_s"].append(b["time_s"])
            r["batch_error_deg"].append(b["error_deg"])
            r["pairs_s"].append(pr["time_s"])
            r["pair_s"].append(pr["pair_s"])
            if stream_problem is not None:
                u = run_updates(stream_problem, m, seed, seq_opts, args.window, prior)
                r["update_s"].extend(u["update_s"])
                r["update_error_deg"].append(u["error_deg"])
            bar.update(1)
    bar.close()
    summary = {}
    print(f"| method | batch s ({args.holds} holds) | pairs s ({args.holds - 1} pairs) | batch / pairs | "
          f"update ms (window {args.window}) | max update ms | one pair ms | update / pair | "
          "batch err (deg) | update err (deg) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for m in methods:
        r = rows[m]
        s = {"batch_s": _med(r["batch_s"]), "pairs_s": _med(r["pairs_s"]), "pair_s": _med(r["pair_s"]),
             "update_s": _med(r["update_s"]), "max_update_s": float(np.max(r["update_s"])) if r["update_s"]
             else math.nan, "batch_error_deg": _med(r["batch_error_deg"]),
             "update_error_deg": _med(r["update_error_deg"])}
        s["batch_over_pairs"] = _med(np.divide(r["batch_s"], r["pairs_s"]))
        s["update_over_pair"] = s["update_s"] / s["pair_s"]
        summary[m] = s
        print(f"| {m} | {s['batch_s']:.3f} | {s['pairs_s']:.3f} | {s['batch_over_pairs']:.2f} | "
              f"{1e3 * s['update_s']:.0f} | {1e3 * s['max_update_s']:.0f} | {1e3 * s['pair_s']:.0f} | "
              f"{s['update_over_pair']:.2f} | {s['batch_error_deg']:.3f} | {s['update_error_deg']:.3f} |")
    print(f"\nCPU seconds, medians over {args.seeds} seeds ({args.cameras} cameras, {args.tracks} tracks per "
          f"camera and hold); update: each hold after the window of {args.window} filled, of {args.stream_holds}.")
    if args.json:
        Path(args.json).write_text(json.dumps({"args": vars(args), "summary": summary, "runs": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
