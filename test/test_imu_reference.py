"""The IMU's own gravity at a stamp: only the samples the stillness test passes, the rig's mount, short recordings."""

import dataclasses
import math

import numpy as np
import pytest
from test_zupt import still_trace, trace

from nrmpc_ros.core.rig import ImuMount
from nrmpc_ros.core.so3 import angle_between, exp_so3
from nrmpc_ros.frontend.imu_reference import ImuReference
from nrmpc_ros.frontend.reference import Reference
from nrmpc_ros.sim.synthetic import make_rig

DOWN = np.array([0.0, 0.0, -9.81])  # gravity in the body frame of the first hold (the trace starts level)


def _deg(a, b) -> float:
    return math.degrees(float(angle_between(a, b)))


def test_a_stamp_next_to_a_move_averages_only_the_still_samples(rng):
    t, a, w, _ = trace(rng, 200.0, [("hold", 3.0), ("move", 1.5), ("hold", 3.0)])
    imu = ImuReference(Reference(imu_t=t, imu_a=a, imu_w=w))
    g = imu.gravity_at(2.9)  # the window reaches 0.15 s into the move
    assert g is not None and np.linalg.norm(g) == pytest.approx(9.81, rel=1e-12)
    assert _deg(g, DOWN) < 0.02
    i, j = np.searchsorted(t, [2.65, 3.15])
    assert _deg(-a[i:j].mean(axis=0), DOWN) > 5 * _deg(g, DOWN)  # the moving samples would have pulled it off
    assert imu.gravity_at(3.75) is None  # mid-move: no still sample in the window


def test_a_creep_slower_than_a_fixed_gyro_cut_is_not_still(rng):
    t, a, w = still_trace(rng, seconds=6.0)
    creep = ((t > 4.0) & (t < 5.5))[:, None] * np.array([0.0, 0.0, 0.02])  # rad/s: under a 0.05 rad/s cut-off
    imu = ImuReference(Reference(imu_t=t, imu_a=a, imu_w=w + creep))
    assert imu.noise is not None
    assert imu.gravity_at(1.5) is not None
    assert imu.gravity_at(4.75) is None


def test_the_rig_mount_turns_the_mean_into_body_gravity(rng):
    t, a, w = still_trace(rng, seconds=3.0)
    turn = exp_so3(np.array([0.0, 0.0, math.pi / 2]))  # IMU x along body y
    rig = dataclasses.replace(make_rig(), imu=ImuMount(rotation=turn))
    g = ImuReference(Reference(imu_t=t, imu_a=a, imu_w=w), rig).gravity_at(1.5)
    assert g is not None and np.linalg.norm(g) == np.float64(rig.gravity_magnitude)
    i, j = np.searchsorted(t, [1.25, 1.75])
    assert _deg(g, -(turn @ a[i:j].mean(axis=0))) < 1e-6  # every sample of the window is still
    assert _deg(g, -a[i:j].mean(axis=0)) > 0.5  # the mount was applied


def test_a_recording_too_short_for_the_noise_has_no_imu_gravity(rng):
    t, a, w = still_trace(rng, seconds=0.5)
    imu = ImuReference(Reference(imu_t=t, imu_a=a, imu_w=w))
    assert imu.noise is None and imu.gravity_at(0.25) is None
    assert ImuReference(Reference()).gravity_at(0.0) is None


def test_a_stamp_at_a_runs_end_on_a_ringing_mount_takes_periods_of_its_run(rng):
    """An IMU on a bar ringing at 1.5 Hz, a stamp just after its hold's still run ends: the still samples within
    a period of it span less than a period, over which the fit cannot take the swing out of the mean. The IMU
    alone there is the mean over the run's samples within two periods of the stamp: within 0.05 deg of the
    same hold's mid-hold gravity (over the last period's samples alone it was degrees off)."""
    from test_zupt import ringing_trace

    from nrmpc_ros.frontend.zupt import ZuptConfig

    t, a, w, holds = ringing_trace(rng, 200.0, 1.5)
    imu = ImuReference(Reference(imu_t=t, imu_a=a, imu_w=w), zupt=ZuptConfig(mount_ringing_hz=1.5))
    h0, h1 = holds[1]
    truth = imu.gravity_at(0.5 * (h0 + h1), window_s=0.5 * (h1 - h0) - 0.2)
    near_end = imu.gravity_at(h1 + 0.1)
    assert truth is not None and near_end is not None
    assert _deg(near_end, truth) < 0.05, _deg(near_end, truth)
