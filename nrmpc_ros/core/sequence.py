"""Joint estimation over a sequence of static views: every pose and ONE gravity (docs/CONVENTIONS.md, "Sequences").

Gravity is fixed in the world, so over K views g_k = R_k^T g_0: the
sequence has one gravity unknown and every view's bending constrains it.
:func:`estimate_sequence` is the entry point:

1. **Initialisation from the pairwise estimators.** The first views
   (``chain_pairs``) are each paired with the nearest earlier view that
   shares enough tracks (the previous one unless it shares too few) and
   estimated with the method's two-view estimator; the pair poses are chained
   into poses in view 0. Each later view is placed by resection
   (:mod:`.resection`) on the landmarks the views before it triangulate, the
   cameras bent at the pairs' gravity candidate that explains those views
   best; the two-view estimator places it only where that fails.
2. **Gravity basin by the joint cost.** Every pair's gravity, and the other
   basins it left open (its refined starts: on parallel bars the bending
   reversed or mirrored), carried into view 0, is a candidate for g_0
   (for ``4pt-bending`` also the measured gravity). Each distinct candidate
   gets a short joint bundle adjustment; the one with the best MSAC score over
   all observations wins, so a pair in the wrong basin cannot capture the
   sequence.
3. **Robust joint bundle adjustment** (:func:`.bundle.adjust_bundle`) over
   all observations, repeated while the inlier set (angular error below the
   inlier threshold) changes. ``4pt-bending`` adds each view's measured
   gravity as a prior (``gravity_prior_sigma``); ``6pt-bending`` is vision
   only; ``6pt-nonbending`` refines the poses of the rigid rig.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import EstimationError
from .bundle import (
    BundleState,
    GravityPriors,
    Observations,
)
from .estimators import METHODS, estimate, pair_method
from .loss import msac_score
from .rig import Rig
from .sequence_steps import (
    Chain,
    PairAttempt,
    SequenceEstimate,
    SequenceOptions,
    Unlinked,
    adjust_sequence,
    choose_gravity,
    distinct_candidates,
    observation_errors,
    resect_on_landmarks,
    tracks_observations,
    triangulated,
)
from .tracks import Tracks


def _failure(method, t0, reason) -> SequenceEstimate:
    return SequenceEstimate(method=method, success=False, time_s=time.perf_counter() - t0, reason=reason)


def _chain_pairs(rig: Rig, tracks: Tracks, method: str, opts: SequenceOptions, seed: int, threshold: float,
                 with_gravity: bool) -> Chain:
    """Poses of every view in view 0 from two-view estimates (the first ``opts.chain_pairs`` views after the
    origin, and any later one resection cannot place) and resection, and gravity candidates for g_0; the chain
    stops at the first view that links to no view before it (:class:`Unlinked`)."""
    K = tracks.num_views
    R, t = [np.eye(3)], [np.zeros(3)]
    candidates, methods = [], []
    pair_opts = opts.pair_estimator()
    bend = {}  # the candidates so far -> the one that bends the cameras of the resections
    for k in range(1, K):
        if opts.chain_pairs is not None and k > opts.chain_pairs:
            placed = _resect_next(rig, tracks, method, np.array(R), np.array(t), candidates, threshold, opts,
                                  seed + k, with_gravity, bend)
            if placed is not None:
                R.append(placed[0])
                t.append(placed[1])
                methods.append(placed[2])
                continue
        why = []
        for j in range(k - 1, max(-1, k - 1 - opts.max_pair_gap), -1):
            m = tracks.pair(j, k)
            cams = len(np.unique(m.cam))
            if len(m) < opts.min_pair_matches or cams < 2:
                why.append(PairAttempt(j, len(m), cams))
                continue
            pm = pair_method(method, m.has_gravity)
            est = estimate(rig, m, method=pm, seed=seed + k, options=pair_opts)
            if not est.success:
                why.append(PairAttempt(j, len(m), cams, estimated=True, failure=est.info.reason))
                continue
            R.append(R[j] @ est.R)
            t.append(R[j] @ est.t + t[j])
            methods.append((pm, j))
            if est.gravity is not None:
                weight = float(est.num_inliers)
                for g in [est.gravity] + list(est.info.gravity_candidates):
                    candidates.append((R[j] @ np.asarray(g, float), weight))
            break
        else:
            return Chain(np.array(R), np.array(t), candidates, methods, Unlinked(k, tuple(why)))
    return Chain(np.array(R), np.array(t), candidates, methods)


def _resect_next(rig: Rig, tracks: Tracks, method: str, R, t, candidates, threshold: float,
                 opts: SequenceOptions, seed: int, with_gravity: bool, bend: dict):
    """(R, t, (method, reference view)) of the next view k = len(R) placed by resection on the landmarks the
    views before it triangulate, the cameras bent at the candidate g_0 that explains those views best (chosen
    once for the candidates so far, kept in ``bend``); None where that fails (no candidate, too few landmarks
    seen twice before, or too few inliers from two cameras)."""
    k = len(R)
    before = tracks.view < k
    gravity = None
    if with_gravity:
        distinct = distinct_candidates(candidates, math.radians(opts.candidate_separation_deg), opts.max_candidates)
        if not distinct:
            return None
        if len(candidates) not in bend:
            obs, _ = Observations.from_arrays(tracks.view[before], tracks.cam[before], tracks.track[before],
                                              tracks.f[before], k)  # a landmark seen once scores 0 for all
            scores = [msac_score(observation_errors(*triangulated(
                rig, obs, BundleState(R, t, g, np.zeros((obs.num_points, 3))))[::-1]), threshold)
                for g in distinct] if len(distinct) > 1 else [0.0]
            bend.clear()
            bend[len(candidates)] = distinct[int(np.argmin(scores))]
        gravity = bend[len(candidates)]
    mine = np.flatnonzero(tracks.view == k)
    seen = np.isin(tracks.track, tracks.track[mine]) & before
    shared = np.bincount(tracks.view[seen], minlength=k)
    j = int(np.argmax(shared))  # the guess: the view that shares most of this view's landmarks
    placed = resect_on_landmarks(rig, (tracks.view[before], tracks.cam[before], tracks.track[before],
                                       tracks.f[before]), R, t, gravity,
                                 (tracks.cam[mine], tracks.track[mine], tracks.f[mine]), (R[j], t[j]), threshold,
                                 opts.min_pair_matches, seed)
    if placed is None:
        return None
    res = placed[0]
    return res.R, res.t, (method, j)


def estimate_sequence(rig: Rig, tracks: Tracks, method: str = "6pt-bending", seed: int = 0,
                      options: SequenceOptions | dict | None = None) -> SequenceEstimate:
    """Poses of every view and one gravity from the tracks of a sequence of static views.

    ``6pt-bending`` is vision only, ``4pt-bending`` adds the tracks' g_meas as priors
    (``options.estimator.gravity_prior_sigma``; views without a measurement have none), ``6pt-nonbending``
    refines the poses of the rig taken as rigid. Deterministic for ``seed``. Raises for an unknown method,
    4pt-bending without measured gravity, or tracks that do not fit the rig; a sequence that cannot be
    estimated returns success False with the reason.
    """
    t0 = time.perf_counter()
    if method not in METHODS:
        raise EstimationError(f"unknown method {method!r} (choose one of {', '.join(METHODS)})")
    opts = options if isinstance(options, SequenceOptions) else SequenceOptions.from_dict(options)
    tracks.check_rig(rig)
    measured = tracks.measured_gravity(rig)
    if method == "4pt-bending" and (measured is None or np.count_nonzero(np.all(np.isfinite(measured), 1)) < 2):
        raise EstimationError(f"{tracks.source}: 4pt-bending needs measured gravity (g_meas) in at least two "
                              "views; use 6pt-bending for vision only")
    model_rig = rig.as_rigid() if method == "6pt-nonbending" else rig
    with_gravity = method != "6pt-nonbending" and rig.is_flexible
    K = tracks.num_views
    if K < 2:
        return _failure(method, t0, "needs at least two views")
    focal = float(np.mean([c.focal_px for c in rig.cameras]))
    threshold = opts.estimator.threshold_px / focal
    chained = _chain_pairs(model_rig, tracks, method, opts, seed, threshold, with_gravity)
    if chained.unlinked is not None:
        return _failure(method, t0, str(chained.unlinked))
    R, t, cands, pair_methods = chained.R, chained.t, chained.candidates, chained.methods
    obs, obs_index = tracks_observations(tracks)
    if len(obs) == 0:
        return _failure(method, t0, "no track is seen in two views")
    priors = None
    if method == "4pt-bending" and math.isfinite(opts.estimator.gravity_prior_sigma):
        priors = GravityPriors(measured, opts.estimator.gravity_prior_sigma, opts.gravity_bias_sigma)
    gravity, n_cand = None, 0
    if with_gravity:
        if method == "4pt-bending":
            cands += [(R[k] @ measured[k], 0.0) for k in range(K) if np.all(np.isfinite(measured[k]))]
        distinct = distinct_candidates(cands, math.radians(opts.candidate_separation_deg), opts.max_candidates)
        if not distinct:
            return _failure(method, t0, "no pair gave a gravity estimate")
        rng = np.random.default_rng(seed)
        chosen, n_cand = choose_gravity(model_rig, obs, R, t, distinct, priors, threshold, opts, rng)
        if isinstance(chosen, np.ndarray):
            gravity = chosen
        else:
            R, t, gravity = chosen.R, chosen.t, chosen.gravity
    out = adjust_sequence(model_rig, tracks, obs, obs_index, R, t, gravity, with_gravity, method, priors, threshold,
                          opts, seed, t0)
    out.pair_methods, out.candidates = pair_methods, n_cand
    return out


__all__ = ["SequenceEstimate", "SequenceOptions", "estimate_sequence"]
