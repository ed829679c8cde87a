#!/usr/bin/env python3
"""The pipeline on bags of every recording style and rig: coverage, accuracy, settling, noise (docs/RESULTS.md).

    python scripts/bench_holds.py [--out /tmp/nrmpc_bench_holds] [--styles all] [--rigs all] [--seeds 1]
                                  [--methods auto,6pt-bending] [--json results.json]

Bags are rendered once into --out (reused when they exist; delete the folder to re-render) with
:func:`nrmpc_ros.render.bagmaker.make_bag`: for each rig (two cameras on one straight bar, three cameras of
which one fisheye, the four-camera cross; stiff-enough bars to settle within the holds) and each recording
style (snapshots with and without IMU; a 10 Hz stream with smooth moves; a stream with abrupt moves, ringing
bars (damping 0.03), +-8 ms camera stamp jitter and 2 % frame drops; JPEG-compressed images). Every bag is
replayed with each method through the same loop as ``nrmpc replay``; the table gives, per bag and method, the
share of holds after the first with an estimate, the estimates outside every ground-truth hold, the median
gravity error against ground truth of the published estimates and of the batch solution, the bag's own
IMU-only gravity error, the relative rotation error, the median settling time found against the one the bars'
frequency and damping imply, and the per-hold track noise of one frame against the averaged one.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.core import load_rig, save_rig
from nrmpc_ros.core.dynamics import bar_natural_frequencies, ringing_decay_time
from nrmpc_ros.core.rig import Camera, Rig
from nrmpc_ros.frontend.evaluation import batch_rows, evaluate, read_reference, row_from_estimate
from nrmpc_ros.frontend.pipeline import Pipeline, PipelineConfig
from nrmpc_ros.frontend.replay import replay_bag, resolve_imu_topic
from nrmpc_ros.render.bagmaker import BagOptions, make_bag
from nrmpc_ros.render.sequence import MotionOptions
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

BAR = {"EI": 0.5, "mass": 0.1, "bar_length": 0.4}  # 2.4 Hz, 9 deg of tip rotation under a full transverse load
RESOLUTION = (640, 480)
FOCAL = 470.0


def _rigs() -> dict:
    line2 = make_rig(RigSpec(num_cameras=2, layout="line", focal=FOCAL, resolution=RESOLUTION, **BAR))
    ring3 = make_rig(RigSpec(num_cameras=3, layout="ring", focal=FOCAL, resolution=RESOLUTION, **BAR))
    c = ring3.cameras[2]
    fish = Camera(name=c.name, model="equidistant", intrinsics=(300.0, 300.0, 319.5, 239.5),
                  distortion=(0.02, -0.01, 0.003, -0.001), resolution=RESOLUTION, position=c.position,
                  rotation=c.rotation, mass=c.mass, EI=c.EI, image_topic=c.image_topic, info_topic=c.info_topic)
    fish3 = replace(ring3, cameras=ring3.cameras[:2] + (fish,), source="<3 cameras, one fisheye>")
    cross4 = make_rig(RigSpec(num_cameras=4, layout="cross", focal=FOCAL, resolution=RESOLUTION, **BAR))
    return {"line2": line2, "fish3": fish3, "cross4": cross4}


def _styles() -> dict:
    """Recording style -> (MotionOptions kwargs, BagOptions kwargs)."""
    base = {"views": 6, "hold_seconds": 2.5, "min_move_seconds": 1.0}
    return {
        "snapshot-imu": ({**base, "capture": "snapshot"}, {}),
        "snapshot-noimu": ({**base, "capture": "snapshot"}, {"imu": False}),
        "stream-smooth": ({**base, "hold_seconds": 3.0, "capture": "stream", "rate": 10.0,
                           "move_profile": "min-jerk"}, {}),
        "stream-ringing": ({**base, "hold_seconds": 5.0, "capture": "stream", "rate": 10.0,
                            "move_profile": "trapezoid"}, {"damping": 0.03, "jitter_ms": 8.0, "drop_rate": 0.02}),
        "compressed": ({**base, "hold_seconds": 3.0, "capture": "stream", "rate": 10.0}, {"encoding": "jpeg"}),
    }


def make_bags(out: Path, rigs: dict, styles: dict, seeds: int) -> list:
    """(name, bag dir, rig file, style, rig name, make_bag summary or None) of every bag, rendered if missing."""
    out.mkdir(parents=True, exist_ok=True)
    bags = []
    for rname, rig in rigs.items():
        rig_file = out / f"{rname}.yaml"
        if not rig_file.exists():
            save_rig(rig, rig_file, header="rig of scripts/bench_holds.py")
        for sname, (mo, bo) in styles.items():
            for seed in range(seeds):
                name = f"{rname}-{sname}-{seed}"
                path = out / name
                summary = None
                if not path.exists():
                    t0 = time.perf_counter()
                    bag_rig = rig if bo.get("imu", True) else replace(rig, imu=None)
                    summary = make_bag(bag_rig, path, BagOptions(motion=MotionOptions(**mo), seed=seed, **bo),
                                       progress=False)
                    print(f"rendered {name} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
                bags.append((name, path, rig_file, sname, rname, summary))
    return bags


def implied_settle_s(rig: Rig, damping: float | None) -> float:
    """Time for the slowest bar's ringing to fall to 1e-3 of its start (nan without ringing)."""
    if damping is None:
        return math.nan
    f = bar_natural_frequencies(rig)
    f = f[np.isfinite(f)]
    return float(ringing_decay_time(float(f.min()), damping)) if len(f) else math.nan


def run_bag(path: Path, rig_file: Path, method: str) -> dict:
    rig = load_rig(rig_file)
    t0 = time.perf_counter()
    with BagReader(path) as bag:
        imu_topic = resolve_imu_topic(bag, rig, warn=lambda m: None)
        pipe = Pipeline(rig, PipelineConfig(), method=method)
        rows = [row_from_estimate(e) for es in replay_bag(bag, rig, pipe, imu_topic, warn=lambda m: None)
                for e in es]
        ref = read_reference(bag, imu_topic)
    wall = time.perf_counter() - t0
    ev = evaluate(rows, ref, rig)
    batch = batch_rows(pipe.batch(), method)
    evb = evaluate(batch, ref, rig)
    st = pipe.stats.as_dict()
    g = ev.stats("gravity_vs_gt_deg")
    return {"estimates": len(rows), "holds_gt": ev.holds, "coverage": ev.coverage, "outside": ev.outside_holds,
            "gravity_deg": g["median"], "gravity_mean_deg": g["mean"],
            "batch_gravity_deg": evb.stats("gravity_vs_gt_deg")["median"],
            "imu_gravity_deg": ev.stats("imu_vs_gt_deg")["median"],
            "rotation_deg": ev.stats("rotation_deg")["median"], "settle_s": st["median_settle_s"],
            "noise_px": st["median_noise_px"], "averaged_noise_px": st["median_averaged_noise_px"],
            "methods": st["methods"], "dropped": st["dropped"], "wall_s": wall, "ringing_holds": st["ringing_holds"],
            "hold_ms": float(np.median([r.time_ms for r in rows])) if rows else math.nan}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="/tmp/nrmpc_bench_holds_vga", help="folder of the rendered bags (reused)")
    p.add_argument("--styles", default="all", help="comma-separated styles (default all: " +
                   ",".join(_styles()) + ")")
    p.add_argument("--rigs", default="all", help="comma-separated rigs (default all: line2,fish3,cross4)")
    p.add_argument("--seeds", type=int, default=1, help="bags per style and rig (default 1)")
    p.add_argument("--methods", default="auto,6pt-bending", help="comma-separated methods")
    p.add_argument("--json", help="also write the results as JSON")
    args = p.parse_args(argv)
    rigs, styles = _rigs(), _styles()
    if args.rigs != "all":
        rigs = {k: rigs[k] for k in args.rigs.split(",")}
    if args.styles != "all":
        styles = {k: styles[k] for k in args.styles.split(",")}
    bags = make_bags(Path(args.out), rigs, styles, args.seeds)
    results = []
    print("| bag | method | coverage | outside | gravity (deg) | batch | IMU only | rotation | settle s (implied) "
          "| noise px 1 frame -> avg | hold ms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, path, rig_file, sname, rname, _ in bags:
        damping = styles[sname][1].get("damping")
        implied = implied_settle_s(rigs[rname], damping)
        for method in args.methods.split(","):
            if method == "auto" and not styles[sname][1].get("imu", True):
                continue
            r = run_bag(path, rig_file, method)
            r.update(bag=name, style=sname, rig=rname, method=method, implied_settle_s=implied)
            results.append(r)
            print(f"| {name} | {method} | {r['coverage']:.2f} | {r['outside']} | {r['gravity_deg']:.3f} | "
                  f"{r['batch_gravity_deg']:.3f} | {r['imu_gravity_deg']:.3f} | {r['rotation_deg']:.3f} | "
                  f"{r['settle_s']:.2f} ({implied:.2f}) | {r['noise_px']:.3f} -> {r['averaged_noise_px']:.4f} | "
                  f"{r['hold_ms']:.0f} |", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
