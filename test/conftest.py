"""Shared fixtures: seeded synthetic rigs and problems (paper set-up)."""

import numpy as np
import pytest

from nrmpc_ros.sim.synthetic import RigSpec, Scenario, make_problem, make_rig


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture
def cross_rig():
    return make_rig(RigSpec())


def problem(scenario=None, seed=0, **kw):
    return make_problem(scenario or Scenario(**kw), seed=seed)


@pytest.fixture(scope="session")
def recordings_dir(tmp_path_factory):
    """Where the rendered recordings of test/recordings.py are kept for the session."""
    return tmp_path_factory.mktemp("recordings")
