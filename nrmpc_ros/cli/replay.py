"""``nrmpc replay``: the node's pipeline on a bag, one CSV row per estimate (docs/CONVENTIONS.md, Bags)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np

from ..bag.reader import BagReader, bag_root
from ..config import from_mapping, load_mapping
from ..core import load_rig
from ..core.so3 import rotation_angle
from ..errors import InputError
from ..frontend.accel_tilt import describe_tilt
from ..frontend.droplog import DropLog
from ..frontend.drops import sorted_counts
from ..frontend.estimates_csv import CsvWriter, batch_rows, row_from_estimate
from ..frontend.evaluation import evaluate
from ..frontend.evaluation_report import format_report
from ..frontend.extrinsics import NO_IMU_NOTE, ExtrinsicsCsv, hold_poses, imu_mount_warning
from ..frontend.feeder import IMU, MAX_CLOCK_OFFSET_S, FeederConfig
from ..frontend.imu import describe_gaps
from ..frontend.imu_agreement import describe_check
from ..frontend.imu_clock import SIGNIFICANT_STDS
from ..frontend.imu_clock_check import clock_passes, describe_clock, measure_imu_clock
from ..frontend.imu_mount import AxesMeasuringPass, describe_imu_axes
from ..frontend.imu_units import UnitsMeasuringPass, describe_accel_scale, describe_gyro_noise, describe_units
from ..frontend.pipeline import PIPELINE_METHODS, PipelineConfig
from ..frontend.reference import read_reference
from ..frontend.replay import BagReplay, check_camera_info, resolve_imu_topic
from ..frontend.runner import PipelineRunner
from ..frontend.topics import bag_image_topics
from ..frontend.trajectory import describe as describe_trajectories
from ..frontend.trajectory import sequence_errors, write_trajectories
from ..frontend.zupt import IMAGES_STILL_WINDOWS, describe_noise
from ..safeio import check_outputs
from .argtypes import nonnegative_seconds, number, positive_int, seed
from .common import add_trajectory_arguments


def register(sub):
    p = sub.add_parser("replay", help="run the estimator pipeline on a bag, write estimates to CSV",
                       description="Runs the same pipeline as the ROS 2 node on a rosbag2 (sqlite3/mcap) or ROS 1 "
                                   "bag and writes one CSV row per estimate the node would publish; prints the "
                                   "estimates and their errors against the IMU and /ground_truth/* at the end.")
    p.add_argument("bag", metavar="BAG", help="rosbag2 directory or ROS 1 .bag file")
    p.add_argument("--rig", required=True, help="rig YAML file (docs/CONVENTIONS.md (Files))")
    p.add_argument("--method", default="auto", choices=PIPELINE_METHODS,
                   help="auto: 4pt-bending when IMU gravity is available for both views, else 6pt-bending")
    p.add_argument("--out", required=True, help="output CSV: one row per hold as the node publishes it")
    p.add_argument("--batch", metavar="BATCH.csv", help="also write the joint solution of all holds at once "
                   "(each hold relative to the one before it)")
    p.add_argument("--extrinsics", metavar="OUT.csv",
                   help="also write every camera's pose in the body frame at each image's stamp, from the bars' "
                        "dynamics driven by the IMU (docs/CONVENTIONS.md, The rig in motion), one row per image and "
                        "camera, with the accelerometer bias of the whole recording from the first sample on "
                        "(source smoothed); without an IMU one row per camera and hold (the static model at the "
                        "hold's gravity)")
    p.add_argument("--extrinsics-causal", metavar="OUT.csv",
                   help="also write the same poses as the node publishes them: each with the accelerometer bias "
                        "known at that image (source imu; needs the IMU)")
    add_trajectory_arguments(p, "the bag's /ground_truth/pose")
    p.add_argument("--report", metavar="OUT.html", help="also write the recording's report: one self-contained HTML "
                   "page (holds, settling, gravity against the IMU with its 2-std band, refusals by reason)")
    p.add_argument("--calibrate-bars", action="store_true", help="with --report: also calibrate the bars' compliance "
                   "from the holds (needs the IMU; as nrmpc calibrate-bars) and show it in the report")
    p.add_argument("--config", help="pipeline settings YAML (keys of PipelineConfig: tracking, holds, imu, zupt, "
                   "sequence, ...)")
    p.add_argument("--imu-topic", help="IMU topic (default: the rig file's imu.topic)")
    p.add_argument("--no-imu", action="store_true", help="ignore the IMU (auto then runs 6pt-bending)")
    p.add_argument("--sync-tolerance", type=nonnegative_seconds, default=None,
                   help="camera stamps of one set lie within +- this (s) of the set's median stamp (default: 0.45 "
                        "of the smallest camera frame period, estimated from the stamps)")
    p.add_argument("--queue-size", type=positive_int, default=None,
                   help=f"synchronizer queue depth per camera (default {FeederConfig().queue_size})")
    p.add_argument("--imu-clock-offset", type=number(float, lo=-MAX_CLOCK_OFFSET_S, hi=MAX_CLOCK_OFFSET_S, unit="s"),
                   default=None, metavar="S", help="add S seconds to every IMU stamp as it is read: an IMU stamped by "
                   "another clock than the cameras' (replay prints it, measured from the rotations between holds "
                   "when the IMU's stamps are seconds off, from the arrival times when more; default 0)")
    p.add_argument("--imu-gyro-scale", type=number(float, lo=1e-6, hi=1e6), default=None, metavar="K",
                   help="multiply every IMU angular rate by K as it is read: 0.0174533 (pi/180) for a driver that "
                   "writes deg/s (replay measures the unit from the moves and replays with it when the gyro reads "
                   "deg/s; default 1)")
    p.add_argument("--imu-accel-scale", type=number(float, lo=1e-6, hi=1e6), default=None, metavar="K",
                   help="multiply every IMU specific force by K as it is read: 9.80665 for a driver that writes g "
                   "(replay measures the unit from the still norm and replays with it when it reads g; default 1)")
    p.add_argument("--imu-axes-turn", type=_quaternion, default=None, metavar="X,Y,Z,W",
                   help="turn every IMU sample by this quaternion as it is read, before the rig file's imu rotation: "
                   "an IMU whose axes the rig file has wrong (replay measures the turn from the turns between holds "
                   "where the images refute the IMU's gravity, and replays with it; default: none)")
    p.add_argument("--seed", type=seed, default=0, help="RANSAC seed")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--quiet", action="store_true", help="print only the statistics, not every estimate")
    p.set_defaults(func=run)


def check_tum_flags(args, bag) -> None:
    """--tum-gt needs --tum (the holds and origins it is written at) and ground truth in the bag."""
    from ..frontend.reference import GT_POSE_TOPIC

    if args.tum_gt and not args.tum:
        raise InputError("--tum-gt", "needs --tum: the ground truth is written at the estimated holds")
    if args.tum_gt and not bag.has_topic(GT_POSE_TOPIC):
        raise InputError("--tum-gt", f"{bag.source} has no {GT_POSE_TOPIC} topic")


def load_config(path, seed: int) -> PipelineConfig:
    """The pipeline settings of the --config file (errors name the file and the key); its seed wins over --seed."""
    d = dict(load_mapping(path, "pipeline settings file")) if path else {}
    d.setdefault("seed", seed)
    return from_mapping(PipelineConfig, d, str(path or "--seed"))


def _quaternion(text) -> list:
    """``X,Y,Z,W``: four finite numbers, not all zero (argparse's error names the flag)."""
    try:
        q = [float(x) for x in str(text).split(",")]
    except ValueError:
        q = []
    if len(q) != 4 or not all(math.isfinite(x) for x in q) or math.hypot(*q) < 0.5:
        raise argparse.ArgumentTypeError(f"must be a unit quaternion X,Y,Z,W, got {text!r}")
    return q


def input_config(args) -> FeederConfig:
    """The input settings: the node's defaults, the synchronizer's from the flags when given."""
    d = {}
    if args.sync_tolerance is not None:
        d["sync_tolerance_s"] = args.sync_tolerance
    if args.queue_size is not None:
        d["queue_size"] = args.queue_size
    if getattr(args, "imu_clock_offset", None) is not None:
        d["imu_clock_offset_s"] = args.imu_clock_offset
    for key in ("imu_gyro_scale", "imu_accel_scale"):
        if getattr(args, key, None) is not None:
            d[key] = getattr(args, key)
    if getattr(args, "imu_axes_turn", None) is not None:
        d["imu_axes_turn_xyzw"] = args.imu_axes_turn
    flags = {"sync_tolerance_s": "--sync-tolerance", "queue_size": "--queue-size",
             "imu_clock_offset_s": "--imu-clock-offset", "imu_gyro_scale": "--imu-gyro-scale",
             "imu_accel_scale": "--imu-accel-scale", "imu_axes_turn_xyzw": "--imu-axes-turn"}
    try:
        return from_mapping(FeederConfig, d, "flags")
    except InputError as exc:
        raise InputError(flags.get(exc.field, "flags"), exc.message) from None


def _calibration(rig, runner) -> str:
    """The bar calibration over the replay's sequences of holds (nrmpc_ros/calibration.py), or why it could not
    run, as the report shows it."""
    from ..calibration import calibrate_sequences, describe
    from ..errors import EstimationError

    try:
        return describe(calibrate_sequences(rig, runner.sequences()), rig)
    except EstimationError as exc:
        return f"could not run: {exc}"


@dataclass
class _Pass:
    """One pass of the pipeline over the bag: its runner and input, the rows written, the reference read (in the
    cameras' clock), the batch rows, the rows of the extrinsics files, and the hold estimates (the clock is measured
    from their rotations: :func:`~nrmpc_ros.frontend.imu_clock_check.measure_imu_clock`)."""

    runner: PipelineRunner
    replay: BagReplay
    rows: list
    ref: object
    batch: list
    extrinsics_rows: int | None
    causal_rows: int | None
    estimates: list

    def measured_clock(self, rig):
        """The IMU clock offset this pass still shows (:func:`~nrmpc_ros.frontend.imu_clock_check.
        measure_imu_clock`), or None."""
        return measure_imu_clock(self.runner.pipeline, self.ref, rig, self.estimates)


def _answered(poses) -> None:
    """The causal poses of a frame set where only the smoothed rows are written (nothing to do with them)."""


def _replay_pass(args, bag, rig, cfg, inputs: FeederConfig, image_topics, imu_topic, warn) -> _Pass:
    """The pipeline over the bag with the input settings ``inputs``; writes --out and the other outputs (each
    appears whole when the pass ends: a second pass replaces them)."""
    extrinsics = ExtrinsicsCsv(args.extrinsics, rig) if args.extrinsics else None
    by_hold = extrinsics is not None and imu_topic is None
    causal = ExtrinsicsCsv(args.extrinsics_causal, rig, "--extrinsics-causal") if args.extrinsics_causal else None
    # the frame sets' poses are asked for whenever rows per image are wanted: the smoothed rows answer again the
    # frame sets the pipeline answered while it ran
    on_poses = causal.write if causal is not None else _answered if extrinsics is not None and not by_hold else None
    runner = PipelineRunner(rig, cfg, method=args.method, drops=DropLog(math.inf),  # counts, first ones warned
                            on_poses=on_poses)
    if extrinsics is not None and not by_hold and runner.pipeline.extrinsics is not None:
        runner.pipeline.extrinsics.keep_samples = True  # for the smoothed rows after the run
    if getattr(args, "report", None):
        runner.pipeline.hold_log = []  # every closed hold, for the report
        runner.pipeline.sequence.keep_history = bool(getattr(args, "calibrate_bars", False))
    replay = BagReplay(bag, rig, runner, imu_topic, inputs, warn, image_topics)
    rows, ests = [], []
    with CsvWriter(args.out, "--out") as writer, extrinsics or nullcontext(), causal or nullcontext():
        # --out and the others appear only on success
        for estimates in replay.run(progress=not args.no_progress):
            for est in estimates:
                row = row_from_estimate(est)
                writer.write(row)
                rows.append(row)
                ests.append(est)
                if by_hold:
                    extrinsics.write(hold_poses(rig, est.stamp, est.gravity, runner.pipeline.sequence.rest_turns))
        if extrinsics is not None and not by_hold and runner.pipeline.extrinsics is not None:
            for poses in runner.pipeline.extrinsics.smoothed():  # the final bias from the first sample on
                extrinsics.write(poses)
        ref = read_reference(bag, imu_topic, warn)
        ref = replay.feeder.as_read(ref)  # the IMU's samples in the cameras' clock and in rad/s, as the
        # pipeline read them (an IMU on another clock moved onto the cameras' as it arrived)
        batch = []
        if args.batch:
            method = rows[-1].method if rows else args.method
            batch = batch_rows(runner.pipeline.batch(), method)
            with CsvWriter(args.batch, "--batch") as bw:
                for row in batch:
                    bw.write(row)
    return _Pass(runner, replay, rows, ref, batch, extrinsics.rows if extrinsics is not None else None,
                 causal.rows if causal is not None else None,
                 ests)


def run(args) -> int:
    check_outputs({"--out": args.out, "--batch": args.batch, "--tum": args.tum, "--tum-gt": args.tum_gt,
                   "--extrinsics": args.extrinsics, "--extrinsics-causal": args.extrinsics_causal,
                   "--report": getattr(args, "report", None)},
                  {"BAG": bag_root(args.bag), "--rig": args.rig, "--config": args.config})
    rig = load_rig(args.rig)
    cfg = load_config(args.config, args.seed)
    t_start = time.perf_counter()

    def warn(msg):
        print(f"nrmpc replay: warning: {msg}", file=sys.stderr)

    def note(msg):
        print(f"images: {msg}")

    with BagReader(args.bag) as bag:
        check_tum_flags(args, bag)
        image_topics = bag_image_topics(bag, rig, note)
        imu_topic = resolve_imu_topic(bag, rig, args.imu_topic, use_imu=not args.no_imu, warn=warn)
        check_camera_info(bag, rig, warn)
        by_hold = bool(args.extrinsics) and imu_topic is None
        if args.extrinsics_causal and imu_topic is None:
            raise InputError("--extrinsics-causal", f"needs the IMU ({NO_IMU_NOTE})")
        if by_hold:
            print(f"extrinsics: {NO_IMU_NOTE}")
        elif args.extrinsics and imu_mount_warning(rig):
            warn(imu_mount_warning(rig))
        inputs = input_config(args)

        def units_said(units, before):
            st, given = before.runner.stats, units_pass.inputs
            print(f"IMU units: {describe_units(units)}; the pass gave {st.estimates} estimates of {st.holds} holds; "
                  f"replaying with --imu-gyro-scale {given.imu_gyro_scale:.7g} --imu-accel-scale "
                  f"{given.imu_accel_scale:.7g} (a scale of 1 keeps the samples as they are)")

        units_pass = UnitsMeasuringPass(
            lambda given: _replay_pass(args, bag, rig, cfg, given, image_topics, imu_topic, warn), inputs,
            lambda p: p.runner.pipeline, units_said,
            measure=args.imu_gyro_scale is None and args.imu_accel_scale is None and imu_topic is not None)

        def axes_said(axes, before):
            said = f"IMU axes: {describe_imu_axes(axes, rig.imu.rotation)}"
            if not axes.applies:
                print(said)
                return
            st, q = before.runner.stats, run_pass.inner.inputs.imu_axes_turn_xyzw
            print(f"{said}; the pass gave {st.estimates} estimates of {st.holds} holds; replaying with "
                  f"--imu-axes-turn={','.join(f'{x:.6f}' for x in q)} (0,0,0,1 keeps the samples as they are)")

        run_pass = AxesMeasuringPass(units_pass, lambda p: p.runner.pipeline,
                                     rig.imu.rotation if rig.imu is not None else np.eye(3), axes_said,
                                     measure=args.imu_axes_turn is None and imu_topic is not None)

        def said(measured, before, passes):
            total = before.replay.feeder.config.imu_clock_offset_s + measured.offset_s
            st = before.runner.stats
            print(f"IMU clock against the cameras ({measured.source.value}): {describe_clock(measured)}; pass "
                  f"{passes} gave {st.estimates} estimates of {st.holds} holds; replaying with "
                  f"--imu-clock-offset {total:.3f} (--imu-clock-offset 0 keeps the stamps as they are)")

        if args.imu_clock_offset is None and imu_topic is not None:  # measured and applied
            p, measured, _ = clock_passes(run_pass, lambda q: q.measured_clock(rig), inputs.imu_clock_offset_s,
                                          said, applied=lambda q: q.replay.feeder.config.imu_clock_offset_s)
        else:
            p = run_pass(inputs.imu_clock_offset_s)
            measured = p.measured_clock(rig) if imu_topic is not None else None
    runner, replay, rows, ref, batch = p.runner, p.replay, p.rows, p.ref, p.batch
    elapsed = time.perf_counter() - t_start
    zupt = runner.pipeline.zupt.config  # the IMU reference uses the stillness test as configured for the holds
    ev = evaluate(rows, ref, rig, zupt=zupt)
    st = runner.stats
    print(format_report(ev, per_estimate=not args.quiet))
    if batch:
        evb = evaluate(batch, ref, rig, zupt=zupt)
        gb = evb.stats("gravity_vs_gt_deg")
        gi = evb.stats("gravity_vs_imu_deg")
        parts = [f"vs ground truth median {gb['median']:.3f} deg (n={gb['n']})" if gb["n"] else "",
                 f"vs IMU median {gi['median']:.3f} deg (n={gi['n']})" if gi["n"] else ""]
        print(f"batch (all holds at once, {args.batch}): gravity " + ("; ".join(p for p in parts if p) or
                                                                       f"of {len(batch)} holds written"))
    seqs = write_trajectories(rows, args.tum, ref, args.tum_gt) if args.tum else sequence_errors(rows, ref)
    print(describe_trajectories(seqs))
    d = st.as_dict()
    print(f"frames {st.frames}, holds {st.holds}, estimates {st.estimates} "
          f"({', '.join(f'{m}: {n}' for m, n in sorted(st.methods.items())) or 'none'}), sequences {st.sequences}"
          + (f" ({st.merges} merged back, {st.bridges} bridged by the gyro)" if st.merges or st.bridges else ""))
    turns = runner.pipeline.sequence.rest_turns
    if turns is not None:  # the rig file gave rotation_std_deg: the rest rotations' errors were estimated
        print("rig file's rest rotations, estimated off by (deg, rotation_std_deg beside): " + ", ".join(
            f"{c.name} {math.degrees(rotation_angle(E)):.3f} ({c.rotation_std_deg:g})"
            for c, E in zip(rig.cameras, turns) if c.rotation_std_deg > 0))
    if st.holds:
        print(f"holds: median settle {d['median_settle_s']:.2f} s after the stop (slowest bar period "
              f"{runner.pipeline.bar_period_s:.3f} s), residual motion {d['median_residual_px']:.3f} px, track noise "
              f"{d['median_noise_px']:.3f} px per frame -> {d['median_averaged_noise_px']:.3f} px averaged over "
              f"{np.median(st.settled_frames):.0f} settled frames"
              + (f"; {st.ringing_holds} of {st.holds} measured at the fitted rest of their ringing"
                 if st.ringing_holds else "")
              + (f"; {st.penalized_holds} carried residual ringing as extra noise (median "
                 f"{d['median_ringing_px']:.3f} px; from "
                 f"{', '.join(f'{k} {v}' for k, v in sorted(st.ringing_sources.items()))})"
                 if st.penalized_holds else ""))
    if st.dropped:
        print("not estimated: " + "; ".join(f"{k.message}: {v}" for k, v in sorted_counts(st.dropped)))
    if st.gravity_withheld:
        print("estimated without gravity: " + "; ".join(f"{k.value}: {v}"
                                                       for k, v in sorted_counts(st.gravity_withheld)))
    if not st.holds:
        print(runner.pipeline.no_hold_report() or "no hold found: no frame set reached the pipeline")
    print(f"inputs dropped: {replay.drops.summary()}")
    alike = replay.feeder.events["imu samples stamped alike"]
    if alike:
        print(f"IMU samples stamped alike: {alike} (a driver that reads them in batches; each batch spread evenly "
              f"over the interval since the stamp before it)")
    frozen = [replay.feeder.name_of(i) for i in [*range(rig.num_cameras), IMU] if replay.feeder.stamped_by_arrival(i)]
    if frozen:
        print(f"stamps that do not advance (header.stamp unset?): {', '.join(frozen)}; stamped by the recording time")
    for rebase in replay.feeder.rebases:
        print(f"{'IMU' if rebase.stream == IMU else 'camera'} clock: "
              f"{rebase.describe(replay.feeder.name_of(rebase.stream))}")
    jumps = replay.feeder.events["time jumps back"]
    if jumps:
        print(f"time jumps back: {jumps} (each started a new sequence)")
    print(f"camera sync: {replay.feeder.sync.describe()}")
    times = [r.time_ms for r in rows]
    if times:
        print(f"hold time (linking + estimation): median {np.median(times):.0f} ms; wall time {elapsed:.1f} s")
    if imu_topic is not None:
        clock = runner.pipeline.imu_clock.estimate()
        found = "not measurable (no move both show)"
        if clock is not None:
            found = (f"{1e3 * clock.offset_s:+.1f} +- {1e3 * clock.std_s:.1f} ms (correlation {clock.correlation:.2f}"
                     f" over {clock.frames} frames in {clock.moves} moves; on top of the offset applied, "
                     f"{1e3 * (replay.feeder.config.imu_clock_offset_s + cfg.imu_time_offset_s):+.1f} ms): ")
            found = "add " + found + "add it to the IMU stamps" if clock.significant else \
                "no offset shown, " + found + f"within {SIGNIFICANT_STDS:g} std of zero"
        print("IMU clock against the cameras (gyro rate vs image motion): " + found)
        noise = runner.pipeline.zupt.noise_in_use
        if noise is not None:
            print(f"IMU stillness test: {describe_noise(noise, runner.pipeline.zupt.config)}")
            since = st.covariance_distrusted_at
            if since is not None:
                print(f"IMU covariances: not used from {since:.3f} s: the images held still for "
                      f"{IMAGES_STILL_WINDOWS} stillness-test windows where the noise they claim read every window "
                      f"as motion and the quietest windows showed more (a low-pass filtered IMU?); the samples' own "
                      f"noise since (zupt.use_covariance: false from the start)")
            scale = describe_accel_scale(noise, runner.pipeline.rig.gravity_magnitude)
            if scale:
                print(f"IMU scale: {scale}")
            tilt = describe_tilt(runner.pipeline.accel_tilt, runner.pipeline.extrinsics)
            if tilt:
                print(f"IMU bias: {tilt}")
            weights = [w for w in (r.extra.get("imu_calibrated_weight") for r in rows) if w is not None]
            if weights:
                print(f"IMU calibration: a calibrated accelerometer's tilt ({cfg.imu_bias_sigma_deg:g} deg) weighed "
                      f"{np.median(weights):.2f} against its bias as the norms leave it open (median of "
                      f"{len(weights)} estimates; 1: the images and norms agree with a calibrated chip, 0: they "
                      f"refute one)")
            gyro_noise = describe_gyro_noise(noise) if args.imu_gyro_scale is None and \
                replay.feeder.config.imu_gyro_scale == 1.0 else None  # (a scale given: the user's word stands)
            if gyro_noise:
                print(f"IMU gyro units: {gyro_noise}")
        gaps = describe_gaps(runner.pipeline.imu)
        if gaps:
            print(f"IMU gaps: {gaps}")
        check = runner.pipeline.estimator.imu_check
        refuted = describe_check(check)
        if refuted:
            print(f"IMU gravity: {refuted}")
        if measured is not None:
            print(f"IMU clock against the cameras ({measured.source.value}): {describe_clock(measured)}: each hold's "
                  f"IMU samples are another moment's: replay with --imu-clock-offset "
                  f"{replay.feeder.config.imu_clock_offset_s + measured.offset_s:.3f} (the node: "
                  f"input.imu_clock_offset_s), or fix the IMU's clock")
    if p.extrinsics_rows is not None:
        cost = f", {1e3 * runner.poses_s / runner.poses_sets:.3f} ms per frame set" if runner.poses_sets else ""
        print(f"wrote {p.extrinsics_rows} camera poses to {args.extrinsics} "
              f"({'holds, static model' if by_hold else 'every image, bars driven by the IMU'}{cost})")
        bias = runner.pipeline.extrinsics.bias_estimate if runner.pipeline.extrinsics is not None else None
        if not by_hold and bias is not None:
            print(f"  with the final accelerometer bias "
                  f"{np.array2string(bias.bias_ms2, precision=4)} +- {np.array2string(bias.std_ms2, precision=4)} "
                  f"m/s^2 (IMU frame, {bias.holds} holds, {bias.with_gravity} with vision gravity) from the start")
    if p.causal_rows is not None:
        print(f"wrote {p.causal_rows} camera poses to {args.extrinsics_causal} (as the node publishes them: the "
              f"accelerometer bias known at each image)")
    if not getattr(args, "scratch_out", False):  # nrmpc report's CSV is a temporary file
        print(f"wrote {len(rows)} estimates to {args.out}")
    if getattr(args, "report", None):
        from ..report import collect, write_report

        t_report = time.perf_counter()
        calibration = _calibration(rig, runner) if getattr(args, "calibrate_bars", False) else None
        size = write_report(collect(str(args.bag), runner, replay.drops.counts(), ref, ev, calibration), args.report,
                            "--report")
        print(f"wrote the report {args.report} ({size / 1e6:.2f} MB in {time.perf_counter() - t_report:.2f} s)")
    return 0
