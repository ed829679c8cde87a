#!/usr/bin/env python3
"""Gravity accuracy, the honesty of its published std, and the hold time, with and without patch alignment.

    python scripts/bench_gravity_std.py [--out /tmp/nrmpc_bench_gravity_std] [--rigs fish3,line2] [--seeds 0]
                                        [--views 6] [--json out.json]

Small rendered bags (320x240, 10 Hz stream, smooth moves, stiff-enough bars to settle within the 3 s holds)
of two rigs: three cameras on a ring of which one is an equidistant fisheye, and two cameras on one bar.
Each bag is replayed through the same loop as ``nrmpc replay`` with ``auto`` (4pt-bending with the IMU) and
``6pt-bending`` (vision only) in variants (--variants): ``today`` (tracks' own positions, one noise for all
cameras), ``aligned`` (patch alignment, docs/PIPELINE.md, "Patch alignment") and ``new`` (patch alignment and
each camera weighed by its own noise with the correspondence-bias floor, ``sequence.camera_noise``). The
table gives per run the median gravity error against ground truth, the IMU-only error, the fractions of
published gravities within 1, 2 and 3 of their own (largest angular) standard deviations of the truth, and
the median time per hold (linking, alignment and the window solve; wall clock on whatever else the machine
runs). Bags are rendered once into --out and reused.
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
from nrmpc_ros.core.rig import Camera
from nrmpc_ros.frontend.estimates_csv import row_from_estimate
from nrmpc_ros.frontend.evaluation import evaluate
from nrmpc_ros.frontend.patch_align import PatchAlignConfig
from nrmpc_ros.frontend.pipeline import Pipeline, PipelineConfig
from nrmpc_ros.frontend.reference import read_reference
from nrmpc_ros.frontend.replay import replay_bag, resolve_imu_topic
from nrmpc_ros.render.bagmaker import BagOptions, make_bag
from nrmpc_ros.render.sequence import MotionOptions
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

BAR = {"EI": 1.0, "mass": 0.15, "bar_length": 0.3}  # about 4.3 Hz
RES = (320, 240)


def rigs() -> dict:
    line2 = make_rig(RigSpec(num_cameras=2, layout="line", focal=235.0, resolution=RES, **BAR))
    ring3 = make_rig(RigSpec(num_cameras=3, layout="ring", focal=235.0, resolution=RES, **BAR))
    c = ring3.cameras[2]
    fish = Camera(name=c.name, model="equidistant", intrinsics=(150.0, 150.0, 159.5, 119.5),
                  distortion=(0.02, -0.01, 0.003, -0.001), resolution=RES, position=c.position, rotation=c.rotation,
                  mass=c.mass, EI=c.EI, image_topic=c.image_topic, info_topic=c.info_topic)
    return {"fish3": replace(ring3, cameras=ring3.cameras[:2] + (fish,), source="<3 cameras, one fisheye>"),
            "line2": line2}


def bag(out: Path, name: str, rig, seed: int, views: int) -> tuple:
    out.mkdir(parents=True, exist_ok=True)
    path, rig_file = out / f"{name}-{seed}", out / f"{name}.yaml"
    if not rig_file.exists():
        save_rig(rig, rig_file, header="rig of scripts/bench_gravity_std.py")
    if not path.exists():
        mo = MotionOptions(views=views, hold_seconds=3.0, min_move_seconds=1.0, capture="stream", rate=10.0,
                           move_profile="min-jerk")
        t0 = time.perf_counter()
        make_bag(rig, path, BagOptions(motion=mo, seed=seed), progress=False)
        print(f"rendered {path.name} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return path, rig_file


VARIANTS = {"today": (False, False), "aligned": (True, False), "new": (True, True)}


def run(path: Path, rig_file: Path, method: str, variant: str) -> dict:
    rig = load_rig(rig_file)
    aligned, camera_noise = VARIANTS[variant]
    base = PipelineConfig()
    cfg = PipelineConfig(patch_align=PatchAlignConfig(enabled=aligned),
                         sequence=replace(base.sequence, camera_noise=camera_noise))
    with BagReader(path) as reader:
        imu_topic = resolve_imu_topic(reader, rig, warn=lambda m: None)
        pipe = Pipeline(rig, cfg, method=method)
        rows = [row_from_estimate(e) for es in replay_bag(reader, rig, pipe, imu_topic, warn=lambda m: None)
                for e in es]
        ref = read_reference(reader, imu_topic)
    ev = evaluate(rows, ref, rig)
    err = np.asarray(ev.errors["gravity_vs_gt_deg"], float)
    sig = np.array([r.extra.get("gravity_sigma_deg", math.nan) for r in rows], float)
    ok = np.isfinite(err) & np.isfinite(sig) & (sig > 0)
    z = err[ok] / sig[ok]
    within = [float(np.mean(z <= k)) if len(z) else math.nan for k in (1, 2, 3)]
    return {"estimates": int(ok.sum()), "gravity_deg": float(np.median(err[ok])) if ok.any() else math.nan,
            "imu_deg": ev.stats("imu_vs_gt_deg")["median"], "within": within,
            "sigma_deg": float(np.median(sig[ok])) if ok.any() else math.nan,
            "hold_ms": float(np.median([r.time_ms for r in rows])) if rows else math.nan}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="/tmp/nrmpc_bench_gravity_std", help="folder of the rendered bags (reused)")
    p.add_argument("--rigs", default="fish3,line2", help="comma-separated rigs: fish3, line2")
    p.add_argument("--seeds", default="0", help="comma-separated bag seeds")
    p.add_argument("--views", type=int, default=6, help="holds per bag")
    p.add_argument("--methods", default="auto,6pt-bending", help="comma-separated methods")
    p.add_argument("--variants", default="today,new", help="comma-separated: " + ",".join(VARIANTS))
    p.add_argument("--json", help="also write the rows to this JSON file")
    a = p.parse_args(argv)
    all_rigs = rigs()
    results = []
    print("| bag | method | variant | estimates | gravity (deg) | IMU only (deg) | median std (deg) | "
          "within 1 / 2 / 3 std | hold ms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for rname in a.rigs.split(","):
        for seed in (int(s) for s in a.seeds.split(",")):
            path, rig_file = bag(Path(a.out), rname, all_rigs[rname], seed, a.views)
            for method in a.methods.split(","):
                for variant in a.variants.split(","):
                    r = run(path, rig_file, method, variant)
                    r.update(bag=path.name, method=method, variant=variant)
                    results.append(r)
                    w = " / ".join(f"{x:.2f}" for x in r["within"])
                    print(f"| {path.name} | {method} | {variant} | {r['estimates']} | "
                          f"{r['gravity_deg']:.3f} | {r['imu_deg']:.3f} | {r['sigma_deg']:.3f} | {w} | "
                          f"{r['hold_ms']:.0f} |", flush=True)
    if a.json:
        from nrmpc_ros.safeio import atomic_write

        with atomic_write(a.json, flag="--json") as fp:
            json.dump(results, fp, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
