"""The IMU's own gravity at any stamp of a recording: the reference an estimate's gravity is scored against.

The accelerometer reads the specific force a = -g only while the rig is still, so the reference at a stamp
is the mean of the still samples within ``window_s`` of it. Which samples are still is decided by the one
stillness test of the front end (:mod:`nrmpc_ros.frontend.zupt`: its noise estimated once from the whole
recording, or from the messages' covariances), the same test that decides when the pipeline measures a hold;
the mean needs as many samples as a hold's (:attr:`ImuConfig.min_samples
<nrmpc_ros.frontend.imu.ImuConfig.min_samples>`) and becomes body-frame gravity through the rig's IMU mount
as :meth:`ImuBuffer.gravity <nrmpc_ros.frontend.imu.ImuBuffer.gravity>` does (docs/CONVENTIONS.md, "Gravity
measurements"). Without a rig (or one without an ``imu`` block) the IMU frame is taken as the body frame.

The samples stay in the reference's arrays rather than in an :class:`~nrmpc_ros.frontend.imu.ImuBuffer`: the
buffer keeps a bounded, time-ordered history for a live stream, while scoring asks about any stamp of a
recording of any length, in any order.
"""

from __future__ import annotations

import numpy as np

from ..core.deformation import gravity_from_accelerometer
from ..core.rig import Rig
from ..errors import InputError
from .imu import ImuConfig
from .mount_ringing import mean_under_ringing
from .reference import Reference
from .zupt import ImuNoise, ZuptConfig, estimate_noise, ringing_damping, still_mask, still_runs
from .zupt import for_rig as zupt_for_rig

WINDOW_S = 0.25  # default half-width (s) of the window around a stamp (several stillness windows)
NOMINAL_GRAVITY = 9.81  # m/s^2, the magnitude given to gravity without a rig


class ImuReference:
    """Body-frame gravity from a recording's still accelerometer samples around any stamp.

    ``noise`` is the noise the stillness test used (None when the recording is too short to estimate it and
    its messages carry no covariances: then no stamp has an IMU gravity).
    """

    def __init__(self, ref: Reference, rig: Rig | None = None, zupt: ZuptConfig | None = None,
                 imu: ImuConfig | None = None):
        self.rig = rig
        self.min_samples = (imu or ImuConfig()).min_samples
        zupt = zupt or ZuptConfig()
        if rig is not None:  # the stillness test as the pipeline runs it (an IMU on a ringing bar)
            zupt = zupt_for_rig(zupt, rig)
        self._ringing_hz, self._damping = float(zupt.mount_ringing_hz or 0.0), ringing_damping(zupt)
        self._t, self._a, self._w = ref.imu_t, ref.imu_a, ref.imu_w
        self.noise: ImuNoise | None = None
        self.still = np.zeros(len(ref.imu_t), bool)
        self._runs = (np.zeros(0, np.int64), np.zeros(0, np.int64))  # (first, last) index of each still run
        if ref.has_imu:
            try:
                self.noise = estimate_noise(ref.imu_t, ref.imu_a, ref.imu_w, zupt, ref.imu_covariance, "the IMU")
            except InputError:
                return
            self.still = still_mask(ref.imu_t, ref.imu_a, ref.imu_w, self.noise, zupt, "the IMU")
            self._runs = still_runs(ref.imu_t, self.still, zupt)

    def gravity_at(self, stamp: float, window_s: float = WINDOW_S) -> np.ndarray | None:
        """Gravity (body frame, m/s^2) from the still samples within +-``window_s`` of ``stamp``, on a ringing
        mount within at least one of its periods either side (what the ringing's fit needs to take it out of
        the mean; the IMU alone at its best); None with fewer than ``min_samples`` of them."""
        if self._ringing_hz:
            window_s = max(window_s, 1.0 / self._ringing_hz)
        i, j = np.searchsorted(self._t, [stamp - window_s, stamp + window_s])
        if self._ringing_hz and np.any(self.still[i:j]):
            i, j = self._run_around(stamp, i, j, 2.0 / self._ringing_hz)
        still = self.still[i:j]
        if np.count_nonzero(still) < self.min_samples:
            return None
        mean = mean_under_ringing(self._t[i:j], self._a[i:j], self._ringing_hz, self._w[i:j], still,
                                  self._damping)[0]  # an IMU
        # on a ringing bar: its still samples turned back by the mount's turn, which the gyro saw throughout
        if self.rig is not None and self.rig.imu is not None:
            try:
                return gravity_from_accelerometer(self.rig, mean)
            except InputError:  # a mean the mount cannot turn into gravity (as ImuBuffer.gravity refuses it)
                return None
        gm = self.rig.gravity_magnitude if self.rig is not None else NOMINAL_GRAVITY
        return -gm * mean / np.linalg.norm(mean)

    def _run_around(self, stamp: float, i: int, j: int, reach_s: float) -> tuple:
        """Sample range [i, j) of the still run nearest ``stamp`` among the still samples of [i, j), within
        +-``reach_s`` of the stamp: one attitude throughout, and on a ringing mount the periods its fit needs (a
        stamp near a run's end saw less than a period of it in +-window, and the mean kept part of the swing)."""
        k = i + int(np.argmin(np.where(self.still[i:j], np.abs(self._t[i:j] - stamp), np.inf)))
        first, last = self._runs
        r = int(np.searchsorted(last, k))  # the run that holds still sample k
        lo, hi = np.searchsorted(self._t, [stamp - reach_s, stamp + reach_s])
        return max(int(first[r]), int(lo)), min(int(last[r]) + 1, int(hi))


__all__ = ["ImuReference", "WINDOW_S"]
