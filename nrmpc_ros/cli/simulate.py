"""``nrmpc simulate``: synthetic rig, matches or tracks, and ground truth (paper section 4 set-up).

Writes into --out: ``rig.yaml`` (docs/CONVENTIONS.md (Files)), ``<prefix>_NNN.npz`` and
``<prefix>_NNN.truth.json`` for --count problems with seeds seed, seed+1, ...
Two-view problems (the default) give matches files (docs/CONVENTIONS.md (Files)) and truth
with R, t, gravity in both views and the outlier indices; ``--sequence``
gives sequences of static views instead: tracks files (see
:mod:`nrmpc_ros.core.tracks`) and truth with R_k, t_k and g_k per view, g_0
and the outlier observation indices (:class:`nrmpc_ros.sim.sequence.SequenceProblem`).
Every truth file also holds the scenario and the seed. The scenario comes
from flags, from a YAML scenario file (the fields of
:class:`nrmpc_ros.sim.synthetic.Scenario`, or with --sequence of
:class:`nrmpc_ros.sim.sequence.SequenceScenario`, plus optional ``seed``,
``count`` and ``rig_file``), or both (flags win).

Outputs: --out is a directory that may already hold other files (several
runs write into one), so it is not replaced as a whole; each file is written
atomically instead (complete or absent, never half-written), and every file
name is checked against the inputs before the first one is written.

The argument helpers here are shared with ``nrmpc observability``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from ..config import load_mapping
from ..errors import InputError
from ..safeio import atomic_write, check_output
from .argtypes import positive_int, seed

# flag dest -> Scenario field or "rig.<RigSpec field>"
_RIG_FLAGS = {
    "cameras": "rig.num_cameras", "layout": "rig.layout", "looking": "rig.looking", "bar_length": "rig.bar_length",
    "mass": "rig.mass", "EI": "rig.EI", "focal": "rig.focal",
}
_SCENARIO_FLAGS = {
    **_RIG_FLAGS, "points": "num_points", "noise": "pixel_noise",
    "outliers": "outlier_fraction", "gravity_noise": "gravity_noise_px", "gravity_frame": "gravity_frame",
    "max_rotation": "max_rotation", "max_translation": "max_translation",
}
# flag dest -> SequenceScenario field (a pair of fields for a flag with two values)
_SEQUENCE_FLAGS = {
    **_RIG_FLAGS, "views": "num_views", "min_step": "min_step_deg", "max_step": "max_step_deg",
    "tracks_per_camera": "tracks_per_camera", "track_views": ("min_track_views", "max_track_views"),
    "noise": "pixel_noise", "outliers": "outlier_fraction", "gravity_noise_deg": "gravity_noise_deg",
    "gravity_measured": "gravity_measured", "max_translation": "max_translation",
}
_EXTRA_KEYS = ("seed", "count", "rig_file")
MAX_COUNT = 100_000  # problems per run: each is its own pair of files


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


def _load_scenario_file(path: str) -> dict:
    """The mapping of a scenario file, read through nrmpc_ros.safeio (size, encoding and YAML bounds)."""
    return load_mapping(path, "scenario file")


def _check_keys(source, d: dict, allowed, prefix=""):
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise InputError(source, f"unknown key (allowed: {', '.join(sorted(allowed))})", prefix + str(unknown[0]))


def scenario_from_args(args):
    """(Scenario, custom Rig or None, extras {'seed', 'count'}) from --scenario and the flags, validated."""
    from ..sim.synthetic import Scenario

    return _scenario_from_args(args, Scenario, _SCENARIO_FLAGS, _validate)


def sequence_scenario_from_args(args):
    """(SequenceScenario, custom Rig or None, extras) from --scenario and the flags, validated."""
    from ..sim.sequence import SequenceScenario

    def validate(sc, source):
        _validate_rig_spec(sc.rig, source)
        sc.validate(source)

    return _scenario_from_args(args, SequenceScenario, _SEQUENCE_FLAGS, validate)


def _scenario_from_args(args, scenario_cls, flags: dict, validate):
    from ..core import load_rig
    from ..sim.synthetic import RigSpec

    sc_fields = {f.name for f in dataclasses.fields(scenario_cls)}
    rig_fields = {f.name for f in dataclasses.fields(RigSpec)}
    d: dict = {"rig": {}}
    extras: dict = {}
    source = "command line"
    if getattr(args, "scenario", None):
        source = args.scenario
        data = _load_scenario_file(args.scenario)
        _check_keys(source, data, sc_fields | set(_EXTRA_KEYS))
        rig_d = data.get("rig") or {}
        if not isinstance(rig_d, dict):
            raise InputError(source, "must be a mapping of RigSpec fields", "rig")
        _check_keys(source, rig_d, rig_fields, "rig.")
        d.update({k: v for k, v in data.items() if k in sc_fields and k != "rig"})
        d["rig"].update(rig_d)
        extras = {k: data[k] for k in _EXTRA_KEYS if k in data}
        if "rig_file" in extras:
            rf = Path(extras["rig_file"])
            extras["rig_file"] = str(rf if rf.is_absolute() else Path(args.scenario).parent / rf)
    for dest, key in flags.items():
        value = getattr(args, dest, None)
        if value is None:
            continue
        if isinstance(key, tuple):
            d.update(zip(key, value))
        elif key.startswith("rig."):
            d["rig"][key[4:]] = value
        else:
            d[key] = value
    r = d["rig"]
    if "layout" not in r and r.get("num_cameras", 4) != 4:
        r["layout"] = "ring"
    if "resolution" in r:
        res = r["resolution"]
        if not (isinstance(res, (list, tuple)) and len(res) == 2 and all(_integer(v) and v >= 1 for v in res)):
            raise InputError(source, f"expected [width, height] in pixels, got {res!r}", "rig.resolution")
        r["resolution"] = tuple(res)
    for key in ("seed", "count"):
        if key in extras and not (_integer(extras[key]) and extras[key] >= (0 if key == "seed" else 1)):
            raise InputError(source, f"must be an integer >= {0 if key == 'seed' else 1}, got {extras[key]!r}", key)
    if "rig_file" in extras and not isinstance(extras["rig_file"], str):
        raise InputError(source, f"must be a path, got {extras['rig_file']!r}", "rig_file")
    try:
        sc = scenario_cls.from_dict(d)
    except TypeError as exc:
        raise InputError(source, f"bad scenario ({exc})") from None
    validate(sc, source)
    rig = None
    rig_path = getattr(args, "rig", None) or extras.get("rig_file")
    if rig_path:
        for dest in ("cameras", "layout", "looking", "bar_length", "mass", "focal"):
            if getattr(args, dest, None) is not None:
                raise InputError("--" + dest.replace("_", "-"), "cannot be combined with a custom rig (--rig); "
                                 "edit the rig file instead")
        rig = load_rig(rig_path)
        if getattr(args, "EI", None) is not None:
            from ..experiments.crlb import set_bar_ei

            rig = set_bar_ei(rig, args.EI)
    return sc, rig, extras


def _need(source: str, ok: bool, field: str, msg: str) -> None:
    if not ok:
        raise InputError(source, msg, field)


def _integer(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _real(x) -> bool:
    """A number a scenario field may hold: int or float, never a bool, and not NaN."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and not (isinstance(x, float) and math.isnan(x))


def _check_types(source: str, obj, prefix: str, strings: tuple) -> None:
    """Every field of a scenario dataclass is a number (int or float, not a bool), or a string for ``strings``."""
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if f.name in strings:
            _need(source, isinstance(v, str), prefix + f.name, f"must be a string, got {v!r}")
        elif f.name not in ("rig", "resolution"):
            _need(source, _real(v), prefix + f.name, f"must be a number, got {v!r}")


def _validate_rig_spec(r, source: str) -> None:
    """RigSpec values make_rig can use; InputError names the field."""
    _need(source, _integer(r.num_cameras) and 1 <= r.num_cameras <= 1000, "rig.num_cameras",
          "must be an integer in 1..1000")
    _check_types(source, r, "rig.", ("layout", "looking"))
    try:
        r.validate()
    except ValueError as exc:
        raise InputError(source, str(exc), "rig") from None
    _need(source, r.bar_length > 0 and math.isfinite(r.bar_length), "rig.bar_length", "must be > 0 (m)")
    _need(source, r.mass >= 0 and math.isfinite(r.mass), "rig.mass", "must be >= 0 (kg)")
    _need(source, r.EI > 0, "rig.EI", "must be > 0 (N m^2; inf = rigid)")
    _need(source, r.focal > 0 and math.isfinite(r.focal), "rig.focal", "must be > 0 (px)")


def _validate(sc, source: str) -> None:
    """Scenario values a generator can use; InputError names the field."""
    from ..sim.synthetic import GRAVITY_FRAMES

    def need(ok, field, msg):
        _need(source, ok, field, msg)

    _validate_rig_spec(sc.rig, source)
    _check_types(source, sc, "", ("gravity_frame",))
    need(_integer(sc.num_points) and 1 <= sc.num_points <= 10_000_000, "num_points",
         "must be an integer in 1..10000000")
    need(sc.num_points >= sc.rig.num_cameras, "num_points", "must be at least the number of cameras")
    need(0 <= sc.pixel_noise < math.inf, "pixel_noise", "must be finite and >= 0 (px)")
    need(0 <= sc.outlier_fraction < 1, "outlier_fraction", "must be in [0, 1)")
    need(0 <= sc.gravity_noise_px < math.inf, "gravity_noise_px", "must be finite and >= 0 (px)")
    need(sc.gravity_frame in GRAVITY_FRAMES, "gravity_frame", f"must be one of {', '.join(GRAVITY_FRAMES)}")
    need(0 <= sc.max_rotation < math.inf, "max_rotation", "must be finite and >= 0 (rad)")
    need(0 <= sc.max_translation < math.inf, "max_translation", "must be finite and >= 0 (m)")


_SEQUENCE_HELP = "write sequences of static views (tracks .npz) instead of two-view problems (matches .npz)"


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


# flags of one kind of problem that the other kind does not take
_PAIR_ONLY = ("points", "gravity_noise", "gravity_frame", "max_rotation")
_SEQUENCE_ONLY = ("views", "min_step", "max_step", "tracks_per_camera", "track_views", "gravity_noise_deg",
                  "gravity_measured")


def _check_mode_flags(args, sequence: bool) -> None:
    for dest in _PAIR_ONLY if sequence else _SEQUENCE_ONLY:
        if getattr(args, dest, None) is not None:
            flag = "--no-gravity" if dest == "gravity_measured" else "--" + dest.replace("_", "-")
            raise InputError(flag, "applies to two-view problems only, not with --sequence" if sequence
                             else "applies to sequences only (add --sequence)")


def register(sub):
    p = sub.add_parser(
        "simulate", help="write a synthetic rig, matches (or tracks) .npz and ground-truth JSON",
        description="Draws --count seeded two-view problems of a bending rig (the paper's section 4 set-up), or "
                    "with --sequence sequences of static views with landmark tracks, and writes rig.yaml, "
                    "<prefix>_NNN.npz and <prefix>_NNN.truth.json into --out. "
                    "Solve pairs with: nrmpc solve --rig OUT/rig.yaml --method 4pt-bending OUT/*.npz")
    p.add_argument("--out", required=True, help="output directory (created if missing); each file in it is written "
                   "atomically")
    p.add_argument("--seed", type=seed, help="seed of the first problem (default 0); problem k uses seed + k")
    p.add_argument("--count", type=positive_int, help="number of problems (default 1)")
    p.add_argument("--prefix", help="file name prefix (default: pair, or seq with --sequence)")
    add_scenario_arguments(p)
    add_sequence_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core import save_matches, save_rig
    from ..sim.synthetic import make_problem, make_rig

    sequence = bool(getattr(args, "sequence", False))
    _check_mode_flags(args, sequence)
    sc, rig, extras = (sequence_scenario_from_args if sequence else scenario_from_args)(args)
    seed = args.seed if args.seed is not None else int(extras.get("seed", 0))
    count = args.count if args.count is not None else int(extras.get("count", 1))
    prefix = args.prefix if args.prefix is not None else ("seq" if sequence else "pair")
    if count > MAX_COUNT:
        raise InputError("--count" if args.count is not None else args.scenario, f"must be <= {MAX_COUNT}, got "
                         f"{count}", None if args.count is not None else "count")
    if not prefix or "/" in prefix or prefix in (".", ".."):
        raise InputError("--prefix", f"must be a plain file name prefix, got {prefix!r}")
    out = Path(args.out)
    width = max(3, len(str(count - 1)))
    names = [f"{prefix}_{k:0{width}d}" for k in range(count)]
    inputs = {"--rig": args.rig, "--scenario": args.scenario, "rig_file of --scenario": extras.get("rig_file")}
    check_output(out, inputs, "--out", directory=True)
    for path in [out / "rig.yaml"] + [out / f"{n}{ext}" for n in names for ext in (".npz", ".truth.json")]:
        check_output(path, inputs, "--out")
    rig = rig if rig is not None else make_rig(sc.rig)
    rig_path = out / "rig.yaml"
    save_rig(rig, rig_path, header=f"written by nrmpc simulate; scenario: {json.dumps(sc.to_dict())}", flag="--out")
    for k, name in enumerate(names):
        s = seed + k
        if sequence:
            from ..core.tracks import save_tracks
            from ..sim.sequence import make_sequence

            seq = make_sequence(sc, seed=s, rig=rig)
            save_tracks(seq.tracks, out / f"{name}.npz", flag="--out")
            truth = {"tracks": f"{name}.npz", "rig": "rig.yaml", "seed": s, **seq.truth_dict()}
        else:
            problem = make_problem(sc, seed=s, rig=rig)
            save_matches(problem.matches, out / f"{name}.npz", flag="--out")
            truth = {"matches": f"{name}.npz", "rig": "rig.yaml", "seed": s, **problem.truth_dict()}
        truth["scenario"] = _jsonable(sc.to_dict())
        with atomic_write(out / f"{name}.truth.json", flag="--out") as fh:
            fh.write(json.dumps(truth) + "\n")
    kind = "sequence" if sequence else "problem"
    print(f"wrote {rig_path} and {count} {kind}(s) {prefix}_*.npz / .truth.json to {out}")
    return 0


def _jsonable(d):
    """inf -> 'inf' so the JSON stays standard."""
    if isinstance(d, dict):
        return {k: _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    if isinstance(d, float) and not math.isfinite(d):
        return str(d)
    return d
