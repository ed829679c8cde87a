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
    a = _arrays(rng)
    change(a)
    path = tmp_path / "bad.npz"
    np.savez(path, **a)
    with pytest.raises(InputError) as exc:
        load_matches(path)
    assert str(path) in str(exc.value) and f"'{field}'" in str(exc.value)


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
