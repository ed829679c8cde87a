"""``nrmpc solve``: run an estimator on matches files (docs/CONVENTIONS.md (Command line))."""

from __future__ import annotations

import contextlib
import json
import sys

from ..core import METHODS, estimate, load_matches, load_rig
from ..safeio import atomic_write, check_output
from .argtypes import seed


def register(sub):
    p = sub.add_parser("solve", help="estimate relative pose (and gravity) from matches .npz files",
                       description="Prints one result object (JSON, docs/CONVENTIONS.md: Files) per matches "
                       "file, in order.")
    p.add_argument("--rig", required=True, help="rig YAML file (docs/CONVENTIONS.md (Files))")
    p.add_argument("--method", required=True, choices=METHODS)
    p.add_argument("--seed", type=seed, default=0, help="RANSAC seed (default 0)")
    p.add_argument("--out", help="write results to this file (one JSON object per line) instead of stdout; it "
                   "appears only when every file was solved")
    p.add_argument("matches", nargs="+", metavar="MATCHES.npz")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.out:
        check_output(args.out, {"--rig": args.rig, "MATCHES.npz": args.matches}, "--out")
    rig = load_rig(args.rig)
    with atomic_write(args.out, flag="--out") if args.out else contextlib.nullcontext(sys.stdout) as out:
        for path in args.matches:
            m = load_matches(path, rig)
            est = estimate(rig, m, method=args.method, seed=args.seed)
            out.write(json.dumps(est.to_json(path)) + "\n")
            out.flush()
    return 0
