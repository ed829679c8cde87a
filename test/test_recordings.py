"""Every recording style on 2-, 3- (one fisheye) and 4-camera rigs: every hold after the first gets an
estimate, none is stamped outside a hold; holds settle and average; with an IMU the estimate beats it."""

import math

import numpy as np
import pytest
from recordings import RIGS, STYLES, recording

from nrmpc_ros.bag.reader import BagReader
from nrmpc_ros.core import load_rig
from nrmpc_ros.frontend.estimates_csv import row_from_estimate
from nrmpc_ros.frontend.evaluation import evaluate
from nrmpc_ros.frontend.pipeline import Pipeline, PipelineConfig
from nrmpc_ros.frontend.reference import read_reference
from nrmpc_ros.frontend.replay import replay_bag, resolve_imu_topic

pytestmark = pytest.mark.slow  # every test here renders bags


def replay(path, rig_file, method="auto"):
    rig = load_rig(rig_file)
    with BagReader(path) as bag:
        imu_topic = resolve_imu_topic(bag, rig, warn=lambda m: None)
        pipe = Pipeline(rig, PipelineConfig(), method=method)
        ests = [e for es in replay_bag(bag, rig, pipe, imu_topic, warn=lambda m: None) for e in es]
        ref = read_reference(bag, imu_topic)
    return pipe, ests, evaluate([row_from_estimate(e) for e in ests], ref, rig)


@pytest.mark.parametrize("style", sorted(STYLES))
@pytest.mark.parametrize("rig_name", RIGS)
def test_every_hold_gets_an_estimate_inside_it(recordings_dir, rig_name, style):
    path, rig_file, summary = recording(recordings_dir, rig_name, style)
    pipe, ests, ev = replay(path, rig_file)
    holds = len(summary["holds"]) if summary else ev.holds
    assert ev.holds == holds == STYLES[style][0]["views"]
    assert ev.holds_with_estimate == holds - 1, pipe.stats.dropped
    assert ev.outside_holds == 0
    assert pipe.stats.holds == holds
    for e in ests:  # an estimate's stamp is a frame of the hold's frames used; what may still ring is its noise
        assert e.hold.settled_start <= e.stamp <= e.hold.settled_end
        assert e.noise_scale >= 1.0 and e.hold.ringing_px >= 0.0
        assert (e.noise_scale > 1.0) == (e.hold.ringing_px > 0.0) or e.hold.ringing_px < 1e-3
    with_imu = STYLES[style][1].get("imu", True)
    assert {e.method for e in ests} == ({"4pt-bending"} if with_imu else {"6pt-bending"})
    if not with_imu and pipe.sequence.parallel_bars:  # vision only on one bar: a young sequence has no gravity
        assert all(e.gravity is None for e in ests)
    else:
        assert ev.stats("gravity_vs_gt_deg")["median"] < (1.0 if with_imu else 15.0)
    assert ev.stats("rotation_deg")["median"] < 0.5


def test_streamed_holds_are_averaged_and_ringing_is_waited_out(recordings_dir):
    """A 10 Hz stream: each hold's settled part averages many frames (the averaged noise is the frame noise over
    the root of their number); with ringing bars the settled part starts later than without."""
    path, rig_file, _ = recording(recordings_dir, "cross4", "stream-smooth")
    calm, _, _ = replay(path, rig_file)
    path, rig_file, summary = recording(recordings_dir, "cross4", "stream-ringing")
    ringing, _, _ = replay(path, rig_file)
    for st in (calm.stats, ringing.stats):
        frames = np.array(st.settled_frames)
        assert np.all(frames >= 3)
        ratio = np.array(st.noise_px) / np.array(st.averaged_noise_px)
        assert np.allclose(ratio, np.sqrt(frames), rtol=0.5)
    # the holds after a move (the first hold starts the bag: nothing rings there)
    assert max(ringing.stats.settle_s[1:]) > max(calm.stats.settle_s[1:]) + 0.5
    d = ringing.stats.as_dict()
    assert d["median_residual_px"] < 0.2


def test_vision_only_on_a_bag_with_an_imu(recordings_dir):
    """6pt-bending ignores the IMU's gravity but still finds every hold (the IMU still tells when it is still)."""
    path, rig_file, _ = recording(recordings_dir, "cross4", "snapshot-imu")
    pipe, ests, ev = replay(path, rig_file, method="6pt-bending")
    assert {e.method for e in ests} == {"6pt-bending"} and ev.holds_with_estimate == ev.holds - 1
    assert all(e.gravity is not None and math.isfinite(e.gravity_sigma_deg) for e in ests)
