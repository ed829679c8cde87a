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
exact. Times are integer nanoseconds on one camera frame grid of period
1 / rate: holds and moves last whole frame periods.

Capture modes (which instants the cameras are triggered at):

- ``holds``: at the frame rate, only while the body is still;
- ``snapshot``: one trigger per hold, on its last frame-grid instant (the
  bars have had the whole hold to settle);
- ``stream``: at the frame rate throughout, holds and moves.
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

    def validate(self) -> None:
        """One OptionError naming the field of the first bad option."""
        def positive(x):
            return isinstance(x, numbers.Real) and not isinstance(x, bool) and 0 < x < math.inf

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
        ]
        for name, ok, msg in checks:
            if not ok:
                raise OptionError(_OWNER, name, f"{msg}, got {getattr(self, name, None)!r}")


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
    hold_start: np.ndarray  # (V,) first instant of each hold (the body is still from here to hold_end)
    hold_frames: int  # frame periods per hold
    move_ns: np.ndarray  # (V-1,) duration of each move
    phi: np.ndarray  # (V-1, 3) body-frame rotation vector of each move
    dp: np.ndarray  # (V-1, 3) world translation of each move
    gravity_magnitude: float = 9.81
    profile: str = "cosine"
    accel_fraction: float = 0.25

    @property
    def hold_end(self) -> np.ndarray:
        """(V,) end of each hold (the next move starts here), ns."""
        return self.hold_start + self.hold_frames * self.period_ns

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
        j = np.arange(self.hold_frames, dtype=np.int64)
        t = (self.hold_start[:, None] + j[None, :] * self.period_ns).reshape(-1)
        return t, np.repeat(np.arange(len(self.R)), self.hold_frames)

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
        if moving.any():
            R[moving] = self.R[km] @ exp_so3(s[:, None] * self.phi[km])
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
    n_hold = max(1, int(round(opts.hold_seconds * opts.rate)))
    phi = np.array([log_so3(R[k].T @ R[k + 1]) for k in range(V - 1)]).reshape(-1, 3)
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
        start[k] = start[k - 1] + n_hold * period + move_ns[k - 1]
    return Trajectory(R=R, p=p, period_ns=period, hold_start=start, hold_frames=n_hold, move_ns=move_ns,
                      phi=phi, dp=dp, gravity_magnitude=float(gravity_magnitude), profile=opts.move_profile,
                      accel_fraction=float(opts.accel_fraction))
