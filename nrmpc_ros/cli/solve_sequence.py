"""``nrmpc solve-sequence``: every pose and one gravity from the tracks of a sequence of static views.

One JSON object per tracks file, in order (docs/CONVENTIONS.md, "Command
line"), from :func:`nrmpc_ros.core.sequence.estimate_sequence`: view k's pose
in view 0 (p_0 = R_k p_k + t_k), its body-frame gravity and that gravity's
standard deviation from the joint solution. Every input (rig, options, all
tracks files) is read and checked before the first estimate, so a bad file
ends the command with one error before any result is written.
"""

from __future__ import annotations

import contextlib
import json
import sys

import numpy as np

from ..core import METHODS, load_rig
from ..core.tracks import load_tracks
from ..errors import InputError
from ..safeio import atomic_write, check_output
from .argtypes import seed


def register(sub):
    p = sub.add_parser(
        "solve-sequence", help="estimate every pose and one gravity from tracks .npz files of static views",
        description="Joint estimation over a sequence of static views (one gravity for the whole sequence). "
                    "Prints one JSON object per tracks file, in order: the views' poses in view 0, their "
                    "body-frame gravity and its standard deviation, the inlier count and the estimate's wall "
                    "time. 4pt-bending uses the files' measured gravity (g_meas) as a prior; 6pt-bending is "
                    "vision only.")
    p.add_argument("--rig", required=True, help="rig YAML file")
    p.add_argument("--method", required=True, choices=METHODS)
    p.add_argument("--seed", type=seed, default=0, help="seed of the pairwise starts (default 0, must be >= 0)")
    p.add_argument("--options", metavar="FILE.yaml",
                   help="SequenceOptions fields as a YAML mapping (e.g. max_iterations: 30; estimator: "
                        "{gravity_prior_sigma: 0.005}); unset fields keep their defaults")
    p.add_argument("--out", help="write the results to this file (one JSON object per line) instead of stdout")
    p.add_argument("tracks", nargs="+", metavar="TRACKS.npz")
    p.set_defaults(func=run)


def load_options(path: str | None):
    """SequenceOptions from a YAML mapping of its fields (defaults without a file); errors name file and key."""
    from ..config import from_file
    from ..core.sequence import SequenceOptions

    if path is None:
        return SequenceOptions()
    return from_file(SequenceOptions, path, "sequence options file")


def _needs_gravity(tracks, path: str) -> None:
    """4pt-bending needs measured gravity in at least two views."""
    g = tracks.g_meas
    if g is None:
        raise InputError(path, "4pt-bending needs measured gravity but the file has none; use 6pt-bending for "
                         "vision only", "g_meas")
    if np.count_nonzero(np.all(np.isfinite(g), axis=1)) < 2:
        raise InputError(path, "4pt-bending needs measured gravity in at least two views (rows of NaN = none); "
                         "use 6pt-bending for vision only", "g_meas")


def result_json(est, path: str) -> dict:
    """The result object of one tracks file.

    Two solutions are reported as failures rather than as numbers nobody should use: non-finite poses or
    gravity, and a gravity whose joint information is singular (standard deviation inf: the tracks do not
    constrain it, e.g. bearings without parallax).
    """
    out = est.to_json(path)
    if not est.success:
        return out
    reason = None
    arrays = [est.R, est.t] + ([] if est.gravity is None else [est.gravity])
    if not all(np.all(np.isfinite(a)) for a in arrays):
        reason = "the joint adjustment did not converge (non-finite poses or gravity)"
    elif est.gravity is not None and not np.all(np.isfinite(est.gravity_sigma_rad)):
        reason = "gravity is not observable from these tracks (the joint information is singular)"
    if reason:
        out.update(success=False, views=[], num_inliers=0, reason=reason)
    return out


def run(args) -> int:
    from ..core.sequence import estimate_sequence

    if args.out:
        check_output(args.out, {"--rig": args.rig, "--options": args.options, "TRACKS.npz": args.tracks}, "--out")
    rig = load_rig(args.rig)
    opts = load_options(args.options)
    sequences = []
    for path in args.tracks:
        tracks = load_tracks(path)
        tracks.check_rig(rig)
        if args.method == "4pt-bending":
            _needs_gravity(tracks, path)
        sequences.append((path, tracks))
    with atomic_write(args.out, flag="--out") if args.out else contextlib.nullcontext(sys.stdout) as out:
        for path, tracks in sequences:
            est = estimate_sequence(rig, tracks, args.method, seed=args.seed, options=opts)
            out.write(json.dumps(result_json(est, path), allow_nan=False) + "\n")
            out.flush()
    return 0

