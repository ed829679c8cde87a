"""Monte Carlo runner and ``nrmpc experiment``: determinism, executors, statistics, outputs."""

import csv
import math

import pytest

from nrmpc_ros.cli.main import main
from nrmpc_ros.errors import InputError
from nrmpc_ros.experiments.runner import execute, summarize, task_seed
from nrmpc_ros.experiments.sweeps import EXPERIMENTS, make_tasks, run_experiment

TINY = {"pixel_noise": (0.1,), "EI": (0.1, 10.0)}


def _tasks(runs=2, seed=0, methods=("6pt-bending", "4pt-bending")):
    tasks, cells = make_tasks(EXPERIMENTS["noise-ei"], 4, runs, seed, axes=TINY, methods=methods, num_points=120)
    return tasks, cells


def _strip(rows):
    return [{k: v for k, v in r.items() if k != "time_s"} for r in rows]


def test_tasks_grid_and_seeds():
    tasks, cells = _tasks(runs=3)
    assert len(cells) == 2 and len(tasks) == 6
    assert {t.seed for t in tasks} == {task_seed(0, r) for r in range(3)}  # common random numbers over cells
    assert task_seed(0, 1) != task_seed(1, 1)
    ei = {t.cell: t.scenario["rig"]["EI"] for t in tasks}
    assert ei == {0: 0.1, 1: 10.0}
    with pytest.raises(InputError):
        make_tasks(EXPERIMENTS["outliers"], 4, 1, 0, axes={"outlier_fraction": (0.5, 1.0)})
    with pytest.raises(InputError):
        make_tasks(EXPERIMENTS["noise-ei"], 4, 0, 0)
    with pytest.raises(InputError):
        make_tasks(EXPERIMENTS["noise-ei"], 4, 1, 0, methods=("8pt",))


def test_deterministic_serial_vs_processes():
    tasks, _ = _tasks()
    a = execute(tasks, workers=1, progress=False)
    b = execute(list(reversed(tasks)), workers=2, progress=False)
    assert len(a) == 2 * len(tasks)
    assert _strip(a) == _strip(b)
    assert all(r["success"] for r in a if r["method"] == "4pt-bending")


def test_dask_local_cluster_gives_the_same_rows():
    distributed = pytest.importorskip("dask.distributed")
    tasks, _ = _tasks(runs=1)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        rows = execute(tasks, scheduler=lc.scheduler_address, progress=False)
    assert _strip(rows) == _strip(execute(tasks, workers=1, progress=False))


def test_summary_over_successful_and_all_runs():
    def row(run, method, ok, produced, rot):
        return {"cell": 0, "EI": 0.1, "run": run, "method": method, "success": ok, "produced": produced,
                "rotation": rot, "translation": 0.01, "gravity": rot if method != "6pt-nonbending" else math.nan,
                "time_s": 0.1}

    rows = [row(0, "6pt-bending", True, True, 0.001), row(1, "6pt-bending", True, True, 0.003),
            row(2, "6pt-bending", False, True, 0.9), row(3, "6pt-bending", False, False, math.nan),
            row(0, "6pt-nonbending", True, True, 0.01)]
    s = {r["method"]: r for r in summarize(rows, ("EI",))}
    b = s["6pt-bending"]
    assert b["runs"] == 4 and b["success_rate"] == 0.5 and b["produced_rate"] == 0.75
    assert b["rotation_mean_success"] == pytest.approx(0.002)
    assert b["rotation_median_success"] == pytest.approx(0.002)
    assert b["rotation_mean_all"] == pytest.approx((0.001 + 0.003 + 0.9 + math.pi) / 4)  # no pose counts as pi
    assert b["rotation_median_all"] == pytest.approx((0.003 + 0.9) / 2)
    assert math.isnan(s["6pt-nonbending"]["gravity_mean_all"])  # no gravity, not a failure


def test_run_experiment_writes_outputs(tmp_path):
    res = run_experiment("outliers", tmp_path, cameras=2, runs=1, seed=1, axes={"outlier_fraction": (0.0, 0.2)},
                         num_points=120, progress=False)
    assert [p.name for p in res["csv"]] == ["outliers-2cam_runs.csv", "outliers-2cam_summary.csv"]
    with open(res["csv"][0]) as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2 * 3 and {r["method"] for r in rows} == {"6pt-nonbending", "6pt-bending", "4pt-bending"}
    assert all(p.stat().st_size > 2000 for p in res["images"])
    md = res["markdown"].read_text()
    assert "outliers-2cam.png" in md and "success %" in md and "wall time" in md


def test_cli(tmp_path, capsys):
    out = tmp_path / "exp"
    args = ["experiment", "gravity-noise", "--runs", "1", "--points", "100", "--gravity-noise", "0,0.1",
            "--workers", "1", "--no-progress", "--out", str(out)]
    assert main(args) == 0
    assert (out / "gravity-noise-4cam.md").exists() and (out / "gravity-noise-4cam.png").exists()
    with open(out / "gravity-noise-4cam_summary.csv") as fh:
        summary = list(csv.DictReader(fh))
    assert [r["method"] for r in summary] == ["4pt-bending", "4pt-bending"]
    assert main(["experiment", "outliers", "--ei", "1", "--out", str(out)]) == 2  # not an axis of outliers
    assert "not an axis" in capsys.readouterr().err
    assert main(["experiment", "noise-ei", "--cameras", "1", "--out", str(out)]) == 2
