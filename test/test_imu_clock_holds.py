"""The IMU clock offset from the rotations between holds: seconds off, where no move is on camera."""

import numpy as np
import pytest

from nrmpc_ros.core.rig import ImuMount
from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.frontend.imu_clock_holds import offset_from_turns, orientations


def recording(rng, holds=8, rate=200.0, hold_s=(1.5, 3.0), move_s=1.0):
    """Gyro samples (IMU frame = body frame) of holds joined by turns about random axes, and per hold its
    still span (s) and the body's orientation (body -> world)."""
    t, w, spans, attitude = [], [], [], [np.eye(3)]
    now, R = 0.0, np.eye(3)
    for k in range(holds):
        length = rng.uniform(*hold_s)
        n = int(length * rate)
        t.append(now + np.arange(n) / rate)
        w.append(np.zeros((n, 3)))
        spans.append((now + 0.3, now + length - 0.1))
        now += n / rate
        if k == holds - 1:
            break
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = np.radians(rng.uniform(5, 30))
        m = int(move_s * rate)
        tau = (np.arange(m) + 0.5) / m
        rate_profile = angle / move_s * 2 * np.sin(np.pi * tau) ** 2  # integrates to the angle
        t.append(now + np.arange(m) / rate)
        w.append(rate_profile[:, None] * axis)
        R = R @ exp_so3(angle * axis)
        attitude.append(R)
        now += m / rate
    return np.concatenate(t), np.concatenate(w), spans, attitude


def pairs_of(spans, attitude):
    """(span_a, span_b, R) of consecutive holds: p_a = R p_b."""
    return [(spans[k], spans[k + 1], attitude[k].T @ attitude[k + 1]) for k in range(len(spans) - 1)]


def test_the_orientation_track_is_the_ordered_product(rng):
    t = np.arange(50) / 100.0
    w = rng.normal(scale=0.5, size=(50, 3))
    C = orientations(t, w)
    step = np.eye(3)
    for k in range(1, 50):  # the reference, sample by sample
        step = step @ exp_so3(w[k - 1] * 0.01)
        np.testing.assert_allclose(C[k], step, atol=1e-12)


@pytest.mark.parametrize("offset_s", [-7.3, -2.0, 0.6, 4.25])
def test_an_imu_clock_seconds_off_is_found(rng, offset_s):
    """The IMU stamps its samples offset_s late; the offset to add comes back within its own half width, which
    is below half the holds' slack."""
    t, w, spans, attitude = recording(rng)
    w = w + rng.normal(scale=0.002, size=w.shape) + np.array([0.002, -0.001, 0.0])  # noise and bias
    found = offset_from_turns(t + offset_s, w, ImuMount(), pairs_of(spans, attitude))
    assert found is not None and found.pairs == 7
    assert abs(found.offset_s + offset_s) <= found.half_width_s < 0.5
    assert found.residual_deg < 1.0 < found.as_stamped_deg
    assert found.refutes_stamps


def test_stamps_that_agree_give_an_interval_holding_zero_and_too_little_gives_nothing(rng):
    t, w, spans, attitude = recording(rng)
    found = offset_from_turns(t, w, ImuMount(), pairs_of(spans, attitude))
    assert found is not None and abs(found.offset_s) <= found.half_width_s and not found.refutes_stamps
    assert offset_from_turns(t, w, ImuMount(), pairs_of(spans, attitude)[:2]) is None  # two pairs
    inside = ImuMount(mount="cam0")
    assert offset_from_turns(t, w, inside, pairs_of(spans, attitude)) is None  # an IMU on a bar turns with it
    wrong = [(a, b, R.T) for a, b, R in pairs_of(spans, attitude)]  # images that tell another motion
    assert offset_from_turns(t, w, ImuMount(), wrong) is None


def back_and_forth(holds=10, rate=200.0, hold_s=2.5, move_s=1.0, angle_deg=20.0, snapshot_after_s=0.5):
    """Gyro samples of a rig turning back and forth between two attitudes (20 deg about one axis), and per hold
    the stamp of a snapshot 0.5 s after its stop and the body's orientation."""
    t, w, spans, attitude = [], [], [], [np.eye(3)]
    now, R = 0.0, np.eye(3)
    axis = np.array([0.0, 0.6, 0.8])
    for k in range(holds):
        n = int(hold_s * rate)
        t.append(now + np.arange(n) / rate)
        w.append(np.zeros((n, 3)))
        spans.append((now + snapshot_after_s, now + snapshot_after_s))
        now += n / rate
        if k == holds - 1:
            break
        angle = np.radians(angle_deg) * (1.0 if k % 2 == 0 else -1.0)
        m = int(move_s * rate)
        tau = (np.arange(m) + 0.5) / m
        t.append(now + np.arange(m) / rate)
        w.append((angle / move_s * 2 * np.sin(np.pi * tau) ** 2)[:, None] * axis)
        R = R @ exp_so3(angle * axis)
        attitude.append(R)
        now += m / rate
    return np.concatenate(t), np.concatenate(w), spans, attitude


def test_a_rig_turning_back_and_forth_agrees_as_stamped_and_no_offset_is_found():
    """Between two attitudes in turn, the pairs of the middle holds agree as stamped and again at a shift of two
    holds (7 s) either way, over as wide a run of lags: the stamps as they are win (an interval holding zero),
    not the first of the equal runs (an offset of 6 s whose interval excludes zero)."""
    t, w, spans, attitude = back_and_forth()
    found = offset_from_turns(t, w, ImuMount(), pairs_of(spans, attitude)[3:6])
    assert found is not None and found.as_stamped_deg < 0.1
    assert abs(found.offset_s) <= found.half_width_s < 1.5


@pytest.mark.parametrize("seed", range(20))
def test_snapshots_whose_turns_the_images_give_a_degree_off_do_not_refute_the_stamps(seed):
    """Snapshots 0.5 s after each stop, stamped right, and images whose turns between them are 0.4-1.3 deg off
    (vision alone on two cameras of one bar): a shift that ends a gyro's interval in the tail of a move can
    bring one more pair within the agreement tolerance, at the same median disagreement. Taken as an offset
    (the plateau alone decided: 3 of these 20 recordings), it moved every snapshot's IMU window into a move and
    refused every hold of a recording. No such lag refutes the stamps."""
    rng = np.random.default_rng(seed)
    t, w, spans, attitude = recording(rng, holds=6, hold_s=(2.5, 2.5))
    snapshots = [(a + 0.2, a + 0.2) for a, _ in spans]  # the still spans start 0.3 s after the stop
    pairs = []
    for a, b, R in pairs_of(snapshots, attitude):
        axis = rng.normal(size=3)
        pairs.append((a, b, R @ exp_so3(np.radians(rng.uniform(0.4, 1.3)) * axis / np.linalg.norm(axis))))
    found = offset_from_turns(t, w, ImuMount(), pairs)
    assert found is None or not found.refutes_stamps
