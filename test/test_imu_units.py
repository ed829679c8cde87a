"""The gyro's unit from the moves the images show: rad/s (REP 103) or a driver's deg/s, measured, replayed with
and applied by the running node."""

import math

import numpy as np
import pytest
from test_imu_clock import _rendered_rates, _ring3

from nrmpc_ros.frontend.imu_units import DEGREE, GyroEvidence, gyro_units, gyro_units_from_turns


def _stiff_ring3():
    """Three cameras on 8 Hz bars that ring (damping 0.04)."""
    import dataclasses

    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=2.3, mass=0.1, bar_length=0.3))
    return dataclasses.replace(rig, cameras=tuple(dataclasses.replace(c, damping=0.04) for c in rig.cameras))


@pytest.mark.parametrize("seed", [2, 3])
@pytest.mark.parametrize("rig", [_stiff_ring3, _ring3])
def test_a_gyro_in_rad_s_reads_rad_s_and_one_in_deg_s_reads_deg_s(seed, rig):
    """The same rendered moves (ringing bars, MEMS noise), the gyro written in rad/s and in deg/s: the images'
    motion over the gyro's prediction is about 1 (the bars' swing added: up to a few) and 1/57.3 of that, every
    resample of the moves agreeing. Bars that ring in the holds as fast as the moves turn the images (2.6 Hz) give
    no verdict, never a wrong one."""
    rad = gyro_units(_rendered_rates(rig(), 0.0, seed=seed))
    deg = gyro_units(_rendered_rates(rig(), 0.0, seed=seed, gyro_unit=DEGREE))
    if rig is _ring3 and (rad is None or deg is None):
        assert (rad is None or not rad.in_degrees) and (deg is None or deg.in_degrees)
        return
    assert rad is not None and deg is not None
    assert 0.5 < rad.ratio < 4.0 and not rad.in_degrees and rad.confidence == 0.0, rad
    assert deg.ratio / DEGREE == pytest.approx(rad.ratio, rel=0.05) and deg.in_degrees and deg.confidence == 1.0, deg
    assert deg.moves == rad.moves >= 3 and deg.frames == rad.frames


def test_a_clock_seconds_off_does_not_read_as_deg_s():
    """The IMU's stamps 1.3-9 s late, in rad/s: the images do not move where the gyro does (their own moves fall
    among the gyro's still frames), so no verdict, where the holds' still images against the moves' rates would
    have read deg/s."""
    for late_s in (1.3, 9.0):
        assert gyro_units(_rendered_rates(_stiff_ring3(), late_s, views=8)) is None


def test_cameras_that_record_only_the_holds_give_no_verdict():
    """No move inside the frames (the cameras skip the moves): nothing to compare the gyro's size with."""
    assert gyro_units(_rendered_rates(_stiff_ring3(), 0.0, capture="holds", gyro_unit=DEGREE)) is None


@pytest.fixture(scope="module")
def deg_bag(tmp_path_factory):
    """A stream with the gyro written in deg/s (a driver that breaks REP 103), and its rig file."""
    from nrmpc_ros.cli.main import main

    d = tmp_path_factory.mktemp("degs")
    assert main(["make-bag", "--out", str(d / "degs"), "--save-rig", str(d / "rig.yaml"), "--resolution",
                 "320x240", "--supersample", "1", "--cameras", "4", "--rate", "15", "--capture", "stream",
                 "--bar-hz", "3", "--damping", "0.03", "--views", "9", "--seed", "11", "--gyro-unit", "deg/s",
                 "--no-progress"]) == 0
    return d / "degs", d / "rig.yaml"


@pytest.mark.slow
def test_replay_measures_a_gyro_in_deg_s_and_replays_with_its_scale(deg_bag, tmp_path, capsys):
    """In deg/s every rate is 57 times its size. Replay measures the unit from the moves, says so, and replays
    with --imu-gyro-scale pi/180: every hold is estimated, within 0.2 deg of the truth; --imu-gyro-scale 1 keeps
    the rates as they are (and measures nothing)."""
    from nrmpc_ros.cli.main import main

    path, rig_file = deg_bag
    assert main(["replay", str(path), "--rig", str(rig_file), "--out", str(tmp_path / "x.csv"),
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    said = [ln for ln in text.splitlines() if ln.startswith("IMU units:")]
    assert len(said) == 1 and "the gyro reads deg/s" in said[0], text
    assert "--imu-gyro-scale 0.01745329 --imu-accel-scale 1 " in said[0] and "accelerometer" not in said[0]
    assert "with an estimate (after the first): 8/8" in text, text
    medians = [float(ln.split("median")[1].split()[0]) for ln in text.splitlines()
               if ln.strip().startswith("gravity vs ground truth")]
    assert medians and max(medians) < 0.2
    assert main(["replay", str(path), "--rig", str(rig_file), "--out", str(tmp_path / "y.csv"), "--no-progress",
                 "--imu-gyro-scale", "1"]) == 0
    kept = capsys.readouterr().out
    assert "IMU units:" not in kept and "IMU gyro units:" not in kept  # the scale given: nothing measured


@pytest.mark.slow
def test_the_running_node_measures_a_gyro_in_deg_s_and_applies_its_scale(deg_bag):
    """The node, fed as it runs: once the holds ended have three moves between them it asks the moves, finds the
    gyro in deg/s, multiplies its rates by pi/180 from then on (one new sequence, said once, in the IMU
    diagnostics), and the holds after the restart's first are estimated, each within 3 of its std of the truth."""
    from test_service import live_service, within_3_std_of_the_truth

    path, rig_file = deg_bag
    s, ests, logs = live_service(path, rig_file)
    assert s.counts["IMU units applied"] == 1 and s.feeder.config.imu_gyro_scale == pytest.approx(DEGREE)
    assert s.feeder.config.imu_accel_scale == 1.0
    said = [line for line in logs if "the gyro reads deg/s" in line]
    assert len(said) == 1 and "a new sequence" in said[0]
    assert "0.01745329" in s.diagnostics()[1].values["units"] and "measured and applied" in s.diagnostics()[1].values[
        "units"]
    assert len(ests) >= 4
    within_3_std_of_the_truth(path, ests)


@pytest.mark.parametrize("rate_hz, density_deg, in_degrees, said", [
    (200.0, 0.01, False, False), (1000.0, 0.1, False, False), (50.0, 0.1, False, False),  # rad/s, up to the worst
    (200.0, 0.125, False, False),  # rad/s, a quarter beyond the worst (a vibrating mount): no deg/s reads so little
    (200.0, 0.01, True, True), (1000.0, 0.01, True, True), (50.0, 0.003, True, True),  # deg/s, down to the best
])
def test_a_gyro_noise_no_mems_gyro_has_is_said_as_deg_s(rate_hz, density_deg, in_degrees, said):
    """Where the moves are off camera the gyro's white noise at rest is the hint: a MEMS gyro of 0.003-0.1
    deg/s/sqrt(Hz) at 50-1000 Hz in rad/s is never said; the same in deg/s always is (what the covariances claim
    plays no part)."""
    from nrmpc_ros.frontend.imu_units import describe_gyro_noise
    from nrmpc_ros.frontend.zupt import ImuNoise

    sigma = DEGREE * density_deg * (rate_hz / 2.0) ** 0.5 / (DEGREE if in_degrees else 1.0)
    noise = ImuNoise(0.02, 10.0 * sigma, period_s=1.0 / rate_hz, white=(0.02, sigma))
    text = describe_gyro_noise(noise)
    assert (text is not None) == said, (sigma, text)
    assert not said or ("deg/s" in text and "--imu-gyro-scale 0.0174533" in text)


@pytest.mark.slow
def test_replay_reads_a_gyro_in_deg_s_where_the_cameras_skip_the_moves_from_its_noise(tmp_path, capsys):
    """Cameras that record only three holds: no move on camera and two turns between holds, too few to measure the
    unit with. The gyro's noise is beyond any MEMS gyro's, and read as deg/s the recording gives more estimates:
    replay says both and keeps that pass (every hold estimated; as written one of two)."""
    text = _replayed_holds(tmp_path, capsys, "--gyro-unit", "deg/s", "--views", "3")
    said = [ln for ln in text.splitlines() if ln.startswith("IMU units:")]
    assert len(said) == 1 and "noise at rest is" in said[0] and "gave 3 estimates where the rates as written gave 2" \
        in said[0] and "--imu-gyro-scale 0.01745329" in said[0], text
    assert "IMU gyro units:" not in text and "with an estimate (after the first): 2/2" in text, text


@pytest.mark.slow
def test_replay_reads_a_gyro_in_deg_s_on_a_ringing_mount_from_its_noise_and_the_holds_it_gives(tmp_path, capsys):
    """The IMU inside a camera on a ringing bar, its gyro in deg/s and its accelerometer in g, cameras that record
    only the holds: the ringing read 57 times too large keeps every hold from reading still, so no turn between
    holds measures the unit and no move is on camera. The gyro's noise at rest is beyond any MEMS gyro's and,
    read as deg/s, the recording gives its holds: replay says so and keeps that pass."""
    text = _replayed_holds(tmp_path, capsys, "--gyro-unit", "deg/s", "--accel-unit", "g", "--imu-in-camera", "cam1",
                           "--damping", "0.04", "--bar-hz", "2.5", "--imu-rate", "1000", "--views", "5")
    said = [ln for ln in text.splitlines() if ln.startswith("IMU units:") and "deg/s" in ln]
    assert len(said) == 1 and "times the noisiest MEMS gyro's" in said[0], text
    assert "--imu-gyro-scale 0.01745329 --imu-accel-scale 9.80665" in said[0]
    assert "with an estimate (after the first): 4/4" in text and "IMU gyro units:" not in text, text


@pytest.mark.slow
def test_replay_measures_an_accelerometer_in_g_and_replays_with_its_scale(tmp_path, capsys):
    """An accelerometer in g reads 1 at rest: the holds stand (directions) but the bars' loads are a tenth of
    their size. Replay says so and replays with --imu-accel-scale 9.80665: the same holds, and the still norm
    then agrees with the rig's gravity (no 'IMU scale:' line)."""
    text = _replayed_holds(tmp_path, capsys, "--accel-unit", "g")
    said = [ln for ln in text.splitlines() if ln.startswith("IMU units:")]
    assert len(said) == 1 and "the accelerometer reads g: 0.99" in said[0] and "deg/s" not in said[0], said
    assert "--imu-gyro-scale 1 --imu-accel-scale 9.80665" in said[0]
    assert "IMU scale:" not in text and "with an estimate (after the first): 3/3" in text, text


def _replayed_holds(tmp_path, capsys, *units) -> str:
    """What nrmpc replay prints of a small holds recording (4 holds of 1 s, cameras off in the moves) whose IMU
    make-bag wrote in ``units``."""
    from nrmpc_ros.cli.main import main

    path, rig_file = tmp_path / "holds", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(path), "--save-rig", str(rig_file), "--resolution", "160x120",
                 "--supersample", "1", "--capture", "holds", "--views", "4", "--hold-seconds", "1", "--seed", "25",
                 *units, "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["replay", str(path), "--rig", str(rig_file), "--out", str(tmp_path / "x.csv"),
                 "--no-progress"]) == 0
    return capsys.readouterr().out


def _turns(images_deg, read_deg, before_ok=True):
    """What a pipeline collected of the turns between holds: the images' angle and the gyro's as read (deg)."""
    from types import SimpleNamespace

    from nrmpc_ros.core.so3 import exp_so3
    from nrmpc_ros.frontend.gyro import GyroRotation

    images = [(k, k + 1, exp_so3(np.array([0.0, 0.0, math.radians(a)]))) for k, a in enumerate(images_deg)]
    gyro = {k + 1: (k if before_ok else k - 1, GyroRotation(np.eye(3), 0.0, 2, math.radians(r)))
            for k, r in enumerate(read_deg)}
    from nrmpc_ros.frontend.pipeline import Pipeline

    collected = SimpleNamespace(images_turns=images, gyro_turns=gyro)
    collected.turns_between_holds = lambda: Pipeline.turns_between_holds(collected)
    return collected


@pytest.mark.parametrize("seed", range(4))
def test_the_turns_between_holds_read_a_gyro_in_rad_s_and_one_in_deg_s(seed):
    """Turns of 5-30 deg the images measured to a hundredth of a degree, the gyro's to 1 %: in rad/s the ratio is
    1, in deg/s 1/57.3; the verdict is the one the moves on camera give (GyroUnits, 95 % of resamples)."""
    rng = np.random.default_rng(seed)
    true = rng.uniform(5.0, 30.0, size=6)
    images = true + rng.normal(scale=0.01, size=6)
    read = true * (1 + rng.normal(scale=0.01, size=6))
    rad = gyro_units_from_turns(_turns(images, read))
    deg = gyro_units_from_turns(_turns(images, read / DEGREE))
    assert rad.evidence is GyroEvidence.TURNS_BETWEEN_HOLDS and rad.moves == 6
    assert not rad.in_degrees and rad.ratio == pytest.approx(1.0, abs=0.05)
    assert deg.in_degrees and deg.ratio == pytest.approx(DEGREE, rel=0.05)


def test_turns_that_cannot_measure_the_unit_give_no_verdict():
    """Fewer than three turns, turns under 2 deg (a gyro in rad/s taken for deg/s would shrink them to nothing
    the images see), and a gyro turn from another hold than the images' are not evidence."""
    assert gyro_units_from_turns(_turns([10.0, 20.0], [10.0, 20.0])) is None
    assert gyro_units_from_turns(_turns([1.0, 1.5, 1.9, 20.0], [57.0, 86.0, 109.0, 1146.0])) is None
    assert gyro_units_from_turns(_turns([10.0, 20.0, 15.0], [573.0, 1146.0, 859.0], before_ok=False)) is None


@pytest.mark.slow
def test_replay_measures_a_gyro_in_deg_s_from_the_turns_between_holds(tmp_path, capsys):
    """Cameras that record only the holds: no move on camera, but the holds' poses turn the rig by what the gyro
    says 57 times over. Replay measures the unit from those turns and replays with its scale: every hold
    estimated, as when told."""
    from nrmpc_ros.cli.main import main

    path, rig_file = tmp_path / "holds", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(path), "--save-rig", str(rig_file), "--resolution", "160x120",
                 "--supersample", "1", "--capture", "holds", "--views", "6", "--hold-seconds", "1", "--seed", "26",
                 "--gyro-unit", "deg/s", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["replay", str(path), "--rig", str(rig_file), "--out", str(tmp_path / "x.csv"),
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    said = [ln for ln in text.splitlines() if ln.startswith("IMU units:")]
    assert len(said) == 1 and "the gyro reads deg/s: the images turn the rig" in said[0], text
    assert "--imu-gyro-scale 0.01745329" in said[0] and "IMU gyro units:" not in text
    assert "with an estimate (after the first): 5/5" in text, text


def test_an_accelerometer_that_reads_no_gravity_at_rest_is_told_from_one_in_g():
    """A fused driver's linear acceleration (gravity taken out) reads its noise and bias at rest, a few
    hundredths of a m/s^2: its still means' directions are no gravity. An accelerometer in g reads about 1, a
    tenth of the rig's gravity, and is scaled instead; one in m/s^2 reads the gravity."""
    from types import SimpleNamespace

    from nrmpc_ros.frontend.imu_units import describe_accel_scale, reads_no_gravity

    for norm, none in ((0.04, True), (0.3, True), (1.0, False), (9.79, False), (math.nan, False)):
        assert reads_no_gravity(SimpleNamespace(accel_norm=norm), 9.81) is none
    said = describe_accel_scale(SimpleNamespace(accel_norm=0.04), 9.81)
    assert "gravity taken out" in said and "not used" in said
    assert "in units of g?" in describe_accel_scale(SimpleNamespace(accel_norm=1.0), 9.81)


@pytest.mark.slow
def test_replay_of_an_imu_topic_with_gravity_taken_out_estimates_from_the_images(tmp_path, capsys):
    """The IMU topic a fused driver publishes as linear acceleration: every hold is estimated, without the
    IMU's gravity (each counted, and the summary says why), where the images' refutation of its gravity lost the
    first holds."""
    from nrmpc_ros.cli.main import main

    bag, rig_file = tmp_path / "linear", tmp_path / "rig.yaml"
    assert main(["make-bag", "--out", str(bag), "--save-rig", str(rig_file), "--resolution", "320x240",
                 "--supersample", "1", "--cameras", "4", "--views", "6", "--bar-hz", "4", "--damping", "0.05",
                 "--seed", "41", "--imu-gravity-removed", "--no-progress"]) == 0
    assert main(["replay", str(bag), "--rig", str(rig_file), "--out", str(tmp_path / "x.csv"), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "with an estimate (after the first): 5/5" in text, text
    assert "hold without IMU gravity: the accelerometer reads no gravity at rest" in text
    assert any(ln.startswith("IMU scale:") and "gravity taken out" in ln for ln in text.splitlines())
    medians = [float(ln.split("median")[1].split()[0]) for ln in text.splitlines()
               if ln.strip().startswith("gravity vs ground truth")]
    assert medians and max(medians) < 0.3
