"""An IMU clock seconds off the cameras', measured from a whole recording and applied by ``nrmpc replay``: on a
stream from the moves (the far search), on holds from the rotations between them; a right clock is left alone."""

import math

import numpy as np
import pytest
from recordings import recording

from nrmpc_ros.cli.main import main
from nrmpc_ros.frontend.replay import collect_sequences, resolve_imu_topic

pytestmark = pytest.mark.slow  # renders bags


def _replay(path, rig_file, out, capsys, *flags):
    assert main(["replay", str(path), "--rig", str(rig_file), "--out", str(out), "--no-progress", "--quiet",
                 *flags]) == 0
    return capsys.readouterr().out


def _medians(text):
    return [float(ln.split("median")[1].split()[0]) for ln in text.splitlines()
            if ln.strip().startswith("gravity vs ground truth")]


@pytest.mark.parametrize("rig_name", ["fish3", "cross4"])
def test_a_stream_with_the_imu_2_s_late_is_measured_and_replayed_with_it(recordings_dir, tmp_path, capsys,
                                                                          rig_name):
    """The IMU stamped 2 s late: as stamped, the holds' IMU windows are another moment's, holds are lost and the
    gravities wrong. Replay measures the offset from the moves (each camera's image rate against the gyro's
    prediction), says so, and replays with it: every hold estimated, every gravity within a tenth of a degree."""
    path, rig_file, _ = recording(recordings_dir, rig_name, "imu-clock-2s")
    as_stamped = _replay(path, rig_file, tmp_path / "a.csv", capsys, "--imu-clock-offset", "0")
    assert "replaying with" not in as_stamped
    line = next(ln for ln in as_stamped.splitlines() if "IMU clock against the cameras (the gyro's rate" in ln)
    assert "replay with --imu-clock-offset -2.0" in line or "replay with --imu-clock-offset -1.9" in line, line
    text = _replay(path, rig_file, tmp_path / "b.csv", capsys)
    line = next(ln for ln in text.splitlines() if "replaying with --imu-clock-offset" in ln)
    offset = float(line.split("replaying with --imu-clock-offset ")[1].split()[0])
    assert offset == pytest.approx(-2.0, abs=0.05)
    assert "with an estimate (after the first): 5/5" in text
    assert max(_medians(text)) < 0.1
    assert "refuted" not in text


def test_a_right_clock_is_left_alone(recordings_dir, tmp_path, capsys):
    path, rig_file, _ = recording(recordings_dir, "cross4", "stream-smooth")
    text = _replay(path, rig_file, tmp_path / "a.csv", capsys)
    assert "replaying with" not in text and "another moment's" not in text
    assert all(math.isfinite(m) for m in _medians(text))


def test_a_running_pipeline_measures_the_clock_once_the_images_refute_the_imu(recordings_dir):
    """What the node can do while it runs: once the images refute the IMU's gravity, the frame stage measures
    the clock from the moves it has seen (the node's IMU diagnostics show it with the setting to change)."""
    from nrmpc_ros.bag.reader import BagReader
    from nrmpc_ros.core import load_rig
    from nrmpc_ros.frontend.imu_clock_check import ClockEvidence
    from nrmpc_ros.frontend.pipeline import Pipeline, PipelineConfig
    from nrmpc_ros.frontend.replay import replay_bag, resolve_imu_topic

    path, rig_file, _ = recording(recordings_dir, "cross4", "imu-clock-2s")
    rig = load_rig(rig_file)
    with BagReader(path) as bag:
        pipe = Pipeline(rig, PipelineConfig())
        for _ in replay_bag(bag, rig, pipe, resolve_imu_topic(bag, rig, warn=lambda m: None), warn=lambda m: None):
            pass
    assert pipe.estimator.imu_check.refuted >= 1
    clock = pipe.imu_clock_off
    assert clock is not None and clock.source is ClockEvidence.MOVES
    assert clock.offset_s == pytest.approx(-2.0, abs=0.05)


def test_bar_calibration_from_a_stream_with_the_imu_2_s_late(recordings_dir):
    """nrmpc calibrate-bars reads the holds' IMU gravities: 2 s off, they are another moment's. The moves'
    offset is applied as replay applies it, and every bar's compliance comes out at the rig file's truth."""
    from nrmpc_ros.calibration import calibrate_sequences
    from nrmpc_ros.core import load_rig

    path, rig_file, _ = recording(recordings_dir, "cross4", "imu-clock-2s")
    rig = load_rig(rig_file)
    said = []
    result = calibrate_sequences(rig, collect_sequences(path, rig, warn=said.append))
    assert any("replaying with that offset" in line for line in said)
    truth = rig.compliance
    assert result.compliance == pytest.approx(truth, rel=0.05), (result.compliance, truth)


def _node_on(path, rig, measured: bool):
    """The node's service fed a recording message by message (bag time as now), each message's work and its
    holds' estimates run before the next arrives (a node that keeps up): (estimates, service, its log)."""
    from nrmpc_ros.bag.reader import BagReader
    from nrmpc_ros.frontend.feeder import FeederConfig
    from nrmpc_ros.frontend.node_config import NodeConfig
    from nrmpc_ros.frontend.pipeline import PipelineConfig
    from nrmpc_ros.frontend.service import EstimatorService
    from nrmpc_ros.frontend.topics import bag_image_topics

    out, logs = [], []
    with BagReader(path) as bag:
        cameras, imu = [t.topic for t in bag_image_topics(bag, rig)], resolve_imu_topic(bag, rig, warn=lambda m: None)
    s = EstimatorService(rig, NodeConfig(work_queue_size=100000, input=FeederConfig(imu_clock_measured=measured)),
                         PipelineConfig(), cameras, imu, out.append, lambda lv, ln: logs.append(ln))

    def run():
        while len(s.queue):
            s.work_once()
            while s.estimate_once() is not None:
                pass

    with BagReader(path) as bag:
        for topic, t_ns, msg in bag.messages(cameras + [imu]):
            if topic == imu:
                s.on_imu(msg, t_ns * 1e-9)
            else:
                s.on_image(cameras.index(topic), msg, t_ns * 1e-9)
            run()
    s.feeder.end()
    run()
    return [o.estimate for o in out], s, logs


def test_a_running_node_applies_the_clock_it_measures_and_its_later_holds_are_right(recordings_dir):
    """The node cannot replay: once its frame stage measures the IMU 2 s late (the images having refuted the
    IMU's gravity), it adds the offset to the IMU's stamps from then on and starts a new sequence; every hold
    after that is estimated within a fifth of a degree and 3 of its stds (the new sequence's first hold has
    two holds' norms to grade the accelerometer's tilt by: a std of 0.24 deg). Told not to
    (input.imu_clock_measured false), it only shows the measurement, and the same holds stay wrong or refused."""
    from nrmpc_ros.bag.reader import BagReader
    from nrmpc_ros.core import load_rig
    from nrmpc_ros.core.so3 import angle_between
    from nrmpc_ros.frontend.reference import read_reference

    path, rig_file, _ = recording(recordings_dir, "cross4", "imu-clock-2s")
    rig = load_rig(rig_file)
    with BagReader(path) as bag:
        ref = read_reference(bag, resolve_imu_topic(bag, rig, warn=lambda m: None))

    def error_deg(e):
        k = int(np.searchsorted(ref.grav_t, e.stamp, side="right")) - 1
        return math.degrees(float(angle_between(e.gravity, ref.grav_g[k])))

    got, s, logs = _node_on(path, rig, True)
    assert s.feeder.config.imu_clock_offset_s == pytest.approx(-2.0, abs=0.05)
    assert s.counts["IMU clock offsets applied"] == 1
    assert any("added to the IMU's stamps from now on" in line for line in logs)
    assert "applied" in s.diagnostics()[1].values["clock offset"]
    later = [e for e in got if e.sequence == max(x.sequence for x in got)]
    assert len(later) >= 2 and all(error_deg(e) < min(0.2, 3 * e.gravity_sigma_deg) for e in later)
    kept, s0, _ = _node_on(path, rig, False)
    assert s0.feeder.config.imu_clock_offset_s == 0.0 and "clock check" in s0.diagnostics()[1].values
    since = min(e.stamp for e in later)
    same = [e for e in kept if e.stamp >= since]
    assert len(same) < len(later) or max(error_deg(e) for e in same) > 1.0


def test_a_running_node_leaves_a_right_clock_alone(recordings_dir):
    from nrmpc_ros.core import load_rig

    path, rig_file, _ = recording(recordings_dir, "cross4", "stream-smooth")
    got, s, _ = _node_on(path, load_rig(rig_file), True)
    assert len(got) >= 2 and s.counts["IMU clock offsets applied"] == 0
    assert s.feeder.config.imu_clock_offset_s == 0.0 and "clock offset" not in s.diagnostics()[1].values


def test_a_gyro_bias_is_no_clock_offset(tmp_path, capsys):
    """Snapshots of a rig whose gyro is 0.56 deg/s off (a MEMS gyro nobody calibrated): integrated from hold to
    hold the bias turned the gyro's rotations by degrees off the images', and a shift of 1.9 s happened to agree
    better: the replay moved the IMU there and lost half the holds. The rotations are integrated with the bias the
    stillness test measured taken out: the stamps agree, nothing is moved, every hold is estimated."""
    bag, rig = tmp_path / "bias", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(bag), "--save-rig", str(rig), "--resolution", "320x240", "--supersample",
                 "1", "--cameras", "4", "--views", "5", "--capture", "snapshot", "--snapshot-delay", "0.65",
                 "--hold-seconds-range", "1.5,3.2", "--imu-rate", "100", "--gyro-bias", "0.0098", "--gyro-noise",
                 "0.005", "--imu-noise", "0.07", "--damping", "0.11", "--camera-rates", "12,15,5,15",
                 "--camera-phases-ms", "15,19,128,46", "--speed", "57", "--move-profile", "trapezoid",
                 "--min-move-seconds", "1.23", "--seed", "309", "--no-progress"]) == 0
    capsys.readouterr()
    text = _replay(bag, rig, tmp_path / "a.csv", capsys)
    assert "replaying with" not in text, text
    assert "with an estimate (after the first): 4/4" in text, text
