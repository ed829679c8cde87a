"""``nrmpc calibrate-bars``: each bar's compliance (m/EI) from a bag's holds (or matches files) with known gravity."""

from __future__ import annotations

from ..bag.reader import bag_root
from ..calibration import calibrate_bars, describe, describe_dynamics, identify_bar_dynamics, rig_dict_with_dynamics
from ..core import load_matches, load_rig, save_rig
from ..errors import InputError
from ..safeio import check_output
from .argtypes import positive_radians, seed


def register(sub):
    p = sub.add_parser(
        "calibrate-bars", help="self-calibrate bar stiffness (compliance m/EI) from a bag with an IMU or matches files",
        description="Joint estimation of every bar's compliance (or one shared scalar with --shared) over the holds "
                    "of a bag whose gravity the IMU measures (or over view pairs in matches files), with standard "
                    "deviations; writes the calibrated rig file. "
                    "Bars whose compliance is not significantly different from rigid are reported as not "
                    "observable and left as they are.")
    p.add_argument("bag", nargs="?", help="rosbag2 directory (or ROS 1 .bag) with camera images and an IMU")
    p.add_argument("--rig", required=True, help="rig YAML (its bar values are the starting point)")
    p.add_argument("--out", required=True, help="calibrated rig YAML to write")
    p.add_argument("--matches", nargs="+", metavar="NPZ", help="use matches files with g1/g2 instead of a bag")
    p.add_argument("--shared", action="store_true", help="one compliance for all bars")
    p.add_argument("--gravity-sigma", type=positive_radians, default=0.005,
                   help="matches files: std of measured gravity (rad); a bag: prior std of the accelerometer's "
                        "constant tilt, each hold's own noise coming from its samples (default 0.005)")
    p.add_argument("--seed", type=seed, default=0, help="RANSAC seed (matches files)")
    p.set_defaults(func=run)


def _sequences_from_bag(bag, rig, holds=None):
    """The bag's sequences of holds with the IMU's gravity of every hold (``holds`` receives every hold)."""
    from ..frontend.replay import collect_sequences

    stats = {}
    seqs = collect_sequences(bag, rig, stats=stats, progress=True, holds=holds)
    views = sum(s.tracks.num_views for s in seqs)
    print(f"{views} holds in {len(seqs)} sequence(s) with IMU gravity from {bag} ({stats['frames']} frame sets)")
    return seqs


def _save_rig_dict(d: dict, path, header: str) -> None:
    """A rig file's mapping written atomically with ``header`` lines as comments (as core.save_rig does)."""
    import yaml

    from ..safeio import atomic_write

    text = "".join(f"# {line}\n" for line in header.splitlines()) + yaml.safe_dump(d, sort_keys=False,
                                                                                   default_flow_style=None)
    with atomic_write(path, flag="--out") as fh:
        fh.write(text)


def run(args) -> int:
    from ..calibration import calibrate_sequences

    check_output(args.out, {"BAG": args.bag and bag_root(args.bag), "--rig": args.rig, "--matches": args.matches},
                 "--out")
    rig = load_rig(args.rig)
    if args.matches:
        pairs = [load_matches(p, rig) for p in args.matches]
        cal = calibrate_bars(rig, pairs, shared=args.shared, gravity_sigma_rad=args.gravity_sigma, seed=args.seed)
        dyn = []  # matches files have no ringing to fit
        source = f"{len(pairs)} matches files"
    elif args.bag:
        holds = []
        seqs = _sequences_from_bag(args.bag, rig, holds)
        cal = calibrate_sequences(rig, seqs, shared=args.shared, bias_sigma_rad=args.gravity_sigma)
        dyn = identify_bar_dynamics(rig, holds)
        source = f"bag {args.bag}"
    else:
        raise InputError("calibrate-bars", "give a BAG or --matches files")
    print(describe(cal, rig))
    if dyn:
        print(describe_dynamics(dyn, rig))
    header = [f"bar compliance calibrated by nrmpc calibrate-bars from {source}"]
    for gi in range(len(cal.compliance)):
        names = ", ".join(rig.cameras[i].name for i in range(rig.num_cameras) if cal.groups[i] == gi)
        state = (f"{cal.compliance[gi]:.6g} +- {cal.std[gi]:.2g} kg/(N m^2)" if cal.observable[gi]
                 else "not observable (unchanged)")
        header.append(f"{names}: compliance {state}")
    for d in dyn:
        if d is not None:
            header.append(f"{d.camera}: damping {d.zeta:.4g} +- {d.zeta_std:.2g}, natural frequency {d.freq_hz:.4g} +- "
                          f"{d.freq_std_hz:.2g} Hz (rig file: {d.rig_freq_hz:.4g} Hz) from the ringing after the stops")
    if any(d is not None for d in dyn):
        _save_rig_dict(rig_dict_with_dynamics(cal.calibrated_rig(rig), dyn), args.out, "\n".join(header))
    else:
        save_rig(cal.calibrated_rig(rig), args.out, header="\n".join(header), flag="--out")
    print(f"wrote {args.out}")
    return 0
