"""Writing outputs safely: no command writes into its inputs, and a failing run never leaves a
half-written file behind nor clobbers the previous good output.

- :func:`check_output` / :func:`check_outputs`: refuse, before anything is
  computed, an output path that is one of the inputs (the same file after
  resolving symlinks, hard links too), lies inside an input directory (a
  rosbag2 directory is an input) or is a directory where a file is expected;
  the error names the flag.
- :class:`AtomicFile` / :func:`atomic_write`: the bytes go to a temporary file
  beside the destination, are fsync'ed and renamed onto it (``os.replace``)
  only when the writer succeeds; on any exception the temporary is removed
  and the destination keeps its previous content.
- :func:`atomic_directory`: a directory output (a bag) is built under a
  temporary name beside its destination and renamed in one step.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
from pathlib import Path

from ..errors import InputError

PARTIAL_SUFFIX = ".partial"  # a temporary output is ".<name>.<random>.partial" beside its destination


def _input_paths(inputs) -> list[tuple[str, str]]:
    """(label, path) of every input of ``inputs``: {label: path, list of paths or None}."""
    out = []
    for label, value in inputs.items():
        values = value if isinstance(value, (list, tuple)) else [value]
        out += [(label, os.fspath(v)) for v in values if v is not None and os.fspath(v) != ""]
    return out


def _stat_or_none(path: str, flag: str | None = None):
    try:
        return os.stat(path)
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        if flag is None:
            return None  # an unreadable input is its loader's error, later
        if isinstance(exc, NotADirectoryError):
            raise InputError(flag, f"{path}: a parent of this path is not a directory") from None
        raise InputError(flag, f"cannot use {path} as an output ({getattr(exc, 'strerror', None) or exc})") from None


def _inside(path: str, directory: str) -> bool:
    try:
        return os.path.commonpath([path, directory]) == directory
    except ValueError:  # different drives, or relative against absolute
        return False


def check_output(path, inputs, flag: str, *, directory: bool = False) -> None:
    """Refuse the output ``path`` of ``flag`` when writing it would touch an input; nothing is written.

    ``inputs`` maps a label (the flag or positional name, e.g. ``"--rig"`` or
    ``"BAG"``) to a path, a list of paths or None. Refused, each with one
    InputError naming ``flag``: the output is one of the inputs (the same path
    after resolving symlinks, or the same file through a hard link), it lies
    inside an input directory (a rosbag2 directory is an input: writing a
    ``.db3`` into it corrupts the bag), it is an existing directory where a
    file is expected (``directory`` False), or an existing file where a
    directory is expected (``directory`` True).
    """
    if path is None or os.fspath(path) == "":
        raise InputError(flag, "needs a path")
    text = os.fspath(path)
    if "\x00" in text:
        raise InputError(flag, "invalid path (it contains a NUL character)")
    real = os.path.realpath(text)
    st = _stat_or_none(text, flag)
    if st is not None and stat.S_ISDIR(st.st_mode) != directory:
        want = "a directory" if directory else "a file name"
        raise InputError(flag, f"{text} is {'a directory' if not directory else 'a file'}; give {want}")
    for label, inp in _input_paths(inputs):
        ist = _stat_or_none(inp)
        same_file = st is not None and ist is not None and (st.st_dev, st.st_ino) == (ist.st_dev, ist.st_ino)
        if same_file or real == os.path.realpath(inp):
            raise InputError(flag, f"{text} is the input {label} ({inp}); an output never overwrites an input: "
                                   f"choose another path")
        if ist is not None and stat.S_ISDIR(ist.st_mode) and _inside(real, os.path.realpath(inp)):
            raise InputError(flag, f"{text} lies inside the input directory {inp} ({label}); an output never "
                                   f"writes into an input: choose a path outside it")


def check_outputs(outputs, inputs, *, directories=()) -> None:
    """:func:`check_output` for every output of ``outputs`` ({flag: path or None}; the flags in
    ``directories`` are directory outputs), and no two outputs may be the same path."""
    seen = {}
    for flag, path in outputs.items():
        if path is None:
            continue
        check_output(path, inputs, flag, directory=flag in directories)
        real = os.path.realpath(os.fspath(path))
        if real in seen:
            raise InputError(flag, f"{path} is also the {seen[real]} output; give each output its own path")
        seen[real] = flag


def _umask() -> int:
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # no /proc: read it by setting it (and put it back at once)
    os.umask(mask)
    return mask


def _fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (best effort: not every file system can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class AtomicFile:
    """A file written under a temporary name beside ``path`` and renamed onto ``path`` by :meth:`commit`.

    Until then ``path`` keeps its previous content (or stays absent), and
    :meth:`discard` removes the temporary, so a run that fails half-way leaves
    neither a half-written output nor a clobbered earlier one. The temporary
    (``.<name>.<random>.partial``, in the same directory so the rename is
    atomic) shows a long run's progress while it is written. Missing parent
    directories are created. The result gets the permissions of the file it
    replaces, or the usual ones (0666 less the umask) for a new file.
    ``file`` is the open file object (text: UTF-8; ``mode`` "w" or "wb").
    """

    def __init__(self, path, mode: str = "w", *, flag: str | None = None, newline: str | None = None):
        if mode not in ("w", "wb"):
            raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
        self.path = Path(path)
        self._what = f"the {flag} file" if flag else "the output file"
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=PARTIAL_SUFFIX, dir=self.path.parent)
        except (OSError, ValueError) as exc:
            raise InputError(str(path), f"cannot write {self._what} ({getattr(exc, 'strerror', None) or exc})") \
                from None
        self.temp = Path(tmp)
        text = {} if "b" in mode else {"encoding": "utf-8", "newline": newline}
        self.file = os.fdopen(fd, mode, **text)
        self._done = False

    def commit(self) -> None:
        """Flush, fsync and rename the temporary onto ``path`` (once; later calls do nothing)."""
        if self._done:
            return
        self._done = True
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            st = _stat_or_none(str(self.path))
            os.chmod(self.temp, stat.S_IMODE(st.st_mode) if st is not None else 0o666 & ~_umask())
            os.replace(self.temp, self.path)
        except OSError as exc:
            self._remove_temp()
            raise InputError(str(self.path), f"cannot write {self._what} ({exc.strerror or exc})") from None
        _fsync_dir(self.path.parent)

    def discard(self) -> None:
        """Drop what was written: the temporary is removed, ``path`` is left as it was."""
        if self._done:
            return
        self._done = True
        with contextlib.suppress(OSError, ValueError):
            self.file.close()
        self._remove_temp()

    def _remove_temp(self) -> None:
        with contextlib.suppress(OSError):
            self.file.close()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.temp)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.commit()
        else:
            self.discard()
        return False


@contextlib.contextmanager
def atomic_write(path, mode: str = "w", *, flag: str | None = None, newline: str | None = None):
    """``with atomic_write(path) as fh:`` -- the file object of an :class:`AtomicFile`, committed when the
    block ends normally and discarded when it raises (any exception, Ctrl-C too)."""
    out = AtomicFile(path, mode, flag=flag, newline=newline)
    try:
        yield out.file
    except BaseException:
        out.discard()
        raise
    out.commit()


def _fsync_tree(root: Path) -> None:
    for dirpath, _, files in os.walk(root):
        for name in files:
            with contextlib.suppress(OSError):
                fd = os.open(os.path.join(dirpath, name), os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)
        _fsync_dir(Path(dirpath))


@contextlib.contextmanager
def atomic_directory(path, *, flag: str | None = None):
    """``with atomic_directory(out) as work:`` -- build a directory output at ``work``, renamed onto ``out``.

    ``work`` does not exist yet; the caller creates it. It lies in a staging
    directory ``.<name>.<random>.partial`` beside ``out`` and has the same
    name, since a rosbag2 names its files after its directory. When the block
    ends normally everything in it is fsync'ed and ``work`` is renamed onto
    ``out`` in one step; when it raises the staging directory is removed.
    Readers therefore see no bag or a complete one, never half of one.
    ``out`` must not exist: a rename cannot merge into an existing directory,
    and replacing one would drop whatever it holds.
    """
    dest = Path(path)
    source = flag or str(path)
    if os.path.lexists(dest):
        raise InputError(source, f"{path} already exists; remove it or choose another path")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=PARTIAL_SUFFIX, dir=dest.parent))
    except (OSError, ValueError) as exc:
        raise InputError(source, f"cannot create {path} ({getattr(exc, 'strerror', None) or exc})") from None
    work = stage / dest.name
    try:
        yield work
        _fsync_tree(work)
        if os.path.lexists(dest):
            raise InputError(source, f"{path} appeared while it was being written; the new output is dropped")
        try:
            os.rename(work, dest)
        except OSError as exc:
            raise InputError(source, f"cannot create {path} ({exc.strerror or exc})") from None
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    with contextlib.suppress(OSError):
        os.rmdir(stage)
    _fsync_dir(dest.parent)


def content_digest(path) -> str:
    """SHA-256 of a file, or of a directory's relative file names and contents; "absent" when it does not
    exist. Equal digests before and after a command show that it wrote nothing into that input."""
    import hashlib

    path = Path(path)
    if not os.path.lexists(path):
        return "absent"
    h = hashlib.sha256()
    if path.is_dir():
        for p in sorted(path.rglob("*")):
            h.update(str(p.relative_to(path)).encode())
            if p.is_file():
                h.update(p.read_bytes())
    else:
        h.update(path.read_bytes())
    return h.hexdigest()
