"""Holds: the intervals in which the rig is still, measured from their settled frames (docs/PIPELINE.md, "Holds").

A :class:`HoldRecorder` collects, camera by camera, the track positions of
every frame of one hold (tracked from the hold's anchor frame, see
:class:`~nrmpc_ros.frontend.tracking.KltTracker`). :meth:`HoldRecorder.measure`
then decides which frames to use and how much to trust them:

- each camera's image offset after the stop (the median track displacement
  from the anchor) is fitted with its bar's damped response
  (:mod:`.ringing`, started at the rig file's sqrt(3 EI / (m L^3)) / (2 pi));
- frames where the fitted ringing is predicted below the noise
  (``max(settle_px, settle_noise x the offset's noise)``) and the offset is
  at rest are settled: their longest run is averaged, and carries what the
  average keeps of the fitted ringing (its mean over the frames used);
- a camera's tracks count only in the frames that carry its image, at that
  image's own stamp (cameras at their own rates and phases);
- bars that ring through the hold: the frames the damped response explains
  are used at its rest position (the fitted oscillation removed from every
  track of the camera, ``Hold.ringing``); too few frames to fit: all of them,
  with their spread as the residual ringing;
- a hold with one frame (a snapshot) carries the ringing its stop may have
  left, from the IMU's deceleration (or a default load) decayed at the bar's
  damping; without an IMU nothing tells when it stopped: it is measured as
  it stands, and the ringing a stop of the default load leaves, at any time
  since the frame before as likely as another (the envelope's root mean
  square over that interval), is an unknown turn of each camera that its
  covariance carries (``Hold.unknown_ringing_px``).

The ringing a hold may still carry is ``Hold.ringing_px`` (with its source):
the pipeline turns it into extra bearing noise for the joint estimate.
Only what is physically unusable is refused, by a typed rule
(:class:`Refusal`) with its numbers.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from ..config import check, option
from ..core.dynamics import bar_natural_frequencies
from ..core.loss import MAD_TO_STD
from ..core.rig import Rig
from .ringing import RingingFit, fit_damped_response, rest_drift
from .ringing_turns import turn_back

EXPLAINED_NOISE_SIGMAS = 3.0  # a fit explains a camera's offsets: residual within this many of their noise ...
EXPLAINED_SHARE = 0.1  # ... or within this share of the offsets' spread (the ringing it removed)
CREEP_SIGMAS = 3.0  # without an IMU a hold whose ringing's rest moves beyond this many stds (and thr) creeps
CREEP_MIN_FRAMES = 3  # a rest that moves is judged over at least this many frames (a line and its scatter)
TRIMMED_SHARES = (0.125, 0.25, 0.375)  # without an IMU, a fit is tried again without this share of the last frames
TAIL_MISFIT = 3.0  # ... where the first fit's residual RMS in those frames is at least this many times the rest's
OUTLIER_FACTOR = 5.0  # a frame further off a camera's fit than this many times its median frame is left out
GLITCH_SHARE = 0.1  # lone frames off the fits (stamp glitches) are bridged in a settled run while at most this share
MIN_FIT_FRAMES = 8  # the damped response has 8 parameters per camera (rest, cos, sin per axis; frequency, damping)
# for 2 numbers per frame: 8 frames leave as many degrees of freedom for its noise as it has parameters


class Refusal(Enum):
    """Why a hold gives no measurement: only what is physically unusable (:meth:`HoldRecorder.measure`)."""

    NO_FRAMES = "no frames"
    NO_TRACKS = "no camera had enough tracks"
    NOT_STILL = "the image never settled (the rig moved)"
    TRACKS_LOST = "too few tracks lasted through the settled frames"
    TURNING = "the IMU says the rig turned steadily through it"


@dataclass(frozen=True)
class HoldRefusal:
    """A refused hold: the rule (counted by the pipeline) and the numbers behind it."""

    rule: Refusal
    detail: str

    def __str__(self) -> str:
        return f"{self.rule.value}: {self.detail}" if self.detail else self.rule.value

    def __contains__(self, text: str) -> bool:
        return text in str(self)


class RingingSource(Enum):
    """Where a hold's expected residual ringing comes from (:attr:`Hold.ringing_px`)."""

    SETTLED = "settled"  # the fitted ringing (or the image itself) is below the noise in the frames used
    FIT = "fit"  # the damped response fitted to the hold's image offsets (rest position of the fit)
    SPREAD = "spread"  # too few frames to fit the ringing: the offsets' own spread about their mean
    IMU = "imu"  # a snapshot: the stop's deceleration measured by the IMU, decayed at the bar's damping
    DEFAULT = "default"  # a snapshot whose stop the IMU did not see: holds.stop_load_m_s2, decayed
    PREDICTED = "predicted"  # a snapshot whose ringing the IMU-driven bars predicted and removed: that error
    RIGID = "rigid"  # no flexible bar: nothing rings
    UNKNOWN = "unknown"  # a snapshot without an IMU: nothing says when the rig stopped


@dataclass
class HoldConfig:
    """When frames belong to a hold, how far their bars may still ring (pixels of each camera's image)."""

    still_step_px: float = option(0.3, "without an IMU a hold starts when the median image motion between two "
                                  "frames is at most this (px)", lo=0.0, hi=100.0, lo_open=True)
    hold_radius_deg: float = option(3.0, "without an IMU a hold lasts while the image stays within this angle of "
                                    "the hold's first frame (deg, through each camera's focal length): ringing "
                                    "bars oscillate inside it, the moves between holds leave it", lo=0.0, hi=90.0,
                                    lo_open=True)
    settle_px: float = option(0.2, "the ringing is settled where the damped response predicts less than this "
                              "(px) or less than settle_noise times the image offset's noise; a frame deviating "
                              "from the rest position by more is not at rest", lo=0.0, hi=100.0, lo_open=True)
    settle_noise: float = option(4.0, "see settle_px (in units of the offset's frame-to-frame noise)", lo=0.0,
                                 hi=1000.0, lo_open=True)
    damping: float = option(0.02, "damping ratio assumed for bars whose rig file gives none (a light damping: the "
                            "ringing is assumed to last long, so its expected residual is conservative)",
                            lo=0.0, hi=0.99, lo_open=True)
    stop_load_m_s2: float = option(3.0, "a snapshot whose stop the IMU did not see is assumed to have stopped "
                                   "with this change of load (m/s^2) setting its bars ringing", lo=0.0, hi=100.0)
    predict_ringing: bool = option(True, "with an IMU, a snapshot's ringing predicted by the bars' state is "
                                   "removed from its bearings and only the prediction's error is extra noise "
                                   "(false: the stop's decayed envelope is the extra noise)")
    damping_rel_std: float = option(0.2, "relative std of a damping ratio the rig file gives (the bar "
                                     "calibration's target), for the predicted ringing's error", lo=0.0, hi=10.0)
    unknown_damping_std: float = option(0.03, "std of the damping ratio of a bar whose rig file gives none (the "
                                        "assumed light damping, while bars with a camera at the tip span about "
                                        "0.01-0.08), for the predicted ringing's error", lo=0.0, hi=1.0)
    frequency_rel_std: float = option(0.01, "relative std of a bar's natural frequency sqrt(3 EI / (m L^3)) / "
                                      "(2 pi): half that of the rig file's compliance as the bar calibration "
                                      "measures it (2 %), for the predicted ringing's error", lo=0.0, hi=1.0)
    ringing_depth_m: float | None = option(None, "a snapshot's camera moved by its predicted ringing (not "
                                           "removed) is judged at points this far (m): its translation over this "
                                           "depth is part of the prediction's error; None: not counted (the "
                                           "hold's pose and landmarks absorb most of it)", lo=0.0, hi=1e6,
                                           lo_open=True, nullable=True)
    lone_gap_s: float = option(1.0, "a frame with no other frame within this (s), or lone_periods frame periods, "
                               "is a snapshot: a hold of its own", lo=0.0, hi=3600.0, lo_open=True)
    lone_periods: float = option(3.0, "see lone_gap_s", lo=0.0, hi=1000.0)
    measure_s: float = option(2.0, "a hold is estimated once its settled part lasts this long (s), or when it "
                              "ends", lo=0.0, hi=3600.0, lo_open=True)
    min_settled_frames: int = option(3, "frames in a row a settled part needs (fewer when the hold has fewer)",
                                     lo=1, hi=100000)
    min_track_share: float = option(0.5, "a track is averaged when it is in this share of the settled frames",
                                    lo=0.0, hi=1.0, lo_open=True)
    min_tracks: int = option(8, "tracks a camera needs in a hold to contribute", lo=1, hi=100000)

    def __post_init__(self):
        check(self, "hold config")


@dataclass
class BarRinging:
    """What the hold logic knows of the bars' ringing: the slowest bar's frequency (Hz, inf: rigid) and damping
    ratio (the rig file's, an identified one, or ``holds.damping``), and each camera's image offset per unit of
    load (px per m/s^2: the bar's tip rotation per load through the focal length)."""

    freq_hz: float
    zeta: float
    px_per_load: np.ndarray  # (M,)
    camera_freq_hz: np.ndarray | None = None  # (M,) each camera's own bar (inf: rigid); None: all at freq_hz
    cameras: tuple | None = None  # the rig's cameras: their models turn a ringing camera's tracks back (None: pixels)

    @classmethod
    def of(cls, rig: Rig, cfg: HoldConfig | None = None) -> BarRinging:
        cfg = cfg or HoldConfig()
        f = bar_natural_frequencies(rig)
        flex = np.isfinite(f) & (f > 0)
        zs = [getattr(c, "damping", None) for c, fl in zip(rig.cameras, flex) if fl]
        zs = [z for z in zs if z is not None and 0 < z < 1]
        zeta = min(zs) if zs else cfg.damping  # the slowest decay rules the settling
        cr_ux = rig.bar_derivatives[1]  # (M, 3, 3): bend rotation per unit load
        px = np.array([np.linalg.norm(cr_ux[i], 2) * c.focal_px for i, c in enumerate(rig.cameras)])
        return cls(float(f[flex].min()) if flex.any() else math.inf, float(zeta), px, np.where(flex, f, math.inf),
                   tuple(rig.cameras))

    def camera_freq(self, i: int) -> float:
        """Camera i's bar frequency (Hz): its ringing in the image is at its own bar's frequency."""
        return self.freq_hz if self.camera_freq_hz is None else float(self.camera_freq_hz[i])

    @property
    def period_s(self) -> float:
        return 1.0 / self.freq_hz if math.isfinite(self.freq_hz) and self.freq_hz > 0 else 0.0

    def envelope(self, amplitude_px: float, tau) -> np.ndarray:
        """The ringing envelope (px) at times tau after a stop that started it at ``amplitude_px``."""
        tau = np.maximum(np.asarray(tau, dtype=float), 0.0)
        if not self.period_s:
            return np.zeros_like(tau)
        return amplitude_px * np.exp(-self.decay_per_s * tau)

    @property
    def decay_per_s(self) -> float:
        """The envelope's decay rate zeta 2 pi f (1/s)."""
        return self.zeta * 2.0 * math.pi * self.freq_hz

    def rms_envelope(self, amplitude_px: float, span_s: float) -> float:
        """The root mean square of the ringing envelope (px) over a stop at a time uniformly unknown within the
        ``span_s`` before the instant (the stop started it at ``amplitude_px``): A sqrt((1 - e^(-2 a T)) / (2 a
        T)), a = zeta 2 pi f; 0 for an unbounded span (nothing before) and for rigid bars."""
        if not self.period_s or not (math.isfinite(span_s) and span_s > 0.0):
            return 0.0
        x = 2.0 * self.decay_per_s * span_s
        return float(amplitude_px * math.sqrt(-math.expm1(-x) / x))


def slowest_bar_period(rig: Rig) -> float:
    """Period (s) of the slowest flexible bar of the rig; 0 for a rigid rig."""
    f = bar_natural_frequencies(rig)
    f = f[np.isfinite(f) & (f > 0)]
    return float(1.0 / f.min()) if len(f) else 0.0


@dataclass
class CameraHold:
    """One camera's measurement of a hold: its tracks' averaged positions (px) and what they cost."""

    ids: np.ndarray  # (n,) track ids of the camera's tracker
    uv: np.ndarray  # (n, 2) averaged over the settled frames
    anchor_uv: np.ndarray  # (n, 2) in the anchor frame (where descriptors are taken)
    frames: int  # settled frames with this camera
    noise_px: float  # std of one frame's track position (px), NaN with a single frame


@dataclass
class SettlingSeries:
    """How a hold settled: per frame (stamps ``t``, s) each camera's image offset from its rest position (px, the
    median track displacement from the anchor frame minus its median over the frames after the settle time;
    NaN where the camera had no tracks), the threshold a settled frame stays under (px) and the time from which
    frames count (the start of the settled part)."""

    t: np.ndarray  # (F,)
    offset_px: np.ndarray  # (F, M) rig camera order
    threshold_px: float
    settle_after: float


@dataclass
class Hold:
    """A measured hold (times in seconds)."""

    start: float  # the rig stopped (IMU still onset, or the first frame of the hold)
    end: float  # last frame of the hold
    settled_start: float
    settled_end: float
    stamp: float  # a frame inside the settled part: the hold's estimates carry it
    frames: int  # frames of the hold
    settled_frames: int
    residual_px: float  # RMS offset of the settled frames from the rest position (largest camera)
    cameras: list  # CameraHold or None, rig camera order
    snapshot: bool = False  # a single frame
    anchor_images: list = field(default_factory=list)  # per camera: the anchor frame (descriptors)
    ringing: bool = False  # the bars still rang at the end: measured at the fitted rest position
    settling: SettlingSeries | None = None  # every camera's image offset over the hold's frames (None: a snapshot)
    ringing_px: float = 0.0  # the residual ringing the measurement may carry (px, largest camera): extra noise
    ringing_source: RingingSource = RingingSource.SETTLED
    # a snapshot nothing saw stop: per camera the ringing a stop of holds.stop_load_m_s2 at any time since the
    # frame before leaves (px, per axis): not removed, not weighed, an unknown turn the covariance carries (None:
    # none)
    unknown_ringing_px: np.ndarray | None = None
    trace_t: np.ndarray | None = None  # (F,) stamps of the hold's frames
    trace: np.ndarray | None = None  # (F, M, 2) each camera's image offset from its anchor (NaN: no camera)
    fit: list = field(default_factory=list)  # per camera: the RingingFit of its offsets, or None

    @property
    def settle_s(self) -> float:
        """How long after the stop the settled part began."""
        return self.settled_start - self.start

    @property
    def noise_px(self) -> float:
        """Median over cameras of one frame's position noise (px)."""
        v = [c.noise_px for c in self.cameras if c is not None and math.isfinite(c.noise_px)]
        return float(np.median(v)) if v else math.nan

    @property
    def averaged_noise_px(self) -> float:
        """The same for the averaged positions: noise_px / sqrt(settled frames)."""
        v = [c.noise_px / math.sqrt(c.frames) for c in self.cameras
             if c is not None and math.isfinite(c.noise_px) and c.frames > 0]
        return float(np.median(v)) if v else math.nan


class HoldRecorder:
    """The frames of the hold being recorded: per frame its stamp and every camera's (ids, uv)."""

    def __init__(self, start: float, anchors: list, anchor_images: list, snapshot: bool = False,
                 since_previous_s: float = math.inf):
        """anchors: per camera (ids, uv) of the anchor frame or None; start: when the rig stopped;
        ``since_previous_s``: from the frame set before its first to its first (inf: none before)."""
        self.start = float(start)
        self.anchors = anchors
        self.anchor_images = anchor_images
        self.snapshot = snapshot
        self.stamps: list = []
        self.taken: list = []  # per frame: each camera's image stamp (s), None for a camera without an image
        self.positions: list = []  # per frame: list of (ids, uv) or None per camera
        self.measured = False  # estimated already (a long hold is measured once, before it ends)
        self.aligned_ahead = False  # its anchor frames went to the estimation stage once it had settled
        self.prediction = None  # a snapshot's ringing predicted from the IMU (.snapshot_ringing.RingingPrediction)
        self.prediction_at = None  # (stamp, cameras, their image stamps) of a snapshot whose ringing is yet to be
        # predicted: once the IMU's stillness test has decided that instant, at the latest when the hold is measured
        self.jumped = ""  # the camera whose lost tracks opened it inside a stream (a jump, not a lone frame)
        self.since_previous_s = float(since_previous_s)

    def add(self, stamp: float, positions: list, taken: list | None = None) -> None:
        """One frame of the hold at ``stamp``: per camera its tracks' (ids, uv) or None, ``taken`` the stamp of
        each camera's image (None: the frame's stamp, for every camera with positions)."""
        self.stamps.append(float(stamp))
        self.positions.append(positions)
        self.taken.append([None if p is None else float(stamp if taken is None or taken[i] is None else taken[i])
                           for i, p in enumerate(positions)])

    def __len__(self) -> int:
        return len(self.stamps)

    def _camera_tracks(self, i: int):
        """(anchor ids (n,), anchor uv (n, 2), X (F, n, 2) with NaN where a frame lacks the track)."""
        a_ids, a_uv = self.anchors[i]
        F = len(self.stamps)
        X = np.full((F, len(a_ids), 2), np.nan)
        for f, pos in enumerate(self.positions):  # frames, not points: the points of a frame go at once
            if pos is None or pos[i] is None:
                continue
            ids, uv = pos[i]
            _, ia, ib = np.intersect1d(a_ids, ids, assume_unique=True, return_indices=True)
            X[f, ia] = uv[ib]
        return a_ids, a_uv, X

    def measure(self, cfg: HoldConfig, bar_period_s: float, imu_still_since: float | None = None,
                bars: BarRinging | None = None, stop_amplitude_px: float | None = None):
        """(Hold, None) of the hold's frames, or (None, :class:`HoldRefusal`).

        ``bars`` (default: the slowest bar at ``bar_period_s``, damping ``cfg.damping``) predicts the ringing;
        ``stop_amplitude_px``: the image ringing the stop set off (from the IMU's deceleration): a snapshot's
        residual ringing, and how far a hold too short to fit its ringing may plausibly ring.
        """
        if bars is None:
            f = 1.0 / bar_period_s if bar_period_s > 0 else math.inf
            bars = BarRinging(f, cfg.damping, np.zeros(len(self.anchors)))
        with warnings.catch_warnings():  # frames without a camera, tracks lost: all-NaN medians are expected
            warnings.simplefilter("ignore", RuntimeWarning)
            return self._measure(cfg, bars, imu_still_since, stop_amplitude_px)

    def _measure(self, cfg: HoldConfig, bars: BarRinging, imu_still_since: float | None,
                 stop_amplitude_px: float | None):
        F = len(self.stamps)
        if F == 0:
            return None, HoldRefusal(Refusal.NO_FRAMES, "")
        t = np.array(self.stamps)
        M = len(self.anchors)
        taken = np.array([[np.nan if x is None else x for x in row] for row in self.taken], float).reshape(F, M)
        cams = [i for i in range(M) if self.anchors[i] is not None and len(self.anchors[i][0]) >= cfg.min_tracks]
        if not cams:
            return None, HoldRefusal(Refusal.NO_TRACKS, f"fewer than {cfg.min_tracks} in every camera")
        start = self.start if imu_still_since is None else min(self.start, imu_still_since)
        tau = t - start
        own_tau = np.where(np.isfinite(taken), taken, t[:, None]) - start  # (F, M) each camera's images' own times
        tracks = {i: self._camera_tracks(i) for i in cams}
        ringing, fits = False, [None] * M
        trace = np.full((F, M, 2), np.nan)
        correction = np.zeros((F, M, 2))  # the fitted ringing removed from every track of a camera
        track_correction = {}  # camera -> (F, n, 2): each track's own fitted ringing, where fitted
        settling = None
        unknown = None
        if F == 1 and not self.snapshot and imu_still_since is None:
            # a stream's hold cut to one frame (the next one moved, the ones before left it): nothing shows the rig
            # at rest there (a snapshot's stillness is its capture's promise; a stream shows it in its frames)
            return None, HoldRefusal(Refusal.NOT_STILL, "one frame of a stream, and the images moved around it")
        if F == 1:
            settled = np.ones(1, bool)
            residual = 0.0
            if not bars.period_s:
                ringing_px, source = 0.0, RingingSource.RIGID
            elif imu_still_since is None:
                ringing_px, source = 0.0, RingingSource.UNKNOWN
                # the stop came at any time since the frame before, as likely at one as at another (none before:
                # any time at all): the envelope's root mean square over that interval; at a random phase of the
                # swing, along one of the two directions a bar bends in: a std of half of it per axis
                unknown = 0.5 * bars.rms_envelope(cfg.stop_load_m_s2, self.since_previous_s) * bars.px_per_load
            else:
                source = RingingSource.IMU if stop_amplitude_px is not None else RingingSource.DEFAULT
                a0 = stop_amplitude_px if stop_amplitude_px is not None else \
                    cfg.stop_load_m_s2 * float(np.max(bars.px_per_load, initial=0.0))
                ringing_px = float(bars.envelope(a0, tau[0]))
        else:
            shifts = [tracks[i][2] - tracks[i][1][None] for i in cams]  # (F, n, 2) per camera
            offsets = np.stack([np.nanmedian(d, axis=1) for d in shifts], axis=1)  # (F, cams, 2)
            trace[:, cams] = offsets
            noise = _offset_noise(shifts, offsets)
            thr = max(cfg.settle_px, cfg.settle_noise * noise)
            after = tau >= 0
            env = np.zeros(F)  # predicted ringing per frame (largest camera)
            model = np.zeros_like(offsets)  # fitted ringing (without the rest offset)
            rest = np.nanmedian(offsets[after][len(offsets[after]) // 2:], axis=0)  # (cams, 2): the later half
            fitted = False
            span = float(tau[after][-1] - tau[after][0]) if after.sum() > 1 else 0.0
            fit_tried = bool(bars.period_s) and after.sum() >= MIN_FIT_FRAMES and span >= bars.period_s
            if fit_tried:  # a period pins the rest
                for k, i in enumerate(cams):
                    tau_i = own_tau[:, i]
                    fit = _camera_fit(tau_i, offsets[:, k], after, bars.camera_freq(i), noise, imu_still_since is None)
                    if fit is None:
                        continue
                    fits[i] = fit
                    model[:, k] = fit.oscillation(0, tau_i)
                    env = np.maximum(env, fit.amplitude(0, tau_i))
                    rest[k] = fit.rest[0]
                    fitted = True
            dev = np.nanmax(np.linalg.norm(offsets - rest[None], axis=2), axis=1)
            at_rest = after & (env <= thr) & (dev <= thr)
            need = min(cfg.min_settled_frames, int(after.sum()))
            settled = _longest_run(at_rest) if at_rest.any() else at_rest
            creep = _creep_px([None] * M, cams, own_tau, offsets, settled) \
                if imu_still_since is None and settled.sum() >= max(need, 1) else None
            if creep is None and imu_still_since is None and not self.snapshot and settled.sum() >= max(need, 1):
                # a stream's settled frames too few for any camera's drift to be judged: as with one frame,
                # nothing shows the rig at rest there (a slow creep moves the image less than its noise from one
                # frame to the next; only a line through CREEP_MIN_FRAMES of them shows it)
                return None, HoldRefusal(Refusal.NOT_STILL, (
                    f"{int(settled.sum())} settled frames of a stream, fewer than the {CREEP_MIN_FRAMES} that show "
                    f"the images do not drift"))
            if creep is not None and creep[1] > max(thr, CREEP_SIGMAS * creep[2]):
                # the images alone judge stillness: settled frames whose image drifts are a creep (the frames
                # within the bound of the rest are then the few the drift passes through)
                return None, HoldRefusal(Refusal.NOT_STILL, (
                    f"camera {creep[0]}'s image drifts by {creep[1]:.2f} px over the settled frames "
                    f"(std {creep[2]:.2f} px, threshold {thr:.3f} px)"))
            if settled.sum() >= max(need, 1):
                source = RingingSource.SETTLED if bars.period_s else RingingSource.RIGID
                # what the average of the settled frames keeps of the fitted ringing: its mean over each camera's
                # frames used (the swing about that mean is in the tracks' measured noise already)
                present = np.isfinite(offsets[:, :, 0]) & settled[:, None]
                kept = [float(np.linalg.norm(model[present[:, k], k].mean(axis=0)))
                        for k in range(len(cams)) if present[:, k].any()]
                ringing_px = max(kept, default=0.0)
            elif fitted:
                # the bars ring through the frames: every frame whose offset the damped response explains is
                # used at the fitted rest position (the ringing removed from every track of its camera)
                # a frame the fit explains lies within the fit's own scatter of it (what the model does not
                # follow of a large ringing, e.g. the stamps' jitter times its speed), at least within thr
                per_cam = np.linalg.norm(offsets - rest[None] - model, axis=2)  # (F, cams)
                tol = np.array([thr if fits[i] is None else
                                max(thr, EXPLAINED_NOISE_SIGMAS * math.sqrt(2.0) * fits[i].residual_rms)
                                for i in cams])
                dev_model = np.nanmax(per_cam, axis=1)
                off = per_cam > tol[None]  # (F, cams)
                explained = after & ~off.any(axis=1)
                # a lone frame off a camera's fit between two frames the fits explain is a stamp's glitch (a
                # software-synchronised camera's frame stamped late), not a move: left out, it does not cut the
                # run -- while such frames are rare; a camera without a fit judges its frames as before
                unfitted = np.array([fits[i] is None for i in cams])
                glitch = _lone_gaps(explained) & ~(off & unfitted[None]).any(axis=1)
                if glitch.sum() > GLITCH_SHARE * explained.sum():
                    glitch[:] = False
                settled = _longest_run(explained | glitch) & explained
                if settled.sum() < need:
                    return None, HoldRefusal(Refusal.NOT_STILL, (
                        f"the damped response explains no {need} frames in a row within {thr:.3f} px"))
                if imu_still_since is None:  # the images alone judge stillness: a rest that creeps is a move
                    creep = _creep_px(fits, cams, own_tau, offsets, settled)
                    if creep is not None and creep[1] > max(thr, CREEP_SIGMAS * creep[2]):
                        return None, HoldRefusal(Refusal.NOT_STILL, (
                            f"the rest of camera {creep[0]}'s ringing moves by {creep[1]:.2f} px over the hold "
                            f"(std {creep[2]:.2f} px, threshold {thr:.3f} px)"))
                turn_std = {}  # camera -> the std of its rest turn (px through its focal length)
                for k, i in enumerate(cams):
                    correction[:, i] = model[:, k]
                    if fits[i] is None:
                        continue
                    tau_i = own_tau[:, i]
                    X = tracks[i][2]
                    # the camera's turns taken back to its rest through its own model (ringing_turns), then
                    # each track's own remaining ringing (the bar tip's shift) where it was seen long enough
                    turned = None if bars.cameras is None else turn_back(
                        bars.cameras[i], tracks[i][1], X, tau_i, settled, bars.camera_freq(i), MIN_FIT_FRAMES)
                    if turned is not None:
                        turn_std[i] = float(np.max(turned[1].rest_std)) * bars.cameras[i].focal_px
                    Xb = X if turned is None else turned[0]
                    own, fitted_tracks = fits[i].track_oscillations(tau_i, Xb, settled, MIN_FIT_FRAMES)
                    left = 0.0 if turned is not None else model[:, k][:, None, :]
                    track_correction[i] = X - Xb + np.where(fitted_tracks[None, :, None], own, left)
                ringing, source = True, RingingSource.FIT
                rest_std = {i: turn_std.get(i, fits[i].rest_std[0]) for i in cams if fits[i] is not None}
                dev = dev_model
            elif bars.period_s and np.nanmax(dev[after], initial=0.0) <= _radius_px(cfg, bars, stop_amplitude_px) \
                    and (imu_still_since is not None or
                         (not fit_tried and _oscillates(tau[after], offsets[after], bars.period_s))):
                # too few frames (or less than a period) to fit the ringing: all of them, trusted as far as their
                # own spread allows. Without an IMU only where no fit could be tried: frames enough to fit that
                # no damped response explains show something else than ringing (a creep under it), and nothing
                # vouches for their stillness
                settled = after.copy()
                ringing, source = True, RingingSource.SPREAD
                ringing_px = float(np.sqrt(np.nanmean(dev[settled] ** 2)))
            else:
                return None, HoldRefusal(Refusal.NOT_STILL, (
                    f"image offset from the rest position {np.nanmin(dev[after]) if after.any() else math.nan:.3f}"
                    f" px at best, threshold {thr:.3f} px, and no damped response of the bar "
                    f"({bars.freq_hz:.3g} Hz) explains the offsets"))
            residual = float(np.sqrt(np.nanmean(dev[settled] ** 2)))
            per_camera = np.full((F, M), np.nan)
            per_camera[:, cams] = np.linalg.norm(offsets - rest[None], axis=2)
            settling = SettlingSeries(t, per_camera, float(thr), float(t[np.flatnonzero(settled)[0]]))
        idx = np.flatnonzero(settled)
        cam_holds = [None] * M
        for i in cams:
            a_ids, a_uv, X = tracks[i]
            Xs = X[idx] - (track_correction[i][idx] if i in track_correction else correction[idx, i][:, None, :])
            present = np.isfinite(Xs[:, :, 0])
            frames = int(np.count_nonzero(present.any(axis=1)))
            if frames == 0:
                continue
            keep = present.sum(axis=0) >= max(1, cfg.min_track_share * frames)
            if keep.sum() < cfg.min_tracks:
                continue
            mean = np.nanmean(Xs[:, keep], axis=0)
            n = present[:, keep].sum(axis=0)
            dev2 = np.nansum((Xs[:, keep] - mean[None]) ** 2, axis=(0, 2))
            dof = 2 * (n - (3 if i in track_correction else 1))  # (rest, and each track's own cos and sin)
            noise = math.sqrt(float(dev2.sum() / dof.sum())) if dof.sum() > 0 else math.nan
            cam_holds[i] = CameraHold(a_ids[keep], mean, a_uv[keep], frames, noise)
        if all(c is None for c in cam_holds):
            return None, HoldRefusal(Refusal.TRACKS_LOST, f"fewer than {cfg.min_tracks} tracks in every camera")
        if source is RingingSource.FIT:
            # the fitted rest's uncertainty beyond what the tracks' own noise gives it, which their average
            # carries already (what the fit does not follow, e.g. the stamps' jitter, moves all tracks of a frame
            # alike: their average does not shrink it). That part is a frame's median offset's noise (pi/2 times
            # the tracks' noise squared over their number) over the frames: from the tracks' own noise, not from
            # the spread of their shifts about the frame's median, which a large turn of a wide-angle camera
            # makes pixels wide across the image
            extra = [s ** 2 - (0.5 * math.pi * np.nan_to_num(c.noise_px) ** 2 / (c.frames * len(c.ids))
                               if c is not None else 0.0)
                     for s, c in ((s, cam_holds[i]) for i, s in rest_std.items())]
            ringing_px = float(math.sqrt(max(max(extra, default=0.0), 0.0)))
        mid = idx[len(idx) // 2]
        return Hold(start=start, end=float(t[-1]), settled_start=float(t[idx[0]]), settled_end=float(t[idx[-1]]),
                    stamp=float(t[mid]), frames=F, settled_frames=len(idx), residual_px=residual,
                    cameras=cam_holds, snapshot=F == 1, anchor_images=self.anchor_images, ringing=ringing,
                    ringing_px=ringing_px, ringing_source=source, unknown_ringing_px=unknown, trace_t=t,
                    trace=trace, fit=fits, settling=settling), None

    def settled_duration(self, cfg: HoldConfig, bar_period_s: float, imu_still_since: float | None = None,
                         bars: BarRinging | None = None) -> float:
        """How long the settled part lasts so far (s); 0 when nothing is settled yet."""
        if len(self.stamps) < 2:
            return 0.0
        hold, _ = self.measure(cfg, bar_period_s, imu_still_since, bars)
        if hold is None or hold.ringing:  # ringing decays: such a hold is measured when it ends
            return 0.0
        return hold.settled_end - hold.settled_start


def _radius_px(cfg: HoldConfig, bars: BarRinging, stop_amplitude_px: float | None = None) -> float:
    """Largest image offset a ringing bar plausibly gives (px): the ringing a stop of ``stop_load_m_s2`` sets
    off, or twice the one the IMU measured for this stop (``stop_amplitude_px``) where that is larger (a swing to
    either side of a rest that a part of a period only roughly gives), at least 1 px; unbounded when the bars'
    image offset per load is not known."""
    px = float(np.max(bars.px_per_load, initial=0.0))
    measured = stop_amplitude_px if stop_amplitude_px is not None and math.isfinite(stop_amplitude_px) else 0.0
    return max(cfg.stop_load_m_s2 * px, 2.0 * measured, 1.0) if px > 0 else math.inf


def _oscillates(tau: np.ndarray, offsets: np.ndarray, period_s: float) -> bool:
    """Without an IMU, too few frames to fit the ringing: they show a ringing (not a slow move) when they span
    a bar period and a straight line through them drifts less than twice their spread about their mean (a
    ramp drifts 3.5 times its spread, an oscillation over a period or more less than 1.5 times)."""
    span = float(tau[-1] - tau[0]) if len(tau) > 1 else 0.0
    if span < period_s or len(tau) < CREEP_MIN_FRAMES:  # a line passes through two frames, whatever they show
        return False
    x = tau - tau.mean()
    y = offsets - np.nanmean(offsets, axis=0)
    slope = np.nansum(x[:, None, None] * y, axis=0) / max(float(x @ x), 1e-300)  # (cams, 2)
    drift = float(np.nanmax(np.abs(slope))) * span
    spread = float(np.sqrt(np.nanmean(y ** 2)))
    return drift <= 2.0 * spread


def _explains(fit: RingingFit, offsets: np.ndarray, noise: float) -> bool:
    """The damped response explains a camera's offsets: its residual is at the offsets' noise (or a small
    fraction of the ringing it removed), not a motion the model cannot follow."""
    spread = float(np.sqrt(np.nanmean(np.sum((offsets - np.nanmean(offsets, axis=0)) ** 2, axis=1))))
    return fit.residual_rms <= max(EXPLAINED_NOISE_SIGMAS * noise, EXPLAINED_SHARE * spread)


def _camera_fit(tau: np.ndarray, offsets: np.ndarray, after: np.ndarray, freq_hz: float, noise: float,
                late_end: bool) -> RingingFit | None:
    """The damped response of one camera's offsets (F, 2) at times tau (F,) that explains them (:func:`_explains`)
    over the frames ``after`` the stop, or None. A fit with frames far off it (beyond OUTLIER_FACTOR times the
    median frame's distance, at least 3 noise stds) is tried again without them, and so is a fit that does not
    explain: a hold may be seen to end a frame or two after the next move began, and that frame alone spoils the
    fit of the rest -- of a large ringing too, whose spread lets the spoiled fit pass as explaining and biases
    the rest it gives by a share of the frame's offset. ``late_end`` (without an IMU, where the images see a move
    start only once it outgrows the ringing, a few tenths of a second in): then also without the hold's last
    TRIMMED_SHARES of its frames, the first that explains, where the first fit's misfit sits in the frames left
    out (TAIL_MISFIT): a move starting, not a creep all along."""
    fit = fit_damped_response([(tau, offsets)], freq_hz, None)
    if fit is None:
        return None
    r = np.linalg.norm(offsets - fit.rest[0] - fit.oscillation(0, tau), axis=1)
    near = after & (r <= max(OUTLIER_FACTOR * float(np.nanmedian(r[after])), EXPLAINED_NOISE_SIGMAS * noise))
    explained = _explains(fit, offsets[after], noise)
    if explained and near.sum() == after.sum():
        return fit
    tries = [near]
    if late_end:  # only where the misfit sits in the frames left out (a move starting), not all along (a creep)
        F = len(tau)
        for share in TRIMMED_SHARES:
            keep = after & (np.arange(F) < F - math.ceil(share * F))
            tail = after & ~keep
            if tail.any() and keep.any() and \
                    np.sqrt(np.nanmean(r[tail] ** 2)) >= TAIL_MISFIT * np.sqrt(np.nanmean(r[keep] ** 2)):
                tries.append(keep)
    for keep in tries:
        if keep.sum() < MIN_FIT_FRAMES or keep.sum() == after.sum():
            continue
        refit = fit_damped_response([(tau[keep], offsets[keep])], freq_hz, None)
        if refit is not None and _explains(refit, offsets[keep], noise):
            return refit
    return fit if explained else None


def _creep_px(fits: list, cams: list, tau: np.ndarray, offsets: np.ndarray, settled: np.ndarray) -> tuple | None:
    """(camera, drift px, its std px) of the camera whose rest moves furthest over the ``settled`` frames
    (tau (F, M): each camera's images' times after the stop), or None without a camera to judge. A fitted camera
    (``fits[i]``) is judged with its ringing about a rest that moves linearly (:meth:`.ringing.RingingFit.drift`;
    a hold that creeps slowly while its bars ring keeps its frames near their first one and its ringing
    explained; only its rest moves) over at least MIN_FIT_FRAMES frames; the others with a rest alone that moves
    (:func:`.ringing.rest_drift`) over at least CREEP_MIN_FRAMES."""
    worst = None
    for k, i in enumerate(cams):
        tau_i = tau[:, i]
        use = settled & np.isfinite(offsets[:, k]).all(axis=1)
        if use.sum() < (MIN_FIT_FRAMES if fits[i] is not None else CREEP_MIN_FRAMES):
            continue
        v, sd = fits[i].drift(tau_i[use], offsets[use, k]) if fits[i] is not None else \
            rest_drift(tau_i[use], offsets[use, k], np.ones((int(use.sum()), 1)))
        span = float(np.ptp(tau_i[use]))
        drift, std = float(np.linalg.norm(v)) * span, float(np.linalg.norm(sd)) * span
        if worst is None or drift - CREEP_SIGMAS * std > worst[1] - CREEP_SIGMAS * worst[2]:
            worst = (i, drift, std)
    return worst


def _offset_noise(shifts: list, offsets: np.ndarray) -> float:
    """Noise (px) of a frame's image offset: the tracks' spread about their frame's median shift (measurement
    noise, whatever the rig does), over the square root of their number (the offset is their median)."""
    out = []
    for i, d in enumerate(shifts):
        r = np.linalg.norm(d - offsets[:, i, None, :], axis=2)  # (F, n)
        n = np.count_nonzero(np.isfinite(r), axis=1)
        ok = n > 0
        if ok.any():
            spread = MAD_TO_STD * np.nanmedian(r[ok], axis=1) / math.sqrt(2.0)  # per axis, per frame
            out.append(float(np.median(1.2533 * spread / np.sqrt(n[ok]))))
    return max(out) if out else 0.0


def _lone_gaps(mask: np.ndarray) -> np.ndarray:
    """The single False entries of mask with True on both sides."""
    out = np.zeros(len(mask), bool)
    if len(mask) >= 3:
        out[1:-1] = ~mask[1:-1] & mask[:-2] & mask[2:]
    return out


def _longest_run(mask: np.ndarray) -> np.ndarray:
    """The longest run of True in mask (the first when tied), as a mask (all False when there is none)."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    out = np.zeros(len(mask), bool)
    if not len(starts):
        return out
    k = int(np.argmax(ends - starts))
    out[starts[k]:ends[k]] = True
    return out


__all__ = ["BarRinging", "CameraHold", "Hold", "HoldConfig", "HoldRecorder", "HoldRefusal", "Refusal", "RingingSource",
           "SettlingSeries", "slowest_bar_period"]
