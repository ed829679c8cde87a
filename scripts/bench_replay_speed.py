#!/usr/bin/env python3
"""CPU cost of the replay pipeline per configuration, beside the cost of decoding and of one KLT pass per image.

One 6-camera VGA stream bag at 30 Hz with JPEG images (``make-bag --encoding jpeg``, 4 holds of 2 s) is
rendered once, or given with ``--bag``/``--rig``. Every configuration -- 2, 4 or 6 of its cameras, at 30 Hz or
every other frame (15 Hz), JPEG as recorded or raw mono8 (each JPEG decoded once beforehand) -- runs through
the node's input policy and pipeline (:class:`~nrmpc_ros.frontend.feeder.Feeder` and
:class:`~nrmpc_ros.frontend.runner.PipelineRunner`, as ``nrmpc replay`` does) with its messages already in
memory, so the CPU time measured (``time.process_time``: every thread of this process) is the pipeline's own:
decoding, tracking, hold logic, estimation. Reported per configuration:

- CPU seconds per second of data;
- pipeline CPU per image, beside the CPU of ``cv2.imdecode`` of the same JPEG images and of one forward
  ``cv2.calcOpticalFlowPyrLK`` call (the tracker's window and levels, its number of corners) on them,
  measured in the same run, and their ratios (absolute times depend on the machine's load; the ratios much
  less);
- the trackers' work: the share of images tracked (a settled hold tracks fewer, docs/PIPELINE.md,
  "Performance notes"), the mean pyramid levels of the first LK pass per tracked image, the tracks per
  tracked image that needed the full forward-backward pass, the tracks per tracked image dropped, and the
  frames whose tracks were lost (all of them);
- holds measured, estimates and the median gravity error against the bag's ground truth.

``--imu-prediction both`` runs every configuration with KLT started from the IMU's turn and from the images
alone (``tracking.imu_prediction``), one after the other.

    python scripts/bench_replay_speed.py [--bag BAG --rig RIG] [--cameras 2 4 6] [--rates 15 30] [--json OUT]
                                         [--encodings jpeg raw] [--imu-prediction on|off|both]
"""

from __future__ import annotations

# isort: off
from nrmpc_ros import threads  # noqa: F401 - one BLAS thread, as the command line and the node
# isort: on
import argparse
import dataclasses
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import yaml

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.core.rig import load_rig
from nrmpc_ros.frontend.droplog import DropLog
from nrmpc_ros.frontend.feeder import Feeder
from nrmpc_ros.frontend.pipeline import PipelineConfig
from nrmpc_ros.frontend.runner import PipelineRunner
from nrmpc_ros.frontend.tracking import TrackerStats, TrackingConfig, detect_corners

VIEWS = 4  # holds of the rendered bag


def render(directory: Path) -> tuple:
    """(bag, rig file): 6 cameras, 640x480 JPEG at 30 Hz, 4 holds of 2 s joined by 0.8 s moves."""
    from nrmpc_ros.cli.main import main as nrmpc

    bag, rig = directory / "bag6", directory / "rig6.yaml"
    code = nrmpc(["make-bag", "--cameras", "6", "--resolution", "640x480", "--views", str(VIEWS), "--hold-seconds",
                  "2", "--rate", "30", "--capture", "stream", "--move-seconds", "0.8", "--max-step", "15", "--encoding",
                  "jpeg", "--seed", "0", "--save-rig", str(rig), "--out", str(bag), "--no-progress"])
    if code:
        raise SystemExit(code)
    return bag, rig


def sub_rig(rig: Path, cameras: int, directory: Path) -> Path:
    """The rig file with its first ``cameras`` cameras."""
    d = yaml.safe_load(rig.read_text())
    d["cameras"] = d["cameras"][:cameras]
    out = directory / f"rig{cameras}.yaml"
    out.write_text(yaml.safe_dump(d, sort_keys=False))
    return out


def load(bag: Path) -> tuple:
    """(messages [(topic, t_ns, msg)], ground truth gravity {stamp: g}) of the bag, in bag order."""
    with BagReader(bag) as reader:
        topics = [t for t in reader.topics if t.endswith("/compressed") or t == "/imu/data"]
        messages = list(reader.messages(topics))
        truth = {}
        if reader.has_topic("/ground_truth/gravity"):
            for _, _, m in reader.messages(["/ground_truth/gravity"]):
                s = m.header.stamp
                truth[round(s.sec + 1e-9 * s.nanosec, 6)] = np.array([m.vector.x, m.vector.y, m.vector.z])
    return messages, truth


def raw_message(msg):
    """A mono8 sensor_msgs/Image-like message of a JPEG CompressedImage (decoded once, outside the timing)."""
    img = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_GRAYSCALE)
    return SimpleNamespace(header=msg.header, height=img.shape[0], width=img.shape[1], step=img.shape[1],
                           encoding="mono8", is_bigendian=0, data=img.reshape(-1))


def configuration(messages, rig_path: Path, cameras: int, rate_hz: float, raw: bool) -> tuple:
    """(rig, [(topic or None for the IMU, camera index, msg)], seconds of data, images) of one configuration."""
    rig = load_rig(rig_path)
    topics = {c.image_topic.rstrip("/") + "/compressed": i for i, c in enumerate(rig.cameras)}
    stamps = sorted({t for topic, t, _ in messages if topic in topics})
    period = np.median(np.diff(stamps)) * 1e-9
    every = max(1, int(round(1.0 / (rate_hz * period))))
    keep = {t for k, t in enumerate(stamps) if k % every == 0}
    out, images = [], 0
    for topic, t, msg in messages:
        if topic == "/imu/data":
            out.append((None, -1, msg))
        elif topic in topics and t in keep:
            out.append((topic, topics[topic], raw_message(msg) if raw else msg))
            images += 1
    return rig, out, (max(stamps) - min(stamps)) * 1e-9, images


def run(rig, items, imu_prediction: bool = True) -> tuple:
    """CPU seconds of the feeder and pipeline over ``items``, and the runner (its statistics) and estimates."""
    work: list = []
    drops = DropLog(math.inf)
    config = PipelineConfig()
    config.tracking.imu_prediction = imu_prediction
    runner = PipelineRunner(rig, config, "auto", drops)
    feeder = Feeder(rig, None, work.append, drops, [c.image_topic for c in rig.cameras], "/imu/data")
    estimates = []
    t0 = time.process_time()
    for topic, index, msg in items:
        if topic is None:
            feeder.imu_msg(msg)
        else:
            feeder.image(index, msg)
        for w in work:
            estimates += runner.run(w)
        work.clear()
    feeder.end()
    for w in work:
        estimates += runner.run(w)
    return time.process_time() - t0, runner, estimates


def unit_costs(messages, rig_path: Path, samples: int = 40) -> dict:
    """CPU per image (s) of cv2.imdecode of a JPEG and of one forward calcOpticalFlowPyrLK into the next frame of
    the same camera (the tracker's window, levels and corners), over ``samples`` images of camera 0."""
    rig = load_rig(rig_path)
    topic = rig.cameras[0].image_topic.rstrip("/") + "/compressed"
    jpegs = [np.frombuffer(m.data, np.uint8) for t, _, m in messages if t == topic]
    step = max(1, len(jpegs) // samples)
    pairs = [(jpegs[k], jpegs[k + 1]) for k in range(0, len(jpegs) - 1, step)]
    cfg = TrackingConfig()
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)
    imgs = [(cv2.imdecode(a, cv2.IMREAD_GRAYSCALE), cv2.imdecode(b, cv2.IMREAD_GRAYSCALE)) for a, b in pairs]
    corners = [detect_corners(a, cfg, cfg.max_tracks) for a, _ in imgs]
    t0 = time.process_time()
    for a, _ in pairs:
        cv2.imdecode(a, cv2.IMREAD_GRAYSCALE)
    decode = (time.process_time() - t0) / len(pairs)
    t0 = time.process_time()
    for (a, b), p in zip(imgs, corners):
        cv2.calcOpticalFlowPyrLK(a, b, p, None, winSize=(cfg.klt_window, cfg.klt_window), maxLevel=cfg.klt_levels,
                                 criteria=crit)
    klt = (time.process_time() - t0) / len(pairs)
    return {"decode_ms": 1e3 * decode, "klt_forward_ms": 1e3 * klt}


def tracker_work(runner) -> dict:
    """The trackers' work summed over cameras (the runner's current pipeline)."""
    total = TrackerStats()
    for trk in runner.pipeline.trackers:
        for f in dataclasses.fields(TrackerStats):
            setattr(total, f.name, getattr(total, f.name) + getattr(trk.stats, f.name))
    return dataclasses.asdict(total)


def gravity_error_deg(estimates, truth) -> float | None:
    errs = []
    for e in estimates:
        g = truth.get(round(e.stamp, 6))
        if g is not None:
            c = float(np.dot(e.gravity, g) / (np.linalg.norm(e.gravity) * np.linalg.norm(g)))
            errs.append(math.degrees(math.acos(max(-1.0, min(1.0, c)))))
    return float(np.median(errs)) if errs else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bag", type=Path, help="a 6-camera JPEG stream bag (default: render one, a few minutes)")
    ap.add_argument("--rig", type=Path, help="its rig file (with --bag)")
    ap.add_argument("--cameras", type=int, nargs="+", default=[2, 4, 6])
    ap.add_argument("--rates", type=float, nargs="+", default=[15.0, 30.0])
    ap.add_argument("--views", type=int, default=VIEWS, help="holds of the bag (with --bag)")
    ap.add_argument("--encodings", nargs="+", choices=("jpeg", "raw"), default=["jpeg", "raw"])
    ap.add_argument("--imu-prediction", choices=("on", "off", "both"), default="on",
                    help="KLT starts from the IMU's turn (on), from the images alone (off), or each in turn")
    ap.add_argument("--json", help="also write the results to this file")
    args = ap.parse_args(argv)
    predictions = {"on": [True], "off": [False], "both": [True, False]}[args.imu_prediction]
    work = Path(tempfile.mkdtemp(prefix="bench_replay_speed_"))
    bag, rig = (args.bag, args.rig) if args.bag else render(work)
    messages, truth = load(bag)
    rows = []
    print("| cameras | Hz | IMU start | images | CPU s per s of data | pipeline ms/image | x decode | x KLT fwd | "
          "decode ms | KLT fwd ms | tracked | levels | full-pass tracks | dropped tracks | lost | holds | estimates | "
          "gravity err (deg) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for raw in [e == "raw" for e in args.encodings]:
        for cams in args.cameras:
            for rate in args.rates:
                for imu_prediction in predictions:
                    r, items, seconds, images = configuration(messages, sub_rig(rig, cams, work), cams, rate, raw)
                    unit = unit_costs(messages, rig)  # in the same run, just before: the same load on the machine
                    cpu, runner, estimates = run(r, items, imu_prediction)
                    st = runner.stats
                    tw = tracker_work(runner)
                    tracked = max(tw["frames"], 1)
                    per_image = 1e3 * cpu / images
                    row = {"encoding": "raw mono8" if raw else "jpeg", "cameras": cams, "rate_hz": rate,
                           "imu_prediction": imu_prediction, "images": images, "data_s": seconds, "cpu_s": cpu,
                           "cpu_per_data_s": cpu / seconds, "ms_per_image": per_image, **unit,
                           "x_decode": per_image / unit["decode_ms"], "x_klt": per_image / unit["klt_forward_ms"],
                           "tracked_share": tw["frames"] / images, "levels_per_image": tw["levels"] / tracked,
                           "full_pass_per_image": tw["full_pass_tracks"] / tracked,
                           "dropped_per_image": tw["dropped_tracks"] / tracked, "lost": tw["lost"],
                           "holds": st.holds, "views": args.views, "estimates": len(estimates),
                           "gravity_error_deg": gravity_error_deg(estimates, truth)}
                    rows.append(row)
                    err = row["gravity_error_deg"]
                    print(f"| {cams} {'raw' if raw else 'jpeg'} | {rate:g} | {'on' if imu_prediction else 'off'} | "
                          f"{images} | {row['cpu_per_data_s']:.2f} | {per_image:.2f} | {row['x_decode']:.2f} | "
                          f"{row['x_klt']:.2f} | {unit['decode_ms']:.2f} | {unit['klt_forward_ms']:.2f} | "
                          f"{row['tracked_share']:.2f} | {row['levels_per_image']:.2f} | "
                          f"{row['full_pass_per_image']:.1f} | {row['dropped_per_image']:.2f} | {tw['lost']} | "
                          f"{st.holds}/{args.views} | {len(estimates)} | "
                          f"{'n/a' if err is None else f'{err:.3f}'} |", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
