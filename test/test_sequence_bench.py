"""The sequence benchmark (`nrmpc bench --sequence`): end to end on a few sequences, its numbers consistent."""

import json
import math

import numpy as np
import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.experiments.sequence_bench import (
    FAILED_DEG,
    METHODS,
    SequenceTask,
    format_sequence_table,
    run_sequence_bench,
    run_sequence_task,
)
from nrmpc_ros.sim.synthetic import RigSpec

RIG = "line2-ei1"


@pytest.fixture(scope="module")
def bench():
    """Two sequences of the two-camera bar through the command line, on two worker processes."""
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["bench", "--sequence", "--runs", "2", "--seed", "5", "--rigs", RIG, "--workers", "2",
                     "--json"])
    assert code == 0
    return json.loads(buf.getvalue())


def test_numbers_are_finite_and_consistent(bench):
    assert bench["runs"] == 2 and list(bench["rigs"]) == [RIG] and len(bench["records"]) == 2
    K = bench["scenario"]["num_views"]
    assert K == 10 and bench["scenario"]["pixel_noise"] == 0.3 and bench["scenario"]["outlier_fraction"] == 0.05
    for m in METHODS:
        md = bench["rigs"][RIG]["methods"][m]
        recs = [r["methods"][m] for r in bench["records"]]
        for route, holds in (("joint", K), ("pairwise", K - 1)):
            d = md[route]
            err = np.concatenate([r[f"{route}_error_deg"] for r in recs])
            bound = np.concatenate([r[f"{route}_bound_deg"] for r in recs])
            assert len(err) == len(bound) == 2 * holds
            assert np.all(np.isfinite(err)) and np.all(np.isfinite(bound)) and np.all(bound > 0)
            assert d["median_error_deg"] == pytest.approx(np.median(err))
            assert d["median_bound_deg"] == pytest.approx(np.median(bound))
            assert d["error_over_bound"] == pytest.approx(d["median_error_deg"] / d["median_bound_deg"])
            ok = [np.all(np.array(r[f"{route}_error_deg"]) < bench["success_deg"]) for r in recs]
            assert d["success_rate"] == pytest.approx(np.mean(ok))
            assert d["median_time_s"] == pytest.approx(np.median([r[f"{route}_time_s"] for r in recs]))
            assert 0 < d["median_time_s"] < 60
        assert md["time_ratio"] == pytest.approx(np.median([r["joint_time_s"] / r["pairwise_time_s"] for r in recs]))
        assert md["bound_ratio"] == pytest.approx(md["pairwise"]["median_bound_deg"] / md["joint"]["median_bound_deg"])
        # one gravity over ten holds: the joint bound is well below the pairs' and the estimate reaches it
        assert md["bound_ratio"] > 2
        assert md["joint"]["success_rate"] == 1.0 and md["joint"]["error_over_bound"] < 3
    # the accelerometer prior lowers the bounds
    six, four = (bench["rigs"][RIG]["methods"][m] for m in ("6pt-bending", "4pt-bending"))
    assert four["joint"]["median_bound_deg"] < six["joint"]["median_bound_deg"]
    assert four["pairwise"]["median_bound_deg"] < six["pairwise"]["median_bound_deg"]


def test_one_worker_gives_the_numbers_of_two(bench, capsys):
    assert main(["bench", "--sequence", "--runs", "1", "--seed", "5", "--rigs", RIG, "--workers", "1",
                 "--methods", "6pt-bending", "--json"]) == 0
    one = json.loads(capsys.readouterr().out)["records"][0]
    two = bench["records"][0]
    assert one["seed"] == two["seed"] and list(one["methods"]) == ["6pt-bending"]
    for key in ("joint_error_deg", "joint_bound_deg", "pairwise_error_deg", "pairwise_bound_deg"):
        assert one["methods"]["6pt-bending"][key] == two["methods"]["6pt-bending"][key]


def test_markdown_table(bench):
    table = format_sequence_table(bench)
    lines = table.splitlines()
    assert lines[0].startswith("| rig | method |") and set(lines[1]) == {"|", "-"}
    rows = [line.split(" | ") for line in lines[2:4]]
    assert [r[1] for r in rows] == list(METHODS)
    j = bench["rigs"][RIG]["methods"]["6pt-bending"]["joint"]
    assert float(rows[0][2]) == pytest.approx(j["median_error_deg"], rel=1e-2)
    assert lines[0].count("|") == lines[2].count("|")
    assert f"{FAILED_DEG:g} deg" in table


def test_a_hold_without_gravity_counts_as_failed():
    """Two cameras on one rigid bar: no gravity from vision, every hold counts 180 deg and nothing succeeds."""
    rigid = RigSpec(num_cameras=2, layout="line", EI=math.inf, mass=0.15, bar_length=0.3)
    rec = run_sequence_task(SequenceTask("rigid", rigid, 0, 3, ("6pt-bending",)))["methods"]["6pt-bending"]
    assert rec["joint_error_deg"] == [FAILED_DEG] * 10 and rec["pairwise_error_deg"] == [FAILED_DEG] * 9
    assert rec["joint_failure"] and rec["pairwise_failure"]
    assert all(math.isinf(b) for b in rec["joint_bound_deg"])


@pytest.mark.parametrize("argv, flag", [
    (["--runs", "0"], "--runs"),
    (["--seed", "-1"], "--seed"),
    (["--workers", "0"], "--workers"),
    (["--rigs", "cross4-ei1,triangle"], "--rigs"),
    (["--rigs", "line2-ei1,line2-ei1"], "--rigs"),
    (["--methods", "6pt-nonbending"], "--methods"),
    (["--points", "100"], "--points"),
    (["--no-poselib"], "--no-poselib"),
    (["--EI", "2"], "--EI"),
])
def test_bad_flags(argv, flag, capsys):
    assert main(["bench", "--sequence", *argv]) == 2
    assert flag in capsys.readouterr().err


def test_sequence_flags_need_sequence(capsys):
    for argv, flag in ((["--rigs", RIG], "--rigs"), (["--workers", "2"], "--workers")):
        assert main(["bench", "--runs", "1", *argv]) == 2
        assert flag in capsys.readouterr().err
    with pytest.raises(ValueError):
        run_sequence_bench(runs=True)
