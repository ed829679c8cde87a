"""Malformed inputs through the command line: every one ends in one clear error naming what is wrong
(docs/INPUTS.md), and no run writes into its inputs.

The good inputs are simulated matches and tracks files and one small rendered bag (nrmpc make-bag, 320x240,
3 holds of 2 s) with a replay CSV of it. Malformed variants of each kind of input -- rig files, matches and
tracks files, bags, estimate CSVs, settings files and flags -- and output paths that collide with an input each
run as ``nrmpc ...`` in a subprocess (a traceback is seen as the user would see it) and are classified:

- clear named error: exit status 2, no traceback, the message names the file (and the key, flag or topic);
- accepted correctly: an input that is fine (or only warned about) runs to the end with the right result;
- traceback: a Python traceback or any other exit status;
- silent wrong: exit 0 where the input should have been refused, or a result that is wrong (a partial output
  left behind, a good input refused);
- unnamed error: exit 2 but the message does not name what is wrong;
- data modified: an input (or a previous output the run must keep) has other bytes afterwards.

One test per kind of input fails on every run of the last four kinds and lists them. Some 150 runs of the
command line take minutes: the module is slow.
"""

from __future__ import annotations

import io
import os
import pickle
import shutil
import subprocess
import sys
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml
from badbags import corrupt_message, digest, retype

REPO = Path(__file__).resolve().parents[1]
GOOD = ("clear named error", "accepted correctly")

pytestmark = pytest.mark.slow


@dataclass
class Case:
    """One run: ``argv`` of nrmpc; ``names`` the error must contain (none: the run must succeed)."""

    area: str
    name: str
    argv: list
    names: tuple = ()
    inputs: tuple = ()  # files or directories whose bytes must not change
    absent: tuple = ()  # paths the run must not leave behind (nor temporary outputs beside them)
    stdout: str = ""  # a successful run must print this
    stderr: str = ""  # ... and warn this
    result: dict = field(default_factory=dict)


def nrmpc(*argv, check=True, timeout=600):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "nrmpc_ros.cli.main", *map(str, argv)], capture_output=True,
                          text=True, env=env, timeout=timeout)
    if check and proc.returncode != 0:
        raise RuntimeError(f"nrmpc {' '.join(map(str, argv))} failed:\n{proc.stderr}")
    return proc



def partials(path: Path) -> list:
    """Temporary outputs (``*.partial``) in the directory of ``path`` (or in it)."""
    d = path if path.is_dir() else path.parent
    return [p.name for p in d.glob(".*.partial")] if d.is_dir() else []


# ---------------------------------------------------------------------------
# fixtures
# ---------------------------------------------------------------------------

def sim_inputs(w: Path) -> dict:
    """The good simulated inputs: a rig with a matches file, a rig with a tracks file."""
    nrmpc("simulate", "--out", w / "sim", "--points", "200")
    nrmpc("simulate", "--out", w / "seq", "--sequence", "--views", "4", "--tracks-per-camera", "40")
    return {"w": w, "sim_rig": w / "sim" / "rig.yaml", "matches": w / "sim" / "pair_000.npz",
            "seq_rig": w / "seq" / "rig.yaml", "tracks": w / "seq" / "seq_000.npz"}


def bag_inputs(f: dict) -> dict:
    """The good recorded inputs besides ``f``: a rendered bag with its rig, and the replay's CSV of it."""
    w = f["w"]
    f = {**f, "bag": w / "bag", "rig": w / "rig.yaml", "csv": w / "good.csv"}
    nrmpc("make-bag", "--resolution", "320x240", "--views", "3", "--hold-seconds", "2", "--no-progress",
          "--out", f["bag"], "--save-rig", f["rig"])
    nrmpc("replay", f["bag"], "--rig", f["rig"], "--out", f["csv"], "--no-progress", "--quiet")
    return f


def write(path: Path, data) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, bytes):
        path.write_bytes(data)
    else:
        path.write_text(data, encoding="utf-8")
    return path


def npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for key, value in arrays.items():
            b = io.BytesIO()
            np.save(b, value, allow_pickle=True)
            z.writestr(f"{key}.npy", b.getvalue())
    return buf.getvalue()


def zip_bomb(path: Path, key: str) -> Path:
    """A small archive whose one member unpacks to 300 MiB of zeros (more than any array may have)."""
    n = 300 << 20
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (n // 24, 3)})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z, z.open(f"{key}.npy", "w", force_zip64=True) as m:
        m.write(header.getvalue())
        chunk = bytes(1 << 20)
        for _ in range(n >> 20):
            m.write(chunk)
    return path


def copy_bag(f: dict, name: str) -> Path:
    dst = f["w"] / "bags" / name
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(f["bag"], dst)
    return dst


# ---------------------------------------------------------------------------
# variants
# ---------------------------------------------------------------------------

def rig_cases(f: dict) -> list:
    d = f["w"] / "rigs"
    base = yaml.safe_load(f["sim_rig"].read_text())
    text = f["sim_rig"].read_text()

    def edited(name, edit):
        r = yaml.safe_load(text)
        edit(r)
        return write(d / f"{name}.yaml", yaml.safe_dump(r, sort_keys=False))

    def cam0(key, value):
        return lambda r: r["cameras"][0].__setitem__(key, value)

    bomb = "a0: &a0 [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]\n" for i in range(1, 9))
    variants = {
        "binary": (write(d / "binary.yaml", bytes(range(256)) * 8), "binary"),
        "latin-1": (write(d / "latin1.yaml", ("# caméra\n" + text).encode("latin-1")), "Latin-1"),
        "utf-16": (write(d / "utf16.yaml", text.encode("utf-16")), "UTF-16"),
        "deep brackets": (write(d / "deep.yaml", "cameras: " + "[" * 50000 + "]" * 50000 + "\n"), "deeper"),
        "alias bomb": (write(d / "bomb.yaml", bomb), "alias"),
        "empty": (write(d / "empty.yaml", ""), ""),
        "top-level list": (write(d / "list.yaml", "[1, 2]\n"), ""),
        "huge mass": (edited("mass", lambda r: r["cameras"][0]["bar"].__setitem__("mass", 1e300)), "mass"),
        "huge integer": (write(d / "hugeint.yaml", text.replace("gravity_magnitude: 9.81",
                                                                "gravity_magnitude: " + "9" * 5000)), ""),
        "bool for a number": (edited("bool", lambda r: r["cameras"][0]["bar"].__setitem__("mass", True)), "mass"),
        "string for a number": (edited("str", lambda r: r["cameras"][0]["intrinsics"].__setitem__(0, "800")),
                                "intrinsics"),
        "NaN position": (edited("nan", cam0("position", [float("nan"), 0.0, 0.0])), "position"),
        "duplicate image topics": (edited("dup", lambda r: r["cameras"][1].__setitem__(
            "image_topic", r["cameras"][0]["image_topic"])), "image_topic"),
        "info topic is an image topic": (edited("infoimg", lambda r: r["cameras"][1].__setitem__(
            "info_topic", r["cameras"][0]["image_topic"])), "info_topic"),
        "bad topic name": (edited("topic", cam0("image_topic", "/cam0//image")), "image_topic"),
        "implausible bend": (edited("bend", lambda r: r["cameras"][0]["bar"].__setitem__("EI", 1e-4)), "bar"),
        "negative focal": (edited("focal", lambda r: r["cameras"][0]["intrinsics"].__setitem__(0, -5.0)),
                           "intrinsics"),
        "wrong camera count": (edited("nocams", lambda r: r.__setitem__("cameras", [])), "cameras"),
        "missing file": (d / "absent.yaml", "no such file"),
        "directory": (d, "directory"),
    }
    assert base["cameras"][0]["bar"]
    cases = [Case("rig", name, ["solve", "--rig", p, "--method", "6pt-bending", f["matches"]], (str(p), frag),
                  inputs=(p,)) for name, (p, frag) in variants.items()]
    chain = {"cam0": {"camera_model": "pinhole", "intrinsics": [400.0, 400.0, 320.0, 240.0],
                      "distortion_model": "radtan", "distortion_coeffs": [0.0, 0.0, 0.0, 0.0],
                      "resolution": [640, 480], "rostopic": "/cam0/image_raw"}}
    kalibr = {
        "Kalibr: binary": (write(d / "kalibr-bin.yaml", bytes(range(256))), "binary"),
        "Kalibr: alias bomb": (write(d / "kalibr-bomb.yaml", bomb), "alias"),
        "Kalibr: bad opencv-matrix": (write(d / "kalibr-cv.yaml", "%YAML:1.0\ncam0:\n  T_cn_cnm1: !!opencv-matrix\n"
                                            "    rows: four\n    cols: 4\n    data: [1]\n"), "opencv-matrix"),
        "Kalibr: string intrinsics": (write(d / "kalibr-str.yaml", yaml.safe_dump(
            {"cam0": {**chain["cam0"], "intrinsics": ["a", 1, 2, 3]}})), "intrinsics"),
        "Kalibr: no cameras": (write(d / "kalibr-none.yaml", "cam7: {}\n"), "cam"),
    }
    out = f["w"] / "out" / "kalibr"
    for name, (p, frag) in kalibr.items():
        cases.append(Case("rig", name, ["import-kalibr", p, "--out", out / f"{p.stem}.yaml"], (str(p), frag),
                          inputs=(p,), absent=(out / f"{p.stem}.yaml",)))
    bom = write(d / "bom.yaml", b"\xef\xbb\xbf" + text.encode())
    cases.append(Case("rig", "UTF-8 with byte-order mark", ["solve", "--rig", bom, "--method", "6pt-bending",
                                                           f["matches"]], inputs=(bom,), stdout='"success": true'))
    return cases


def _npz_variants(d: Path, good: dict, kind: str) -> dict:
    raw = npz_bytes(good)
    npy = io.BytesIO()
    np.save(npy, good[next(iter(good))])
    first = next(iter(good))
    out = {
        "empty": (write(d / "empty.npz", b""), "empty"),
        "truncated": (write(d / "trunc.npz", raw[: len(raw) // 2]), ""),
        ".npy renamed": (write(d / "npy.npz", npy.getvalue()), ".npy"),
        "text": (write(d / "text.npz", "f1,f2,cam\n1,2,3\n"), "text"),
        "pickle": (write(d / "pickle.npz", pickle.dumps({"a": 1})), "pickle"),
        "zip bomb": (zip_bomb(d / "bomb.npz", first), first),
        "object dtype": (write(d / "object.npz", npz_bytes({**good, first: np.array([1, "a"], dtype=object)})),
                         "pickle"),
        "string dtype": (write(d / "str.npz", npz_bytes({**good, first: good[first].astype(str)})), first),
        "NaN": (write(d / "nan.npz", npz_bytes({**good, first: np.where(np.arange(good[first].size).reshape(
            good[first].shape) == 3, np.nan, good[first].astype(float))})), first),
        "missing array": (write(d / "missing.npz", npz_bytes({k: v for k, v in good.items() if k != first})),
                          first),
        "unknown array": (write(d / "unknown.npz", npz_bytes({**good, "colour": np.zeros(3)})), "colour"),
        "missing file": (d / "absent.npz", "no such file"),
    }
    if kind == "matches":
        out["complex bearings"] = (write(d / "complex.npz", npz_bytes({**good, "f2": good["f2"] * (1 + 0j)})),
                                   "f2")
        out["fractional camera index"] = (write(d / "cam.npz", npz_bytes({**good, "cam": good["cam"] + 0.5})),
                                          "cam")
        out["camera index beyond the rig"] = (write(d / "cam9.npz", npz_bytes({**good, "cam": good["cam"] + 9})),
                                              "cam")
    else:
        out["fractional view index"] = (write(d / "view.npz", npz_bytes({**good, "view": good["view"] + 0.5})),
                                        "view")
        dup = {k: (np.concatenate([v, v[:1]]) if k != "g_meas" else v) for k, v in good.items()}
        out["observation twice"] = (write(d / "dup.npz", npz_bytes(dup)), "track")
        out["negative track id"] = (write(d / "neg.npz", npz_bytes({**good, "track": good["track"] - 10 ** 6})),
                                    "track")
    return out


def matches_cases(f: dict) -> list:
    with np.load(f["matches"]) as z:
        good = {k: z[k] for k in z.files}
    variants = _npz_variants(f["w"] / "matches", {"f1": good["f1"], **good}, "matches")
    cases = [Case("matches", name, ["solve", "--rig", f["sim_rig"], "--method", "6pt-bending", p], (str(p), frag),
                  inputs=(p,)) for name, (p, frag) in variants.items()]
    few = write(f["w"] / "matches" / "few.npz", npz_bytes({k: v[:5] if k in ("f1", "f2", "cam") else v
                                                           for k, v in good.items()}))
    for method in ("6pt-bending", "4pt-bending"):
        cases.append(Case("matches", f"5 correspondences ({method}): a failure with its reason",
                          ["solve", "--rig", f["sim_rig"], "--method", method, few], inputs=(few,),
                          stdout='"success": false', result={"forbid": "no reason recorded", "need": '"reason": '}))
    return cases


def tracks_cases(f: dict) -> list:
    with np.load(f["tracks"]) as z:
        good = {k: z[k] for k in z.files}
    variants = _npz_variants(f["w"] / "tracks", {"f": good["f"], **good}, "tracks")
    return [Case("tracks", name, ["solve-sequence", "--rig", f["seq_rig"], "--method", "6pt-bending", p],
                 (str(p), frag), inputs=(p,)) for name, (p, frag) in variants.items()]


def bag_cases(f: dict) -> list:
    w, rig = f["w"], f["rig"]
    d = w / "bags"
    d.mkdir(exist_ok=True)
    text = rig.read_text()

    def rig_with(name, edit):
        r = yaml.safe_load(text)
        edit(r)
        return write(w / "rigs" / f"bag-{name}.yaml", yaml.safe_dump(r, sort_keys=False))

    nometa = copy_bag(f, "nometa")
    (nometa / "metadata.yaml").unlink()
    badmeta = copy_bag(f, "badmeta")
    write(badmeta / "metadata.yaml", "rosbag2_bagfile_information: [\n")
    trunc = copy_bag(f, "truncated")
    db = next(trunc.glob("*.db3"))
    os.truncate(db, db.stat().st_size // 3)
    garbage = copy_bag(f, "garbage")
    write(next(garbage.glob("*.db3")), bytes(np.random.default_rng(0).integers(0, 256, 8192, dtype=np.uint8)))
    corrupt = corrupt_message(copy_bag(f, "corrupt"), "/cam1/image_raw")
    gt_string = retype(copy_bag(f, "gtstring"), "/ground_truth/gravity", "std_msgs/msg/String")
    imu_vec = retype(copy_bag(f, "imuvec"), "/imu/data", "geometry_msgs/msg/Vector3Stamped")
    empty = d / "emptydir"
    empty.mkdir(exist_ok=True)
    out = w / "out" / "bag"

    def replay(name, bag, names, rig_file=rig, extra=(), **kw):
        csv = out / "".join(ch if ch.isalnum() else "_" for ch in name) / "estimates.csv"  # a directory per run
        return Case("bag", name, ["replay", bag, "--rig", rig_file, "--out", csv, "--no-progress", "--quiet", *extra],
                    names, inputs=(bag, rig_file), absent=() if not names else (csv,), **kw)

    missing_cam = rig_with("cam9", lambda r: r["cameras"][2].__setitem__("image_topic", "/cam9/image_raw"))
    no_imu_topic = rig_with("imu9", lambda r: r["imu"].__setitem__("topic", "/imu9/data"))
    info_pose = rig_with("infopose", lambda r: r["cameras"][0].__setitem__("info_topic", "/ground_truth/pose"))
    no_imu = rig_with("noimu", lambda r: r.pop("imu"))
    cases = [
        replay("no metadata.yaml", nometa, (str(nometa), "metadata.yaml")),
        replay("metadata.yaml not YAML", badmeta, (str(badmeta),)),
        replay("truncated db3", trunc, (str(trunc),)),
        replay("db3 of random bytes", garbage, (str(garbage),)),
        replay("corrupt message half-way", corrupt, (str(corrupt), "/cam1/image_raw")),
        replay("empty directory", empty, (str(empty),)),
        replay("no such bag", d / "absent", (str(d / "absent"),)),
        replay("a CSV as the bag", f["csv"], (str(f["csv"]),)),
        replay("camera topic missing", f["bag"], ("/cam9/image_raw",), missing_cam),
        replay("IMU topic missing (runs without)", f["bag"], (), no_imu_topic, stdout="wrote",
               stderr="running without IMU"),
        replay("--imu-topic is an image topic", f["bag"], ("--imu-topic", "/cam0/image_raw", "sensor_msgs/msg/Imu"),
               extra=("--imu-topic", "/cam0/image_raw")),
        replay("IMU topic of type Vector3Stamped", imu_vec, (str(rig), "imu.topic", "Vector3Stamped")),
        replay("info_topic names a PoseStamped topic", f["bag"], (str(info_pose), "info_topic"), info_pose),
        replay("ground truth as std_msgs/String (ignored)", gt_string, (), stdout="wrote",
               stderr="/ground_truth/gravity carries std_msgs/msg/String"),
        replay("a storage file as the bag", next(f["bag"].glob("*.db3")), (), stdout="wrote 3 estimates"),
        Case("bag", "calibrate-bars without an IMU", ["calibrate-bars", f["bag"], "--rig", no_imu, "--out",
                                                      out / "cal.yaml"], (str(no_imu), "imu"),
             inputs=(f["bag"], no_imu), absent=(out / "cal.yaml",)),
        Case("bag", "compare: --imu-topic is an image topic", ["compare", f["csv"], "--bag", f["bag"], "--quiet",
                                                              "--imu-topic", "/cam0/image_raw"],
             ("--imu-topic", "/cam0/image_raw"), inputs=(f["csv"], f["bag"])),
    ]
    return cases


def csv_cases(f: dict) -> list:
    d = f["w"] / "csv"
    good = f["csv"].read_text()
    head, *rows = good.splitlines(keepends=True)
    cols = head.rstrip("\n").split(",")
    first = rows[0].rstrip("\n").split(",")

    def cell(key, value):
        r = list(first)
        r[cols.index(key)] = value
        return head + ",".join(r) + "\n"

    variants = {
        "binary": (write(d / "binary.csv", b"PK\x03\x04" + bytes(range(256))), "binary"),
        "truncated mid-row": (write(d / "trunc.csv", good[: len(head) + len(rows[0]) // 2]), "columns"),
        "empty": (write(d / "empty.csv", ""), "header"),
        "latin-1": (write(d / "latin1.csv", cell("method", "6pt-bending").replace("6pt", "é").encode("latin-1")),
                    "Latin-1"),
        "utf-16": (write(d / "utf16.csv", good.encode("utf-16")), "UTF-16"),
        "not the estimates header": (write(d / "header.csv", "a,b,c\n1,2,3\n"), "header"),
        "NaN quaternion": (write(d / "nan.csv", cell("qx", "nan")), "qx"),
        "text for a number": (write(d / "text.csv", cell("tx", "one")), "tx"),
        "quaternion not unit": (write(d / "quat.csv", cell("qw", "3.0")), "qx"),
        "fractional inlier count": (write(d / "inl.csv", cell("num_inliers", "2.5")), "num_inliers"),
        "missing file": (d / "absent.csv", "no such file"),
    }
    r = list(first)
    for k in ("gx", "gy", "gz"):
        r[cols.index(k)] = "0"
    variants["zero gravity"] = (write(d / "g0.csv", head + ",".join(r) + "\n"), "gx")
    cases = [Case("csv", name, ["compare", p, "--bag", f["bag"], "--quiet"], (str(p), frag), inputs=(p,))
             for name, (p, frag) in variants.items()]
    only_head = write(d / "head.csv", head)
    cases.append(Case("csv", "header only (no estimates)", ["compare", only_head, "--bag", f["bag"], "--quiet"],
                      inputs=(only_head,), stdout="no estimates"))
    return cases


def config_cases(f: dict) -> list:
    d = f["w"] / "configs"
    out = f["w"] / "out" / "config"
    replay_cfg = {
        "tracking: 5": ("tracking: 5\n", "tracking"),
        "a word for a number": ("tracking: {min_matches_per_camera: forty}\n", "tracking.min_matches_per_camera"),
        "seed: abc": ("seed: abc\n", "seed"),
        "out of range": ("tracking: {max_tracks: 1000000000}\n", "tracking.max_tracks"),
        "unknown key": ("tracking: {num_features: 1000000000}\n", "tracking.num_features"),
        "unknown top-level key": ("min_matches: forty\n", "min_matches"),
        "a list": ("[1, 2]\n", ""),
        "not YAML": ("tracking: {max_tracks: [\n", "YAML"),
        "huge integer": ("imu_gravity_floor_deg: " + "9" * 400 + "\n", "imu_gravity_floor_deg"),
        "NaN": ("tracking: {ratio: .nan}\n", "tracking.ratio"),
        "bool for a number": ("window: yes\n", "window"),
        "string for an optional number": ("sequence: {gravity_bias_sigma: abc}\n", "sequence.gravity_bias_sigma"),
        "fraction for an integer": ("window: 2.5\n", "window"),
    }
    cases = []
    for name, (text, key) in replay_cfg.items():
        p = write(d / f"replay-{len(cases)}.yaml", text)
        cases.append(Case("config", f"replay --config: {name}", ["replay", f["bag"], "--rig", f["rig"], "--config", p,
                                                                  "--out", out / f"{len(cases)}.csv", "--no-progress"],
                          (str(p), key), inputs=(p,), absent=(out / f"{len(cases)}.csv",)))
    p = write(d / "binary.yaml", bytes(range(1, 256)) + b"\x00")
    cases.append(Case("config", "replay --config: binary", ["replay", f["bag"], "--rig", f["rig"], "--config", p,
                                                             "--out", out / "b.csv"], (str(p), "binary"), inputs=(p,)))
    for name, text, key in (("a word for a number", "max_iterations: many\n", "max_iterations"),
                            ("unknown key", "estimator: {huber: 2}\n", "estimator.huber")):
        p = write(d / f"options-{len(cases)}.yaml", text)
        cases.append(Case("config", f"solve-sequence --options: {name}",
                          ["solve-sequence", "--rig", f["seq_rig"], "--method", "6pt-bending", "--options", p,
                           f["tracks"]], (str(p), key), inputs=(p,)))
    for name, text, key in (("a word for a number", "pixel_noise: abc\n", "pixel_noise"),
                            ("string points", "num_points: many\n", "num_points"),
                            ("resolution not a pair", "rig: {resolution: 5}\n", "rig.resolution"),
                            ("seed: abc", "seed: abc\n", "seed"), ("count: 0", "count: 0\n", "count"),
                            ("rig not a mapping", "rig: 5\n", "rig"), ("bool mass", "rig: {mass: yes}\n", "rig.mass")):
        p = write(d / f"scenario-{len(cases)}.yaml", text)
        cases.append(Case("config", f"simulate --scenario: {name}", ["simulate", "--scenario", p, "--out",
                                                                      out / f"sim{len(cases)}"],
                          (str(p), key), inputs=(p,), absent=(out / f"sim{len(cases)}",)))
    for name, text, key in (("fractional seed", "seed: 1.5\n", "seed"), ("a word for seconds", "hold-seconds: abc\n",
                                                                          "hold-seconds"),
                            ("unknown key", "colour: red\n", "colour")):
        p = write(d / f"bag-{len(cases)}.yaml", text)
        cases.append(Case("config", f"make-bag --scenario: {name}", ["make-bag", "--scenario", p, "--out",
                                                                      out / f"bag{len(cases)}", "--no-progress"],
                          (str(p), key), inputs=(p,), absent=(out / f"bag{len(cases)}",)))
    flags = [
        ("replay --sync-tolerance -1", ["replay", f["bag"], "--rig", f["rig"], "--out", out / "f.csv",
                                        "--sync-tolerance", "-1"], "--sync-tolerance"),
        ("replay --sync-tolerance nan", ["replay", f["bag"], "--rig", f["rig"], "--out", out / "f.csv",
                                         "--sync-tolerance", "nan"], "--sync-tolerance"),
        ("replay --queue-size 0", ["replay", f["bag"], "--rig", f["rig"], "--out", out / "f.csv", "--queue-size", "0"],
         "--queue-size"),
        ("solve --seed -1", ["solve", "--rig", f["sim_rig"], "--method", "6pt-bending", "--seed", "-1",
                             f["matches"]], "--seed"),
        ("calibrate-bars --gravity-sigma 0", ["calibrate-bars", f["bag"], "--rig", f["rig"], "--out", out / "c.yaml",
                                              "--gravity-sigma", "0"], "--gravity-sigma"),
        ("compare --imu-window -1", ["compare", f["csv"], "--bag", f["bag"], "--imu-window", "-1"], "--imu-window"),
        ("make-bag --seed -1", ["make-bag", "--seed", "-1", "--out", out / "s"], "--seed"),
        ("simulate --count 0", ["simulate", "--count", "0", "--out", out / "s"], "--count"),
    ]
    cases += [Case("config", name, argv, (flag,), inputs=(f["rig"], f["bag"]), absent=(out / "f.csv",))
              for name, argv, flag in flags]
    return cases


def output_cases(f: dict) -> list:
    w, bag, rig, csv = f["w"], f["bag"], f["rig"], f["csv"]
    d = w / "outputs"
    d.mkdir(exist_ok=True)
    cfg = write(d / "pipeline.yaml", "window: 10\n")
    scenario = write(d / "scenario.yaml", "views: 3\n")
    camchain = write(d / "camchain.yaml", yaml.safe_dump({"cam0": {
        "camera_model": "pinhole", "intrinsics": [400.0, 400.0, 320.0, 240.0], "distortion_model": "radtan",
        "distortion_coeffs": [0.0, 0.0, 0.0, 0.0], "resolution": [640, 480], "rostopic": "/cam0/image_raw"}}))
    link = d / "link.yaml"
    if not os.path.lexists(link):
        link.symlink_to(rig)
    hard = d / "hard.yaml"
    if not hard.exists():
        os.link(rig, hard)
    simdir = d / "simdir"
    simdir.mkdir(exist_ok=True)
    sim_input = simdir / "rig.yaml"
    shutil.copy(f["sim_rig"], sim_input)
    md_rig = d / "exp" / "outliers-4cam.md"
    md_rig.parent.mkdir(exist_ok=True)
    shutil.copy(f["sim_rig"], md_rig)
    prev = d / "previous" / "estimates.csv"
    prev.parent.mkdir(exist_ok=True)
    shutil.copy(csv, prev)
    corrupt = w / "bags" / "corrupt"
    r = ["replay", bag, "--rig", rig, "--no-progress", "--quiet"]
    table = [
        ("replay --out is the rig", [*r, "--out", rig], "--out", (bag, rig)),
        ("replay --out inside the bag", [*r, "--out", bag / "sample.db3"], "--out", (bag,)),
        ("replay --out is the bag's db3", [*r, "--out", next(bag.glob("*.db3"))], "--out", (bag,)),
        ("replay --out is the bag directory", [*r, "--out", bag], "--out", (bag,)),
        ("replay --out is --config", [*r, "--config", cfg, "--out", cfg], "--out", (cfg,)),
        ("replay --out is a symlink to the rig", [*r, "--out", link], "--out", (rig, link)),
        ("replay --out is a hard link to the rig", [*r, "--out", hard], "--out", (rig, hard)),
        ("replay --batch is the rig", [*r, "--out", d / "x.csv", "--batch", rig], "--batch", (rig,)),
        ("replay --batch is --out", [*r, "--out", d / "x.csv", "--batch", d / "x.csv"], "--batch", (rig,)),
        ("replay fails half-way: previous --out kept", ["replay", corrupt, "--rig", rig, "--no-progress", "--out",
                                                         prev], str(corrupt), (prev, corrupt), (prev.parent / "x",)),
        ("calibrate-bars --out is --rig", ["calibrate-bars", bag, "--rig", rig, "--out", rig], "--out", (rig, bag)),
        ("calibrate-bars --out inside the bag", ["calibrate-bars", bag, "--rig", rig, "--out", bag / "rig.yaml"],
         "--out", (bag,)),
        ("calibrate-bars --out is a matches file", ["calibrate-bars", "--rig", f["sim_rig"], "--matches",
                                                    f["matches"], "--out", f["matches"]], "--out", (f["matches"],)),
        ("import-kalibr --out is the camchain", ["import-kalibr", camchain, "--out", camchain, "--force"], "--out",
         (camchain,)),
        ("make-bag --save-rig is --rig", ["make-bag", "--rig", rig, "--save-rig", rig, "--out", d / "nb"],
         "--save-rig", (rig,)),
        ("make-bag --save-rig is --scenario", ["make-bag", "--scenario", scenario, "--save-rig", scenario, "--out",
                                               d / "nb"], "--save-rig", (scenario,)),
        ("make-bag --out is an existing bag", ["make-bag", "--out", bag, "--no-progress"], "--out", (bag,)),
        ("make-bag --out inside the rig file's path", ["make-bag", "--rig", rig, "--out", rig / "b"], "--out",
         (rig,)),
        ("simulate would overwrite its --rig", ["simulate", "--rig", sim_input, "--out", simdir], "--out",
         (sim_input,)),
        ("solve --out is a matches file", ["solve", "--rig", f["sim_rig"], "--method", "6pt-bending", "--out",
                                           f["matches"], f["matches"]], "--out", (f["matches"],)),
        ("solve --out is --rig", ["solve", "--rig", f["sim_rig"], "--method", "6pt-bending", "--out", f["sim_rig"],
                                  f["matches"]], "--out", (f["sim_rig"],)),
        ("solve-sequence --out is a tracks file", ["solve-sequence", "--rig", f["seq_rig"], "--method", "6pt-bending",
                                                   "--out", f["tracks"], f["tracks"]], "--out", (f["tracks"],)),
        ("compare --plot is the CSV", ["compare", csv, "--bag", bag, "--quiet", "--plot", csv], "--plot", (csv,)),
        ("compare --json inside the bag", ["compare", csv, "--bag", bag, "--quiet", "--json", bag / "s.json"],
         "--json", (bag,)),
        ("compare --json is --rig", ["compare", csv, "--bag", bag, "--rig", rig, "--quiet", "--json", rig], "--json",
         (rig,)),
        ("compare --plot is --json", ["compare", csv, "--bag", bag, "--quiet", "--plot", d / "p", "--json", d / "p"],
         "--json", (csv,)),
        ("observability --out would overwrite its --rig",
         ["observability", "--sweep-ei", "--rig", write(d / "obs" / "observability_ei.csv", f["sim_rig"].read_text()),
          "--out", d / "obs", "--samples", "2"], "--out", (d / "obs" / "observability_ei.csv",)),
        ("experiment --out would overwrite its --rig", ["experiment", "outliers", "--rig", md_rig, "--out",
                                                        md_rig.parent, "--runs", "1"], "--out", (md_rig,)),
    ]
    cases = []
    for name, argv, flag, inputs, *absent in table:
        cases.append(Case("outputs", name, argv, (flag,), inputs=tuple(inputs),
                          absent=tuple(absent[0]) if absent else (d / "x.csv", d / "nb", d / "p")))
    return cases




# ---------------------------------------------------------------------------
# running and classifying
# ---------------------------------------------------------------------------

def run_case(c: Case) -> Case:
    before = {str(p): digest(Path(p)) for p in c.inputs}
    t0 = time.perf_counter()
    proc = nrmpc(*c.argv, check=False)
    after = {str(p): digest(Path(p)) for p in c.inputs}
    err = proc.stderr.strip()
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    left = [str(p) for p in c.absent if os.path.lexists(p)]
    left += [f"{Path(p).parent}/{n}" for p in c.absent for n in partials(Path(p).parent)]
    if "Traceback (most recent call last)" in err or proc.returncode not in (0, 2):
        kind = "traceback"
    elif c.names:
        if proc.returncode == 0:
            kind = "silent wrong"
        elif left:
            kind, err = "silent wrong", f"left behind: {', '.join(left)}; {err}"
        elif len(lines) == 1 and all(n in lines[0] for n in c.names):
            kind = "clear named error"
        else:
            kind = "unnamed error"
    else:
        ok = proc.returncode == 0 and c.stdout in proc.stdout and c.stderr in proc.stderr and not left
        ok = ok and c.result.get("need", "") in proc.stdout and c.result.get("forbid", "\0") not in proc.stdout
        kind = "accepted correctly" if ok else "silent wrong"
    c.result = {"kind": kind, "modified": [p for p in before if before[p] != after[p]], "rc": proc.returncode,
                "message": (lines[0] if lines else err.splitlines()[-1] if err else proc.stdout[-200:]).strip(),
                "seconds": time.perf_counter() - t0}
    return c


def _run_all(cases: list) -> None:
    """Run every case (two at a time) and fail with the list of those not refused clearly or run correctly."""
    with ThreadPoolExecutor(2) as pool:
        cases = list(pool.map(run_case, cases))
    bad = [c for c in cases if c.result["kind"] not in GOOD or c.result["modified"]]
    lines = [f"[{c.area}] {c.name}: {c.result['kind']} (exit {c.result['rc']})"
             f"{' MODIFIED ' + str(c.result['modified']) if c.result['modified'] else ''}\n"
             f"    {c.result['message'][:400]}" for c in bad]
    assert not bad, f"{len(bad)} of {len(cases)} runs not clear or correct:\n" + "\n".join(lines)


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return sim_inputs(tmp_path_factory.mktemp("audit"))


@pytest.fixture(scope="module")
def recorded(simulated):
    return bag_inputs(simulated)


@pytest.mark.parametrize("cases", [rig_cases, matches_cases, tracks_cases], ids=["rig", "matches", "tracks"])
def test_malformed_simulated_inputs_end_in_one_named_error(simulated, cases):
    _run_all(cases(simulated))


@pytest.mark.parametrize("cases", [bag_cases, csv_cases, config_cases, output_cases],
                         ids=["bag", "csv", "config", "outputs"])
def test_malformed_recorded_inputs_and_colliding_outputs_end_in_one_named_error(recorded, cases):
    _run_all(cases(recorded))
