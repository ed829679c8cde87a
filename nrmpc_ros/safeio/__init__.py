"""Files in and out, safely: the one place where the package opens a file (docs/INPUTS.md).

Two halves with one job each:

- :mod:`.reading`: every input file (rig YAML, matches and tracks .npz,
  settings, CSV) is read through size limits, UTF-8 decoding that names what
  a file in another encoding is, bounded YAML and .npz archives checked before
  anything is unpacked; an unusable file ends in ONE
  :class:`~nrmpc_ros.errors.InputError` naming it.
- :mod:`.writing`: no command writes into its inputs (outputs are checked
  against them before anything is computed), and every output appears only
  when the run succeeds (written to a temporary beside it and renamed).

Callers import the names from here.
"""

from .reading import (
    NPY_MAX_HEADER_BYTES,
    NPZ_MAX_MEMBERS,
    YAML_MAX_ALIASES,
    YAML_MAX_BYTES,
    YAML_MAX_DEPTH,
    YAML_MAX_NODES,
    BoundedSafeLoader,
    GiB,
    KiB,
    MiB,
    check_input_file,
    decode_text,
    load_npz,
    load_yaml,
    read_bytes,
    read_text,
    yaml_from_text,
)
from .writing import (
    PARTIAL_SUFFIX,
    AtomicFile,
    atomic_directory,
    atomic_write,
    check_output,
    check_outputs,
    content_digest,
)

__all__ = ["NPY_MAX_HEADER_BYTES", "NPZ_MAX_MEMBERS", "PARTIAL_SUFFIX", "YAML_MAX_ALIASES", "YAML_MAX_BYTES",
           "YAML_MAX_DEPTH", "YAML_MAX_NODES", "AtomicFile", "BoundedSafeLoader", "GiB", "KiB", "MiB",
           "atomic_directory", "atomic_write", "check_input_file", "check_output", "check_outputs",
           "content_digest", "decode_text", "load_npz", "load_yaml", "read_bytes", "read_text", "yaml_from_text"]
