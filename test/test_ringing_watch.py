"""The image path's shape tells a ringing bar from a move, across bar frequencies, camera rates and stamp jitter."""

import math

import numpy as np
import pytest

from nrmpc_ros.frontend.ringing_watch import KEPT_SHARE, RINGING_SHARE, RingingWatch

# (bar Hz, camera Hz): soft and stiff bars, slow and fast cameras
CASES = [(1.5, 5.0), (1.5, 30.0), (3.0, 10.0), (4.3, 15.0), (8.0, 30.0), (8.0, 60.0)]


def _feed(watch, t, xy, cam=0):
    """The path's points as the tracker gives them: shifts between consecutive images."""
    prev = None
    for tk, p in zip(t, xy):
        watch.add(cam, float(tk), (0.0, 0.0) if prev is None else p - prev, False)
        prev = p


def _ringing(t, f, zeta, amp_px, rest, rng):
    w = 2.0 * math.pi * f
    ph = rng.uniform(0.0, 2.0 * math.pi, 2)
    e = amp_px * np.exp(-zeta * w * t)
    return rest + np.stack([e * np.cos(w * t + ph[0]), 0.6 * e * np.sin(w * t + ph[1])], axis=1)


def _times(rate, seconds, jitter_s, rng):
    t = np.arange(0.0, seconds, 1.0 / rate)
    return t, t + rng.uniform(-jitter_s, jitter_s, len(t))  # (when the image was taken, its stamp)


@pytest.mark.parametrize("f,rate", CASES)
@pytest.mark.parametrize("jittered", [False, True])
def test_ringing_about_a_rest_is_no_move_and_gives_the_rest(f, rate, jittered):
    """Stamps jittered by up to 8 ms (software synchronisation), or a fiftieth of the bar's period where that is
    less (an 8 Hz bar moves by 40 % of its swing in 8 ms: that is not ringing one can tell from a move)."""
    rng = np.random.default_rng(int(10 * f + rate + jittered))
    rest = np.array([3.0, -2.0])
    jitter_s = min(8e-3, 0.02 / f) if jittered else 0.0
    for amp in (3.0, 40.0):  # a few pixels, and a soft bar's tens of pixels
        taken, stamped = _times(rate, 2.0, jitter_s, rng)
        xy = _ringing(taken, f * 1.1, 0.03, amp, rest, rng) + rng.normal(0.0, 0.02, (len(taken), 2))
        watch = RingingWatch([f], 0.03)  # the rig file's frequency 10 % off the bar's
        _feed(watch, stamped, xy)
        v = watch.judge(0)
        assert v.rings is True and v.share <= RINGING_SHARE, (amp, v.share)
        # the path starts at the first image: its rest there is rest - xy[0]
        assert np.linalg.norm(v.rest - (rest - xy[0])) <= 0.1 * amp + 0.1


@pytest.mark.parametrize("f,rate", CASES)
@pytest.mark.parametrize("kind", ["steady", "accelerating", "stopping", "starting"])
def test_a_move_is_no_ringing_even_with_ringing_on_top(f, rate, kind):
    rng = np.random.default_rng(int(10 * f + rate))
    T = max(1.25 / f, 8.0 / rate) + 2.0 / rate  # the watch's window, and a frame to spare
    t = np.arange(0.0, T, 1.0 / rate)
    s = t / t[-1]
    travel = 40.0  # px over the window: a move of a few degrees
    shape = {"steady": s, "accelerating": s ** 2, "stopping": 1.0 - (1.0 - s) ** 2,
             "starting": np.maximum(s - 0.4, 0.0) ** 2 / 0.36}[kind]
    xy = travel * np.stack([shape, 0.3 * shape], axis=1)
    xy += _ringing(t, f, 0.03, 0.1 * travel, np.zeros(2), rng)  # the bar rings too, by a tenth of the move
    watch = RingingWatch([f], 0.03)
    _feed(watch, t, xy)
    v = watch.judge(0)
    assert v.rings is False and v.share > RINGING_SHARE, v.share
    if kind != "starting":  # a move under way is out of the looser bound an open hold keeps
        assert v.share > KEPT_SHARE and v.kept() is False


@pytest.mark.parametrize("f,rate", [(8.0, 15.0), (8.0, 5.0), (4.3, 10.0), (3.0, 5.0)])
def test_a_camera_too_slow_for_the_bar_judges_by_the_aliases_that_swing(f, rate):
    """Sampled below twice the bar's frequency, a ringing shows at its alias: the frequencies whose alias makes a
    cycle over the window tell it from a steady move, which is never taken for ringing; a ringing is."""
    rng = np.random.default_rng(int(10 * f + rate))
    t = np.arange(0.0, 3.0, 1.0 / rate)
    watch = RingingWatch([f], 0.03)
    _feed(watch, t, np.stack([10.0 * t, 3.0 * t], axis=1))
    assert watch.judge(0).rings is not True
    watch = RingingWatch([f], 0.03)
    xy = _ringing(t, f, 0.03, 8.0, np.array([3.0, -2.0]), rng)
    _feed(watch, t, xy)
    v = watch.judge(0)
    assert v.rings is True and np.linalg.norm(v.rest - ([3.0, -2.0] - xy[0])) < 0.1, v  # the path starts at 0


def test_no_verdict_before_a_window_on_rigid_bars_or_after_lost_tracks():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 2.0, 1.0 / 30.0)
    xy = _ringing(t, 2.0, 0.03, 10.0, np.zeros(2), rng)
    watch = RingingWatch([2.0, math.inf], 0.03)
    _feed(watch, t[:10], xy[:10])  # a third of a second: less than 1.25 periods
    early = watch.judge(0)
    assert early.rings is None and early.rest is None and math.isnan(early.share)
    _feed(watch, t[10:], xy[10:])
    assert watch.judge(0).rings is True
    _feed(watch, t, xy, cam=1)  # a rigid camera never rings
    assert watch.judge(1).rings is None
    watch.add(0, 2.5, (0.0, 0.0), True)  # tracks lost: the path starts again
    assert watch.judge(0).rings is None
    _feed(watch, t + 3.0, xy)
    assert watch.judge(0).rings is True
    watch.reset()  # a gap in the stream: every path starts again
    assert watch.judge(0).rings is None
