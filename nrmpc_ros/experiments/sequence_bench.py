"""Benchmark of the joint estimation over a sequence of holds against the pairwise route, beside their bounds.

On simulated sequences (:mod:`nrmpc_ros.sim.sequence`: 10 holds, 0.3 px
image noise, 5 % outliers, measured gravity with 0.3 deg noise) of four rigs,
for 6pt-bending (vision only) and 4pt-bending (measured gravity as a prior
with the std of its simulated noise):

- **joint**: :func:`nrmpc_ros.core.sequence.estimate_sequence` on the whole
  sequence, one gravity for all holds; the error of each hold's gravity g_k;
- **pairwise**: :func:`nrmpc_ros.core.estimate` on each consecutive pair
  (k - 1, k) on its own; the error of hold k's gravity R^T g of that pair.

Each route's median per-hold error is divided by the median per-hold
Cramér-Rao bound of the same sequences (:func:`.crlb.sequence_bound`, joint
or pairwise, with the prior for 4pt-bending), so an efficient estimator
scores ~1 (docs/CONVENTIONS.md, "Sequences"). A sequence succeeds when every
hold's gravity is within 5 deg; a route that gives no gravity for a hold
counts as 180 deg there. Times: the batch estimate's ``time_s`` against the
wall time of the whole pairwise route on the same sequence, in the same
process. Tasks (one sequence of one rig) are seeded and independent and run
on worker processes with one BLAS thread each, so the numbers do not depend
on the number of workers.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from ..core import EstimatorOptions, estimate
from ..core.sequence import SequenceOptions, estimate_sequence
from ..core.so3 import angle_between
from ..errors import NrmpcError, OptionError
from ..sim.sequence import SequenceScenario, make_sequence
from ..sim.synthetic import RigSpec
from .crlb import sequence_bound
from .runner import task_seed

# the benchmark's rigs: two cameras on one straight bar, a ring of three, the paper's cross (stiff and compliant)
RIGS = {
    "line2-ei1": RigSpec(num_cameras=2, layout="line", EI=1.0, mass=0.15, bar_length=0.3),
    "ring3-ei1.3": RigSpec(num_cameras=3, layout="ring", EI=1.3),
    "cross4-ei1": RigSpec(EI=1.0),
    "cross4-ei0.1": RigSpec(EI=0.1),
}
METHODS = ("6pt-bending", "4pt-bending")
ROUTES = ("joint", "pairwise")
_OWNER = "sequence benchmark"  # how OptionError names this module's options
SUCCESS_DEG = 5.0  # every hold's gravity within this for a sequence to succeed
FAILED_DEG = 180.0  # error of a hold without gravity
_CRASHES = (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError)


def bench_scenario(spec: RigSpec) -> SequenceScenario:
    """The benchmark's sequences of one rig: 10 holds, 0.3 px, 5 % outliers, SequenceScenario defaults else."""
    return SequenceScenario(rig=spec, num_views=10, pixel_noise=0.3, outlier_fraction=0.05)


@dataclass(frozen=True)
class SequenceTask:
    """One seeded sequence of one rig, solved by each method along both routes."""

    rig: str  # its name in the results
    spec: RigSpec
    run: int
    seed: int
    methods: tuple = METHODS


def _errors_deg(gravity, truth) -> np.ndarray:
    """(n,) angle (deg) between estimated and true gravity per hold; FAILED_DEG where there is none."""
    if gravity is None:
        return np.full(len(truth), FAILED_DEG)
    return np.array([math.degrees(angle_between(g, t)) if g is not None else FAILED_DEG
                     for g, t in zip(gravity, truth)])


def _joint(problem, method, seed, opts: SequenceOptions) -> tuple[np.ndarray, float, str]:
    """Per-hold gravity errors (K,) of the batch estimate, its time_s and why it failed ('' if not)."""
    try:
        est = estimate_sequence(problem.rig, problem.tracks, method, seed=seed, options=opts)
    except NrmpcError:
        raise  # the set-up is wrong: stop and say so
    except _CRASHES as exc:
        return _errors_deg(None, problem.gravity), math.nan, f"crash: {type(exc).__name__}: {exc}"
    grav = est.gravity if est.success else None
    reason = "" if est.success and grav is not None else (est.reason or "no gravity")
    return _errors_deg(grav, problem.gravity), est.time_s, reason


def _pairwise(problem, method, seed, opts: EstimatorOptions) -> tuple[np.ndarray, float, str]:
    """Errors (K-1,) of hold k's gravity from the pair (k-1, k) alone, k = 1..K-1; total wall time; the first
    failure's reason."""
    tracks, K = problem.tracks, problem.tracks.num_views
    grav, why = [], ""
    t0 = time.perf_counter()
    for k in range(1, K):
        try:
            est = estimate(problem.rig, tracks.pair(k - 1, k), method, seed=seed + k, options=opts)
            g = est.gravity2 if est.success else None
            if g is None and not why:
                why = f"pair ({k - 1}, {k}): {est.info.reason or 'no gravity'}"
        except NrmpcError:
            raise
        except _CRASHES as exc:
            g = None
            why = why or f"pair ({k - 1}, {k}): crash: {type(exc).__name__}: {exc}"
        grav.append(g)
    return _errors_deg(grav, problem.gravity[1:]), time.perf_counter() - t0, why


def run_sequence_task(task: SequenceTask) -> dict:
    """Errors (deg), bounds (deg) and times of one sequence: {rig, run, seed, methods: {method: {...}}}."""
    sc = bench_scenario(task.spec)
    problem = make_sequence(sc, seed=task.seed)
    focal = float(np.mean([c.focal_px for c in problem.rig.cameras]))
    sigma = sc.pixel_noise / focal
    prior = math.radians(sc.gravity_noise_deg)
    out = {"rig": task.rig, "run": task.run, "seed": task.seed, "methods": {}}
    for method in task.methods:
        # the measured gravity's prior std is its simulated noise, for both routes (6pt-bending ignores it)
        est_opts = EstimatorOptions(gravity_prior_sigma=prior)
        bound = sequence_bound(problem, sigma, prior if method == "4pt-bending" else math.inf)
        joint_err, joint_time, joint_why = _joint(problem, method, task.seed, SequenceOptions(estimator=est_opts))
        pair_err, pair_time, pair_why = _pairwise(problem, method, task.seed, est_opts)
        out["methods"][method] = {
            "joint_error_deg": joint_err.tolist(),
            "joint_bound_deg": np.degrees(bound.median_angles("joint")).tolist(),
            "joint_time_s": joint_time, "joint_failure": joint_why,
            "pairwise_error_deg": pair_err.tolist(),
            "pairwise_bound_deg": np.degrees(bound.median_angles("pair")[1:]).tolist(),
            "pairwise_time_s": pair_time, "pairwise_failure": pair_why,
        }
    return out


@contextmanager
def _one_thread_per_worker():
    """Worker processes started meanwhile use one BLAS / OpenMP thread each: they already share the cores."""
    names = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
    saved = {n: os.environ.get(n) for n in names}
    os.environ.update({n: "1" for n in names})
    try:
        yield
    finally:
        for n, v in saved.items():
            if v is None:
                os.environ.pop(n, None)
            else:
                os.environ[n] = v


def _execute(tasks: list[SequenceTask], workers: int, progress: bool) -> list[dict]:
    """Run the tasks on ``workers`` fresh processes with one BLAS thread each; results in task order.

    Always in worker processes, even for one: the number of BLAS threads changes the order of floating-point
    sums, which the robust adjustment can carry into the third digit of an error, so results (and times)
    depend neither on the worker count nor on this process's thread settings.
    """
    import multiprocessing

    from tqdm import tqdm

    bar = tqdm(total=len(tasks), desc="sequence bench", unit="sequence", disable=not progress, dynamic_ncols=True)
    results: list = [None] * len(tasks)
    try:
        # spawned (not forked) workers read the thread limits when they import numpy
        with _one_thread_per_worker(), ProcessPoolExecutor(
                max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = {pool.submit(run_sequence_task, task): i for i, task in enumerate(tasks)}
            try:
                for fut in as_completed(futures):
                    results[futures[fut]] = fut.result()
                    bar.update(1)
            except BaseException:
                for fut in futures:
                    fut.cancel()
                raise
        return results
    finally:
        bar.close()


def _median(values) -> float | None:
    """Median of the defined values (NaN: a crash left none); an unbounded bound (inf) counts."""
    v = np.asarray(values, float)
    v = v[~np.isnan(v)]
    return float(np.median(v)) if len(v) else None


def _ratio(a, b) -> float | None:
    ok = a is not None and b is not None and math.isfinite(a) and math.isfinite(b) and b > 0
    return float(a / b) if ok else None


def summarize_route(records: list[dict], route: str) -> dict:
    """Median per-hold error and bound (deg) of one route over its sequences, their ratio, the success rate
    (every hold within SUCCESS_DEG), the failed estimates and the median time per sequence."""
    err = np.concatenate([r[f"{route}_error_deg"] for r in records])
    bound = np.concatenate([r[f"{route}_bound_deg"] for r in records])
    ok = [bool(np.all(np.asarray(r[f"{route}_error_deg"]) < SUCCESS_DEG)) for r in records]
    failures = [r[f"{route}_failure"] for r in records if r[f"{route}_failure"]]
    med_err, med_bound = _median(err), _median(bound)
    return {"median_error_deg": med_err, "median_bound_deg": med_bound, "error_over_bound": _ratio(med_err, med_bound),
            "success_rate": float(np.mean(ok)), "failures": len(failures),
            "first_failure": failures[0] if failures else None,
            "median_time_s": _median([r[f"{route}_time_s"] for r in records])}


def run_sequence_bench(runs: int = 20, seed: int = 0, rigs=tuple(RIGS), methods=METHODS, workers: int = 1,
                       progress: bool = True) -> dict:
    """Both routes of every method on ``runs`` seeded sequences of every rig; summary and per-run records.

    Returns {runs, seed, workers, scenario (of the first rig, the others differ in rig only), success_deg,
    rigs: {rig: {spec, methods: {method: {joint, pairwise, time_ratio, bound_ratio}}}}, records}.
    ``time_ratio`` is the median over sequences of the batch time over the pairwise route's time,
    ``bound_ratio`` the median pairwise bound over the median joint bound.
    """
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise OptionError(_OWNER, "runs", f"must be an integer >= 1, got {runs!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise OptionError(_OWNER, "seed", f"must be an integer >= 0, got {seed!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise OptionError(_OWNER, "workers", f"must be an integer >= 1, got {workers!r}")
    rigs, methods = tuple(rigs), tuple(methods)
    for name, given, known in (("rigs", rigs, RIGS), ("methods", methods, METHODS)):
        bad = [x for x in given if x not in known]
        if bad or not given or len(set(given)) != len(given):
            what = f"unknown {bad[0]!r}" if bad else "empty or repeated"
            raise OptionError(_OWNER, name, f"{what} (choose from {', '.join(known)})")
    tasks = [SequenceTask(rig, RIGS[rig], k, task_seed(seed, k), methods) for rig in rigs for k in range(runs)]
    records = _execute(tasks, min(workers, len(tasks)), progress)
    out_rigs = {}
    for rig in rigs:
        mine = [r for r in records if r["rig"] == rig]
        per_method = {}
        for m in methods:
            recs = [r["methods"][m] for r in mine]
            d = {route: summarize_route(recs, route) for route in ROUTES}
            d["time_ratio"] = _median([r["joint_time_s"] / r["pairwise_time_s"] for r in recs
                                       if r["pairwise_time_s"] > 0])
            d["bound_ratio"] = _ratio(d["pairwise"]["median_bound_deg"], d["joint"]["median_bound_deg"])
            per_method[m] = d
        out_rigs[rig] = {"spec": dataclasses.asdict(RIGS[rig]), "methods": per_method}
    return {"runs": runs, "seed": seed, "workers": workers, "success_deg": SUCCESS_DEG,
            "scenario": bench_scenario(RIGS[rigs[0]]).to_dict(), "rigs": out_rigs, "records": records}


def format_sequence_table(res: dict) -> str:
    """The markdown table of ``nrmpc bench --sequence``."""
    def f(v, fmt="{:.3g}"):
        return "-" if v is None else fmt.format(v)

    head = ("| rig | method | joint err (deg) | joint CRLB (deg) | joint err/CRLB | joint success | "
            "pair err (deg) | pair CRLB (deg) | pair err/CRLB | pair success | batch time (s) | pairs time (s) | "
            "batch/pairs time |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for rig, d in res["rigs"].items():
        for m, md in d["methods"].items():
            j, p = md["joint"], md["pairwise"]
            cells = [rig, m, f(j["median_error_deg"]), f(j["median_bound_deg"]), f(j["error_over_bound"], "{:.2f}"),
                     f(100 * j["success_rate"], "{:.0f} %"), f(p["median_error_deg"]), f(p["median_bound_deg"]),
                     f(p["error_over_bound"], "{:.2f}"), f(100 * p["success_rate"], "{:.0f} %"),
                     f(j["median_time_s"], "{:.2f}"), f(p["median_time_s"], "{:.2f}"),
                     f(md["time_ratio"], "{:.2f}")]
            lines.append("| " + " | ".join(cells) + " |")
    sc = res["scenario"]
    lines.append("")
    lines.append(f"{res['runs']} seeded sequences per rig (seed {res['seed']}) of {sc['num_views']} holds, "
                 f"{sc['pixel_noise']:g} px, {100 * sc['outlier_fraction']:g} % outliers, measured gravity "
                 f"{sc['gravity_noise_deg']:g} deg (the prior of 4pt-bending). Errors and bounds: medians over "
                 f"every hold of every sequence (joint: holds 0..K-1, pair: hold k of pair (k-1, k)); a hold "
                 f"without gravity counts {FAILED_DEG:g} deg. Success: every hold within {res['success_deg']:g} "
                 "deg. Times: medians per sequence; batch/pairs is the median per-sequence ratio.")
    fails = [f"{rig} {m} {route}: {md[route]['failures']} (first: {md[route]['first_failure']})"
             for rig, d in res["rigs"].items() for m, md in d["methods"].items() for route in ROUTES
             if md[route]["failures"]]
    if fails:
        lines.append("Sequences with a failed estimate: " + "; ".join(fails))
    return "\n".join(lines)


__all__ = ["FAILED_DEG", "METHODS", "RIGS", "ROUTES", "SUCCESS_DEG", "SequenceTask", "bench_scenario",
           "format_sequence_table", "run_sequence_bench", "run_sequence_task", "summarize_route"]
