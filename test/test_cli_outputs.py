"""No command writes into its inputs, and a failing run leaves its previous output as it was.

Every command that writes is run with its output pointing at each of its inputs, inside an input bag and at a
directory where a file belongs: exit status 2, one error naming the output's flag, and every input with the
same bytes as before. Then runs that fail half-way (a bag with a corrupt message, a bad file after good
ones) keep the previous output and leave no temporary file behind.
"""

from __future__ import annotations

import os
import shutil

import pytest
import yaml
from badbags import copy_bag, corrupt_message, digest
from recordings import recording

from nrmpc_ros.cli.main import main
from nrmpc_ros.frontend.estimates_csv import read_csv
from nrmpc_ros.safeio import PARTIAL_SUFFIX

CAMCHAIN = {"cam0": {"camera_model": "pinhole", "intrinsics": [400.0, 400.0, 320.0, 240.0],
                     "distortion_model": "radtan", "distortion_coeffs": [0.0, 0.0, 0.0, 0.0],
                     "resolution": [640, 480], "rostopic": "/cam0/image_raw"}}


def _run(argv, capsys):
    """(exit status, stderr) of ``nrmpc argv``; a flag refused while parsing exits through SystemExit."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err


def _partials(d):
    return sorted(p.name for p in d.rglob(f"*{PARTIAL_SUFFIX}"))


@pytest.fixture(scope="module")
def files(recordings_dir, tmp_path_factory):
    """A rendered bag and its rig, simulated matches and tracks, a replay CSV and small settings files."""
    bag, rig, _ = recording(recordings_dir, "cross4", "stream-smooth")
    d = tmp_path_factory.mktemp("outputs")
    assert main(["simulate", "--out", str(d / "sim"), "--points", "200"]) == 0
    assert main(["simulate", "--out", str(d / "seq"), "--sequence", "--views", "3", "--tracks-per-camera", "30"]) == 0
    csv = d / "estimates.csv"
    assert main(["replay", str(bag), "--rig", str(rig), "--out", str(csv), "--no-progress", "--quiet"]) == 0
    (d / "pipeline.yaml").write_text("window: 10\n")
    (d / "options.yaml").write_text("max_iterations: 20\n")
    (d / "scenario.yaml").write_text("views: 3\n")
    (d / "camchain.yaml").write_text(yaml.safe_dump(CAMCHAIN))
    (d / "experiment").mkdir()
    shutil.copy(d / "sim" / "rig.yaml", d / "experiment" / "outliers-4cam.md")  # a rig file named like an output
    (d / "sweep").mkdir()
    shutil.copy(d / "sim" / "rig.yaml", d / "sweep" / "observability_ei.csv")
    return {"bag": bag, "rig": rig, "db3": next(bag.glob("*.db3")), "csv": csv, "d": d,
            "config": d / "pipeline.yaml", "options": d / "options.yaml", "scenario": d / "scenario.yaml",
            "camchain": d / "camchain.yaml", "sim_rig": d / "sim" / "rig.yaml", "matches": d / "sim" / "pair_000.npz",
            "seq_rig": d / "seq" / "rig.yaml", "tracks": d / "seq" / "seq_000.npz",
            "md_rig": d / "experiment" / "outliers-4cam.md", "sweep_rig": d / "sweep" / "observability_ei.csv"}


REPLAY = ["replay", "{bag}", "--rig", "{rig}", "--config", "{config}", "--no-progress", "--quiet"]
# (command line with the output, flag named by the error, inputs whose bytes must not change)
CASES = {
    "replay --out is --rig": (REPLAY + ["--out", "{rig}"], "--out", ["bag", "rig", "config"]),
    "replay --out is --config": (REPLAY + ["--out", "{config}"], "--out", ["bag", "rig", "config"]),
    "replay --out inside the bag": (REPLAY + ["--out", "{bag}/sample.db3"], "--out", ["bag"]),
    "replay --out is the bag's database": (REPLAY + ["--out", "{db3}"], "--out", ["bag"]),
    "replay --out is the bag directory": (REPLAY + ["--out", "{bag}"], "--out", ["bag"]),
    "replay --batch is --rig": (REPLAY + ["--out", "{d}/new.csv", "--batch", "{rig}"], "--batch", ["rig"]),
    "replay --batch is --out": (REPLAY + ["--out", "{d}/new.csv", "--batch", "{d}/new.csv"], "--batch", ["rig"]),
    "calibrate-bars --out is --rig": (["calibrate-bars", "{bag}", "--rig", "{rig}", "--out", "{rig}"], "--out",
                                      ["bag", "rig"]),
    "calibrate-bars --out inside the bag": (["calibrate-bars", "{bag}", "--rig", "{rig}", "--out",
                                             "{bag}/rig.yaml"], "--out", ["bag"]),
    "calibrate-bars --out is a matches file": (["calibrate-bars", "--rig", "{sim_rig}", "--matches", "{matches}",
                                                "--out", "{matches}"], "--out", ["matches", "sim_rig"]),
    "import-kalibr --out is the camchain": (["import-kalibr", "{camchain}", "--out", "{camchain}", "--force"], "--out",
                                            ["camchain"]),
    "import-kalibr --out is --imu-chain": (["import-kalibr", "{camchain}", "--imu-chain", "{camchain}", "--out",
                                            "{camchain}", "--force"], "--out", ["camchain"]),
    "make-bag --save-rig is --rig": (["make-bag", "--rig", "{rig}", "--save-rig", "{rig}", "--out", "{d}/newbag"],
                                     "--save-rig", ["rig"]),
    "make-bag --save-rig is --scenario": (["make-bag", "--scenario", "{scenario}", "--save-rig", "{scenario}",
                                           "--out", "{d}/newbag"], "--save-rig", ["scenario"]),
    "make-bag --out is an existing bag": (["make-bag", "--out", "{bag}", "--no-progress"], "--out", ["bag"]),
    "simulate --out holds its --rig": (["simulate", "--rig", "{sim_rig}", "--out", "{d}/sim"], "--out",
                                       ["sim_rig", "matches"]),
    "solve --out is a matches file": (["solve", "--rig", "{sim_rig}", "--method", "6pt-bending", "--out", "{matches}",
                                       "{matches}"], "--out", ["matches"]),
    "solve --out is --rig": (["solve", "--rig", "{sim_rig}", "--method", "6pt-bending", "--out", "{sim_rig}",
                              "{matches}"], "--out", ["sim_rig"]),
    "solve-sequence --out is a tracks file": (["solve-sequence", "--rig", "{seq_rig}", "--method", "6pt-bending",
                                               "--out", "{tracks}", "{tracks}"], "--out", ["tracks"]),
    "solve-sequence --out is --options": (["solve-sequence", "--rig", "{seq_rig}", "--method", "6pt-bending",
                                           "--options", "{options}", "--out", "{options}", "{tracks}"], "--out",
                                          ["options"]),
    "compare --plot is the CSV": (["compare", "{csv}", "--bag", "{bag}", "--quiet", "--plot", "{csv}"], "--plot",
                                  ["csv"]),
    "compare --json is --rig": (["compare", "{csv}", "--bag", "{bag}", "--rig", "{rig}", "--quiet", "--json", "{rig}"],
                                "--json", ["rig"]),
    "compare --json inside the bag": (["compare", "{csv}", "--bag", "{bag}", "--quiet", "--json", "{bag}/s.json"],
                                      "--json", ["bag"]),
    "compare --plot is a directory": (["compare", "{csv}", "--bag", "{bag}", "--quiet", "--plot", "{d}"], "--plot",
                                      ["csv"]),
    "observability --out holds its --rig": (["observability", "--sweep-ei", "--rig", "{sweep_rig}", "--out",
                                             "{d}/sweep", "--samples", "2"], "--out", ["sweep_rig"]),
    "experiment --out holds its --rig": (["experiment", "outliers", "--rig", "{md_rig}", "--out", "{d}/experiment",
                                          "--runs", "1", "--workers", "1", "--no-progress"], "--out", ["md_rig"]),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CASES))
def test_an_output_never_writes_into_an_input(files, capsys, name):
    argv, flag, inputs = CASES[name]
    argv = [a.format(**files) for a in argv]
    before = {k: digest(files[k]) for k in inputs}
    code, err = _run(argv, capsys)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"error: {flag}: " in lines[0], err
    assert {k: digest(files[k]) for k in inputs} == before
    assert not (files["d"] / "new.csv").exists() and not (files["d"] / "newbag").exists()
    assert _partials(files["d"]) == [] and _partials(files["bag"]) == []


@pytest.mark.slow
def test_links_to_an_input_are_the_input(files, tmp_path, capsys):
    """A symlink or a hard link to the rig is the rig: refused as --out."""
    (tmp_path / "soft.yaml").symlink_to(files["rig"])
    os.link(files["rig"], tmp_path / "hard.yaml")
    before = digest(files["rig"])
    for out in ("soft.yaml", "hard.yaml"):
        code, err = _run([a.format(**files) for a in REPLAY] + ["--out", tmp_path / out], capsys)
        assert code == 2 and "error: --out: " in err and "is the input --rig" in err, err
    assert digest(files["rig"]) == before


@pytest.mark.slow
def test_replay_failing_half_way_keeps_the_previous_output(files, tmp_path, capsys):
    """A message that does not decode ends the replay with one error naming the bag and topic: the estimates
    written so far are dropped and the CSV of an earlier run stays as it was, with no temporary file beside it."""
    bag = corrupt_message(copy_bag(files["bag"], tmp_path / "bag"), "/cam2/image_raw")
    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(files["csv"], out / "estimates.csv")
    shutil.copy(files["csv"], out / "batch.csv")
    before = digest(out)
    code, err = _run(["replay", bag, "--rig", files["rig"], "--out", out / "estimates.csv", "--batch",
                      out / "batch.csv", "--no-progress", "--quiet"], capsys)
    assert code == 2 and str(bag) in err and "/cam2/image_raw" in err, err
    assert "Traceback" not in err
    assert digest(out) == before and _partials(out) == []
    assert len(read_csv(out / "estimates.csv")) == len(read_csv(files["csv"]))


@pytest.mark.slow
def test_a_failed_replay_leaves_nothing_where_there_was_nothing(files, tmp_path, capsys):
    bag = corrupt_message(copy_bag(files["bag"], tmp_path / "bag"), "/cam0/image_raw")
    code, err = _run(["replay", bag, "--rig", files["rig"], "--out", tmp_path / "o" / "x.csv", "--no-progress"],
                     capsys)
    assert code == 2 and str(bag) in err
    assert list((tmp_path / "o").iterdir()) == []


@pytest.mark.slow
def test_solve_with_a_bad_file_after_good_ones_keeps_the_previous_output(files, tmp_path, capsys):
    out = tmp_path / "results.jsonl"
    out.write_text("previous results\n")
    bad = tmp_path / "bad.npz"
    bad.write_text("not an archive")
    code, err = _run(["solve", "--rig", files["sim_rig"], "--method", "6pt-bending", "--out", out, files["matches"],
                      bad], capsys)
    assert code == 2 and str(bad) in err
    assert out.read_text() == "previous results\n" and _partials(tmp_path) == []
    code, err = _run(["solve", "--rig", files["sim_rig"], "--method", "6pt-bending", "--out", out, files["matches"]],
                     capsys)
    assert code == 0, err
    assert '"success": true' in out.read_text() and _partials(tmp_path) == []


def test_make_bag_appears_complete_or_not_at_all(tmp_path, capsys):
    """The bag is built under a temporary name beside --out and renamed: a refused run leaves nothing, a
    finished one leaves only the bag."""
    code, err = _run(["make-bag", "--resolution", "64x48", "--cameras", "2", "--layout", "line", "--views", "2",
                      "--hold-seconds", "0.5", "--rate", "4", "--no-progress", "--out", tmp_path / "bag"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]
    assert sorted(p.name for p in (tmp_path / "bag").iterdir()) == ["bag.db3", "metadata.yaml"]
