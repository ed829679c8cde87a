"""``nrmpc calibrate-bars``: estimate each bar's compliance (m/EI) from many view pairs with known gravity."""

from __future__ import annotations

from ..calibration import calibrate_bars, describe
from ..core import load_matches, load_rig, save_rig
from ..errors import InputError


def register(sub):
    p = sub.add_parser(
        "calibrate-bars", help="self-calibrate bar stiffness (compliance m/EI) from a bag with an IMU or matches files",
        description="Joint estimation of every bar's compliance (or one shared scalar with --shared) over many view "
                    "pairs whose gravity is known (IMU), with standard deviations; writes the calibrated rig file. "
                    "Bars whose compliance is not significantly different from rigid are reported as not "
                    "observable and left as they are.")
    p.add_argument("bag", nargs="?", help="rosbag2 directory (or ROS 1 .bag) with camera images and an IMU")
    p.add_argument("--rig", required=True, help="rig YAML (its bar values are the starting point)")
    p.add_argument("--out", required=True, help="calibrated rig YAML to write")
    p.add_argument("--matches", nargs="+", metavar="NPZ", help="use matches files with g1/g2 instead of a bag")
    p.add_argument("--shared", action="store_true", help="one compliance for all bars")
    p.add_argument("--gravity-sigma", type=float, default=0.005, help="std of measured gravity (rad, default 0.005)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def _pairs_from_bag(bag, rig):
    """Every view pair the pipeline estimates with 4pt-bending on the bag (IMU gravity in both views)."""
    from ..frontend.replay import collect_pairs

    stats = {}
    pairs = collect_pairs(bag, rig, stats=stats)
    print(f"{len(pairs)} view pairs with IMU gravity from {bag} ({stats['frames']} frame sets, "
          f"{stats['static_views']} static views)")
    return pairs


def run(args) -> int:
    rig = load_rig(args.rig)
    if args.matches:
        pairs = [load_matches(p, rig) for p in args.matches]
    elif args.bag:
        pairs = _pairs_from_bag(args.bag, rig)
    else:
        raise InputError("calibrate-bars", "give a BAG or --matches files")
    cal = calibrate_bars(rig, pairs, shared=args.shared, gravity_sigma_rad=args.gravity_sigma, seed=args.seed)
    print(describe(cal, rig))
    header = ["bar compliance calibrated by nrmpc calibrate-bars from "
              + (f"{len(pairs)} matches files" if args.matches else f"bag {args.bag}")]
    for gi in range(len(cal.compliance)):
        names = ", ".join(rig.cameras[i].name for i in range(rig.num_cameras) if cal.groups[i] == gi)
        state = (f"{cal.compliance[gi]:.6g} +- {cal.std[gi]:.2g} kg/(N m^2)" if cal.observable[gi]
                 else "not observable (unchanged)")
        header.append(f"{names}: compliance {state}")
    save_rig(cal.calibrated_rig(rig), args.out, header="\n".join(header))
    print(f"wrote {args.out}")
    return 0
