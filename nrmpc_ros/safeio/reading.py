"""Hardened reading of input files: the one place where the package opens what it reads.

Every loader of the package (rig YAML, matches .npz, tracks, pipeline
configuration, CSV) reads its bytes through these functions, so that an odd or
hostile file -- too big, binary, in the wrong text encoding, a YAML alias bomb,
ten thousand nested brackets, a zip bomb, a pickle -- ends in ONE
:class:`~nrmpc_ros.errors.InputError` naming the file, never in a traceback, a
memory blow-up or a silently wrong value.

- :func:`read_text`: bytes -> UTF-8 text, size checked before reading.
- :func:`load_yaml` / :func:`yaml_from_text`: YAML with bounded aliases, nesting
  depth and expanded size (a ``yaml.SafeLoader``, so no Python objects).
- :func:`load_npz`: a ``numpy.savez`` archive, every member's declared size and
  dtype checked from the zip directory and the ``.npy`` header before anything
  is allocated; pickles are never loaded.

The limits are the module constants below; callers pass tighter or looser
ones for their own file kind. What each loader accepts is described in
docs/INPUTS.md.

Outputs are written by :mod:`.writing`.
"""

from __future__ import annotations

import lzma
import math
import os
import re
import stat
import zipfile
import zlib

import numpy as np
import numpy.lib.format as npy_format
import yaml

from ..errors import InputError

KiB = 1 << 10
MiB = 1 << 20
GiB = 1 << 30

# --- Limits (one place for each) ---------------------------------------------
YAML_MAX_BYTES = 1 * MiB  # a rig file or a pipeline configuration is a few kB: 1 MiB is a generous bound
YAML_MAX_ALIASES = 100  # hand-written files use a handful of anchors; alias bombs need many more
YAML_MAX_DEPTH = 64  # configurations nest 3-5 levels; deeper is generated garbage (and recursion in PyYAML)
YAML_MAX_NODES = 100_000  # nodes after alias expansion: a 1 MiB file of plain values holds fewer than this
NPZ_MAX_MEMBERS = 64  # a data archive holds a few named arrays
NPY_MAX_HEADER_BYTES = 10_000  # numpy's own bound on the .npy header (a Python literal parsed on load)
_SNIFF_BYTES = 512  # enough of a file's start to tell zip, .npy, pickle, gzip and text apart

# Every exception a corrupt zip member, compressor or .npy payload can raise while being decoded.
_DECODE_ERRORS = (
    zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, lzma.LZMAError, EOFError, OSError, ValueError,
    NotImplementedError, RuntimeError, OverflowError, TypeError, SyntaxError, RecursionError,
)


def _size_text(n: int) -> str:
    for unit, scale in (("GiB", GiB), ("MiB", MiB), ("KiB", KiB)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"


def check_input_file(path, *, what: str, max_bytes: int) -> os.stat_result:
    """``os.stat`` the input and refuse a missing file, a directory or one bigger than ``max_bytes``.

    Nothing is read. Non-regular files (a pipe, ``/dev/stdin``) pass; their
    readers bound what they read instead.
    """
    src = str(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(src, f"cannot read {what}: no such file") from None
    except NotADirectoryError:
        raise InputError(src, f"cannot read {what}: a parent of this path is not a directory") from None
    except OSError as exc:
        raise InputError(src, f"cannot read {what} ({exc.strerror or exc})") from None
    except (ValueError, TypeError) as exc:  # an embedded NUL or a path of the wrong type
        raise InputError(src, f"cannot read {what}: invalid path ({exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(src, f"cannot read {what}: this is a directory, not a file")
    if st.st_size > max_bytes:
        raise InputError(src, f"{what} is {_size_text(st.st_size)}, more than the {_size_text(max_bytes)} "
                              f"such a file may have")
    return st


def read_bytes(path, *, what: str, max_bytes: int) -> bytes:
    """All bytes of a file of at most ``max_bytes`` (checked before reading, and again while reading)."""
    src = str(path)
    check_input_file(path, what=what, max_bytes=max_bytes)
    try:
        with open(path, "rb") as fh:
            data = fh.read(max_bytes + 1)  # a file that grows, or a pipe, is still bounded
    except IsADirectoryError:
        raise InputError(src, f"cannot read {what}: this is a directory, not a file") from None
    except OSError as exc:
        raise InputError(src, f"cannot read {what} ({exc.strerror or exc})") from None
    if len(data) > max_bytes:
        raise InputError(src, f"{what} is more than the {_size_text(max_bytes)} such a file may have")
    return data


def _line_col(data: bytes, offset: int) -> str:
    line = data.count(b"\n", 0, offset) + 1
    col = offset - (data.rfind(b"\n", 0, offset) + 1) + 1
    return f"line {line}, column {col}"


def _utf16_without_bom(data: bytes) -> str | None:
    """'UTF-16-LE' / 'UTF-16-BE' when NULs sit at every odd / even byte (ASCII text in UTF-16), else None."""
    if len(data) < 2:
        return None
    even, odd = data[0::2], data[1::2]
    if odd.count(0) >= 0.9 * len(odd) and even.count(0) == 0:
        return "UTF-16-LE"
    if even.count(0) >= 0.9 * len(even) and odd.count(0) == 0:
        return "UTF-16-BE"
    return None


def decode_text(data: bytes, source: str, *, what: str) -> str:
    """UTF-8 bytes -> str; refuse binary content and other encodings, naming the encoding it looks like.

    A UTF-8 byte-order mark is dropped. UTF-16/UTF-32 (with or without a
    byte-order mark), Latin-1 / Windows-1252 and binary data are refused with
    the offset of the first offending byte, so the user knows what to re-save.
    """
    boms = ((b"\x00\x00\xfe\xff", "UTF-32-BE"), (b"\xff\xfe\x00\x00", "UTF-32-LE"),
            (b"\xfe\xff", "UTF-16-BE"), (b"\xff\xfe", "UTF-16-LE"))
    for bom, name in boms:
        if data.startswith(bom):
            raise InputError(source, f"{what} is {name} text (byte-order mark {bom.hex(' ')}); save it as UTF-8")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    nul = data.find(b"\x00")
    if nul >= 0:
        utf16 = _utf16_without_bom(data)
        if utf16:
            raise InputError(source, f"{what} looks like {utf16} text without a byte-order mark (NUL bytes "
                                     f"between the characters); save it as UTF-8")
        raise InputError(source, f"{what} is binary, not text: NUL byte at offset {nul} ({_line_col(data, nul)})")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        where = f"byte 0x{data[exc.start]:02x} at {_line_col(data, exc.start)}, offset {exc.start}"
        try:
            sample = data.decode("cp1252")
        except UnicodeDecodeError:
            sample = None
        if sample is not None and all(ch.isprintable() or ch in "\t\r\n" for ch in sample):
            raise InputError(source, f"{what} is not UTF-8: {where}; it looks like Latin-1 / Windows-1252 "
                                     f"text: save it as UTF-8") from None
        raise InputError(source, f"{what} is not UTF-8 text: {where}") from None


def read_text(path, *, what: str, max_bytes: int) -> str:
    """The text of a UTF-8 file of at most ``max_bytes``.

    The size is checked with ``os.stat`` before anything is read. Refused, each
    with one InputError naming ``path``: a missing or unreadable file, a
    directory, a file too big, binary content (NUL bytes) and text that is not
    UTF-8 (the message says whether it looks like UTF-16, UTF-32 or Latin-1).
    ``what`` names the kind of file in messages ("rig file").
    """
    return decode_text(read_bytes(path, what=what, max_bytes=max_bytes), str(path), what=what)


# ---------------------------------------------------------------------------
# YAML
# ---------------------------------------------------------------------------

class BoundedSafeLoader(yaml.SafeLoader):
    """A SafeLoader that refuses alias bombs and deep nesting while composing, before anything is built.

    Each composed node is weighed: its size and height *after* alias
    expansion (an alias weighs as much as its target). A "billion laughs"
    document has few nodes but an exponential expanded size, so it is refused
    as soon as one node weighs more than ``max_nodes``, without expanding it.
    Nesting is counted on the way down, so 50 000 brackets stop at
    ``max_depth`` instead of exhausting Python's recursion limit.
    """

    def __init__(self, stream, *, source: str, max_aliases: int, max_depth: int, max_nodes: int):
        super().__init__(stream)
        self._source = source
        self._limits = (max_aliases, max_depth, max_nodes)
        self._aliases = 0
        self._depth = 0
        self._weights: dict[int, tuple[int, int]] = {}  # id(node) -> (expanded size, expanded height)

    def _refuse(self, message: str, event) -> None:
        mark = getattr(event, "start_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        raise InputError(self._source, f"{message}{where}")

    def compose_node(self, parent, index):
        max_aliases, max_depth, max_nodes = self._limits
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            self._aliases += 1
            if self._aliases > max_aliases:
                self._refuse(f"more than {max_aliases} YAML aliases (*name); refusing a possible alias bomb", event)
            node = super().compose_node(parent, index)
            if id(node) not in self._weights:
                self._refuse(f"YAML alias *{event.anchor} refers to a node that contains it (a recursive "
                             f"structure)", event)
            return node
        event = self.peek_event()
        self._depth += 1
        if self._depth > max_depth:
            self._refuse(f"YAML nested deeper than {max_depth} levels", event)
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        size, height = self._weigh(node)
        if size > max_nodes:
            self._refuse(f"YAML expands to more than {max_nodes} values (through aliases); refusing a possible "
                         f"alias bomb", event)
        if height > max_depth:
            self._refuse(f"YAML nested deeper than {max_depth} levels (through aliases)", event)
        return node

    def _weigh(self, node) -> tuple[int, int]:
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        else:
            children = ()
        weights = [self._weights[id(c)] for c in children]
        w = (1 + sum(s for s, _ in weights), 1 + max((h for _, h in weights), default=0))
        self._weights[id(node)] = w
        return w


# YAML 1.2 reads 1e-3 as a float; PyYAML's YAML 1.1 rules read it as the string '1e-3' (a float there needs a
# dot: 1.0e-3). Plain scalars in exponent form are resolved as floats here; quoted ones stay strings.
BoundedSafeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789"))


def _yaml_error_text(exc: yaml.YAMLError) -> str:
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem:
        mark = exc.problem_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        context = f" ({exc.context})" if exc.context else ""
        return f"{exc.problem}{context}{where}"
    return str(exc).replace("\n", " ")


def yaml_from_text(text: str, source: str, *, max_chars: int = YAML_MAX_BYTES, max_aliases: int = YAML_MAX_ALIASES,
                   max_depth: int = YAML_MAX_DEPTH, max_nodes: int = YAML_MAX_NODES, loader=None):
    """Parse one YAML document from a string with the bounds of :func:`load_yaml`; ``source`` names it in errors.

    Returns plain Python data (dict, list, str, int, float, bool, None,
    datetime, bytes): SafeLoader tags only. An empty document gives None.
    ``loader`` is a subclass of :class:`BoundedSafeLoader` with extra
    constructors (OpenCV's matrices in Kalibr files); it keeps the bounds.
    """
    loader_cls = loader or BoundedSafeLoader
    if not isinstance(text, str):
        raise InputError(source, f"expected YAML text, got {type(text).__name__}")
    if len(text) > max_chars:
        raise InputError(source, f"YAML text of {len(text)} characters, more than the {max_chars} allowed")
    loader = None
    try:
        loader = loader_cls(text, source=source, max_aliases=max_aliases, max_depth=max_depth,
                            max_nodes=max_nodes)  # the reader already refuses control characters
        return loader.get_single_data()
    except InputError:
        raise
    except yaml.YAMLError as exc:
        raise InputError(source, f"not valid YAML: {_yaml_error_text(exc)}") from None
    except RecursionError:
        raise InputError(source, "not valid YAML: nested too deeply") from None
    except (ValueError, OverflowError, TypeError) as exc:  # a scalar a constructor cannot convert
        reason = str(exc).split(";")[0]  # drop interpreter advice such as sys.set_int_max_str_digits()
        raise InputError(source, f"not valid YAML: a value cannot be read ({reason})") from None
    finally:
        if loader is not None:
            loader.dispose()


def load_yaml(path, *, what: str, max_bytes: int = YAML_MAX_BYTES, max_aliases: int = YAML_MAX_ALIASES,
              max_depth: int = YAML_MAX_DEPTH, max_nodes: int = YAML_MAX_NODES):
    """Read and parse a YAML file safely (see :func:`read_text` and :func:`yaml_from_text`).

    ``max_aliases`` bounds the number of aliases, ``max_nodes`` the number of
    values after alias expansion and ``max_depth`` the nesting depth; a file
    beyond any bound is refused while it is being parsed, before it is built.
    """
    text = read_text(path, what=what, max_bytes=max_bytes)
    return yaml_from_text(text, str(path), max_chars=max_bytes, max_aliases=max_aliases, max_depth=max_depth,
                          max_nodes=max_nodes)


# ---------------------------------------------------------------------------
# .npz
# ---------------------------------------------------------------------------

def _sniff(head: bytes) -> str | None:
    """Why ``head`` (a file's first bytes) is not a zip archive, or None if it is one."""
    if head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        return None
    if head.startswith(npy_format.MAGIC_PREFIX):
        return "it is a single .npy array (numpy.save), not an .npz archive (numpy.savez)"
    if len(head) >= 2 and head[0] == 0x80 and 2 <= head[1] <= 5:
        return "it is a Python pickle; pickles are never loaded (they can run code)"
    if head.startswith(b"\x1f\x8b"):
        return "it is gzip-compressed; an .npz is a zip archive"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 3:
            return "it is not a zip archive"
        text = head[:exc.start].decode("utf-8")  # the sniff window cut a multi-byte character: still text
    if all(ch.isprintable() or ch in "\t\r\n" for ch in text):
        return "it is text, not a zip archive"
    return "it is not a zip archive"


def _npy_header(fp, src: str, key: str):
    """(shape, fortran_order, dtype) of a .npy stream, from its header only."""
    version = npy_format.read_magic(fp)
    if version == (1, 0):
        return npy_format.read_array_header_1_0(fp, max_header_size=NPY_MAX_HEADER_BYTES)
    if version == (2, 0):
        return npy_format.read_array_header_2_0(fp, max_header_size=NPY_MAX_HEADER_BYTES)
    raise InputError(src, f"unsupported .npy format version {version[0]}.{version[1]}", key)


def _member_key(src: str, name: str) -> str:
    if not name.endswith(".npy"):
        raise InputError(src, f"archive member {name!r} is not a .npy array: not a numpy .npz file")
    return name[: -len(".npy")]


def load_npz(path, *, what: str, max_bytes: int, max_array_bytes: int, allowed_keys=None) -> dict:
    """The arrays of a ``numpy.savez`` / ``savez_compressed`` archive, as {key: ndarray}.

    Checked before anything is decompressed or allocated: the file size
    (``max_bytes``), that it is a zip archive (a 0-byte file, a ``.npy``, a
    pickle, gzip or text renamed ``.npz`` each get their own message), the
    number of members, every member's name against ``allowed_keys`` (an
    unknown key is an error naming it) and every member's uncompressed size as
    declared in the zip central directory (``max_array_bytes``, so a small file
    that would unpack to gigabytes is refused). Then each ``.npy`` header: an
    object dtype (which needs pickle) is refused, never loaded, and the
    declared shape x itemsize must fit the member. ``allow_pickle`` stays off.
    """
    src = str(path)
    st = check_input_file(path, what=what, max_bytes=max_bytes)
    if not stat.S_ISREG(st.st_mode):
        raise InputError(src, f"{what} must be a regular file (an .npz archive is read with seeks)")
    if st.st_size == 0:
        raise InputError(src, f"not a readable .npz archive: the {what} is empty (0 bytes)")
    allowed = None if allowed_keys is None else set(allowed_keys)
    try:
        with open(path, "rb") as fh:
            why = _sniff(fh.read(_SNIFF_BYTES))
            if why:
                raise InputError(src, f"not a readable .npz archive: {why}")
            fh.seek(0)
            try:
                zf = zipfile.ZipFile(fh)
            except _DECODE_ERRORS as exc:
                raise InputError(src, f"not a readable .npz archive: {exc}") from None
            with zf:
                return _read_members(zf, src, max_array_bytes, allowed)
    except OSError as exc:  # opening or reading the file itself
        raise InputError(src, f"cannot read {what} ({exc.strerror or exc})") from None


def _read_members(zf: zipfile.ZipFile, src: str, max_array_bytes: int, allowed: set | None) -> dict:
    infos = zf.infolist()
    if len(infos) > NPZ_MAX_MEMBERS:
        raise InputError(src, f"the archive has {len(infos)} members, more than the {NPZ_MAX_MEMBERS} allowed")
    keys = []
    for info in infos:
        key = _member_key(src, info.filename)
        if key in keys:
            raise InputError(src, "the archive holds this array twice", key)
        if allowed is not None and key not in allowed:
            raise InputError(src, f"unknown array (allowed: {', '.join(sorted(allowed))})", key)
        if info.file_size > max_array_bytes:
            raise InputError(src, f"array unpacks to {_size_text(info.file_size)} (declared in the archive), more "
                                  f"than the {_size_text(max_array_bytes)} allowed", key)
        keys.append(key)
    out = {}
    for key, info in zip(keys, infos):
        out[key] = _read_member(zf, info, src, key, max_array_bytes)
    return out


def _read_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, src: str, key: str, max_array_bytes: int) -> np.ndarray:
    try:
        with zf.open(info) as fp:
            shape, _, dtype = _npy_header(fp, src, key)
            header_len = fp.tell()
        if dtype.hasobject:
            raise InputError(src, f"array holds Python objects (dtype {dtype}); loading it would need pickle, "
                                  f"which is never used: save plain numeric arrays", key)
        if dtype.itemsize == 0:
            raise InputError(src, f"array has an empty dtype ({dtype})", key)
        nbytes = math.prod(int(n) for n in shape) * dtype.itemsize
        if nbytes > max_array_bytes:
            raise InputError(src, f"array of shape {shape} and dtype {dtype} is {_size_text(nbytes)}, more than "
                                  f"the {_size_text(max_array_bytes)} allowed", key)
        if header_len + nbytes > info.file_size:
            raise InputError(src, f"array is truncated: shape {shape} of {dtype} needs {nbytes} bytes, the "
                                  f"member holds {info.file_size - header_len}", key)
        with zf.open(info) as fp:
            return npy_format.read_array(fp, allow_pickle=False, max_header_size=NPY_MAX_HEADER_BYTES)
    except InputError:
        raise
    except _DECODE_ERRORS as exc:
        raise InputError(src, f"array cannot be read ({exc})", key) from None
