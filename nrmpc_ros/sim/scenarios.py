"""Scenarios of simulated problems: built from a scenario file and field values, validated, with a custom rig.

A scenario is a :class:`~nrmpc_ros.sim.synthetic.Scenario` (two-view
problems) or a :class:`~nrmpc_ros.sim.sequence.SequenceScenario` (sequences
of static views). :func:`load_scenario` merges, in this order, the defaults,
a YAML scenario file (the dataclass's fields, a ``rig`` mapping of
:class:`~nrmpc_ros.sim.synthetic.RigSpec` fields, plus optional ``seed``,
``count`` and ``rig_file``) and field values given by the caller (a command
line's flags), and checks every value. Errors name the file and key, or for
the caller's values the field (``rig.num_cameras``, ``pixel_noise``); a
command line maps fields back to its flags.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from ..config import load_mapping
from ..errors import InputError, OptionError

KINDS = ("pair", "sequence")
EXTRA_KEYS = ("seed", "count", "rig_file")  # keys of a scenario file beside the scenario's fields
# rig fields a custom rig file replaces (EI may still be set: it then sets every massive bar)
RIG_FILE_EXCLUDES = ("num_cameras", "layout", "looking", "bar_length", "mass", "focal")
_OWNER = "scenario"  # how OptionError names the caller's field values


def load_scenario_file(path: str) -> dict:
    """The mapping of a scenario file, read through nrmpc_ros.safeio (size, encoding and YAML bounds)."""
    return load_mapping(path, "scenario file")


def scenario_class(kind: str):
    """The scenario dataclass of ``kind`` ('pair' or 'sequence')."""
    if kind == "pair":
        from .synthetic import Scenario

        return Scenario
    if kind == "sequence":
        from .sequence import SequenceScenario

        return SequenceScenario
    raise OptionError(_OWNER, "kind", f"must be one of {', '.join(KINDS)}, got {kind!r}")


def load_scenario(kind: str, values: dict | None = None, scenario_file: str | None = None,
                  rig_file: str | None = None):
    """(scenario, custom Rig or None, extras {'seed', 'count', 'rig_file'}), validated.

    ``values`` maps scenario fields (``pixel_noise``) and rig fields (``rig.EI``)
    to values; they override ``scenario_file``'s. ``rig_file`` (else the
    file's ``rig_file``, relative to the scenario file) replaces the simulated
    rig; ``rig.EI`` then sets every massive bar's EI.
    """
    from ..core import load_rig
    from .synthetic import RigSpec, default_layout

    cls = scenario_class(kind)
    sc_fields = {f.name for f in dataclasses.fields(cls)}
    rig_fields = {f.name for f in dataclasses.fields(RigSpec)}
    values = dict(values or {})
    d: dict = {"rig": {}}
    extras: dict = {}
    source = "command line"
    if scenario_file:
        source = scenario_file
        data = load_scenario_file(scenario_file)
        _check_keys(source, data, sc_fields | set(EXTRA_KEYS))
        rig_d = data.get("rig") or {}
        if not isinstance(rig_d, dict):
            raise InputError(source, "must be a mapping of RigSpec fields", "rig")
        _check_keys(source, rig_d, rig_fields, "rig.")
        d.update({k: v for k, v in data.items() if k in sc_fields and k != "rig"})
        d["rig"].update(rig_d)
        extras = {k: data[k] for k in EXTRA_KEYS if k in data}
        if "rig_file" in extras and isinstance(extras["rig_file"], str):
            rf = Path(extras["rig_file"])
            extras["rig_file"] = str(rf if rf.is_absolute() else Path(scenario_file).parent / rf)
    unknown = sorted(k for k in values if k not in sc_fields - {"rig"} and k.removeprefix("rig.") not in rig_fields)
    if unknown:
        raise OptionError(_OWNER, unknown[0], f"is not a field of {cls.__name__} or rig.RigSpec")
    for key, value in values.items():
        if key.startswith("rig."):
            d["rig"][key[4:]] = value
        else:
            d[key] = value
    r = d["rig"]
    if "layout" not in r:
        r["layout"] = default_layout(r.get("num_cameras", RigSpec.num_cameras))
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
        sc = cls.from_dict(d)
    except TypeError as exc:
        raise InputError(source, f"bad scenario ({exc})") from None
    if kind == "pair":
        validate_scenario(sc, source)
    else:
        validate_rig_spec(sc.rig, source)
        sc.validate(source)
    rig = None
    rig_path = rig_file or extras.get("rig_file")
    if rig_path:
        for name in RIG_FILE_EXCLUDES:
            if "rig." + name in values:
                raise OptionError(_OWNER, "rig." + name, "cannot be combined with a custom rig file; edit the rig "
                                  "file instead")
        rig = load_rig(rig_path)
        if "rig.EI" in values:
            rig = rig.with_bar_ei(values["rig.EI"])
    return sc, rig, extras


def _check_keys(source, d: dict, allowed, prefix=""):
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise InputError(source, f"unknown key (allowed: {', '.join(sorted(allowed))})", prefix + str(unknown[0]))


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


def validate_rig_spec(r, source: str) -> None:
    """RigSpec values make_rig can use; InputError names the field."""
    _need(source, _integer(r.num_cameras) and 1 <= r.num_cameras <= 1000, "rig.num_cameras",
          "must be an integer in 1..1000")
    _check_types(source, r, "rig.", ("layout", "looking"))
    try:
        r.validate()
    except OptionError as exc:  # the spec names its field
        raise InputError(source, exc.message, f"rig.{exc.field}") from None
    _need(source, r.bar_length > 0 and math.isfinite(r.bar_length), "rig.bar_length", "must be > 0 (m)")
    _need(source, r.mass >= 0 and math.isfinite(r.mass), "rig.mass", "must be >= 0 (kg)")
    _need(source, r.EI > 0, "rig.EI", "must be > 0 (N m^2; inf = rigid)")
    _need(source, r.focal > 0 and math.isfinite(r.focal), "rig.focal", "must be > 0 (px)")


def validate_scenario(sc, source: str) -> None:
    """Two-view Scenario values a generator can use; InputError names the field."""
    from .synthetic import GRAVITY_FRAMES

    def need(ok, field, msg):
        _need(source, ok, field, msg)

    validate_rig_spec(sc.rig, source)
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
