"""The rig's trajectory in a rendered bag: holds at static attitudes joined by moves.

The body is held still at V attitudes (world z up, tilts of the body z axis
from the vertical in [min_tilt, max_tilt], a rotation of [min_step, max_step]
between successive attitudes, small random translations). Between two holds
it moves along R(s) = R_k Exp(s phi_k), p(s) = p_k + s dp_k, where the path
parameter s(tau), tau = time into the move / move duration, follows one of
the move profiles:

- ``cosine``: s = (1 - cos(pi tau)) / 2 (smooth velocity, acceleration steps
  at the start and the end of the move),
- ``min-jerk``: s = 10 tau^3 - 15 tau^4 + 6 tau^5 (minimum jerk: velocity
  and acceleration continuous, zero at both ends),
- ``trapezoid``: trapezoidal velocity, constant acceleration for a fraction
  ``accel_fraction`` of the move, coasting, then the same deceleration (the
  acceleration steps: an abrupt, hand-held-like move).

The body's angular velocity (body frame) is s' phi_k and the acceleration of
its origin s'' dp_k, both in closed form, so the IMU and the bars' loads are
exact. Times are integer nanoseconds on one frame grid of period 1 / rate:
holds and moves last whole frame periods. Holds last ``hold_seconds``, or a
random length in ``hold_seconds_range`` each. A fraction ``creep_fraction``
of the holds after the first creeps: the body turns slowly at
``creep_deg_per_s`` about a random body axis for the whole hold (it is not
still; the move that follows starts where the creep ended).

Capture modes (which instants the cameras are triggered at; each camera may
have its own rate and phase, ``camera_rates`` and ``camera_phases_ms``, else
all fire together at ``rate``):

- ``holds``: each camera at its rate, only while the body is still;
- ``snapshot``: one trigger per camera and hold, ``snapshot_delay`` seconds
  after the stop (plus the camera's phase), by default on the hold's last
  frame-grid instant (the bars have had the whole hold to settle);
- ``stream``: each camera at its rate throughout, holds and moves.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from ..core.so3 import exp_so3, log_so3, rotation_angle
from ..errors import OptionError

WORLD_GRAVITY = np.array([0.0, 0.0, -1.0])  # direction; scaled by the rig's gravity_magnitude
CAPTURES = ("holds", "snapshot", "stream")
PROFILES = ("cosine", "min-jerk", "trapezoid")
_OWNER = "motion options"  # how OptionError names this module's options


@dataclass
class MotionOptions:
    """How the rig moves and when the cameras fire; angles in degrees, times in seconds, lengths in metres."""

    views: int = 10  # number of holds (static attitudes)
    hold_seconds: float = 2.0
    rate: float = 10.0  # camera frames per second (the frame grid)
    imu_rate: float = 200.0
    min_tilt: float = 10.0
    max_tilt: float = 40.0
    min_step: float = 5.0
    max_step: float = 30.0
    max_translation: float = 0.15  # half-size of the cube positions are drawn from
    speed: float = 30.0  # deg/s of the moves when move_seconds is not given
    min_move_seconds: float = 0.5
    move_seconds: float | None = None  # fixed duration of every move; None: from speed
    move_profile: str = "cosine"
    accel_fraction: float = 0.25  # trapezoid: fraction of the move spent accelerating (and again decelerating)
    capture: str = "holds"
    start_time: float = 1_700_000_000.0  # seconds, stamp of the first frame
    hold_seconds_range: tuple | None = None  # (A, B): each hold lasts U(A, B) s instead of hold_seconds
    snapshot_delay: float | None = None  # snapshot capture: seconds after the stop; None: the hold's last frame
    camera_rates: tuple | None = None  # frames per second of each camera; None: every camera at rate
    camera_phases_ms: tuple | None = None  # each camera's first trigger after the grid's instants, ms; None: 0
    creep_fraction: float = 0.0  # share of the holds after the first that turn slowly (not still)
    creep_deg_per_s: float = 0.5  # rotation rate of a creeping hold

    def hold_range(self) -> tuple:
        """(shortest, longest) hold in seconds."""
        return tuple(self.hold_seconds_range) if self.hold_seconds_range is not None else (self.hold_seconds,) * 2

    def rates(self, num_cameras: int) -> np.ndarray:
        """(M,) frames per second of each camera."""
        return np.full(num_cameras, float(self.rate)) if self.camera_rates is None else np.asarray(
            self.camera_rates, dtype=float)

    def phases_ns(self, num_cameras: int) -> np.ndarray:
        """(M,) each camera's trigger phase, ns."""
        if self.camera_phases_ms is None:
            return np.zeros(num_cameras, dtype=np.int64)
        return np.rint(np.asarray(self.camera_phases_ms, dtype=float) * 1e6).astype(np.int64)

    def validate_cameras(self, num_cameras: int) -> None:
        """The per-camera options fit a rig of ``num_cameras`` cameras (OptionError naming the field)."""
        for name in ("camera_rates", "camera_phases_ms"):
            v = getattr(self, name)
            if v is not None and len(v) != num_cameras:
                raise OptionError(_OWNER, name, f"needs one value per camera ({num_cameras}), got {len(v)}")
        phase_s = float(np.max(self.phases_ns(num_cameras))) * 1e-9
        if self.capture == "snapshot" and self.snapshot_delay is not None:
            if self.snapshot_delay + phase_s >= self.hold_range()[0]:
                raise OptionError(_OWNER, "snapshot_delay", f"{self.snapshot_delay:g} s (plus the largest camera "
                                  f"phase) must be shorter than the shortest hold ({self.hold_range()[0]:g} s)")
        elif self.capture == "snapshot" and phase_s * self.rate >= 1:
            raise OptionError(_OWNER, "camera_phases_ms", f"snapshots on the hold's last frame: each phase must be "
                              f"below the frame period {1e3 / self.rate:g} ms (or give a snapshot delay)")

    def validate(self) -> None:
        """One OptionError naming the field of the first bad option."""
        def finite(x):
            return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)

        def positive(x):
            return finite(x) and x > 0

        checks = [
            ("views", isinstance(self.views, (int, np.integer)) and self.views >= 1, "must be an integer >= 1"),
            ("hold_seconds", positive(self.hold_seconds), "must be a finite number > 0"),
            ("rate", positive(self.rate), "must be a finite number > 0"),
            ("imu_rate", positive(self.imu_rate), "must be a finite number > 0"),
            ("min_tilt", 0 <= self.min_tilt <= self.max_tilt < 90, "need 0 <= min_tilt <= max_tilt < 90 deg"),
            ("min_step", 0 <= self.min_step <= self.max_step <= 120,
             "need 0 <= min_step <= max_step <= 120 deg"),
            ("max_translation", self.max_translation >= 0, "must be >= 0"),
            ("speed", positive(self.speed), "must be a finite number > 0"),
            ("min_move_seconds", positive(self.min_move_seconds), "must be a finite number > 0"),
            ("move_seconds", self.move_seconds is None or positive(self.move_seconds), "must be a finite number > 0"),
            ("move_profile", self.move_profile in PROFILES, f"must be one of {', '.join(PROFILES)}"),
            ("accel_fraction", 0 < self.accel_fraction <= 0.5, "must be in (0, 0.5]"),
            ("capture", self.capture in CAPTURES, f"must be one of {', '.join(CAPTURES)}"),
            ("hold_seconds_range", self.hold_seconds_range is None or (
                len(self.hold_seconds_range) == 2 and all(positive(x) for x in self.hold_seconds_range)
                and self.hold_seconds_range[0] <= self.hold_seconds_range[1]), "must be A,B seconds with 0 < A <= B"),
            ("snapshot_delay", self.snapshot_delay is None or (
                finite(self.snapshot_delay) and self.snapshot_delay >= 0), "must be a finite number >= 0"),
            ("camera_rates", self.camera_rates is None or (
                len(self.camera_rates) >= 1 and all(positive(x) for x in self.camera_rates)),
             "must be one finite rate > 0 per camera"),
            ("camera_phases_ms", self.camera_phases_ms is None or (
                all(finite(x) and x >= 0 for x in self.camera_phases_ms)), "must be finite numbers >= 0"),
            ("creep_fraction", finite(self.creep_fraction) and 0 <= self.creep_fraction <= 1,
             "must be in [0, 1]"),
            ("creep_deg_per_s", positive(self.creep_deg_per_s), "must be a finite number > 0"),
        ]
        for name, ok, msg in checks:
            if not ok:
                raise OptionError(_OWNER, name, f"{msg}, got {getattr(self, name, None)!r}")
        if self.snapshot_delay is not None and self.capture != "snapshot":
            raise OptionError(_OWNER, "snapshot_delay", f"only with capture 'snapshot', not {self.capture!r}")
        rates = self.camera_rates or (self.rate,) * len(self.camera_phases_ms or ())
        if self.camera_phases_ms is not None and len(self.camera_phases_ms) == len(rates):
            for k, (ph, r) in enumerate(zip(self.camera_phases_ms, rates)):
                if ph >= 1e3 / r:
                    raise OptionError(_OWNER, "camera_phases_ms", f"camera {k}: phase {ph:g} ms must be below its "
                                      f"frame period ({1e3 / r:g} ms)")
        if self.capture == "snapshot" and self.snapshot_delay is not None and (
                self.snapshot_delay >= self.hold_range()[0]):
            raise OptionError(_OWNER, "snapshot_delay", f"{self.snapshot_delay:g} s must be shorter than the "
                              f"shortest hold ({self.hold_range()[0]:g} s)")


def move_profile(name: str, tau, accel_fraction: float = 0.25):
    """Path parameter s(tau) of a move and its derivatives ds/dtau, d2s/dtau2, for tau in [0, 1] (see module doc)."""
    tau = np.clip(np.asarray(tau, dtype=float), 0.0, 1.0)
    if name == "cosine":
        return 0.5 * (1.0 - np.cos(np.pi * tau)), 0.5 * np.pi * np.sin(np.pi * tau), 0.5 * np.pi**2 * np.cos(
            np.pi * tau)
    if name == "min-jerk":
        t2 = tau * tau
        return t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2), 30.0 * t2 * (1.0 - tau) ** 2, 60.0 * tau * (
            1.0 - 3.0 * tau + 2.0 * t2)
    if name == "trapezoid":
        a = float(accel_fraction)
        acc = 1.0 / (a * (1.0 - a))  # peak speed 1 / (1 - a) reached after a
        rise, fall = tau < a, tau > 1.0 - a
        r = 1.0 - tau
        s = np.where(rise, 0.5 * acc * tau**2, np.where(fall, 1.0 - 0.5 * acc * r**2, 0.5 * acc * a * a
                                                           + (tau - a) / (1.0 - a)))
        ds = np.where(rise, acc * tau, np.where(fall, acc * r, 1.0 / (1.0 - a)))
        dds = np.where(rise, acc, np.where(fall, -acc, 0.0))
        return s, ds, dds
    raise OptionError(_OWNER, "move_profile", f"unknown profile {name!r} (supported: {', '.join(PROFILES)})")


def _rz(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def sample_attitudes(rng: np.random.Generator, opts: MotionOptions) -> np.ndarray:
    """(V, 3, 3) body -> world rotations with the tilt and step limits of ``opts`` (rejection sampling)."""
    d2r = math.pi / 180.0
    out = []
    yaw = rng.uniform(-math.pi, math.pi)
    for k in range(opts.views):
        for _ in range(10000):
            y = yaw + rng.uniform(-opts.max_step, opts.max_step) * d2r if k else yaw
            az = rng.uniform(0, 2 * math.pi)
            tilt = rng.uniform(opts.min_tilt, opts.max_tilt) * d2r
            R = _rz(y) @ exp_so3(tilt * np.array([math.cos(az), math.sin(az), 0.0]))
            if k == 0:
                break
            step = float(rotation_angle(out[-1].T @ R)) / d2r
            if opts.min_step <= step <= opts.max_step:
                break
        else:
            raise OptionError(_OWNER, "min_step", "cannot find attitudes within the tilt and step limits; widen them")
        yaw = y
        out.append(R)
    return np.array(out)


@dataclass
class Trajectory:
    """Holds at static attitudes, the moves between them and the frame grid (all times in ns)."""

    R: np.ndarray  # (V, 3, 3) body -> world at each hold
    p: np.ndarray  # (V, 3) body origin in the world
    period_ns: int  # camera frame period
    hold_start: np.ndarray  # (V,) first instant of each hold (the body stops here and moves again at hold_end)
    hold_frames: np.ndarray  # (V,) frame periods of each hold
    move_ns: np.ndarray  # (V-1,) duration of each move
    phi: np.ndarray  # (V-1, 3) body-frame rotation vector of each move (from where the hold before it ended)
    dp: np.ndarray  # (V-1, 3) world translation of each move
    gravity_magnitude: float = 9.81
    profile: str = "cosine"
    accel_fraction: float = 0.25
    creep: np.ndarray | None = None  # (V, 3) body-frame rotation rate of each hold, rad/s (zero: still)

    def __post_init__(self):
        self.hold_frames = np.broadcast_to(np.asarray(self.hold_frames, dtype=np.int64), (len(self.R),)).copy()
        if self.creep is None:
            self.creep = np.zeros((len(self.R), 3))

    @property
    def hold_end(self) -> np.ndarray:
        """(V,) end of each hold (the next move starts here), ns."""
        return self.hold_start + self.hold_frames * self.period_ns

    @property
    def hold_seconds(self) -> np.ndarray:
        """(V,) duration of each hold, s."""
        return self.hold_frames * self.period_ns * 1e-9

    @property
    def creeping(self) -> np.ndarray:
        """(V,) True for the holds that turn slowly (not still)."""
        return np.linalg.norm(self.creep, axis=1) > 0

    @property
    def R_end(self) -> np.ndarray:
        """(V, 3, 3) attitude at the end of each hold (R unless the hold creeps)."""
        return self.R @ exp_so3(self.creep * self.hold_seconds[:, None])

    @property
    def start_ns(self) -> int:
        return int(self.hold_start[0])

    @property
    def end_ns(self) -> int:
        return int(self.hold_end[-1])

    def breakpoints(self) -> np.ndarray:
        """Sorted instants (ns) where the body's acceleration may jump: hold starts and ends, and the trapezoid's
        switches between accelerating, coasting and decelerating."""
        b = [self.hold_start, self.hold_end]
        if self.profile == "trapezoid" and len(self.move_ns):
            ramp = np.rint(self.accel_fraction * self.move_ns).astype(np.int64)
            b += [self.hold_end[:-1] + ramp, self.hold_end[:-1] + self.move_ns - ramp]
        return np.unique(np.concatenate(b))

    def frame_times(self, capture: str = "holds"):
        """Trigger times (ns) of the cameras in a capture mode, and the hold index of each (-1 while moving)."""
        if capture == "stream":
            t = np.arange(self.start_ns, self.end_ns, self.period_ns, dtype=np.int64)
            return t, self.view_index(t)
        if capture == "snapshot":
            return self.hold_end - self.period_ns, np.arange(len(self.R))
        if capture != "holds":
            raise OptionError(_OWNER, "capture", f"unknown capture mode {capture!r} (supported: {', '.join(CAPTURES)})")
        t = np.concatenate([a + np.arange(n, dtype=np.int64) * self.period_ns
                            for a, n in zip(self.hold_start, self.hold_frames)])
        return t, np.repeat(np.arange(len(self.R)), self.hold_frames)

    def camera_triggers(self, opts: MotionOptions, num_cameras: int):
        """Trigger instants of every camera with its own rate and phase (see the module docstring).

        Returns t (F,) the sorted distinct trigger times (ns), view (F,) the hold of each (-1 while moving) and
        fires (F, M), which cameras are triggered at each. Without per-camera rates, phases or a snapshot
        delay this is :meth:`frame_times` with every camera firing.
        """
        opts.validate_cameras(num_cameras)
        phases = opts.phases_ns(num_cameras)
        periods = np.rint(1e9 / opts.rates(num_cameras)).astype(np.int64)
        per_camera = []
        for period, phase in zip(periods, phases):
            if opts.capture == "snapshot":
                if opts.snapshot_delay is None:
                    t = self.hold_end - self.period_ns + phase
                else:
                    t = self.hold_start + int(round(opts.snapshot_delay * 1e9)) + phase
            elif opts.capture == "stream":
                t = np.arange(self.start_ns + phase, self.end_ns, period, dtype=np.int64)
            else:
                t = np.concatenate([np.arange(a + phase, b, period, dtype=np.int64)
                                    for a, b in zip(self.hold_start, self.hold_end)])
            per_camera.append(np.asarray(t, dtype=np.int64))
        t = np.unique(np.concatenate(per_camera))
        fires = np.zeros((len(t), num_cameras), dtype=bool)
        for i, ti in enumerate(per_camera):
            fires[np.searchsorted(t, ti), i] = True
        return t, self.view_index(t), fires

    def view_index(self, t_ns) -> np.ndarray:
        """Index of the hold containing each time, -1 while moving."""
        t = np.asarray(t_ns, dtype=np.int64)
        k = np.searchsorted(self.hold_start, t, side="right") - 1
        kc = np.clip(k, 0, len(self.R) - 1)
        inside = (k >= 0) & (t < self.hold_end[kc])
        return np.where(inside, kc, -1)

    def _moves(self, t_ns):
        """Times (N,) int64, the hold each follows (N,), which are moving, and for those: move index, duration
        T (s) and the profile s, ds/dtau, d2s/dtau2."""
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        k = np.clip(np.searchsorted(self.hold_start, t, side="right") - 1, 0, len(self.R) - 1)
        moving = (t >= self.hold_end[k]) & (k < len(self.R) - 1)
        km = k[moving]
        T = self.move_ns[km] * 1e-9
        return t, k, moving, km, T, move_profile(self.profile, (t[moving] - self.hold_end[km]) * 1e-9 / T,
                                                 self.accel_fraction)

    def state(self, t_ns):
        """Pose and motion at times t_ns (N,): R (N,3,3) body->world, p (N,3), omega (N,3) body frame rad/s,
        acceleration (N,3) of the body origin in the world, m/s^2."""
        t, k, moving, km, T, (s, ds, dds) = self._moves(t_ns)
        R = self.R[k].copy()
        p = self.p[k].copy()
        omega = np.zeros((len(t), 3))
        acc = np.zeros((len(t), 3))
        creeps = ~moving & self.creeping[k]
        if creeps.any():  # a creeping hold turns at a constant body rate from its start
            kc = k[creeps]
            dt = np.clip((t[creeps] - self.hold_start[kc]) * 1e-9, 0.0, self.hold_seconds[kc])
            R[creeps] = self.R[kc] @ exp_so3(dt[:, None] * self.creep[kc])
            omega[creeps] = self.creep[kc]
        if moving.any():
            R[moving] = self.R_end[km] @ exp_so3(s[:, None] * self.phi[km])
            p[moving] = self.p[km] + s[:, None] * self.dp[km]
            omega[moving] = (ds / T)[:, None] * self.phi[km]
            acc[moving] = (dds / T**2)[:, None] * self.dp[km]
        return R, p, omega, acc

    def angular_acceleration(self, t_ns) -> np.ndarray:
        """(N, 3) body-frame angular acceleration, rad/s^2 (the rotation axis of a move is fixed: s'' phi / T^2)."""
        t, _, moving, km, T, (_, _, dds) = self._moves(t_ns)
        out = np.zeros((len(t), 3))
        out[moving] = (dds / T**2)[:, None] * self.phi[km]
        return out

    def gravity_body(self, R) -> np.ndarray:
        """Gravity in the body frame, g_B = R^T (0, 0, -|g|), for R (N, 3, 3)."""
        return np.einsum("nji,j->ni", R, self.gravity_magnitude * WORLD_GRAVITY)

    def load_body(self, R, acc) -> np.ndarray:
        """Quasi-static bending load g - a in the body frame (equals gravity when still), m/s^2."""
        return np.einsum("nji,nj->ni", R, self.gravity_magnitude * WORLD_GRAVITY - acc)


def make_trajectory(rng: np.random.Generator, opts: MotionOptions, gravity_magnitude: float = 9.81) -> Trajectory:
    """Random static attitudes and the moves joining them (see the module docstring)."""
    opts.validate()
    R = sample_attitudes(rng, opts)
    V = len(R)
    p = rng.uniform(-opts.max_translation, opts.max_translation, size=(V, 3)) * np.array([1.0, 1.0, 0.5])
    period = int(round(1e9 / opts.rate))
    if opts.hold_seconds_range is None:
        n_hold = np.full(V, max(1, int(round(opts.hold_seconds * opts.rate))), dtype=np.int64)
    else:
        n_hold = np.maximum(1, np.rint(rng.uniform(*opts.hold_seconds_range, size=V) * opts.rate)).astype(np.int64)
    creep = np.zeros((V, 3))
    n_creep = int(round(opts.creep_fraction * (V - 1)))
    if n_creep:  # drawn last: the attitudes and positions stay those of the same seed without creep
        which = 1 + rng.choice(V - 1, size=n_creep, replace=False)
        axes = rng.normal(size=(n_creep, 3))
        creep[which] = math.radians(opts.creep_deg_per_s) * axes / np.linalg.norm(axes, axis=1, keepdims=True)
    R_end = R @ exp_so3(creep * (n_hold * period * 1e-9)[:, None])
    phi = np.array([log_so3(R_end[k].T @ R[k + 1]) for k in range(V - 1)]).reshape(-1, 3)
    dp = np.diff(p, axis=0).reshape(-1, 3)
    if opts.move_seconds is not None:
        move_periods = np.full(V - 1, max(1, int(round(opts.move_seconds * opts.rate))), dtype=np.int64)
    else:
        angle = np.degrees(np.linalg.norm(phi, axis=1)) if V > 1 else np.zeros(0)
        move_periods = np.ceil(np.maximum(opts.min_move_seconds, angle / opts.speed) * opts.rate).astype(np.int64)
    move_ns = move_periods * period
    start = np.empty(V, dtype=np.int64)
    start[0] = int(round(opts.start_time * 1e9))
    for k in range(1, V):
        start[k] = start[k - 1] + n_hold[k - 1] * period + move_ns[k - 1]
    return Trajectory(R=R, p=p, period_ns=period, hold_start=start, hold_frames=n_hold, move_ns=move_ns,
                      phi=phi, dp=dp, gravity_magnitude=float(gravity_magnitude), profile=opts.move_profile,
                      accel_fraction=float(opts.accel_fraction), creep=creep)
