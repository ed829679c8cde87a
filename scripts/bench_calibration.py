#!/usr/bin/env python3
"""Bar calibration on bags of every recording style with an IMU: each bar's EI recovered from a rig file whose
EI values are all twice the truth (docs/RESULTS.md).

    python scripts/bench_calibration.py [--out /tmp/nrmpc_bench_holds_vga] [--styles all] [--rigs all]
                                        [--factor 2.0] [--json results.json]

The bags are those of scripts/bench_holds.py (rendered there into --out when missing). For each bag the
holds and their IMU gravity are collected with the wrong rig (:func:`nrmpc_ros.frontend.replay.collect_sequences`,
as ``nrmpc calibrate-bars`` does), then :func:`nrmpc_ros.calibration.calibrate_sequences` estimates every
bar's compliance; the table gives per bag and bar the relative EI error and the error over the reported
standard deviation (|z| < 3 when the standard deviations cover the errors).

    python scripts/bench_calibration.py --dynamics DIR [DIR ...] [--json results.json]

Each DIR holds a rendered ``bag`` and the ``rig.yaml`` it was rendered with (scripts/bench_extrinsics.py
writes both; any make-bag bag with ``--save-rig`` renamed so works): every bar's natural frequency and damping
ratio identified from the ringing after the stops as ``nrmpc calibrate-bars`` does
(:func:`nrmpc_ros.calibration.identify_bar_dynamics` on the holds the pipeline measures, starting at the rig
file's frequency), against the rig file's truth, with the error over the reported std. Targets: frequency
within 3 %, damping within 20 %, |z| < 3.
"""

from __future__ import annotations

# isort: off
import nrmpc_ros.threads  # noqa: F401  (one BLAS thread, before numpy)
# isort: on
import argparse
import json
import sys
from pathlib import Path

import numpy as np
from bench_holds import _rigs, _styles, make_bags

from nrmpc_ros.calibration import calibrate_sequences, identify_bar_dynamics
from nrmpc_ros.core import load_rig
from nrmpc_ros.core.dynamics import bar_natural_frequencies
from nrmpc_ros.frontend.replay import collect_sequences


def calibrate_bag(path: Path, rig_file: Path, factor: float) -> dict:
    truth = load_rig(rig_file)
    wrong = truth.with_compliance(truth.compliance / factor)  # EI x factor
    stats = {}
    seqs = collect_sequences(path, wrong, warn=lambda m: None, stats=stats)
    cal = calibrate_sequences(wrong, seqs)
    k_true = truth.compliance
    rows = []
    for i, gi in enumerate(cal.groups):
        if gi < 0:
            continue
        k, s = float(cal.compliance[gi]), float(cal.std[gi])
        rows.append({"camera": truth.cameras[i].name, "ei_error": k_true[i] / k - 1.0,
                     "compliance_error": k / k_true[i] - 1.0, "std_rel": s / k_true[i],
                     "z": (k - k_true[i]) / s if s > 0 else float("nan"), "observable": bool(cal.observable[gi])})
    return {"holds": int(sum(s.tracks.num_views for s in seqs)), "sequences": len(seqs), "bars": rows}


def dynamics_of_bag(folder: Path) -> dict:
    """Every bar's identified frequency and damping against the rig file it was rendered with."""
    rig = load_rig(folder / "rig.yaml")
    holds: list = []
    collect_sequences(folder / "bag", rig, warn=lambda m: None, stats={}, holds=holds)
    f_true = bar_natural_frequencies(rig)
    rows = []
    for i, d in enumerate(identify_bar_dynamics(rig, holds)):
        if d is None:
            continue
        z_true = rig.cameras[i].damping
        rows.append({"camera": d.camera, "freq_hz": d.freq_hz, "freq_true_hz": float(f_true[i]),
                     "freq_error": d.freq_hz / f_true[i] - 1.0, "freq_z": (d.freq_hz - f_true[i]) / d.freq_std_hz,
                     "zeta": d.zeta, "zeta_true": z_true, "zeta_error": d.zeta / z_true - 1.0,
                     "zeta_z": (d.zeta - z_true) / d.zeta_std, "stops": d.num_stops})
    return {"bag": str(folder), "cameras": rig.num_cameras, "holds": len(holds), "bars": rows}


def main_dynamics(folders, json_out=None) -> int:
    results = []
    print("| bag | cameras | holds | bar | frequency (true) | error | z | damping (true) | error | z |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for folder in folders:
        r = dynamics_of_bag(Path(folder))
        results.append(r)
        for b in r["bars"]:
            print(f"| {Path(folder).name} | {r['cameras']} | {r['holds']} | {b['camera']} | {b['freq_hz']:.3f} "
                  f"({b['freq_true_hz']:.3f}) Hz | {100 * b['freq_error']:+.2f} % | {b['freq_z']:+.2f} | "
                  f"{b['zeta']:.4f} ({b['zeta_true']:g}) | {100 * b['zeta_error']:+.1f} % | {b['zeta_z']:+.2f} |",
                  flush=True)
    bars = [b for r in results for b in r["bars"]]
    if bars:
        worst = {k: max(abs(b[k]) for b in bars) for k in ("freq_error", "freq_z", "zeta_error", "zeta_z")}
        print(f"bars: {len(bars)}; largest frequency error {100 * worst['freq_error']:.2f} % (|z| "
              f"{worst['freq_z']:.2f}), largest damping error {100 * worst['zeta_error']:.1f} % (|z| "
              f"{worst['zeta_z']:.2f})")
    if json_out:
        Path(json_out).write_text(json.dumps(results, indent=1))
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="/tmp/nrmpc_bench_holds_vga", help="folder of the rendered bags (reused)")
    p.add_argument("--styles", default="all", help="comma-separated styles (styles without an IMU are skipped)")
    p.add_argument("--rigs", default="all", help="comma-separated rigs (default all: line2,fish3,cross4)")
    p.add_argument("--factor", type=float, default=2.0, help="the starting rig's EI is the truth times this")
    p.add_argument("--json", help="also write the results as JSON")
    p.add_argument("--dynamics", nargs="+", metavar="DIR", help="identify the bars' frequency and damping on "
                   "these folders (each a bag/ and its rig.yaml) instead")
    args = p.parse_args(argv)
    if args.dynamics:
        return main_dynamics(args.dynamics, args.json)
    rigs, styles = _rigs(), _styles()
    if args.rigs != "all":
        rigs = {k: rigs[k] for k in args.rigs.split(",")}
    styles = {k: v for k, v in styles.items() if (args.styles == "all" or k in args.styles.split(","))
              and v[1].get("imu", True)}
    bags = make_bags(Path(args.out), rigs, styles, 1)
    results = []
    print("| bag | holds | bar | EI error | std (rel.) | z |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, path, rig_file, sname, rname, _ in bags:
        r = calibrate_bag(path, rig_file, args.factor)
        r.update(bag=name, style=sname, rig=rname)
        results.append(r)
        for b in r["bars"]:
            print(f"| {name} | {r['holds']} | {b['camera']} | {100 * b['ei_error']:+.1f} % | "
                  f"{100 * b['std_rel']:.1f} % | {b['z']:+.2f} |", flush=True)
    errs = np.array([abs(b["ei_error"]) for r in results for b in r["bars"]])
    zs = np.array([abs(b["z"]) for r in results for b in r["bars"]])
    print(f"bars: {len(errs)}; largest EI error {100 * errs.max():.1f} %, median {100 * np.median(errs):.1f} %; "
          f"|z| median {np.median(zs):.2f}, largest {zs.max():.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
