"""Monte Carlo experiments, Cramér-Rao bounds and the benchmark (paper section 4).

- :mod:`.runner`: seeded tasks (grid cell x run x methods), run in-process, on local processes or on Dask.
- :mod:`.sweeps`: the paper's noise-ei, outliers and gravity-noise grids with CSV, PNG and markdown output.
- :mod:`.crlb` and :mod:`.observability`: Fisher information of the angular residuals, bounds, EI sweep.
- :mod:`.bench`: the three estimators and PoseLib's rigid pipeline timed on the same problems.
"""
