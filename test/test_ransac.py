import numpy as np

from nrmpc_ros.core.ransac import RansacOptions, draw_sample, ransac, required_iterations


class LineProblem:
    """y = a x + b with errors |y - a x - b|: a tiny problem to test the loop itself."""

    sample_size = 2

    def __init__(self, x, y):
        self.x, self.y = x, y
        self.num_data = len(x)

    def generate(self, s):
        x, y = self.x[s], self.y[s]
        if abs(x[1] - x[0]) < 1e-12:
            return []
        a = (y[1] - y[0]) / (x[1] - x[0])
        return [(a, y[0] - a * x[0])]

    def errors(self, models, idx=None):
        x = self.x if idx is None else self.x[idx]
        y = self.y if idx is None else self.y[idx]
        return np.array([np.abs(y - a * x - b) for a, b in models])


def test_ransac_finds_the_line_and_stops_early():
    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, 1000)
    y = 2 * x + 0.5 + rng.normal(scale=1e-3, size=1000)
    out = rng.random(1000) < 0.4
    y[out] = rng.uniform(-3, 3, out.sum())
    res = ransac(LineProblem(x, y), RansacOptions(threshold=5e-3, max_iterations=500), np.random.default_rng(0))
    a, b = res.model
    assert abs(a - 2) < 0.01 and abs(b - 0.5) < 0.01
    assert res.inliers[~out].mean() > 0.95 and res.inliers[out].mean() < 0.05
    assert res.iterations < 200  # adaptive stopping: ~30 needed at 60 % inliers


def test_ransac_is_deterministic_for_a_seed():
    rng = np.random.default_rng(4)
    x = rng.uniform(-1, 1, 300)
    y = -x + rng.normal(scale=0.01, size=300)
    opts = RansacOptions(threshold=0.03)
    r1 = ransac(LineProblem(x, y), opts, np.random.default_rng(5))
    r2 = ransac(LineProblem(x, y), opts, np.random.default_rng(5))
    assert r1.model == r2.model and r1.iterations == r2.iterations


def test_required_iterations_and_grouped_samples():
    assert required_iterations(1.0, 6, 0.999) == 1.0
    assert np.isinf(required_iterations(0.0, 6, 0.999))
    assert 5 < required_iterations(0.95, 6, 0.999) < 6
    groups = np.array([0] * 50 + [1])
    rng = np.random.default_rng(0)
    for _ in range(20):
        s = draw_sample(rng, 51, 6, groups)
        assert len(set(s)) == 6
