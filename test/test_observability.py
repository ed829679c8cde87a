"""Cramér-Rao bounds (issue 3, ``nrmpc observability``): validated against a seeded Monte Carlo."""

import json
import math

import numpy as np
import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.core.bundle import refine_two_view
from nrmpc_ros.core.metrics import pose_errors
from nrmpc_ros.experiments.crlb import problem_bound, set_bar_ei
from nrmpc_ros.experiments.observability import ei_limit, observability, sweep_ei
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
    p100 = make_problem(sc, 3, rig=set_bar_ei(rig, 100.0))
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
