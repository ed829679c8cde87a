"""Tracks of a sequence of static views: validation, file round trip, pairs and view subsets."""

import numpy as np
import pytest

from nrmpc_ros.core.tracks import Tracks, load_tracks, save_tracks
from nrmpc_ros.errors import InputError

K, M, PER = 3, 2, 5  # views, cameras, tracks per camera


def _arrays(rng):
    """Every track of camera c is seen by c in all K views; ids are sparse (not 0..L-1)."""
    view, cam, track = (a.reshape(-1) for a in np.meshgrid(np.arange(K), np.arange(M), np.arange(PER),
                                                           indexing="ij"))
    track = 10 * track + 1000 * cam + 7
    n = len(view)
    g = rng.normal(size=(K, 3))
    g[1] = np.nan  # view 1 without a gravity measurement
    return {"view": view, "cam": cam, "track": track, "f": 3.0 * rng.normal(size=(n, 3)), "g_meas": g}


def _save(path, a):
    np.savez(path, **a)
    return path


def test_round_trip_normalises_and_keeps_nan_rows(tmp_path, rng, cross_rig):
    a = _arrays(rng)
    a["view"] = a["view"].astype(np.int32)
    a["cam"] = a["cam"].astype(float)  # whole numbers stored as floats are accepted
    t = load_tracks(_save(tmp_path / "t.npz", a))
    assert len(t) == K * M * PER and t.num_views == K
    assert t.view.dtype == t.cam.dtype == t.track.dtype == np.int64
    assert np.allclose(np.linalg.norm(t.f, axis=1), 1.0)
    t.check_rig(cross_rig)
    g = t.measured_gravity(cross_rig)
    assert np.all(np.isnan(g[1])) and np.allclose(np.linalg.norm(g[[0, 2]], axis=1), 9.81)
    assert np.allclose(g[0] / 9.81, a["g_meas"][0] / np.linalg.norm(a["g_meas"][0]))
    save_tracks(t, tmp_path / "t2.npz")
    t2 = load_tracks(tmp_path / "t2.npz")
    for key, value in t.to_npz_dict().items():  # bearings are renormalised again on load: equal to rounding
        assert np.allclose(getattr(t2, key), value, rtol=0, atol=1e-15, equal_nan=True)
    a.pop("g_meas")
    t3 = load_tracks(_save(tmp_path / "t3.npz", a))
    assert t3.g_meas is None and t3.measured_gravity(cross_rig) is None and "g_meas" not in t3.to_npz_dict()


def _set(key, row, value):
    def change(a):
        a[key] = a[key].astype(float) if isinstance(value, float) and a[key].dtype.kind == "i" else a[key]
        a[key][row] = value
    return change


@pytest.mark.parametrize(
    "change, field",
    [
        (lambda a: a.pop("view"), "view"),
        (lambda a: a.pop("cam"), "cam"),
        (lambda a: a.pop("track"), "track"),
        (lambda a: a.pop("f"), "f"),
        (lambda a: a.update(colour=np.ones(3)), "colour"),
        (lambda a: a.update(f=a["f"][:, :2]), "f"),
        (lambda a: a.update(f=np.round(a["f"]).astype(np.int64)), "f"),
        (lambda a: a.update(f=np.zeros((0, 3)), view=a["view"][:0], cam=a["cam"][:0], track=a["track"][:0]), "f"),
        (_set("f", (4, 1), np.nan), "f"),
        (_set("f", (4, 2), np.inf), "f"),
        (_set("f", 6, 0.0), "f"),
        (lambda a: a.update(view=a["view"][:-1]), "view"),
        (lambda a: a.update(cam=a["cam"][:, None]), "cam"),
        (_set("view", 3, 1.5), "view"),
        (_set("track", 3, np.nan), "track"),
        (lambda a: a.update(cam=a["cam"].astype(bool)), "cam"),
        (lambda a: a.update(track=a["track"].astype(str)), "track"),
        (_set("view", 0, -1), "view"),
        (_set("cam", 2, -3), "cam"),
        (_set("track", 5, -1), "track"),
        (_set("track", 0, 1e30), "track"),
        (_set("track", 1, 7), "track"),  # track 7 is already seen by camera 0 in view 0
        (lambda a: a.update(view=np.where(a["view"] == 2, 3, a["view"]), g_meas=np.ones((4, 3))), "view"),
        (lambda a: a.update(g_meas=a["g_meas"][:2]), "g_meas"),
        (lambda a: a.update(g_meas=np.ones((K + 1, 3))), "g_meas"),
        (lambda a: a.update(g_meas=np.ones(3)), "g_meas"),
        (_set("g_meas", (0, 2), np.inf), "g_meas"),
        (_set("g_meas", (1, 0), 1.0), "g_meas"),  # partly NaN row
        (_set("g_meas", 2, 0.0), "g_meas"),
        (lambda a: a.update(g_meas=np.full((K, 3), "x")), "g_meas"),
    ],
)
def test_bad_tracks_name_file_and_field(tmp_path, rng, change, field):
    a = _arrays(rng)
    change(a)
    path = _save(tmp_path / "bad.npz", a)
    with pytest.raises(InputError) as exc:
        load_tracks(path)
    assert str(path) in str(exc.value) and f"'{field}'" in str(exc.value)


def test_constructor_checks_num_views(rng):
    a = _arrays(rng)
    with pytest.raises(InputError, match="'num_views'"):
        Tracks(**a, num_views=True)
    with pytest.raises(InputError, match="'view'.*num_views is 2"):
        Tracks(a["view"], a["cam"], a["track"], a["f"], num_views=2)
    with pytest.raises(InputError, match="'view'.*view 3"):  # trailing views without observations
        Tracks(a["view"], a["cam"], a["track"], a["f"], num_views=5)


def test_single_view_track_is_allowed(rng):
    a = _arrays(rng)
    a["track"][0] = 123456  # now seen in view 0 only
    t = Tracks(a["view"], a["cam"], a["track"], a["f"])
    assert np.sum(t.track == 123456) == 1


def test_camera_index_out_of_rig_range(rng, cross_rig):
    a = _arrays(rng)
    a["cam"][a["cam"] == 1] = 4
    t = Tracks(**a, source="seq.npz")
    with pytest.raises(InputError, match="seq.npz: field 'cam'.*camera index 4"):
        t.check_rig(cross_rig)


@pytest.mark.parametrize("content, message", [
    (b"", r"is empty \(0 bytes\)"),
    (b"hello", "not a readable"),
    (None, "no such"),
])
def test_unreadable_files(tmp_path, content, message):
    path = tmp_path / "x.npz"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=message):
        load_tracks(path)


def test_npy_directory_and_pickled_arrays(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros(3))
    with pytest.raises(InputError, match="single .npy array"):
        load_tracks(tmp_path / "a.npy")
    with pytest.raises(InputError, match="directory"):
        load_tracks(tmp_path)
    np.savez(tmp_path / "obj.npz", view=np.array([0, 1], dtype=object))
    with pytest.raises(InputError, match="'view'"):
        load_tracks(tmp_path / "obj.npz")


def _multi_camera_tracks(rng):
    """Track 5 is seen by camera 0 in views 0 and 2 and by camera 1 in view 1; track 6 by camera 1 in all
    three views; track 8 by camera 0 in views 1 and 2; track 9 by cameras 0 and 1 in view 0 only."""
    rows = [(0, 0, 5), (2, 0, 5), (1, 1, 5), (0, 1, 6), (1, 1, 6), (2, 1, 6), (1, 0, 8), (2, 0, 8),
            (0, 0, 9), (0, 1, 9)]
    v, c, k = np.array(rows).T
    g = np.array([[0, 0, -1.0], [np.nan] * 3, [0.1, 0, -1.0]])
    return Tracks(v, c, k, rng.normal(size=(len(v), 3)), g)


def test_pair_indices_match_the_same_camera_only(rng):
    t = _multi_camera_tracks(rng)
    i1, i2 = t.pair_indices(0, 2)
    assert t.track[i1].tolist() == [5, 6] and t.cam[i1].tolist() == [0, 1]
    i1, i2 = t.pair_indices(0, 1)
    assert t.track[i1].tolist() == [6]  # track 5 changes camera between views 0 and 1
    i1, i2 = t.pair_indices(2, 1)
    assert t.track[i1].tolist() == [8, 6] and np.all(t.view[i1] == 2) and np.all(t.view[i2] == 1)


def test_pair_is_consistent_with_pair_indices(rng):
    a = _arrays(rng)
    drop = (a["view"] == 2) & (a["track"] % 20 == 7)  # tracks 0, 2, 4 of each camera end after view 1
    t = Tracks(*(a[k][~drop] for k in ("view", "cam", "track", "f")), a["g_meas"])
    for k1, k2 in ((0, 1), (0, 2), (2, 0), (1, 2)):
        i1, i2 = t.pair_indices(k1, k2)
        assert np.all(t.view[i1] == k1) and np.all(t.view[i2] == k2)
        assert np.array_equal(t.cam[i1], t.cam[i2]) and np.array_equal(t.track[i1], t.track[i2])
        shared = {(c, k) for v, c, k in zip(t.view, t.cam, t.track) if v == k1}
        shared &= {(c, k) for v, c, k in zip(t.view, t.cam, t.track) if v == k2}
        assert len(i1) == len(shared)
        m = t.pair(k1, k2)
        assert np.allclose(m.f1, t.f[i1], atol=1e-15) and np.allclose(m.f2, t.f[i2], atol=1e-15)
        assert np.array_equal(m.cam, t.cam[i1])
        measured = 1 not in (k1, k2)
        assert m.has_gravity == measured
        if measured:
            assert np.array_equal(m.g1, t.g_meas[k1]) and np.array_equal(m.g2, t.g_meas[k2])
    assert len(t.pair_indices(0, 2)[0]) == M * PER - len(np.unique(a["track"][drop]))


@pytest.mark.parametrize("views", [(1, 1), (0, 3), (-1, 0), (0.0, 1.0)])
def test_pair_rejects_bad_views(rng, views):
    t = Tracks(**_arrays(rng))
    with pytest.raises(InputError, match="'view'"):
        t.pair(*views)


def test_views_subset_renumbers_in_the_given_order(rng):
    t = _multi_camera_tracks(rng)
    s = t.views_subset([2, 0])
    assert s.num_views == 2 and len(s) == np.sum(t.view != 1)
    assert np.array_equal(s.g_meas, t.g_meas[[2, 0]])
    assert np.array_equal(s.view, np.where(t.view[t.view != 1] == 2, 0, 1))
    m, m_old = s.pair(0, 1), t.pair(2, 0)
    assert np.allclose(m.f1, m_old.f1, atol=1e-15) and np.allclose(m.f2, m_old.f2, atol=1e-15)
    assert np.array_equal(m.g1, m_old.g1) and np.array_equal(m.cam, m_old.cam)
    with pytest.raises(InputError, match="'view'"):
        t.views_subset([0, 0])
    with pytest.raises(InputError, match="'view'"):
        t.views_subset([3])


def test_subset_keeps_view_numbering(rng):
    t = Tracks(**_arrays(rng))
    keep = t.track % 1000 == 7  # the first track of each camera, in all views
    s = t.subset(keep)
    assert len(s) == K * M and s.num_views == K and np.array_equal(s.view, t.view[keep])
    assert np.array_equal(t.subset(np.flatnonzero(keep)).f, s.f)
    with pytest.raises(InputError, match="'view'.*view 2"):
        t.subset(t.view < 2)  # would leave view 2 without observations
