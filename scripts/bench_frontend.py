#!/usr/bin/env python3
"""Throughput and accuracy of the front end (tracking + matching + estimation) on one core, from a bag in memory.

    OMP_NUM_THREADS=1 python scripts/bench_frontend.py [--bag bags/sample --rig config/sample_cross4.yaml]
        [--method 4pt-bending --method 6pt-bending] [--set tracking.max_matches_per_camera=60 ...] [--profile 30]

Images are decoded and synchronised first (not timed); then every frame set
goes through a fresh Pipeline. Times are CPU seconds of this process
(``time.process_time``; OpenCV, OpenMP and BLAS limited to one thread), so a
busy machine does not distort them. ``pairs_per_s`` = estimates / CPU time of
all ``add_frames`` calls (tracking of every frame set + pairing, matching,
verification and estimation of the static views): the rate at which view
pairs are turned into estimates. The CPU time is split into tracking (per
frame set), pair processing (per static view: descriptors, matching,
verification, estimation) and ``estimate()`` alone; ``frontend_ms_per_pair``
is everything but ``estimate()`` (tracking, features, matching, verification,
pairing) per estimate. Accuracy comes from the
bag's ``/ground_truth/*`` exactly as ``nrmpc compare`` computes it (median
gravity and relative rotation errors, share of static attitudes with an
estimate).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

import nrmpc_ros.frontend.pipeline as pipeline_module  # noqa: E402
from nrmpc_ros.bag.reader import BagReader  # noqa: E402
from nrmpc_ros.core import load_rig  # noqa: E402
from nrmpc_ros.frontend.estimates_csv import row_from_estimate  # noqa: E402
from nrmpc_ros.frontend.evaluation import evaluate  # noqa: E402
from nrmpc_ros.frontend.images import decode_image, stamp_seconds  # noqa: E402
from nrmpc_ros.frontend.pipeline import FrameSet, Pipeline, PipelineConfig  # noqa: E402
from nrmpc_ros.frontend.reference import read_reference  # noqa: E402
from nrmpc_ros.frontend.sync import StampSynchronizer  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def load_bag(bag_path, rig, tolerance=0.01):
    """Synchronised frame sets [(stamp, images)] and IMU samples [(stamp, accel, gyro)] of a bag, in bag order."""
    topics = [c.image_topic for c in rig.cameras]
    imu_topic = rig.imu.topic if rig.imu is not None else None
    events = []
    with BagReader(bag_path) as bag:
        if imu_topic and not bag.has_topic(imu_topic):
            imu_topic = None
        sync = StampSynchronizer(rig.num_cameras, tolerance, 10)
        index = {t: i for i, t in enumerate(topics)}
        for topic, _, msg in bag.messages(topics + ([imu_topic] if imu_topic else [])):
            if topic == imu_topic:
                a, w = msg.linear_acceleration, msg.angular_velocity
                events.append(("imu", stamp_seconds(msg), (a.x, a.y, a.z), (w.x, w.y, w.z)))
                continue
            for s in sync.add(index[topic], stamp_seconds(msg), decode_image(msg, topic)):
                events.append(("frames", s.stamp, s.items))
    return events


def load_reference(bag_path, rig):
    """IMU and ground truth of a bag (for the accuracy columns), or None when it has no ground truth."""
    with BagReader(bag_path) as bag:
        ref = read_reference(bag, rig.imu.topic if rig.imu is not None else None)
    return ref if ref.has_pose or ref.has_gravity else None


class _Clock:
    """CPU seconds spent inside a wrapped callable (nested calls of the same clock are not double counted)."""

    def __init__(self):
        self.total = 0.0
        self.calls = 0

    def wrap(self, fn):
        def timed(*a, **kw):
            t0 = time.process_time()
            try:
                return fn(*a, **kw)
            finally:
                self.total += time.process_time() - t0
                self.calls += 1
        return timed


def accuracy(rig, ests, reference) -> dict:
    """Median errors against the ground truth (as ``nrmpc compare``) and the share of attitudes estimated."""
    if reference is None:
        return {}
    ev = evaluate([row_from_estimate(e) for e in ests], reference, rig)
    out = {"coverage": ev.coverage}
    for key in ("gravity_vs_gt_deg", "rotation_deg", "translation_deg"):
        s = ev.stats(key)
        out[f"median_{key}"] = s["median"]
        out[f"p90_{key}"] = s["p90"]
    return out


def bench(rig, events, method="auto", config: PipelineConfig | None = None, reference=None) -> dict:
    """Run the pipeline over pre-decoded events; CPU timing, counts and (with a reference) accuracy."""
    cv2.setNumThreads(1)
    pipe = Pipeline(rig, config or PipelineConfig(), method=method)
    pair_clock, est_clock = _Clock(), _Clock()
    pipe._static_view = pair_clock.wrap(pipe._static_view)  # per static view: pairing, matching, estimation
    original_estimate = pipeline_module.estimate
    pipeline_module.estimate = est_clock.wrap(original_estimate)
    ests, total = [], 0.0
    try:
        for ev in events:
            if ev[0] == "imu":
                pipe.add_imu(ev[1], ev[2], ev[3])
                continue
            t0 = time.process_time()
            ests += pipe.add_frames(FrameSet(ev[1], ev[2]))
            total += time.process_time() - t0
    finally:
        pipeline_module.estimate = original_estimate
    frames = pipe.stats.frames
    n = len(ests)
    out = {
        "method": method, "frames": frames, "static_views": pipe.stats.static_views, "estimates": n,
        "methods": dict(pipe.stats.methods), "match_modes": sorted({e.match_mode for e in ests}),
        "cpu_s": total, "pairs_per_s": n / total if total else math.nan,
        "pair_only_per_s": n / pair_clock.total if pair_clock.total else math.nan,
        "pair_ms": 1000.0 * pair_clock.total / max(n, 1),
        "estimate_ms": 1000.0 * est_clock.total / max(est_clock.calls, 1),
        "frontend_ms_per_pair": 1000.0 * (total - est_clock.total) / max(n, 1),
        "tracking_ms_per_frame": 1000.0 * (total - pair_clock.total) / max(frames, 1),
        "median_matches": float(np.median([e.num_matches for e in ests])) if ests else math.nan,
        "dropped": pipe.stats.as_dict()["dropped"],
    }
    out.update(accuracy(rig, ests, reference))
    return out


def parse_sets(items) -> dict:
    """``--set a.b=value`` items -> nested PipelineConfig mapping (values parsed as YAML scalars)."""
    d: dict = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--set needs KEY=VALUE, got {item!r}")
        node = d
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = yaml.safe_load(value)
    return d


def describe(r: dict) -> str:
    s = (f"{r['method']:>15}: {r['estimates']} pairs / {r['static_views']} static views / {r['frames']} frame sets "
         f"in {r['cpu_s']:.2f} s CPU -> {r['pairs_per_s']:.1f} pairs/s; per pair {r['pair_ms']:.0f} ms "
         f"(estimate {r['estimate_ms']:.0f} ms, {r['median_matches']:.0f} matches, {'/'.join(r['match_modes'])}); "
         f"tracking {r['tracking_ms_per_frame']:.1f} ms per frame set; all but estimate() "
         f"{r['frontend_ms_per_pair']:.0f} ms per pair")
    if "coverage" in r:
        s += (f"\n{'':>17}accuracy vs ground truth: gravity median {r['median_gravity_vs_gt_deg']:.2f} deg "
              f"(p90 {r['p90_gravity_vs_gt_deg']:.2f}), rotation median {r['median_rotation_deg']:.3f} deg "
              f"(p90 {r['p90_rotation_deg']:.3f}), attitudes with an estimate {100 * r['coverage']:.0f}%")
    return s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", default=str(ROOT / "bags" / "sample"))
    ap.add_argument("--rig", default=str(ROOT / "config" / "sample_cross4.yaml"))
    ap.add_argument("--method", action="append", help="method(s) to time (default: 4pt-bending and 6pt-bending)")
    ap.add_argument("--descriptor", choices=("orb", "sift"), default="orb")
    ap.add_argument("--config", help="pipeline settings YAML (as nrmpc replay --config)")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE",
                    help="override one setting, e.g. tracking.max_matches_per_camera=60 or estimator.subset_size=100")
    ap.add_argument("--repeat", type=int, default=1, help="runs per method (the fastest is reported)")
    ap.add_argument("--profile", type=int, default=0, metavar="N", help="print the N costliest functions (cProfile)")
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args(argv)
    rig = load_rig(args.rig)
    events = load_bag(args.bag, rig)
    reference = load_reference(args.bag, rig)
    d = yaml.safe_load(Path(args.config).read_text()) if args.config else {}
    d = dict(d or {})
    d.setdefault("tracking", {})
    d["tracking"] = {"descriptor": args.descriptor, **(d["tracking"] or {})}
    for k, v in parse_sets(args.set).items():
        d[k] = {**(d.get(k) or {}), **v} if isinstance(v, dict) else v
    cfg = PipelineConfig.from_dict(d)
    results = []
    for method in args.method or ["4pt-bending", "6pt-bending"]:
        if args.profile:
            import cProfile
            import pstats

            prof = cProfile.Profile()
            prof.enable()
            bench(rig, events, method, cfg)
            prof.disable()
            pstats.Stats(prof).sort_stats(os.environ.get("PROFILE_SORT", "tottime")).print_stats(args.profile)
        runs = [bench(rig, events, method, cfg, reference) for _ in range(max(1, args.repeat))]
        r = max(runs, key=lambda x: x["pairs_per_s"])
        results.append(r)
        print(describe(r), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
