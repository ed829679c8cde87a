"""Property-based fuzzing of the loaders of rigs, matches, tracks, pipeline settings and estimate CSVs
(hypothesis, derandomised).

Whatever the input, the only outcomes allowed are a valid result that
satisfies the loader's invariants, or an InputError naming the source. Any
other exception (TypeError, ZeroDivisionError, LinAlgError, RecursionError,
MemoryError, ...) fails the test.
"""

import copy
import io
import math
import string
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from nrmpc_ros.cli.replay import load_config
from nrmpc_ros.config import to_mapping
from nrmpc_ros.core import deformed_extrinsics, load_matches, load_rig, rig_from_dict
from nrmpc_ros.core.matches import Matches
from nrmpc_ros.core.rig import (
    GRAVITY_RANGE,
    MAX_CAMERAS,
    MAX_DISTORTION_COEFF,
    MAX_FOCAL_PX,
    MAX_MASS_KG,
    MAX_POSITION_M,
    MAX_RESOLUTION_PX,
    MAX_TIP_ROTATION_DEG,
    MIN_FOCAL_PX,
)
from nrmpc_ros.core.tracks import load_tracks
from nrmpc_ros.errors import InputError
from nrmpc_ros.frontend.estimates_csv import CsvWriter, EstimateRow, read_csv
from nrmpc_ros.frontend.pipeline import PipelineConfig
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

# Deterministic (same examples on every run, no example database written), bounded, no per-example deadline.
FUZZ = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

BASE_RIG = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.2)).to_dict()
BASE_RIG["imu"] = {"topic": "/imu/data", "mount": "cam1", "rotation_xyzw": [0.0, 0.0, 0.0, 1.0]}
BASE_RIG["cameras"][2]["model"] = "equidistant"
BASE_RIG["cameras"][2]["distortion"] = [0.01, -0.002, 0.0, 0.0]
BASE_RIG["cameras"][1]["info_topic"] = "/cam1/info"

SOURCE = "<fuzz rig>"

# Values a careless or hostile file may hold where a number, string, list or mapping is expected.
ODD_SCALARS = st.one_of(
    st.none(), st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.sampled_from([10**400, -(10**400), 0, -1, 1, 2, 640, 20_001, 10**5 + 1]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e-300, 1e300, 1e308, -0.0, 5e-324, 0.1, 0.4, 9.81, 0.05, 1e5, 2e4, 100.0, 1000.0]),
    st.text(max_size=12),
    st.sampled_from(["inf", ".inf", "-inf", "nan", "yes", "cam0", "cam1", "/cam0/image_raw", "/cam0/camera_info",
                     "/imu/data", "~/x", "a//b", "pinhole", "equidistant", "body", "1e3", ""]),
)
# Plausible edits keep many mutated rigs valid, so the invariants of valid rigs are exercised too.
PLAUSIBLE = st.one_of(st.floats(-2, 2), st.floats(0.01, 1000), st.integers(1, 5000),
                      st.lists(st.floats(-1, 1), min_size=3, max_size=5))
ODD = st.one_of(
    PLAUSIBLE, ODD_SCALARS,
    st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5), st.booleans()),
             max_size=6),
    st.dictionaries(st.sampled_from(["mass", "EI", "topic", "x", "name"]), ODD_SCALARS, max_size=3),
)
NEW_KEYS = st.one_of(st.sampled_from(["bar", "info_topic", "image_topic", "distortion", "imu", "mount", "EI", "mass",
                                      "topic", "body_frame", "gravity_magnitude", "colour"]), st.text(max_size=6),
                     st.integers(-2, 2))


def _paths(obj, prefix=()):
    """Every (key or index) path into a nested mapping/list, the root excluded."""
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    for k, v in items:
        yield prefix + (k,)
        yield from _paths(v, prefix + (k,))


def _get(obj, path):
    for k in path:
        obj = obj[k]
    return obj


def _mutate(data, draw):
    """Apply 1-3 random edits to ``data`` in place: replace a value, drop a key or item, add one."""
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_paths(data))
        if not paths:
            return
        path = draw(st.sampled_from(paths))
        parent, key = _get(data, path[:-1]), path[-1]
        action = draw(st.sampled_from(["replace", "replace", "drop", "add"]))
        if action == "replace":
            parent[key] = draw(ODD)
        elif action == "drop":
            del parent[key]
        elif isinstance(parent, dict):
            parent[draw(NEW_KEYS)] = draw(ODD)
        else:
            parent.insert(key, copy.deepcopy(parent[key]) if draw(st.booleans()) else draw(ODD))


def _check_rig(rig):
    """The invariants every rig that loads satisfies (bounds of nrmpc_ros.core.rig)."""
    M = rig.num_cameras
    assert 1 <= M <= MAX_CAMERAS
    assert GRAVITY_RANGE[0] <= rig.gravity_magnitude <= GRAVITY_RANGE[1]
    names = [c.name for c in rig.cameras]
    assert len(set(names)) == M and all(n and not n[0].isdigit() for n in names)
    images = [c.image_topic for c in rig.cameras]
    infos = [c.info_topic for c in rig.cameras]
    assert len(set(images)) == M and len(set(infos)) == M and not set(images) & set(infos)
    if rig.imu is not None:
        assert rig.imu.topic not in images + infos and rig.imu.mount in names + ["body"]
        assert np.allclose(rig.imu.rotation @ rig.imu.rotation.T, np.eye(3), atol=1e-6)
    assert np.all(np.isfinite(rig.positions)) and np.all(np.linalg.norm(rig.positions, axis=1) <= MAX_POSITION_M)
    R = rig.rotations
    assert np.allclose(R @ np.transpose(R, (0, 2, 1)), np.eye(3), atol=1e-6) and np.allclose(np.linalg.det(R), 1)
    for c in rig.cameras:
        assert all(MIN_FOCAL_PX <= f <= MAX_FOCAL_PX for f in c.intrinsics[:2])
        assert all(isinstance(n, int) and 1 <= n <= MAX_RESOLUTION_PX for n in c.resolution)
        assert all(math.isfinite(k) and abs(k) <= MAX_DISTORTION_COEFF for k in c.distortion)
        assert 0 <= c.mass <= MAX_MASS_KG and c.EI > 0
    u, cd, cr = rig.bar_coefficients
    L = np.linalg.norm(rig.positions, axis=1)
    assert np.all(np.degrees(cr * rig.gravity_magnitude) <= MAX_TIP_ROTATION_DEG + 1e-9)
    assert np.all(cd * rig.gravity_magnitude <= L + 1e-12)
    # What the estimator gets from it is finite, and the rig round-trips through its own file format.
    w, W = deformed_extrinsics(rig, np.array([0.0, 0.3, -1.0]) * rig.gravity_magnitude / math.hypot(0.3, 1.0))
    assert np.all(np.isfinite(w)) and np.all(np.isfinite(W))
    again = rig_from_dict(rig.to_dict(), "<round trip>")
    assert np.allclose(again.positions, rig.positions) and np.allclose(again.compliance, rig.compliance)


def _rig_or_input_error(load, source):
    try:
        rig = load()
    except InputError as exc:
        assert str(exc).startswith(source)
        return None
    _check_rig(rig)
    return rig


def test_base_rig_is_valid():
    assert _rig_or_input_error(lambda: rig_from_dict(copy.deepcopy(BASE_RIG), SOURCE), SOURCE) is not None


@FUZZ
@given(st.data())
def test_rig_from_dict_mutations(data):
    d = copy.deepcopy(BASE_RIG)
    _mutate(d, data.draw)
    _rig_or_input_error(lambda: rig_from_dict(d, SOURCE), SOURCE)


@FUZZ
@given(st.data())
def test_rig_from_dict_numeric_perturbations(data):
    """Numbers scaled by 1e-4..1e4 or sign-flipped: around the plausibility bounds, on both sides of them."""
    d = copy.deepcopy(BASE_RIG)
    numeric = [p for p in _paths(d) if isinstance(_get(d, p), float | int) and not isinstance(_get(d, p), bool)]
    for path in data.draw(st.lists(st.sampled_from(numeric), min_size=1, max_size=3)):
        parent = _get(d, path[:-1])
        factor = 10.0 ** data.draw(st.floats(-4, 4)) * data.draw(st.sampled_from([1, 1, 1, -1]))
        parent[path[-1]] = parent[path[-1]] * factor if parent[path[-1]] else factor
    _rig_or_input_error(lambda: rig_from_dict(d, SOURCE), SOURCE)


def _mutated_text(d: dict, draw, mapping_too: bool = False) -> str:
    """YAML of ``d`` with up to three edits of the text (characters inserted, deleted, replaced); with
    ``mapping_too``, of a copy of ``d`` first mutated as a mapping half of the time."""
    if mapping_too:
        d = copy.deepcopy(d)
        if draw(st.booleans()):
            _mutate(d, draw)
    text = yaml.safe_dump(d, sort_keys=False, default_flow_style=draw(st.sampled_from([None, True, False])))
    for _ in range(draw(st.integers(0, 3))):
        i = draw(st.integers(0, len(text)))
        j = draw(st.integers(i, min(len(text), i + 8)))
        text = text[:i] + draw(st.text(alphabet="[]{}:,-&*!|>'\"#%@` \n\t.~/_0189aeinfxyz", max_size=6)) + text[j:]
    return text


def _mutated_bytes(raw: bytes, draw) -> bytes:
    """``raw`` with one to four bytes overwritten, sometimes cut short, or (one time in five) other bytes."""
    out = bytearray(raw)
    for _ in range(draw(st.integers(1, 4))):
        out[draw(st.integers(0, len(out) - 1))] = draw(st.integers(0, 255))
    if draw(st.booleans()):
        out = out[:draw(st.integers(0, len(out)))]
    if draw(st.integers(0, 4)) == 0:
        out = bytearray(draw(st.binary(max_size=200)))
    return bytes(out)


def _corrupted_npz(path: Path, arrays: dict, draw) -> Path:
    """An .npz of ``arrays`` (compressed or not) written to ``path`` with its bytes mutated."""
    buf = io.BytesIO()
    (np.savez_compressed if draw(st.booleans()) else np.savez)(buf, **arrays)
    path.write_bytes(_mutated_bytes(buf.getvalue(), draw))
    return path


def _loaded_or_named_error(load, path: Path):
    """``load(path)``, or None after an InputError that starts with the path."""
    try:
        return load(path)
    except InputError as exc:
        assert str(exc).startswith(str(path))
        return None


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@FUZZ
@given(st.data())
def test_load_rig_mutated_yaml_text(fuzz_dir, data):
    """A valid rig file, mutated as a mapping and then as text (characters inserted, deleted, replaced)."""
    text = _mutated_text(BASE_RIG, data.draw, mapping_too=True)
    path = fuzz_dir / "rig.yaml"
    path.write_text(text)
    _rig_or_input_error(lambda: load_rig(path), str(path))


@FUZZ
@given(st.one_of(st.binary(max_size=300), st.text(max_size=300).map(str.encode),
                 st.text(max_size=100).map(lambda t: t.encode("utf-16"))))
def test_load_rig_random_bytes(fuzz_dir, payload):
    path = fuzz_dir / "random.yaml"
    path.write_bytes(payload)
    _rig_or_input_error(lambda: load_rig(path), str(path))


# --- matches -------------------------------------------------------------------

MATCH_KEYS = ["f1", "f2", "cam", "g1", "g2", "g1_cam", "g2_cam", "g_cam_index"]
NUMERIC_DTYPES = st.sampled_from([np.float64, np.float32, np.float16, np.int64, np.int8, np.uint64, np.bool_,
                                  np.complex128])
DTYPES = st.one_of(NUMERIC_DTYPES, st.sampled_from([np.dtype("U3"), np.dtype("S2"),
                                                    np.dtype([("a", "<f8"), ("b", "<i4")])]))
ARRAYS = DTYPES.flatmap(lambda dt: hnp.arrays(dt, st.one_of(st.just(()), hnp.array_shapes(min_dims=1, max_dims=3,
                                                                                           max_side=6))))
ODD_ROWS = st.sampled_from([[0, 0, 0], [1e308, 1e308, 1e308], [1e-300, 0, 0], [np.nan, 0, 1], [np.inf, 0, 0],
                            [-1e6, 0, 0], [1e7, 0, 0], [1e-7, 0, 0]])


def _write_npz(path, arrays):
    """Like numpy.savez, but any key works (savez's own keyword arguments, 'file', clash with array names)."""
    with zipfile.ZipFile(path, "w") as z:
        for key, value in arrays.items():
            buf = io.BytesIO()
            np.save(buf, value, allow_pickle=False)
            z.writestr(f"{key}.npy", buf.getvalue())


def _check_matches(m, rig):
    n = len(m.cam)
    assert m.f1.shape == m.f2.shape == (n, 3) and m.f1.dtype == m.f2.dtype == np.float64
    assert np.all(np.isfinite(m.f1)) and np.all(np.isfinite(m.f2))
    assert np.allclose(np.linalg.norm(m.f1, axis=1), 1, atol=1e-12)
    assert np.allclose(np.linalg.norm(m.f2, axis=1), 1, atol=1e-12)
    assert m.cam.dtype == np.int64 and np.all(m.cam >= 0) and np.all(m.cam < MAX_CAMERAS)
    if rig is not None:
        assert np.all(m.cam < rig.num_cameras)
    for g in (m.g1, m.g2, m.g1_cam, m.g2_cam):
        assert g is None or (g.shape == (3,) and np.all(np.isfinite(g)) and np.linalg.norm(g) > 0)
    if m.g_cam_index is not None:
        assert isinstance(m.g_cam_index, int) and m.g1_cam is not None
    if rig is not None and m.has_gravity:
        g1, g2 = m.body_gravity(rig)
        assert np.isclose(np.linalg.norm(g1), rig.gravity_magnitude) and np.all(np.isfinite(g2))


@FUZZ
@given(st.data())
def test_load_matches_random_arrays(fuzz_dir, cross_rig, data):
    n = data.draw(st.integers(0, 12))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    arrays = {"f1": rng.normal(size=(n, 3)), "f2": rng.normal(size=(n, 3)), "cam": rng.integers(0, 4, n)}
    if data.draw(st.booleans()):
        arrays.update(g1_cam=rng.normal(size=3), g2_cam=rng.normal(size=3), g_cam_index=np.int64(rng.integers(4)))
    elif data.draw(st.booleans()):
        arrays.update(g1=rng.normal(size=3), g2=rng.normal(size=3))
    for _ in range(data.draw(st.integers(0, 3))):
        action = data.draw(st.sampled_from(["array", "row", "drop", "add", "cast"]))
        key = data.draw(st.sampled_from(sorted(arrays))) if arrays else None
        if action == "array" and key:
            arrays[key] = data.draw(ARRAYS)
        elif action == "row" and key in ("f1", "f2") and n and np.asarray(arrays[key]).dtype == np.float64 \
                and np.shape(arrays[key]) == (n, 3):
            arrays[key][data.draw(st.integers(0, n - 1))] = data.draw(ODD_ROWS)
        elif action == "drop" and key:
            del arrays[key]
        elif action == "add":
            name = data.draw(st.one_of(st.sampled_from(MATCH_KEYS + ["file", "allow_pickle"]),
                                       st.text(string.ascii_letters + string.digits + "_", min_size=1, max_size=6)))
            arrays[name] = data.draw(ARRAYS)
        elif action == "cast" and key and np.asarray(arrays[key]).dtype.kind in "biufc":
            with warnings.catch_warnings(), np.errstate(all="ignore"):  # NaN -> int is garbage on purpose
                warnings.simplefilter("ignore")
                arrays[key] = np.asarray(arrays[key]).astype(data.draw(NUMERIC_DTYPES))
    path = fuzz_dir / "m.npz"
    _write_npz(path, arrays)
    rig = cross_rig if data.draw(st.booleans()) else None
    try:
        m = load_matches(path, rig)
    except InputError as exc:
        assert str(exc).startswith(str(path))
        return
    _check_matches(m, rig)


@FUZZ
@given(st.data())
def test_load_matches_corrupted_bytes(fuzz_dir, data):
    """A valid archive with bytes flipped, cut or replaced; and random bytes."""
    rng = np.random.default_rng(5)
    arrays = {"f1": rng.normal(size=(6, 3)), "f2": rng.normal(size=(6, 3)), "cam": np.arange(6) % 4}
    m = _loaded_or_named_error(load_matches, _corrupted_npz(fuzz_dir / "c.npz", arrays, data.draw))
    if m is not None:
        _check_matches(m, None)


def _shaped(n, cols=None):
    """Arrays of the expected shape (n, 3) or (n,) but of any dtype and any values (NaN, inf, huge, tiny)."""
    shape = (n, cols) if cols else (n,)
    return DTYPES.flatmap(lambda dt: hnp.arrays(dt, shape))


@FUZZ
@given(st.data())
def test_matches_constructor_random_arrays(data):
    n = data.draw(st.integers(0, 8))
    f1, f2 = (data.draw(st.one_of(_shaped(n, 3), ARRAYS)) for _ in range(2))
    cam = data.draw(st.one_of(_shaped(n), ARRAYS, hnp.arrays(np.int64, n, elements=st.integers(0, 3))))
    try:
        m = Matches(f1, f2, cam)
    except InputError as exc:
        assert str(exc).startswith("<matches>")
        return
    _check_matches(m, None)


# --- tracks --------------------------------------------------------------------

TRACK_KEYS = ["view", "cam", "track", "f", "g_meas"]


def _good_tracks(rng, n_views=3, n_tracks=6):
    """Every track seen by camera (track % 4) in every view, with measured gravity in all but the last view."""
    view, track = (a.ravel() for a in np.meshgrid(np.arange(n_views), np.arange(n_tracks), indexing="ij"))
    cam = track % 4
    g = rng.normal(size=(n_views, 3))
    g[-1] = np.nan
    return {"view": view, "cam": cam, "track": track, "f": rng.normal(size=(len(view), 3)), "g_meas": g}


def _check_tracks(t):
    n = len(t)
    assert n >= 1 and t.f.shape == (n, 3) and t.f.dtype == np.float64 and np.all(np.isfinite(t.f))
    assert np.allclose(np.linalg.norm(t.f, axis=1), 1, atol=1e-12)
    for a in (t.view, t.cam, t.track):
        assert a.shape == (n,) and a.dtype == np.int64 and np.all(a >= 0)
    K = t.num_views
    assert isinstance(K, int) and K == int(t.view.max()) + 1 and np.all(np.bincount(t.view, minlength=K) > 0)
    assert len({(v, c, k) for v, c, k in zip(t.view, t.cam, t.track)}) == n
    if t.g_meas is not None:
        g = t.g_meas
        assert g.shape == (K, 3) and g.dtype == np.float64
        nan = np.isnan(g).all(axis=1)
        assert np.all(np.isfinite(g[~nan])) and np.all(np.linalg.norm(g[~nan], axis=1) > 0)
        assert not np.any(np.isnan(g[~nan]))


def test_base_tracks_settings_and_csv_are_valid(fuzz_dir):
    """The starting points of the fuzzing below load, so mutations are tried on both sides of validity."""
    path = fuzz_dir / "base.npz"
    _write_npz(path, _good_tracks(np.random.default_rng(3)))
    _check_tracks(load_tracks(path))
    _check_config(PipelineConfig.from_dict(copy.deepcopy(BASE_CONFIG), "<base>"))
    _good_csv(path.with_suffix(".csv"), np.random.default_rng(3))
    rows = read_csv(path.with_suffix(".csv"))
    assert len(rows) == 3 and rows[1].gravity is None
    _check_rows(rows)


@FUZZ
@given(st.data())
def test_load_tracks_random_arrays(fuzz_dir, data):
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    arrays = _good_tracks(rng, data.draw(st.integers(1, 4)), data.draw(st.integers(1, 8)))
    n = len(arrays["view"])
    for _ in range(data.draw(st.integers(0, 3))):
        action = data.draw(st.sampled_from(["array", "row", "drop", "add", "cast", "index"]))
        key = data.draw(st.sampled_from(sorted(arrays))) if arrays else None
        if action == "array" and key:
            arrays[key] = data.draw(ARRAYS)
        elif action == "row" and key == "f" and np.shape(arrays["f"]) == (n, 3) and arrays["f"].dtype == np.float64:
            arrays["f"][data.draw(st.integers(0, n - 1))] = data.draw(ODD_ROWS)
        elif action == "index" and key in ("view", "cam", "track") and np.shape(arrays[key]) == (n,):
            arrays[key] = np.asarray(arrays[key]).copy()
            arrays[key][data.draw(st.integers(0, n - 1))] = data.draw(st.sampled_from(
                [-1, 0, 1, 7, 999, 2**62, 2**63 - 1]))
        elif action == "drop" and key:
            del arrays[key]
        elif action == "add":
            name = data.draw(st.one_of(st.sampled_from(TRACK_KEYS + ["num_views", "allow_pickle"]),
                                       st.text(string.ascii_letters + "_", min_size=1, max_size=6)))
            arrays[name] = data.draw(ARRAYS)
        elif action == "cast" and key and np.asarray(arrays[key]).dtype.kind in "biufc":
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                arrays[key] = np.asarray(arrays[key]).astype(data.draw(NUMERIC_DTYPES))
    path = fuzz_dir / "t.npz"
    _write_npz(path, arrays)
    t = _loaded_or_named_error(load_tracks, path)
    if t is not None:
        _check_tracks(t)


@FUZZ
@given(st.data())
def test_load_tracks_corrupted_bytes(fuzz_dir, data):
    arrays = _good_tracks(np.random.default_rng(7))
    t = _loaded_or_named_error(load_tracks, _corrupted_npz(fuzz_dir / "tc.npz", arrays, data.draw))
    if t is not None:
        _check_tracks(t)


# --- pipeline settings ---------------------------------------------------------

BASE_CONFIG = to_mapping(PipelineConfig())


def _check_config(cfg):
    """A config that loads holds values of its defaults' types and loads again from its own mapping."""
    def same_kinds(value, default, path):
        if isinstance(default, dict):
            for k in default:
                same_kinds(value[k], default[k], f"{path}{k}.")
        elif default is not None:
            assert type(value) is type(default), (path, value)
            assert not isinstance(value, float) or not math.isnan(value), path
    mapping = to_mapping(cfg)
    same_kinds(mapping, BASE_CONFIG, "")
    assert to_mapping(PipelineConfig.from_dict(mapping, "<again>")) == mapping


@FUZZ
@given(st.data())
def test_pipeline_config_from_dict_mutations(data):
    d = copy.deepcopy(BASE_CONFIG)
    _mutate(d, data.draw)
    try:
        cfg = PipelineConfig.from_dict(d, "<fuzz config>")
    except InputError as exc:
        assert str(exc).startswith("<fuzz config>")
        return
    _check_config(cfg)


@FUZZ
@given(st.data())
def test_replay_config_file_mutated_text(fuzz_dir, data):
    """The --config file of nrmpc replay: a valid settings file mutated as a mapping, then as text."""
    text = _mutated_text(BASE_CONFIG, data.draw, mapping_too=True)
    path = fuzz_dir / "settings.yaml"
    path.write_bytes(text.encode() if data.draw(st.integers(0, 5)) else data.draw(st.binary(max_size=200)))
    try:
        cfg = load_config(path, seed=data.draw(st.integers(0, 2**63 - 1)))
    except InputError as exc:
        assert str(exc).startswith(str(path))
        return
    _check_config(cfg)


# --- estimate CSVs -------------------------------------------------------------

ODD_CELLS = st.one_of(st.sampled_from(["", "nan", "inf", "-inf", "1e400", "-0", "0", "1", "2.5", "-1", "abc", " 1",
                                       "0x10", "1_000", "\"", ",", "\n", "9" * 400, "6pt-bending", "\x00"]),
                      st.text(max_size=6))


def _good_csv(path, rng, n=3):
    with CsvWriter(path) as w:
        for k in range(n):
            q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            R = q * np.sign(np.linalg.det(q))
            g = None if k == 1 else rng.normal(size=3)
            w.write(EstimateRow(10.0 + k, 9.0 + k, "4pt-bending", R, rng.normal(size=3), g, 40 + k, 12.5,
                                {"gravity_sigma_deg": 0.1, "hold": k}, (9.0, R, rng.normal(size=3))))
    return path.read_text()


def _check_rows(rows):
    for r in rows:
        assert math.isfinite(r.stamp) and math.isfinite(r.ref_stamp) and math.isfinite(r.time_ms)
        assert np.allclose(r.R @ r.R.T, np.eye(3), atol=1e-6) and np.all(np.isfinite(r.t))
        assert r.gravity is None or (np.all(np.isfinite(r.gravity)) and np.linalg.norm(r.gravity) > 0)
        assert isinstance(r.num_inliers, int) and r.num_inliers >= 0
        if r.origin is not None:
            assert math.isfinite(r.origin[0]) and np.allclose(r.origin[1] @ r.origin[1].T, np.eye(3), atol=1e-6)


@FUZZ
@given(st.data())
def test_read_csv_mutations(fuzz_dir, data):
    """A valid estimates CSV with cells replaced, characters inserted or deleted, cut short; or random bytes."""
    path = fuzz_dir / "estimates.csv"
    text = _good_csv(path, np.random.default_rng(data.draw(st.integers(0, 2**32 - 1))))
    lines = text.splitlines(keepends=True)
    for _ in range(data.draw(st.integers(0, 3))):
        action = data.draw(st.sampled_from(["cell", "cell", "chars", "cut"]))
        if action == "cell":
            k = data.draw(st.integers(0, len(lines) - 1))
            cells = lines[k].rstrip("\n").split(",")
            cells[data.draw(st.integers(0, len(cells) - 1))] = data.draw(ODD_CELLS)
            lines[k] = ",".join(cells) + "\n"
        elif action == "chars":
            t = "".join(lines)
            i = data.draw(st.integers(0, len(t)))
            t = t[:i] + data.draw(st.text(alphabet=',"\n\r.-e0123456789nanif\x00', max_size=4)) + t[i + 2:]
            lines = t.splitlines(keepends=True) or [""]
        else:
            t = "".join(lines)
            lines = [t[:data.draw(st.integers(0, len(t)))]]
    payload = "".join(lines).encode()
    if data.draw(st.integers(0, 6)) == 0:
        payload = data.draw(st.binary(max_size=300))
    elif data.draw(st.integers(0, 6)) == 0:
        payload = "".join(lines).encode(data.draw(st.sampled_from(["utf-16", "latin-1", "utf-8-sig"])),
                                        errors="replace")
    path.write_bytes(payload)
    rows = _loaded_or_named_error(read_csv, path)
    if rows is not None:
        _check_rows(rows)
