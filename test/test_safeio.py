"""Safe readers of untrusted files (every odd or hostile file is one InputError naming it) and safe writers of
outputs (never into an input, complete or not at all)."""

import gzip
import io
import os
import pickle
import struct
import time
import warnings
import zipfile

import numpy as np
import pytest

from nrmpc_ros.errors import InputError
from nrmpc_ros.safeio import (
    PARTIAL_SUFFIX,
    YAML_MAX_BYTES,
    AtomicFile,
    MiB,
    atomic_directory,
    atomic_write,
    check_output,
    check_outputs,
    load_npz,
    load_yaml,
    read_text,
    yaml_from_text,
)

# --- read_text ----------------------------------------------------------------

TEXT = "name: café\nmass: 0.1\n"


@pytest.mark.parametrize("name, payload, fragment", [
    ("utf16_bom", TEXT.encode("utf-16"), "UTF-16-LE text (byte-order mark ff fe)"),
    ("utf16be_bom", b"\xfe\xff" + TEXT.encode("utf-16-be"), "UTF-16-BE text"),
    ("utf16_nobom", TEXT.encode("utf-16-le"), "UTF-16-LE text without a byte-order mark"),
    ("utf32_bom", TEXT.encode("utf-32"), "UTF-32-LE"),
    ("latin1", TEXT.encode("latin-1"), "not UTF-8: byte 0xe9 at line 1, column 10"),
    ("cp1252", "name: \u201ccam\u201d\n".encode("cp1252"), "Latin-1 / Windows-1252"),
    ("binary", bytes(range(256)) * 4, "binary, not text: NUL byte at offset 0"),
    ("binary_late", b"a: 1\nb: \x00\x01\x02", "NUL byte at offset 8 (line 2, column 4)"),
    ("not_text", b"a: \xff\xfe\x81\x00" + bytes(range(1, 32)), "binary"),
])
def test_read_text_refuses_other_encodings_and_binary(tmp_path, name, payload, fragment):
    path = tmp_path / f"{name}.yaml"
    path.write_bytes(payload)
    with pytest.raises(InputError) as exc:
        read_text(path, what="rig file", max_bytes=MiB)
    assert str(exc.value).startswith(f"{path}: rig file") and fragment in str(exc.value)


def test_read_text_accepts_utf8_with_and_without_bom(tmp_path):
    (tmp_path / "a").write_bytes(TEXT.encode("utf-8"))
    (tmp_path / "b").write_bytes(b"\xef\xbb\xbf" + TEXT.encode("utf-8"))
    assert read_text(tmp_path / "a", what="x", max_bytes=100) == TEXT
    assert read_text(tmp_path / "b", what="x", max_bytes=100) == TEXT


def test_read_text_missing_directory_and_size_checked_before_reading(tmp_path):
    with pytest.raises(InputError, match="cannot read rig file: no such file"):
        read_text(tmp_path / "none.yaml", what="rig file", max_bytes=MiB)
    with pytest.raises(InputError, match="is a directory"):
        read_text(tmp_path, what="rig file", max_bytes=MiB)
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="a parent of this path is not a directory"):
        read_text(tmp_path / "f" / "g", what="rig file", max_bytes=MiB)
    big = tmp_path / "big.yaml"
    with open(big, "wb") as fh:  # 50 MB, sparse: nothing is written, so nothing may be read either
        fh.truncate(50 * MiB)
    t0 = time.perf_counter()
    with pytest.raises(InputError) as exc:
        read_text(big, what="rig file", max_bytes=YAML_MAX_BYTES)
    assert f"{big}: rig file is 50 MiB, more than the 1 MiB" in str(exc.value)
    assert time.perf_counter() - t0 < 0.5
    just_over = tmp_path / "over.yaml"
    just_over.write_text("a" * (100 + 1))
    with pytest.raises(InputError, match="101 bytes, more than the 100 bytes"):
        read_text(just_over, what="rig file", max_bytes=100)
    assert read_text(just_over, what="rig file", max_bytes=101) == "a" * 101


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads any file")
def test_read_text_unreadable(tmp_path):
    p = tmp_path / "secret.yaml"
    p.write_text("a: 1")
    p.chmod(0)
    with pytest.raises(InputError, match="cannot read rig file .Permission denied"):
        read_text(p, what="rig file", max_bytes=MiB)


# --- YAML -----------------------------------------------------------------------

def _billion_laughs(levels=9):
    lines = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("name, text, fragment", [
    ("alias_bomb", _billion_laughs(), "expands to more than 100000 values"),
    ("many_aliases", "a: &a 1\nb: [" + ", ".join(["*a"] * 101) + "]\n", "more than 100 YAML aliases"),
    ("recursive_alias", "a: &a [1, *a]\n", "recursive structure"),
    ("deep_brackets", "[" * 50_000 + "]" * 50_000, "nested deeper than 64 levels (line 1, column 65)"),
    ("deep_mapping", "".join(f"{' ' * i}k:\n" for i in range(100)), "nested deeper than 64 levels"),
    ("deep_through_aliases", "".join(f"a{i}: &a{i} [{'*a' + str(i - 1) if i else 0}]\n" for i in range(70)),
     "nested deeper than 64 levels (through aliases)"),
    ("python_tag", "a: !!python/object/apply:os.system [echo hi]\n", "could not determine a constructor"),
    ("unclosed", "cameras: [\n", "not valid YAML"),
    ("two_documents", "a: 1\n---\nb: 2\n", "expected a single document"),
    ("huge_integer", "a: " + "9" * 5000 + "\n", "a value cannot be read (Exceeds the limit"),
    ("bad_date", "a: 2001-13-45\n", "month must be in 1..12"),
    ("control_char", "a: \x07\n", "special characters are not allowed"),
    ("unhashable_key", "? [a, b]\n: 1\n", "unhashable"),
])
def test_load_yaml_refuses_hostile_documents(tmp_path, name, text, fragment):
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    t0 = time.perf_counter()
    with pytest.raises(InputError) as exc:
        load_yaml(path, what="rig file")
    assert str(exc.value).startswith(str(path)) and fragment in str(exc.value)
    assert time.perf_counter() - t0 < 2.0  # refused while parsing, never expanded


def test_yaml_within_the_bounds_loads_and_exponents_are_floats(tmp_path):
    text = _billion_laughs(levels=3) + "e: [1e-3, -2E+2, '1e3', 1.5e3, 0.1]\n"
    data = yaml_from_text(text, "<t>")
    assert len(data["a2"]) == 9 and data["a2"][0] is data["a1"]
    assert data["e"] == [1e-3, -200.0, "1e3", 1500.0, 0.1]
    assert yaml_from_text("", "<t>") is None
    (tmp_path / "a.yaml").write_text("a: &x {b: 1}\nc: *x\n")
    assert load_yaml(tmp_path / "a.yaml", what="config") == {"a": {"b": 1}, "c": {"b": 1}}


def test_yaml_from_text_limits(tmp_path):
    with pytest.raises(InputError, match="<param>: YAML text of 11 characters, more than the 10"):
        yaml_from_text("a: 12345678", "<param>", max_chars=10)
    with pytest.raises(InputError, match="<param>: expected YAML text, got bytes"):
        yaml_from_text(b"a: 1", "<param>")
    with pytest.raises(InputError, match="nested deeper than 3 levels"):
        yaml_from_text("a: {b: {c: 1}}", "<param>", max_depth=3)
    assert yaml_from_text("a: {b: 1}", "<param>", max_depth=3) == {"a": {"b": 1}}


# --- .npz -----------------------------------------------------------------------

NPZ = {"what": "matches file", "max_bytes": 64 * MiB, "max_array_bytes": MiB}


def _npz_bytes(**arrays):
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _patch_declared_size(data: bytes, size: int) -> bytes:
    """The archive with every member's uncompressed size, local header and central directory, set to ``size``."""
    out = bytearray(data)
    for sig, offset in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        i = out.find(sig)
        while i >= 0:
            out[i + offset:i + offset + 4] = struct.pack("<I", size)
            i = out.find(sig, i + 4)
    return bytes(out)


class _Boom:
    """Unpickling this would create a file: proof that a pickle payload is never executed."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _zip(tmp_path, members, name="x.npz", compression=zipfile.ZIP_STORED):
    path = tmp_path / name
    with warnings.catch_warnings(), zipfile.ZipFile(path, "w", compression=compression) as z:
        warnings.simplefilter("ignore")  # a duplicate member name is what one case is about
        for member, payload in members:
            z.writestr(member, payload)
    return path


def _npy(array) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _npy_header_only(shape, descr="<f8") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue()


@pytest.fixture(scope="module")
def npz_cases(tmp_path_factory):
    """name -> (path, fragment of the message, key the message names or None), and the pickle marker path."""
    tmp_path = tmp_path_factory.mktemp("npz")
    marker = tmp_path / "pickle-was-executed"
    cases = {}

    def add(name, payload, fragment, key=None):
        p = tmp_path / f"{name}.npz"
        p.write_bytes(payload)
        cases[name] = (p, fragment, key)

    add("empty", b"", "empty (0 bytes)")
    add("npy_renamed", _npy(np.ones(3)), "a single .npy array (numpy.save)")
    add("text", b"f1,f2,cam\n1,2,3\n", "it is text, not a zip archive")
    add("pickle_file", pickle.dumps(_Boom(str(marker))), "a Python pickle; pickles are never loaded")
    add("gzip", gzip.compress(_npy(np.ones(3))), "gzip-compressed")
    add("garbage", bytes(range(256)), "not a zip archive")
    add("truncated_zip", _npz_bytes(f1=np.ones((50, 3)))[:300], "not a readable .npz archive")
    obj = np.empty(1, dtype=object)
    obj[0] = _Boom(str(marker))
    buf = io.BytesIO()
    np.savez(buf, f1=obj)  # numpy pickles object arrays into the member
    add("object_array", buf.getvalue(), "holds Python objects (dtype object)", "f1")
    add("declared_1_2_GB", _patch_declared_size(_npz_bytes(f1=np.ones((4, 3))), 1_200_000_000),
        "unpacks to 1.12 GiB (declared in the archive)", "f1")
    crc = bytearray(_npz_bytes(f1=np.arange(40.0)))
    crc[crc.find(b"\x00\x00\x00\x00\x00\x00\xf0?") + 7] ^= 0xFF  # flip a byte of 1.0 inside the stored member
    add("bad_crc", bytes(crc), "cannot be read", "f1")
    cases["real_bomb"] = (_zip(tmp_path, [("f1.npy", _npy_header_only((4 * MiB,)) + bytes(32 * MiB))],
                               "real_bomb.npz", zipfile.ZIP_DEFLATED), "more than the 1 MiB allowed", "f1")
    cases["header_lies"] = (_zip(tmp_path, [("f1.npy", _npy_header_only((10**12,)) + bytes(64))], "lies.npz"),
                            "is 7.45e+03 GiB, more than the 1 MiB allowed", "f1")
    cases["truncated_member"] = (_zip(tmp_path, [("f1.npy", _npy_header_only((100,)) + bytes(64))], "trunc.npz"),
                                 "truncated: shape (100,) of float64 needs 800 bytes", "f1")
    cases["not_npy_member"] = (_zip(tmp_path, [("readme.txt", b"hi")], "txt.npz"),
                               "member 'readme.txt' is not a .npy array", None)
    cases["bad_npy_member"] = (_zip(tmp_path, [("f1.npy", b"not an npy file at all")], "badnpy.npz"),
                               "cannot be read", "f1")
    cases["duplicate"] = (_zip(tmp_path, [("f1.npy", _npy(np.ones(3))), ("f1.npy", _npy(np.ones(3)))], "dup.npz"),
                          "holds this array twice", "f1")
    cases["many_members"] = (_zip(tmp_path, [(f"f{i}.npy", _npy(np.ones(1))) for i in range(65)], "many.npz"),
                             "65 members, more than the 64", None)
    cases["unknown_key"] = (_zip(tmp_path, [("f1.npy", _npy(np.ones(3))), ("colour.npy", _npy(np.ones(3)))],
                                 "unknown.npz"), "unknown array (allowed: cam, f1)", "colour")
    cases["zero_itemsize"] = (_zip(tmp_path, [("f1.npy", _npy(np.zeros(3, dtype="V0")))], "v0.npz"),
                              "empty dtype", "f1")
    return cases, marker


CASES = ["empty", "npy_renamed", "text", "pickle_file", "gzip", "garbage", "truncated_zip", "object_array",
         "declared_1_2_GB", "bad_crc", "real_bomb", "header_lies", "truncated_member", "not_npy_member",
         "bad_npy_member", "duplicate", "many_members", "unknown_key", "zero_itemsize"]


@pytest.mark.parametrize("case", CASES)
def test_load_npz_refuses_hostile_archives(npz_cases, case):
    cases, marker = npz_cases
    path, fragment, key = cases[case]
    t0 = time.perf_counter()
    with pytest.raises(InputError) as exc:
        load_npz(path, allowed_keys={"f1", "cam"} if case == "unknown_key" else None, **NPZ)
    msg = str(exc.value)
    assert msg.startswith(str(path)) and fragment in msg, msg
    if key is not None:
        assert f"field '{key}'" in msg
    assert not marker.exists()  # no pickle ran
    assert time.perf_counter() - t0 < 2.0  # refused from the directory and headers, nothing inflated


def test_load_npz_reads_plain_and_compressed_archives(tmp_path):
    rng = np.random.default_rng(3)
    arrays = {"f1": rng.normal(size=(10, 3)), "cam": np.arange(10), "g": np.float32(2.5), "s": np.array(["ab"])}
    np.savez(tmp_path / "a.npz", **arrays)
    np.savez_compressed(tmp_path / "b.npz", **arrays)
    for name in ("a.npz", "b.npz"):
        out = load_npz(tmp_path / name, **NPZ)
        assert sorted(out) == sorted(arrays)
        for k, v in arrays.items():
            assert np.array_equal(out[k], v) and out[k].dtype == np.asarray(v).dtype
    assert load_npz(_zip(tmp_path, [], "empty_archive.npz"), **NPZ) == {}


def test_load_npz_missing_directory_and_file_size(tmp_path):
    with pytest.raises(InputError, match="cannot read matches file: no such file"):
        load_npz(tmp_path / "none.npz", **NPZ)
    with pytest.raises(InputError, match="is a directory"):
        load_npz(tmp_path, **NPZ)
    big = tmp_path / "big.npz"
    with open(big, "wb") as fh:
        fh.truncate(65 * MiB)
    with pytest.raises(InputError, match="matches file is 65 MiB, more than the 64 MiB"):
        load_npz(big, **NPZ)


# --- outputs: check_output, atomic_write, atomic_directory ---------------------------------------------------

def _left(d):
    return sorted(p.name for p in d.iterdir() if p.name.endswith(PARTIAL_SUFFIX))


def test_check_output_refuses_inputs_links_and_directories(tmp_path):
    rig = tmp_path / "rig.yaml"
    rig.write_text("x: 1\n")
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("m\n")
    (tmp_path / "soft").symlink_to(rig)
    os.link(rig, tmp_path / "hard")
    inputs = {"--rig": rig, "BAG": bag, "--config": None, "FILES": [tmp_path / "a.npz", None]}
    refused = {rig: "is the input --rig", tmp_path / "soft": "is the input --rig", tmp_path / "hard":
               "is the input --rig", bag / "sample.db3": "inside the input directory", bag / "sub" / "x":
               "inside the input directory", bag: "is a directory", tmp_path / "a.npz": "is the input FILES",
               tmp_path / "." / "rig.yaml": "is the input --rig"}
    for path, fragment in refused.items():
        with pytest.raises(InputError) as exc:
            check_output(path, inputs, "--out")
        assert str(exc.value).startswith("--out: ") and fragment in str(exc.value), path
    check_output(tmp_path / "new.csv", inputs, "--out")  # a new file beside the inputs is fine
    check_output(tmp_path / "outdir", inputs, "--out", directory=True)
    with pytest.raises(InputError, match="--out: .* is a file"):
        check_output(rig, {}, "--out", directory=True)
    with pytest.raises(InputError, match="--out: .*a parent of this path is not a directory"):
        check_output(rig / "x.csv", {}, "--out")
    with pytest.raises(InputError, match="--batch: .* is also the --out output"):
        check_outputs({"--out": tmp_path / "o.csv", "--batch": tmp_path / "." / "o.csv", "--plot": None}, inputs)


def test_atomic_write_replaces_on_success_and_keeps_the_old_file_on_failure(tmp_path):
    out = tmp_path / "sub" / "result.json"  # the missing directory is created
    with atomic_write(out) as fh:
        fh.write("first\n")
    assert out.read_text() == "first\n"
    os.chmod(out, 0o640)
    with pytest.raises(RuntimeError):
        with atomic_write(out) as fh:
            fh.write("half of the sec")
            raise RuntimeError("the run failed half-way")
    assert out.read_text() == "first\n" and _left(out.parent) == []
    with atomic_write(out, "wb") as fh:
        fh.write(b"second\n")
    assert out.read_bytes() == b"second\n" and (out.stat().st_mode & 0o777) == 0o640


def test_atomic_file_shows_progress_beside_the_destination(tmp_path):
    out = tmp_path / "rows.csv"
    f = AtomicFile(out, flag="--out")
    f.file.write("a,b\n")
    f.file.flush()
    assert not out.exists() and f.temp.parent == tmp_path and f.temp.read_text() == "a,b\n"
    f.discard()
    assert not out.exists() and list(tmp_path.iterdir()) == []
    out.write_text("")
    with pytest.raises(InputError, match="cannot write the --out file"):
        AtomicFile(out / "x", flag="--out")  # a plain file where its directory should be


def test_atomic_directory_renames_a_complete_directory_or_removes_it(tmp_path):
    dest = tmp_path / "bag"
    with pytest.raises(InputError, match="failed on purpose"):
        with atomic_directory(dest, flag="--out") as work:
            work.mkdir()
            (work / "bag.db3").write_bytes(b"half")
            raise InputError("bag.db3", "failed on purpose")
    assert list(tmp_path.iterdir()) == []
    with atomic_directory(dest, flag="--out") as work:
        assert work.name == "bag" and not work.exists()
        work.mkdir()
        (work / "bag.db3").write_bytes(b"all")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"] and (dest / "bag.db3").read_bytes() == b"all"
    with pytest.raises(InputError, match="--out: .* already exists"):
        with atomic_directory(dest, flag="--out"):
            pass
