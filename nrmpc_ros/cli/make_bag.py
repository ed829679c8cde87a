"""``nrmpc make-bag``: render a synthetic rosbag2 of a bending rig, recorded the way real rigs are recorded.

Options come from the flags, from a scenario file (``--scenario FILE.yaml``:
a mapping whose keys are the option names, e.g. ``hold-seconds: 2`` or
``hold_seconds: 2``, ``no-imu: true``), or both: flags override the file, the
file overrides the defaults. An unknown key is an error naming it. A
relative ``rig`` path in the file is relative to the file's directory.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..bag.writer import ENCODINGS, STORAGES
from ..core.rig import MAX_POSITION_STD_M, MAX_ROTATION_STD_DEG, load_rig, save_rig
from ..core.so3 import exp_so3
from ..errors import InputError, OptionError
from ..render.bagmaker import ACCEL_UNITS, EXPOSURE_OFFSET_GREY, GYRO_UNITS, BagOptions
from ..render.sequence import CAPTURES, PROFILES, MotionOptions
from ..safeio import atomic_directory, check_outputs
from ..sim.scenarios import load_scenario_file
from ..sim.synthetic import LAYOUTS, RigSpec, default_layout, make_rig
from .argtypes import seed

MOTION_ALIASES = {"static": "holds", "continuous": "stream"}  # --motion: the older name of --capture
VGA_WIDTH, VGA_FOCAL = 640, 470.0  # the default focal length belongs to 640 px wide images
DEFAULT_EI = 0.2  # N m^2, the bars of rigs built from flags without --EI or --bar-hz

_M, _B = MotionOptions(), BagOptions()  # the library's defaults, shown in --help
DEFAULTS = {
    "rig": None, "cameras": 4, "layout": None, "EI": None, "mass": 0.1, "bar_length": 0.4, "focal": None,
    "width": None, "height": None, "save_rig": None, "views": _M.views, "hold_seconds": _M.hold_seconds,
    "rate": _M.rate, "imu_rate": _M.imu_rate, "capture": _M.capture, "move_seconds": None,
    "min_move_seconds": _M.min_move_seconds, "speed": _M.speed, "move_profile": _M.move_profile,
    "accel_fraction": _M.accel_fraction, "min_tilt": _M.min_tilt, "max_tilt": _M.max_tilt,
    "min_step": _M.min_step, "max_step": _M.max_step, "max_translation": _M.max_translation, "damping": None,
    "seed": _B.seed, "image_noise": _B.image_noise, "imu_noise": _B.imu_noise, "gyro_noise": _B.gyro_noise,
    "imu_covariance_scale": _B.imu_covariance_scale, "imu_lowpass_hz": _B.imu_lowpass_hz, "imu_bias": _B.imu_bias,
    "gyro_bias": _B.gyro_bias, "accel_scale_error": _B.accel_scale_error,
    "vibration": _B.vibration, "vibration_hz": _B.vibration_hz, "imu_stamp_jitter_ms": _B.imu_stamp_jitter_ms,
    "shutter_ms": _B.shutter_ms, "walker_speed": _B.walker_speed, "imu_loss": _B.imu_loss,
    "imu_loss_burst_ms": _B.imu_loss_burst_ms,
    "imu_gravity_removed": _B.imu_gravity_removed,
    "no_imu": not _B.imu, "jitter_ms": _B.jitter_ms,
    "drop_rate": _B.drop_rate, "encoding": _B.encoding, "jpeg_quality": _B.jpeg_quality, "storage": _B.storage,
    "supersample": _B.supersample, "out": None, "no_progress": False,
    "imu_time_offset_ms": _B.imu_time_offset_ms, "imu_clock_start_s": _B.imu_clock_start_s,
    "camera_clock_start_s": _B.camera_clock_start_s, "unstamped": None,
    "camera_rates": None, "camera_phases_ms": None,
    "hold_seconds_range": None, "snapshot_delay": None, "exposure_drift": _B.exposure_drift,
    "exposure_period_s": _B.exposure_period_s, "creep_fraction": _M.creep_fraction,
    "creep_deg_per_s": _M.creep_deg_per_s, "bar_hz": None, "camera_latency_ms": _B.camera_latency_ms,
    "camera_burst_s": _B.camera_burst_s, "camera_burst_stagger_ms": _B.camera_burst_stagger_ms,
    "gyro_unit": _B.gyro_unit, "accel_unit": _B.accel_unit,
    "imu_in_camera": None, "rig_imu_turn_deg": None, "rig_rotation_error_deg": None,
    "rig_position_error_m": None,
}
_INTERNAL = {"func", "command", "make_bag_parser", "scenario"}


def _resolution(text: str):
    """'WxH' -> (W, H) pixels."""
    try:
        w, h = (int(x) for x in str(text).lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 320x240, got {text!r}") from None
    return w, h


def _floats(text) -> tuple:
    """'10,15,30' (or a YAML list of numbers) -> (10.0, 15.0, 30.0): finite numbers."""
    items = text if isinstance(text, (list, tuple)) else str(text).split(",")
    try:
        if any(isinstance(x, bool) for x in items):
            raise ValueError
        values = tuple(float(x) for x in items)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers such as 10,15,30, got {text!r}") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated finite numbers, got {text!r}")
    return values


def _rotation_vector_deg(text) -> tuple:
    """'0,0,90' (or a YAML list) -> (0.0, 0.0, 90.0): a rotation vector in degrees."""
    items = text if isinstance(text, (list, tuple)) else str(text).split(",")
    try:
        if len(items) != 3 or any(isinstance(x, bool) for x in items):
            raise ValueError
        values = tuple(float(x) for x in items)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a rotation vector RX,RY,RZ in degrees such as 0,0,90, got "
                                         f"{text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected three finite numbers, got {text!r}")
    return values


def _clock_starts(text) -> tuple:
    """'1000,,' (or a YAML list with nulls) -> (1000.0, None, None): per camera the reading of its own clock at
    the first frame, or None (the common clock)."""
    items = text if isinstance(text, (list, tuple)) else str(text).split(",")
    try:
        if any(isinstance(x, bool) for x in items):
            raise ValueError
        values = tuple(None if x is None or (isinstance(x, str) and not x.strip()) else float(x) for x in items)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected comma-separated seconds, an empty entry for a camera on the "
                                         f"common clock, such as 1000,,, got {text!r}") from None
    if not values or not all(v is None or math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated finite seconds, got {text!r}")
    return values


def _names(text) -> tuple:
    """'cam1,imu' (or a YAML list) -> ('cam1', 'imu')."""
    items = text if isinstance(text, (list, tuple)) else str(text).split(",")
    names = tuple(str(x).strip() for x in items)
    if not names or not all(names) or any(isinstance(x, bool) for x in items):
        raise argparse.ArgumentTypeError(f"expected comma-separated names such as cam1,imu, got {text!r}")
    return names


def _pair(text) -> tuple:
    """'A,B' -> (A, B)."""
    values = _floats(text)
    if len(values) != 2:
        raise argparse.ArgumentTypeError(f"expected two numbers A,B, got {text!r}")
    return values


def ei_for_frequency(hz: float, mass: float, bar_length: float) -> float:
    """Flexural rigidity EI (N m^2) giving a tip-mass bar the natural frequency ``hz``:
    f = sqrt(3 EI / (m L^3)) / (2 pi) (``nrmpc_ros.core.dynamics.bar_natural_frequencies``)."""
    return (2.0 * math.pi * hz) ** 2 * mass * bar_length**3 / 3.0


def register(sub):
    d = DEFAULTS
    p = sub.add_parser(
        "make-bag", argument_default=argparse.SUPPRESS,
        help="render a synthetic rosbag2 of a bending rig in a textured room",
        description="Holds the rig still at a sequence of attitudes (5-30 deg apart, tilted 10-40 deg) joined by "
                    "moves, renders every camera with its bent extrinsics and writes images (raw, or png/jpeg on "
                    "<image_topic>/compressed), CameraInfo, an IMU (a = -g + noise + bias, 200 Hz by default) "
                    "and /ground_truth/{pose,gravity,angular_velocity} at every trigger. Capture modes, move "
                    "profiles, ringing bars, per-camera rates, stamp jitter, frame drops, an IMU clock offset, "
                    "holds of random length, creeping holds and exposure drift make it look like a user's "
                    "recording (bags/README.md).")
    p.add_argument("--scenario", metavar="FILE.yaml",
                   help="options from a YAML mapping (keys = option names, e.g. hold-seconds: 2; a relative rig path "
                        "is relative to the file); flags override it")
    rig = p.add_argument_group("rig (a rig file, or one built from these flags)")
    rig.add_argument("--rig", help="rig YAML file (docs/CONVENTIONS.md, Files); the layout flags below are "
                     "then ignored")
    rig.add_argument("--cameras", type=int, help=f"number of cameras (default {d['cameras']})")
    rig.add_argument("--layout", choices=LAYOUTS, help="camera layout (default cross for 4 cameras, else ring)")
    rig.add_argument("--EI", type=float, help=f"bar flexural rigidity N m^2 (default {DEFAULT_EI}; inf = rigid)")
    rig.add_argument("--bar-hz", type=float, metavar="HZ",
                     help="set EI so that every bar's natural frequency sqrt(3 EI / (m L^3)) / (2 pi) is HZ "
                          "(e.g. 1.5 soft, 8 stiff; instead of --EI; rigs built from flags)")
    rig.add_argument("--mass", type=float, help=f"tip mass kg (default {d['mass']})")
    rig.add_argument("--bar-length", type=float, help=f"bar length m (default {d['bar_length']})")
    rig.add_argument("--width", type=int, help="image width px of the cameras built from flags (default 640)")
    rig.add_argument("--height", type=int, help="image height px (default 480)")
    rig.add_argument("--resolution", type=_resolution, metavar="WxH", help="--width and --height in one, e.g. 320x240")
    rig.add_argument("--focal", type=float,
                     help=f"focal length px (default {VGA_FOCAL:g} at {VGA_WIDTH} px wide, scaled with --width)")
    rig.add_argument("--save-rig", metavar="RIG.yaml", help="also write the rig used to this file")
    mo = p.add_argument_group("motion and capture")
    mo.add_argument("--views", type=int, help=f"number of holds (static attitudes) (default {d['views']})")
    mo.add_argument("--hold-seconds", "--static-seconds", dest="hold_seconds", type=float,
                    help=f"seconds still at each attitude (default {d['hold_seconds']:g})")
    mo.add_argument("--rate", "--stream-hz", dest="rate", type=float,
                    help=f"camera frames per second; holds and moves last whole frame periods (default {d['rate']:g})")
    mo.add_argument("--imu-rate", type=float, help=f"IMU samples per second (default {d['imu_rate']:g})")
    mo.add_argument("--camera-rates", type=_floats, metavar="R0,R1,...",
                    help="frames per second of each camera, one per camera, e.g. 10,15,30 (default: all at --rate; "
                         "holds and moves still last whole --rate periods)")
    mo.add_argument("--camera-phases-ms", type=_floats, metavar="P0,P1,...",
                    help="each camera's trigger phase in ms, one per camera, each below its frame period (default 0)")
    mo.add_argument("--hold-seconds-range", type=_pair, metavar="A,B",
                    help="each hold lasts a random time in [A, B] s (instead of --hold-seconds)")
    mo.add_argument("--snapshot-delay", type=float, metavar="S",
                    help="--capture snapshot: each camera's one image per hold is taken S s after the stop (plus "
                         "its phase) (default: on the hold's last frame)")
    mo.add_argument("--creep-fraction", type=float, metavar="F",
                    help="share of the holds after the first that creep: the body turns slowly through the whole "
                         "hold, so it is not still (/ground_truth/angular_velocity is non-zero there) (default 0)")
    mo.add_argument("--creep-deg-per-s", type=float,
                    help=f"rotation rate of a creeping hold, deg/s (default {d['creep_deg_per_s']:g})")
    mo.add_argument("--capture", choices=CAPTURES,
                    help="holds: frames at --rate while still; snapshot: one synchronised frame per camera at the end "
                         "of each hold; stream: frames at --rate throughout (default holds)")
    mo.add_argument("--motion", choices=sorted(MOTION_ALIASES),
                    help="older name of --capture: static = holds, continuous = stream")
    mo.add_argument("--move-seconds", type=float, help="fixed duration of every move (default: from --speed)")
    mo.add_argument("--speed", type=float, help=f"deg/s of the moves without --move-seconds (default {d['speed']:g})")
    mo.add_argument("--min-move-seconds", type=float,
                    help=f"shortest move without --move-seconds (default {d['min_move_seconds']:g})")
    mo.add_argument("--move-profile", choices=PROFILES,
                    help="cosine: (1 - cos pi tau) / 2; min-jerk: 10 tau^3 - 15 tau^4 + 6 tau^5; trapezoid: "
                         "trapezoidal velocity, acceleration steps (default cosine)")
    mo.add_argument("--accel-fraction", type=float,
                    help=f"trapezoid: fraction of a move spent accelerating, and again decelerating, in (0, 0.5] "
                         f"(default {d['accel_fraction']:g})")
    mo.add_argument("--min-tilt", type=float, help=f"deg (default {d['min_tilt']:g})")
    mo.add_argument("--max-tilt", type=float, help=f"deg (default {d['max_tilt']:g})")
    mo.add_argument("--min-step", type=float, help=f"min rotation between attitudes, deg (default {d['min_step']:g})")
    mo.add_argument("--max-step", type=float, help=f"max rotation between attitudes, deg (default {d['max_step']:g})")
    mo.add_argument("--max-translation", type=float,
                    help=f"m, half-size of the position cube (default {d['max_translation']:g})")
    mo.add_argument("--damping", type=float, metavar="ZETA",
                    help="bars ring after each move with this damping ratio in (0, 1), e.g. 0.03, at their natural "
                         "frequency sqrt(3 EI / (m L^3)) / (2 pi); a rig file's bar.damping wins for its bar "
                         "(default: the rig file's, else none: quasi-static bending)")
    se = p.add_argument_group("sensors and output")
    se.add_argument("--seed", type=seed, help="seed of everything random (default 0)")
    se.add_argument("--image-noise", type=float, help=f"pixel noise std, grey levels (default {d['image_noise']:g})")
    se.add_argument("--imu-noise", type=float, help=f"accelerometer noise std m/s^2 (default {d['imu_noise']:g})")
    se.add_argument("--gyro-noise", type=float, help=f"gyro noise std rad/s (default {d['gyro_noise']:g})")
    se.add_argument("--imu-lowpass-hz", type=float, metavar="HZ",
                    help="the IMU's digital low-pass filter, as MEMS IMUs have: a 2nd-order Butterworth at HZ on "
                         "its output, signal and noise (the noise std per sample stays --imu-noise/--gyro-noise; "
                         "its samples are correlated); below half --imu-rate (default 0: none, white noise)")
    se.add_argument("--imu-covariance-scale", type=float, metavar="K",
                    help="the Imu messages' covariances claim K times the true noise std, as drivers fill them: "
                         "0 all zeros (unknown), 0.1 a noise density taken for a per-sample std, 10 a generous "
                         f"constant (default {d['imu_covariance_scale']:g}: the truth)")
    se.add_argument("--imu-bias", type=float, help=f"accelerometer bias norm m/s^2 (default {d['imu_bias']:g})")
    se.add_argument("--gyro-bias", type=float, help=f"gyro bias norm rad/s (default {d['gyro_bias']:g})")
    se.add_argument("--accel-scale-error", type=float, metavar="S",
                    help="each accelerometer axis reads (1 + s) times the truth, s uniform in +-S per axis: an "
                         f"uncalibrated MEMS chip's sensitivity error, 0.01-0.03 (default {d['accel_scale_error']:g})")
    se.add_argument("--vibration", type=float, metavar="A",
                    help="a motor's vibration the IMU reads all along, A m/s^2 RMS (an engine or idling "
                         "propellers: 0.1-3), with the rocking it brings to the gyro; the images do not show it "
                         f"(default {d['vibration']:g}: none)")
    se.add_argument("--vibration-hz", type=float, metavar="HZ",
                    help="its frequency; an IMU sampling slower than twice it reads it aliased "
                         f"(default {d['vibration_hz']:g})")
    se.add_argument("--imu-gravity-removed", action="store_true",
                    help="the IMU topic carries a fused driver's linear acceleration (gravity taken out: about 0 at "
                         "rest), as an AHRS publishes beside its raw accelerometer")
    se.add_argument("--imu-stamp-jitter-ms", type=float, metavar="MS",
                    help="a driver that stamps each IMU sample when the host receives it: the stamp trails the "
                         "sample by up to MS ms (uniform), in arrival order; above the sample period samples come "
                         f"in batches (default {d['imu_stamp_jitter_ms']:g}: stamped when taken)")
    se.add_argument("--imu-loss", type=float, metavar="P",
                    help="share of the IMU's samples the recording lost, in [0, 0.5]: a USB or serial link, a busy "
                         f"recorder (default {d['imu_loss']:g})")
    se.add_argument("--imu-loss-burst-ms", type=float, metavar="MS",
                    help="the lost samples come in runs this long on average (ms; at 1 kHz, 20 ms is 20 samples "
                         f"in a row) (default {d['imu_loss_burst_ms']:g}: one by one)")
    se.add_argument("--gyro-unit", choices=sorted(GYRO_UNITS),
                    help="unit of the Imu messages' angular_velocity and its covariance: deg/s is a driver that "
                         f"breaks REP 103 (default {d['gyro_unit']})")
    se.add_argument("--accel-unit", choices=sorted(ACCEL_UNITS),
                    help="unit of their linear_acceleration and its covariance: g (9.80665 m/s^2) is a driver that "
                         f"breaks REP 103 (default {d['accel_unit']})")
    se.add_argument("--imu-time-offset-ms", type=float, metavar="MS",
                    help="the IMU's stamps are its true sample times + MS (a constant clock offset to the cameras; "
                         "the bag receives each sample at its true time, as a recorder on the cameras' clock "
                         "would; default 0)")
    for flag, kind, metavar, text in (  # drivers' stamps: other clocks, none
            ("--imu-clock-start-s", float, "S", "the IMU stamps with its own clock, reading S s at the first frame "
             "(1000: a counter since power-on); received on the cameras' clock (default: stamped by it)"),
            ("--camera-clock-start-s", _clock_starts, "S0,S1,...", "cameras stamping with their own clocks: per "
             "camera what its clock reads at the first frame, empty for one on the common clock (,2500,: the second "
             "camera's counter); received on the common clock (default: every camera on it)"),
            ("--unstamped", _names, "NAME,...", "inputs whose driver leaves header.stamp at 0: camera names (or "
             "indices) and/or imu (default: none)")):
        se.add_argument(flag, type=kind, metavar=metavar, help=text)
    se.add_argument("--exposure-drift", type=float, metavar="A",
                    help="auto-exposure drift: each camera's grey levels become gain I + offset, the gain drifting "
                         f"slowly within 1 +- A and the offset within +- {EXPOSURE_OFFSET_GREY:g} A grey levels, "
                         "in [0, 0.5] (default 0)")
    se.add_argument("--exposure-period-s", type=float, metavar="S",
                    help=f"typical period of the exposure drift, s; each camera's is 0.7-1.3 x this "
                         f"(default {d['exposure_period_s']:g})")
    se.add_argument("--no-imu", action="store_true", help="write no IMU topic (and --save-rig writes no imu block)")
    se.add_argument("--imu-in-camera", metavar="CAMERA",
                    help="the IMU sits inside this camera (its name or index), axes along the camera's, as in a "
                         "camera module with an IMU: it rides on that camera's bar and reads its ringing too "
                         "(--save-rig writes the mount) (default: at the body centre)")
    se.add_argument("--rig-imu-turn-deg", type=_rotation_vector_deg, metavar="RX,RY,RZ",
                    help="--save-rig writes the IMU's rotation turned by this rotation vector (deg, in the frame "
                         "the rig file gives the IMU's rotation in: the body's, or its camera's) from the one the bag "
                         "was recorded with: a rig file whose IMU axes are wrong, as a hand-written one for a flight "
                         "controller mounted sideways (0,0,90) or FRD axes taken for FLU (180,0,0) (default: the "
                         "IMU's true rotation)")
    for flag, what in (("--rig-rotation-error-deg", "rest rotation turned by a random rotation of S deg per axis "
                                                     "(about the camera's own axes, drawn from --seed) and "
                                                     "rotation_std_deg: S: the rig file of a calibration good to S "
                                                     "deg, as a real rig's is (default: the true rotations)"),
                       ("--rig-position-error-m", "rest position moved by a random shift of S m per axis and "
                                                  "position_std_m: S (default: the true positions)")):
        se.add_argument(flag, type=float, metavar="S", help=f"--save-rig writes every camera's {what}")
    se.add_argument("--shutter-ms", type=float, metavar="MS",
                    help="each image integrates the scene over MS ms from its trigger, its stamp (a camera's "
                         "exposure time: 5-30 ms indoors): motion blur while the rig moves or its bars ring, up to "
                         f"the frame period (default {d['shutter_ms']:g}: an instant)")
    se.add_argument("--walker-speed", type=float, metavar="M_PER_S",
                    help="someone walks back and forth through the room at this speed (m/s, up to 3), through holds "
                         "and moves alike: a person-sized textured box on a lane 1.2-1.5 m beside the rig's start, "
                         f"whose corners move while the rig holds still (default {d['walker_speed']:g}: nobody)")
    se.add_argument("--jitter-ms", type=float,
                    help="each camera's stamp is off the trigger by a uniform random amount within +-J ms (default 0)")
    se.add_argument("--drop-rate", type=float, help="probability that a camera loses a frame, in [0, 1) (default 0)")
    se.add_argument("--camera-latency-ms", type=float, metavar="MS", help="every image is received (its bag time) "
                    "this long after its stamp, the IMU's samples at theirs: a slow camera driver (default 0)")
    se.add_argument("--camera-burst-s", type=float, metavar="S",
                    help="images are received in bursts, all of an S-second interval at its end: a driver or "
                         "link that buffers (default 0: one by one)")
    se.add_argument("--camera-burst-stagger-ms", type=float, metavar="MS",
                    help="within a burst camera i's images are received i x MS after its end: a driver or link "
                         "that delivers a burst topic by topic (default 0: in stamp order)")
    se.add_argument("--encoding", choices=ENCODINGS,
                    help="raw sensor_msgs/Image encoding, or png/jpeg for CompressedImage on <image_topic>/compressed "
                         "(default mono8)")
    se.add_argument("--jpeg-quality", type=int, help=f"0-100 (default {d['jpeg_quality']})")
    se.add_argument("--supersample", type=int, metavar="S",
                    help=f"S x S rays per pixel: each pixel integrates its area as a sensor does; 1 samples its "
                         f"centre only, which aliases fine texture (default {d['supersample']})")
    se.add_argument("--storage", choices=sorted(STORAGES), help="rosbag2 storage (default sqlite3)")
    se.add_argument("--out", metavar="DIR", help="output bag directory (must not exist; required); it appears "
                    "complete or not at all")
    se.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run, make_bag_parser=p)


# -- options: defaults < scenario file < flags ------------------------------------------------------------------

def _actions(parser) -> dict:
    """Option name (without dashes, '-' or '_') -> argparse action, for every option of the parser."""
    out = {}
    for a in parser._actions:
        for s in a.option_strings:
            if s.startswith("--") and a.dest not in _INTERNAL | {"help"}:
                out[s[2:]] = out[s[2:].replace("-", "_")] = a
    return out


def _coerce(action, value, source: str, key: str):
    """A scenario file value checked like the flag would check it."""
    def bad(msg):
        return InputError(source, msg, key)

    if isinstance(action, argparse._StoreTrueAction):
        if not isinstance(value, bool):
            raise bad(f"must be true or false, got {value!r}")
        return value
    if value is None:
        if DEFAULTS.get(action.dest, 0) is not None:
            raise bad("needs a value")
        return None
    kind = action.type
    if kind in (_floats, _pair, _clock_starts, _names) and isinstance(value, (list, tuple)):
        try:
            return kind(list(value))
        except argparse.ArgumentTypeError as exc:
            raise bad(str(exc)) from None
    if kind is _resolution and isinstance(value, (list, tuple)):
        if len(value) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise bad(f"expected [width, height] in pixels, got {value!r}")
        return tuple(value)
    if isinstance(value, bool) or isinstance(value, (list, dict)):
        raise bad(f"expected a single {getattr(kind, '__name__', 'value')}, got {value!r}")
    if kind is int and isinstance(value, float):
        raise bad(f"expected an integer, got {value!r}")
    try:
        value = kind(value) if kind is not None else str(value)
    except (TypeError, ValueError, argparse.ArgumentTypeError) as exc:
        raise bad(str(exc)) from None
    if action.choices is not None and value not in action.choices:
        raise bad(f"must be one of {', '.join(map(str, action.choices))}, got {value!r}")
    return value


def _normalise(values: dict, source: str) -> dict:
    """Fold the aliases of one level (file or flags): --motion into --capture, --resolution into --width/--height."""
    values = dict(values)
    if "motion" in values:
        capture = MOTION_ALIASES[values.pop("motion")]
        if values.setdefault("capture", capture) != capture:
            raise InputError(source, f"--motion asks for {capture!r} but --capture for {values['capture']!r}",
                             "motion")
    if "resolution" in values:
        for key, v in zip(("width", "height"), values.pop("resolution")):
            if values.setdefault(key, v) != v:
                raise InputError(source, f"--resolution and --{key} disagree", "resolution")
    return values


def resolve_options(args) -> dict:
    """All option values (dests of the parser), merged as defaults < --scenario file < flags."""
    flags = {k: v for k, v in vars(args).items() if k not in _INTERNAL}
    merged = dict(DEFAULTS)
    scenario = getattr(args, "scenario", None)
    if scenario:
        data = load_scenario_file(scenario)
        actions = _actions(args.make_bag_parser)
        from_file = {}
        for key, value in data.items():
            action = actions.get(str(key))
            if action is None:
                raise InputError(scenario, "unknown key: not a make-bag option (see nrmpc make-bag --help)",
                                 str(key))
            from_file[action.dest] = _coerce(action, value, scenario, str(key))
        if from_file.get("rig") and not Path(from_file["rig"]).is_absolute():
            from_file["rig"] = str(Path(scenario).parent / from_file["rig"])
        merged.update(_normalise(from_file, scenario))
    merged.update(_normalise(flags, "command line"))
    if not merged["out"]:
        raise InputError("--out", "required: the output bag directory (a flag or an 'out' key of --scenario)")
    return merged


# -- rig and library options ------------------------------------------------------------------------------------

def rig_from_options(o: dict):
    """The rig of --rig, or a simulated one from the layout flags (with an IMU at the body centre unless --no-imu);
    with --imu-in-camera the IMU inside that camera."""
    rig = _rig_of(o)
    cam = o["imu_in_camera"]
    if cam is None:
        return rig
    if rig.imu is None:
        raise InputError("--imu-in-camera", "there is no IMU to mount (--no-imu)")
    names = [c.name for c in rig.cameras]
    name = names[int(cam)] if str(cam).isdigit() and int(cam) < len(names) and str(cam) not in names else str(cam)
    if name not in names:
        raise InputError("--imu-in-camera", f"no camera {cam!r} (the rig has {', '.join(names)}, or an index "
                                            f"0-{len(names) - 1})")
    return rig.with_imu_in(name)


def _rig_of(o: dict):
    if o["rig"]:
        if o["width"] is not None or o["height"] is not None:
            raise InputError("--resolution/--width/--height", "only for rigs built from flags; the rig file "
                                                              "fixes each camera's resolution")
        if o["bar_hz"] is not None:
            raise InputError("--bar-hz", "only for rigs built from flags; the rig file fixes each bar's EI")
        rig = load_rig(o["rig"])
        return replace(rig, imu=None) if o["no_imu"] else rig
    if o["bar_hz"] is not None:
        if o["EI"] is not None:
            raise InputError("--bar-hz", "sets EI; give --bar-hz or --EI, not both")
        if not (0 < o["bar_hz"] < math.inf):
            raise InputError("--bar-hz", f"must be a finite frequency > 0 Hz, got {o['bar_hz']!r}")
        if not (0 < o["mass"] < math.inf and 0 < o["bar_length"] < math.inf):
            raise InputError("--bar-hz", "needs a tip mass (--mass) > 0 and a bar length > 0 to ring")
        o = {**o, "EI": ei_for_frequency(o["bar_hz"], o["mass"], o["bar_length"])}
    elif o["EI"] is None:
        o = {**o, "EI": DEFAULT_EI}
    checks = [("--bar-length", 0 < o["bar_length"] < math.inf), ("--mass", 0 <= o["mass"] < math.inf),
              ("--EI", o["EI"] > 0), ("--width", o["width"] is None or o["width"] >= 2),
              ("--height", o["height"] is None or o["height"] >= 2),
              ("--focal", o["focal"] is None or 0 < o["focal"] < math.inf)]
    for flag, ok in checks:
        if not ok:
            raise InputError(flag, f"out of range, got {o[flag[2:].replace('-', '_')]!r}")
    width = o["width"] or (VGA_WIDTH if o["height"] is None else round(o["height"] * 4 / 3))
    height = o["height"] or round(width * 3 / 4)
    focal = o["focal"] if o["focal"] is not None else VGA_FOCAL * width / VGA_WIDTH
    try:
        spec = RigSpec(num_cameras=o["cameras"], layout=o["layout"] or default_layout(o["cameras"]),
                       bar_length=o["bar_length"], mass=o["mass"], EI=o["EI"], focal=focal,
                       resolution=(int(width), int(height)))
        return make_rig(spec, imu=not o["no_imu"])
    except OptionError as exc:  # the spec names its field
        raise InputError("--cameras" if exc.field == "num_cameras" else "--layout", exc.message) from None
    except ValueError as exc:
        raise InputError("--layout", str(exc)) from None


def bag_options(o: dict):
    """The library's BagOptions of the merged option values."""
    motion = MotionOptions(
        views=o["views"], hold_seconds=o["hold_seconds"], rate=o["rate"], imu_rate=o["imu_rate"],
        min_tilt=o["min_tilt"], max_tilt=o["max_tilt"], min_step=o["min_step"], max_step=o["max_step"],
        max_translation=o["max_translation"], speed=o["speed"], min_move_seconds=o["min_move_seconds"],
        move_seconds=o["move_seconds"], move_profile=o["move_profile"], accel_fraction=o["accel_fraction"],
        capture=o["capture"], hold_seconds_range=o["hold_seconds_range"], snapshot_delay=o["snapshot_delay"],
        camera_rates=o["camera_rates"], camera_phases_ms=o["camera_phases_ms"], creep_fraction=o["creep_fraction"],
        creep_deg_per_s=o["creep_deg_per_s"],
    )
    return BagOptions(motion=motion, seed=o["seed"], encoding=o["encoding"], jpeg_quality=o["jpeg_quality"],
                      storage=o["storage"], image_noise=o["image_noise"], imu_noise=o["imu_noise"],
                      gyro_noise=o["gyro_noise"], imu_covariance_scale=o["imu_covariance_scale"],
                      imu_lowpass_hz=o["imu_lowpass_hz"], imu_bias=o["imu_bias"], gyro_bias=o["gyro_bias"],
                      accel_scale_error=o["accel_scale_error"], vibration=o["vibration"],
                      vibration_hz=o["vibration_hz"],
                      imu_stamp_jitter_ms=o["imu_stamp_jitter_ms"], imu_gravity_removed=o["imu_gravity_removed"],
                      shutter_ms=o["shutter_ms"], walker_speed=o["walker_speed"], imu_loss=o["imu_loss"],
                      imu_loss_burst_ms=o["imu_loss_burst_ms"],
                      imu=not o["no_imu"], damping=o["damping"],
                      jitter_ms=o["jitter_ms"], drop_rate=o["drop_rate"],
                      supersample=o["supersample"], imu_time_offset_ms=o["imu_time_offset_ms"],
                      imu_clock_start_s=o["imu_clock_start_s"], camera_clock_start_s=o["camera_clock_start_s"],
                      unstamped=tuple(o["unstamped"] or ()),
                      exposure_drift=o["exposure_drift"], exposure_period_s=o["exposure_period_s"],
                      camera_latency_ms=o["camera_latency_ms"], camera_burst_s=o["camera_burst_s"],
                      camera_burst_stagger_ms=o["camera_burst_stagger_ms"], gyro_unit=o["gyro_unit"],
                      accel_unit=o["accel_unit"])


def _check_outputs(o: dict, scenario) -> None:
    """Neither output may touch an input, --out must not exist yet and --save-rig's directory must (checked
    before rendering)."""
    check_outputs({"--out": o["out"], "--save-rig": o["save_rig"]}, {"--rig": o["rig"], "--scenario": scenario},
                  directories=("--out",))
    if os.path.lexists(o["out"]):
        raise InputError("--out", f"{o['out']} already exists; remove it or choose another path")
    if o["save_rig"] and not Path(o["save_rig"]).resolve().parent.is_dir():
        raise InputError("--save-rig", f"no such directory {Path(o['save_rig']).resolve().parent}")
    for key, top, unit in (("rig_rotation_error_deg", MAX_ROTATION_STD_DEG, "deg"),
                           ("rig_position_error_m", MAX_POSITION_STD_M, "m")):
        flag, error = "--" + key.replace("_", "-"), o[key]
        if error is None:
            continue
        if not o["save_rig"]:
            raise InputError(flag, "changes the cameras of the rig file --save-rig writes: needs --save-rig")
        if not (math.isfinite(error) and 0 <= error <= top):
            raise InputError(flag, f"must be a finite number of {unit} in [0, {top:g}], got {error!r}")
    if o["rig_imu_turn_deg"] is not None and (not o["save_rig"] or o["no_imu"]):
        raise InputError("--rig-imu-turn-deg", "turns the IMU of the rig file --save-rig writes: needs --save-rig "
                                               "and an IMU (not --no-imu)")


def run(args) -> int:
    from ..render.bagmaker import make_bag

    o = resolve_options(args)
    rig = rig_from_options(o)
    opts = bag_options(o)
    opts.validate()
    opts.motion.validate_cameras(rig.num_cameras)
    _check_outputs(o, getattr(args, "scenario", None))
    with atomic_directory(o["out"], flag="--out") as work:  # readers see no bag or a complete one
        summary = make_bag(rig, work, opts, progress=not o["no_progress"])
    if o["save_rig"]:
        if opts.damping is not None:  # the rig the bag was rendered with: every flexible bar rang with a damping
            rig = replace(rig, cameras=tuple(replace(c, damping=opts.damping) if c.damping is None and c.is_flexible
                                             else c for c in rig.cameras))
        if o["rig_imu_turn_deg"] is not None:
            turn = exp_so3(np.radians(o["rig_imu_turn_deg"]))
            rig = replace(rig, imu=replace(rig.imu, rotation=turn @ rig.imu.rotation))
        rng = np.random.default_rng(np.random.SeedSequence([o["seed"], 0xCA1]))  # its own: the bag is the same
        if o["rig_rotation_error_deg"] is not None:
            rig = rig.with_rotation_errors(o["rig_rotation_error_deg"], rng)
        if o["rig_position_error_m"] is not None:
            rig = rig.with_position_errors(o["rig_position_error_m"], rng)
        save_rig(rig, o["save_rig"], header="rig written by nrmpc make-bag", flag="--save-rig")
    traj = summary["trajectory"]
    tilts = [math.degrees(math.acos(max(-1.0, min(1.0, float(R[2, 2]))))) for R in traj.R]
    print(f"wrote {o['out']}: {summary['views']} holds, {summary['frames']} triggers ({opts.motion.capture}), "
          f"{summary['images']} images of {rig.num_cameras} cameras, {summary['dropped']} frames dropped, "
          + (f"{summary['imu_lost']} IMU samples lost, " if summary["imu_lost"] else "")
          + (f"{summary['blurred']} images blurred by the shutter, " if summary["blurred"] else "") +
          f"{summary['duration_s']:.1f} s, "
          f"tilts {min(tilts):.0f}-{max(tilts):.0f} deg", file=sys.stderr)
    if summary["holds"][0]["settled"] is not None:  # the bars ring (--damping or the rig file's bar.damping)
        settle = max([h["settled"] - h["start"] for h in summary["holds"][1:] if h["settled"] is not None],
                     default=0.0)
        hold = min(h["end"] - h["start"] for h in summary["holds"])
        freqs = ", ".join(f"{f:.2f}" for f in summary["bar_frequencies_hz"])
        late = (f" (longer than the shortest hold, {hold:g} s: the bars still ring when they end)"
                if settle > hold else "")
        print(f"  bars ring at {freqs} Hz; ringing below 1e-3 after {settle:.1f} s of each hold{late}",
              file=sys.stderr)
    for topic, n in sorted(summary["counts"].items()):
        print(f"  {topic}: {n}", file=sys.stderr)
    return 0
