import numpy as np
import pytest

from nrmpc_ros.core import Matches, load_matches, save_matches
from nrmpc_ros.errors import InputError


def _arrays(rng, n=20):
    f1 = rng.normal(size=(n, 3))
    f2 = rng.normal(size=(n, 3))
    return {"f1": f1, "f2": f2, "cam": np.arange(n) % 4}


def test_round_trip_normalises(tmp_path, rng, cross_rig):
    a = _arrays(rng)
    np.savez(tmp_path / "m.npz", **a, g1=np.array([0, 0, -2.0]), g2=np.array([0, 1.0, -5]))
    m = load_matches(tmp_path / "m.npz", cross_rig)
    assert np.allclose(np.linalg.norm(m.f1, axis=1), 1.0) and m.cam.dtype == np.int64
    g1, g2 = m.body_gravity(cross_rig)
    assert np.isclose(np.linalg.norm(g1), 9.81) and np.isclose(np.linalg.norm(g2), 9.81)
    save_matches(m, tmp_path / "m2.npz")
    m2 = load_matches(tmp_path / "m2.npz")
    assert np.allclose(m2.f2, m.f2) and np.allclose(m2.g1, m.g1)


@pytest.mark.parametrize(
    "change, field",
    [
        (lambda a: a.update(f1=a["f1"][:, :2]), "f1"),
        (lambda a: a.update(f2=a["f2"][:-1]), "f2"),
        (lambda a: a["f1"].__setitem__((3, 1), np.nan), "f1"),
        (lambda a: a["f2"].__setitem__(5, 0.0), "f2"),
        (lambda a: a.update(cam=a["cam"][:-2]), "cam"),
        (lambda a: a.update(cam=a["cam"] - 1), "cam"),
        (lambda a: a.update(cam=a["cam"] + 0.5), "cam"),
        (lambda a: a.pop("cam"), "cam"),
        (lambda a: a.update(g1=np.array([0, 0, -9.8])), "g2"),
        (lambda a: a.update(g1=np.zeros(3), g2=np.ones(3)), "g1"),
        (lambda a: a.update(g1=np.ones(3), g2=np.ones(3), g1_cam=np.ones(3), g2_cam=np.ones(3), g_cam_index=0),
         "g1_cam"),
        (lambda a: a.update(g1_cam=np.ones(3), g2_cam=np.ones(3)), "g_cam_index"),
        (lambda a: a.update(extra=np.ones(3)), "extra"),
    ],
)
def test_bad_matches_name_file_and_field(tmp_path, rng, change, field):
    path, msg = _refusal(tmp_path, rng, change)
    assert str(path) in msg and f"'{field}'" in msg


def _refusal(tmp_path, rng, change):
    """(path, message) of the InputError load_matches raises on a valid file edited by ``change``."""
    a = _arrays(rng)
    change(a)
    path = tmp_path / "bad.npz"
    np.savez(path, **a)
    with pytest.raises(InputError) as exc:
        load_matches(path)
    return path, str(exc.value)


def test_camera_index_out_of_rig_range(tmp_path, rng, cross_rig):
    a = _arrays(rng)
    a["cam"][7] = 4
    np.savez(tmp_path / "m.npz", **a)
    with pytest.raises(InputError, match="entry 7 has camera index 4"):
        load_matches(tmp_path / "m.npz", cross_rig)


def test_not_an_npz(tmp_path):
    (tmp_path / "x.npz").write_text("hello")
    with pytest.raises(InputError, match="not a readable"):
        load_matches(tmp_path / "x.npz")
    with pytest.raises(InputError, match="no such"):
        load_matches(tmp_path / "none.npz")


def test_subset_keeps_gravity(rng):
    a = _arrays(rng)
    m = Matches(**a, g1=np.array([0, 0, -1.0]), g2=np.array([0, 0, -1.0]))
    s = m.subset(np.array([0, 2, 4]))
    assert len(s) == 3 and s.has_gravity


# --- every key checked: dtypes, shapes, norms, indices ------------------------------

BAD_ARRAYS = [
    (lambda a: a.update(g1=np.array(["0", "0", "-9.8"]), g2=np.ones(3)), "g1", "dtype <U4"),
    (lambda a: a.update(g1=np.array([0, 0, 1e308]), g2=np.ones(3)), "g1", "entry beyond 1e+06"),
    (lambda a: a.update(g1=np.ones(3), g2=np.array([0, 0, np.inf])), "g2", "NaN or inf"),
    (lambda a: a.update(g1=np.ones((1, 3)), g2=np.ones(3)), "g1", "expected shape (3,)"),
    (lambda a: a.update(f1=a["f1"] > 0), "f1", "dtype bool"),
    (lambda a: a.update(f2=a["f2"] + 0j), "f2", "dtype complex128"),
    (lambda a: a.update(f1=a["f1"].astype(str)), "f1", "dtype <U"),
    (lambda a: a["f1"].__setitem__(2, [1e308, 1e308, 0]), "f1", "entry beyond 1e+06 (first: row 2)"),
    (lambda a: a["f2"].__setitem__(4, [1e-300, 0, 0]), "f2", "(first: row 4, tiny (norm 1e-300 < 1e-06))"),
    (lambda a: a["f2"].__setitem__(6, [0, 0, 0]), "f2", "(first: row 6, zero-length)"),
    (lambda a: a["f1"].__setitem__(1, [np.inf, 0, 0]), "f1", "NaN or inf (first: row 1)"),
    (lambda a: a.update(f1=a["f1"][None]), "f1", "expected shape (N, 3)"),
    (lambda a: a.update(cam=a["cam"].astype(np.uint64) + np.uint64(2**63)), "cam", "beyond the 1000 cameras"),
    (lambda a: a.update(cam=a["cam"] * 1e300), "cam", "beyond the 1000 cameras"),
    (lambda a: a.update(cam=a["cam"] + np.nan), "cam", "must be integers, entry 0 is nan"),
    (lambda a: a.update(cam=a["cam"] > 0), "cam", "dtype bool"),
    (lambda a: a.update(cam=a["cam"].astype(str)), "cam", "expected integer camera indices"),
    (lambda a: a.update(cam=a["cam"][:, None]), "cam", "expected shape (20,)"),
    (lambda a: a.update(g1_cam=np.ones(3), g2_cam=np.ones(3), g_cam_index=np.array([0])), "g_cam_index", "scalar"),
    (lambda a: a.update(g1_cam=np.ones(3), g2_cam=np.ones(3), g_cam_index=1.0), "g_cam_index", "scalar integer"),
    (lambda a: a.update(g1_cam=np.ones(3), g2_cam=np.ones(3), g_cam_index=True), "g_cam_index", "scalar integer"),
    (lambda a: a.update(g1_cam=np.ones(3), g2_cam=np.ones(3), g_cam_index=-1), "g_cam_index", "in [0, 1000)"),
    (lambda a: a.update(g1_cam=np.ones(3), g2_cam=np.zeros(3), g_cam_index=0), "g2_cam", "zero-length"),
    (lambda a: a.update(g_cam_index=0), "g_cam_index", "without g1_cam and g2_cam"),
    (lambda a: a.update(colour=np.ones(3)), "colour", "unknown array"),
]


@pytest.mark.parametrize("change, field, fragment", BAD_ARRAYS)
def test_odd_arrays_name_file_key_and_reason(tmp_path, rng, change, field, fragment):
    path, msg = _refusal(tmp_path, rng, change)
    assert msg.startswith(f"{path}: field '{field}': ") and fragment in msg, msg


def test_in_memory_matches_get_the_same_checks(rng):
    a = _arrays(rng)
    with pytest.raises(InputError, match=r"<matches>: field 'f1': 1 bearing vectors have an entry beyond"):
        Matches(np.vstack([a["f1"][:-1], [1e308, 0, 0]]), a["f2"], a["cam"])
    m = Matches(a["f1"] * 1e5, a["f2"].astype(np.float32), a["cam"].astype(np.uint8))
    assert np.allclose(np.linalg.norm(m.f1, axis=1), 1) and m.f2.dtype == np.float64 and m.cam.dtype == np.int64


@pytest.mark.parametrize("name, payload, fragment", [
    ("empty", b"", "the matches file is empty (0 bytes)"),
    ("text", b"f1 f2 cam\n0 0 1\n", "it is text"),
    ("npy", None, "a single .npy array"),
    ("pickle", None, "holds Python objects"),
    ("bomb", None, "unpacks to 1.12 GiB (declared in the archive), more than the 256 MiB allowed"),
])
def test_hostile_matches_files(tmp_path, rng, name, payload, fragment):
    path = tmp_path / f"{name}.npz"
    marker = tmp_path / "executed"
    if name == "npy":
        np.save(tmp_path / "x.npy", _arrays(rng)["f1"])
        (tmp_path / "x.npy").rename(path)
    elif name == "pickle":
        obj = np.empty(20, dtype=object)
        obj[:] = [_Trap(str(marker))] * 20
        np.savez(path, f1=_arrays(rng)["f1"], f2=obj, cam=np.zeros(20, int))
    elif name == "bomb":
        np.savez(path, **_arrays(rng))
        path.write_bytes(_declare_size(path.read_bytes(), "f2.npy", 1_200_000_000))
    else:
        path.write_bytes(payload)
    with pytest.raises(InputError) as exc:
        load_matches(path)
    assert str(exc.value).startswith(str(path)) and fragment in str(exc.value), str(exc.value)
    assert not marker.exists()


class _Trap:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):  # unpickling would create the marker file
        return (open, (self.marker, "w"))


def _declare_size(data: bytes, member: str, size: int) -> bytes:
    """The zip archive with ``member``'s uncompressed size in its central directory entry set to ``size``."""
    out = bytearray(data)
    i = out.find(b"PK\x01\x02")
    while i >= 0:
        name_len = int.from_bytes(out[i + 28:i + 30], "little")
        if out[i + 46:i + 46 + name_len].decode() == member:
            out[i + 24:i + 28] = size.to_bytes(4, "little")
        i = out.find(b"PK\x01\x02", i + 4)
    return bytes(out)


def test_solve_says_why_a_pair_fails(tmp_path, rng, capsys, cross_rig):
    """Too few correspondences: `nrmpc solve` prints success false and the estimator's reason."""
    import json

    from nrmpc_ros.cli.main import main
    from nrmpc_ros.core import save_rig

    save_rig(cross_rig, tmp_path / "rig.yaml")
    np.savez(tmp_path / "few.npz", **_arrays(rng, n=5))
    assert main(["solve", "--rig", str(tmp_path / "rig.yaml"), "--method", "6pt-bending",
                 str(tmp_path / "few.npz")]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["success"] is False
    assert r["reason"] == "needs at least 8 correspondences seen by at least 2 cameras, got 5 from 4 camera(s)"
