"""The joint estimate, view by view: a sliding window over the newest views of a sequence.

:class:`IncrementalSequence` takes the observations of one static view at a
time (camera, landmark id, bearing, optionally measured gravity) and returns
that view's pose in the sequence origin (view 0) and its gravity from the
joint solution (docs/PIPELINE.md, "The joint estimate over the sequence"):

1. The new view is paired with the newest earlier view that shares enough
   landmarks (seen by two cameras at least). While the sequence is young it
   is estimated with the two-view estimator of the method and its pose in
   the origin follows by chaining; later it is placed by resection on the
   landmarks the window's earlier views triangulate (:mod:`.resection`; the
   two-view estimator only where too few of them fit).
2. Gravity: the first pair's gravity candidates (its own and the basins it
   left open) are compared by the joint cost; while the sequence is young,
   or when a new pair's gravity contradicts the joint one beyond that pair's
   own noise, the joint gravity competes again with the pair's candidates.
3. The newest ``window`` views are adjusted jointly (robust bundle adjustment
   with inlier classification, :func:`.sequence.refine_sequence`; after a
   resection from the inliers so far, the rest of the window being adjusted
   already); older
   views keep their poses. Their observations of landmarks the window still
   sees stay in the problem (with those fixed poses); landmarks the window
   no longer sees are condensed, poses fixed, into information on the
   origin's gravity (:func:`.bundle.condense_gravity`) that every later solve
   uses as a prior. So every observation counts once and the problem stays
   the size of the window.

:meth:`IncrementalSequence.batch` adjusts all views of the sequence at once
from the incremental result. A view that shares too few landmarks with the
views before it starts a new sequence (its gravity is unknown again).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .bundle import BundleState, GravityInformation, GravityPriors, Observations, condense_gravity
from .estimators import estimate
from .matches import Matches
from .rig import Rig
from .sequence import (
    RIGID_REASON,
    SequenceEstimate,
    SequenceOptions,
    choose_gravity,
    distinct_candidates,
    refine_sequence,
    repair_links,
    resect_on_landmarks,
    triangulated,
)
from .so3 import angle_between, normalize
from .tracks import Tracks

RECONSIDER_SIGMAS = 3.0  # a pair's gravity contradicts the joint one beyond this many of its own stds only


@dataclass
class ViewEstimate:
    """One view of a sequence: pose in the origin (p_0 = R p + t), gravity in its body frame from the joint
    solution (m/s^2) with its largest angular std, and how it was obtained."""

    sequence: int  # sequence number (a reset or a break starts the next)
    view: int  # index in the sequence (0 = origin)
    reference: int  # the view it was paired with
    method: str  # two-view method of that pair
    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray | None
    gravity_sigma_rad: float
    cov_gravity: np.ndarray | None  # (3, 3) m^2/s^4, rank 2
    cov_pose: np.ndarray  # (6, 6) over (dr in the body frame, t in the origin)
    num_observations: int
    num_inliers: int
    window: int  # views adjusted in this solve
    time_s: float


@dataclass
class SequenceRecord:
    """What a sequence measured and estimated: its tracks (with measured gravity), the views' poses in its
    origin, the origin's gravity and each view's measured-gravity std (rad)."""

    tracks: Tracks
    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray | None
    measured_sigma: np.ndarray


@dataclass
class _Sequence:
    """Everything one sequence has seen and estimated."""

    number: int
    view: list = field(default_factory=list)  # per view: (n,) arrays
    cam: list = field(default_factory=list)
    track: list = field(default_factory=list)
    f: list = field(default_factory=list)
    measured: list = field(default_factory=list)  # per view (3,) or NaN
    measured_sigma: list = field(default_factory=list)
    R: list = field(default_factory=list)
    t: list = field(default_factory=list)
    gravity: np.ndarray | None = None  # origin's gravity
    condensed: GravityInformation | None = None
    retired: set = field(default_factory=set)  # landmark ids folded into ``condensed``
    inlier: list = field(default_factory=list)  # per view (n,) bool

    @property
    def num_views(self) -> int:
        return len(self.view)

    def arrays(self):
        return (np.concatenate(self.view), np.concatenate(self.cam), np.concatenate(self.track),
                np.concatenate(self.f), np.concatenate(self.inlier))


class IncrementalSequence:
    """Views in, joint poses and gravity out; see the module docstring."""

    def __init__(self, rig: Rig, method: str = "6pt-bending", options: SequenceOptions | dict | None = None,
                 window: int = 10, seed: int = 0, young_views: int = 5, reconsider_deg: float = 3.0,
                 keep_history: bool = False):
        self.rig = rig
        self.method = method
        self.options = options if isinstance(options, SequenceOptions) else SequenceOptions.from_dict(options)
        if int(window) < 2:
            raise ValueError(f"window must be at least 2 views, got {window}")
        self.window = int(window)
        self.seed = int(seed)
        self.young_views = int(young_views)  # the joint gravity competes with each new pair's candidates until then
        self.reconsider_rad = math.radians(reconsider_deg)  # ... and whenever a pair disagrees by more than this
        self.model_rig = rig.as_rigid() if method == "6pt-nonbending" else rig
        self.with_gravity = method != "6pt-nonbending" and rig.is_flexible
        focal = float(np.mean([c.focal_px for c in rig.cameras]))
        self.threshold = self.options.estimator.threshold_px / focal
        self._pair_options = self.options.pair_estimator()
        self._noise_rad = self.threshold / 2.0  # angular noise of the latest solve (condenses retired landmarks)
        self._sequences = 0
        self.seq = _Sequence(0)
        self.keep_history = keep_history  # keep finished sequences (the bar calibration wants them all)
        self.history: list = []

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Start a new sequence: the next view is its origin (with ``keep_history`` the old one is kept)."""
        if self.keep_history and self.seq.num_views >= 2:
            self.history.append(self.seq)
        self._sequences += 1
        self.seq = _Sequence(self._sequences)

    def sequences(self) -> list:
        """Every sequence of two views or more so far (with ``keep_history``; else the current one): a
        :class:`SequenceRecord` each."""
        seqs = self.history + ([self.seq] if self.seq.num_views >= 2 else [])
        return [SequenceRecord(self._tracks_of(s), np.array(s.R[: s.num_views]), np.array(s.t[: s.num_views]),
                               s.gravity, np.array(s.measured_sigma)) for s in seqs if len(s.R) >= s.num_views]

    @property
    def num_views(self) -> int:
        return self.seq.num_views

    def tracks(self) -> Tracks:
        """The current sequence's observations as tracks (with the measured gravity)."""
        return self._tracks_of(self.seq)

    @staticmethod
    def _tracks_of(s: _Sequence) -> Tracks:
        view, cam, track, f, _ = s.arrays()
        g = np.array(s.measured)
        return Tracks(view, cam, track, f, g if np.isfinite(g).any() else None, num_views=s.num_views,
                      source=f"sequence {s.number}")

    def relative_pose(self, view: int, reference: int):
        """(R, t) of ``view`` in ``reference``'s body frame (p_ref = R p + t)."""
        s = self.seq
        Rr, tr = s.R[reference], s.t[reference]
        return Rr.T @ s.R[view], Rr.T @ (s.t[view] - tr)

    # ----------------------------------------------------------------- views
    def add_view(self, cam, track, f, measured_gravity=None, measured_sigma_rad: float | None = None):
        """Add the next view's observations; returns its :class:`ViewEstimate`, or a str saying why there is
        none (the origin of a sequence, or a view that starts a new one)."""
        t0 = time.perf_counter()
        cam = np.asarray(cam, dtype=np.int64)
        track = np.asarray(track, dtype=np.int64)
        f = normalize(np.asarray(f, dtype=float).reshape(-1, 3))
        g = np.full(3, np.nan) if measured_gravity is None else np.asarray(measured_gravity, float)
        sg = self.options.estimator.gravity_prior_sigma if measured_sigma_rad is None else float(measured_sigma_rad)
        s = self.seq
        k = s.num_views
        s.view.append(np.full(len(cam), k, np.int64))
        s.cam.append(cam)
        s.track.append(track)
        s.f.append(f)
        s.measured.append(g)
        s.measured_sigma.append(sg)
        s.inlier.append(np.ones(len(cam), bool))
        if k == 0:
            s.R.append(np.eye(3))
            s.t.append(np.zeros(3))
            return "the first view of a sequence is its origin"
        placed = self._resect(k)
        warm = placed is not None
        if warm:
            j, pm, (R, t) = placed
            s.R.append(R)
            s.t.append(t)
        else:
            paired = self._pair(k)
            if isinstance(paired, str):
                self._restart_from_last()
                return f"new sequence: {paired}"
            j, pm, est = paired
            s.R.append(s.R[j] @ est.R)
            s.t.append(s.R[j] @ est.t + s.t[j])
            if self.with_gravity:
                self._update_gravity(k, j, est)
        res, first = self._solve_window(k, warm)
        self._retire(first + 1)
        return self._estimate(k, j, pm, res, first, time.perf_counter() - t0)

    def _shared(self, j: int, k: int):
        """Observation indices (in views j and k) of the landmarks both see with the same camera."""
        s = self.seq
        a = s.cam[j] * (1 << 40) + s.track[j]
        b = s.cam[k] * (1 << 40) + s.track[k]
        _, ia, ib = np.intersect1d(a, b, assume_unique=False, return_indices=True)
        return ia, ib

    def _links(self, k: int):
        """The earlier views view k may be paired with, newest first: (j, shared observation indices in j and
        in k, pair method) of those that share enough landmarks from two cameras, or a str why none does."""
        s = self.seq
        why, out = [], []
        for j in range(k - 1, max(-1, k - 1 - self.options.max_pair_gap), -1):
            ia, ib = self._shared(j, k)
            cams = len(np.unique(s.cam[j][ia]))
            if len(ia) < self.options.min_pair_matches or cams < 2:
                why.append(f"view {j}: {len(ia)} shared landmarks from {cams} camera(s)")
                continue
            has_g = np.all(np.isfinite(s.measured[j])) and np.all(np.isfinite(s.measured[k]))
            out.append((j, ia, ib, self.method if self.method != "4pt-bending" or has_g else "6pt-bending"))
        return out or "; ".join(why) or "no earlier view"

    def _resect(self, k: int):
        """(reference view, method, (R, t)) of view k placed by resection on the landmarks the earlier views
        of the window triangulate (docs/PIPELINE.md, "The joint estimate over the sequence"), or None where
        the two-view estimate is to place it: a young sequence (its gravity still competes with each pair's),
        no link, or too few landmarks that fit one pose."""
        s = self.seq
        opts = self.options
        if not opts.resect_views or k < self.young_views or (self.with_gravity and s.gravity is None):
            return None
        links = self._links(k)
        if isinstance(links, str):
            return None
        j, _, _, pm = links[0]
        view, cam, track, f, inl = s.arrays()
        known = (view < k) & (view > k - self.window) & inl & np.isin(track, s.track[k])
        if s.retired:
            known &= ~np.isin(track, np.fromiter(s.retired, np.int64))
        placed = resect_on_landmarks(self.model_rig, (view[known], cam[known], track[known], f[known]), s.R[:k],
                                     s.t[:k], s.gravity if self.with_gravity else None,
                                     (s.cam[k], s.track[k], s.f[k]), (s.R[j], s.t[j]), self.threshold,
                                     opts.min_pair_matches, self.seed + k)
        if placed is None:
            return None
        res, hit = placed
        inlier = np.zeros(len(s.cam[k]), bool)
        inlier[hit[res.inliers]] = True
        inlier[np.setdiff1d(np.arange(len(inlier)), hit)] = True  # new landmarks: judged by the window solve
        s.inlier[k] = inlier
        return j, pm, (res.R, res.t)

    def _pair(self, k: int):
        """(reference view, method, two-view estimate) of view k, or why none."""
        s = self.seq
        links = self._links(k)
        if isinstance(links, str):
            return links
        why = []
        for j, ia, ib, pm in links:
            has_g = np.all(np.isfinite(s.measured[j])) and np.all(np.isfinite(s.measured[k]))
            m = Matches(s.f[j][ia], s.f[k][ib], s.cam[j][ia], s.measured[j] if has_g else None,
                        s.measured[k] if has_g else None, source=f"views {j}, {k}")
            est = estimate(self.model_rig, m, method=pm, seed=self.seed + k, options=self._pair_options)
            if est.success:
                return j, pm, est
            why.append(f"view {j}: {est.info.reason or 'estimation failed'}")
        return "; ".join(why) or "no earlier view"

    def _restart_from_last(self) -> None:
        """The newest view cannot be linked: it becomes the origin of a new sequence."""
        s = self.seq
        last = (s.cam.pop(), s.track.pop(), s.f.pop(), s.measured.pop(), s.measured_sigma.pop())
        s.view.pop()
        s.inlier.pop()
        self.reset()
        n = self.seq
        n.view.append(np.zeros(len(last[0]), np.int64))
        n.cam.append(last[0])
        n.track.append(last[1])
        n.f.append(last[2])
        n.measured.append(last[3])
        n.measured_sigma.append(last[4])
        n.inlier.append(np.ones(len(last[0]), bool))
        n.R.append(np.eye(3))
        n.t.append(np.zeros(3))

    # --------------------------------------------------------------- gravity
    def _priors(self, K: int) -> GravityPriors | None:
        s = self.seq
        if self.method != "4pt-bending" or not math.isfinite(self.options.estimator.gravity_prior_sigma):
            return None
        g = np.array(s.measured[:K])
        if not np.isfinite(g).any():
            return None
        return GravityPriors(g, np.array(s.measured_sigma[:K]), self.options.gravity_bias_sigma)

    def _update_gravity(self, k: int, j: int, est) -> None:
        """Choose the origin's gravity among the joint one and the new pair's candidates (see the module)."""
        s = self.seq
        if est.gravity is None:
            return
        Rj = s.R[j]
        cands = [(Rj @ np.asarray(g, float), float(est.num_inliers))
                 for g in [est.gravity] + list(est.info.gravity_candidates)]
        if self.method == "4pt-bending":
            cands += [(s.R[i] @ s.measured[i], 0.0) for i in (j, k) if np.all(np.isfinite(s.measured[i]))]
        if s.gravity is not None:
            young = k < self.young_views
            # a pair contradicts the joint gravity by more than reconsider_deg and its own noise allows
            sigma = est.info.gravity_sigma_rad or 0.0
            if not young and angle_between(cands[0][0], s.gravity) < max(self.reconsider_rad,
                                                                         RECONSIDER_SIGMAS * sigma):
                return
            cands = [(s.gravity, math.inf)] + cands
        opts = self.options
        distinct = distinct_candidates(cands, math.radians(opts.candidate_separation_deg), opts.max_candidates)
        first = max(0, k + 1 - self.window)
        obs, _, free = self._window_problem(k, first)
        R, t = np.array(s.R), np.array(s.t)
        rng = np.random.default_rng(self.seed + k)
        chosen, _ = choose_gravity(self.model_rig, obs, R, t, distinct, self._priors(k + 1), self.threshold, opts,
                                   rng, free_views=free, gravity_information=s.condensed)
        if isinstance(chosen, np.ndarray):
            s.gravity = chosen
        else:
            s.gravity = chosen.gravity
            for i in free:
                s.R[i], s.t[i] = chosen.R[i], chosen.t[i]

    # ---------------------------------------------------------------- solves
    def _window_problem(self, k: int, first: int):
        """Observations of the window views [first, k] and the older views' observations of landmarks the
        window sees (minus retired ones), and the free views."""
        s = self.seq
        view, cam, track, f, _ = s.arrays()
        live = np.unique(track[view >= first])
        keep = np.isin(track, live)
        if s.retired:
            keep &= ~np.isin(track, np.fromiter(s.retired, np.int64))
        obs, _ = Observations.from_arrays(view[keep], cam[keep], track[keep], f[keep], k + 1)
        free = np.arange(max(first, 1), k + 1)
        if first > 0 and not np.any(view[keep] < first):
            free = free[1:]  # nothing older ties the window to the origin: its first view holds the gauge
        return obs, np.flatnonzero(keep), free

    def _solve_window(self, k: int, warm: bool = False):
        """Robust adjustment of the window ending at view k. ``warm``: every view of it but k is adjusted
        already and k was placed by resection, so the inliers so far start it and one round may do."""
        s = self.seq
        first = max(0, k + 1 - self.window)
        obs, idx, free = self._window_problem(k, first)
        start = None
        if warm:  # the inliers so far, and the observations of landmarks not seen twice before view k
            before = np.bincount(obs.point, weights=obs.view < k, minlength=obs.num_points)
            start = np.concatenate(s.inlier)[idx] | (before[obs.point] < 2)
        res, inl = refine_sequence(self.model_rig, obs, np.array(s.R), np.array(s.t), s.gravity, self.threshold,
                                   priors=self._priors(k + 1), gravity_information=s.condensed, free_views=free,
                                   max_iterations=self.options.max_iterations, rounds=self.options.window_rounds,
                                   huber_k=self.options.estimator.huber_k, inliers=start,
                                   min_rounds=1 if warm else 2, tol=self.options.relative_tolerance)
        st = res.state
        for i in free:
            s.R[i], s.t[i] = st.R[i], st.t[i]
        if self.with_gravity and st.gravity is not None:
            s.gravity = st.gravity
        flat = np.concatenate(s.inlier)
        flat[idx] = inl
        sizes = np.cumsum([len(x) for x in s.inlier])[:-1]
        s.inlier = np.split(flat, sizes)
        return res, first

    def _retire(self, first_next: int) -> None:
        """Fold landmarks no later window can see into the origin's gravity information (poses fixed)."""
        s = self.seq
        if not self.with_gravity or s.gravity is None or first_next <= 0:
            return
        view, cam, track, f, inl = s.arrays()
        still_seen = np.unique(track[view >= first_next])
        old = ~np.isin(track, still_seen) & inl
        if s.retired:
            old &= ~np.isin(track, np.fromiter(s.retired, np.int64))
        if not old.any():
            return
        obs, _ = Observations.from_arrays(view[old], cam[old], track[old], f[old], s.num_views)
        seen_twice = np.bincount(obs.point, minlength=obs.num_points) >= 2
        if seen_twice.any():
            obs, _ = obs.subset(seen_twice[obs.point])
            state = BundleState(np.array(s.R), np.array(s.t), s.gravity, np.zeros((obs.num_points, 3)))
            state, _ = triangulated(self.model_rig, obs, state)
            info = condense_gravity(self.model_rig, obs, state, self._noise_rad, self.options.estimator.huber_k)
            if info is not None:
                s.condensed = info.combined(s.condensed)
        s.retired.update(int(x) for x in np.unique(track[old]))

    def _estimate(self, k, j, pm, res, first, elapsed) -> ViewEstimate:
        s = self.seq
        self._noise_rad = res.sigma_rad
        g = cov = None
        sigma = math.inf
        if self.with_gravity and s.gravity is not None:
            g = s.R[k].T @ s.gravity
            sigma = res.gravity_sigma_rad(k)
            cov = res.gravity_covariance(k)
        n = len(s.cam[k])
        return ViewEstimate(sequence=s.number, view=k, reference=j, method=pm, R=s.R[k].copy(), t=s.t[k].copy(),
                            gravity=g, gravity_sigma_rad=sigma, cov_gravity=cov,
                            cov_pose=res.pose_covariance(k, body=True), num_observations=n,
                            num_inliers=int(np.count_nonzero(s.inlier[k])), window=k + 1 - first,
                            time_s=elapsed)

    # ----------------------------------------------------------------- batch
    def batch(self) -> SequenceEstimate:
        """All views of the current sequence adjusted at once, from the incremental estimates."""
        t0 = time.perf_counter()
        s = self.seq
        K = s.num_views
        if K < 2 or len(s.R) < K:
            return SequenceEstimate(method=self.method, success=False, reason="fewer than two linked views")
        view, cam, track, f, _ = s.arrays()
        obs, _ = Observations.from_arrays(view, cam, track, f, K)
        seen = (np.bincount(obs.point, minlength=obs.num_points) >= 2)[obs.point]
        obs, _ = obs.subset(seen)
        refine = dict(priors=self._priors(K), max_iterations=self.options.max_iterations,
                      rounds=self.options.inlier_rounds, huber_k=self.options.estimator.huber_k,
                      tol=self.options.relative_tolerance)
        res, inl = refine_sequence(self.model_rig, obs, np.array(s.R), np.array(s.t), s.gravity, self.threshold,
                                   **refine)
        res, inl, repairs = repair_links(self.model_rig, self.tracks(), obs, res, inl, self.method, self.threshold,
                                         self.options, self.seed, **refine)
        st = res.state
        grav = sig = None
        reason = ""
        if self.with_gravity and st.gravity is not None:
            grav = st.view_gravity
            sig = np.array([res.gravity_sigma_rad(i) for i in range(K)])
        elif self.method != "6pt-nonbending":
            reason = RIGID_REASON
        inliers = np.zeros(len(view), bool)
        inliers[np.flatnonzero(seen)[inl]] = True
        return SequenceEstimate(method=self.method, success=True, R=st.R, t=st.t, gravity=grav,
                                gravity_sigma_rad=sig, inliers=inliers, time_s=time.perf_counter() - t0,
                                reason=reason, bundle=res, link_repairs=repairs)


__all__ = ["IncrementalSequence", "SequenceRecord", "ViewEstimate"]
