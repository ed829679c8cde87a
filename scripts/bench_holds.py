#!/usr/bin/env python3
"""The pipeline on bags recorded the way users record them: a matrix of styles x rigs against the targets.

    python scripts/bench_holds.py [--quick | --full] [--seeds 1] [--out /tmp/nrmpc_bench_matrix] [--workers 1]
                                  [--methods auto,6pt-bending] [--json results.json]
    python scripts/bench_holds.py --vga [--styles all] [--rigs all] [--seeds 1]   # the VGA style table
    python scripts/bench_holds.py --random 24 [--random-start 0] [--workers 2]   # recordings drawn at random

Matrix (the default, docs/RESULTS.md): small bags (320x240, f = 235 px, one ray per pixel, six holds, bars
ringing with damping ratio 0.05) rendered once into --out with :func:`nrmpc_ros.render.bagmaker.make_bag`
(reused when they exist; delete the folder to re-render). Rigs: 2 to 6 cameras (``line2`` two cameras on one
bar, ``ring3``, ``cross4``, ``ring5``, ``ring6``), each with soft (2 Hz) or stiff (6 Hz) bars, and ``ring3-mixed``
and ``cross4-mixed``: soft (1.5 Hz) and stiff (8 Hz) bars in turn on one body. Styles (holds at 10 Hz, IMU at
200 Hz unless said): ``imu100`` / ``imu200`` / ``imu500`` the IMU rate; ``snap0.5`` one image per camera 0.5 s
after each stop; ``snap0.15`` one 0.15 s after each stop, IMU at 50 Hz (its stillness window,
0.18 s, is longer than that); ``camrates`` each camera its own rate (10, 15, 30, 20, 12, 25 Hz) and phase;
``exposure`` auto-exposure drift (gain 1 +- 0.3, 10 s periods); ``creep`` random 2-4 s holds of which a third
creep at 0.5 deg/s (not still); ``imuclock`` random 1.5-3.5 s holds and an IMU clock 15 ms off the cameras';
``swsync`` software-synchronised cameras streaming through the moves (+-8 ms stamp jitter, 2 % of frames
dropped), bars damped at 0.03 that ring through the holds, IMU at 1000 Hz; ``noimu`` no IMU at all, a 30 Hz
stream through the moves (+-3 ms stamps), bars damped at 0.03 that ring through the holds (the images alone
tell the holds: ``6pt-bending`` only); ``imubar`` the IMU inside the second camera (a camera module with an
IMU), riding on its bar, which rings through the holds (damping 0.03); ``imudlpf`` a 1 kHz IMU that low-pass
filters its output at 40 Hz (a MEMS IMU's digital filter: its noise correlated over a dozen samples); ``imucov``
an IMU whose messages' covariances claim a fifth of its noise (a driver's datasheet figure); ``imuclock2s`` a
stream through the moves with the IMU stamped 2 s late (another clock: replayed, as ``nrmpc replay`` does, with
the offset the recording shows); ``imuswing`` the IMU inside the second camera on a stream at 15 Hz through
abrupt (trapezoidal) moves, IMU at 400 Hz, bars damped at 0.02: the tip swings by tenths of a radian after a stop;
``imusnap`` one image per camera 0.3 s after each stop, the IMU (100 Hz) inside the first camera, bars damped at
0.02: the snapshots catch the bars ringing by tens of pixels and the images tell gravity hardly at all;
``imuraw`` an accelerometer nobody calibrated (bias 0.6 m/s^2, 3.5 deg of tilt, and each axis's scale within
+-2 %); ``gyrodeg`` a gyro driver that writes deg/s (the cameras record only the holds: the unit is measured
from the turns between them, as ``nrmpc replay`` does); ``vibration`` a running motor the IMU reads all along (1.5 m/s^2
RMS at 45 Hz, with its rocking on the gyro), which the Imu messages' covariances do not claim; ``imuhost`` an IMU
at 400 Hz stamped when the host reads it (up to 6 ms late, in batches of one stamp); ``imucounter`` an IMU stamped
by its own counter (1000 s at the first frame; replayed as ``nrmpc replay`` does, moved onto the cameras' clock by
the recording times); ``camcounter`` the second camera stamped by its own counter (2500 s at the first frame);
``unstamped`` the second camera's and the IMU's drivers leave header.stamp at 0 (stamped by the recording time);
``imuaxes`` a rig file whose IMU axes are turned 38 deg off the IMU's (the rotation vector (30, -20, 10) deg, as a
rig file written by hand; replayed as ``nrmpc replay`` does: the axes measured from the turns between holds);
``imuloss`` a 1 kHz IMU whose link lost 5 % of its samples in runs of 30 ms on average, the cameras streaming
through the moves; ``blur`` a 15 Hz stream whose images integrate 30 ms from their stamps (an indoor exposure:
the moves smear by up to tens of pixels, the images' content is 15 ms later than their stamps); ``slow`` holds
at 5 Hz with the IMU at 50 Hz and ``fast`` a 60 Hz stream through the moves with the IMU at 1 kHz (the ends of
the camera and IMU rates users record at); ``far`` ten snapshots with moves of up to a metre and more across the
rendered room (positions drawn from a cube of 1.6 m), so that some holds share too few landmarks with any other
and start sequences of their own (the breaks a rig carried from place to place makes); ``walker`` someone walking
back and forth through the room at 1.2 m/s, through the holds (its corners move while the rig holds still);
``calib`` a rig file whose cameras' rest rotations are off by a calibration's error, 0.05 deg per axis, and
say so (``rotation_std_deg``), as a real rig's calibration is (gravity rests on the bends those rotations
measure: docs/PIPELINE.md, "The rig file's calibration").
``--full`` runs every style on every rig; ``--quick`` (the default) one rig per style, every camera count and
both bar stiffnesses among them. ``--seeds N`` renders every cell with seeds 0 to N-1 (other hold attitudes,
noise and IMU biases: one seed is one draw of the accelerometer's bias for every cell, so a share within the stds
over one seed tells little), and the table ends with the share within 1, 2 and 3 stds of every published gravity
together, per method.

``--random N`` replaces the matrix by N recordings drawn at random (:func:`random_recording`, seeds from
``--random-start``): every feature of the styles above, combined as no style combines them (a 5 Hz camera beside
a 20 Hz one on a 1.6 Hz bar ringing through 2 s holds, a third of them creeping, under a noisy 400 Hz IMU); each
recording's recipe is printed after the table. The styles test one habit each; users have several at once.

Every bag is replayed with each method through the same loop as ``nrmpc replay``. Per bag and method:
coverage of the still holds after the first (target >= 0.9); estimates stamped in a creeping hold or while
moving (target 0: ``/ground_truth/angular_velocity`` non-zero, or outside every still hold of the ground
truth); median gravity error against ground truth; the IMU-only error (the accelerometer's still samples
within +-0.25 s of each still hold's ground-truth stamps: :mod:`nrmpc_ros.frontend.imu_reference`); ``auto``
(4pt-bending) against it (target <= 0.75x);
``6pt-bending`` median (target <= 0.3 deg on three to six cameras, <= 0.6 deg on two cameras on one bar); the
share of published gravities within 1, 2 and 3 of their own standard deviations (``gravity_sigma_deg``) of the
truth (target >= 95 % within 3). Beside the error, the Cramér-Rao bound of each published gravity at the bag's
true geometry (:func:`estimate_bounds`; median over the cell's estimates) and the median error over it: near 1
the estimate is as good as that noise and bending allow, well above 1 it leaves accuracy behind. The bags are
kept: a second run scores them again without rendering.

The ``--vga`` table: for each rig (two cameras on one straight bar, three cameras of
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
from nrmpc_ros.config import from_mapping, load_mapping
from nrmpc_ros.core import load_rig, save_rig
from nrmpc_ros.core.bundle import GravityPriors, Observations, RotationPrior
from nrmpc_ros.core.dynamics import bar_natural_frequencies, ringing_decay_time
from nrmpc_ros.core.rig import Camera, Rig
from nrmpc_ros.core.sequence_steps import CORRESPONDENCE_BIAS_FLOOR_PX
from nrmpc_ros.core.so3 import angle_between, exp_so3
from nrmpc_ros.experiments.crlb import observed_sequence_bound
from nrmpc_ros.frontend.estimates_csv import batch_rows, row_from_estimate
from nrmpc_ros.frontend.estimation import ringing_noise_rad
from nrmpc_ros.frontend.evaluation import evaluate, static_holds
from nrmpc_ros.frontend.feeder import FeederConfig
from nrmpc_ros.frontend.imu_clock_check import clock_passes, measure_imu_clock
from nrmpc_ros.frontend.imu_mount import AxesMeasuringPass
from nrmpc_ros.frontend.imu_reference import ImuReference
from nrmpc_ros.frontend.imu_units import UnitsMeasuringPass
from nrmpc_ros.frontend.pipeline import Pipeline, PipelineConfig
from nrmpc_ros.frontend.reference import STAMP_TOLERANCE_S, nearest_stamp, read_reference
from nrmpc_ros.frontend.replay import BagReplay, resolve_imu_topic
from nrmpc_ros.render.bagmaker import ANGULAR_VELOCITY_TOPIC, BagOptions, make_bag
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
                    bag_rig, bag_opts, _ = style_rig(rig, bo)
                    summary = make_bag(bag_rig, path, BagOptions(motion=MotionOptions(**mo), seed=seed, **bag_opts),
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


def replay_rows(path: Path, rig, method: str, with_holds: bool = False, keep: list | None = None,
                config: PipelineConfig | None = None):
    """Replay one bag with one method: (rows, reference, pipeline, wall s, the ground truth's still holds or
    None). ``keep``, a list, receives the hold estimates themselves, and the pipeline then keeps every
    sequence and measured hold (what :func:`estimate_bounds` needs)."""
    t0 = time.perf_counter()
    with BagReader(path) as bag:
        imu_topic = resolve_imu_topic(bag, rig, warn=lambda m: None)
        ref = read_reference(bag, imu_topic)

        def one_pass(inputs):  # as nrmpc replay: the gyro's unit, the IMU's axes and its clock measured and applied
            pipe = Pipeline(rig, config or PipelineConfig(), method=method)
            if keep is not None:
                pipe.sequence.keep_history = True
                pipe.measured_holds = []
            replay = BagReplay(bag, rig, pipe, imu_topic, inputs, warn=lambda m: None)
            ests = [e for es in replay.run() for e in es]
            return pipe, ests, replay.feeder.as_read(ref), replay.feeder.config.imu_clock_offset_s

        run_pass = AxesMeasuringPass(UnitsMeasuringPass(one_pass, FeederConfig(), lambda result: result[0],
                                                        measure=imu_topic is not None),
                                     lambda result: result[0], rig.imu.rotation if rig.imu is not None else np.eye(3),
                                     measure=imu_topic is not None)

        def measure(result):
            pipe, ests, shifted, _ = result
            return measure_imu_clock(pipe, shifted, rig, ests) if imu_topic is not None else None

        (pipe, ests, ref, _), _, _ = clock_passes(run_pass, measure, applied=lambda result: result[3])
        if keep is not None:
            keep.extend(ests)
        rows = [row_from_estimate(e) for e in ests]
        holds = still_holds(bag, ref) if with_holds else None
    return rows, ref, pipe, time.perf_counter() - t0, holds


def run_bag(path: Path, rig_file: Path, method: str) -> dict:
    rig = load_rig(rig_file)
    rows, ref, pipe, wall, _ = replay_rows(path, rig, method)
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


def vga_main(argv=None) -> int:
    """The VGA style table (``--vga``)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--vga", action="store_true")
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




# -- the matrix ------------------------------------------------------------------------------------------------

SMALL = (320, 240)
SMALL_FOCAL = 235.0
BAR_HZ = {"soft": 2.0, "stiff": 6.0}  # the project's bars span 1.5-8 Hz
MASS, BAR_LENGTH = 0.1, 0.4
MIXED_BAR_HZ = (1.5, 8.0)  # the mixed rigs' bars in turn: both ends of the project's range
MIXED_CAMERAS = (3, 4)
SUPERSAMPLE = 1  # one ray per pixel: a quarter of the rendering time of 2 x 2 (as the test recordings)
DAMPING = 0.05  # a lightly damped bar: ringing falls to 1e-3 after 22 s at 2 Hz, 7 s at 6 Hz
IMU_AXES_TURN_DEG = (30.0, -20.0, 10.0)  # the imuaxes style's rig file: its IMU turned 38 deg off the IMU's axes
CALIBRATION_ERROR_DEG = 0.05  # the calib style: each camera's rest rotation off by a random turn of this std per axis
LAYOUT = {2: "line", 3: "ring", 4: "cross", 5: "ring", 6: "ring"}
CAMERA_RATES = (10.0, 15.0, 30.0, 20.0, 12.0, 25.0)
# 6pt-bending's median: 0.3 deg on rigs of three to six cameras, 0.6 deg on two cameras on one bar
TARGETS = {"coverage": 0.9, "bad": 0, "ratio_4pt": 0.75, "median_6pt_deg": 0.3, "median_6pt_bar_deg": 0.6,
           "within3": 0.95}


def _bar_EI(hz: float) -> float:
    """Flexural rigidity (N m^2) of the matrix's bars for a natural frequency hz: f = sqrt(3 EI / (m L^3)) / 2 pi."""
    return (2.0 * math.pi * hz) ** 2 * MASS * BAR_LENGTH**3 / 3.0


def matrix_rigs() -> dict:
    """'<layout><M>-<soft|stiff|mixed>' -> Rig: 2 to 6 cameras, soft and stiff bars, an IMU at the body centre;
    the ``mixed`` rigs (3 and 4 cameras) carry both ends of the bars' range on one body, soft and stiff bars in
    turn (a wing and a fuselage mast)."""
    out = {}
    for M, layout in LAYOUT.items():
        for bar, hz in BAR_HZ.items():
            out[f"{layout}{M}-{bar}"] = make_rig(RigSpec(num_cameras=M, layout=layout, focal=SMALL_FOCAL,
                                                         resolution=SMALL, EI=_bar_EI(hz), mass=MASS,
                                                         bar_length=BAR_LENGTH))
        if M in MIXED_CAMERAS:
            rig = out[f"{layout}{M}-soft"]
            cams = tuple(replace(c, EI=_bar_EI(MIXED_BAR_HZ[i % 2])) for i, c in enumerate(rig.cameras))
            out[f"{layout}{M}-mixed"] = replace(rig, cameras=cams, source=f"<{M} cameras, soft and stiff bars>")
    return out


def matrix_styles() -> dict:
    """Style -> function of the camera count giving (MotionOptions kwargs, BagOptions kwargs)."""
    base = {"views": 6, "hold_seconds": 2.5, "min_move_seconds": 1.0, "rate": 10.0}
    bag = {"damping": DAMPING}

    def rates(M):
        return {"camera_rates": CAMERA_RATES[:M], "camera_phases_ms": tuple(7.0 * i for i in range(M))}

    return {
        "imu100": lambda M: ({**base, "imu_rate": 100.0}, bag),
        "imu200": lambda M: ({**base, "imu_rate": 200.0}, bag),
        "imu500": lambda M: ({**base, "imu_rate": 500.0}, bag),
        "snap0.5": lambda M: ({**base, "capture": "snapshot", "snapshot_delay": 0.5}, bag),
        "snap0.15": lambda M: ({**base, "capture": "snapshot", "snapshot_delay": 0.15, "imu_rate": 50.0}, bag),
        "camrates": lambda M: ({**base, **rates(M)}, bag),
        "exposure": lambda M: (base, {**bag, "exposure_drift": 0.3, "exposure_period_s": 10.0}),
        "creep": lambda M: ({**base, "views": 7, "hold_seconds_range": (2.0, 4.0), "creep_fraction": 1 / 3,
                             "creep_deg_per_s": 0.5}, bag),
        "imuclock": lambda M: ({**base, "hold_seconds_range": (1.5, 3.5)}, {**bag, "imu_time_offset_ms": 15.0}),
        "swsync": lambda M: ({**base, "capture": "stream", "imu_rate": 1000.0},
                             {"damping": 0.03, "jitter_ms": 8.0, "drop_rate": 0.02}),
        "noimu": lambda M: ({**base, "capture": "stream", "rate": 30.0},
                            {"damping": 0.03, "jitter_ms": 3.0, "imu": False}),
        "imubar": lambda M: (base, {"damping": 0.03, "imu_camera": 1}),
        "imuswing": lambda M: ({**base, "capture": "stream", "rate": 15.0, "imu_rate": 400.0,
                                "move_profile": "trapezoid"}, {"damping": 0.02, "imu_camera": 1}),
        "imusnap": lambda M: ({**base, "views": 12, "capture": "snapshot", "snapshot_delay": 0.3, "imu_rate": 100.0},
                              {"damping": 0.02, "imu_camera": 0}),
        "imudlpf": lambda M: ({**base, "imu_rate": 1000.0}, {**bag, "imu_lowpass_hz": 40.0}),
        "imucov": lambda M: (base, {**bag, "imu_covariance_scale": 0.2}),
        "imuclock2s": lambda M: ({**base, "capture": "stream"}, {**bag, "imu_time_offset_ms": 2000.0}),
        "imuraw": lambda M: (base, {**bag, "imu_bias": 0.6, "accel_scale_error": 0.02}),
        "gyrodeg": lambda M: (base, {**bag, "gyro_unit": "deg/s"}),
        "vibration": lambda M: (base, {**bag, "vibration": 1.5, "vibration_hz": 45.0}),
        "imuhost": lambda M: ({**base, "imu_rate": 400.0}, {**bag, "imu_stamp_jitter_ms": 6.0}),
        "imucounter": lambda M: (base, {**bag, "imu_clock_start_s": 1000.0}),
        "camcounter": lambda M: (base, {**bag, "camera_clock_start_s": (None, 2500.0) + (None,) * (M - 2)}),
        "unstamped": lambda M: (base, {**bag, "unstamped": ("1", "imu")}),
        "imuaxes": lambda M: (base, {**bag, "rig_imu_turn_deg": IMU_AXES_TURN_DEG}),
        "imuloss": lambda M: ({**base, "capture": "stream", "imu_rate": 1000.0},
                              {**bag, "imu_loss": 0.05, "imu_loss_burst_ms": 30.0}),
        "blur": lambda M: ({**base, "capture": "stream", "rate": 15.0}, {**bag, "shutter_ms": 30.0}),
        "slow": lambda M: ({**base, "rate": 5.0, "imu_rate": 50.0}, bag),
        "fast": lambda M: ({**base, "capture": "stream", "rate": 60.0, "imu_rate": 1000.0}, bag),
        "far": lambda M: ({**base, "views": 10, "capture": "snapshot", "max_translation": 0.8}, bag),
        "walker": lambda M: (base, {**bag, "walker_speed": 1.2}),
        "calib": lambda M: (base, {**bag, "rig_rotation_error_deg": CALIBRATION_ERROR_DEG}),
    }


def style_rig(rig: Rig, bag: dict) -> tuple:
    """(rig, BagOptions kwargs, rig file suffix) of a style: without an IMU, or with the IMU inside camera
    ``imu_camera`` (axes along the camera's: a camera module with an IMU, riding on that camera's bar). A style's
    ``rig_imu_turn_deg`` turns the rig file's IMU only (:func:`file_rig`): the bag is rendered with the true one."""
    bag = dict(bag)
    if bag.pop("rig_imu_turn_deg", None) is not None:
        rig, bag, suffix = style_rig(rig, bag)
        return rig, bag, suffix + "-imu-turned"
    error = bag.pop("rig_rotation_error_deg", None)
    if error is not None:
        rig, bag, suffix = style_rig(rig, bag)
        return rig, bag, suffix + f"-calib{error:g}"
    if not bag.get("imu", True):  # its own rig file: another style on this rig reads the IMU from its file
        return replace(rig, imu=None), bag, "-no-imu"
    if "imu_camera" in bag:
        name = rig.cameras[bag.pop("imu_camera")].name
        return rig.with_imu_in(name), bag, f"-imu-in-{name}"
    return rig, bag, ""


QUICK = [("imu100", "ring3-stiff"), ("imu200", "ring3-stiff"), ("imu500", "cross4-soft"),
         ("snap0.5", "line2-soft"), ("snap0.15", "cross4-soft"), ("camrates", "ring5-stiff"),
         ("exposure", "ring6-soft"), ("creep", "cross4-stiff"), ("imuclock", "line2-stiff"), ("swsync", "line2-soft"),
         ("noimu", "ring3-soft"), ("imubar", "ring5-soft"), ("imudlpf", "ring6-stiff"), ("imucov", "cross4-soft"),
         ("imuclock2s", "ring3-soft"), ("imuswing", "cross4-soft"), ("imuraw", "ring3-stiff"),
         ("gyrodeg", "line2-soft"), ("vibration", "cross4-stiff"), ("imuhost", "ring5-soft"),
         ("imucounter", "ring6-soft"), ("camcounter", "ring3-stiff"), ("unstamped", "cross4-soft"),
         ("imuaxes", "ring5-stiff"), ("imuloss", "ring6-stiff"), ("blur", "line2-soft"), ("slow", "line2-soft"),
         ("fast", "ring3-stiff"), ("far", "cross4-soft"), ("walker", "cross4-soft"),
         ("calib", "ring3-soft"), ("calib", "cross4-stiff")]


RANDOM_HABITS = (("encoding", "jpeg"), ("walker_speed", 1.2), ("vibration", 1.5), ("gyro_unit", "deg/s"),
                 ("accel_unit", "g"), ("imu_lowpass_hz", 40.0), ("imu_stamp_jitter_ms", 6.0), ("imu_loss", 0.05),
                 ("camera_latency_ms", 40.0), ("shutter_ms", 20.0), ("imu_clock_start_s", 1000.0),
                 ("imu_covariance_scale", 0.2), ("imu_bias", 0.6))
"""Habits a random recording takes, each with probability RANDOM_HABIT_P (with its companions: an uncalibrated
chip's scales, lost samples' bursts, a motor's frequency)."""
RANDOM_HABIT_P = 0.12


def random_recording(seed: int) -> tuple:
    """(rig, MotionOptions kwargs, BagOptions kwargs, recipe) of a recording drawn at random: 2 to 6 cameras,
    each bar its own frequency within 1.5-8 Hz, damping 0.02-0.12, holds of random length, snapshots at any time
    after the stop, streams or holds at 5-60 Hz, each camera its own rate and phase in some, an IMU at 50-1000 Hz
    (or none) with its noise, biases and clock offset drawn, inside a camera in some, creeping holds in some, and
    each of :data:`RANDOM_HABITS` in some: the styles' features combined as no style combines them."""
    r = np.random.default_rng(seed)
    M = int(r.integers(2, 7))
    hz = np.exp(r.uniform(math.log(1.5), math.log(8.0), M))
    rig = matrix_rigs()[f"{LAYOUT[M]}{M}-soft"]
    rig = replace(rig, cameras=tuple(replace(c, EI=_bar_EI(float(h))) for c, h in zip(rig.cameras, hz)),
                  source=f"<{M} cameras, bars {hz.min():.1f}-{hz.max():.1f} Hz>")
    capture = str(r.choice(["holds", "snapshot", "stream"], p=[0.45, 0.25, 0.3]))
    rate = float(r.choice([5, 10, 15, 20, 30, 60], p=[0.1, 0.3, 0.2, 0.15, 0.15, 0.1]))
    imu = bool(r.random() > 0.12)
    imu_rate = float(r.choice([50, 100, 200, 400, 1000]))
    mo = {"views": int(r.integers(5, 9)), "rate": rate, "imu_rate": imu_rate, "capture": capture,
          "hold_seconds_range": (float(r.uniform(1.2, 2.5)), float(r.uniform(2.5, 5.0))),
          "min_move_seconds": float(r.uniform(0.5, 1.5)), "speed": float(r.uniform(15, 60)),
          "move_profile": str(r.choice(["cosine", "min-jerk", "trapezoid"]))}
    if capture == "snapshot":
        mo["snapshot_delay"] = float(r.uniform(0.08, 1.0))
    if r.random() < 0.25:
        mo["camera_rates"] = tuple(float(x) for x in r.choice([5, 10, 12, 15, 20, 25, 30], M))
        mo["camera_phases_ms"] = tuple(float(r.uniform(0, 1000.0 / x)) * 0.9 for x in mo["camera_rates"])
    if r.random() < 0.15 and capture != "snapshot":
        mo["creep_fraction"] = 1 / 3

    def sometimes(p, draw):  # the coin first, then the value: the draws' order is the recordings' identity
        return draw() if r.random() < p else 0.0

    bo = {"damping": float(np.exp(r.uniform(math.log(0.02), math.log(0.12)))), "imu": imu,
          "imu_bias": float(r.choice([0.02, 0.05, 0.1, 0.3])), "gyro_bias": float(r.uniform(0.0005, 0.01)),
          "imu_noise": float(r.uniform(0.01, 0.08)), "gyro_noise": float(r.uniform(0.001, 0.006)),
          "imu_time_offset_ms": sometimes(0.4, lambda: float(r.uniform(-20, 20))),
          "jitter_ms": sometimes(0.4, lambda: float(r.uniform(0, 8))),
          "drop_rate": sometimes(0.3, lambda: float(r.uniform(0, 0.03))),
          "exposure_drift": 0.3 if r.random() < 0.2 else 0.0, "exposure_period_s": 10.0}
    if bo["imu"] and r.random() < 0.2:
        bo["imu_camera"] = int(r.integers(0, M))
    for key, value in RANDOM_HABITS:
        if r.random() < RANDOM_HABIT_P:
            bo[key] = value
            bo.update({"imu_bias": {"accel_scale_error": 0.02}, "imu_loss": {"imu_loss_burst_ms": 30.0},
                       "vibration": {"vibration_hz": 45.0}}.get(key, {}))
    if not bo["imu"]:
        mo.pop("imu_rate")
    recipe = ", ".join([f"{capture} at {mo['rate']:g} Hz"] + [f"{k}={_recipe_value(v)}" for k, v in
                                                               sorted({**mo, **bo}.items())
                                                               if k not in ("capture", "rate")])
    return rig, mo, bo, recipe


def _recipe_value(v) -> str:
    if isinstance(v, (tuple, list)):
        return "(" + ",".join(_recipe_value(x) for x in v) + ")"
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def render_random(out: Path, seed: int) -> tuple:
    """(bag dir, rig file, rig, recipe) of random recording ``seed`` (:func:`random_recording`), rendered if
    missing (written beside, then renamed)."""
    rig, mo, bo, recipe = random_recording(seed)
    rig, bo, _ = style_rig(rig, bo)
    rig_file = out / f"random-{seed}.yaml"
    if not rig_file.exists():
        save_rig(rig, rig_file, header=f"rig of scripts/bench_holds.py --random ({recipe})")
    path = out / f"random-{seed}"
    _render_once(path, rig, BagOptions(motion=MotionOptions(**mo), seed=seed, supersample=SUPERSAMPLE, **bo))
    return path, rig_file, rig, recipe


def _render_once(path: Path, rig: Rig, options: BagOptions) -> None:
    """Render the bag ``path`` unless it exists: written beside it, then renamed (never half a bag)."""
    if path.exists():
        return
    tmp = path.parent / (path.name + ".partial")
    if tmp.exists():
        import shutil

        shutil.rmtree(tmp)
    t0 = time.perf_counter()
    make_bag(rig, tmp, options, progress=False)
    tmp.rename(path)
    print(f"rendered {path.name} in {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)


def file_rig(rig: Rig, bag: dict) -> Rig:
    """The rig the style's rig file carries: the rendered one, its IMU turned by ``rig_imu_turn_deg`` (a rotation
    vector in deg, as ``nrmpc make-bag --rig-imu-turn-deg``) and its cameras' rest rotations calibrated to
    ``rig_rotation_error_deg`` (``nrmpc make-bag --rig-rotation-error-deg``) where the style gives them."""
    turn = bag.get("rig_imu_turn_deg")
    if turn is not None:
        rig = replace(rig, imu=replace(rig.imu, rotation=exp_so3(np.radians(turn)) @ rig.imu.rotation))
    error = bag.get("rig_rotation_error_deg")
    if error is not None:  # drawn as nrmpc make-bag --rig-rotation-error-deg draws it for seed 0
        rig = rig.with_rotation_errors(error, np.random.default_rng(np.random.SeedSequence([0, 0xCA1])))
    return rig


def matrix_cells(full: bool) -> list:
    """(style, rig) pairs of the quick subset or of the full matrix."""
    if not full:
        return list(QUICK)
    return [(s, r) for r in matrix_rigs() for s in matrix_styles()]


def render_cell(out: Path, style: str, rig_name: str, seed: int = 0, supersample: int = SUPERSAMPLE) -> tuple:
    """(bag dir, rig file) of one cell, rendered if missing (written beside, then renamed: never half a bag);
    ``supersample`` rays per pixel side (a bag of another than the default is named for it)."""
    rig = matrix_rigs()[rig_name]
    mo, style_bag = matrix_styles()[style](rig.num_cameras)
    rig, bo, suffix = style_rig(rig, style_bag)
    rig_file = out / f"{rig_name}{suffix}.yaml"
    if not rig_file.exists():
        save_rig(file_rig(rig, style_bag), rig_file, header="rig of scripts/bench_holds.py (matrix)")
    path = out / (f"{style}-{rig_name}-{seed}" + ("" if supersample == SUPERSAMPLE else f"-ss{supersample}"))
    _render_once(path, rig, BagOptions(motion=MotionOptions(**mo), seed=seed, supersample=supersample, **bo))
    return path, rig_file


def still_holds(bag, ref) -> list:
    """(start, end) stamps of the ground truth's holds in which the body is still: of each of static_holds, the
    stamps from its first to its last of zero angular velocity, where none between turns. A hold's ends, the same
    pose to a hundredth of a degree, may be a move's slow start or end (a minimum-jerk move turns at 0.02 rad/s 30
    ms before it stops): trimmed off. A creep's poses, a few ms apart between cameras of other rates, may repeat
    to the tolerance: a run at no stamp of which the body is still is no hold."""
    holds = static_holds(ref)
    if not bag.has_topic(ANGULAR_VELOCITY_TOPIC):
        return holds
    t, w = [], []
    for _, _, msg in bag.messages([ANGULAR_VELOCITY_TOPIC]):
        t.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
        w.append(math.sqrt(msg.vector.x ** 2 + msg.vector.y ** 2 + msg.vector.z ** 2))
    t, w = np.array(t), np.array(w)
    out = []
    for a, b in holds:
        inside = (t >= a) & (t <= b)
        zero = t[inside & (w == 0)]
        if len(zero) and not np.any(w[(t > zero[0]) & (t < zero[-1])] > 0):
            out.append((float(zero[0]), float(zero[-1])))
    return out


def _truth_at(ref, stamp: float):
    """(body -> world rotation, position, gravity in the body frame) of the ground truth at a stamp, or None."""
    i, j = nearest_stamp(ref.pose_t, stamp), nearest_stamp(ref.grav_t, stamp)
    if i is None or j is None:
        return None
    return ref.pose_R[i], ref.pose_p[i], ref.grav_g[j]


def _hold_camera_noise_rad(rig, hold, cam: np.ndarray, fallback_rad: float, ringing: bool) -> np.ndarray:
    """Each bearing's angular std as the pipeline measured it (N,): its (hold, camera)'s averaged track noise
    (one frame's over the root of the settled frames; ``fallback_rad``, the sequence's a posteriori noise, where
    a single frame leaves it unmeasured) with the correspondence-bias floor in quadrature, and with ``ringing``
    the hold's residual ringing as the estimation stage adds it
    (:func:`~nrmpc_ros.frontend.estimation.ringing_noise_rad`)."""
    focal = np.array([c.focal_px for c in rig.cameras])
    px = np.full(rig.num_cameras, math.nan)
    for c, ch in enumerate(hold.cameras):
        if ch is not None and ch.frames > 0 and math.isfinite(ch.noise_px):
            px[c] = ch.noise_px / math.sqrt(ch.frames)
    white = np.where(np.isfinite(px), np.hypot(px, CORRESPONDENCE_BIAS_FLOOR_PX) / focal,
                     np.hypot(fallback_rad, CORRESPONDENCE_BIAS_FLOOR_PX / focal))
    return np.hypot(white[cam], ringing_noise_rad(rig, hold, cam) if ringing else 0.0)


MIN_GROUP = 10  # observations a (hold, camera) needs for its own noise at the truth (core.bundle.camera_noise_factors)
NOISES = ("tracks", "ringing", "truth")  # the bearing noise each bound is taken at (see estimate_bounds)


def estimate_bounds(rig, pipe, ests: list, ref) -> list:
    """Per hold estimate: the Cramér-Rao bound (median angle, deg) of its gravity at each noise of ``NOISES``
    (nan each where it cannot be had), and the median bearing noise (px) of each.

    The bound is the joint one over the views its sequence had when it was published (the origin up to its
    own hold), at the ground truth's poses and gravity of those holds' stamps, for the landmarks the sequence's
    inlier observations track (triangulated at the truth, :func:`~nrmpc_ros.experiments.crlb.
    observed_sequence_bound`; an observation beyond the pipeline's inlier threshold of its truth-triangulated
    landmark is a mismatch and dropped) and, with 4pt-bending, the measured gravity at its own std (and the
    accelerometer's tilt, as the pipeline estimates it) and the gyro's rotations between consecutive holds at
    theirs. Noises, per hold and camera: ``tracks`` what the
    pipeline measured (:func:`_hold_camera_noise_rad`: the averaged track noise and the correspondence-bias
    floor); ``ringing`` that and the residual ringing the estimation stage adds as noise; ``truth`` the spread
    (robust, per axis) of the bearings about their landmarks triangulated at the truth (what the bearings'
    error really was, bias and ringing included, as if it were white) and the measured gravity at the
    accelerometer's own white noise (its std without the pipeline's floor; the accelerometer's tilt as before).
    nan where a hold of the sequence has no stamp (it came with a merge) or no ground truth."""
    seq = pipe.sequence
    seqs = {s.number: s for s in seq.history + [seq.seq]}
    holds = {h.stamp: h for h in pipe.measured_holds}
    stamps: dict = {}
    for e in ests:
        stamps.setdefault(e.sequence, {})[0] = e.origin_stamp
        stamps[e.sequence][e.hold_index] = e.stamp
    nothing = {**{n: math.nan for n in NOISES}, **{n + "_px": math.nan for n in NOISES}}
    out = []
    for e in ests:
        s, k = seqs.get(e.sequence), e.hold_index
        st = [stamps.get(e.sequence, {}).get(v) for v in range(k + 1)]
        truth = [None if x is None else _truth_at(ref, x) for x in st]
        if e.gravity is None or s is None or k >= s.num_views or any(x is None or holds.get(x) is None
                                                                    for x in st) or any(x is None for x in truth):
            out.append(dict(nothing))
            continue
        out.append({**nothing, **_view_bounds(rig, seq, s, k, truth, [holds[x] for x in st],
                                              pipe.config.imu_gravity_floor_deg)})
    return out


def _view_bounds(rig, seq, s, k: int, truth: list, holds: list, imu_floor_deg: float) -> dict:
    """The bounds of :func:`estimate_bounds` for view k of sequence ``s`` (an IncrementalSequence's) given the
    ground truth and the measured hold of each of its views 0..k; ``imu_floor_deg`` the floor the pipeline
    adds to each hold's IMU gravity std."""
    view, cam, track, f, inl = s.arrays()
    use = inl & (view <= k)
    view, cam, track, f = view[use], cam[use], track[use], f[use]
    Rw0, pw0, g0 = truth[0]
    R = np.array([Rw0.T @ Rw for Rw, _, _ in truth])
    t = np.array([Rw0.T @ (pw - pw0) for _, pw, _ in truth])
    priors = white = None
    if seq.method == "4pt-bending":
        ms = s.measured_sigmas(k + 1)
        g = np.where(np.isfinite(ms)[:, None], np.array([gk for _, _, gk in truth]), np.nan)
        # the gyro's rotations between consecutive holds at their stds, at the truth's rotations
        turns = tuple(RotationPrior(a, b, R[a].T @ R[b], sd) for a, b, _, sd in s.turns(k + 1))
        tilt = s.tilt_sigma(k + 1, seq.options.gravity_bias_sigma)  # the prior the estimate had
        priors = GravityPriors(g, ms, tilt, turns)
        # the accelerometer's own white noise: its std without the floor the pipeline adds (the tilt stays)
        floor = math.radians(imu_floor_deg)
        white = GravityPriors(g, np.sqrt(np.maximum(ms**2 - floor**2, (1e-3 * floor) ** 2)),
                              tilt, turns)
    focal = np.array([c.focal_px for c in rig.cameras])
    r = {}

    def bound_at(name, sigma, keep, priors=priors):
        nominal = float(np.median(sigma))
        obs, _ = Observations.from_arrays(view[keep], cam[keep], track[keep], f[keep], k + 1, sigma / nominal)
        b = observed_sequence_bound(rig, obs, R, t, g0, nominal, priors, outlier_rad=seq.threshold)
        r[name] = math.degrees(float(b.median_angles()[k]))
        r[name + "_px"] = float(np.median((sigma * focal[cam[keep]])[b.used])) if len(b.used) else math.nan
        return b

    every = np.arange(len(view))
    measured = {}
    for name in ("tracks", "ringing"):
        sigma = np.empty(len(view))
        for v in range(k + 1):
            mine = view == v
            sigma[mine] = _hold_camera_noise_rad(rig, holds[v], cam[mine], seq.noise_rad, name == "ringing")
        measured[name] = bound_at(name, sigma, every)
    first = measured["tracks"]
    keep = first.used
    if len(keep):
        # each (hold, camera)'s noise at the truth, per axis: the median distance of its bearings from their
        # landmarks over that of a 2-D Gaussian (sqrt(2 ln 2) sigma), robust to the tails the inlier threshold
        # lets in (the Gaussian of that spread is the bulk's information), with the landmarks' dof shared out
        # (a (hold, camera) with fewer than MIN_GROUP observations takes the spread of all, as the pipeline's
        # per-(hold, camera) noise does)
        # (a landmark seen along parallel rays is placed on its anchor's ray: that observation's zero distance
        # tells nothing of the noise and is left out of the spread)
        group = view[keep] * rig.num_cameras + cam[keep]
        dof = max(2 * len(keep) - 3 * first.landmarks, 1)
        rayleigh = math.sqrt(2.0 * math.log(2.0))
        res = first.residual_rad
        seen = res > 1e-9 * np.median(res[res > 0]) if np.any(res > 0) else res > 0
        per = np.full(group.max() + 1, np.median(res[seen]) / rayleigh if seen.any() else math.nan)
        for gr in np.unique(group):
            mine = (group == gr) & seen
            if mine.sum() >= MIN_GROUP:
                per[gr] = np.median(res[mine]) / rayleigh
        per *= math.sqrt(2 * len(keep) / dof)
        bound_at("truth", np.maximum(per[group], 1e-12), keep, white)
    return r


def score_cell(path: Path, rig_file: Path, method: str, bound: bool = True,
               config: PipelineConfig | None = None) -> dict:
    """Replay one bag with one method (``config``: the pipeline settings, default PipelineConfig()) and score it
    against the ground truth (see the module docstring)."""
    rig = load_rig(rig_file)
    ests: list = []
    rows, ref, pipe, wall, holds = replay_rows(path, rig, method, with_holds=True, keep=ests, config=config)
    ev = evaluate(rows, ref, rig)
    stamps = np.array([r.stamp for r in rows])
    tol = STAMP_TOLERANCE_S

    def within(a, b):
        return (stamps >= a - tol) & (stamps <= b + tol)

    later = holds[1:]  # the first hold is every sequence's reference: it gets no estimate of its own
    covered = sum(bool(np.any(within(a, b))) for a, b in later)
    inside = np.zeros(len(stamps), bool)
    for a, b in holds:
        inside |= within(a, b)
    err = ev.errors["gravity_vs_gt_deg"]
    sigma = np.array([float(r.extra.get("gravity_sigma_deg") or math.nan) for r in rows])
    published = np.isfinite(err) & np.isfinite(sigma) & (sigma > 0)
    z = err[published] / sigma[published]
    imu_err = []
    if ref.has_imu:
        imu = ImuReference(ref, rig)
        for a, b in holds:
            for k in np.flatnonzero((ref.grav_t >= a) & (ref.grav_t <= b)):
                g = imu.gravity_at(float(ref.grav_t[k]))
                if g is not None:
                    imu_err.append(math.degrees(float(angle_between(g, ref.grav_g[k]))))
    share = {f"within{k}": float(np.mean(z <= k)) if len(z) else math.nan for k in (1, 2, 3)}
    t0 = time.perf_counter()
    per = estimate_bounds(rig, pipe, ests, ref) if bound else []
    bounds = {n: np.array([b[n] for b in per] or [math.nan] * len(ests)) for n in NOISES}
    noise_px = {n: np.array([b[n + "_px"] for b in per] or [math.nan] * len(ests)) for n in NOISES}
    both = np.isfinite(bounds["tracks"]) & np.isfinite(err)

    def med(x):
        return float(np.median(x[both])) if both.any() else math.nan

    bound_deg = med(bounds["tracks"])
    return {"estimates": len(rows), "still_holds": len(holds), "covered": covered,
            "coverage": covered / len(later) if later else math.nan, "bad": int(np.count_nonzero(~inside)),
            "gravity_deg": ev.stats("gravity_vs_gt_deg")["median"],
            "bound_deg": bound_deg, "bounded": int(both.sum()), "bound_s": time.perf_counter() - t0,
            "error_over_bound": med(err) / bound_deg if both.any() else math.nan,
            "ringing_bound_deg": med(bounds["ringing"]), "truth_bound_deg": med(bounds["truth"]),
            **{f"{n}_noise_px": med(noise_px[n]) for n in NOISES},
            "errors_deg": [float(x) for x in err], **{f"{n}_bounds_deg": [float(x) for x in bounds[n]] for n in NOISES},
            "sigmas_deg": [float(x) for x in sigma],
            "imu_only_deg": float(np.median(imu_err)) if imu_err else math.nan, "published": int(len(z)),
            "methods": sorted({r.method for r in rows}), "wall_s": wall, "cameras": rig.num_cameras, **share}


def run_cell(job) -> list:
    """Render (if missing) and score one (out, style, rig, methods, pipeline settings file or None, rays per
    pixel side, seed) cell; one result dict per method."""
    out, style, rig_name, methods, config, supersample, seed = job
    recipe = None
    if style == "random":  # a recording drawn at random (--random): its rig and habits from the seed
        path, rig_file, rig, recipe = render_random(out, seed)
        rig_name, with_imu = rig.source.strip("<>"), rig.imu is not None
    else:
        path, rig_file = render_cell(out, style, rig_name, seed=seed, supersample=supersample)
        with_imu = matrix_styles()[style](1)[1].get("imu", True)
    cfg = None if config is None else from_mapping(PipelineConfig, load_mapping(config, "--config"), config)
    results = []
    for method in methods:
        if method == "auto" and not with_imu:  # auto is 6pt-bending there, and no IMU-only error to compare with
            continue
        r = score_cell(path, rig_file, method, config=cfg)
        r.update(style=style, rig=rig_name, method=method, seed=seed, recipe=recipe)
        results.append(r)
    return results


def verdict(r: dict) -> str:
    """The targets a result misses ('ok' when none): coverage, bad estimates, accuracy, calibration."""
    miss = []
    if not r["coverage"] >= TARGETS["coverage"]:
        miss.append("coverage")
    if r["bad"] > TARGETS["bad"]:
        miss.append("bad")
    if r["method"] == "auto" and not r["gravity_deg"] <= TARGETS["ratio_4pt"] * r["imu_only_deg"]:
        miss.append("vs IMU")
    target = TARGETS["median_6pt_bar_deg" if r.get("cameras") == 2 else "median_6pt_deg"]
    if r["method"] == "6pt-bending" and not r["gravity_deg"] <= target:
        miss.append("6pt median")
    if not r["within3"] >= TARGETS["within3"]:
        miss.append("3 sigma")
    return "ok" if not miss else "misses " + ", ".join(miss)


def _f(x, fmt) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def table(results: list) -> str:
    """Markdown table of the results, one row per bag and method."""
    lines = ["| style | rig | method | coverage | bad | gravity deg | bound deg: tracks / +ringing / truth | "
             "error / bound: tracks / truth | IMU only deg | vs IMU | within 1/2/3 std | verdict |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in results:
        ratio = r["gravity_deg"] / r["imu_only_deg"] if r["method"] == "auto" else math.nan
        style = r["style"] if not r.get("seed") else f"{r['style']} (seed {r['seed']})"
        lines.append(f"| {style} | {r['rig']} | {r['method']} | {r['covered']}/{r['still_holds'] - 1} "
                     f"| {r['bad']} | {_f(r['gravity_deg'], '.3f')} | {_f(r.get('bound_deg'), '.3f')} / "
                     f"{_f(r.get('ringing_bound_deg'), '.3f')} / {_f(r.get('truth_bound_deg'), '.3f')} | "
                     f"{_f(r.get('error_over_bound'), '.2f')} / "
                     f"{_f(r['gravity_deg'] / r.get('truth_bound_deg', math.nan), '.2f')} | "
                     f"{_f(r['imu_only_deg'], '.3f')} | "
                     f"{_f(ratio, '.2f')} | {_f(r['within1'], '.0%')} / {_f(r['within2'], '.0%')} / "
                     f"{_f(r['within3'], '.0%')} ({r['published']}) | {verdict(r)} |")
    return "\n".join(lines)


def pooled(results: list) -> str:
    """Per method, every published gravity of every recording together: the share within 1, 2 and 3 of its own
    std of the truth (the promise a std makes), and the recordings with the fewest within 2."""
    lines = ["| method | published | within 1 std | within 2 | within 3 | fewest within 2 (recording) |",
             "| --- | --- | --- | --- | --- | --- |"]
    for method in sorted({r["method"] for r in results}):
        mine = [r for r in results if r["method"] == method]
        z = np.concatenate([np.array(r["errors_deg"], float) / np.array(r["sigmas_deg"], float) for r in mine])
        z = z[np.isfinite(z)]
        worst = min(mine, key=lambda r: (r["within2"] if r["published"] else math.inf))
        name = f"{worst['style']}:{worst['rig']}" + (f" seed {worst['seed']}" if worst.get("seed") else "")
        lines.append(f"| {method} | {len(z)} | " + " | ".join(_f(float(np.mean(z <= k)) if len(z) else math.nan,
                                                              ".1%") for k in (1, 2, 3))
                     + f" | {_f(worst['within2'], '.0%')} ({name}) |")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--vga" in argv:
        return vga_main(argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = p.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="one rig per style (the default)")
    g.add_argument("--full", action="store_true", help="every style on every rig (2-6 cameras, soft and stiff)")
    p.add_argument("--vga", action="store_true", help="the VGA style table instead (see the module docstring)")
    p.add_argument("--out", default="/tmp/nrmpc_bench_matrix", help="folder of the rendered bags (reused)")
    p.add_argument("--workers", type=int, default=1, help="bags rendered and replayed in parallel (default 1)")
    p.add_argument("--methods", default="auto,6pt-bending", help="comma-separated methods")
    p.add_argument("--cells", help="comma-separated style:rig cells instead of --quick/--full")
    p.add_argument("--seeds", type=int, default=1, help="bags per cell, seeds 0 to N-1 (default 1): other noise, "
                   "IMU biases and hold attitudes for the same style and rig")
    p.add_argument("--random", type=int, default=0, metavar="N", help="instead of the matrix, N recordings drawn "
                   "at random, the styles' features combined (random_recording), seeds from --random-start")
    p.add_argument("--random-start", type=int, default=0, help="the first random recording's seed (default 0)")
    p.add_argument("--json", help="also write the results as JSON")
    p.add_argument("--config", help="pipeline settings YAML (keys of PipelineConfig, as for nrmpc replay)")
    p.add_argument("--supersample", type=int, default=SUPERSAMPLE, choices=range(1, 9), metavar="{1..8}",
                   help=f"rays per pixel side of the rendered bags (default {SUPERSAMPLE}: point sampling, "
                        "aliased; 2 or more integrate each pixel's area as a lens and sensor do)")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cells = [tuple(c.split(":")) for c in args.cells.split(",")] if args.cells else matrix_cells(args.full)
    jobs = [(out, s, r, args.methods.split(","), args.config, args.supersample, seed)
            for seed in range(args.seeds) for s, r in cells]
    if args.random:
        jobs = [(out, "random", "", args.methods.split(","), args.config, SUPERSAMPLE, seed)
                for seed in range(args.random_start, args.random_start + args.random)]
    t0 = time.perf_counter()
    if args.workers > 1:
        from multiprocessing import Pool

        with Pool(args.workers) as pool:
            results = [r for rs in pool.imap(run_cell, jobs) for r in rs]
    else:
        results = []
        for job in jobs:
            cell = run_cell(job)
            results += cell
            print("\n".join(table(cell).split("\n")[2:]), file=sys.stderr, flush=True)
    print(table(results))
    print("\n" + pooled(results))
    recipes = {r["seed"]: r["recipe"] for r in results if r.get("recipe")}
    if recipes:
        print("\n" + "\n".join(f"- random seed {seed}: {recipe}" for seed, recipe in sorted(recipes.items())))
    print(f"\n{len(jobs)} bags, {len(results)} replays in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
