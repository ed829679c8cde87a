"""The IMU's axes from the turns between holds (hand-eye rotation by Wahba's problem) and the verdict on the rig
file's: taken only where the turns fix the axes and fit one rotation, the axes stand out of their std and a
calibration's tolerance, and the IMU's gravity so turned agrees with the images' own."""

import math

import numpy as np
import pytest

from nrmpc_ros.core.so3 import exp_so3, log_so3, rotation_angle
from nrmpc_ros.frontend.gyro import GyroRotation
from nrmpc_ros.frontend.imu_mount import (
    AxesVerdict,
    describe_imu_axes,
    imu_axes_from_turns,
    turn_refutes_axes,
    turn_refutes_gyro,
    turns_share_axes,
    wahba,
)

GYRO_SIGMA = math.radians(0.2)
READ_NOISE = math.radians(0.02)


def _random_rotation(rng, deg=None):
    axis = rng.normal(size=3)
    angle = math.radians(deg) if deg is not None else rng.uniform(0.0, math.pi)
    return exp_so3(angle * axis / np.linalg.norm(axis))


def _turns(rng, D, n, axes=None, noise_rad=READ_NOISE):
    """n turns of 5-30 deg between holds: the gyro's in the rig file's axes, the images' D R_g D^T, each read with
    ``noise_rad`` per axis; about random axes, or about ``axes`` (n, 3)."""
    out = []
    for k in range(n):
        axis = rng.normal(size=3) if axes is None else np.asarray(axes[k], float)
        r_g = math.radians(rng.uniform(5.0, 30.0)) * axis / np.linalg.norm(axis)
        r_i = D @ r_g + rng.normal(scale=noise_rad, size=3)
        out.append((exp_so3(r_i), 0.0, GyroRotation(exp_so3(r_g + rng.normal(scale=noise_rad, size=3)), GYRO_SIGMA,
                                                    100)))
    return out


def _gravities(rng, D, n, off_deg=0.25, images_sigma_deg=0.05):
    """n holds' (IMU gravity in the rig file's axes, the images' gravity, its std): the images' the IMU's turned
    by D, then tilted by ``off_deg`` (an accelerometer's bias, or a bar's bend the rig file does not know)."""
    out = []
    for _ in range(n):
        g_body = exp_so3(rng.normal(scale=0.4, size=3)) @ np.array([0.0, 0.0, -9.81])
        g_imu = D.T @ g_body
        across = np.cross(g_body, rng.normal(size=3))
        tilt = exp_so3(math.radians(off_deg) * across / np.linalg.norm(across))
        out.append((g_imu, tilt @ g_body, math.radians(images_sigma_deg)))
    return out


@pytest.mark.parametrize("seed", range(5))
def test_wahba_recovers_a_rotation_from_noiseless_pairs(seed):
    rng = np.random.default_rng(seed)
    D = _random_rotation(rng)
    b = rng.normal(size=(4, 3))
    assert np.allclose(wahba(b @ D.T, b, np.ones(4)), D, atol=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_turned_axes_are_measured_within_their_std_and_taken(seed):
    """Axes turned 30-180 deg (another convention, an IMU mounted sideways): D within 3 of its std, verdict WRONG,
    and the correction makes the rig file's rotation read the samples right (M C = D M)."""
    rng = np.random.default_rng(seed)
    D = _random_rotation(rng, deg=rng.uniform(30.0, 180.0))
    M = _random_rotation(rng)
    axes = imu_axes_from_turns(_turns(rng, D, 5), _gravities(rng, D, 4), math.radians(0.3))
    error = rotation_angle(axes.turn.T @ D)
    assert error <= 3.0 * axes.sigma_rad and axes.sigma_rad < math.radians(1.0)
    assert axes.verdict is AxesVerdict.WRONG
    assert np.allclose(M @ axes.correction(M), axes.turn @ M, atol=1e-12)
    assert "rotation_xyzw would be" in describe_imu_axes(axes, M)


@pytest.mark.parametrize("seed", range(4))
def test_right_axes_and_axes_within_a_calibration_s_tolerance_leave_the_rig_file_alone(seed):
    """The rig file's axes right (D = I), or off by half a degree (within what a calibration leaves, though the
    turns measure it): AGREE."""
    rng = np.random.default_rng(seed)
    right = imu_axes_from_turns(_turns(rng, np.eye(3), 5), _gravities(rng, np.eye(3), 4), math.radians(0.3))
    assert right.verdict is AxesVerdict.AGREE and right.distance_chi2 < 21.1
    D = _random_rotation(rng, deg=0.5)
    assert imu_axes_from_turns(_turns(rng, D, 5), _gravities(rng, D, 4), math.radians(0.3)).verdict is \
        AxesVerdict.AGREE


def test_turns_that_do_not_fix_the_axes_give_no_verdict():
    """Fewer than two turns: none; turns about one axis leave the angle about it open (the holds' gravities close
    it); turns that fit no one rotation (a clock seconds off reads other moves): NOT_MEASURABLE."""
    rng = np.random.default_rng(3)
    D = _random_rotation(rng, deg=90.0)
    assert imu_axes_from_turns(_turns(rng, D, 1)) is None
    one_axis = _turns(rng, D, 5, axes=[(0.0, 0.0, 1.0)] * 5)
    assert imu_axes_from_turns(one_axis).verdict is AxesVerdict.NOT_MEASURABLE
    # the holds' gravities fix what the turns leave open, and a fit they took part in is still tested by them
    fixed = imu_axes_from_turns(one_axis, _gravities(rng, D, 4), math.radians(0.3))
    assert fixed.gravity_fitted and fixed.verdict is AxesVerdict.WRONG
    assert rotation_angle(fixed.turn.T @ D) <= 3.0 * fixed.sigma_rad
    scrambled = [(exp_so3(log_so3(R) + rng.normal(scale=0.2, size=3)), s, g) for R, s, g in _turns(rng, D, 6)]
    assert imu_axes_from_turns(scrambled, _gravities(rng, D, 3)).verdict is AxesVerdict.NOT_MEASURABLE


@pytest.mark.parametrize("off_deg, verdict", [(0.25, AxesVerdict.WRONG), (2.0, AxesVerdict.GRAVITY_DISAGREES)])
def test_axes_whose_gravity_still_disagrees_with_the_images_are_not_taken(off_deg, verdict):
    """An IMU inside a camera on a bar that the rig file puts at the body: the turns measure its mean axes, but
    its gravity is off by the bar's bend at every hold (1-3 deg on a soft bar), more than the accelerometer's
    tilt prior allows: not taken, and said. An accelerometer's bias (a quarter degree) is within it."""
    rng = np.random.default_rng(11)
    D = _random_rotation(rng, deg=100.0)
    axes = imu_axes_from_turns(_turns(rng, D, 5), _gravities(rng, D, 5, off_deg=off_deg), math.radians(0.3))
    assert axes.verdict is verdict
    if verdict is AxesVerdict.GRAVITY_DISAGREES:
        assert "not applied" in describe_imu_axes(axes, np.eye(3))
    none = imu_axes_from_turns(_turns(rng, D, 5), [], math.radians(0.3))
    assert none.verdict is AxesVerdict.WRONG_UNCHECKED and none.applies


def test_turns_that_fit_no_rotation_the_others_fit_are_left_out():
    """Images' turns 2.5 deg off at stds of a tenth (two-hold estimates in another basin): one or two among five
    are left out and said, the axes from the others; three among five (no majority one rotation fits): no
    verdict."""
    rng = np.random.default_rng(5)
    D = _random_rotation(rng, deg=180.0)
    turns = _turns(rng, D, 5)

    def off(k, axis):
        return (exp_so3(log_so3(turns[k][0]) + np.radians(2.5) * np.asarray(axis, float)), 0.0, turns[k][2])

    for n_bad in (1, 2):
        bad = [off(k, np.eye(3)[k]) for k in range(n_bad)] + turns[n_bad:]
        axes = imu_axes_from_turns(bad, _gravities(rng, D, 2), math.radians(0.3))
        assert axes.left_out == n_bad and axes.turns == 5 - n_bad and axes.verdict is AxesVerdict.WRONG
        assert rotation_angle(axes.turn.T @ D) <= 3.0 * axes.sigma_rad
        assert f"{n_bad} more that fit none left out" in describe_imu_axes(axes, np.eye(3))
    worse = [off(k, np.eye(3)[k]) for k in range(3)] + turns[3:]
    assert imu_axes_from_turns(worse, _gravities(rng, D, 2)).verdict is AxesVerdict.NOT_MEASURABLE


def test_turns_that_refute_the_axes_each_its_own_way_do_not_put_them_off():
    """Axes off turn every turn's rotation vector by one rotation and keep its angle. Two images' turns in other
    basins (a snapshot rig of three cameras: 7.7 deg off the gyro's at a std of 1.9, and 15 deg off at 1.4, the
    gyro right to a tenth) each refute the rig file's axes, but no one rotation fits both: the axes stand. A turn
    whose angle differs from the gyro's refutes nothing of them; three turns of axes 40 deg off share them (two
    are not enough: each hold is refused, the axes stand); turns that a rotation fits each barely, but not
    together over the fit's degrees of freedom, do not."""
    rng = np.random.default_rng(11)

    def turn(r_images_deg, r_gyro_deg, images_sigma_deg):
        return (exp_so3(np.radians(r_images_deg)), math.radians(images_sigma_deg),
                GyroRotation(exp_so3(np.radians(r_gyro_deg)), math.radians(0.3), 100))

    turned = turn([22.99, 11.02, -2.28], [22.42, 3.30, -1.53], 1.9)  # 7.7 deg off, the same angle within its std
    longer = turn([-29.75, 2.12, 17.79], [-19.25, 13.0, 15.17], 1.4)  # 6.4 deg longer than the gyro's
    assert turn_refutes_axes(turned) and not turn_refutes_axes(longer)
    assert turn_refutes_gyro(longer)  # its hold's IMU gravity is not used (a gyro in other units turns so too)
    other = turn([-14.0, 18.0, 9.0], [-19.25, 13.0, 15.17], 1.4)  # turned otherwise, the angle the gyro's
    assert turn_refutes_axes(other) and not turns_share_axes([turned, other])
    D = exp_so3(np.radians([0.0, 0.0, 40.0]))  # turns of 25 deg about x and y differ from the gyro's by 17 deg
    off = [(R, math.radians(0.3), g) for R, _, g in _turns(rng, D, 3, axes=[[1.0, 0.0, 0.2], [0.0, 1.0, -0.2],
                                                                             [1.0, 1.0, 0.3]],
                                                             noise_rad=math.radians(0.3))]
    assert all(turn_refutes_axes(t) for t in off) and turns_share_axes(off)
    assert not turns_share_axes(off[:2])  # two turns: each hold refused, the axes not yet put off
    # the same snapshot rig on another pass: two turns 8 and 18 deg off, each a few deg longer than the gyro's.
    # A 31 deg rotation fits each within 12.3 (the single turn's bound is 16.3), but the two together at 24.5
    # over the three degrees of freedom the fit leaves: no one rotation
    first = turn([23.01, 11.62, -2.37], [22.42, 3.30, -1.53], 1.884)
    second = turn([-26.85, -3.16, 16.12], [-19.25, 13.0, 15.17], 1.151)
    third = turn([-22.8, -2.8, 14.34], [-19.25, 13.0, 15.17], 2.44)  # the second's hold on yet another pass
    assert turn_refutes_axes(first) and turn_refutes_axes(second) and turn_refutes_axes(third)
    assert not turns_share_axes([first, second, third])
