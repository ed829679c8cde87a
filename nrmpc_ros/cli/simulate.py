"""``nrmpc simulate``: synthetic rig, matches or tracks, and ground truth (paper section 4 set-up).

Writes into --out: ``rig.yaml`` (docs/CONVENTIONS.md (Files)), ``<prefix>_NNN.npz`` and
``<prefix>_NNN.truth.json`` for --count problems with seeds seed, seed+1, ...
Two-view problems (the default) give matches files (docs/CONVENTIONS.md (Files)) and truth
with R, t, gravity in both views and the outlier indices; ``--sequence``
gives sequences of static views instead: tracks files (see
:mod:`nrmpc_ros.core.tracks`) and truth with R_k, t_k and g_k per view, g_0
and the outlier observation indices (:class:`nrmpc_ros.sim.sequence.SequenceProblem`).
Every truth file also holds the scenario and the seed. The scenario comes
from flags, from a YAML scenario file (the fields of
:class:`nrmpc_ros.sim.synthetic.Scenario`, or with --sequence of
:class:`nrmpc_ros.sim.sequence.SequenceScenario`, plus optional ``seed``,
``count`` and ``rig_file``), or both (flags win).

Outputs: --out is a directory that may already hold other files (several
runs write into one), so it is not replaced as a whole; each file is written
atomically instead (complete or absent, never half-written), and every file
name is checked against the inputs before the first one is written.

The scenario flags are :mod:`nrmpc_ros.cli.common`'s; the scenarios are
built by :mod:`nrmpc_ros.sim.scenarios`.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError
from ..safeio import atomic_write, check_output
from .argtypes import positive_int, seed
from .common import (
    add_scenario_arguments,
    add_sequence_arguments,
    check_mode_flags,
    jsonable,
    scenario_from_args,
    sequence_scenario_from_args,
)

MAX_COUNT = 100_000  # problems per run: each is its own pair of files


def register(sub):
    p = sub.add_parser(
        "simulate", help="write a synthetic rig, matches (or tracks) .npz and ground-truth JSON",
        description="Draws --count seeded two-view problems of a bending rig (the paper's section 4 set-up), or "
                    "with --sequence sequences of static views with landmark tracks, and writes rig.yaml, "
                    "<prefix>_NNN.npz and <prefix>_NNN.truth.json into --out. "
                    "Solve pairs with: nrmpc solve --rig OUT/rig.yaml --method 4pt-bending OUT/*.npz")
    p.add_argument("--out", required=True, help="output directory (created if missing); each file in it is written "
                   "atomically")
    p.add_argument("--seed", type=seed, help="seed of the first problem (default 0); problem k uses seed + k")
    p.add_argument("--count", type=positive_int, help="number of problems (default 1)")
    p.add_argument("--prefix", help="file name prefix (default: pair, or seq with --sequence)")
    add_scenario_arguments(p)
    add_sequence_arguments(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core import save_matches, save_rig
    from ..sim.synthetic import make_problem, make_rig

    sequence = bool(getattr(args, "sequence", False))
    check_mode_flags(args, sequence)
    sc, rig, extras = (sequence_scenario_from_args if sequence else scenario_from_args)(args)
    seed = args.seed if args.seed is not None else int(extras.get("seed", 0))
    count = args.count if args.count is not None else int(extras.get("count", 1))
    prefix = args.prefix if args.prefix is not None else ("seq" if sequence else "pair")
    if count > MAX_COUNT:
        raise InputError("--count" if args.count is not None else args.scenario, f"must be <= {MAX_COUNT}, got "
                         f"{count}", None if args.count is not None else "count")
    if not prefix or "/" in prefix or prefix in (".", ".."):
        raise InputError("--prefix", f"must be a plain file name prefix, got {prefix!r}")
    out = Path(args.out)
    width = max(3, len(str(count - 1)))
    names = [f"{prefix}_{k:0{width}d}" for k in range(count)]
    inputs = {"--rig": args.rig, "--scenario": args.scenario, "rig_file of --scenario": extras.get("rig_file")}
    check_output(out, inputs, "--out", directory=True)
    for path in [out / "rig.yaml"] + [out / f"{n}{ext}" for n in names for ext in (".npz", ".truth.json")]:
        check_output(path, inputs, "--out")
    rig = rig if rig is not None else make_rig(sc.rig)
    rig_path = out / "rig.yaml"
    save_rig(rig, rig_path, header=f"written by nrmpc simulate; scenario: {json.dumps(sc.to_dict())}", flag="--out")
    for k, name in enumerate(names):
        s = seed + k
        if sequence:
            from ..core.tracks import save_tracks
            from ..sim.sequence import make_sequence

            seq = make_sequence(sc, seed=s, rig=rig)
            save_tracks(seq.tracks, out / f"{name}.npz", flag="--out")
            truth = {"tracks": f"{name}.npz", "rig": "rig.yaml", "seed": s, **seq.truth_dict()}
        else:
            problem = make_problem(sc, seed=s, rig=rig)
            save_matches(problem.matches, out / f"{name}.npz", flag="--out")
            truth = {"matches": f"{name}.npz", "rig": "rig.yaml", "seed": s, **problem.truth_dict()}
        truth["scenario"] = jsonable(sc.to_dict())
        with atomic_write(out / f"{name}.truth.json", flag="--out") as fh:
            fh.write(json.dumps(truth) + "\n")
    kind = "sequence" if sequence else "problem"
    print(f"wrote {rig_path} and {count} {kind}(s) {prefix}_*.npz / .truth.json to {out}")
    return 0

