"""The front-end pipeline shared by ``nrmpc replay`` and the ROS 2 node.

    pipe = Pipeline(rig, PipelineConfig(), method="auto")
    pipe.add_imu(stamp, accel, gyro)               # any time, optional
    out = pipe.add_frames(FrameSet(stamp, images))   # -> list[PipelineEstimate]

Per frame set: KLT tracking in every camera, static-window detection
(:mod:`.static`), and for each new static view the pairing policy (see
docs/PIPELINE.md): pair with the current reference view, else with the previous
static view; correspondences from KLT tracks or descriptors, verified per
camera; then :func:`nrmpc_ros.core.estimate`. ``auto`` runs 4pt-bending when
the IMU gives gravity within ``imu.max_age_s`` for both views, else 6pt-bending.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field, fields

import numpy as np

from ..cameras import check_image_size
from ..core import METHODS, EstimatorOptions, Matches, estimate
from ..core.fusion import CHI2_2DOF_999, GravityFusion
from ..core.rig import Rig
from ..core.so3 import angle_between, rotation_angle, tangent_basis
from ..errors import InputError
from .imu import ImuBuffer, ImuConfig, ImuGravity
from .static import StaticConfig, StaticDetector
from .tracking import KltTracker, TrackingConfig, detect_features, match_features, verify_pairs

PIPELINE_METHODS = ("auto",) + METHODS
# EstimatorOptions the pipeline changes from the core defaults (throughput, docs/PIPELINE.md "Throughput"):
# the gravity starts of 6pt-bending are compared on 100 correspondences, 2 of them refined, BA capped at 10 steps.
ESTIMATOR_DEFAULTS = {"subset_size": 100, "gravity_refine_starts": 2, "max_ba_iterations": 10}


@dataclass
class FusionConfig:
    """Fused gravity (:class:`~nrmpc_ros.core.fusion.GravityFusion`) settings."""

    cov_scale: float = 4.0  # variance inflation of the BA gravity covariance (it misses model and rendering errors)
    process_sigma_deg: float = 0.057  # added per propagation (rotation errors the covariance misses)
    gate: float = CHI2_2DOF_999  # Mahalanobis^2 above which an estimate is rejected as an outlier
    max_rejections: int = 3  # rejections in a row after which the newest estimates replace the fused state
    min_support: int = 3  # a pair rejected by a fused state of this many estimates publishes the fused gravity

    def __post_init__(self):
        for name in ("cov_scale", "gate"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not v > 0:
                raise InputError("pipeline config", f"must be a positive number, got {v!r}", f"fusion.{name}")
        if not isinstance(self.process_sigma_deg, (int, float)) or not self.process_sigma_deg >= 0:
            raise InputError("pipeline config", f"must be >= 0, got {self.process_sigma_deg!r}",
                             "fusion.process_sigma_deg")
        for name in ("max_rejections", "min_support"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise InputError("pipeline config", f"must be an integer >= 1, got {v!r}", f"fusion.{name}")


@dataclass
class PipelineConfig:
    """All front-end settings; nested blocks have their own defaults."""

    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    static: StaticConfig = field(default_factory=StaticConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    estimator: dict = field(default_factory=lambda: dict(ESTIMATOR_DEFAULTS))  # EstimatorOptions fields
    imu_still_window_s: float = 0.2  # IMU stillness of a snapshot frame is checked over this window before it
    min_matches: int = 40  # verified correspondences (all cameras) needed to estimate
    min_cameras: int = 2  # cameras contributing correspondences
    refresh_matches: int = 200  # after a pair with fewer matches than this, the current view becomes the reference
    advance_rotation_deg: float = 15.0  # after a pair rotated this much (deg), the current view becomes the reference
    min_tilt_deg: float = 2.0  # change of gravity direction in the body needed between paired views
    max_gravity_sigma_deg: float = 2.0  # a pair's gravity with a larger std is weak: not fused, fused one published
    seed: int = 0

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "pipeline config") -> PipelineConfig:
        """Build from a nested mapping (e.g. YAML / ROS parameters); unknown keys are errors."""
        d = dict(d or {})
        sub = {"tracking": TrackingConfig, "static": StaticConfig, "imu": ImuConfig, "fusion": FusionConfig}
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise InputError(source, f"unknown option (allowed: {', '.join(sorted(names))})", unknown[0])
        kw = {}
        for k, v in d.items():
            if k in sub:
                allowed = {f.name for f in fields(sub[k])}
                bad = sorted(set(v or {}) - allowed)
                if bad:
                    raise InputError(source, f"unknown option (allowed: {', '.join(sorted(allowed))})", f"{k}.{bad[0]}")
                kw[k] = sub[k](**(v or {}))
            elif k == "estimator":
                kw[k] = {**ESTIMATOR_DEFAULTS, **(v or {})}  # given options on top of the pipeline's defaults
            else:
                kw[k] = v
        cfg = cls(**kw)
        EstimatorOptions.from_dict(cfg.estimator)  # validates
        return cfg


@dataclass
class FrameSet:
    """Synchronised images (2-D uint8, rig camera order) with one stamp (seconds)."""

    stamp: float
    images: list


GRAVITY_SOURCE_WORDS = {
    "pair": "from the pair itself",
    "fused": "fused (the pair's own was weak or outvoted)",
    "weak-pair": "from a weak pair with nothing fused yet",
    "pair-hinted": "from the pair, re-estimated in the fused gravity's basin (ambiguous pair)",
}
# chi^2 (2 d.o.f., 99 %): a pair re-estimated from the fused gravity is kept when its MSAC score exceeds its own
# estimate's by less than this, in units of the pair's noise (Pipeline._settle_basin)
AMBIGUITY_CHI2 = 9.21


@dataclass
class PipelineEstimate:
    """One estimate: the current view relative to the reference view (SPEC section 2)."""

    stamp: float  # current view (view 2)
    ref_stamp: float  # reference view (view 1)
    method: str
    R: np.ndarray  # p_ref = R p_cur + t
    t: np.ndarray
    gravity: np.ndarray | None  # current body frame, m/s^2
    num_inliers: int
    time_ms: float  # matching + verification + estimation of this pair
    num_matches: int = 0
    match_mode: str = ""  # klt | descriptors
    cov_gravity: np.ndarray | None = None  # 3x3, current body frame
    gravity_sigma_deg: float = math.nan
    imu_gravity: np.ndarray | None = None  # IMU gravity of the current view (body frame), when available
    tilt_deg: float = math.nan  # angle between gravity in the two body frames
    info: dict = field(default_factory=dict)
    gravity_fused: np.ndarray | None = None  # fused gravity (all estimates so far), current body frame, m/s^2
    cov_gravity_fused: np.ndarray | None = None  # 3x3, current body frame (rank 2: tangent to the sphere)
    gravity_fused_sigma_deg: float = math.nan  # largest angular std of gravity_fused
    fused_count: int = 0  # estimates in the fused state since its last (re)start
    fused_rejected: int = 0  # estimates rejected as outliers since then
    fused_accepted: bool | None = None  # whether this estimate's gravity entered the fused state
    gravity_source: str = ""  # what ``gravity`` is: pair, pair-hinted, fused, weak-pair (Pipeline._published_gravity)


@dataclass
class PipelineStats:
    frames: int = 0
    static_views: int = 0
    pairs: int = 0
    estimates: int = 0
    reference_changes: int = 0
    methods: Counter = field(default_factory=Counter)
    dropped: Counter = field(default_factory=Counter)  # reason -> count (frames, views or pairs)
    gravity_sources: Counter = field(default_factory=Counter)  # PipelineEstimate.gravity_source -> count
    hinted_pairs: int = 0  # 6pt-bending pairs that contradicted the fused gravity and were estimated again from it
    hinted_kept: int = 0  # ... whose re-estimate fitted as well and replaced the pair's own

    def as_dict(self) -> dict:
        return {"frames": self.frames, "static_views": self.static_views, "pairs": self.pairs,
                "estimates": self.estimates, "reference_changes": self.reference_changes,
                "methods": dict(self.methods), "dropped": dict(self.dropped),
                "gravity_sources": dict(self.gravity_sources), "hinted_pairs": self.hinted_pairs,
                "hinted_kept": self.hinted_kept}


@dataclass
class _View:
    stamp: float
    images: list
    tracks: list  # per camera KLT Snapshot (ids, uv, features the tracks were seeded from)
    imu: ImuGravity | None
    features: list | None = None

    def get_features(self, cfg: TrackingConfig) -> list:
        """Descriptor features per camera: the ones the tracks were seeded from in this frame, else detected now."""
        if self.features is None:
            self.features = [snap.features if snap.features is not None else detect_features(img, cfg)
                             for snap, img in zip(self.tracks, self.images)]
        return self.features


class Pipeline:
    """Frames and IMU samples in, relative pose + gravity estimates out."""

    def __init__(self, rig: Rig, config: PipelineConfig | None = None, method: str = "auto"):
        if method not in PIPELINE_METHODS:
            raise InputError("pipeline", f"unknown method {method!r} (choose one of {', '.join(PIPELINE_METHODS)})",
                             "method")
        self.rig = rig
        self.config = config or PipelineConfig()
        self.method = method
        self.estimator_options = EstimatorOptions.from_dict(self.config.estimator)
        self.imu = ImuBuffer(rig, self.config.imu)
        self.trackers = [KltTracker(self.config.tracking) for _ in rig.cameras]
        self.detector = StaticDetector(self.config.static)
        tc = self.config.tracking
        self._cap = max(int(tc.max_matches_per_camera), int(tc.max_matches_total) // rig.num_cameras)
        self.stats = PipelineStats()
        self.reference: _View | None = None
        self.previous: _View | None = None
        self.last_stamp = -math.inf
        self.last_method: str | None = None
        self.last_pair = None  # (ref stamp, stamp, Matches) of the latest estimation, for diagnostics
        fc = self.config.fusion
        self.fusion = GravityFusion(rig.gravity_magnitude, gate=fc.gate, process_sigma_rad=math.radians(
            fc.process_sigma_deg), max_rejections=fc.max_rejections)
        self._orient: dict = {}  # view stamp -> orientation in the first view of the current chain of estimates
        self._fused_stamp: float | None = None  # view whose body frame holds the fused state

    # ------------------------------------------------------------------ input
    def add_imu(self, stamp: float, accel, gyro=None) -> None:
        """One IMU sample (specific force m/s^2, angular rate rad/s, IMU frame); bad samples are counted."""
        if self.rig.imu is None:
            self.stats.dropped["imu sample ignored: rig file has no imu block"] += 1
            return
        reason = self.imu.add(stamp, accel, gyro)
        if reason:
            self.stats.dropped[f"imu sample: {reason}"] += 1

    def _check(self, frames: FrameSet) -> list:
        src = f"frame set at {frames.stamp!r}"
        if not isinstance(frames.stamp, (int, float, np.floating)) or not math.isfinite(float(frames.stamp)):
            raise InputError(src, "stamp must be a finite number of seconds", "stamp")
        imgs = list(frames.images)
        if len(imgs) != self.rig.num_cameras:
            raise InputError(src, f"got {len(imgs)} images but the rig {self.rig.source} has "
                             f"{self.rig.num_cameras} cameras", "images")
        out = []
        for cam, img in zip(self.rig.cameras, imgs):
            where = cam.image_topic or cam.name
            a = np.asarray(img)
            if a.ndim != 2 or a.dtype != np.uint8:
                raise InputError(where, f"camera {cam.name!r}: expected a 2-D uint8 image, got shape {a.shape} "
                                 f"dtype {a.dtype}", "images")
            check_image_size(cam, a.shape[1], a.shape[0], where)
            out.append(np.ascontiguousarray(a))
        return out

    def add_frames(self, frames: FrameSet) -> list:
        """Process one synchronised frame set; returns the estimates it produced (0 or more).

        Raises InputError (naming the camera) for a wrong number or size of
        images; the pipeline's state is untouched then and later frames work.
        """
        images = self._check(frames)
        stamp = float(frames.stamp)
        if stamp <= self.last_stamp:
            self.stats.dropped["frame set out of order"] += 1
            return []
        prev_stamp, self.last_stamp = self.last_stamp, stamp
        self.stats.frames += 1
        for trk, img in zip(self.trackers, images):
            trk.track(img)
        motions = [trk.anchor_motion() for trk in self.trackers]
        motion = float(np.median([m[0] for m in motions]))
        tracks = int(sum(m[1] for m in motions))
        imu_still = None
        if len(self.imu):
            t0 = max(prev_stamp, stamp - self.config.imu_still_window_s)
            imu_still = self.imu.is_still(t0, stamp)
        new_window, confirmed = self.detector.update(stamp, motion, tracks, imu_still)
        if new_window:
            for trk in self.trackers:
                trk.set_anchor()
        if not confirmed:
            return []
        return self._static_view(stamp, images)

    # ------------------------------------------------------------ static views
    def _static_view(self, stamp: float, images: list) -> list:
        self.stats.static_views += 1
        imu, reason = self.imu.gravity(self.detector.window.start, stamp) if self.rig.imu is not None else (None, "")
        if imu is None and len(self.imu):
            self.stats.dropped[f"view without IMU gravity: {reason.split(' (')[0]}"] += 1
        view = _View(stamp, images, [trk.snapshot() for trk in self.trackers], imu)
        if self.reference is None:
            self._set_reference(view)
            self.previous = view
            return []
        out = []
        candidates = [self.reference] + ([self.previous] if self.previous is not self.reference else [])
        why = []
        for ref in candidates:
            if ref.imu is not None and view.imu is not None:
                tilt = math.degrees(float(angle_between(ref.imu.gravity, view.imu.gravity)))
                if tilt < self.config.min_tilt_deg:
                    why.append(f"tilt {tilt:.1f} deg < min_tilt_deg")
                    continue
            self.stats.pairs += 1
            t0 = time.perf_counter()
            f1, f2, cam, mode = self._correspond(ref, view)
            n_cams = len(np.unique(cam))
            if len(cam) < self.config.min_matches or n_cams < self.config.min_cameras:
                why.append(f"too few matches ({len(cam)} from {n_cams} cameras)")
                continue
            if ref is not self.reference:
                self._set_reference(ref)
            est = self._estimate(ref, view, f1, f2, cam, mode, t0)
            if est is not None:
                out.append(est)
            rotated = est is not None and math.degrees(rotation_angle(est.R)) >= self.config.advance_rotation_deg
            if len(cam) < self.config.refresh_matches or rotated:
                self._set_reference(view)  # tracks are running out, or enough baseline: start afresh from here
            break
        else:
            reason = why[-1] if why else "no reference"
            key = "tilt" if reason.startswith("tilt") else "too few matches"
            self.stats.dropped[f"static view not paired: {key}"] += 1
            if key != "tilt":
                self._set_reference(view)
        self.previous = view
        return out

    def _set_reference(self, view: _View) -> None:
        if self.reference is not None and self.reference is not view:
            self.stats.reference_changes += 1
        self.reference = view

    def _correspond(self, ref: _View, view: _View):
        """Verified correspondences: KLT tracks when enough survive (auto/klt), else (or if more) descriptors."""
        cfg = self.config.tracking
        klt = None
        if cfg.mode in ("auto", "klt"):
            klt = self._verify([trk.pairs_since(snap) for trk, snap in zip(self.trackers, ref.tracks)])
            enough = min(cfg.min_klt_matches, 0.5 * self.rig.num_cameras * self._cap)
            if cfg.mode == "klt" or len(klt[2]) >= enough:
                return (*klt, "klt")
        fa, fb = ref.get_features(cfg), view.get_features(cfg)
        pairs = []
        for a, b in zip(fa, fb):
            ia, ib = match_features(a, b, cfg)
            pairs.append((a.uv[ia], b.uv[ib]))
        desc = self._verify(pairs)
        if klt is not None and len(klt[2]) > len(desc[2]):
            return (*klt, "klt")
        return (*desc, "descriptors")

    def _verify(self, pairs):
        f1s, f2s, cams = [], [], []
        for i, (cam, (uv1, uv2)) in enumerate(zip(self.rig.cameras, pairs)):
            f1, f2, idx = verify_pairs(cam, uv1, uv2, self.config.tracking, self._cap)
            f1s.append(f1)
            f2s.append(f2)
            cams.append(np.full(len(idx), i, np.int64))
        return np.concatenate(f1s), np.concatenate(f2s), np.concatenate(cams)

    def _method(self, ref: _View, view: _View) -> str | None:
        if self.method != "auto":
            return self.method
        return "4pt-bending" if ref.imu is not None and view.imu is not None else "6pt-bending"

    def _estimate(self, ref: _View, view: _View, f1, f2, cam, mode, t0):
        method = self._method(ref, view)
        g1 = g2 = None
        if method == "4pt-bending":
            if ref.imu is None or view.imu is None:
                self.stats.dropped["4pt-bending without IMU gravity for both views"] += 1
                return None
            g1, g2 = ref.imu.gravity, view.imu.gravity
        m = Matches(f1, f2, cam, g1=g1, g2=g2, source=f"pair {ref.stamp:.3f} -> {view.stamp:.3f}")
        self.last_pair = (ref.stamp, view.stamp, m)
        est = estimate(self.rig, m, method=method, seed=self.config.seed, options=self.estimator_options)
        elapsed = 1000.0 * (time.perf_counter() - t0)
        self.last_method = method
        if not est.success:
            self.stats.dropped[f"estimation failed: {est.info.get('reason', 'unknown')}"] += 1
            return None
        if method == "6pt-bending" and est.gravity is not None:
            est = self._settle_basin(ref, m, est)
        self._chain(ref, view, est.R)
        g_cur, cov, sigma, tilt = est.gravity2, None, math.nan, math.nan
        if g_cur is not None:
            tilt = math.degrees(float(angle_between(est.gravity, g_cur)))
            if "cov_gravity" in est.info:
                cov = est.R.T @ np.asarray(est.info["cov_gravity"]) @ est.R
            sigma = math.degrees(est.info.get("gravity_sigma_rad", math.nan))
            if method == "6pt-bending" and tilt < self.config.min_tilt_deg:
                self.stats.dropped["estimate dropped: tilt below min_tilt_deg (gravity unobservable)"] += 1
                return None
        self.stats.estimates += 1
        self.stats.methods[method] += 1
        out = PipelineEstimate(
            stamp=view.stamp, ref_stamp=ref.stamp, method=method, R=est.R, t=est.t, gravity=g_cur,
            num_inliers=est.num_inliers, time_ms=elapsed, num_matches=len(cam), match_mode=mode, cov_gravity=cov,
            gravity_sigma_deg=sigma, imu_gravity=None if view.imu is None else view.imu.gravity, tilt_deg=tilt,
            info=est.info, gravity_source="" if g_cur is None else "pair")
        # weakly observable gravity (e.g. parallel bars, little rotation) stays out of the fused state
        weak = g_cur is not None and not sigma <= self.config.max_gravity_sigma_deg
        self._fuse(out, use_gravity=not weak)
        self._published_gravity(out, weak, self.config.fusion.min_support)
        if out.gravity_source:
            self.stats.gravity_sources[out.gravity_source] += 1
        return out

    def _settle_basin(self, ref: _View, m: Matches, est):
        """Estimate again from the fused gravity a 6pt-bending pair that contradicts a fused state of at least
        ``fusion.min_support`` estimates, and keep the hinted estimate when it fits the correspondences
        statistically as well (MSAC score within AMBIGUITY_CHI2 in units of the pair's noise).

        On parallel bars two gravity basins fit a pair about equally (bending reversed or mirrored; paper,
        section 3.3); the history of views then decides, and the pair's rotation, which carries the fused
        state on, comes from the right basin too. A hinted estimate that fits clearly worse is not used:
        the pair's own then counts against the fused state (challengers, :class:`GravityFusion`).
        """
        fz = self.fusion
        st = fz.state
        cov_g, sigma = est.info.get("cov_gravity"), est.info.get("sigma_rad")
        if (st is None or st.num_fused < self.config.fusion.min_support or cov_g is None or not sigma
                or ref.stamp not in self._orient or self._fused_stamp not in self._orient):
            return est
        to_ref = self._orient[self._fused_stamp].T @ self._orient[ref.stamp]  # view 1 in the fused state's frame
        cov_rot = est.info.get("cov_rotation")
        cov2 = self.config.fusion.cov_scale * (est.R.T @ np.asarray(cov_g) @ est.R)
        if fz.agrees(est.gravity2, cov2, to_ref @ est.R, None if cov_rot is None else np.asarray(cov_rot)):
            return est
        hinted = estimate(self.rig, m, method="6pt-bending", seed=self.config.seed, options=self.estimator_options,
                          gravity_hint=fz.carried(to_ref).gravity)
        self.stats.hinted_pairs += 1
        if not hinted.success or hinted.gravity is None:
            return est
        excess = (hinted.info["msac_score_rad2"] - est.info["msac_score_rad2"]) / sigma**2
        if not excess < AMBIGUITY_CHI2:
            return est
        self.stats.hinted_kept += 1
        return hinted

    @staticmethod
    def _published_gravity(e: PipelineEstimate, weak: bool, min_support: int = 3) -> None:
        """Choose the gravity this estimate publishes (``~/gravity``, CSV g; SPEC sections 10, 11).

        The pair's own estimate, unless it is weak (std above max_gravity_sigma_deg) or contradicts a
        fused state built from at least ``min_support`` estimates; then the fused estimate, which is this
        same body frame's gravity from all views so far. A weak estimate with nothing fused yet is
        published as ``weak-pair``, its std in the CSV. A pair rejected by a younger fused state still
        publishes its own gravity: that state may be the wrong one (it is replaced when the estimates
        it rejects agree among themselves, see GravityFusion).
        """
        if e.gravity is None:
            return
        outvoted = e.fused_accepted is False and e.fused_count >= min_support
        if e.gravity_fused is not None and (weak or outvoted):
            e.gravity, e.cov_gravity, e.gravity_source = e.gravity_fused, e.cov_gravity_fused, "fused"
        elif weak:
            e.gravity_source = "weak-pair"
        elif e.info.get("gravity_hint"):
            e.gravity_source = "pair-hinted"

    # ----------------------------------------------------------- fused gravity
    def _chain(self, ref: _View, view: _View, R: np.ndarray) -> None:
        """Record the orientation of ``view``; a reference outside the chain starts a new one (fusion restarts)."""
        if ref.stamp not in self._orient:
            self._orient = {ref.stamp: np.eye(3)}
            self.fusion.reset()
            self._fused_stamp = None
        self._orient[view.stamp] = self._orient[ref.stamp] @ R
        keep = {ref.stamp, view.stamp, self._fused_stamp, self.reference.stamp,
                None if self.previous is None else self.previous.stamp}
        self._orient = {k: v for k, v in self._orient.items() if k in keep}

    def _fuse(self, e: PipelineEstimate, use_gravity: bool = True) -> None:
        """Carry the fused gravity into the current body frame, fuse this estimate's gravity (if use_gravity),
        fill e's fused fields."""
        fz = self.fusion
        if self._fused_stamp is not None and self._fused_stamp != e.stamp:
            R_delta = self._orient[self._fused_stamp].T @ self._orient[e.stamp]
            cov_rot = e.info.get("cov_rotation")  # right perturbation of R, hence of R_delta
            fz.propagate(R_delta, None if cov_rot is None else np.asarray(cov_rot))
            self._fused_stamp = e.stamp
        if use_gravity and e.gravity is not None and e.cov_gravity is not None and np.all(np.isfinite(e.cov_gravity)):
            e.fused_accepted = fz.update(e.gravity, self.config.fusion.cov_scale * e.cov_gravity)
            self._fused_stamp = e.stamp
        st = fz.state
        if st is None:
            return
        B = tangent_basis(st.gravity / np.linalg.norm(st.gravity)) * self.rig.gravity_magnitude
        e.gravity_fused, e.cov_gravity_fused = st.gravity, B @ st.cov_tangent @ B.T
        e.gravity_fused_sigma_deg = math.degrees(st.sigma_rad)
        e.fused_count, e.fused_rejected = st.num_fused, st.num_rejected
