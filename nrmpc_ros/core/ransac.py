"""One robust loop for every problem (the PoseLib pattern).

A problem plugs in as an object with ``sample_size``, ``num_data``,
``generate(sample) -> list of models``, ``errors(models) -> (K, N) errors``
and optionally ``local_optimize(model, inlier_mask) -> model``. Scoring is
MSAC (truncated squared error) over all correspondences at once per batch of
hypotheses; stopping is adaptive on the inlier ratio, capped, and also ends
once the best model has not improved for ``patience`` iterations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .loss import msac_score


@dataclass
class RansacOptions:
    threshold: float  # error threshold (same unit as errors(), here rad)
    confidence: float = 0.999
    min_iterations: int = 5
    max_iterations: int = 1000
    patience: int = 100  # stop when no better model for this many iterations
    local_optimization: bool = True
    preemptive_subset: int = 100  # models are first ranked on this many correspondences


@dataclass
class RansacResult:
    model: object
    inliers: np.ndarray  # bool mask
    errors: np.ndarray
    iterations: int
    cost: float

    @property
    def num_inliers(self) -> int:
        return int(self.inliers.sum())


def required_iterations(inlier_ratio: float, sample_size: int, confidence: float) -> float:
    """Iterations needed to draw one all-inlier sample with the given confidence."""
    p = inlier_ratio**sample_size
    if p >= 1.0:
        return 1.0
    if p <= 1e-12:
        return math.inf
    return math.log(1.0 - confidence) / math.log(1.0 - p)


def draw_sample(rng: np.random.Generator, n: int, k: int, groups: np.ndarray | None = None) -> np.ndarray:
    """k distinct indices; with ``groups`` (camera ids) a sample never lies in one group alone."""
    for _ in range(20):
        s = rng.choice(n, size=k, replace=False)
        if groups is None or np.any(groups[s] != groups[s[0]]):
            return s
    return s


def ransac(problem, options: RansacOptions, rng: np.random.Generator,
           groups: np.ndarray | None = None) -> RansacResult | None:
    """Run the robust loop; returns None when no hypothesis was ever generated."""
    n = problem.num_data
    best = None
    best_cost = math.inf
    needed = math.inf
    last_improvement = 0
    it = 0
    subset = None
    if options.preemptive_subset and n > 3 * options.preemptive_subset:
        subset = np.sort(rng.choice(n, size=options.preemptive_subset, replace=False))
    for it in range(1, options.max_iterations + 1):
        models = problem.generate(draw_sample(rng, n, problem.sample_size, groups))
        if models and subset is not None:
            sub_err = problem.errors(models, subset)
            sub_cost = msac_score(sub_err, options.threshold, axis=1) * (n / len(subset))
            k = int(np.argmin(sub_cost))
            models = [models[k]] if sub_cost[k] < 1.5 * best_cost else []
        if models:
            errs = problem.errors(models)
            costs = msac_score(errs, options.threshold, axis=1)
            k = int(np.argmin(costs))
            if costs[k] < best_cost:
                model, err, cost = models[k], errs[k], float(costs[k])
                if options.local_optimization and hasattr(problem, "local_optimize"):
                    lo = problem.local_optimize(model, err < options.threshold)
                    if lo is not None:
                        lo_err = problem.errors([lo])[0]
                        lo_cost = msac_score(lo_err, options.threshold)
                        if lo_cost < cost:
                            model, err, cost = lo, lo_err, lo_cost
                best, best_cost = (model, err), cost
                ratio = float(np.mean(err < options.threshold))
                needed = required_iterations(ratio, problem.sample_size, options.confidence)
                last_improvement = it
        if it >= options.min_iterations and best is not None:
            if it >= needed or it - last_improvement >= options.patience:
                break
    if best is None:
        return None
    model, err = best
    return RansacResult(model=model, inliers=err < options.threshold, errors=err, iterations=it, cost=best_cost)
