"""ROS domains for the tests' DDS traffic: one per test, never shared by tests running at once."""

import os
import random


def domain_id(low: int, high: int) -> int:
    """A ROS_DOMAIN_ID in [low, high] for one test. Under pytest-xdist each worker draws from its own residue
    class modulo the number of workers, so two tests running at the same time on two workers never meet; on one
    worker the tests run one after another and their processes are gone before the next starts."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    count = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    return random.choice(range(low + index % count, high + 1, count))
