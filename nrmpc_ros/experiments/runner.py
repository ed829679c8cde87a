"""Monte Carlo runner: a grid of scenarios x seeded runs x methods, locally or on a Dask cluster.

A :class:`Task` is one seeded synthetic problem (one grid cell, one run) on
which every requested method runs, so all methods see the same data. Tasks
are plain picklable data and :func:`run_task` is a pure function of them, so
results do not depend on where or in which order tasks ran: :func:`execute`
sorts the rows by (cell, run, method). Run ``r`` of every cell uses the same
problem seed (common random numbers), which makes curves over a grid axis
smoother than independent draws would.

Errors follow docs/CONVENTIONS.md (Errors and success) (:func:`nrmpc_ros.core.pose_errors`).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field

import numpy as np

from ..core import METHODS, Estimate, EstimateInfo, estimate, pose_errors, rig_from_dict
from ..errors import NrmpcError, OptionError
from ..sim.synthetic import Scenario, make_problem

ERROR_KINDS = ("rotation", "translation", "gravity")


@dataclass(frozen=True)
class Task:
    """One seeded problem of one grid cell, solved by each of ``methods``."""

    cell: int
    params: dict  # the grid coordinates of the cell (written to the CSV)
    scenario: dict  # Scenario.to_dict()
    run: int
    seed: int
    methods: tuple = METHODS
    rig: dict | None = None  # a custom rig as Rig.to_dict(), else the scenario's simulated rig
    options: dict | None = field(default=None)  # EstimatorOptions overrides


def task_seed(base_seed: int, run: int) -> int:
    """The problem and RANSAC seed of run ``run`` (independent streams via SeedSequence)."""
    return int(np.random.SeedSequence([int(base_seed), int(run)]).generate_state(1)[0])


def run_task(task: Task) -> list[dict]:
    """Solve one problem with every method; one row per method with its errors (docs/CONVENTIONS.md, Errors and
    success)."""
    sc = Scenario.from_dict(task.scenario)
    rig = rig_from_dict(task.rig, "<experiment rig>") if task.rig else None
    problem = make_problem(sc, seed=task.seed, rig=rig)
    rows = []
    for method in task.methods:
        error = ""
        try:
            est = estimate(problem.rig, problem.matches, method, seed=task.seed, options=task.options)
        except NrmpcError:
            raise  # the set-up is wrong (e.g. 4pt-bending without gravity): stop and say so
        except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            # an estimator crash is a failed run, recorded with its reason, not the end of a long sweep
            est = Estimate(method=method, success=False, info=EstimateInfo(reason=repr(exc)))
            error = f"{type(exc).__name__}: {exc}"
        err = pose_errors(est.R, est.t, problem.R, problem.t, est.gravity, problem.gravity)
        rows.append({
            "cell": task.cell, **task.params, "run": task.run, "seed": task.seed, "method": method,
            "produced": bool(est.success), "success": bool(err["success"]),
            "rotation": err["rotation"], "translation": err["translation"], "translation_m": err["translation_m"],
            "gravity": err["gravity"], "num_inliers": est.num_inliers, "time_s": est.time_s, "error": error,
        })
    return rows


def _progress(total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="problem", disable=not enabled, dynamic_ncols=True)


def _order(rows: list[dict], methods_order: tuple) -> list[dict]:
    rank = {m: i for i, m in enumerate(methods_order)}
    return sorted(rows, key=lambda r: (r["cell"], r["run"], rank.get(r["method"], len(rank))))


def execute(tasks: list[Task], workers: int = 1, scheduler: str | None = None, progress: bool = True,
            desc: str = "monte carlo") -> list[dict]:
    """Run all tasks (in-process, on ``workers`` local processes, or on the Dask scheduler at ``scheduler``)."""
    if workers < 1:
        raise OptionError("experiment runner", "workers", f"must be >= 1, got {workers}")
    methods_order = tasks[0].methods if tasks else METHODS
    rows: list[dict] = []
    bar = _progress(len(tasks), desc, progress)
    try:
        if scheduler:
            rows = _execute_dask(tasks, scheduler, bar)
        elif workers == 1:
            for task in tasks:
                rows.extend(run_task(task))
                bar.update(1)
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                futures = [pool.submit(run_task, task) for task in tasks]
                try:
                    for fut in as_completed(futures):
                        rows.extend(fut.result())
                        bar.update(1)
                except BaseException:
                    for fut in futures:
                        fut.cancel()
                    raise
    finally:
        bar.close()
    return _order(rows, methods_order)


def _execute_dask(tasks: list[Task], address: str, bar) -> list[dict]:
    try:
        from dask.distributed import Client
        from dask.distributed import as_completed as dask_as_completed
    except ImportError:
        raise OptionError("experiment runner", "scheduler", "needs dask.distributed: pip install 'dask[distributed]' "
                         "(or the package's [dask] extra)") from None
    try:
        client = Client(address, timeout=30)
    except (OSError, TimeoutError) as exc:
        raise OptionError("experiment runner", "scheduler",
                          f"{address}: cannot connect to the Dask scheduler ({exc})") from None
    rows: list[dict] = []
    try:
        futures = client.map(run_task, tasks, pure=False)
        for fut in dask_as_completed(futures):
            rows.extend(fut.result())
            bar.update(1)
    finally:
        client.close()
    return rows


# ---------------------------------------------------------------------------
# statistics (docs/CONVENTIONS.md (Errors and success))
# ---------------------------------------------------------------------------

def _stats(values: np.ndarray) -> tuple[float, float]:
    v = values[np.isfinite(values)]
    if len(v) == 0:
        return math.nan, math.nan
    return float(np.mean(v)), float(np.median(v))


def summarize(rows: list[dict], keys: tuple) -> list[dict]:
    """Per (keys..., method): success rate and mean/median errors over successful runs and over all runs.

    "All runs" counts a run that produced no pose with the largest possible
    angle (pi) for rotation and translation (and gravity for the bending
    methods), so a method cannot look better by giving up. Gravity of
    6pt-nonbending is absent (nan).
    """
    groups: dict = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys) + (r["method"],), []).append(r)
    out = []
    for gkey, grp in groups.items():
        ok = np.array([r["success"] for r in grp], bool)
        produced = np.array([r["produced"] for r in grp], bool)
        row = dict(zip(keys + ("method",), gkey))
        row["runs"] = len(grp)
        row["success_rate"] = float(ok.mean())
        row["produced_rate"] = float(produced.mean())
        row["crashes"] = sum(1 for r in grp if r.get("error"))
        has_gravity = grp[0]["method"] != "6pt-nonbending"
        for kind in ERROR_KINDS:
            vals = np.array([r[kind] for r in grp], float)
            row[f"{kind}_mean_success"], row[f"{kind}_median_success"] = _stats(vals[ok])
            if kind != "gravity" or has_gravity:
                vals = np.where(produced, vals, math.pi)
            row[f"{kind}_mean_all"], row[f"{kind}_median_all"] = _stats(vals)
        row["time_median_s"] = float(np.median([r["time_s"] for r in grp]))
        row["time_mean_s"] = float(np.mean([r["time_s"] for r in grp]))
        out.append(row)
    return out


def default_workers() -> int:
    """One process per available core."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


__all__ = ["ERROR_KINDS", "Task", "default_workers", "execute", "run_task", "summarize", "task_seed"]
