"""Cramér-Rao bounds (``nrmpc observability``): validated against a seeded Monte Carlo; bounds of sequences."""

import json
import math

import numpy as np
import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.core.bundle import refine_two_view
from nrmpc_ros.core.metrics import pose_errors
from nrmpc_ros.experiments.crlb import problem_bound
from nrmpc_ros.experiments.observability import (
    ei_limit,
    first_holds,
    observability,
    sequence_observability,
    sweep_ei,
)
from nrmpc_ros.sim.sequence import SequenceScenario, make_sequence
from nrmpc_ros.sim.synthetic import RigSpec, Scenario, make_problem, make_rig


def test_ground_truth_initialised_refinement_reaches_the_bound():
    """RMS gravity and rotation errors of the refinement over 60 seeded problems are within 20% of the bound."""
    sc = Scenario(outlier_fraction=0.0, pixel_noise=0.1)
    sigma = sc.pixel_noise / sc.rig.focal
    errors, bounds = [], []
    rig = make_rig(sc.rig)
    for seed in range(60):
        p = make_problem(sc, seed, rig=rig)
        m = p.matches
        b = problem_bound(p, sigma)
        res = refine_two_view(p.rig, m.f1, m.f2, m.cam, p.R, p.t, p.gravity, points=p.points)
        e = pose_errors(res.R, res.t, p.R, p.t, res.g, p.gravity)
        errors.append([e["rotation"], e["gravity"]])
        bounds.append([b.rms("rotation"), b.rms("gravity")])
    rms_err = np.sqrt(np.mean(np.square(errors), axis=0))
    rms_bound = np.sqrt(np.mean(np.square(bounds), axis=0))
    ratio = rms_err / rms_bound
    print("RMS error / RMS bound (rotation, gravity):", ratio)
    assert np.all(np.abs(ratio - 1.0) < 0.2), ratio


def test_bound_scales_with_noise_and_compliance():
    sc = Scenario(num_points=300, outlier_fraction=0.0)
    rig = make_rig(RigSpec(EI=10.0))
    p = make_problem(sc, 3, rig=rig)
    b1, b2 = problem_bound(p, 1e-4), problem_bound(p, 2e-4)
    for kind in ("rotation", "translation", "gravity"):  # the bound is linear in the noise
        assert b2.rms(kind) == pytest.approx(2 * b1.rms(kind), rel=1e-6)
    # stiffer bars: smaller deflections, gravity bound grows ~ linearly with EI once EI is large
    p100 = make_problem(sc, 3, rig=rig.with_bar_ei(100.0))
    assert problem_bound(p100, 1e-4).rms("gravity") / b1.rms("gravity") == pytest.approx(10.0, rel=0.05)
    rigid = make_problem(sc, 3, rig=make_rig(RigSpec(EI=math.inf)))
    b = problem_bound(rigid, 1e-4)
    assert math.isinf(b.rms("gravity")) and math.isfinite(b.rms("rotation"))


def test_sweep_and_limit():
    sc = Scenario(num_points=200, outlier_fraction=0.0)
    rows = sweep_ei(None, sc, [0.1, 1.0, 10.0], samples=3, seed=1)
    g = [r["gravity_rms"] for r in rows]
    assert g[0] < g[1] < g[2]
    lim = ei_limit([0.1, 1.0, 10.0], g, math.sqrt(g[1] * g[2]))
    assert 1.0 < lim < 10.0
    assert ei_limit([1, 10, 100], [1e-3, 1e-2, 1e-1], 1e-2) == pytest.approx(10.0)
    assert ei_limit([1, 10], [1e-3, 1e-2], 1.0) is None
    assert ei_limit([1, 10], [1e-3, 1e-2], 1e-4) == 0.0
    res = observability(make_rig(sc.rig), sc, samples=2, seed=0)
    assert res["gravity"]["median"] < res["gravity"]["rms"]


def test_cli_sweep(tmp_path, capsys):
    args = ["observability", "--samples", "2", "--points", "150", "--sweep-ei", "--ei-range", "0.1,100,4",
            "--accuracy-deg", "0.5", "--out", str(tmp_path), "--json"]
    assert main(args) == 0
    res = json.loads(capsys.readouterr().out)
    assert (tmp_path / "observability_ei.png").stat().st_size > 1000
    assert len((tmp_path / "observability_ei.csv").read_text().splitlines()) == 5
    assert 0.1 < res["sweep"]["ei_limit"] < 100
    assert res["bounds_rad"]["gravity"]["rms"] > 0
    assert main(["observability", "--samples", "2", "--points", "100"]) == 0
    assert "gravity" in capsys.readouterr().out
    assert main(["observability", "--noise", "0"]) == 2
    assert main(["observability", "--sweep-ei", "--ei-range", "5,1,3"]) == 2


SEQ = SequenceScenario(num_views=6, tracks_per_camera=40)


def test_first_holds_is_the_recording_stopped_early():
    full = make_sequence(SEQ, seed=4)
    part = first_holds(full, 3)
    tr = part.tracks
    assert tr.num_views == 3 and len(part.R) == 3 and len(part.inlier_mask) == len(tr)
    assert np.array_equal(part.gravity, full.gravity[:3]) and np.array_equal(part.tracks.g_meas, full.tracks.g_meas[:3])
    # every landmark kept is seen in two holds at least, and keeps its bearings and inlier flags
    spans = {k: set(tr.view[tr.track == k]) for k in np.unique(tr.track)}
    assert all(len(v) >= 2 for v in spans.values())
    idx = {(v, c, k): i for i, (v, c, k) in enumerate(zip(full.tracks.view, full.tracks.cam, full.tracks.track))}
    src = np.array([idx[key] for key in zip(tr.view, tr.cam, tr.track)])
    assert np.allclose(tr.f, full.tracks.f[src], atol=1e-12) and np.array_equal(part.inlier_mask, full.inlier_mask[src])
    assert len(tr) < np.count_nonzero(full.tracks.view < 3)  # the landmarks first seen in hold 2 are gone
    with pytest.raises(ValueError):
        first_holds(full, 1)


def test_joint_bound_falls_with_the_holds_and_equals_the_pair_for_two():
    rig = make_rig(SEQ.rig)
    rows = sequence_observability(rig, SEQ, samples=3, seed=2, gravity_prior_sigma=math.radians(0.3),
                                  views=[2, 4, 6])
    assert [r["views"] for r in rows] == [2, 4, 6]
    two, four, six = rows
    for suffix in ("", "_prior"):  # two holds: the joint estimate is the pair's
        assert two["joint" + suffix] == pytest.approx(two["pairwise" + suffix], rel=1e-3)
    assert two["joint"] > four["joint"] > six["joint"]
    assert six["pairwise"] > 2.5 * six["joint"]
    # the pairs do not get better with more holds; the prior helps every bound
    assert six["pairwise"] == pytest.approx(two["pairwise"], rel=0.5)
    for r in rows:
        assert r["joint_prior"] < r["joint"] and r["pairwise_prior"] < r["pairwise"]
    no_prior = sequence_observability(rig, SEQ, samples=3, seed=2, views=[6])[0]
    assert no_prior["joint_prior"] is None and no_prior["joint"] == pytest.approx(six["joint"])
    with pytest.raises(ValueError):
        sequence_observability(rig, SEQ, samples=1, views=[7])


def test_cli_sequence(capsys):
    args = ["observability", "--sequence", "--samples", "2", "--tracks-per-camera", "40", "--views", "5,2"]
    assert main(args + ["--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["views"] == 5 and [r["views"] for r in res["bounds_rad"]] == [2, 5]
    assert res["gravity_prior_sigma"] == pytest.approx(math.radians(0.3))  # the scenario's gravity noise
    five = res["bounds_rad"][1]
    assert 0 < five["joint_prior"] < five["joint"] < five["pairwise"]
    assert main(args + ["--gravity-prior-sigma", "inf"]) == 0
    table = capsys.readouterr().out
    assert "pair/joint" in table and "prior" not in table.split("\n")[1]
    rows = [line.split() for line in table.splitlines() if line.split() and line.split()[0] in ("2", "5")]
    assert [float(r[1]) for r in rows] == pytest.approx([math.degrees(r["joint"]) for r in res["bounds_rad"]],
                                                        rel=5e-3)
    assert main(["observability", "--sequence", "--samples", "1", "--views", "3", "--EI", "inf", "--json"]) == 0
    rigid = json.loads(capsys.readouterr().out)
    assert rigid["bounds_rad"][0]["joint"] == "inf" and "note" in rigid


@pytest.mark.parametrize("argv, flag", [
    (["--sequence", "--points", "100"], "--points"),
    (["--views", "4"], "--views"),
    (["--sequence", "--sweep-ei"], "--sweep-ei"),
    (["--sequence", "--noise", "0"], "--noise"),
    (["--sequence", "--gravity-prior-sigma", "0"], "--gravity-prior-sigma"),
    (["--sequence", "--samples", "0"], "--samples"),
    (["--sequence", "--max-step", "200"], "max_step_deg"),
])
def test_cli_sequence_bad_flags(argv, flag, capsys):
    assert main(["observability", *argv]) == 2
    assert flag in capsys.readouterr().err


def test_cli_sequence_bad_views_list(capsys):
    for text in ("1,3", "a,b", ","):
        with pytest.raises(SystemExit) as exc:
            main(["observability", "--sequence", "--views", text])
        assert exc.value.code == 2 and "--views" in capsys.readouterr().err
