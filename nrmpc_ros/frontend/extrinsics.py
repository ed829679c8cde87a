"""Every camera's extrinsics at every frame set, for the node's TF and ``~/camera_poses`` and ``replay --extrinsics``.

With an IMU the bars' state is propagated from its samples
(:class:`~nrmpc_ros.core.bar_state.BarPropagator`, docs/CONVENTIONS.md "The
rig in motion") and each camera's bent extrinsics are given at its own image
stamp. Without an IMU nothing says how the bars bend between holds: only the
static extrinsics of each measured hold (the static model at the hold's
gravity) are available, and they come with the hold's estimate
(:func:`hold_poses`).
"""

from __future__ import annotations

import csv
import enum
import math
from dataclasses import dataclass

import numpy as np

from ..core.bar_state import BarPropagator
from ..core.deformation import deformed_extrinsics
from ..core.dynamics import bar_natural_frequencies
from ..core.rig import Rig
from ..core.so3 import matrix_to_quat_xyzw
from ..safeio import AtomicFile

SAMPLE_BLOCK = 4096  # IMU samples kept for the smoothed pass are packed into arrays of this many
BIAS_HOLDS = 50  # the accelerometer bias is estimated from this many recent holds (it drifts slowly)
EXTRINSICS_HEADER = ["stamp", "camera", "px", "py", "pz", "qx", "qy", "qz", "qw", "source"]
NO_IMU_NOTE = ("no IMU: only the static extrinsics of holds are available (one row per camera and hold, at the "
               "hold's gravity)")


class ExtrinsicsSource(enum.Enum):
    """Where a camera pose comes from."""

    IMU = "imu"  # the bars' dynamics driven by the IMU, at the image's stamp
    HOLD = "hold"  # the static model at a measured hold's gravity (canonical without gravity)
    SMOOTHED = "smoothed"  # offline: the bars driven by the IMU with the final accelerometer bias from the start


@dataclass(frozen=True)
class CameraPoses:
    """Poses of the cameras in the body frame (camera -> body) at their stamps (s); ``cameras`` rig indices."""

    stamps: np.ndarray  # (K,)
    cameras: np.ndarray  # (K,) int
    positions: np.ndarray  # (K, 3) m
    rotations: np.ndarray  # (K, 3, 3)
    source: ExtrinsicsSource


@dataclass(frozen=True)
class AccelBiasEstimate:
    """The accelerometer's bias (IMU frame, m/s^2) with its covariance ((3, 3), (m/s^2)^2; the prior's in what no
    hold observed, inf there under a flat prior), from ``holds`` still holds of which ``with_gravity`` had a
    gravity from vision."""

    bias_ms2: np.ndarray
    cov_ms2: np.ndarray
    holds: int
    with_gravity: int

    @property
    def std_ms2(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov_ms2))


class AccelBias:
    """The accelerometer's constant bias b from every still hold, recursively (docs/PIPELINE.md, "Extrinsics at
    every frame set").

    At rest an accelerometer reads a_k = -g_k + b + n_k (g_k: hold k's gravity in its frame; n_k the averaged
    noise, variance per axis the samples' over their number plus ``floor_ms2`` squared). Two kinds of
    measurement, each kept under its key and replaced by a later one of the same key:

    - every still hold's mean accelerometer (:meth:`observe_still`, from the first hold on): alone it says
      |a_k - b| = |g|, the rig's gravity magnitude: the component of b along gravity. Holds at other attitudes
      see other components.
    - a gravity from vision for a group of holds (:meth:`observe_group`: the holds of one sequence, each
      hold's gravity the newest view's turned by the sequence's relative rotations, so one error of that
      gravity (covariance across it) is shared by all of them; :meth:`observe_gravity`: one hold): then
      a_k + g_k = b + n_k for every member, all three components, and the shared error is marginalised (the
      members' estimates of b are correlated through it; holds at different attitudes separate b from it).

    The posterior is the Gaussian prior N(0, ``prior_ms2``^2 I) (None: flat) times every kept measurement (the
    last :data:`BIAS_HOLDS` holds); the magnitude equation of holds in no group is relinearised (Gauss-Newton
    from the last estimate; b is three orders below g, so a few steps are exact).
    """

    ITERATIONS = 3

    def __init__(self, gravity_ms2: float, prior_ms2: float | None, floor_ms2: float = 0.0):
        self.gravity_ms2 = float(gravity_ms2)
        self.prior_ms2 = prior_ms2
        self.floor_ms2 = float(floor_ms2)
        self._still: dict = {}  # key -> (mean accelerometer (3,), its variance per axis with the floor)
        self._groups: dict = {}  # group -> (gravity (3,), covariance (3, 3), [(key, turn into the hold's IMU)])
        self.estimate = AccelBiasEstimate(np.zeros(3), self._prior_cov(), 0, 0)

    def _prior_cov(self) -> np.ndarray:
        return np.diag(np.full(3, np.inf if self.prior_ms2 is None else self.prior_ms2 ** 2))

    def observe_still(self, key, accel_mean, accel_var_ms2: float = 0.0) -> None:
        """A still hold's mean accelerometer (IMU frame, m/s^2) and the variance of that mean per axis."""
        a = np.asarray(accel_mean, dtype=float).reshape(3)
        if not np.all(np.isfinite(a)) or not math.isfinite(accel_var_ms2):
            return
        self._still.pop(key, None)
        self._still[key] = (a, float(accel_var_ms2) + self.floor_ms2 ** 2)
        while len(self._still) > BIAS_HOLDS:
            self._still.pop(next(iter(self._still)))
        self.estimate = self._solve()

    def set_prior(self, prior_ms2: float | None) -> None:
        """The prior's std per axis from now on (the next measurement solves with it): what the still holds'
        norms grade (:class:`~nrmpc_ros.frontend.accel_tilt.AccelTiltEvidence`)."""
        self.prior_ms2 = prior_ms2

    def observe_group(self, group, gravity, cov_gravity, members) -> None:
        """Vision's gravity (m/s^2) in one frame with its covariance ((3, 3), across gravity) for the holds
        ``members`` [(key, M (3, 3))], M turning that frame into the hold's IMU frame (a_k = -M g + b); holds
        that :meth:`observe_still` did not give are left out. A covariance that is not finite tells nothing, nor
        does one whose angular std exceeds a radian (vision that has not found gravity's direction yet: the
        linearisation about its estimate means nothing there, and the group's information would be rounding)."""
        g = np.asarray(gravity, dtype=float).reshape(3)
        cov = np.asarray(cov_gravity, dtype=float).reshape(3, 3)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(cov))) or np.linalg.eigvalsh(cov)[-1] > float(g @ g):
            return
        members = [(k, np.asarray(M, dtype=float).reshape(3, 3)) for k, M in members]
        self._groups.pop(group, None)
        self._groups[group] = (g, cov, members)
        while len(self._groups) > BIAS_HOLDS:
            self._groups.pop(next(iter(self._groups)))
        self.estimate = self._solve()

    def observe_gravity(self, key, accel_mean, gravity_imu, cov_gravity_imu, accel_var_ms2: float = 0.0) -> None:
        """One still hold's mean accelerometer and its gravity from vision, both in the IMU frame, with that
        gravity's covariance ((3, 3) (m/s^2)^2): a group of one."""
        a = np.asarray(accel_mean, dtype=float).reshape(3)
        if not np.all(np.isfinite(a)):
            return
        self._still.pop(key, None)
        self._still[key] = (a, float(accel_var_ms2) + self.floor_ms2 ** 2)
        self.observe_group(("hold", key), gravity_imu, cov_gravity_imu, [(key, np.eye(3))])

    def _group_information(self):
        """Per group: (information (3, 3), information @ its estimate of b (3,)) with the shared gravity error
        marginalised, and the keys it covers."""
        out, covered = [], set()
        for g, cov, members in self._groups.values():
            used = [(self._still[k], M) for k, M in members if k in self._still]
            if not used:
                continue
            covered.update(k for k, _ in members if k in self._still)
            y = np.array([a + M @ g for (a, _), M in used])  # (K, 3) each member's estimate of b
            J = np.array([M for _, M in used])  # (K, 3, 3) how the shared gravity error moves them
            var = np.array([v for (_, v), _ in used])
            if np.all(var > 0):  # S = D + J C J^T, D = diag(var): Woodbury, O(K)
                w = 1.0 / var
                AJ = np.einsum("k,kij->ij", w, J)  # A^T D^-1 J
                JJ = np.einsum("k,kji,kjl->il", w, J, J)  # J^T D^-1 J
                Ay, Jy = np.einsum("k,ki->i", w, y), np.einsum("k,kji,kj->i", w, J, y)
                Kc = cov @ np.linalg.inv(np.eye(3) + JJ @ cov)
                out.append((np.sum(w) * np.eye(3) - AJ @ Kc @ AJ.T, Ay - AJ @ Kc @ Jy))
                continue
            Jf = J.reshape(-1, 3)
            S = Jf @ cov @ Jf.T + np.diag(np.repeat(var, 3))
            A = np.tile(np.eye(3), (len(used), 1))
            Si = np.linalg.pinv(S, hermitian=True)
            y = y.reshape(-1)
            out.append((A.T @ Si @ A, A.T @ Si @ y))
        return out, covered

    def _solve(self) -> AccelBiasEstimate:
        prior = np.zeros((3, 3)) if self.prior_ms2 is None else np.eye(3) / self.prior_ms2 ** 2
        groups, covered = self._group_information()
        L = sum((info for info, _ in groups), np.zeros((3, 3)))
        Lm = sum((v for _, v in groups), np.zeros(3))
        lone = [(a, v) for k, (a, v) in self._still.items() if k not in covered]
        A = np.array([a for a, _ in lone]).reshape(-1, 3)
        w = 1.0 / np.maximum(np.array([v for _, v in lone]), 1e-300) if lone else np.zeros(0)
        b = self.estimate.bias_ms2.copy()
        H = prior + L
        for _ in range(self.ITERATIONS if lone else 1):
            d = A - b
            r = np.linalg.norm(d, axis=1)
            n = d / r[:, None]
            H = prior + L + np.einsum("k,ki,kj->ij", w, n, n)
            grad = prior @ b + L @ b - Lm + np.einsum("k,ki->i", w * (self.gravity_ms2 - r), n)
            b = b - np.linalg.lstsq(H, grad, rcond=None)[0]
        lam, V = np.linalg.eigh(H)
        tiny = lam <= 1e-12 * max(float(lam.max()), 1e-300)
        seen = ~tiny
        cov = (V[:, seen] / lam[seen]) @ V[:, seen].T
        if tiny.any():  # a flat prior in a direction no hold observed
            cov = np.where(np.abs(V[:, tiny] @ V[:, tiny].T) > 1e-12, np.inf, cov)
        return AccelBiasEstimate(b, cov, len(self._still), len(covered))


class FrameExtrinsics:
    """The bars' state from the IMU samples; :meth:`at` answers the cameras' extrinsics at a frame set.

    The accelerometer's bias is the floor of the bars' loads (0.05 m/s^2 turns a 3 deg tip rotation by about
    0.015 deg). :class:`AccelBias` estimates it from every still hold: from the first on its mean accelerometer
    against the rig's gravity magnitude (:meth:`observe_still`), and once vision gives the hold's gravity its
    mean accelerometer against that gravity, weighted by its covariance (:meth:`observe_hold`), both with
    ``floor_ms2`` added for the averaged accelerometer, against a zero-mean prior of std ``bias_prior_ms2`` per
    axis (the bias a rig's IMU may have). The estimate is subtracted from the samples; when it changes the bars'
    state is moved as if the new value had been subtracted all along (their loads are linear in the samples),
    so a correction does not make the modelled bars ring. Before the first hold the bias is the prior's mean,
    zero. ``bias_prior_ms2`` 0 declares an unbiased accelerometer (nothing estimated), None a flat prior.

    ``keep_samples`` keeps every sample and every query, for :meth:`smoothed` (offline: a replay).
    """

    def __init__(self, rig: Rig, imu_time_offset_s: float = 0.0, bias_prior_ms2: float | None = None,
                 floor_ms2: float = 0.0, keep_samples: bool = False):
        self.rig = rig
        self.imu_time_offset_s = float(imu_time_offset_s)
        self.bars = BarPropagator(rig, imu_time_offset_s=imu_time_offset_s)
        self.bias = np.zeros(3)  # accelerometer bias subtracted from the samples, IMU frame (m/s^2)
        self.bias_prior_ms2 = bias_prior_ms2
        self.floor_ms2 = float(floor_ms2)
        self.accel_bias = None if bias_prior_ms2 == 0.0 else AccelBias(rig.gravity_magnitude, bias_prior_ms2,
                                                                        floor_ms2)
        self.keep_samples = keep_samples
        # the cameras' rest turns the joint estimate found (M, 3, 3; docs/PIPELINE.md, "The rig file's
        # calibration"): each camera's rotation is its bent rotation times its turn; None: the rig file's as given
        self.rest_turns: np.ndarray | None = None
        self._samples: list = []  # (stamp, ax, ay, az, gx, gy, gz) as received, with keep_samples
        self._sample_blocks: list = []  # the older ones, (SAMPLE_BLOCK, 7) arrays (8 bytes a number)
        self._queries: list = []  # (stamps (K,), cameras (K,)) of every answered frame set, with keep_samples

    def add_imu(self, stamp: float, accel, gyro) -> None:
        (ax, ay, az), b = accel, self.bias
        if self.keep_samples:
            (gx, gy, gz) = gyro
            self._samples.append((float(stamp), float(ax), float(ay), float(az), float(gx), float(gy), float(gz)))
            if len(self._samples) >= SAMPLE_BLOCK:
                self._sample_blocks.append(np.array(self._samples))
                self._samples = []
        self.bars.add_imu(stamp, (float(ax) - b[0], float(ay) - b[1], float(az) - b[2]), gyro)

    def set_bias_prior(self, prior_ms2: float) -> None:
        """The accelerometer bias's prior std per axis (m/s^2) from the next still hold on (none where the rig
        declares the accelerometer unbiased)."""
        if self.accel_bias is not None:
            self.accel_bias.set_prior(prior_ms2)

    @property
    def bias_estimate(self) -> AccelBiasEstimate | None:
        """The accelerometer bias's posterior (None when the rig declares it zero)."""
        return None if self.accel_bias is None else self.accel_bias.estimate

    def observe_still(self, key, accel_mean, accel_std_ms2: float = 0.0, num_samples: int = 1) -> None:
        """A still hold (``key``: e.g. its stamp): its mean accelerometer (IMU frame) over ``num_samples`` samples
        of std ``accel_std_ms2``; its gravity's magnitude tells the bias along gravity."""
        if self.accel_bias is None:
            return
        self.accel_bias.observe_still(key, accel_mean, accel_std_ms2 ** 2 / max(int(num_samples), 1))
        self._apply()

    def _to_imu(self, gravity) -> np.ndarray:
        """The rotation from the body frame into the IMU's at a hold of this gravity (body frame)."""
        imu = self.rig.imu
        if imu is None or imu.mount == "body":
            return imu.rotation.T if imu is not None else np.eye(3)
        j = self.rig.camera_index(imu.mount)
        _, W = deformed_extrinsics(self.rig, gravity)
        return imu.rotation.T @ W[j].T

    @staticmethod
    def _gravity(gravity, cov_gravity):
        g = np.asarray(gravity, dtype=float).reshape(3)
        cov = np.zeros((3, 3)) if cov_gravity is None else np.asarray(cov_gravity, dtype=float).reshape(3, 3)
        return (g, cov) if np.all(np.isfinite(g)) and np.all(np.isfinite(cov)) else (None, None)

    def observe_hold(self, accel_mean, gravity, cov_gravity=None, key=None, accel_std_ms2: float = 0.0,
                     num_samples: int = 1) -> None:
        """One still hold on its own: its mean accelerometer (IMU frame) and its gravity from vision (body frame)
        with that gravity's covariance ((3, 3) m^2/s^4, body frame; None: none of its own, only the averaged
        accelerometer's noise and ``floor_ms2`` weigh the hold); it replaces what :meth:`observe_still` gave
        under the same ``key``. A hold whose covariance is not finite tells nothing."""
        g, cov = self._gravity(gravity, cov_gravity)
        if self.accel_bias is None or g is None:
            return
        to_imu = self._to_imu(g)
        self.accel_bias.observe_gravity(object() if key is None else key, accel_mean, to_imu @ g,
                                        to_imu @ cov @ to_imu.T, accel_std_ms2 ** 2 / max(int(num_samples), 1))
        self._apply()

    def observe_sequence(self, sequence, gravity, cov_gravity, members) -> None:
        """The newest hold of a sequence: its gravity from the joint estimate (body frame) with its covariance,
        and the sequence's holds ``members`` [(key, R)] given by :meth:`observe_still`, R turning the newest
        hold's body frame into that hold's (the joint estimate's relative rotations). Every member's gravity is
        the newest one turned, their errors one: :meth:`AccelBias.observe_group`. It replaces the sequence's
        previous group."""
        g, cov = self._gravity(gravity, cov_gravity)
        if self.accel_bias is None or g is None:
            return
        turns = []
        for key, R in members:
            R = np.asarray(R, dtype=float).reshape(3, 3)
            turns.append((key, self._to_imu(R @ g) @ R))
        self.accel_bias.observe_group(("sequence", sequence), g, cov, turns)
        self._apply()

    def _apply(self) -> None:
        new = self.accel_bias.estimate.bias_ms2
        if np.all(np.isfinite(new)):
            self.bars.shift_specific_force(-(new - self.bias))
            self.bias = new.copy()

    def at(self, stamp: float, stamps=None, present=None) -> CameraPoses | None:
        """Poses of the cameras of one frame set: each at its own stamp (``stamps`` (M,), default the set's),
        only those ``present`` (M,) bool (default all); None before the IMU has given two samples."""
        if not self.bars.ready:
            return None
        M = self.rig.num_cameras
        q = np.array([float(stamp) if stamps is None or stamps[i] is None else float(stamps[i]) for i in range(M)])
        cams = np.arange(M) if present is None else np.flatnonzero(np.asarray(present, dtype=bool))
        w, W = self.bars.extrinsics_at(q[cams], cams)
        if self.keep_samples:
            self._queries.append((q[cams], cams))
        return CameraPoses(q[cams], cams, w, with_rest_turns(W, self.rest_turns, cams), ExtrinsicsSource.IMU)

    def smoothed(self):
        """Every answered frame set again (offline, ``keep_samples``): the bars propagated over all samples with
        the final bias subtracted from the first on; yields :class:`CameraPoses` of source ``SMOOTHED``."""
        bars = BarPropagator(self.rig, imu_time_offset_s=self.imu_time_offset_s)
        b, j = self.bias, 0
        rows = np.concatenate(self._sample_blocks + [np.array(self._samples).reshape(-1, 7)])
        lead = bars.history_s / 2.0  # samples fed ahead of a query: it stays inside the kept history
        for q, cams in self._queries:
            k = int(np.searchsorted(rows[:, 0], float(q.max()) - self.imu_time_offset_s + lead, side="right"))
            for t, ax, ay, az, gx, gy, gz in rows[j:k].tolist():
                bars.add_imu(t, (ax - b[0], ay - b[1], az - b[2]), (gx, gy, gz))
            j = max(j, k)
            if not bars.ready:
                continue
            w, W = bars.extrinsics_at(q, cams)
            yield CameraPoses(q, cams, w, with_rest_turns(W, self.rest_turns, cams), ExtrinsicsSource.SMOOTHED)


def imu_mount_warning(rig: Rig) -> str | None:
    """A warning when the IMU rides on a flexible bar: its readings then carry that bar's own ringing, which the
    propagation removes through that bar's model (docs/CONVENTIONS.md, "The rig in motion"), so the extrinsics
    between holds are as good as the rig file's frequency and damping of that bar; else None."""
    if rig.imu is None or rig.imu.mount == "body":
        return None
    j = rig.camera_index(rig.imu.mount)
    f = bar_natural_frequencies(rig)[j]
    if not np.isfinite(f):
        return None
    damping = rig.cameras[j].damping
    return (f"the IMU rides on camera {rig.imu.mount}'s flexible bar ({f:.1f} Hz, damping "
            + (f"{damping:g}" if damping is not None else "not given: taken as the documented default")
            + "): its readings carry the bar's own ringing, removed through that bar's model, so the cameras' "
            "extrinsics between holds are as good as the rig file's frequency and damping of it (nrmpc "
            "calibrate-bars measures both)")


def hold_poses(rig: Rig, stamp: float, gravity, rest_turns=None) -> CameraPoses:
    """Every camera at a hold: the static model at the hold's gravity (canonical when it has none), each
    rotation times its camera's rest turn (M, 3, 3) where the joint estimate found them."""
    w, W = deformed_extrinsics(rig, np.zeros(3) if gravity is None else np.asarray(gravity, dtype=float))
    M = rig.num_cameras
    return CameraPoses(np.full(M, float(stamp)), np.arange(M), w, with_rest_turns(W, rest_turns, np.arange(M)),
                       ExtrinsicsSource.HOLD)


def with_rest_turns(W: np.ndarray, rest_turns: np.ndarray | None, cams: np.ndarray) -> np.ndarray:
    """The bent rotations W (K, 3, 3) of cameras ``cams`` (K,) times their rest turns (M, 3, 3; docs/PIPELINE.md,
    "The rig file's calibration"), or W as they are where none are known."""
    return W if rest_turns is None else W @ rest_turns[cams]


class ExtrinsicsCsv:
    """``replay --extrinsics``: one row per camera pose, header :data:`EXTRINSICS_HEADER` (docs/CONVENTIONS.md,
    "The rig in motion"); written atomically (the file appears when the run succeeds)."""

    def __init__(self, path, rig: Rig, flag: str | None = "--extrinsics"):
        self.names = [c.name for c in rig.cameras]
        self._out = AtomicFile(path, "w", flag=flag, newline="")
        self._w = csv.writer(self._out.file)
        self._w.writerow(EXTRINSICS_HEADER)
        self.rows = 0

    def write(self, poses: CameraPoses) -> None:
        q = matrix_to_quat_xyzw(poses.rotations).reshape(-1, 4)
        for t, i, p, qi in zip(poses.stamps, poses.cameras, poses.positions, q):
            self._w.writerow([f"{t:.9f}", self.names[int(i)], *(f"{v:.9g}" for v in p), *(f"{v:.9g}" for v in qi),
                              poses.source.value])
            self.rows += 1

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self._out.commit()
        else:
            self._out.discard()
        return False


__all__ = ["EXTRINSICS_HEADER", "NO_IMU_NOTE", "AccelBias", "AccelBiasEstimate", "CameraPoses", "ExtrinsicsCsv",
           "ExtrinsicsSource", "FrameExtrinsics", "hold_poses", "imu_mount_warning"]
