#!/usr/bin/env python3
"""Each camera's extrinsics at every image from ``nrmpc replay --extrinsics`` against the truth (docs/RESULTS.md).

    python scripts/bench_extrinsics.py [--out /tmp/nrmpc_bench_extrinsics] [--cameras 4] [--rate 15]
                                       [--views 4] [--hold 5] [--width 160] [--profile trapezoid] [--seed 0]
                                       [--imu-in-camera CAM] [--json results.json]

Renders (once into --out; delete it to re-render) a stream bag of a rig whose bars differ (natural frequency
2.5-5 Hz, damping 0.06-0.02: the softest bar rings longest), moving by abrupt trapezoid moves between holds,
with the make-bag IMU (200 Hz; accelerometer noise 0.02 m/s^2 and bias 0.05 m/s^2, gyro 0.002 rad/s each).
Runs ``nrmpc replay --extrinsics`` on it and scores every row (one per image and camera) against
``/ground_truth/extrinsics/<camera>``, beside the static model at the true gravity (the best a static-only
tool can do) and the rigid calibration, per phase: moving (between holds), ringing (a hold's first three
decay times 1 / (zeta w) of its slowest-decaying bar) and settled (the rest of the hold): median and p90 of
the rotation error (deg) and of the position error (mm) over all images and cameras, and the worst camera.

The accelerometer's bias sets a floor. The replay estimates it online from every still hold (docs/PIPELINE.md,
"Extrinsics at every frame set"): ``--extrinsics-causal`` rows are what the node gives, ``--extrinsics`` rows the
recording again with the final estimate from the start; both are scored. For comparison the bias is also taken
once from all holds (the mean over the settled part of every hold of the body-frame accelerometer plus the
hold's gravity in the replay's estimates) and the same propagator is run on the bag's IMU corrected by it from
the start; without any correction as well.

The cost of the extrinsics per frame set (propagating the IMU samples since the previous set and answering
every camera at its stamp) is measured in CPU time with the bag's IMU and frame stamps, for this rig and for
a six-camera rig at the same rates.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.cli.main import main as nrmpc
from nrmpc_ros.core import load_rig, save_rig
from nrmpc_ros.core.bar_state import BarPropagator
from nrmpc_ros.core.deformation import deformed_extrinsics
from nrmpc_ros.core.dynamics import bar_natural_frequencies
from nrmpc_ros.core.rig import ImuMount
from nrmpc_ros.core.so3 import matrix_to_quat_xyzw, quat_xyzw_to_matrix, rotation_angle
from nrmpc_ros.render.bagmaker import BagOptions, make_bag
from nrmpc_ros.render.sequence import MotionOptions, make_trajectory
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

FREQ_HZ = (2.5, 3.0, 4.0, 5.0, 3.5, 4.5)  # per camera
DAMPING = (0.06, 0.045, 0.03, 0.02, 0.05, 0.025)
RING_DECAY_TIMES = 3.0  # a hold's ringing phase: this many decay times of its slowest-decaying bar
PHASES = ("moving", "ringing", "settled", "all")


def bench_rig(num_cameras: int, width: int):
    """Bars of mass 0.1 kg and length 0.3 m with EI set for FREQ_HZ, damping DAMPING."""
    layout = "cross" if num_cameras == 4 else "ring"
    rig = make_rig(RigSpec(num_cameras=num_cameras, layout=layout, EI=1.0, mass=0.1, bar_length=0.3,
                           focal=0.73 * width, resolution=(width, width * 3 // 4)))
    cams = []
    for c, f, z in zip(rig.cameras, FREQ_HZ, DAMPING):
        ei = (2 * math.pi * f) ** 2 * 0.1 * 0.3**3 / 3.0
        cams.append(replace(c, EI=ei, damping=z))
    return replace(rig, cameras=tuple(cams))


def read_truth(bag_path, rig):
    """stamp (rounded to 1 us), camera name -> (position, rotation); stamp -> gravity (body)."""
    poses, gravity = {}, {}
    topics = [f"/ground_truth/extrinsics/{c.name}" for c in rig.cameras] + ["/ground_truth/gravity"]
    with BagReader(bag_path) as bag:
        for topic, _, msg in bag.messages(topics):
            s = round(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, 6)
            if topic == "/ground_truth/gravity":
                gravity[s] = np.array([msg.vector.x, msg.vector.y, msg.vector.z])
            else:
                o, p = msg.pose.orientation, msg.pose.position
                poses[(s, topic.rsplit("/", 1)[1])] = (np.array([p.x, p.y, p.z]),
                                                       quat_xyzw_to_matrix([o.x, o.y, o.z, o.w]))
    return poses, gravity


def read_imu(bag_path, topic="/imu/data"):
    rows = []
    with BagReader(bag_path) as bag:
        for _, _, m in bag.messages([topic]):
            a, w = m.linear_acceleration, m.angular_velocity
            rows.append([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, a.x, a.y, a.z, w.x, w.y, w.z])
    return np.array(rows)


def phase_of(traj, stamps, ring_s):
    t_ns = np.rint(np.asarray(stamps) * 1e9).astype(np.int64)
    k = traj.view_index(t_ns)
    since = (t_ns - traj.hold_start[np.maximum(k, 0)]) * 1e-9
    return np.where(k < 0, "moving", np.where(since < ring_s, "ringing", "settled"))


def score(rows, truth, gravity, rig):
    """Errors (deg, mm) of the rows, of the static model at the true gravity and of the rigid calibration."""
    names = {c.name: i for i, c in enumerate(rig.cameras)}
    out = {k: {"rot": [], "pos": [], "cam": []} for k in ("dynamic", "static", "rigid")}
    for r in rows:
        s, name = round(float(r["stamp"]), 6), r["camera"]
        i = names[name]
        p_true, R_true = truth[(s, name)]
        w_s, W_s = deformed_extrinsics(rig, gravity[s])
        est = {"dynamic": (np.array([float(r[k]) for k in ("px", "py", "pz")]),
                           quat_xyzw_to_matrix([float(r[k]) for k in ("qx", "qy", "qz", "qw")])),
               "static": (w_s[i], W_s[i]), "rigid": (rig.positions[i], rig.rotations[i])}
        for k, (p, R) in est.items():
            out[k]["rot"].append(math.degrees(float(rotation_angle(R_true.T @ R))))
            out[k]["pos"].append(1e3 * float(np.linalg.norm(p - p_true)))
            out[k]["cam"].append(i)
    return {k: {a: np.array(v) for a, v in d.items()} for k, d in out.items()}


def table(errors, phase, M):
    lines = ["| phase | images x cameras | dynamics (IMU): median / p90 deg, mm | static model at the true gravity "
             "| rigid calibration | dynamics / static (median rot.) | worst camera, dynamics / static (p90 deg) |",
             "|---|---|---|---|---|---|---|"]
    res = {}
    for ph in PHASES:
        sel = np.ones(len(phase), bool) if ph == "all" else phase == ph
        if not sel.any():
            continue
        cell, stats = [], {}
        for k in ("dynamic", "static", "rigid"):
            r, p = errors[k]["rot"][sel], errors[k]["pos"][sel]
            stats[k] = {"rot_median": float(np.median(r)), "rot_p90": float(np.percentile(r, 90)),
                        "pos_median": float(np.median(p)), "pos_p90": float(np.percentile(p, 90))}
            cell.append(f"{np.median(r):.4f} / {np.percentile(r, 90):.4f} deg, {np.median(p):.3f} / "
                        f"{np.percentile(p, 90):.3f} mm")
        cam = errors["dynamic"]["cam"][sel]
        worst = max(range(M), key=lambda i: np.percentile(errors["static"]["rot"][sel][cam == i], 90)
                    if (cam == i).any() else -1)
        wd = np.percentile(errors["dynamic"]["rot"][sel][cam == worst], 90)
        ws = np.percentile(errors["static"]["rot"][sel][cam == worst], 90)
        ratio = stats["dynamic"]["rot_median"] / max(stats["static"]["rot_median"], 1e-12)
        lines.append(f"| {ph} | {int(sel.sum())} | {cell[0]} | {cell[1]} | {cell[2]} | {ratio:.2f} | "
                     f"cam{worst}: {wd:.4f} / {ws:.4f} |")
        res[ph] = {**stats, "ratio": ratio}
    return "\n".join(lines), res


def bias_from_holds(imu, est_csv, rig, traj, ring_s):
    """Accelerometer bias (body frame, m/s^2): mean over the holds with a vision gravity of (mean accelerometer in
    the hold's settled part, in the body frame) + (the hold's gravity from the replay's estimate)."""
    R_bi = (rig.imu.rotation if rig.imu else np.eye(3))
    out = []
    for r in csv.DictReader(open(est_csv)):
        if not r.get("gx"):
            continue
        s = float(r["stamp"])
        k = int(traj.view_index(np.array([int(round(s * 1e9))]))[0])
        if k < 0:
            continue
        t0, t1 = traj.hold_start[k] * 1e-9 + ring_s, traj.hold_end[k] * 1e-9
        sel = (imu[:, 0] >= t0) & (imu[:, 0] < t1)
        if sel.sum() < 20:
            continue
        f = R_bi @ imu[sel, 1:4].mean(axis=0)
        g = np.array([float(r["gx"]), float(r["gy"]), float(r["gz"])])
        out.append(f + g)
    return (np.mean(out, axis=0), len(out)) if out else (np.zeros(3), 0)


def propagate(rig, imu, frame_stamps, bias=None):
    """The propagator on the bag's IMU (minus ``bias``, IMU frame) answering every camera at each frame stamp;
    returns the poses (F, M) and the CPU time per frame set (s)."""
    prop = BarPropagator(rig)
    R_bi = rig.imu.rotation if rig.imu else np.eye(3)
    b_imu = np.zeros(3) if bias is None else R_bi.T @ bias
    rows = imu.tolist()
    j, cpu, out_w, out_W = 0, 0.0, [], []
    for s in frame_stamps:
        c0 = time.process_time()
        while j < len(rows) and rows[j][0] <= s:
            t, ax, ay, az, wx, wy, wz = rows[j]
            prop.add_imu(t, (ax - b_imu[0], ay - b_imu[1], az - b_imu[2]), (wx, wy, wz))
            j += 1
        poses = prop.extrinsics_at(np.full(rig.num_cameras, s), np.arange(rig.num_cameras))
        if poses is not None:
            out_w.append(poses[0])
            out_W.append(poses[1])
        else:
            out_w.append(rig.positions)
            out_W.append(rig.rotations)
        cpu += time.process_time() - c0
    return np.array(out_w), np.array(out_W), cpu / max(len(frame_stamps), 1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="/tmp/nrmpc_bench_extrinsics")
    ap.add_argument("--cameras", type=int, default=4)
    ap.add_argument("--rate", type=float, default=15.0)
    ap.add_argument("--imu-rate", type=float, default=200.0)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--hold", type=float, default=5.0)
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--profile", default="trapezoid", help="move profile: trapezoid (abrupt), cosine, min-jerk")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--imu-in-camera", metavar="CAM", help="the IMU inside this camera (riding on its bar) "
                    "instead of at the body centre")
    ap.add_argument("--json")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rig = bench_rig(args.cameras, args.width)
    if args.imu_in_camera:
        if args.imu_in_camera not in [c.name for c in rig.cameras]:
            ap.error(f"--imu-in-camera: no camera {args.imu_in_camera!r} (cameras: "
                     f"{', '.join(c.name for c in rig.cameras)})")
        rig = replace(rig, imu=ImuMount(mount=args.imu_in_camera))
    rig_path = out / "rig.yaml"
    save_rig(rig, rig_path, header="bench_extrinsics rig")
    rig = load_rig(rig_path)
    motion = MotionOptions(views=args.views, hold_seconds=args.hold, rate=args.rate, imu_rate=args.imu_rate,
                           move_profile=args.profile, accel_fraction=0.2, capture="stream", min_step=15,
                           max_step=30, speed=40.0)
    opts = BagOptions(motion=motion, seed=args.seed)
    bag = out / "bag"
    summary = None
    if not bag.exists():
        t0 = time.time()
        summary = make_bag(rig, bag, opts, progress=False)
        print(f"rendered {bag} in {time.time() - t0:.0f} s")
    # The trajectory is a function of the seed and the motion options: rebuild it when the bag is reused.
    traj = summary["trajectory"] if summary else make_trajectory(
        np.random.default_rng(np.random.SeedSequence(args.seed).spawn(5)[0]), motion, rig.gravity_magnitude)
    x_csv, e_csv = out / "extrinsics.csv", out / "estimates.csv"
    t0 = time.time()
    c_csv = out / "extrinsics_causal.csv"
    nrmpc(["replay", str(bag), "--rig", str(rig_path), "--out", str(e_csv), "--extrinsics", str(x_csv),
           "--extrinsics-causal", str(c_csv), "--no-progress", "--quiet"])
    print(f"replay: {time.time() - t0:.0f} s wall")
    truth, gravity = read_truth(bag, rig)
    rows = list(csv.DictReader(open(c_csv)))  # causal: what the node gives
    smooth = list(csv.DictReader(open(x_csv)))  # offline: the final bias from the start
    f = bar_natural_frequencies(rig)
    zeta = np.array([c.damping for c in rig.cameras])
    ring_s = RING_DECAY_TIMES / float(np.min(zeta * 2 * math.pi * f))
    phase = phase_of(traj, [float(r["stamp"]) for r in rows], ring_s)
    errors = score(rows, truth, gravity, rig)
    text, res = table(errors, phase, rig.num_cameras)
    M = rig.num_cameras
    print(f"\n{M} cameras ({', '.join(f'{x:.1f}' for x in f)} Hz; damping {', '.join(f'{z:g}' for z in zeta)}), "
          f"{args.rate:g} Hz frames, IMU {args.imu_rate:g} Hz, {args.profile} moves; ringing = first {ring_s:.1f} s "
          f"of each hold\n\nreplay --extrinsics:\n{text}")
    text_s, res_s = table(score(smooth, truth, gravity, rig), phase_of(traj, [float(r["stamp"]) for r in smooth],
                                                                          ring_s), M)
    print(f"\nreplay --extrinsics, smoothed rows (the final bias from the start):\n{text_s}")
    imu = read_imu(bag)
    if args.imu_in_camera:  # the bias from the holds below is the body-centre IMU's
        if args.json:
            Path(args.json).write_text(json.dumps({"replay": res, "smoothed": res_s}, indent=1))
        return 0
    # Bias from the holds, and the same propagator with the IMU corrected by it.
    bias, n_holds = bias_from_holds(imu, e_csv, rig, traj, ring_s)
    stamps = sorted({round(float(r["stamp"]), 6) for r in rows})
    w, W, _ = propagate(rig, imu, stamps, bias)
    idx = {s: k for k, s in enumerate(stamps)}
    names = [c.name for c in rig.cameras]
    corrected = []
    for r in rows:
        k, i = idx[round(float(r["stamp"]), 6)], names.index(r["camera"])
        corrected.append({"stamp": r["stamp"], "camera": r["camera"], **dict(zip(("px", "py", "pz"), w[k, i])),
                          **dict(zip(("qx", "qy", "qz", "qw"), matrix_to_quat_xyzw(W[k, i])))})
    text_b, res_b = table(score(corrected, truth, gravity, rig), phase, M)
    print(f"\naccelerometer bias from all {n_holds} estimated holds: {np.round(bias, 4).tolist()} m/s^2 (|b| = "
          f"{np.linalg.norm(bias):.4f}); the IMU corrected by it from the start:\n{text_b}")
    w, W, _ = propagate(rig, imu, stamps)
    raw = [{"stamp": r["stamp"], "camera": r["camera"],
            **dict(zip(("px", "py", "pz"), w[idx[round(float(r["stamp"]), 6)], names.index(r["camera"])])),
            **dict(zip(("qx", "qy", "qz", "qw"),
                       matrix_to_quat_xyzw(W[idx[round(float(r["stamp"]), 6)], names.index(r["camera"])])))}
           for r in rows]
    text_r, res_r = table(score(raw, truth, gravity, rig), phase, M)
    print(f"\nno bias correction:\n{text_r}")
    # Cost per frame set (CPU time), this rig and a six-camera rig at the same rates.
    _, _, cost = propagate(rig, imu, stamps)
    rig6 = bench_rig(6, args.width)
    _, _, cost6 = propagate(rig6, imu, stamps)
    print(f"\ncost per frame set (CPU, propagation since the previous set + every camera's pose): {M} cameras "
          f"{1e3 * cost:.3f} ms, 6 cameras {1e3 * cost6:.3f} ms ({len(imu) / max(len(stamps), 1):.1f} IMU samples "
          f"per frame set)")
    if args.json:
        Path(args.json).write_text(json.dumps({"replay": res, "smoothed": res_s, "bias_corrected": res_b,
                                               "no_correction": res_r,
                                               "bias": bias.tolist(), "cost_ms": 1e3 * cost,
                                               "cost6_ms": 1e3 * cost6}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
