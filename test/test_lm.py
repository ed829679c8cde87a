"""Levenberg-Marquardt (nrmpc_ros/core/lm.py) on small problems whose optimum is known: a dense non-linear one and
a linear one with points eliminated by the Schur complement (compared with a dense least-squares solve)."""

import numpy as np
import pytest

from nrmpc_ros.core.lm import LinearSystem, LMOptions, SchurStructure, Stop, levenberg_marquardt


class Rosenbrock:
    """Residuals (10 (y - x^2), 1 - x): minimum 0 at (1, 1), a curved valley a Gauss-Newton step overshoots."""

    def residuals(self, s):
        x, y = s
        return np.array([10.0 * (y - x * x), 1.0 - x]), np.array([[-20.0 * x, 10.0], [-1.0, 0.0]])

    def linearize(self, s):
        r, J = self.residuals(s)
        return LinearSystem(cost=0.5 * float(r @ r), Hcc=J.T @ J, bc=-J.T @ r)

    def cost(self, s):
        r, _ = self.residuals(s)
        return 0.5 * float(r @ r)

    def step(self, s, dc, dp):
        return s + dc


def test_dense_problem_reaches_its_known_minimum():
    start = np.array([-1.2, 1.0])
    state, system, stats = levenberg_marquardt(Rosenbrock(), start, LMOptions(max_iterations=200,
                                                                                cost_tolerance=1e-20))
    np.testing.assert_allclose(state, [1.0, 1.0], atol=1e-6)
    assert stats.stop == "converged"
    assert stats.initial_cost == pytest.approx(Rosenbrock().cost(start))
    assert stats.cost == pytest.approx(system.cost) and stats.cost < 1e-12
    assert 0 < stats.accepted <= stats.iterations < 200
    np.testing.assert_allclose(start, [-1.2, 1.0])  # the start is not modified


def test_a_problem_that_never_decreases_stops_on_damping_and_keeps_its_state():
    class Uphill(Rosenbrock):
        def cost(self, s):  # the linearisation promises a decrease, every step raises the cost
            return super().cost(start) + (1.0 if np.any(s != start) else 0.0)

    start = np.array([-1.2, 1.0])
    state, _, stats = levenberg_marquardt(Uphill(), start, LMOptions(max_iterations=100))
    assert stats.stop == "damping" and stats.accepted == 0
    np.testing.assert_array_equal(state, start)
    assert stats.cost == stats.initial_cost


def _linear_problem(seed, num_points, per_point, nc, touched):
    """Observation n: e_n = A_n p_point(n) + B_n c[cols_n] - y_n (2 rows), each touching ``touched`` of the nc
    camera columns; with the dense Jacobian of the same problem."""
    rng = np.random.default_rng(seed)
    point = np.repeat(np.arange(num_points), per_point)
    rng.shuffle(point)
    N = len(point)
    cols = np.array([rng.choice(nc, touched, replace=False) for _ in range(N)])
    A = rng.normal(size=(N, 2, 3))
    B = rng.normal(size=(N, 2, touched))
    y = rng.normal(size=(N, 2))
    J = np.zeros((2 * N, nc + 3 * num_points))
    for n in range(N):
        J[2 * n:2 * n + 2, cols[n]] = B[n]
        J[2 * n:2 * n + 2, nc + 3 * point[n]:nc + 3 * point[n] + 3] = A[n]
    return cols, point, A, B, y, J


class LinearWithPoints:
    def __init__(self, cols, point, A, B, y, nc):
        self.cols, self.point, self.A, self.B, self.y = cols, point, A, B, y
        self.structure = SchurStructure(cols, nc, point, int(point.max()) + 1)

    def residuals(self, state):
        c, p = state
        return np.einsum("nij,nj->ni", self.A, p[self.point]) + np.einsum("nij,nj->ni", self.B, c[self.cols]) - self.y

    def linearize(self, state):
        e = self.residuals(state)
        system = self.structure.accumulate(self.B, e, self.A)
        system.cost = 0.5 * float(np.sum(e * e))
        return system

    def cost(self, state):
        e = self.residuals(state)
        return 0.5 * float(np.sum(e * e))

    def step(self, state, dc, dp):
        return state[0] + dc, state[1] + dp


# a small camera block every observation touches (dense J^T J and coupling), and a wide one each observation
# touches two columns of (both scattered per observation and per pair of observations of a point)
@pytest.mark.parametrize("num_points, per_point, nc, touched", [(6, 4, 2, 2), (40, 3, 30, 2)])
def test_schur_elimination_gives_the_dense_least_squares_solution_and_information(num_points, per_point, nc,
                                                                                  touched):
    cols, point, A, B, y, J = _linear_problem(1, num_points, per_point, nc, touched)
    prob = LinearWithPoints(cols, point, A, B, y, nc)
    assert prob.structure.dense == (nc == 2)
    start = (np.zeros(nc), np.zeros((num_points, 3)))
    (c, p), system, stats = levenberg_marquardt(prob, start, LMOptions(cost_tolerance=1e-12,
                                                                        relative_tolerance=1e-14))
    x = np.linalg.lstsq(J, y.reshape(-1), rcond=None)[0]
    np.testing.assert_allclose(c, x[:nc], atol=1e-6)
    np.testing.assert_allclose(p, x[nc:].reshape(-1, 3), atol=1e-6)
    assert stats.cost == pytest.approx(0.5 * float(np.sum((J @ x - y.reshape(-1)) ** 2)), rel=1e-8)
    # information of the camera block with the points eliminated: the inverse of the camera block of (J^T J)^-1
    cov = np.linalg.inv(J.T @ J)[:nc, :nc]
    info = np.linalg.inv(cov)
    np.testing.assert_allclose(system.information(), info, rtol=1e-6, atol=1e-9 * np.abs(info).max())


def test_runs_of_one_accepted_step_resumed_with_their_system_and_damping_take_the_steps_of_one_run():
    prob, start = Rosenbrock(), np.array([-1.2, 1.0])
    opts = LMOptions(max_iterations=200, cost_tolerance=1e-20)
    whole, _, stats = levenberg_marquardt(prob, start, opts)
    state, system, damping, iterations, runs = start, None, None, 0, 0
    while True:
        state, system, st = levenberg_marquardt(prob, state, LMOptions(max_iterations=200 - iterations,
                                                                       cost_tolerance=1e-20, max_accepted=1),
                                                system=system, damping=damping)
        iterations, damping, runs = iterations + st.iterations, st.damping, runs + 1
        assert st.accepted <= 1
        if st.stop != Stop.MAX_ACCEPTED:
            break
    np.testing.assert_array_equal(state, whole)
    assert st.stop == stats.stop and iterations == stats.iterations and runs == stats.accepted


@pytest.mark.parametrize("lam", [0.0, 1e-2, 1.0])
def test_the_predicted_decrease_is_the_linear_model_s_on_a_linear_problem(lam):
    """On a linear problem the model is exact: the decrease solve() predicts for its damped step (the gain
    ratio's denominator) is the cost's actual decrease, whatever the damping."""
    cols, point, A, B, y, _ = _linear_problem(2, 40, 3, 30, 2)
    prob = LinearWithPoints(cols, point, A, B, y, 30)
    start = (np.zeros(30), np.zeros((40, 3)))
    system = prob.linearize(start)
    dc, dp, _, predicted = system.solve(lam)
    actual = prob.cost(start) - prob.cost(prob.step(start, dc, dp))
    assert predicted > 0
    assert predicted == pytest.approx(actual, rel=1e-8)
