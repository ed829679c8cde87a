"""Camera and IMU messages -> the ordered work of one pipeline; the input policy shared by the node and the replay.

``nrmpc replay`` feeds a bag's messages here in bag order, the node feeds
what its subscriptions receive; both run the work that comes out through
:class:`~nrmpc_ros.frontend.runner.PipelineRunner`, so the node's estimates
are the replay's whenever the same messages arrive. Per message:

1. decode and check (images: decodable, the rig file's size; IMU samples:
   finite, non-zero acceleration, stamps not older than the newest) -- a bad
   message is dropped and counted; IMU samples read in one batch with one
   stamp are kept, spread over the interval since the stamp before them
   (docs/INPUTS.md, "Topics of a bag");
2. the stamp policy of :class:`~nrmpc_ros.frontend.stamps.StampGuard`
   (stamps in the future dropped; a confirmed jump back in time ends the
   sequence: the open hold is estimated, then the pipeline starts afresh);
3. frames are grouped into frame sets by
   :class:`~nrmpc_ros.frontend.sync.StampSynchronizer` (its drops are counted
   with their topic);
4. frame sets and IMU samples leave merged by stamp: a frame set stamped t
   leaves after every IMU sample stamped before t + ``imu_lead_s`` and before
   the others (a sample at the frame's own stamp may be the first of a move),
   so the stillness test around t sees the same samples whatever order the
   topics arrived in. A set waits for an IMU sample at or after
   t + ``imu_lead_s``; it leaves without one when frames ``imu_wait_s`` newer
   arrived and no IMU sample arrived meanwhile (the IMU stopped), or frames
   ``imu_max_lag_s`` newer arrived (the IMU lags too far), at once when there
   is no IMU, and at :meth:`Feeder.end`. An IMU sample stamped s waits until
   no frame set older than s - ``imu_lead_s`` can come any more: every live
   camera has sent a frame that new, and the frame grouping holds none older.
   A camera is live while its stamps are within ``imu_wait_s`` of the IMU's,
   or it sent a frame while the IMU advanced by less than that, up to
   ``imu_max_lag_s`` behind; a camera that has sent nothing yet is live up to
   ``imu_max_lag_s`` behind (drivers start after the IMU's, and cameras
   deliver their frames later than an IMU does). An input that delivers in
   bursts (a driver or link that buffers) is given the silence it has shown:
   the IMU waits for a camera, and a frame set for the IMU, up to
   ``BURST_MARGIN`` times the largest advance of the other input's stamps
   between two of its deliveries in the last ``2 imu_max_lag_s`` of them
   (:class:`~nrmpc_ros.frontend.delivery.DeliveryGaps`), when that is longer than ``imu_wait_s``, still up
   to ``imu_max_lag_s``. A camera seen for less than ``imu_max_lag_s`` is
   waited for that long (its first silence may be its first burst): holding
   IMU samples back delays no frame set, since a set leaves with the samples
   before it; frame sets are not held back so for a young IMU. Whether an
   input stopped
   is judged by what arrived, not by stamps alone: a busy process takes its
   subscriptions' queues in turns, one message of each at a time, so a 200 Hz IMU's
   samples arrive seconds of stamps behind 10 Hz frames although nothing
   stopped.

Work items go to ``sink`` as :class:`~nrmpc_ros.frontend.work.Work` (kind
IMU, FRAMES, FLUSH, RESTART, RESET of :class:`~nrmpc_ros.frontend.work.WorkKind`).
Every drop goes to the :class:`~nrmpc_ros.frontend.droplog.DropLog`.
"""

from __future__ import annotations

import math
import time
from collections import Counter, OrderedDict, deque
from dataclasses import dataclass, replace

import numpy as np

from ..config import check, option
from ..core.rig import Rig
from ..core.so3 import matrix_to_quat_xyzw, quat_xyzw_to_matrix
from ..errors import InputError
from .clock_domain import FROZEN_SPAN_S, ClockDomains, ClockRebase, FrozenStamps
from .delivery import BURST_MARGIN, DeliveryGaps
from .droplog import DropLog
from .drops import Drop
from .images import decode_image, resize_to, ros_seconds, scale_to, stamp_seconds
from .imu_block import ImuBlock
from .pipeline import FrameSet
from .stamps import JumpPolicy, StampGuard
from .sync import StampSynchronizer, SyncConfig
from .work import Work, WorkKind

IMU = "imu"  # stream id of the IMU in the stamp guard (cameras are 0..M-1)
HELD_QUEUES = 4  # a candidate jump back holds up to this many frame queues of messages: every camera's and the
# IMU's messages of the new time wait there until a second input (or jump_confirm of one) confirms it
MAX_CLOCK_OFFSET_S = 2.0**32  # s: the span of a ROS stamp's seconds (a device counter, GPS time, any epoch)
EARLY_FRAMES_HELD = 8  # frames per camera held at most at the start, while a camera's arrival lags are apart
# from the others' and its clock is not known yet
STAMPS_KEPT = 4096  # frame stamps remembered as received (sec, nanosec): far more than the sets waiting


@dataclass
class FeederConfig:
    """Stamps, frame grouping and IMU order (README, "The ROS 2 node", Time)."""

    sync_tolerance_s: float = option(0.0, "half-width of the stamp window of one frame set (s); 0: 0.45 of the "
                                     "smallest camera frame period, estimated from the stamps", lo=0.0, hi=10.0)
    queue_size: int = option(10, "frames per camera the synchronizer holds (keep it above 5: a silent camera "
                             "must not make the others overflow)", lo=1, hi=10000)
    max_future_s: float = option(10.0, "a stamp more than this ahead of the clock (the node's clock; the "
                                 "recording time in nrmpc replay) is dropped (s); .inf: no test", lo=0.0,
                                 lo_open=True)
    jump_back_s: float = option(JumpPolicy.jump_back_s, "a stamp this far behind the newest of its input is a "
                                "jump back in time once a second input or jump_confirm of its messages show it "
                                "(s)", lo=0.0, hi=3600.0, lo_open=True)
    jump_confirm: int = option(JumpPolicy.confirm, "messages of one input that confirm a jump of its clock when no "
                               "other input talks (the stamp checks' jumps back and the frame grouping's)", lo=1,
                               hi=1000)
    grouping: SyncConfig = option(SyncConfig(), "the frame grouping by stamp: how its tolerance follows the frame "
                                  "rate, when a partial frame set leaves, when a stamp is a jump")
    imu_lead_s: float = option(0.0, "a frame set goes to the pipeline after the IMU samples stamped before this "
                               "long after its stamp (s); 0: before its stamp, so a frame taken just before the rig "
                               "moves (a snapshot at the end of its hold) is judged by the samples before it",
                               lo=0.0, hi=10.0)
    imu_wait_s: float = option(0.5, "... or, without them, once frames this much newer arrived and no IMU sample "
                               "meanwhile (s): the IMU stopped", lo=0.0, hi=60.0)
    imu_max_lag_s: float = option(5.0, "... or once frames this much newer arrived, IMU samples or not (s): the "
                                  "IMU lags too far behind the cameras to wait for", lo=0.0, hi=600.0)
    imu_clock_offset_s: float = option(0.0, "added to every IMU stamp as it arrives, before anything else reads it: "
                                       "an IMU stamped by another clock than the cameras' (s; nrmpc replay measures "
                                       "it from the rotations between holds, and both from the arrival times where "
                                       "it is more than 10 s); a lag of milliseconds is the pipeline's "
                                       "imu_time_offset_s", lo=-MAX_CLOCK_OFFSET_S, hi=MAX_CLOCK_OFFSET_S)
    imu_gyro_scale: float = option(1.0, "multiplies every IMU sample's angular rate (its covariance by the square) "
                                   "as it arrives: 0.0174533 (pi/180) turns a driver's deg/s into the rad/s of "
                                   "sensor_msgs/Imu (REP 103; nrmpc replay measures it from the moves)",
                                   lo=1e-6, hi=1e6)
    imu_accel_scale: float = option(1.0, "multiplies every IMU sample's specific force (its covariance by the "
                                    "square) as it arrives: 9.80665 turns a driver's g into the m/s^2 of "
                                    "sensor_msgs/Imu (REP 103; nrmpc replay measures it from the still norm)",
                                    lo=1e-6, hi=1e6)
    imu_axes_turn_xyzw: list = option([0.0, 0.0, 0.0, 1.0], "turns every IMU sample's angular rate and specific "
                                      "force (their covariances alike) by this quaternion (x, y, z, w) as it arrives, "
                                      "before the rig file's imu rotation reads them: the IMU's axes where the rig "
                                      "file has them wrong (nrmpc replay --imu-axes-turn; replay and the node measure "
                                      "it from the turns between holds)")
    imu_units_measured: bool = option(True, "the node multiplies the gyro's rates by pi/180 (the specific force by "
                                      "9.80665) from then on where the moves show deg/s (the still norm g), a new "
                                      "sequence starting (as nrmpc replay replays with it); false: it only warns")
    imu_axes_measured: bool = option(True, "the node turns every IMU sample from then on where the turns between "
                                     "holds measure the IMU's axes tens of degrees off the rig file's (and its "
                                     "gravity so turned agrees with the images'), a new sequence starting (as nrmpc "
                                     "replay replays with it); false: it only warns")
    imu_clock_measured: bool = option(True, "the node adds an IMU clock offset the images measure (the moves "
                                      "against the gyro, once the images refute the IMU's gravity) to this one "
                                      "from then on, a new sequence starting (as nrmpc replay replays with it); "
                                      "false: its IMU diagnostics only show it")

    def __post_init__(self):
        check(self, "input config")
        q = self.imu_axes_turn_xyzw
        if not (isinstance(q, (list, tuple)) and len(q) == 4 and
                all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in q)
                and math.hypot(*q) > 0.5):
            raise InputError("input config", f"must be a unit quaternion [x, y, z, w], got {q!r}",
                             "imu_axes_turn_xyzw")
        self.imu_axes_turn_xyzw = [float(x) / math.hypot(*q) for x in q]

    @property
    def imu_axes_turn(self) -> np.ndarray | None:
        """The rotation :attr:`imu_axes_turn_xyzw` turns each IMU sample by (None: none)."""
        q = self.imu_axes_turn_xyzw
        return None if q[:3] == [0.0, 0.0, 0.0] else quat_xyzw_to_matrix(q)

    def turned_by(self, C: np.ndarray) -> FeederConfig:
        """These settings with every IMU sample turned by ``C`` after the turn they already apply (the IMU's axes
        measured, :mod:`.imu_mount`)."""
        before = self.imu_axes_turn
        turned = C if before is None else C @ before
        return replace(self, imu_axes_turn_xyzw=[float(x) for x in matrix_to_quat_xyzw(turned)])

    def imu_reading(self) -> tuple:
        """(A, G): the 3x3 maps from an IMU sample's specific force and rate as the driver gives them to m/s^2
        and rad/s in the axes the rig file's imu rotation reads (scales and axes turn); None each where it
        keeps them as they are."""
        C = self.imu_axes_turn
        m, k = self.imu_accel_scale, self.imu_gyro_scale
        if C is None:
            return (None if m == 1.0 else m * np.eye(3)), (None if k == 1.0 else k * np.eye(3))
        return m * C, k * C

    def jump_policy(self) -> JumpPolicy:
        """When held stamps are a jump of the clock: one policy for the stamp checks and the frame grouping."""
        return JumpPolicy(self.jump_back_s, self.jump_confirm)


class Feeder:
    """See the module docstring. ``topics`` names the cameras' inputs (rig order) in logs and counts,
    ``imu_topic`` the IMU's (None: no IMU). ``log(level, line)`` gets "info" / "warn" lines."""

    def __init__(self, rig: Rig, config: FeederConfig | None, sink, drops: DropLog, topics: list,
                 imu_topic: str | None = None, log=None, clock=time.monotonic):
        self.rig = rig
        self.config = config or FeederConfig()
        self.sink = sink
        self.drops = drops
        self.topics = list(topics)
        self.imu_topic = imu_topic
        self.log = log or (lambda level, line: None)
        self.clock = clock
        self.guard = self._new_guard()
        self.events = Counter()  # "time jumps back", "frame sets", "imu samples", "images"
        self._stamps: OrderedDict = OrderedDict()  # frame stamp (s) -> (sec, nanosec) as received
        self.resized = [0] * rig.num_cameras  # images per camera resized to the rig file's size
        self.rebases: list = []  # ClockRebase: inputs moved onto the others' clock
        self.timeline = -1  # changes of how the cameras' stamps are read (a new epoch, a camera moved onto the
        # others' clock or stamped by its arrival): what was measured of their delays before is of another timeline
        self._camera_offsets = [0.0] * rig.num_cameras  # s added to each camera's stamps (moved off its own clock)
        self._early: list | None = []  # the cameras' first frames, held while a camera's arrival lags are apart
        # from the other inputs' and its clock is not known yet (None from then on)
        self._frozen = FrozenStamps(self.config.jump_confirm)
        self._by_arrival: set = set()  # inputs stamped by their arrival (their own stamps froze)
        self._domains = ClockDomains(list(range(rig.num_cameras)) + ([IMU] if imu_topic is not None else []),
                                     self.config.jump_confirm)
        self._new_epoch()

    def _new_epoch(self) -> None:
        self.timeline += 1
        self.sync = self._new_sync()
        self._frames: deque = deque()  # (FrameSet, arrival) waiting for the IMU
        self._imu: deque = deque()  # (stamp, accel, gyro, covariances or None)
        self._imu_newest = -math.inf
        self._imu_out = 0  # IMU samples handed over in this epoch
        self._domains.reset()
        self._imu_floor, self._imu_batch = -math.inf, 0  # the stamp before the newest; samples stamped newest
        self._cam_newest = [-math.inf] * self.rig.num_cameras  # newest frame accepted per camera
        self._new_delivery_records()

    def _new_delivery_records(self) -> None:
        window = 2 * self.config.imu_max_lag_s  # each camera's deliveries in the IMU's stamps (.last: the IMU's
        # newest when it last sent), the IMU's in the cameras' newest stamps (.last: theirs when its latest came)
        self._cam_gaps = [DeliveryGaps(window) for _ in range(self.rig.num_cameras)]
        self._imu_gaps = DeliveryGaps(window)

    def _new_sync(self) -> StampSynchronizer:
        c = self.config
        return StampSynchronizer(self.rig.num_cameras, c.sync_tolerance_s or None, c.queue_size, config=c.grouping,
                                 jumps=c.jump_policy(), names=[cam.name for cam in self.rig.cameras])

    def burst_frame_sets(self) -> int:
        """The most frame sets one delivery of a camera has brought lately: the largest age of a frame it
        delivered (:class:`~nrmpc_ros.frontend.delivery.DeliveryGaps`, in the IMU's stamps) over the smallest
        frame period; 0 without an IMU, or when no frame came more than ``imu_wait_s`` old (latency, not a
        backlog)."""
        periods = [p for p in self.sync.periods if p > 0]
        if not periods or self._imu_newest == -math.inf:
            return 0
        backlog = max(g.largest_age(self._imu_newest) for g in self._cam_gaps)
        return math.ceil(backlog / min(periods)) if backlog > self.config.imu_wait_s else 0

    def newest_frame(self, index: int) -> float:
        """The newest stamp (s) of a frame of camera ``index`` accepted in this epoch (-inf: none yet)."""
        return self._cam_newest[index]

    # ------------------------------------------------------------------ input
    def image(self, index: int, msg, now: float | None = None) -> None:
        """One sensor_msgs/Image or CompressedImage of camera ``index``; ``now``: the present (s) or None."""
        topic = self.topics[index]
        self.events["images"] += 1
        try:
            img = decode_image(msg, topic)
        except InputError as exc:
            self._drop(topic, Drop.IMAGE_NOT_DECODED, str(exc))
            return
        except Exception as exc:  # a broken message must not stop the input
            self._drop(topic, Drop.IMAGE_NOT_DECODED, f"{topic}: cannot decode the image ({type(exc).__name__}: {exc})")
            return
        cam = self.rig.cameras[index]
        w, h = cam.resolution
        if img.shape != (h, w):
            scale = scale_to(img, (w, h))
            if scale is None:
                self._drop(topic, Drop.WRONG_IMAGE_SIZE, f"{topic}: image is {img.shape[1]}x{img.shape[0]}, the "
                                                         f"rig file {self.rig.source} says {w}x{h} for camera "
                                                         f"{cam.name!r} (another aspect ratio)")
                return
            if not self.resized[index]:
                self.log("warn", f"{topic}: images are {img.shape[1]}x{img.shape[0]}, the rig file "
                                 f"{self.rig.source} says {w}x{h} for camera {cam.name!r}: resized by {scale:.4g} to "
                                 f"its calibration (a binned or resized stream; calibrate at the stream's size for "
                                 f"its full accuracy)")
            self.resized[index] += 1
            img = resize_to(img, (w, h))
        st = msg.header.stamp
        sec, nsec = int(st.sec), int(getattr(st, "nanosec", getattr(st, "nsec", 0)))
        self._read_stamps(index, ros_seconds(sec, nsec), now)
        early = self._early
        if now is not None and early is not None:
            suspect = [i for i in range(self.rig.num_cameras)
                       if self._domains.lag(i) is None and self._domains.apart(i)]
            if suspect and len(early) < EARLY_FRAMES_HELD * self.rig.num_cameras:
                early.append((index, sec, nsec, img, now))  # until the suspect camera's clock is known: its
                return  # frames handed over would be grouped alone and reach the holds with a foreign stamp
            self._early = [] if not suspect and any(self._domains.lag(i) is None
                                                    for i in range(self.rig.num_cameras)) else None
            for held in early:
                self._frame(*held)
        self._frame(index, sec, nsec, img, now)

    def _frame(self, index: int, sec: int, nsec: int, img, now: float | None) -> None:
        stamp = ros_seconds(sec, nsec)
        if index in self._by_arrival and now is not None:
            stamp = now  # stamped when it arrived: its own stamps are frozen
        elif self._camera_offsets[index]:
            stamp += self._camera_offsets[index]  # published with the stamp it was moved to
        else:
            self._stamps[stamp] = (sec, nsec)
            while len(self._stamps) > STAMPS_KEPT:
                self._stamps.popitem(last=False)
        self._checked(index, stamp, img, now)

    def imu_msg(self, msg, now: float | None = None) -> None:
        """One sensor_msgs/Imu."""
        a, w, stamp = msg.linear_acceleration, msg.angular_velocity, stamp_seconds(msg)
        cov = (getattr(msg, "linear_acceleration_covariance", None), getattr(msg, "angular_velocity_covariance", None))
        self.imu(stamp, (a.x, a.y, a.z), (w.x, w.y, w.z), now, covariance=cov)

    def imu(self, stamp: float, accel, gyro, now: float | None = None, covariance=None) -> None:
        """One IMU sample: specific force (m/s^2) and angular rate (rad/s) in the IMU frame, stamp in s; optionally
        the message's (linear_acceleration_covariance, angular_velocity_covariance), which set the stillness
        test's noise (:meth:`~nrmpc_ros.frontend.pipeline.Pipeline.add_imu`)."""
        self.events["imu samples"] += 1
        A, G = self.config.imu_reading()
        if A is not None or G is not None:
            accel, gyro = _mapped(accel, A), _mapped(gyro, G)
            if covariance is not None:
                covariance = tuple(None if c is None else _mapped_cov(np.asarray(c, dtype=float), F)
                                   for c, F in zip(covariance, (A, G)))
        self._sample(float(self._read_stamps(IMU, stamp, now)), accel, gyro, now, covariance)

    def imu_block(self, block: ImuBlock, now: float | None = None) -> None:
        """IMU samples in arrival order (:class:`~nrmpc_ros.frontend.imu_block.ImuBlock`, the node's IMU callback
        hands over the samples waiting): what :meth:`imu` does sample by sample, in one pass over the arrays for
        a block of good samples with increasing stamps that the stamp policy accepts as they are."""
        n = len(block)
        self.events["imu samples"] += n
        if n:  # stamped by arrival: one arrival, spread as samples read at once
            block = replace(block, stamps=self._read_stamps(IMU, block.stamps, now))
        A, G = self.config.imu_reading()
        if A is not None or G is not None:
            block = replace(block, accel=_mapped(block.accel, A), gyro=_mapped(block.gyro, G),
                            accel_cov=_mapped_cov(block.accel_cov, A), gyro_cov=_mapped_cov(block.gyro_cov, G))
        a, w, t = block.accel, block.gyro, block.stamps
        good = bool(n) and bool(np.isfinite(a).all() and np.isfinite(w).all() and a.any(axis=1).all())
        if good and t[0] > self._imu_newest and self.guard.accept_run(IMU, t, now):
            self._imu_floor = float(t[-2]) if n > 1 else self._imu_newest
            self._imu_newest, self._imu_batch = float(t[-1]), 1
            self._imu_gaps.delivered(max(self._cam_newest), float(t[0]))
            covs = zip(block.accel_cov, block.gyro_cov)
            self._imu.extend((s, ai, wi, c) for s, ai, wi, c in zip(t.tolist(), a.tolist(), w.tolist(), covs))
            self._release()
            return
        for i in range(n):
            self._sample(float(t[i]), a[i], w[i], now, (block.accel_cov[i], block.gyro_cov[i]))

    def _sample(self, stamp: float, accel, gyro, now: float | None, covariance) -> None:
        topic = self.imu_topic or IMU
        a = np.asarray(accel, dtype=float).reshape(-1)
        w = np.asarray(gyro, dtype=float).reshape(-1)
        if a.shape != (3,) or w.shape != (3,):
            self._drop(topic, Drop.IMU_WRONG_SHAPE, f"{topic}: IMU sample with {a.size} acceleration and "
                                                    f"{w.size} rate values (3 each expected)")
        elif not (np.all(np.isfinite(a)) and np.all(np.isfinite(w))):
            self._drop(topic, Drop.IMU_NOT_FINITE, f"{topic}: IMU sample at {stamp:.3f} s has NaN or inf "
                                                   f"values (acceleration {a.tolist()}, rate {w.tolist()})")
        elif not np.any(a):
            self._drop(topic, Drop.IMU_ZERO_ACCEL, f"{topic}: IMU sample at {stamp:.3f} s reads "
                                                   "zero acceleration (no accelerometer?)")
        else:
            self._checked(IMU, float(stamp), (a, w, covariance), now)

    def end(self) -> None:
        """The input ended (a bag's end, every camera silent): every frame set left goes out, then a flush."""
        self._emit_sets(self.sync.flush())
        self._release(final=True)
        self.sink(Work(WorkKind.FLUSH))

    def reset(self, why: str) -> None:
        """A new sequence on request: the frame sets before it go out first."""
        self._release(final=True)
        self.sink(Work(WorkKind.RESET, data=why))

    def ros_stamp(self, stamp: float) -> tuple:
        """(sec, nanosec) of a frame stamp as it was received (computed for stamps not seen)."""
        known = self._stamps.get(stamp)  # one lookup: the input thread may trim the table meanwhile
        if known is not None:
            return known
        sec = math.floor(stamp)
        ns = int(round((stamp - sec) * 1e9))
        return (int(sec) + ns // 1_000_000_000, ns % 1_000_000_000)

    # ------------------------------------------------------------------ stamps
    def as_read(self, ref):
        """A bag's :class:`~nrmpc_ros.frontend.reference.Reference` with the IMU's samples as this feeder read them:
        the offsets and unit scales it ended with, stamped by their recording times if its stamps froze."""
        return ref.as_read(self.config, self.stamped_by_arrival(IMU))

    def stamped_by_arrival(self, stream) -> bool:
        """Whether input ``stream``'s messages are stamped by when they arrive (its own stamps froze)."""
        return stream in self._by_arrival

    def camera_clock_offset_s(self, index: int) -> float:
        """Seconds added to camera ``index``'s stamps (0 unless it was found on another clock)."""
        return self._camera_offsets[index]

    def name_of(self, stream) -> str:
        """The topic of input ``stream`` (a camera index or the IMU)."""
        return (self.imu_topic or IMU) if stream == IMU else self.topics[stream]

    def _checked(self, stream, stamp: float, payload, now: float | None) -> None:
        verdict = self.guard.check(stream, stamp, payload, now)
        for reason, message in verdict.drops:
            self._drop(self.name_of(stream), reason, f"{self.name_of(stream)}: {message}")
        if verdict.jump is not None:
            self._jump_back(verdict.jump)
        elif verdict.accept:
            self._accept(stream, stamp, payload, now)

    def _jump_back(self, jump) -> None:
        why = jump.describe(self.name_of(jump.stream))
        self.events["time jumps back"] += 1
        self.log("warn", f"{why}: the frame grouping, the IMU samples and the holds start afresh (a new sequence)")
        self._start_afresh(why)
        for stream, stamp, payload in jump.held:
            self._accept(stream, stamp, payload)

    def reclock_imu(self, offset_s: float, why: str) -> None:
        """Add ``offset_s`` to the IMU's stamps from now on (an IMU clock measured off the cameras'): the frame
        sets and IMU samples taken so far go out first, then the frame grouping, the IMU samples, the stamp
        checks and the holds start afresh with the new stamps (a new sequence), as after a jump of the clock."""
        self.config = replace(self.config, imu_clock_offset_s=self.config.imu_clock_offset_s + offset_s)
        self._start_afresh(why)
        self.guard = self._new_guard()

    def _offset_s(self, stream) -> float:
        """Seconds added to the input's stamps: the IMU's clock offset, or a camera's move off its own clock."""
        return self.config.imu_clock_offset_s if stream == IMU else self._camera_offsets[stream]

    def _read_stamps(self, stream, stamps, now: float | None):
        """The stamps of an input's message (one, or an array that arrived at ``now``) as everything after reads
        them: by arrival where its own froze, else its own plus its clock's offset, after the clock check
        (:mod:`~nrmpc_ros.frontend.clock_domain`), which may move its clock (or another input's) first."""
        if self._by_arrival_now(stream, stamps, now):
            self._clock_seen(stream, now, now)
            return np.full_like(np.asarray(stamps, dtype=float), now)
        if not self._frozen.repeating(stream):  # a repeated stamp tells no clock
            self._clock_seen(stream, np.asarray(stamps, dtype=float) + self._offset_s(stream), now)
        return np.asarray(stamps, dtype=float) + self._offset_s(stream)

    def _by_arrival_now(self, stream, stamps, now: float | None) -> bool:
        """Whether the input's messages are stamped by when they arrive (``now``): its stamps froze
        (:class:`~nrmpc_ros.frontend.clock_domain.FrozenStamps`), found now or before; said once, its clock
        forgotten, the IMU samples of the frozen stamp waiting dropped. Where its stamps advance again (a driver
        that repeated its last stamp through a stall), its own stamps are used again, said too."""
        if now is None:
            return False
        frozen = self._frozen.seen(stream, stamps, now)
        if stream in self._by_arrival:
            if frozen or self._frozen.repeating(stream):
                return True
            self._by_arrival.discard(stream)
            self.timeline += stream != IMU
            self._domains.reset([stream])
            self.log("warn", f"{self.name_of(stream)}: stamps advance again: its own from now on")
            return False
        if not frozen:
            return False
        self._by_arrival.add(stream)
        self.timeline += stream != IMU
        self._domains.reset([stream])
        if stream == IMU:
            frozen = float(np.asarray(stamps, dtype=float).reshape(-1)[-1]) + self.config.imu_clock_offset_s
            kept = deque(x for x in self._imu if x[0] > frozen)  # the samples read at it, spread before it
            for _ in range(len(self._imu) - len(kept)):
                self._drop(self.name_of(IMU), Drop.IMU_FROZEN_STAMP,
                           f"{self.name_of(IMU)}: IMU sample at or before the frozen stamp {frozen:.6f} s")
            self._imu = kept
            self._imu_newest, self._imu_floor = max((x[0] for x in kept), default=-math.inf), -math.inf
        self.log("warn", f"{self.name_of(stream)}: stamps do not advance ({self.config.jump_confirm} messages or more "
                         f"in a row with one stamp, arriving over more than {FROZEN_SPAN_S:g} s: a driver that leaves "
                         f"header.stamp unset?); stamped by when they arrive from now on (the node's clock; the "
                         f"recording time in nrmpc replay), late by their delivery")
        return True

    def _clock_seen(self, stream, stamps, now: float | None) -> set:
        """Hand the arrival lags of ``stamps`` (as read, offsets added) to the clock check
        (:mod:`~nrmpc_ros.frontend.clock_domain`) and move every input it finds on another clock; the inputs
        moved."""
        rebases = self._domains.seen(stream, stamps, now)
        for rebase in rebases:
            if rebase.stream == IMU:
                self._rebase_imu(rebase)
            else:
                self._rebase_camera(rebase)
        return {r.stream for r in rebases}

    def _rebase_camera(self, rebase: ClockRebase) -> None:
        """Move a camera onto the others' clock: its offset grows by the rebase's. Its first frames, held while
        their arrival lags were apart from the others', now go in with it; where frames of the old clock were
        handed over already (the camera spoke first, or its clock changed on the way), what was taken goes out
        and the frame grouping, the IMU samples and the holds start afresh, as after a jump of the clock."""
        self.rebases.append(rebase)
        why = rebase.describe(self.name_of(rebase.stream))
        self.log("warn", why)
        self._camera_offsets[rebase.stream] += rebase.offset_s
        self.timeline += 1
        if self._cam_newest[rebase.stream] > -math.inf:
            self._start_afresh(why)
        self.guard = self._new_guard()

    def _rebase_imu(self, rebase: ClockRebase) -> None:
        """Move the IMU onto the others' clock (:mod:`~nrmpc_ros.frontend.clock_domain`): its offset grows by the
        rebase's, the samples waiting are moved with it, the stamp checks and the inputs' delivery records start
        afresh (they hold the old clock's stamps), and the pipeline too where it was handed samples of the old
        clock; the frame grouping keeps its frames."""
        self.rebases.append(rebase)
        why = rebase.describe(self.name_of(IMU))
        self.log("warn", why)
        d = rebase.offset_s
        self.config = replace(self.config, imu_clock_offset_s=self.config.imu_clock_offset_s + d)
        self._imu = deque((s + d, *data) for s, *data in self._imu)
        self._imu_newest += d
        self._imu_floor += d
        self._new_delivery_records()
        self.guard = self._new_guard()
        if self._imu_out:
            self._imu_out = 0
            self.sink(Work(WorkKind.RESTART, data=why))
        self._release()

    def rescale_imu(self, gyro_factor: float, accel_factor: float, why: str) -> None:
        """Multiply the gyro's rates and the specific force by these factors from now on (units measured): what was
        taken goes out first, then the frame grouping, the IMU samples and the holds start afresh (a new
        sequence)."""
        self.config = replace(self.config, imu_gyro_scale=self.config.imu_gyro_scale * gyro_factor,
                              imu_accel_scale=self.config.imu_accel_scale * accel_factor)
        self._start_afresh(why)

    def turn_imu_axes(self, C: np.ndarray, why: str) -> None:
        """Turn every IMU sample by ``C`` after the turn already applied (the IMU's axes measured, :mod:`.
        imu_mount`) from now on: what was taken goes out first, then the frame grouping, the IMU samples and the
        holds start afresh (a new sequence)."""
        self.config = self.config.turned_by(C)
        self._start_afresh(why)

    def _start_afresh(self, why: str) -> None:
        """What was taken goes out (the frame sets, the IMU samples, a flush), the pipeline restarts (``why``), and
        the frame grouping and the IMU samples start a new epoch."""
        self._emit_sets(self.sync.flush())
        self._release(final=True)
        self.sink(Work(WorkKind.FLUSH))
        self.sink(Work(WorkKind.RESTART, data=why))
        self._new_epoch()

    def _new_guard(self) -> StampGuard:
        c = self.config
        return StampGuard(c.max_future_s, c.jump_policy(), max_held=HELD_QUEUES * c.queue_size)

    def _accept(self, stream, stamp: float, payload, now: float | None = None) -> None:
        if stream == IMU:
            if stamp == self._imu_newest and len(self._imu) >= self._imu_batch:
                self._imu.append((stamp, *payload))
                self._respace_batch()
                self._release()
                return
            if stamp <= self._imu_newest:
                self._drop(self.name_of(IMU), Drop.IMU_OUT_OF_ORDER, f"{self.name_of(IMU)}: IMU sample at "
                           f"{stamp:.6f} s is not newer than the last one ({self._imu_newest:.6f} s)")
                return
            self._imu_floor, self._imu_batch = self._imu_newest, 1
            self._imu_newest = stamp
            self._imu_gaps.delivered(max(self._cam_newest), stamp)
            self._imu.append((stamp, *payload))
        else:
            self._cam_newest[stream] = max(self._cam_newest[stream], stamp)
            self._cam_gaps[stream].delivered(self._imu_newest, stamp)
            self._emit_sets(self.sync.add(stream, stamp, payload, arrival=now))
        self._release()

    def _respace_batch(self) -> None:
        """The samples at the end of the queue that share the newest stamp (a driver that stamps samples when
        the host receives them, several in one read of a serial or USB link) spread evenly over the interval
        since the stamp before them, the last one keeping its stamp: they were taken in that interval, in
        their order. Without a stamp before them (the stream's first), a microsecond apart."""
        self._imu_batch += 1
        self.events["imu samples stamped alike"] += 1
        k, newest = self._imu_batch, self._imu_newest
        floor = self._imu_floor if math.isfinite(self._imu_floor) else newest - k * 1e-6
        for i in range(k):
            _, *data = self._imu[len(self._imu) - k + i]
            self._imu[len(self._imu) - k + i] = (floor + (newest - floor) * (i + 1) / k, *data)

    def _emit_sets(self, sets: list) -> None:
        for stream, stamp, reason in self.sync.take_dropped():
            topic = self.topics[stream]
            self._drop(topic, reason, f"{topic}: frame at {stamp:.6f} s dropped by the frame grouping "
                                      f"({reason.label}; {self.sync.describe()})")
        arrival = self.clock()
        for s in sets:
            self.events["frame sets"] += 1
            self._frames.append((FrameSet(s.stamp, list(s.items), list(s.stamps)), arrival))

    def _frontier(self) -> float:
        """No frame set to come is older than this (s): the sets waiting, the frames grouped, the live cameras'
        newest frames (module docstring, step 4); and IMU samples leave at least imu_wait_s behind the newest."""
        wait, lag, newest = self.config.imu_wait_s, self.config.imu_max_lag_s, self._imu_newest
        live = [t for t, g in zip(self._cam_newest, self._cam_gaps)
                if t >= newest - wait or (t >= newest - lag and newest - g.last <= self._silence(g, newest, True))]
        live += [newest - lag for t in self._cam_newest if t == -math.inf]  # not started yet: the IMU may lead
        waiting = self._frames[0][0].stamp if self._frames else math.inf
        return min(waiting, self.sync.oldest, min(live, default=math.inf), newest - wait)

    def _imu_gone(self, stamp: float) -> bool:
        """Whether a frame set stamped ``stamp`` leaves without its IMU samples (module docstring, step 4): frames
        imu_wait_s newer came, and as much since the IMU's latest sample arrived; or frames imu_max_lag_s newer."""
        newest, wait = max(self._cam_newest), self.config.imu_wait_s
        ahead = newest - stamp
        silence = self._silence(self._imu_gaps, newest)
        return ahead > self.config.imu_max_lag_s or (ahead > wait and newest - self._imu_gaps.last > silence)

    def _silence(self, gaps: DeliveryGaps, other_newest: float, young: bool = False) -> float:
        """How long (in the other input's stamps) an input may stay silent and still be waited for (module
        docstring, step 4): ``imu_wait_s``, or the bursts it has shown; with ``young``, ``imu_max_lag_s``
        while it has been seen for less than that (its first silence may be its first burst)."""
        if young and other_newest - gaps.first < self.config.imu_max_lag_s:
            return self.config.imu_max_lag_s
        return max(self.config.imu_wait_s, BURST_MARGIN * gaps.largest(other_newest))

    def _release(self, final: bool = False) -> None:
        """Frame sets and IMU samples out, merged by stamp (module docstring, step 4)."""
        lead = self.config.imu_lead_s
        frames, imu = self._frames, self._imu
        while frames or imu:
            if frames:
                fs, arrival = frames[0]
                if (final or self.imu_topic is None or self._imu_newest >= fs.stamp + lead
                        or self._imu_gone(fs.stamp)):
                    while imu and imu[0][0] < fs.stamp + lead:
                        self._emit_imu()
                    frames.popleft()
                    self.sink(Work(WorkKind.FRAMES, fs.stamp, (fs, arrival)))
                    continue
            if imu and (final or imu[0][0] < self._frontier() + lead):
                self._emit_imu()
                continue
            break

    def _emit_imu(self) -> None:
        self._imu_out += 1
        s, *data = self._imu.popleft()
        self.sink(Work(WorkKind.IMU, s, tuple(data)))

    def _drop(self, source: str, reason: Drop, message: str) -> None:
        line = self.drops.drop(source, reason, message)
        if line:
            self.log("warn", line)



def _mapped(v, F: np.ndarray | None):
    """Vectors (3,) or (n, 3) through the 3x3 map ``F`` (None: as they are)."""
    return v if F is None else np.asarray(v, dtype=float) @ F.T


def _mapped_cov(c: np.ndarray, F: np.ndarray | None) -> np.ndarray:
    """Row-major 3x3 covariances (9,) or (n, 9) through ``F``: F S F^T (None: as they are; a message's unknown
    covariance, -1 first, and zeros stay as they are)."""
    if F is None:
        return c
    S = c.reshape(-1, 3, 3)
    out = (F @ S @ F.T).reshape(c.shape)
    unknown = S[:, 0, 0] < 0
    if np.any(unknown):
        out.reshape(-1, 9)[unknown] = c.reshape(-1, 9)[unknown]
    return out

__all__ = ["Feeder", "FeederConfig", "IMU", "Work"]
