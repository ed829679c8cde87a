#!/usr/bin/env python3
"""Throughput of the front end (tracking + matching + estimation) on one core, from a bag held in memory.

    python scripts/bench_frontend.py [--bag bags/sample --rig config/sample_cross4.yaml] [--method auto ...]

Images are decoded and synchronised first (not timed); then every frame set
goes through a fresh Pipeline and the wall time of ``add_frames`` is split
into tracking (every frame) and pair processing (matching, verification and
estimation, ``PipelineEstimate.time_ms``). ``pairs_per_s`` = estimates / total
time: the rate at which view pairs are turned into estimates.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from nrmpc_ros.bag.reader import BagReader  # noqa: E402
from nrmpc_ros.core import load_rig  # noqa: E402
from nrmpc_ros.frontend.images import decode_image, stamp_seconds  # noqa: E402
from nrmpc_ros.frontend.pipeline import FrameSet, Pipeline, PipelineConfig  # noqa: E402
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


def bench(rig, events, method="auto", config: PipelineConfig | None = None) -> dict:
    """Run the pipeline over pre-decoded events; timing and counts."""
    cv2.setNumThreads(1)
    pipe = Pipeline(rig, config or PipelineConfig(), method=method)
    ests, total = [], 0.0
    for ev in events:
        if ev[0] == "imu":
            pipe.add_imu(ev[1], ev[2], ev[3])
            continue
        t0 = time.perf_counter()
        ests += pipe.add_frames(FrameSet(ev[1], ev[2]))
        total += time.perf_counter() - t0
    pair_s = sum(e.time_ms for e in ests) / 1000.0
    frames = pipe.stats.frames
    return {
        "method": method, "frames": frames, "static_views": pipe.stats.static_views, "estimates": len(ests),
        "methods": dict(pipe.stats.methods), "match_modes": sorted({e.match_mode for e in ests}),
        "total_s": total, "pairs_per_s": len(ests) / total if total else float("nan"),
        "pair_only_per_s": len(ests) / pair_s if pair_s else float("nan"),
        "median_pair_ms": float(np.median([e.time_ms for e in ests])) if ests else float("nan"),
        "tracking_ms_per_frame": 1000.0 * (total - pair_s) / max(frames, 1),
        "median_matches": float(np.median([e.num_matches for e in ests])) if ests else float("nan"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", default=str(ROOT / "bags" / "sample"))
    ap.add_argument("--rig", default=str(ROOT / "config" / "sample_cross4.yaml"))
    ap.add_argument("--method", action="append", help="method(s) to time (default: 4pt-bending and 6pt-bending)")
    ap.add_argument("--descriptor", choices=("orb", "sift"), default="orb")
    ap.add_argument("--repeat", type=int, default=1, help="runs per method (the best is reported)")
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args(argv)
    rig = load_rig(args.rig)
    events = load_bag(args.bag, rig)
    cfg = PipelineConfig.from_dict({"tracking": {"descriptor": args.descriptor}})
    results = []
    for method in args.method or ["4pt-bending", "6pt-bending"]:
        runs = [bench(rig, events, method, cfg) for _ in range(max(1, args.repeat))]
        r = max(runs, key=lambda x: x["pairs_per_s"])
        results.append(r)
        print(f"{method:>15}: {r['estimates']} pairs from {r['frames']} frame sets in {r['total_s']:.2f} s -> "
              f"{r['pairs_per_s']:.1f} pairs/s (pair processing alone {r['pair_only_per_s']:.1f}/s, median "
              f"{r['median_pair_ms']:.0f} ms, {r['median_matches']:.0f} matches, {'/'.join(r['match_modes'])}); "
              f"tracking {r['tracking_ms_per_frame']:.1f} ms per frame set")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
