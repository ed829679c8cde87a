"""Plots: axis-level drawing functions, one way to make a figure and one way to save it.

Each ``draw_*`` function draws on a matplotlib axis it is given, from plain
arrays, so a caller composes figures from them (the commands' PNG outputs,
a notebook). :func:`figure` selects the non-interactive Agg backend once,
before pyplot is first imported (no screen is needed); :func:`save_png`
writes atomically (complete or absent) and closes the figure.
"""

from __future__ import annotations

import numpy as np

from .safeio import atomic_write

# one colour per estimator, the same in every plot
METHOD_COLOURS = {"6pt-nonbending": "tab:red", "6pt-bending": "tab:blue", "4pt-bending": "tab:green"}
_pyplot = None


def pyplot():
    """matplotlib.pyplot on the Agg backend (selected once, here)."""
    global _pyplot
    if _pyplot is None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        _pyplot = plt
    return _pyplot


def figure(nrows: int = 1, ncols: int = 1, **kwargs):
    """(figure, axes) as ``plt.subplots``."""
    return pyplot().subplots(nrows, ncols, **kwargs)


def save_png(fig, path, flag: str | None = None, dpi: int = 100) -> None:
    """Write ``fig`` as PNG to ``path`` atomically (``flag`` names the option in errors) and close it."""
    try:
        with atomic_write(path, "wb", flag=flag) as fh:
            fig.savefig(fh, format="png", dpi=dpi)
    finally:
        pyplot().close(fig)


def positive(y) -> np.ndarray:
    """y where finite and > 0, else NaN (a log axis shows no point there)."""
    y = np.asarray(y, dtype=float)
    return np.where(np.isfinite(y) & (y > 0), y, np.nan)


def draw_series(ax, series, ylabel: str, xlabel: str | None = None, title: str | None = None,
                logx: bool = False, logy: bool = False, fontsize: int = 8) -> None:
    """Lines: ``series`` is [(x, y, style, colour or None, label or None)]; a series with no finite value is
    left out; grid, labels, legend (when any series is labelled)."""
    for x, y, style, colour, label in series:
        y = np.asarray(y, dtype=float)
        if len(y) and np.isfinite(y).any():
            ax.plot(np.asarray(x, dtype=float), y, style, color=colour, label=label, ms=3)
    if logx:
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    ax.set_ylabel(ylabel, fontsize=fontsize)
    if xlabel:
        ax.set_xlabel(xlabel, fontsize=fontsize)
    if title:
        ax.set_title(title, fontsize=fontsize + 1)
    ax.tick_params(which="both", labelsize=fontsize - 1)
    ax.grid(True, which="both", alpha=0.3, lw=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=fontsize - 1)


def draw_limits(ax, horizontal: tuple | None = None, vertical: tuple | None = None) -> None:
    """Dotted reference lines: ``horizontal`` / ``vertical`` = (value, colour, label)."""
    if horizontal:
        ax.axhline(horizontal[0], color=horizontal[1], lw=0.8, ls=":", label=horizontal[2])
    if vertical:
        ax.axvline(vertical[0], color=vertical[1], lw=0.8, ls=":", label=vertical[2])
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)


def draw_note(ax, text: str) -> None:
    """A panel with nothing to show: ``text`` in its centre, no ticks."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_yticks([])
