import numpy as np
from scipy.spatial.transform import Rotation

from nrmpc_ros.core import so3
from nrmpc_ros.core.so3 import (
    angle_between,
    exp_so3,
    fibonacci_sphere,
    log_so3,
    matrix_to_quat_xyzw,
    quat_xyzw_to_matrix,
    right_jacobian,
    rotation_aligning,
    tangent_basis,
)


def test_exp_matches_scipy_and_log_inverts(rng):
    phi = rng.normal(size=(50, 3))
    phi[:5] *= 1e-9
    R = exp_so3(phi)
    assert np.allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-12)
    wrapped = Rotation.from_rotvec(phi).as_rotvec()
    assert np.allclose(log_so3(R), wrapped, atol=1e-9)


def test_log_near_pi():
    axis = np.array([0.0, 0.6, 0.8])
    R = exp_so3(axis * (np.pi - 1e-6))
    assert np.allclose(exp_so3(log_so3(R)), R, atol=1e-9)


def test_right_jacobian_first_order(rng):
    phi = rng.normal(size=3)
    d = 1e-6 * rng.normal(size=3)
    lhs = exp_so3(phi + d)
    rhs = exp_so3(phi) @ exp_so3(right_jacobian(phi) @ d)
    assert np.abs(lhs - rhs).max() < 1e-11


def test_quaternion_round_trip_and_spec_example():
    V = quat_xyzw_to_matrix([0.5, -0.5, 0.5, -0.5])
    # docs/CONVENTIONS.md (Frames) example: camera looks along body +x, image down = body -z
    assert np.allclose(V[:, 2], [1, 0, 0]) and np.allclose(V[:, 1], [0, 0, -1])
    q = matrix_to_quat_xyzw(V)
    assert np.allclose(quat_xyzw_to_matrix(q), V)


def test_angles_bases_and_sphere(rng):
    a = rng.normal(size=(20, 3))
    assert np.allclose(angle_between(a, a), 0.0, atol=1e-12)
    assert np.allclose(angle_between(a, -a), np.pi)
    n = fibonacci_sphere(100)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    B = tangent_basis(n)
    assert np.allclose(np.einsum("nij,ni->nj", B, n), 0.0, atol=1e-12)
    for v in (np.array([0.0, 0.0, -1.0]), np.array([1.0, 2.0, 3.0])):
        A = rotation_aligning(v, np.array([0.0, 1.0, 0.0]))
        assert np.allclose(A @ (v / np.linalg.norm(v)), [0, 1, 0])


def test_single_vector_fast_paths_match_batches(rng):
    v = np.concatenate([rng.normal(size=(20, 3)), [[0, 0, 1.0], [0.1, 0, -1.0], [1e-6, 0, 0], [0, 0, 0]]])
    for f in (so3.exp_so3, so3.tangent_basis, so3.normalize):
        batch = f(v[:-1] if f is so3.tangent_basis else v)
        for i, x in enumerate(v[:-1] if f is so3.tangent_basis else v):
            assert np.allclose(f(x), batch[i], atol=1e-12)
