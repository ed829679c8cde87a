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

from nrmpc_ros.calibration import calibrate_sequences
from nrmpc_ros.core import load_rig
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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="/tmp/nrmpc_bench_holds_vga", help="folder of the rendered bags (reused)")
    p.add_argument("--styles", default="all", help="comma-separated styles (styles without an IMU are skipped)")
    p.add_argument("--rigs", default="all", help="comma-separated rigs (default all: line2,fish3,cross4)")
    p.add_argument("--factor", type=float, default=2.0, help="the starting rig's EI is the truth times this")
    p.add_argument("--json", help="also write the results as JSON")
    args = p.parse_args(argv)
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
