"""The front-end pipeline shared by ``nrmpc replay`` and the ROS 2 node (docs/PIPELINE.md).

    pipe = Pipeline(rig, PipelineConfig(), method="auto")
    pipe.add_imu(stamp, accel, gyro)                 # any time, optional
    out = pipe.add_frames(FrameSet(stamp, images))   # -> list[HoldEstimate]; None for a camera without a frame
    out += pipe.flush()                              # at the end: the hold still open

Per frame set: KLT tracking in every camera (from the hold's anchor frame
inside a hold), then the hold logic: two frames belong to one hold when the
image barely moved between them and, with an IMU, the zero-velocity detector
says the rig was still; a frame alone (no other frame nearby) is a hold of
its own unless the IMU says the rig moved. When a hold ends (or its settled
part is long enough) it is measured (:mod:`.holds`), its tracks get landmark
ids (:mod:`.linking`) and the joint estimate over the sequence of holds
(:class:`~nrmpc_ros.core.incremental.IncrementalSequence`) gives the hold's
pose and gravity.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from ..cameras import check_image_size
from ..config import check, from_mapping, option
from ..core import METHODS
from ..core.incremental import IncrementalSequence, ViewEstimate
from ..core.rig import Rig
from ..core.sequence import SequenceOptions
from ..errors import InputError
from .holds import Hold, HoldConfig, HoldRecorder, slowest_bar_period
from .imu import ImuBuffer, ImuConfig, ImuGravity
from .linking import HoldLinker
from .tracking import KltTracker, TrackingConfig
from .zupt import ZuptConfig, ZuptDetector

PIPELINE_METHODS = ("auto",) + METHODS
_MOTION_KINDS = ("the IMU says the rig moved", "tracks lost", "image moved", "image left the hold")


@dataclass
class PipelineConfig:
    """All front-end settings; nested blocks have their own defaults."""

    tracking: TrackingConfig = option(TrackingConfig(), "feature tracking and matching")
    holds: HoldConfig = option(HoldConfig(), "holds: when frames belong to one, which are settled")
    imu: ImuConfig = option(ImuConfig(), "IMU samples and a hold's averaged accelerometer")
    zupt: ZuptConfig = option(ZuptConfig(), "the IMU stillness test")
    sequence: SequenceOptions = option(SequenceOptions(), "the joint estimate over the sequence of holds")
    window: int = option(10, "holds adjusted jointly when a new hold arrives (older ones keep their poses)",
                         lo=2, hi=10000)
    imu_gravity_floor_deg: float = option(0.05, "least angular std of a hold's averaged IMU gravity (deg), "
                                          "besides its bias", lo=0.0, hi=90.0, lo_open=True)
    imu_bias_sigma_deg: float = option(0.3, "prior std of the accelerometer's constant tilt (bias) estimated "
                                       "jointly (deg); 0: no such tilt", lo=0.0, hi=90.0)
    seed: int = option(0, "RANSAC seed", lo=0, hi=2**63 - 1)

    def __post_init__(self):
        check(self, "pipeline config")

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "pipeline config") -> PipelineConfig:
        """Build from a nested mapping (e.g. YAML / ROS parameters); unknown keys are errors naming them."""
        return from_mapping(cls, d, source)

    def sequence_options(self) -> SequenceOptions:
        bias = math.radians(self.imu_bias_sigma_deg) if self.imu_bias_sigma_deg > 0 else None
        return replace(self.sequence, gravity_bias_sigma=bias)


@dataclass
class FrameSet:
    """Images (2-D uint8, rig camera order; None for a camera without a frame) with one stamp (seconds)."""

    stamp: float
    images: list


@dataclass
class HoldEstimate:
    """The estimate of one hold: its pose relative to the reference hold (p_ref = R p + t) and in the
    sequence origin, its gravity (current body frame) from the joint solution, and how the hold was measured."""

    stamp: float  # a frame inside the hold's settled part
    ref_stamp: float  # the same of the reference hold (the one it was paired with)
    method: str
    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray | None  # m/s^2, this hold's body frame
    gravity_sigma_deg: float
    cov_gravity: np.ndarray | None
    num_inliers: int
    num_observations: int
    time_ms: float
    origin_stamp: float  # the sequence's first hold: the origin frame
    R_origin: np.ndarray  # pose in the origin (p_origin = R_origin p + t_origin)
    t_origin: np.ndarray
    cov_pose: np.ndarray  # (6, 6): rotation (body frame) and translation (origin frame)
    sequence: int
    hold_index: int
    hold: Hold
    imu_gravity: np.ndarray | None = None  # this hold's averaged accelerometer gravity (body frame)
    links: Counter = field(default_factory=Counter)
    window: int = 0


@dataclass
class PipelineStats:
    frames: int = 0
    holds: int = 0  # holds measured
    ringing_holds: int = 0  # of which the bars still rang at the end (averaged over whole bar periods)
    estimates: int = 0
    sequences: int = 0
    methods: Counter = field(default_factory=Counter)
    dropped: Counter = field(default_factory=Counter)  # reason -> count (frames, holds, IMU samples)
    settle_s: list = field(default_factory=list)  # per measured hold
    residual_px: list = field(default_factory=list)
    noise_px: list = field(default_factory=list)  # one frame's track position noise
    averaged_noise_px: list = field(default_factory=list)
    settled_frames: list = field(default_factory=list)

    def as_dict(self) -> dict:
        def med(v):
            v = [x for x in v if math.isfinite(x)]
            return float(np.median(v)) if v else math.nan

        return {"frames": self.frames, "holds": self.holds, "ringing_holds": self.ringing_holds,
                "estimates": self.estimates,
                "sequences": self.sequences, "methods": dict(self.methods), "dropped": dict(self.dropped),
                "median_settle_s": med(self.settle_s), "median_residual_px": med(self.residual_px),
                "median_noise_px": med(self.noise_px), "median_averaged_noise_px": med(self.averaged_noise_px)}


class Pipeline:
    """Frames and IMU samples in, hold estimates out (see the module docstring)."""

    def __init__(self, rig: Rig, config: PipelineConfig | None = None, method: str = "auto"):
        if method not in PIPELINE_METHODS:
            raise InputError("pipeline", f"unknown method {method!r} (choose one of {', '.join(PIPELINE_METHODS)})",
                             "method")
        self.rig = rig
        self.config = config or PipelineConfig()
        self.method = method
        self.imu = ImuBuffer(rig, self.config.imu)
        self.zupt = ZuptDetector(self.config.zupt, buffer=self.imu)
        self.bar_period_s = slowest_bar_period(rig)
        self.stats = PipelineStats()
        seq_method = "4pt-bending" if method == "auto" else method
        self.sequence = IncrementalSequence(rig, seq_method, self.config.sequence_options(), self.config.window,
                                            seed=self.config.seed)
        self.linker = HoldLinker(rig, self.config.tracking)
        self.trackers = [KltTracker(self.config.tracking) for _ in rig.cameras]
        self._hold: HoldRecorder | None = None
        self._hold_stamps: list = []  # stamp of every hold of the current sequence
        self._periods: list = []  # recent intervals between frame sets (s)
        self.last_stamp = -math.inf
        self._last_check = -math.inf  # when an open hold's settled part was last measured
        self._last_motion: dict = {}  # kind of motion -> the latest frame's reason, with its numbers

    # ------------------------------------------------------------------ input
    def add_imu(self, stamp: float, accel, gyro=None, covariance=None) -> None:
        """One IMU sample (specific force m/s^2, angular rate rad/s, IMU frame) and, optionally, its message's
        (linear_acceleration_covariance, angular_velocity_covariance); bad samples are counted."""
        if self.rig.imu is None:
            self.stats.dropped["imu sample ignored: rig file has no imu block"] += 1
            return
        reason = self.zupt.add(stamp, accel, gyro, covariance)
        if reason:
            self.stats.dropped[f"imu sample: {reason}"] += 1

    def _check(self, frames: FrameSet) -> list:
        src = f"frame set at {frames.stamp!r}"
        if isinstance(frames.stamp, bool) or not isinstance(frames.stamp, (int, float, np.floating)) or \
                not math.isfinite(float(frames.stamp)):
            raise InputError(src, "stamp must be a finite number of seconds", "stamp")
        imgs = list(frames.images)
        if len(imgs) != self.rig.num_cameras:
            raise InputError(src, f"got {len(imgs)} images but the rig {self.rig.source} has "
                             f"{self.rig.num_cameras} cameras", "images")
        out = []
        for cam, img in zip(self.rig.cameras, imgs):
            if img is None:
                out.append(None)
                continue
            where = cam.image_topic or cam.name
            a = np.asarray(img)
            if a.ndim != 2 or a.dtype != np.uint8:
                raise InputError(where, f"camera {cam.name!r}: expected a 2-D uint8 image, got shape {a.shape} "
                                 f"dtype {a.dtype}", "images")
            check_image_size(cam, a.shape[1], a.shape[0], where)
            out.append(np.ascontiguousarray(a))
        if all(x is None for x in out):
            raise InputError(src, "no camera has an image", "images")
        return out

    def _lone_gap(self) -> float:
        """Frames further apart than this do not belong to one stream (s)."""
        p = float(np.median(self._periods)) if self._periods else 0.0
        return max(self.config.holds.lone_gap_s, self.config.holds.lone_periods * p)

    def add_frames(self, frames: FrameSet) -> list:
        """Process one frame set; returns the hold estimates it completed (0 or more).

        Raises InputError (naming the camera) for a wrong number, size or type of images; the pipeline's state
        is untouched then and later frames work.
        """
        images = self._check(frames)
        stamp = float(frames.stamp)
        if stamp <= self.last_stamp:
            self.stats.dropped["frame set out of order"] += 1
            return []
        gap = stamp - self.last_stamp
        self.stats.frames += 1
        steps = [None if img is None else trk.track(img) for trk, img in zip(self.trackers, images)]
        lone_gap = self._lone_gap()
        out = []
        lost = any(s is not None and s.lost for s in steps)
        settling = self._hold is not None and stamp - self._hold.start < self._settle_window()
        if lost and settling and gap <= lone_gap:
            self._reanchor(stamp, images)  # the bars ring too far for the tracks: anchor again, keep the stop
            self._periods = (self._periods + [gap])[-20:]
        elif gap > lone_gap or lost:
            # a new stream, a snapshot, or a jump the tracks could not follow: what was open ends with the
            # previous frame, and this one may start a hold (the rig may be at rest here, its bars ringing)
            out += self._close()
            self._open(stamp, images, snapshot=True)
            if gap <= lone_gap:
                self._periods = (self._periods + [gap])[-20:]
        else:
            self._periods = (self._periods + [gap])[-20:]
            still, why = self._still(self.last_stamp, stamp, steps)
            if self._hold is not None and still:
                self._record(stamp, images)
            elif self._hold is not None and why.endswith("from its first frame)") and settling:
                # the image left the hold before the bars could have settled: ringing, not a move (a move this
                # soon after a stop could not give a settled hold anyway). Anchor again, keep the stop time.
                self._reanchor(stamp, images)
            elif self._hold is not None:
                if len(self._hold) == 1 and self._hold.snapshot:
                    self._moving(why)  # the first frame of a moving stream
                    self._discard()
                else:
                    out += self._close()
            elif still:
                self._open(stamp, images, snapshot=False)
            else:
                self._moving(why)
        self.last_stamp = stamp
        out += self._measure_early(stamp)
        return out

    def flush(self) -> list:
        """Close the open hold (end of a bag, or the cameras stopped)."""
        return self._close()

    def reset(self) -> None:
        """Start a new sequence (the next hold is its origin)."""
        self._discard()
        self.sequence.reset()
        self.linker.reset()
        self._hold_stamps = []

    # ------------------------------------------------------------------ holds
    def _still(self, t0: float, t1: float, steps: list):
        """Whether the rig was at rest between two frames, and why not.

        With an IMU sample in between, the IMU decides (the bars may ring while the body is still); the images
        only say that the tracks were lost. Without one, a hold starts when the image barely moved between
        two frames and lasts while it stays near the hold's first frame (ringing stays near, a move leaves).
        """
        imu = self.zupt.is_still(t0, t1) if self.rig.imu is not None and len(self.imu) else None
        if imu is False:
            return False, "the IMU says the rig moved"
        cfg = self.config.holds
        for i, s in enumerate(steps):
            if s is None:
                continue
            name = self.rig.cameras[i].name
            if s.lost:
                return False, f"{name}: tracks lost"
            if imu is True:
                continue
            if self._hold is None and math.isfinite(s.motion_px) and s.motion_px > cfg.still_step_px:
                return False, f"{name}: image moved {s.motion_px:.2f} px"
            radius = math.radians(cfg.hold_radius_deg) * self.rig.cameras[i].focal_px
            if self._hold is not None and math.isfinite(s.offset_px) and s.offset_px > radius:
                return False, f"{name}: image left the hold ({s.offset_px:.1f} px from its first frame)"
        return True, ""

    def _open(self, stamp: float, images: list, snapshot: bool) -> None:
        anchors, anchor_images = [], []
        for trk, img in zip(self.trackers, images):
            if img is None:
                anchors.append(None)
                anchor_images.append(None)
                trk.end_hold()
                continue
            trk.start_hold()
            anchors.append(trk.positions())
            anchor_images.append(img)
        self._hold = HoldRecorder(stamp, anchors, anchor_images, snapshot)
        self._record(stamp, images)
        self._last_check = stamp

    def _moving(self, why: str) -> None:
        """Count a frame that is not at rest by kind of reason (the numbers of the latest one are kept)."""
        kind = next((k for k in _MOTION_KINDS if k in why), why)
        self.stats.dropped[f"frame not at rest ({kind})"] += 1
        self._last_motion[kind] = why

    def no_hold_report(self) -> str:
        """Why no hold was found (empty once one was): what judged the frames moving, with the numbers."""
        st = self.stats
        if st.holds or not st.frames:
            return ""
        lines = [f"no hold found in {st.frames} frame sets"]
        moving = {k: v for k, v in st.dropped.items() if k.startswith("frame not at rest")}
        for k, n in sorted(moving.items(), key=lambda kv: -kv[1]):
            kind = k[len("frame not at rest ("):-1]
            lines.append(f"  {n} frame sets not at rest: {self._last_motion.get(kind, kind)} (the latest)")
        noise = self.zupt.noise if self.rig.imu is not None and len(self.imu) else None
        if noise is not None:
            z = self.config.zupt
            lines.append(f"  IMU stillness test: noise {max(noise.accel_sigma, z.accel_floor_m_s2):.3g} m/s^2 and "
                         f"{max(noise.gyro_sigma, z.gyro_floor_rad_s):.3g} rad/s "
                         f"per sample (from the {noise.source}), false-alarm probability "
                         f"{self.config.zupt.significance:g} per {self.config.zupt.window_s:g} s window")
        elif self.rig.imu is not None:
            lines.append("  no IMU samples were given: the images alone decided")
        if self.rig.imu is None or not len(self.imu):
            lines.append(f"  without an IMU a hold starts where the image moves at most "
                         f"{self.config.holds.still_step_px:g} px between two frames")
        for k, n in sorted(st.dropped.items()):
            if k.startswith("hold not used"):
                lines.append(f"  {n} holds too short or unsettled: {k[len('hold not used: '):]}")
        if st.frames < 2:
            lines.append("  a single frame set: a hold of one frame needs the IMU still before it, or no IMU")
        return "\n".join(lines)

    def _settle_window(self) -> float:
        """How long after a stop the bars may still ring (s)."""
        return self.config.holds.settle_periods * self.bar_period_s

    def _reanchor(self, stamp: float, images: list) -> None:
        """The open hold starts again from this frame (new anchor) but keeps the time the rig stopped."""
        start, snapshot = self._hold.start, self._hold.snapshot
        self._open(stamp, images, snapshot=snapshot)
        self._hold.start = start

    def _record(self, stamp: float, images: list) -> None:
        h = self._hold
        for i, (trk, img) in enumerate(zip(self.trackers, images)):
            if img is not None and h.anchors[i] is None:  # the camera's frame was missing when the hold began
                trk.start_hold()
                h.anchors[i], h.anchor_images[i] = trk.positions(), img
        h.add(stamp, [trk.positions() if trk.in_hold else None for trk in self.trackers])

    def _discard(self) -> None:
        self._hold = None
        for trk in self.trackers:
            trk.end_hold()

    def _imu_still_since(self, hold: HoldRecorder):
        if self.rig.imu is None or not len(self.imu):
            return None
        return self.zupt.still_since(hold.stamps[0])

    def _measure_early(self, stamp: float) -> list:
        """Estimate a long hold once its settled part lasts ``measure_s`` (it stays open until the rig moves)."""
        h = self._hold
        cfg = self.config.holds
        if h is None or h.measured or len(h) < 2 or stamp - self._last_check < 0.25 * cfg.measure_s:
            return []
        self._last_check = stamp
        if h.settled_duration(cfg, self.bar_period_s, self._imu_still_since(h)) < cfg.measure_s:
            return []
        out = self._estimate_hold(h)
        h.measured = True
        return out

    def _close(self) -> list:
        h = self._hold
        self._discard()
        if h is None or h.measured:
            return []
        if h.snapshot and len(h) == 1 and self.rig.imu is not None and len(self.imu):
            t = h.stamps[0]  # a snapshot is taken at the end of its hold: the IMU must be still before it
            if self.zupt.is_still(t - max(self.config.imu.pad_s, self.config.zupt.window_s), t) is False:
                self.stats.dropped["snapshot while the IMU says the rig moved"] += 1
                return []
        return self._estimate_hold(h)

    def _estimate_hold(self, rec: HoldRecorder) -> list:
        hold, why = rec.measure(self.config.holds, self.bar_period_s, self._imu_still_since(rec))
        if hold is None:
            self.stats.dropped[f"hold not used: {why.split(':')[0]}"] += 1
            self.last_hold_problem = why
            return []
        st = self.stats
        st.holds += 1
        st.ringing_holds += hold.ringing
        st.settle_s.append(hold.settle_s)
        st.residual_px.append(hold.residual_px)
        st.noise_px.append(hold.noise_px)
        st.averaged_noise_px.append(hold.averaged_noise_px)
        st.settled_frames.append(hold.settled_frames)
        t0 = time.perf_counter()
        obs = self.linker.link(hold)
        imu = self._imu_gravity(hold)
        if imu is None and self.method == "4pt-bending":  # forced: no silent fall back to 6pt-bending
            st.dropped["hold without IMU gravity (4pt-bending forced)"] += 1
            return []
        g = sigma = None
        if imu is not None:
            g = imu.gravity
            white = imu.accel_std / (self.rig.gravity_magnitude * math.sqrt(max(imu.num_samples, 1)))
            sigma = math.hypot(white, math.radians(self.config.imu_gravity_floor_deg))
        out = self.sequence.add_view(obs.cam, obs.landmark, obs.f, g, sigma)
        k = self.sequence.num_views - 1
        if k == 0:
            self._hold_stamps = [hold.stamp]
            if self.sequence.seq.number + 1 > st.sequences:
                st.sequences = self.sequence.seq.number + 1
            if isinstance(out, str) and out.startswith("new sequence"):
                st.dropped["hold starts a new sequence (too few landmarks shared)"] += 1
            return []
        self._hold_stamps.append(hold.stamp)
        if isinstance(out, str):
            st.dropped[f"hold not estimated: {out}"] += 1
            return []
        return [self._hold_estimate(out, hold, imu, obs.links, time.perf_counter() - t0)]

    def _imu_gravity(self, hold: Hold) -> ImuGravity | None:
        if self.rig.imu is None or not len(self.imu):
            return None
        t0, t1 = hold.settled_start, hold.settled_end
        if hold.snapshot:
            since = self.zupt.still_since(t1)
            t0 = t1 - self.config.imu.pad_s if since is None else max(since, t1 - 1.0)
        imu, why = self.imu.gravity(t0, t1)
        if imu is None:
            self.stats.dropped[f"hold without IMU gravity: {why.split(' (')[0]}"] += 1
        return imu

    def _hold_estimate(self, v: ViewEstimate, hold: Hold, imu, links, elapsed_s: float) -> HoldEstimate:
        st = self.stats
        st.estimates += 1
        st.methods[v.method] += 1
        R, t = self.sequence.relative_pose(v.view, v.reference)
        return HoldEstimate(
            stamp=hold.stamp, ref_stamp=self._hold_stamps[v.reference], method=v.method, R=R, t=t,
            gravity=v.gravity, gravity_sigma_deg=math.degrees(v.gravity_sigma_rad), cov_gravity=v.cov_gravity,
            num_inliers=v.num_inliers, num_observations=v.num_observations, time_ms=1000.0 * elapsed_s,
            origin_stamp=self._hold_stamps[0], R_origin=v.R, t_origin=v.t, cov_pose=v.cov_pose,
            sequence=v.sequence, hold_index=v.view, hold=hold, imu_gravity=None if imu is None else imu.gravity,
            links=links, window=v.window)

    # ------------------------------------------------------------------ batch
    def batch(self) -> list:
        """Every hold of the current sequence estimated jointly at once: (stamp, R_origin, t_origin, gravity,
        gravity_sigma_deg) per hold, origin first; empty with fewer than two holds."""
        est = self.sequence.batch()
        if not est.success:
            return []
        out = []
        for k, stamp in enumerate(self._hold_stamps[: len(est.R)]):
            g = None if est.gravity is None else est.gravity[k]
            s = math.nan if est.gravity_sigma_rad is None else math.degrees(est.gravity_sigma_rad[k])
            out.append((stamp, est.R[k], est.t[k], g, s))
        return out


__all__ = ["FrameSet", "HoldEstimate", "PIPELINE_METHODS", "Pipeline", "PipelineConfig", "PipelineStats"]
