"""Simulated multipath range series, CCW solid and CW dashed (the paper's first figure)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..imaging import RANGE_LABEL, PathSeries
from . import FIGSIZE, pyplot, save


def draw(ccw: PathSeries, cw: PathSeries, out: str | Path, *, title: str = "",
         direct_ccw: PathSeries | None = None, direct_cw: PathSeries | None = None) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=FIGSIZE, layout="constrained")
    for s, ls, lab, col in ((ccw, "-", "ccw multipath", "C0"), (cw, "--", "cw multipath", "C3")):
        _plot_paths(ax, s, ls=ls, label=lab, color=col, lw=1.1)
    for d, ls, lab in ((direct_ccw, "-", "ccw direct"), (direct_cw, "--", "cw direct")):
        if d is not None:
            _plot_paths(ax, d, ls=ls, label=lab, color="0.5", lw=0.9)
    ax.set_xlabel("pulse number")
    ax.set_ylabel(RANGE_LABEL, fontsize=9)
    ax.set_title(title or "simulated fan echoes: solid ccw, dashed cw", fontsize=10)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.7)
    ax.grid(alpha=0.3)
    return save(fig, out)


def _plot_paths(ax: Any, s: PathSeries, *, ls: str, label: str, color: str, lw: float) -> None:
    """Every path of ``s`` that is ever seen, one legend entry for all of them."""
    lab: str | None = label
    for m in range(s.range_m.shape[1]):
        y = s.range_m[:, m]
        if np.isfinite(y).any():
            ax.plot(s.pulse, y, ls=ls, color=color, lw=lw, label=lab)
            lab = None
