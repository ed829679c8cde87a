"""The paper's section 4 experiments as grids for the Monte Carlo runner, with CSV, PNG and markdown output.

- ``noise-ei``: pixel noise 0-0.2 px x EI 0.1-10 N m^2, all three methods (paper Figs. 4, 5 and 8).
- ``outliers``: outlier fraction 0-0.4 at EI 0.1, 0.1 px (Figs. 6 and 9).
- ``gravity-noise``: gravity-measurement noise 0-0.1 px for 4pt-bending (Figs. 7 and 10).

Fixed values follow the paper: 5% outliers, gravity noise 0.01 px, N = 1000,
VGA f = 800 px, bars 0.4 m with 0.1 kg tips; pixel noise 0.1 px and
EI = 0.1 where the paper's text does not fix them.
"""

from __future__ import annotations

import csv
import itertools
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import METHODS
from ..core.rig import Rig
from ..errors import InputError, OptionError
from ..safeio import atomic_write, check_output
from ..sim.synthetic import RigSpec, Scenario, default_layout
from .runner import ERROR_KINDS, Task, execute, summarize, task_seed


@dataclass(frozen=True)
class Experiment:
    name: str
    axes: dict  # axis name -> default values
    methods: tuple
    figures: str  # paper figures reproduced
    description: str


EXPERIMENTS = {
    "noise-ei": Experiment("noise-ei", {"pixel_noise": (0.0, 0.05, 0.1, 0.15, 0.2), "EI": (0.1, 0.3, 1.0, 3.0, 10.0)},
                           METHODS, "Figs. 4, 5 (4 cameras) and 8 (2 cameras)",
                           "errors and success rate over pixel noise x bar rigidity EI"),
    "outliers": Experiment("outliers", {"outlier_fraction": (0.0, 0.1, 0.2, 0.3, 0.4)}, METHODS,
                           "Figs. 6 (4 cameras) and 9 (2 cameras)", "errors over the outlier fraction"),
    "gravity-noise": Experiment("gravity-noise", {"gravity_noise_px": (0.0, 0.02, 0.04, 0.06, 0.08, 0.1)},
                                ("4pt-bending",), "Figs. 7 (4 cameras) and 10 (2 cameras)",
                                "4pt-bending errors over the gravity-measurement noise"),
}

AXIS_LABELS = {"pixel_noise": "pixel noise (px)", "EI": "EI (N m^2)", "outlier_fraction": "outlier fraction",
               "gravity_noise_px": "gravity noise (px)"}
QUICK_RUNS = 30
_OWNER = "experiment"  # how OptionError names this module's options


def base_scenario(cameras: int) -> Scenario:
    """The paper's nominal case for ``cameras`` cameras (cross for 4, ring otherwise)."""
    return Scenario(rig=RigSpec(num_cameras=cameras, layout=default_layout(cameras)), pixel_noise=0.1,
                    outlier_fraction=0.05, gravity_noise_px=0.01, gravity_frame="camera")


def _cell_scenario(base: Scenario, params: dict) -> Scenario:
    d = base.to_dict()
    for key, value in params.items():
        if key == "EI":
            d["rig"]["EI"] = float(value)
        else:
            d[key] = float(value)
    return Scenario.from_dict(d)


def make_tasks(exp: Experiment, cameras: int, runs: int, seed: int, axes: dict | None = None,
               methods: tuple | None = None, rig: Rig | None = None, num_points: int | None = None,
               options: dict | None = None) -> tuple[list[Task], list[dict]]:
    """All (cell, run) tasks of an experiment; ``axes`` overrides grid values, ``rig`` replaces the simulated rig."""
    if runs < 1:
        raise OptionError(_OWNER, "runs", f"must be >= 1, got {runs}")
    axes = dict(exp.axes if axes is None else axes)
    for key, values in axes.items():
        if not values:
            raise OptionError(_OWNER, key, "needs at least one value")
        if any(not math.isfinite(v) and key != "EI" for v in values) or any(v < 0 for v in values):
            raise OptionError(_OWNER, key, f"values must be finite and >= 0, got {list(values)}")
        if key == "outlier_fraction" and any(v >= 1 for v in values):
            raise OptionError(_OWNER, key, "outlier fractions must be < 1")
        if key == "EI" and any(v <= 0 for v in values):
            raise OptionError(_OWNER, key, "EI must be > 0 (inf = rigid)")
    methods = tuple(methods or exp.methods)
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise OptionError(_OWNER, "methods", f"unknown method {bad[0]!r} (choose from {', '.join(METHODS)})")
    if rig is not None:
        cameras = rig.num_cameras
    base = base_scenario(cameras)
    if num_points is not None:
        if num_points < 12:
            raise OptionError(_OWNER, "num_points", f"must be >= 12, got {num_points}")
        base.num_points = int(num_points)
    names = list(axes)
    cells = [dict(zip(names, combo)) for combo in itertools.product(*(axes[n] for n in names))]
    tasks = []
    for r in range(runs):
        s = task_seed(seed, r)
        for i, params in enumerate(cells):
            sc = _cell_scenario(base, params)
            rig_d = None
            if rig is not None:
                rig_d = (rig.with_bar_ei(params["EI"]) if "EI" in params else rig).to_dict()
            tasks.append(Task(cell=i, params={"cameras": cameras, **params}, scenario=sc.to_dict(), run=r, seed=s,
                              methods=methods, rig=rig_d, options=options))
    return tasks, cells


# ---------------------------------------------------------------------------
# output
# ---------------------------------------------------------------------------

def write_csv(rows: list[dict], path: Path) -> None:
    """Rows as CSV, written atomically (nrmpc_ros.safeio.atomic_write)."""
    if not rows:
        return
    with atomic_write(path, newline="", flag="--out") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


def output_files(name: str, stem: Path) -> list[Path]:
    """Every file an experiment writes beside ``stem`` (``<out>/<name>-<M>cam``): CSVs, plots, markdown."""
    images = ["_errors.png", "_success.png"] if name == "noise-ei" else [".png"]
    return [stem.with_name(stem.name + suffix) for suffix in ("_runs.csv", "_summary.csv", *images, ".md")]


def _series(summary, method, axis, fixed: dict, stat: str):
    pts = sorted((r[axis], r[stat]) for r in summary
                 if r["method"] == method and all(r[k] == v for k, v in fixed.items()))
    return np.array([p[0] for p in pts], float), np.array([p[1] for p in pts], float)


def plot_noise_ei(summary, axes: dict, methods, path: Path, title: str) -> list[Path]:
    """Errors (rows) x methods (columns) over pixel noise, one line per EI; and success rate over EI."""
    from ..plots import draw_note, draw_series, figure, positive, pyplot, save_png

    eis = sorted(axes["EI"])
    cmap = pyplot().get_cmap("viridis")
    colours = {ei: cmap(i / max(len(eis) - 1, 1)) for i, ei in enumerate(eis)}
    fig, axs = figure(3, len(methods), figsize=(3.3 * len(methods), 7.2), squeeze=False, sharex=True)
    for j, method in enumerate(methods):
        for i, kind in enumerate(ERROR_KINDS):
            series = []
            for ei in eis:
                for stat, ls in (("mean", ".-"), ("median", ".--")):
                    x, y = _series(summary, method, "pixel_noise", {"EI": ei}, f"{kind}_{stat}_success")
                    series.append((x, positive(y), ls, colours[ei], f"EI {ei:g} {stat}" if (i, j) == (0, 0) else None))
            no_gravity = kind == "gravity" and method == "6pt-nonbending"
            draw_series(axs[i, j], [] if no_gravity else series, f"{kind} error (rad)" if j == 0 else "",
                        xlabel=AXIS_LABELS["pixel_noise"] if i == 2 else None, title=method if i == 0 else None,
                        logy=not no_gravity)
            if no_gravity:
                draw_note(axs[i, j], "no gravity")
    handles, labels = axs[0, 0].get_legend_handles_labels()
    if axs[0, 0].get_legend():
        axs[0, 0].get_legend().remove()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(eis) * 2, 6), fontsize=7, frameon=False)
    fig.suptitle(f"{title}: mean (solid) and median (dashed) over successful runs", fontsize=9)
    fig.tight_layout(rect=(0, 0.06, 1, 0.97))
    p1 = path.with_name(path.name + "_errors.png")
    save_png(fig, p1, "--out", dpi=80)

    noises = sorted(axes["pixel_noise"])
    fig, axs = figure(1, len(methods), figsize=(3.3 * len(methods), 2.8), squeeze=False, sharey=True)
    ncm = pyplot().get_cmap("plasma")
    for j, method in enumerate(methods):
        series = []
        for k, nz in enumerate(noises):
            x, y = _series(summary, method, "EI", {"pixel_noise": nz}, "success_rate")
            series.append((x, 100 * y, "-o", ncm(k / max(len(noises), 1)), f"{nz:g} px" if j == len(methods) - 1
                           else None))
        draw_series(axs[0, j], series, "success rate (%)" if j == 0 else "", xlabel=AXIS_LABELS["EI"],
                    title=method, logx=True)
        axs[0, j].set_ylim(-3, 103)
    fig.suptitle(f"{title}: success rate (rotation < 0.5 rad and translation < 0.2 rad)", fontsize=9)
    fig.tight_layout()
    p2 = path.with_name(path.name + "_success.png")
    save_png(fig, p2, "--out", dpi=80)
    return [p1, p2]


def plot_line(summary, axis: str, methods, path: Path, title: str) -> list[Path]:
    """Errors (mean solid, median dashed, successful runs) and success rate over one axis, a line per method."""
    from ..plots import METHOD_COLOURS, draw_series, figure, positive, save_png

    fig, axs = figure(1, 4, figsize=(12, 2.9))
    for i, kind in enumerate(ERROR_KINDS):
        series = []
        for method in methods:
            if kind == "gravity" and method == "6pt-nonbending":
                continue
            for stat, ls in (("mean", ".-"), ("median", ".--")):
                x, y = _series(summary, method, axis, {}, f"{kind}_{stat}_success")
                series.append((x, positive(y), ls, METHOD_COLOURS.get(method), f"{method} {stat}" if i == 0 else None))
        draw_series(axs[i], series, "", xlabel=AXIS_LABELS[axis], title=f"{kind} error (rad)", logy=True)
    series = []
    for method in methods:
        x, y = _series(summary, method, axis, {}, "success_rate")
        series.append((x, 100 * y, "-o", METHOD_COLOURS.get(method), None))
    draw_series(axs[3], series, "", xlabel=AXIS_LABELS[axis], title="success rate (%)")
    axs[3].set_ylim(-3, 103)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    p = path.with_name(path.name + ".png")
    save_png(fig, p, "--out", dpi=80)
    return [p]


def _fmt(v, scale=1.0, digits=3):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v * scale:.{digits}g}"


def claims(exp: Experiment, summary: list[dict]) -> list[str]:
    """Measured facts that bear on the paper's statements (RESULTS.md compares them)."""
    lines = []
    by_method: dict = {}
    for r in summary:
        by_method.setdefault(r["method"], []).append(r)
    for method, rs in by_method.items():
        rates = [r["success_rate"] for r in rs]
        lines.append(f"- `{method}`: success rate {100 * min(rates):.0f}% to {100 * max(rates):.0f}% over the grid; "
                     f"median time {1000 * float(np.median([r['time_median_s'] for r in rs])):.0f} ms")
    crashes: dict = {}
    for r in summary:
        crashes[r["method"]] = crashes.get(r["method"], 0) + r.get("crashes", 0)
    for method, n in crashes.items():
        if n:
            lines.append(f"- `{method}`: {n} run(s) raised an exception inside the estimator (counted as failures; "
                         "see the `error` column of the runs CSV)")
    if exp.name == "noise-ei":
        eis = sorted({r["EI"] for r in summary})
        for method, rs in by_method.items():
            lo = np.mean([r["success_rate"] for r in rs if r["EI"] == eis[0]])
            hi = np.mean([r["success_rate"] for r in rs if r["EI"] == eis[-1]])
            lines.append(f"- `{method}`: mean success {100 * lo:.0f}% at EI {eis[0]:g} -> {100 * hi:.0f}% at EI "
                         f"{eis[-1]:g}")
    return lines


def markdown(exp: Experiment, summary, settings: dict, images: list[Path], keys: tuple) -> str:
    lines = [f"# `nrmpc experiment {exp.name}`", "", f"{exp.description} (paper {exp.figures}).", ""]
    lines += ["| setting | value |", "| --- | --- |"]
    lines += [f"| {k} | {v} |" for k, v in settings.items()]
    lines += ["", "## Findings", ""] + claims(exp, summary)
    lines += ["", "## Plots", ""] + [f"![{p.stem}]({p.name})" for p in images]
    lines += ["", "## Summary (errors in mrad; 'ok' = over successful runs, 'all' = over all runs)", ""]
    head = list(keys) + ["method", "success %", "rot med ok", "rot mean ok", "trans med ok", "trans mean ok",
                         "grav med ok", "grav mean ok", "rot med all", "trans med all", "grav med all", "time ms"]
    lines += ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in summary:
        cells = [_fmt(r[k]) for k in keys] + [r["method"], f"{100 * r['success_rate']:.0f}"]
        for kind in ERROR_KINDS:
            cells += [_fmt(r[f"{kind}_median_success"], 1e3), _fmt(r[f"{kind}_mean_success"], 1e3)]
        cells += [_fmt(r[f"{k}_median_all"], 1e3) for k in ERROR_KINDS]
        cells.append(_fmt(r["time_median_s"], 1e3))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def run_experiment(name: str, out_dir, cameras: int = 4, runs: int = QUICK_RUNS, seed: int = 0, workers: int = 1,
                   scheduler: str | None = None, axes: dict | None = None, methods: tuple | None = None,
                   rig: Rig | None = None, num_points: int | None = None, progress: bool = True,
                   command: str | None = None, inputs: dict | None = None) -> dict:
    """Run one experiment and write ``<name>-<M>cam_{runs,summary}.csv``, PNG plots and ``<name>-<M>cam.md``.

    ``out_dir`` may hold other files, so each output is written atomically on its own (complete or absent);
    none may be one of ``inputs`` ({flag: path}, checked before anything runs)."""
    if name not in EXPERIMENTS:
        raise InputError("experiment", f"unknown experiment {name!r} (choose from {', '.join(EXPERIMENTS)})")
    exp = EXPERIMENTS[name]
    if cameras < 2 and rig is None:
        raise OptionError(_OWNER, "cameras", f"needs at least 2 cameras (metric scale), got {cameras}")
    tasks, cells = make_tasks(exp, cameras, runs, seed, axes, methods, rig, num_points)
    cameras = tasks[0].params["cameras"]
    out = Path(out_dir)
    stem = out / f"{name}-{cameras}cam"
    check_output(out, inputs or {}, "--out", directory=True)
    for path in output_files(name, stem):
        check_output(path, inputs or {}, "--out")
    t0 = time.perf_counter()
    rows = execute(tasks, workers=workers, scheduler=scheduler, progress=progress, desc=f"{name} ({cameras} cams)")
    wall = time.perf_counter() - t0
    keys = ("cameras",) + tuple(cells[0])
    summary = summarize(rows, keys)
    write_csv(rows, stem.with_name(stem.name + "_runs.csv"))
    write_csv(summary, stem.with_name(stem.name + "_summary.csv"))
    used_methods = tuple(tasks[0].methods)
    title = f"{name}, {cameras} cameras, {runs} runs per cell"
    if name == "noise-ei":
        images = plot_noise_ei(summary, {k: sorted({c[k] for c in cells}) for k in cells[0]}, used_methods, stem,
                               title)
    else:
        images = plot_line(summary, next(iter(cells[0])), used_methods, stem, title)
    settings = {
        "command": f"`{command}`" if command else "-", "cameras": cameras, "runs per cell": runs,
        "cells": len(cells), "problems": len(tasks), "seed": seed,
        "executor": f"dask at {scheduler}" if scheduler else f"{workers} local process(es)",
        "wall time": f"{wall:.1f} s", "rig": rig.source if rig is not None else "simulated (paper set-up)",
    }
    md = stem.with_name(stem.name + ".md")
    with atomic_write(md, flag="--out") as fh:
        fh.write(markdown(exp, summary, settings, images, keys[1:]))
    return {"rows": rows, "summary": summary, "wall_s": wall, "markdown": md, "images": images,
            "csv": [stem.with_name(stem.name + "_runs.csv"), stem.with_name(stem.name + "_summary.csv")]}


__all__ = ["EXPERIMENTS", "QUICK_RUNS", "Experiment", "base_scenario", "make_tasks", "run_experiment"]
