"""``nrmpc import-kalibr``: write a rig file (docs/CONVENTIONS.md (Files)) from a Kalibr camera chain."""

from __future__ import annotations

import sys
from pathlib import Path

from ..core.rig import save_rig
from ..errors import InputError
from ..kalibr import rig_from_kalibr
from ..safeio import check_output


def register(sub):
    p = sub.add_parser(
        "import-kalibr", help="rig file from a Kalibr camchain (bars left rigid: fill in mass and EI)",
        description="Reads a Kalibr camchain.yaml (pinhole cameras with radtan/equidistant distortion, T_cn_cnm1 "
                    "chained extrinsics; OpenCV %YAML:1.0 files too) and optionally camchain-imucam.yaml "
                    "(T_cam_imu), and writes a docs/CONVENTIONS.md (Files) rig file. Bars are left rigid.")
    p.add_argument("camchain", metavar="CAMCHAIN.yaml", help="Kalibr camchain (or camchain-imucam) file")
    p.add_argument("--imu-chain", metavar="IMUCAM.yaml", help="Kalibr camchain-imucam file with T_cam_imu")
    p.add_argument("--out", required=True, metavar="RIG.yaml", help="rig file to write")
    p.add_argument("--body-frame", default="cam0", metavar="cam0|camN|imu",
                   help="where the body frame is: a camera (default cam0) or the IMU")
    p.add_argument("--frame-id", default="base_link", help="frame_id of the body frame (default base_link)")
    p.add_argument("--imu-topic", default="/imu/data", help="IMU topic when the files do not name one")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.set_defaults(func=run)


def run(args) -> int:
    out = Path(args.out)
    check_output(out, {"CAMCHAIN.yaml": args.camchain, "--imu-chain": args.imu_chain}, "--out")
    if out.exists() and not args.force:
        raise InputError("--out", f"{out} already exists (use --force to overwrite)")
    rig, notes = rig_from_kalibr(args.camchain, args.imu_chain, body_frame=args.body_frame,
                                 imu_topic=args.imu_topic, frame_id=args.frame_id)
    header = (f"rig imported by nrmpc import-kalibr from {args.camchain}"
              + (f" and {args.imu_chain}" if args.imu_chain else "")
              + "\nALL BARS ARE RIGID: add 'bar: {mass: KG, EI: N_M2}' to every camera on a flexible bar.")
    save_rig(rig, out, header=header, flag="--out")
    print(f"wrote {out}: {rig.num_cameras} cameras", file=sys.stderr)
    for note in notes:
        print(f"  note: {note}", file=sys.stderr)
    return 0
