"""``nrmpc make-bag``: render a synthetic rosbag2 of a bending rig (issue 4; SPEC sections 3, 4, 11)."""

from __future__ import annotations

import math
import sys

from ..bag.writer import ENCODINGS, STORAGES
from ..core.rig import load_rig, save_rig
from ..errors import InputError
from ..render.sequence import MOTIONS, MotionOptions
from ..sim.synthetic import LAYOUTS, RigSpec, make_rig


def register(sub):
    p = sub.add_parser(
        "make-bag", help="render a synthetic rosbag2 of a bending rig in a textured room",
        description="Holds the rig still at a sequence of attitudes (5-30 deg apart, tilted 10-40 deg), renders "
                    "every camera with the bent extrinsics of that attitude's gravity and writes images, "
                    "CameraInfo, a 200 Hz IMU (a = -g + noise + bias) and /ground_truth/{pose,gravity}.")
    rig = p.add_argument_group("rig (a rig file, or one built from these flags)")
    rig.add_argument("--rig", help="rig YAML file (SPEC section 7); overrides the flags below")
    rig.add_argument("--cameras", type=int, default=4, help="number of cameras (default 4)")
    rig.add_argument("--layout", choices=LAYOUTS, default="cross", help="camera layout (default cross)")
    rig.add_argument("--EI", type=float, default=0.2, help="bar flexural rigidity N m^2 (default 0.2; inf = rigid)")
    rig.add_argument("--mass", type=float, default=0.1, help="tip mass kg (default 0.1)")
    rig.add_argument("--bar-length", type=float, default=0.4, help="bar length m (default 0.4)")
    rig.add_argument("--focal", type=float, default=470.0, help="focal length px of the VGA cameras (default 470)")
    rig.add_argument("--save-rig", metavar="RIG.yaml", help="also write the rig used to this file")
    mo = p.add_argument_group("motion")
    mo.add_argument("--views", type=int, default=10, help="number of static attitudes (default 10)")
    mo.add_argument("--static-seconds", type=float, default=2.0, help="seconds still at each attitude (default 2)")
    mo.add_argument("--rate", type=float, default=10.0, help="camera frames per second (default 10)")
    mo.add_argument("--imu-rate", type=float, default=200.0, help="IMU samples per second (default 200)")
    mo.add_argument("--motion", choices=MOTIONS, default="static",
                    help="static: frames only while still; continuous: frames also stream during the moves")
    mo.add_argument("--min-tilt", type=float, default=10.0, help="deg (default 10)")
    mo.add_argument("--max-tilt", type=float, default=40.0, help="deg (default 40)")
    mo.add_argument("--min-step", type=float, default=5.0, help="min rotation between attitudes, deg (default 5)")
    mo.add_argument("--max-step", type=float, default=30.0, help="max rotation between attitudes, deg (default 30)")
    mo.add_argument("--max-translation", type=float, default=0.15, help="m, half-size of the position cube")
    mo.add_argument("--speed", type=float, default=30.0, help="deg/s during moves (default 30)")
    se = p.add_argument_group("sensors and output")
    se.add_argument("--seed", type=int, default=0, help="seed of everything random (default 0)")
    se.add_argument("--image-noise", type=float, default=1.0, help="pixel noise std, grey levels (default 1)")
    se.add_argument("--imu-noise", type=float, default=0.02, help="accelerometer noise std m/s^2 (default 0.02)")
    se.add_argument("--gyro-noise", type=float, default=0.002, help="gyro noise std rad/s (default 0.002)")
    se.add_argument("--imu-bias", type=float, default=0.05, help="accelerometer bias norm m/s^2 (default 0.05)")
    se.add_argument("--gyro-bias", type=float, default=0.002, help="gyro bias norm rad/s (default 0.002)")
    se.add_argument("--encoding", choices=ENCODINGS, default="mono8",
                    help="Image encoding, or png/jpeg for CompressedImage (default mono8)")
    se.add_argument("--storage", choices=sorted(STORAGES), default="sqlite3", help="rosbag2 storage (default sqlite3)")
    se.add_argument("--out", required=True, metavar="DIR", help="output bag directory (must not exist)")
    se.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def rig_from_args(args):
    """The rig of --rig, or a simulated one from the layout flags (with an IMU at the body centre)."""
    if args.rig:
        return load_rig(args.rig)
    try:
        spec = RigSpec(num_cameras=args.cameras, layout=args.layout, bar_length=args.bar_length, mass=args.mass,
                       EI=args.EI, focal=args.focal)
        return make_rig(spec, imu=True)
    except ValueError as exc:
        raise InputError("make-bag rig flags", str(exc)) from None


def run(args) -> int:
    from ..render.bagmaker import BagOptions, make_bag

    rig = rig_from_args(args)
    if args.save_rig:
        save_rig(rig, args.save_rig, header="rig written by nrmpc make-bag")
    motion = MotionOptions(
        views=args.views, static_seconds=args.static_seconds, rate=args.rate, imu_rate=args.imu_rate,
        min_tilt=args.min_tilt, max_tilt=args.max_tilt, min_step=args.min_step, max_step=args.max_step,
        max_translation=args.max_translation, speed=args.speed, motion=args.motion,
    )
    opts = BagOptions(motion=motion, seed=args.seed, encoding=args.encoding, storage=args.storage,
                      image_noise=args.image_noise, imu_noise=args.imu_noise, gyro_noise=args.gyro_noise,
                      imu_bias=args.imu_bias, gyro_bias=args.gyro_bias)
    summary = make_bag(rig, args.out, opts, progress=not args.no_progress)
    traj = summary["trajectory"]
    tilts = [math.degrees(math.acos(max(-1.0, min(1.0, float(R[2, 2]))))) for R in traj.R]
    print(f"wrote {args.out}: {summary['views']} static views, {summary['frames']} frame sets x "
          f"{rig.num_cameras} cameras, {summary['duration_s']:.1f} s, tilts {min(tilts):.0f}-{max(tilts):.0f} deg",
          file=sys.stderr)
    for topic, n in sorted(summary["counts"].items()):
        print(f"  {topic}: {n}", file=sys.stderr)
    return 0
