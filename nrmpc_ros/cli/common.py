"""What several commands share: scenario flags, trajectory outputs, JSON output, and flags in library errors.

The library names its options by their fields (``OptionError``: ``bag
options: field 'jpeg_quality'``); :func:`flag_error` turns such an error into
one that names the flag the user typed (``--jpeg-quality``), through the
command's ``field_flags`` (set with ``set_defaults``) or the flag spelled
like the field.
"""

from __future__ import annotations

import argparse
import math
import re

from ..errors import InputError, OptionError

# flag dest -> scenario field ("rig.<RigSpec field>" for the rig)
RIG_FLAGS = {
    "cameras": "rig.num_cameras", "layout": "rig.layout", "looking": "rig.looking", "bar_length": "rig.bar_length",
    "mass": "rig.mass", "EI": "rig.EI", "focal": "rig.focal",
}
SCENARIO_FLAGS = {
    **RIG_FLAGS, "points": "num_points", "noise": "pixel_noise",
    "outliers": "outlier_fraction", "gravity_noise": "gravity_noise_px", "gravity_frame": "gravity_frame",
    "max_rotation": "max_rotation", "max_translation": "max_translation",
}
# flag dest -> SequenceScenario field (a pair of fields for a flag with two values)
SEQUENCE_FLAGS = {
    **RIG_FLAGS, "views": "num_views", "min_step": "min_step_deg", "max_step": "max_step_deg",
    "tracks_per_camera": "tracks_per_camera", "track_views": ("min_track_views", "max_track_views"),
    "noise": "pixel_noise", "outliers": "outlier_fraction", "gravity_noise_deg": "gravity_noise_deg",
    "gravity_measured": "gravity_measured", "max_translation": "max_translation",
}
# flags of one kind of problem that the other kind does not take
PAIR_ONLY = ("points", "gravity_noise", "gravity_frame", "max_rotation")
SEQUENCE_ONLY = ("views", "min_step", "max_step", "tracks_per_camera", "track_views", "gravity_noise_deg",
                 "gravity_measured")
_SEQUENCE_HELP = "write sequences of static views (tracks .npz) instead of two-view problems (matches .npz)"


def flag_of(dest: str) -> str:
    """The flag of an argparse destination (``bar_length`` -> ``--bar-length``)."""
    return "--no-gravity" if dest == "gravity_measured" else "--" + dest.replace("_", "-")


def scenario_field_flags(flags: dict) -> dict:
    """field -> flag of a {flag dest: field} table (both fields of a two-valued flag)."""
    out = {}
    for dest, field in flags.items():
        for f in field if isinstance(field, tuple) else (field,):
            out[f] = flag_of(dest)
    return out


def flag_error(exc: InputError, parser: argparse.ArgumentParser | None, field_flags: dict | None = None):
    """``exc`` naming the command's flag instead of the library's field, when the field came from a flag.

    Only :class:`OptionError` (a library option) is translated: an error in a
    file keeps naming the file and key.
    """
    if not isinstance(exc, OptionError) or not exc.field or parser is None:
        return exc
    flag = (field_flags or {}).get(exc.field) or flag_of(exc.field)
    if not re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", parser.format_help()):
        return exc
    return InputError(flag, exc.message)


def add_scenario_arguments(p, with_gravity=True) -> None:
    """Flags of a synthetic scenario (defaults: the paper's nominal case)."""
    from ..sim.synthetic import GRAVITY_FRAMES, LAYOUTS, LOOKING

    g = p.add_argument_group("scenario (defaults: the paper's nominal case)")
    g.add_argument("--scenario", metavar="FILE.yaml", help="scenario file (Scenario fields; flags override it)")
    g.add_argument("--rig", metavar="RIG.yaml", help="custom rig file instead of a simulated layout")
    g.add_argument("--cameras", type=int, help="number of cameras (default 4)")
    g.add_argument("--layout", choices=LAYOUTS, help="camera placement (default cross for 4 cameras, else ring)")
    g.add_argument("--looking", choices=LOOKING, help="cameras look outward along their bars or all forward (+x)")
    g.add_argument("--bar-length", type=float, help="bar length L (m, default 0.4)")
    g.add_argument("--mass", type=float, help="tip mass (kg, default 0.1)")
    g.add_argument("--EI", "--ei", dest="EI", type=float,
                   help="flexural rigidity (N m^2, default 0.1; inf = rigid); with --rig it sets every massive bar")
    g.add_argument("--focal", type=float, help="focal length (px, default 800)")
    g.add_argument("--points", type=int, help="correspondences N (default 1000)")
    g.add_argument("--noise", type=float, help="pixel noise std (px, default 0.1)")
    g.add_argument("--outliers", type=float, help="outlier fraction in [0, 1) (default 0.05)")
    if with_gravity:
        g.add_argument("--gravity-noise", type=float, help="gravity-measurement noise (px-equivalent angle, "
                       "default 0.01)")
        g.add_argument("--gravity-frame", choices=GRAVITY_FRAMES,
                       help="gravity measured in camera 0's frame, in the body frame, or not at all (default camera)")
    g.add_argument("--max-rotation", type=float, help="motion: max angle per axis (rad, default 0.5)")
    g.add_argument("--max-translation", type=float, help="motion: half-size of the translation cube (m, default 2)")
    p.set_defaults(field_flags={**scenario_field_flags(SCENARIO_FLAGS), **scenario_field_flags(SEQUENCE_FLAGS)})


def add_sequence_arguments(p, sequence_help: str = _SEQUENCE_HELP, views_type=int,
                           views_help: str = "number of static views K (default 10)") -> None:
    """Flags of a simulated sequence of static views (``--sequence``, with the command's own help);
    ``views_type`` parses --views (a command that takes several K passes the largest to
    :func:`sequence_scenario_from_args`)."""
    g = p.add_argument_group(
        "sequence of static views", "With --sequence, --noise defaults to 0.3 px and --max-translation (half-size of "
        "the cube of body positions) to 0.3 m; the other SequenceScenario fields (tilts, depths) come from --scenario.")
    g.add_argument("--sequence", action="store_true", help=sequence_help)
    g.add_argument("--views", type=views_type, help=views_help)
    g.add_argument("--min-step", type=float, help="least rotation between consecutive views (deg, default 5)")
    g.add_argument("--max-step", type=float, help="largest rotation between consecutive views (deg, default 30)")
    g.add_argument("--tracks-per-camera", type=int, help="landmarks visible per camera per view (default 120)")
    g.add_argument("--track-views", type=int, nargs=2, metavar=("MIN", "MAX"),
                   help="run of consecutive views a track is seen in, cut short when it leaves the image "
                        "(default 2 6)")
    g.add_argument("--gravity-noise-deg", type=float,
                   help="measured gravity: std of each tangent-plane component (deg, default 0.3)")
    g.add_argument("--no-gravity", dest="gravity_measured", action="store_const", const=False,
                   help="write no measured gravity (g_meas)")


def check_mode_flags(args, sequence: bool) -> None:
    """Flags of two-view problems are refused with --sequence, and the other way round."""
    for dest in PAIR_ONLY if sequence else SEQUENCE_ONLY:
        if getattr(args, dest, None) is not None:
            raise InputError(flag_of(dest), "applies to two-view problems only, not with --sequence" if sequence
                             else "applies to sequences only (add --sequence)")


def _values(args, flags: dict) -> dict:
    """Scenario field values of the flags given on the command line."""
    values = {}
    for dest, field in flags.items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        values.update(zip(field, value) if isinstance(field, tuple) else {field: value})
    return values


def scenario_from_args(args):
    """(Scenario, custom Rig or None, extras {'seed', 'count', 'rig_file'}) from --scenario, --rig and the flags."""
    from ..sim.scenarios import load_scenario

    return load_scenario("pair", _values(args, SCENARIO_FLAGS), getattr(args, "scenario", None),
                         getattr(args, "rig", None))


def sequence_scenario_from_args(args):
    """(SequenceScenario, custom Rig or None, extras) from --scenario, --rig and the flags."""
    from ..sim.scenarios import load_scenario

    return load_scenario("sequence", _values(args, SEQUENCE_FLAGS), getattr(args, "scenario", None),
                         getattr(args, "rig", None))


def add_trajectory_arguments(p, gt_source: str) -> None:
    """--tum and --tum-gt: the hold poses in each sequence's origin frame, and ``gt_source`` at the same holds."""
    p.add_argument("--tum", metavar="OUT.txt", help="also write the hold poses in each sequence's origin frame "
                   "(TUM format, for evo; a second sequence goes to OUT_seq1.txt, ...)")
    p.add_argument("--tum-gt", metavar="GT.txt", help=f"with --tum: {gt_source} at the same holds, in the same "
                   "origin frame (evo_ape tum GT.txt OUT.txt needs no alignment)")


def jsonable(d):
    """inf and nan -> 'inf' / 'nan' so the JSON stays standard."""
    if isinstance(d, dict):
        return {k: jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [jsonable(v) for v in d]
    if isinstance(d, float) and not math.isfinite(d):
        return str(d)
    return d
