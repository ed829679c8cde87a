"""Options with their documentation and valid range in one place: dataclass field metadata.

Every setting of the front end, the estimators and the node is a dataclass
field made with :func:`option`: default, one line of documentation (units
included), and the values it may take (numeric range, choices). From that one
declaration come the validation (:func:`check`: one InputError naming the
field), the builder from nested mappings such as YAML files or ROS
parameters (:func:`from_mapping`: unknown keys are errors naming them), the
reader of settings files (:func:`from_file`: read through
:func:`nrmpc_ros.safeio.load_yaml`, every error naming the file and the
key), and the ROS parameter descriptors of the node (:func:`describe_fields`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import MISSING, dataclass, field, fields, is_dataclass

from .errors import InputError


def option(default, doc: str, *, lo=None, hi=None, lo_open: bool = False, choices: tuple | None = None,
           nullable: bool = False):
    """A dataclass field with its documentation and valid values (``lo`` <= x <= ``hi``, x > lo when
    ``lo_open``; ``choices``; ``nullable``: None allowed, meaning "off" as the doc says)."""
    meta = {"doc": doc, "lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices, "nullable": nullable}
    if is_dataclass(default) and not isinstance(default, type):
        return field(default_factory=lambda d=default: dataclasses.replace(d), metadata=meta)
    if isinstance(default, (dict, list)):
        return field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    return field(default=default, metadata=meta)


def _kind(default):
    if isinstance(default, bool):
        return bool
    if isinstance(default, int):
        return int
    if isinstance(default, float):
        return float
    return type(default)


def _field_kind(f: dataclasses.Field, default, value):
    """The type a field's values have: its default's, else its annotation's (a field whose default is None)."""
    if default is not None:
        return _kind(default)
    annotation = str(f.type)
    for name, kind in (("bool", bool), ("int", int), ("float", float), ("str", str)):
        if name in annotation.replace("None", "").split("|")[0]:
            return kind
    return type(value)


def _shown(value) -> str:
    """A value as the error message shows it: huge integers shortened (no screenful of digits)."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:12]}...({len(text)} characters)"


def _bound(x) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def check_value(value, f: dataclasses.Field, source: str, name: str):
    """The value converted to the field's kind (an int for a float field becomes a float), or InputError."""
    m = f.metadata
    default = f.default if f.default is not MISSING else (f.default_factory() if f.default_factory is not MISSING
                                                          else None)
    if value is None:
        if m.get("nullable"):
            return None
        raise InputError(source, "must be given (null is not allowed here)", name)
    kind = _field_kind(f, default, value)
    if kind is bool:
        if not isinstance(value, bool):
            raise InputError(source, f"must be true or false, got {_shown(value)}", name)
        return value
    if kind in (int, float):
        given = value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(source, f"must be a number, got {_shown(value)}", name)
        if kind is int and isinstance(value, float) and not value.is_integer():
            raise InputError(source, f"must be an integer, got {_shown(value)}", name)
        try:
            value = int(value) if kind is int else float(value)
        except OverflowError:  # an integer beyond the float range, as a float field's value
            raise InputError(source, f"must be a finite number, got {_shown(given)}", name) from None
        if kind is float and (math.isnan(value) or (math.isinf(value) and m.get("hi") is not None and value > 0)):
            raise InputError(source, f"must be a finite number, got {_shown(given)}", name)
        lo, hi = m.get("lo"), m.get("hi")
        if lo is not None and (value <= lo if m.get("lo_open") else value < lo):
            raise InputError(source, f"must be {'>' if m.get('lo_open') else '>='} {_bound(lo)}, got {_shown(given)}",
                             name)
        if hi is not None and value > hi:
            raise InputError(source, f"must be <= {_bound(hi)}, got {_shown(given)}", name)
        if kind is float and math.isinf(value) and lo is not None and value < 0:
            raise InputError(source, f"must be a finite number, got {_shown(given)}", name)
        return value
    if kind is str:
        if not isinstance(value, str):
            raise InputError(source, f"must be a string, got {value!r}", name)
    choices = m.get("choices")
    if choices and value not in choices:
        raise InputError(source, f"must be one of {', '.join(map(str, choices))}, got {value!r}", name)
    return value


def check(cfg, source: str = "config", prefix: str = "") -> None:
    """Validate every :func:`option` field of a dataclass instance (nested ones too), in place."""
    for f in fields(cfg):
        name = f"{prefix}{f.name}"
        value = getattr(cfg, f.name)
        if is_dataclass(value) and not isinstance(value, type):
            check(value, source, f"{name}.")
        elif "doc" in f.metadata:
            object.__setattr__(cfg, f.name, check_value(value, f, source, name))


def from_mapping(cls, d, source: str = "config", prefix: str = ""):
    """An instance of dataclass ``cls`` from a nested mapping; unknown keys and bad values are InputErrors
    naming the key (``prefix`` + name) and ``source``."""
    if d is None:
        d = {}
    if not isinstance(d, dict):
        raise InputError(source, f"expected a mapping, got {type(d).__name__}", prefix.rstrip(".") or None)
    names = {f.name: f for f in fields(cls)}
    unknown = sorted(set(map(str, d)) - set(names))
    if unknown:
        raise InputError(source, f"unknown option (allowed: {', '.join(sorted(names))})", f"{prefix}{unknown[0]}")
    kw = {}
    for key, value in d.items():
        f = names[key]
        default = f.default_factory() if f.default_factory is not MISSING else f.default
        if is_dataclass(default) and not isinstance(default, type):
            kw[key] = from_mapping(type(default), value, source, f"{prefix}{key}.")
        else:
            kw[key] = check_value(value, f, source, f"{prefix}{key}") if "doc" in f.metadata else value
    try:
        out = cls(**kw)
    except InputError as exc:  # a __post_init__ check across fields
        raise InputError(source, exc.message, exc.field and f"{prefix}{exc.field}") from None
    check(out, source, prefix)
    return out


def load_mapping(path, what: str) -> dict:
    """The top-level mapping of a YAML settings file, read through :func:`nrmpc_ros.safeio.load_yaml` (size,
    encoding, aliases and nesting bounded); an empty file is an empty mapping."""
    from .safeio import load_yaml

    data = load_yaml(path, what=what)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(str(path), f"a {what} must be a mapping of settings (key: value), got "
                                    f"{type(data).__name__}")
    return data


def from_file(cls, path, what: str, defaults: dict | None = None):
    """An instance of dataclass ``cls`` from a YAML file of its fields (:func:`load_mapping`, then
    :func:`from_mapping`); ``defaults`` fill keys the file does not set. Every error names the file and key."""
    data = load_mapping(path, what)
    return from_mapping(cls, {**(defaults or {}), **data}, str(path))


def to_mapping(cfg) -> dict:
    """The nested mapping of a config (inverse of :func:`from_mapping`)."""
    out = {}
    for f in fields(cfg):
        v = getattr(cfg, f.name)
        out[f.name] = to_mapping(v) if is_dataclass(v) and not isinstance(v, type) else v
    return out


@dataclass(frozen=True)
class FieldInfo:
    """A flattened option: dotted name, default, documentation and valid values (for ROS parameters)."""

    name: str
    default: object
    doc: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple | None = None


def describe_fields(cls_or_cfg, prefix: str = "") -> list:
    """Every :func:`option` of a (nested) config, flattened with dots."""
    cfg = cls_or_cfg() if isinstance(cls_or_cfg, type) else cls_or_cfg
    out = []
    for f in fields(cfg):
        v = getattr(cfg, f.name)
        if is_dataclass(v) and not isinstance(v, type):
            out += describe_fields(v, f"{prefix}{f.name}.")
        elif "doc" in f.metadata:
            m = f.metadata
            out.append(FieldInfo(f"{prefix}{f.name}", v, m["doc"], m.get("lo"), m.get("hi"), m.get("choices")))
    return out


__all__ = ["FieldInfo", "check", "check_value", "describe_fields", "from_file", "from_mapping", "load_mapping",
           "option", "to_mapping"]
