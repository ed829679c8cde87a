"""Scores against ground truth: the still holds of the ground truth, which holds got an estimate, which did not."""

import numpy as np

from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.frontend.estimates_csv import EstimateRow
from nrmpc_ros.frontend.evaluation import evaluate, static_holds
from nrmpc_ros.frontend.reference import Reference


def _reference():
    """Ground truth at 10 Hz: still at pose A (0.0-0.3 s), two moving samples, still at pose B (0.6-0.9 s),
    one more moving sample at the end."""
    angles = [0, 0, 0, 0, 0.1, 0.2, 0.3, 0.3, 0.3, 0.3, 0.5]
    R = np.array([exp_so3(np.array([0.0, 0.0, a])) for a in angles])
    return Reference(pose_t=0.1 * np.arange(len(angles)), pose_R=R, pose_p=np.zeros((len(angles), 3)))


def test_static_holds_are_the_runs_of_identical_poses():
    holds = static_holds(_reference())
    assert np.allclose(holds, [(0.0, 0.3), (0.6, 0.9)])  # single moving samples are no holds
    assert static_holds(Reference()) == []


def test_two_cameras_a_few_ms_apart_in_a_slow_move_are_no_hold():
    """Ground truth at a 10 Hz and a 30 Hz camera's triggers (2.7 ms apart in phase): in a slow move (the end of
    a move is one) two instants 2.7 ms apart differ by less than 0.01 deg while the rig turns at up to 3.7 deg/s.
    Only the holds count."""
    t = np.unique(np.round(np.r_[np.arange(0.0, 3.0, 0.1), np.arange(0.0027, 3.0, 1 / 30)], 6))
    s = np.clip((t - 1.0) / 1.0, 0.0, 1.0)  # a slow turn: 2 deg in 1 s (minimum jerk) from 1.0 s
    angle = np.radians(2.0) * (10 * s**3 - 15 * s**4 + 6 * s**5)
    R = np.array([exp_so3(np.array([0.0, 0.0, a])) for a in angle])
    holds = static_holds(Reference(pose_t=t, pose_R=R, pose_p=np.zeros((len(t), 3))))
    assert len(holds) == 2 and holds[0][0] == 0.0 and holds[1][1] == t[-1]
    assert holds[0][1] < 1.1 and holds[1][0] > 1.9


def test_evaluate_counts_the_holds_with_an_estimate_and_the_estimates_outside():
    ref = _reference()
    R = ref.pose_R[0].T @ ref.pose_R[7]
    rows = [EstimateRow(0.7, 0.1, "6pt-bending", R, np.zeros(3), None, 10, 1.0),
            EstimateRow(0.41, 0.1, "6pt-bending", R, np.zeros(3), None, 10, 1.0)]  # stamped while moving
    ev = evaluate(rows, ref)
    assert (ev.holds, ev.holds_with_estimate, ev.outside_holds) == (2, 1, 1)
    assert ev.errors["rotation_deg"][0] < 1e-9 and ev.errors["rotation_deg"][1] > 1.0
    assert np.isnan(ev.errors["gravity_vs_gt_deg"]).all()  # no gravity estimated, none in the ground truth


def test_ground_truth_repeated_at_one_stamp_is_one_pose():
    """A recording that writes the ground truth at every camera's trigger repeats a moving pose at one stamp:
    that is not a hold."""
    ref = _reference()
    n = len(ref.pose_t)
    twice = np.repeat(np.arange(n), 2)
    ref.pose_t, ref.pose_R, ref.pose_p = ref.pose_t[twice], ref.pose_R[twice], ref.pose_p[twice]
    ref.pose_t[1::2] += 1e-9  # one trigger's stamp as two cameras' rates round it
    assert static_holds(ref) == static_holds(_reference())


def test_estimates_on_another_clock_than_the_ground_truth_are_said_so_not_counted_outside_the_holds():
    """Cameras stamping by a counter from 0 s beside ground truth on the recording's clock: no estimate lies in
    the ground truth's time, which the report says instead of calling every estimate one outside the holds."""
    from nrmpc_ros.frontend.evaluation_report import format_report

    ref = _reference()
    R = ref.pose_R[0].T @ ref.pose_R[7]
    rows = [EstimateRow(1000.7, 1000.1, "6pt-bending", R, np.zeros(3), None, 10, 1.0)]
    ev = evaluate(rows, ref)
    assert ev.truth_apart and ev.truth_span == (0.0, 1.0)
    assert "on another clock" in format_report(ev) and "holds in the ground truth" not in format_report(ev)
    near = evaluate([EstimateRow(0.7, 0.1, "6pt-bending", R, np.zeros(3), None, 10, 1.0)], ref)
    assert not near.truth_apart and "holds in the ground truth: 2" in format_report(near)
