"""The markers of ~/markers without ROS: bars at rest and bent (exaggerated), frustums at the bent poses, gravity
with its 2-std cone, the state text; and the service hands the state over on estimates and changes only."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_pipeline import make_stream

from nrmpc_ros.core.attitude import tangent_covariance
from nrmpc_ros.core.deformation import deformed_extrinsics
from nrmpc_ros.core.rig import load_rig
from nrmpc_ros.core.so3 import angle_between, normalize
from nrmpc_ros.frontend.markers import (
    CONE_SIGMAS,
    MarkerKind,
    build_markers,
    gravity_cone,
    marker_array_fields,
    rig_size_m,
)
from nrmpc_ros.frontend.node_config import NodeConfig
from nrmpc_ros.frontend.pipeline import FrameSet, PipelineConfig, RigState, RigStatus
from nrmpc_ros.frontend.service import EstimatorService
from nrmpc_ros.frontend.work import Work, WorkKind
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

REPO_RIG = "config/sample_cross4.yaml"


@pytest.fixture(scope="module")
def rig3():
    return make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.3, mass=0.15, bar_length=0.3, focal=235.0,
                            resolution=(320, 240)))


@pytest.fixture(scope="module")
def run(rig3):
    """The stream of test_pipeline through an EstimatorService: (every (status, output) handed over, frame sets)."""
    frames, imu = make_stream(rig3)
    got = []
    s = EstimatorService(rig3, NodeConfig(rig_file="rig.yaml"), PipelineConfig(), ["a", "b", "c"], "imu",
                         lambda out: None, lambda level, line: None,
                         publish_status=lambda st, out: got.append((st, out)))
    def step():  # the intake's work item, then the holds it measured (the node's two workers, in turn)
        s.work_once()
        while s.estimate_once() is not None:
            pass

    k = 0
    for st, _, _, imgs in frames:
        while k < len(imu) and imu[k][0] <= st:
            s.queue.put(Work(WorkKind.IMU, imu[k][0], (imu[k][1], imu[k][2], None)))
            step()
            k += 1
        s.queue.put(Work(WorkKind.FRAMES, st, (FrameSet(st, imgs), 0.0)))
        step()
    s.queue.put(Work(WorkKind.FLUSH))
    step()
    return got, len(frames), s.counts["estimates"]


def test_the_state_is_handed_over_on_estimates_and_changes_not_per_frame(run):
    got, frames, estimates = run
    assert estimates >= 3 and len(got) < frames / 3
    states = [st.state for st, _ in got]
    assert states[0] is RigState.SETTLING and RigState.MOVING in states and RigState.MEASURING in states
    assert RigState.WAITING not in states
    # consecutive hand-overs differ in state or hold, unless an estimate came with the second
    for (a, _), (b, out_b) in zip(got, got[1:]):
        assert (a.state, a.hold) != (b.state, b.hold) or out_b is not None
    # measuring hold N: N counts the holds of the sequence; estimates carry the hold they estimated
    measuring = [st.hold for st, _ in got if st.state is RigState.MEASURING]
    assert measuring == sorted(measuring) and measuring[0] == 0
    outs = [out for _, out in got if out is not None]
    assert outs[-1].estimate.hold_index == estimates - 1  # (the origin, hold 0, is estimated too)


def test_status_lines_name_the_hold():
    assert RigStatus(RigState.MEASURING, 3, 1.0).describe() == "measuring hold 3"
    assert RigStatus(RigState.ESTIMATED, 3, 1.0).describe() == "hold 3 estimated"
    assert RigStatus(RigState.MOVING, None, 1.0).describe() == "moving"


def test_bars_frustums_and_gravity_follow_the_estimate(run, rig3):
    got, _, _ = run
    status, out = next((st, o) for st, o in reversed(got) if o is not None)
    m = build_markers(rig3, out, status, bend_scale=1.0)
    ns = [x.ns for x in m.markers]
    assert ns == ["bars_rest", "bars_bent", "cameras", "gravity", "gravity_cone", "state"]
    w, W = deformed_extrinsics(rig3, out.gravity)
    rest = m.by_ns("bars_rest")[0].points.reshape(-1, 2, 3)
    bent = m.by_ns("bars_bent")[0].points.reshape(-1, 2, 3)
    assert np.allclose(rest[:, 0], 0) and np.allclose(rest[:, 1], rig3.positions)
    assert np.allclose(bent[:, 0], 0) and np.allclose(bent[:, 1], w) and np.allclose(w, out.camera_positions)
    # frustums: 4 edges from the bent camera centre, along its optical axis in the middle
    fr = m.by_ns("cameras")[0].points.reshape(rig3.num_cameras, 8, 2, 3)
    for i in range(rig3.num_cameras):
        assert np.allclose(fr[i, :4, 0], w[i])
        axis = normalize(fr[i, :4, 1].mean(axis=0) - w[i])
        cam = rig3.cameras[i]
        fx, fy, cx, cy = cam.intrinsics
        centre = W[i] @ normalize(np.array([(0.5 * cam.resolution[0] - cx) / fx, (0.5 * cam.resolution[1] - cy) / fy,
                                            1.0]))
        assert float(angle_between(axis, centre)) < 1e-9
    arrow = m.by_ns("gravity")[0]
    assert arrow.kind is MarkerKind.ARROW and float(angle_between(arrow.points[1], out.gravity)) < 1e-12
    assert "hold" in m.by_ns("state")[0].text and "gravity +-" in m.by_ns("state")[0].text


def test_the_bend_scale_exaggerates_positions_and_rotations_linearly(run, rig3):
    got, _, _ = run
    out = next(o for _, o in reversed(got) if o is not None)
    one = build_markers(rig3, out, None, 1.0).by_ns("bars_bent")[0].points[1::2]
    ten = build_markers(rig3, out, None, 10.0).by_ns("bars_bent")[0].points[1::2]
    assert np.allclose(ten - rig3.positions, 10 * (one - rig3.positions))
    assert np.linalg.norm(ten - rig3.positions) > 1e-3


def test_the_cone_rim_lies_at_two_standard_deviations(rng):
    g = np.array([0.3, -0.2, -9.7])
    A = rng.normal(size=(3, 3))
    cov = 1e-3 * A @ A.T
    ct = tangent_covariance(g, cov)
    tri = gravity_cone(normalize(g), ct, 2.0).reshape(-1, 3, 3)
    assert np.allclose(tri[:, 0], 0) and np.allclose(np.linalg.norm(tri[:, 1], axis=1), 2.0)
    # each rim direction: its angular offset has Mahalanobis distance CONE_SIGMAS in the tangent covariance
    from nrmpc_ros.core.so3 import tangent_basis

    B = tangent_basis(normalize(g))
    d = normalize(tri[:, 1])
    theta = np.arccos(np.clip(d @ normalize(g), -1, 1))
    off = (d @ B) / np.linalg.norm(d @ B, axis=1, keepdims=True) * theta[:, None]
    maha = np.sqrt(np.einsum("ni,ij,nj->n", off, np.linalg.inv(ct), off))
    assert np.allclose(maha, CONE_SIGMAS, rtol=1e-6)


def test_without_gravity_no_arrow_and_the_array_replaces_what_was_shown(rig3):
    m = build_markers(rig3, None, RigStatus(RigState.MOVING, None, 5.0))
    assert [x.ns for x in m.markers] == ["bars_rest", "bars_bent", "cameras", "state"]
    assert np.allclose(m.by_ns("bars_bent")[0].points, m.by_ns("bars_rest")[0].points)
    assert m.by_ns("state")[0].text == "moving"
    f = marker_array_fields(m, "base_link", (5, 7))
    assert f["markers"][0]["action"] == 3  # DELETEALL first
    assert all(x["header"]["frame_id"] == "base_link" for x in f["markers"])
    assert {(x["ns"], x["id"]) for x in f["markers"][1:]} == {(x.ns, x.id) for x in m.markers}
    assert len(f["markers"][1]["points"]) == 2 * rig3.num_cameras


def test_sizes_follow_the_rig():
    rig = load_rig(REPO_RIG)
    assert math.isclose(rig_size_m(rig), 0.4)  # the sample's 0.4 m bars
    text = build_markers(rig, None, None).by_ns("state")[0]
    assert text.text == "waiting" and math.isclose(text.scale[2], 0.15 * 0.4)
