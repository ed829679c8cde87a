#!/usr/bin/env python3
"""Correspondence error between two holds, per camera model and viewpoint change (docs/RESULTS.md).

    python scripts/bench_correspondence.py [--angles 5,15,30] [--models pinhole,equidistant] [--seeds 0,1]
                                           [--width 320] [--noise 0] [--json out.json]

For every camera model, viewpoint change and scene seed, :func:`nrmpc_ros.experiments.correspondence.compare`
renders a reference hold and a second hold of the textured room, follows the corners through the move as the
front end does, and measures against the ray caster's truth (the projection through the second camera of
the 3D point behind each reference position) the error of the tracks' positions (corners refined again in
the second hold) and of the reference patch aligned in the second hold. The table gives, per method, the
median and 90th percentile of the error's length and the length of the mean error (px), the landmarks
compared and the share the alignment accepted.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from nrmpc_ros.experiments.correspondence import MODELS, compare, summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--angles", default="5,15,30", help="viewpoint changes (deg), comma separated")
    ap.add_argument("--models", default=",".join(MODELS), help="camera models, comma separated")
    ap.add_argument("--seeds", default="0,1", help="scene seeds, comma separated")
    ap.add_argument("--width", type=int, default=320, help="image width (px, 4:3)")
    ap.add_argument("--noise", type=float, default=0.0, help="grey-level noise std added to the images")
    ap.add_argument("--json", help="also write the rows to this JSON file")
    a = ap.parse_args(argv)
    rows = []
    print("| camera | viewpoint change (deg) | landmarks | tracks: median / p90 / mean (px) | aligned: median / "
          "p90 / mean (px) | aligned share | align time (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for model in a.models.split(","):
        for angle in (float(x) for x in a.angles.split(",")):
            trk, aln, ok, t = [], [], [], 0.0
            for seed in (int(s) for s in a.seeds.split(",")):
                r = compare(model, angle, width=a.width, seed=seed, noise=a.noise)
                trk.append(r.tracks)
                aln.append(r.aligned[r.aligned_ok])
                ok.append(r.aligned_ok)
                t += r.align_time_s
            st, sa = summary(np.concatenate(trk)), summary(np.concatenate(aln))
            share = float(np.concatenate(ok).mean())
            rows.append({"model": model, "angle_deg": angle, "tracks": st, "aligned": sa, "aligned_share": share,
                         "align_time_s": t})
            print(f"| {model} | {angle:g} | {st['n']} | {st['median_px']:.3f} / {st['p90_px']:.3f} / "
                  f"{st['mean_px']:.3f} | {sa['median_px']:.3f} / {sa['p90_px']:.3f} / {sa['mean_px']:.3f} | "
                  f"{share:.2f} | {t:.2f} |", flush=True)
    if a.json:
        from nrmpc_ros.safeio import atomic_write

        with atomic_write(a.json, flag="--json") as fp:
            json.dump(rows, fp, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
