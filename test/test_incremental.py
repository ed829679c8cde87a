"""The joint estimate view by view (core.incremental.IncrementalSequence): a sliding window that keeps what the
retired views said about gravity, new sequences where no landmark links, resets, and the batch solve."""

import math

import numpy as np
import pytest

from nrmpc_ros.core.incremental import IncrementalSequence
from nrmpc_ros.core.so3 import angle_between, rotation_angle
from nrmpc_ros.sim.sequence import SequenceScenario, make_sequence
from nrmpc_ros.sim.synthetic import RigSpec

RING3 = RigSpec(num_cameras=3, layout="ring", EI=1.3)


def views(p):
    """Per view: (cam, track, f, measured gravity or None) of a simulated sequence."""
    tr = p.tracks
    for k in range(tr.num_views):
        m = tr.view == k
        g = None if tr.g_meas is None else tr.g_meas[k]
        yield tr.cam[m], tr.track[m], tr.f[m], g


def feed(seq, p, sigma=None):
    return [seq.add_view(c, t, f, g, sigma) for c, t, f, g in views(p)]


@pytest.fixture(scope="module")
def noisy():
    sc = SequenceScenario(rig=RING3, num_views=14, pixel_noise=0.3, outlier_fraction=0.05)
    return make_sequence(sc, seed=4)


def test_noise_free_views_are_exact_through_the_window():
    p = make_sequence(SequenceScenario(rig=RING3, num_views=7, pixel_noise=0.0, outlier_fraction=0.0), seed=1)
    seq = IncrementalSequence(p.rig, "6pt-bending", window=4)
    out = feed(seq, p)
    assert isinstance(out[0], str) and "origin" in out[0]
    for k, v in enumerate(out[1:], start=1):
        assert v.view == k and v.sequence == 0 and v.window <= 4
        assert rotation_angle(p.R[k].T @ v.R) < 1e-6 and np.linalg.norm(v.t - p.t[k]) < 1e-6
        assert float(angle_between(v.gravity, p.gravity[k])) < 1e-6


def test_window_keeps_the_information_of_retired_views(noisy):
    """A window of 4 over 14 views ends about as well as adjusting all views at once, and both well inside
    the reported std; the per-view std shrinks as views come in."""
    p = noisy
    seq = IncrementalSequence(p.rig, "6pt-bending", window=4)
    out = [v for v in feed(seq, p) if not isinstance(v, str)]
    assert len(out) == 13 and max(v.window for v in out) == 4
    last = out[-1]
    err = math.degrees(float(angle_between(last.gravity, p.gravity[-1])))
    sig = math.degrees(last.gravity_sigma_rad)
    assert sig < math.degrees(out[0].gravity_sigma_rad) / 2
    assert err < 4 * sig + 0.05, (err, sig)
    batch = seq.batch()
    assert batch.success and batch.R.shape == (14, 3, 3)
    errb = math.degrees(float(angle_between(batch.gravity[-1], p.gravity[-1])))
    assert errb < 4 * math.degrees(batch.gravity_sigma_rad[-1]) + 0.05
    assert abs(err - errb) < 3 * sig + 0.05


def test_measured_gravity_enters_as_priors(noisy):
    p = make_sequence(SequenceScenario(rig=RING3, num_views=6, pixel_noise=0.3, gravity_noise_deg=0.2), seed=2)
    vision = [v for v in feed(IncrementalSequence(p.rig, "6pt-bending"), p) if not isinstance(v, str)]
    imu = [v for v in feed(IncrementalSequence(p.rig, "4pt-bending"), p, math.radians(0.2)) if not isinstance(v, str)]
    assert {v.method for v in imu} == {"4pt-bending"}
    assert imu[-1].gravity_sigma_rad < vision[-1].gravity_sigma_rad


def test_a_view_without_shared_landmarks_starts_a_new_sequence_and_reset_does_too(noisy):
    p = noisy
    seq = IncrementalSequence(p.rig, "6pt-bending", keep_history=True)
    items = list(views(p))
    for c, t, f, g in items[:4]:
        seq.add_view(c, t, f, g)
    c, t, f, g = items[4]
    out = seq.add_view(c, t + 10**6, f, g)  # landmark ids nobody has seen
    assert isinstance(out, str) and out.startswith("new sequence")
    assert seq.seq.number == 1 and seq.num_views == 1
    seq.reset()
    assert seq.seq.number == 2 and seq.num_views == 0
    recs = seq.sequences()
    assert [r.tracks.num_views for r in recs] == [4]
    assert recs[0].R.shape == (4, 3, 3) and recs[0].gravity.shape == (3,)


def test_bad_window():
    with pytest.raises(ValueError, match="window"):
        IncrementalSequence(make_sequence(SequenceScenario(rig=RING3, num_views=2), seed=0).rig, window=1)


def test_settled_views_are_placed_by_resection(noisy, monkeypatch):
    """Past the young views a new view is placed on the window's landmarks, not by a two-view estimate, and
    ends as close to the truth as with the two-view estimates."""
    import nrmpc_ros.core.incremental as incremental

    calls = []
    real = incremental.estimate
    monkeypatch.setattr(incremental, "estimate", lambda *a, **k: calls.append(1) or real(*a, **k))
    p = noisy
    errs = {}
    for resect in (False, True):
        calls.clear()
        seq = IncrementalSequence(p.rig, "6pt-bending", {"resect_views": resect}, window=10, seed=0)
        last = feed(seq, p)[-1]
        errs[resect] = (math.degrees(float(angle_between(last.gravity, p.gravity[-1]))),
                        math.degrees(last.gravity_sigma_rad), len(calls))
    assert errs[False][2] == p.tracks.num_views - 1
    assert errs[True][2] <= 6, errs  # the young views, and a view resection could not place
    for err, sig, _ in errs.values():
        assert err < 4 * sig + 0.05, errs
