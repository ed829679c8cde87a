"""Shared CLI code: library option errors name the flag on the command line and the field in the library."""

import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.errors import InputError, OptionError
from nrmpc_ros.render.bagmaker import BagOptions
from nrmpc_ros.render.sequence import MotionOptions
from nrmpc_ros.sim.scenarios import load_scenario


def test_library_options_name_their_field():
    with pytest.raises(OptionError, match="bag options: field 'jpeg_quality'"):
        BagOptions(jpeg_quality=101).validate()
    with pytest.raises(OptionError, match="field 'jitter_ms'.*half the frame period"):
        BagOptions(jitter_ms=60.0, motion=MotionOptions(rate=10.0)).validate()
    with pytest.raises(OptionError, match="motion options: field 'hold_seconds'"):
        MotionOptions(hold_seconds=0.0).validate()


@pytest.mark.slow
def test_command_line_names_the_flag(tmp_path, capsys):
    out = tmp_path / "bag"
    rc = main(["make-bag", "--views", "2", "--rate", "10", "--jitter-ms", "60", "--no-progress", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "error: --jitter-ms: must be below half the frame period" in err
    assert "field 'jitter_ms'" not in err and not out.exists()


def test_renamed_flags_map_back_from_fields(tmp_path, capsys):
    rig = tmp_path / "rig"
    assert main(["simulate", "--out", str(rig)]) == 0
    capsys.readouterr()
    rc = main(["simulate", "--rig", str(rig / "rig.yaml"), "--cameras", "3", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert rc == 2 and "error: --cameras: cannot be combined with a custom rig file" in err


def test_file_errors_keep_the_file_and_key(tmp_path, capsys):
    sc = tmp_path / "sc.yaml"
    sc.write_text("pixel_noise: -1\n")
    rc = main(["simulate", "--scenario", str(sc), "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert rc == 2 and f"{sc}: field 'pixel_noise'" in err


def test_scenario_library_defaults_and_errors():
    sc, rig, extras = load_scenario("sequence", {"rig.num_cameras": 3, "num_views": 4})
    assert (sc.rig.layout, sc.num_views, rig, extras) == ("ring", 4, None, {})
    assert load_scenario("pair", {})[0].rig.layout == "cross"
    with pytest.raises(OptionError, match="field 'rig.colour'"):
        load_scenario("pair", {"rig.colour": 1})
    with pytest.raises(InputError, match="command line: field 'outlier_fraction'"):
        load_scenario("pair", {"outlier_fraction": 1.0})
