#!/usr/bin/env python3
"""Where a cell of the matrix leaves its Cramér-Rao bound: the data or the search.

    python scripts/bench_bound_gap.py --out /tmp/nrmpc_bench_matrix --bag imu200-ring3-stiff-0
                                      [--method 6pt-bending] [--cuts 3,5,10,30]

On a bag of ``scripts/bench_holds.py`` (kept in ``--out`` beside its rig file), replay the method, take the
final sequence's inlier observations and the ground truth of its holds, and print:

- the distances of the bearings from their landmarks triangulated at the truth (percentiles, px);
- the gravity error of the joint adjustment of those observations started at the truth: least squares at
  the noise the pipeline measured (averaged track noise and the correspondence-bias floor), and with the
  Huber loss at its a posteriori noise -- where the data's own minimum lies;
- the same least squares on the bearings within c times the bulk spread of the truth distances, beside
  the bound at that spread;
- the same cut without the truth: the distances at the pipeline's own final solution, three rounds.

The first and last holds' gravity errors are printed (deg).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_holds as bh  # noqa: E402

from nrmpc_ros.core import load_rig  # noqa: E402
from nrmpc_ros.core.bundle import BundleState, Observations, adjust_bundle  # noqa: E402
from nrmpc_ros.core.sequence_steps import triangulated  # noqa: E402
from nrmpc_ros.core.so3 import angle_between  # noqa: E402
from nrmpc_ros.experiments.crlb import observed_sequence_bound  # noqa: E402

RAYLEIGH = math.sqrt(2.0 * math.log(2.0))  # median length of a 2-D Gaussian of unit std per axis


def _errors(state, truth_g) -> np.ndarray:
    g = state.view_gravity
    return np.array([math.degrees(angle_between(g[k], truth_g[k])) for k in (0, len(g) - 1)])


def _multi_view(obs: Observations) -> Observations:
    seen = np.zeros((obs.num_points, obs.num_views), bool)
    seen[obs.point, obs.view] = True
    return obs.subset((seen.sum(axis=1) >= 2)[obs.point])[0]


def _distances(rig, obs, R, t, g):
    state, prob = triangulated(rig, obs, BundleState(R, t, g, np.zeros((obs.num_points, 3))))
    return np.linalg.norm(prob.residuals(state), axis=1) * (1.0 if obs.scale is None else obs.scale)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder of the matrix's bags and rig files")
    p.add_argument("--bag", required=True, help="bag folder name, <style>-<rig>-<seed>")
    p.add_argument("--method", default="6pt-bending")
    p.add_argument("--cuts", default="3,5,10,30", help="multiples of the bulk spread kept")
    args = p.parse_args(argv)
    out = Path(args.out)
    rig_name = args.bag.rsplit("-", 1)[0].split("-", 1)[1]
    rig = load_rig(out / f"{rig_name}.yaml")
    ests: list = []
    _, ref, pipe, _, _ = bh.replay_rows(out / args.bag, rig, args.method, keep=ests)
    seq, s = pipe.sequence, pipe.sequence.seq
    stamps = {}
    for e in ests:
        if e.sequence == s.number:
            stamps[0] = e.origin_stamp
            stamps[e.hold_index] = e.stamp
    K = s.num_views
    if sorted(stamps) != list(range(K)):
        print(f"the final sequence's holds lack stamps ({sorted(stamps)} of {K})")
        return 1
    truth = [bh._truth_at(ref, stamps[v]) for v in range(K)]
    Rw0, pw0, g0 = truth[0]
    R = np.array([Rw0.T @ Rw for Rw, _, _ in truth])
    t = np.array([Rw0.T @ (pw - pw0) for _, pw, _ in truth])
    gk = np.array([g for _, _, g in truth])
    view, cam, track, f, inl = s.arrays()
    holds = {h.stamp: h for h in pipe.measured_holds}
    sigma = np.empty(len(view))
    for v in range(K):
        mine = view == v
        sigma[mine] = bh._hold_camera_noise_rad(rig, holds[stamps[v]], cam[mine], seq.noise_rad, False)
    nominal = float(np.median(sigma[inl]))
    obs, _ = Observations.from_arrays(view[inl], cam[inl], track[inl], f[inl], K, sigma[inl] / nominal)
    bound = observed_sequence_bound(rig, obs, R, t, g0, nominal, outlier_rad=seq.threshold)
    obs = obs.subset(bound.used)[0]
    focal = float(np.median([c.focal_px for c in rig.cameras]))
    print(f"{args.bag} {args.method}: {K} holds, {len(obs)} observations, {obs.num_points} landmarks; "
          f"bound at the tracks' noise (first, last hold) {np.degrees(bound.median_angles())[[0, -1]].round(3)}")
    d = _distances(rig, obs, R, t, g0) * focal
    print("distances at the truth, percentiles 50/75/90/95/99/100 (px):",
          np.percentile(d, [50, 75, 90, 95, 99, 100]).round(3))
    ls = adjust_bundle(rig, obs, R, t, g0, sigma_rad=nominal, huber_k=1e6, max_iterations=200, tol=1e-13)
    hub = adjust_bundle(rig, obs, R, t, g0, max_iterations=200, tol=1e-13)
    print(f"from the truth: least squares {_errors(ls.state, gk).round(3)}, Huber {_errors(hub.state, gk).round(3)} "
          f"(a posteriori noise {hub.sigma_rad * focal:.3f} px); the pipeline's own "
          f"{np.round([math.degrees(angle_between(s.views[k].R.T @ s.gravity, gk[k])) for k in (0, K - 1)], 3)}")
    bulk = float(np.median(d)) / RAYLEIGH
    for c in (float(x) for x in args.cuts.split(",")):
        keep = _multi_view(obs.subset(d < c * bulk)[0])
        res = adjust_bundle(rig, keep, R, t, g0, sigma_rad=nominal, huber_k=1e6, max_iterations=200, tol=1e-13)
        b = observed_sequence_bound(rig, keep, R, t, g0, bulk / focal)
        print(f"within {c:g} x the bulk ({bulk:.3f} px), {np.mean(d < c * bulk):.0%} kept: "
              f"{_errors(res.state, gk).round(3)}, bound at the bulk {np.degrees(b.median_angles())[[0, -1]].round(3)}")
    (Rp, tp), gp = s.poses(), s.gravity
    for r in range(3):
        dp = _distances(rig, obs, Rp, tp, gp) * focal
        bp = float(np.median(dp)) / RAYLEIGH
        keep = _multi_view(obs.subset(dp < 5 * bp)[0])
        res = adjust_bundle(rig, keep, Rp, tp, gp, sigma_rad=nominal, huber_k=1e6, max_iterations=200, tol=1e-13)
        Rp, tp, gp = res.state.R, res.state.t, res.state.gravity
        print(f"without the truth, round {r}: within 5 x the bulk ({bp:.3f} px) of the pipeline's solution, "
              f"{np.mean(dp < 5 * bp):.0%} kept: {_errors(res.state, gk).round(3)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
