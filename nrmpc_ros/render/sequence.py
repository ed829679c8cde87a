"""The rig's trajectory in a rendered bag: static attitudes joined by smooth moves (issue 4, SPEC sections 2, 4, 11).

The body is held still at V attitudes (world z up, tilts of the body z axis
from the vertical in [min_tilt, max_tilt], a rotation of [min_step, max_step]
between successive attitudes, small random translations). Between two static
windows it moves along R(s) = R_k Exp(s phi_k), p(s) = p_k + s dp_k with the
smooth profile s(tau) = (1 - cos(pi tau)) / 2, so angular velocity and linear
acceleration are known in closed form. Times are integer nanoseconds on one
camera frame grid; static windows and moves last whole frame periods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.so3 import exp_so3, log_so3, rotation_angle

WORLD_GRAVITY = np.array([0.0, 0.0, -1.0])  # direction; scaled by the rig's gravity_magnitude
MOTIONS = ("static", "continuous")


@dataclass
class MotionOptions:
    """How the rig moves; angles in degrees, times in seconds, lengths in metres."""

    views: int = 10
    static_seconds: float = 2.0
    rate: float = 10.0  # camera frames per second
    imu_rate: float = 200.0
    min_tilt: float = 10.0
    max_tilt: float = 40.0
    min_step: float = 5.0
    max_step: float = 30.0
    max_translation: float = 0.15  # half-size of the cube positions are drawn from
    speed: float = 30.0  # deg/s of the moves
    min_move_seconds: float = 0.5
    motion: str = "static"  # static: frames only in static windows; continuous: frames throughout
    start_time: float = 1_700_000_000.0  # seconds, stamp of the first frame

    def validate(self) -> None:
        checks = [
            (self.views >= 1, "--views must be >= 1"),
            (self.static_seconds > 0, "--static-seconds must be > 0"),
            (self.rate > 0 and self.imu_rate > 0, "--rate and --imu-rate must be > 0"),
            (0 <= self.min_tilt <= self.max_tilt < 90, "need 0 <= min tilt <= max tilt < 90 deg"),
            (0 <= self.min_step <= self.max_step <= 120, "need 0 <= min step <= max step <= 120 deg"),
            (self.max_translation >= 0, "--max-translation must be >= 0"),
            (self.speed > 0 and self.min_move_seconds > 0, "move speed and duration must be > 0"),
            (self.motion in MOTIONS, f"--motion must be one of {MOTIONS}"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ValueError(msg)


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
            raise ValueError("cannot find attitudes within the tilt and step limits; widen them")
        yaw = y
        out.append(R)
    return np.array(out)


@dataclass
class Trajectory:
    """Static attitudes, the moves between them and the frame grid (all times in ns)."""

    R: np.ndarray  # (V, 3, 3) body -> world at each static view
    p: np.ndarray  # (V, 3) body origin in the world
    period_ns: int  # camera frame period
    static_start: np.ndarray  # (V,) first frame of each static window
    static_frames: int  # frames per static window
    move_ns: np.ndarray  # (V-1,) duration of each move
    phi: np.ndarray  # (V-1, 3) body-frame rotation vector of each move
    dp: np.ndarray  # (V-1, 3) world translation of each move
    gravity_magnitude: float = 9.81

    @property
    def static_end(self) -> np.ndarray:
        return self.static_start + self.static_frames * self.period_ns

    @property
    def start_ns(self) -> int:
        return int(self.static_start[0])

    @property
    def end_ns(self) -> int:
        return int(self.static_end[-1])

    def frame_times(self, motion: str = "static"):
        """Frame stamps (ns) and their static view index (-1 while moving)."""
        if motion == "continuous":
            t = np.arange(self.start_ns, self.end_ns, self.period_ns, dtype=np.int64)
            return t, self.view_index(t)
        j = np.arange(self.static_frames, dtype=np.int64)
        t = (self.static_start[:, None] + j[None, :] * self.period_ns).reshape(-1)
        return t, np.repeat(np.arange(len(self.R)), self.static_frames)

    def view_index(self, t_ns) -> np.ndarray:
        """Index of the static window holding each time, -1 while moving."""
        t = np.asarray(t_ns, dtype=np.int64)
        k = np.searchsorted(self.static_start, t, side="right") - 1
        kc = np.clip(k, 0, len(self.R) - 1)
        inside = (k >= 0) & (t < self.static_end[kc])
        return np.where(inside, kc, -1)

    def state(self, t_ns):
        """Pose and motion at times t_ns (N,): R (N,3,3) body->world, p (N,3), omega (N,3) body frame rad/s,
        acceleration (N,3) of the body origin in the world, m/s^2."""
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        k = np.clip(np.searchsorted(self.static_start, t, side="right") - 1, 0, len(self.R) - 1)
        R = self.R[k].copy()
        p = self.p[k].copy()
        omega = np.zeros((len(t), 3))
        acc = np.zeros((len(t), 3))
        moving = (t >= self.static_end[k]) & (k < len(self.R) - 1)
        if moving.any():
            km = k[moving]
            T = self.move_ns[km] * 1e-9
            tau = np.clip((t[moving] - self.static_end[km]) * 1e-9 / T, 0.0, 1.0)
            s = 0.5 * (1.0 - np.cos(np.pi * tau))
            ds = 0.5 * np.pi / T * np.sin(np.pi * tau)
            dds = 0.5 * np.pi**2 / T**2 * np.cos(np.pi * tau)
            R[moving] = self.R[km] @ exp_so3(s[:, None] * self.phi[km])
            p[moving] = self.p[km] + s[:, None] * self.dp[km]
            omega[moving] = ds[:, None] * self.phi[km]
            acc[moving] = dds[:, None] * self.dp[km]
        return R, p, omega, acc

    def gravity_body(self, R) -> np.ndarray:
        """Gravity in the body frame, g_B = R^T (0, 0, -|g|) (SPEC section 2), for R (N, 3, 3)."""
        return np.einsum("nji,j->ni", R, self.gravity_magnitude * WORLD_GRAVITY)

    def load_body(self, R, acc) -> np.ndarray:
        """Quasi-static bending load g - a in the body frame (equals gravity when still)."""
        return np.einsum("nji,nj->ni", R, self.gravity_magnitude * WORLD_GRAVITY - acc)


def make_trajectory(rng: np.random.Generator, opts: MotionOptions, gravity_magnitude: float = 9.81) -> Trajectory:
    """Random static attitudes and the moves joining them (see the module docstring)."""
    opts.validate()
    R = sample_attitudes(rng, opts)
    V = len(R)
    p = rng.uniform(-opts.max_translation, opts.max_translation, size=(V, 3)) * np.array([1.0, 1.0, 0.5])
    period = int(round(1e9 / opts.rate))
    n_static = max(1, int(round(opts.static_seconds * opts.rate)))
    phi = np.array([log_so3(R[k].T @ R[k + 1]) for k in range(V - 1)]).reshape(-1, 3)
    dp = np.diff(p, axis=0).reshape(-1, 3)
    angle = np.degrees(np.linalg.norm(phi, axis=1)) if V > 1 else np.zeros(0)
    move_s = np.maximum(opts.min_move_seconds, angle / opts.speed)
    move_ns = (np.ceil(move_s * opts.rate) * period).astype(np.int64)
    start = np.empty(V, dtype=np.int64)
    start[0] = int(round(opts.start_time * 1e9))
    for k in range(1, V):
        start[k] = start[k - 1] + n_static * period + move_ns[k - 1]
    return Trajectory(R=R, p=p, period_ns=period, static_start=start, static_frames=n_static, move_ns=move_ns,
                      phi=phi, dp=dp, gravity_magnitude=float(gravity_magnitude))
