"""The modules the pipeline imports on first use, loaded by the node's workers before their first work.

The command-line tools import heavy modules (SciPy's) only where they are used, so that a command starts in a
fraction of a second. A running node should pay that once, before the data comes: otherwise its first hold's
estimate waits for imports (0.1-0.3 s of its latency budget on this project's benchmark machine) and its first
frame sets for SciPy's special functions. Each worker loads its stage's list as it starts.
"""

from __future__ import annotations

import importlib

# frame sets: the stillness test's chi-square quantiles and erosions, the IMU clock's 1-D minimisation
INTAKE = ("scipy.special", "scipy.ndimage", "scipy.optimize")
# holds: the patch alignment's neighbour search (and the linear algebra SciPy's spatial package loads)
ESTIMATION = ("scipy.special", "scipy.spatial", "scipy.linalg")


def preload(modules: tuple) -> None:
    """Import ``modules`` (dotted names) now."""
    for name in modules:
        importlib.import_module(name)


__all__ = ["ESTIMATION", "INTAKE", "preload"]
