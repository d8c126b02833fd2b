"""Track picture: the filtered angular fingerprint over time with its band, the running
decision, and reversals (decided, and true when a truth file is given)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..answer import Direction
from ..imaging import TrackSeries
from . import pyplot, save

COLOURS = {Direction.SAME: "#2ca02c", Direction.REVERSED: "#d62728",
           Direction.STOPPED: "#7f7f7f", Direction.UNKNOWN: "#ffffff"}


def _spans(t: np.ndarray, labels: np.ndarray) -> Iterator[tuple[float, float, Any]]:
    """(start, end, label) runs of equal labels (a label: an element of ``labels``)."""
    if len(t) == 0:
        return
    edges = np.nonzero(labels[1:] != labels[:-1])[0] + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [len(t)]])
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    for a, b in zip(starts, ends, strict=True):
        yield t[a], t[b - 1] + dt, labels[a]


def draw(s: TrackSeries, out: str | Path, *, title: str = "", min_confidence: float = 0.5,
         true_reversals: Sequence[float] = ()) -> Path:
    plt = pyplot()
    fig, (a1, a2, a3) = plt.subplots(3, 1, sharex=True, figsize=(8.0, 6.0),
                                     layout="constrained",
                                     gridspec_kw=dict(height_ratios=[3.0, 1.6, 1.0]))
    good = ~s.outlier
    a1.scatter(s.t_s[good], s.matched[good], s=4 + 20 * s.quality[good], c="C0",
               alpha=0.5, lw=0, label="matched phase (size = quality)")
    a1.scatter(s.t_s[~good], s.matched[~good], s=8, c="0.6", marker="x", lw=0.6,
               label="outlier (skipped)")
    a1.plot(s.t_s, s.track, color="k", lw=1.2, label="tracked phase")
    if np.isfinite(s.sd).any():
        a1.fill_between(s.t_s, s.track - 2 * s.sd, s.track + 2 * s.sd, color="orange",
                        alpha=0.5, lw=0, label="±2σ")
    a1.set_ylabel("reference phase\n(blade periods, unwrapped)")
    a1.legend(loc="best", fontsize=7, framealpha=0.7, markerscale=1.5)
    for a, b, lab in _spans(s.t_s, s.direction):
        if lab != Direction.UNKNOWN:
            a2.axvspan(a, b, color=COLOURS.get(lab, "w"), alpha=0.18, lw=0)
    a2.plot(s.t_s, s.relative_rate, color="k", lw=1.0)
    a2.axhline(0.0, color="0.5", lw=0.6)
    a2.set_ylabel("relative rate\n(this / reference)")
    from matplotlib.patches import Patch

    a2.legend(handles=[Patch(color=COLOURS[k], alpha=0.35 if k != Direction.UNKNOWN else 1.0,
                             label=k.value, ec="0.7") for k in COLOURS],
              loc="best", fontsize=7, ncol=4, framealpha=0.7)
    a3.plot(s.t_s, s.confidence, color="C1", lw=1.0)
    a3.axhline(min_confidence, color="0.4", lw=0.7, ls=":")
    a3.set_ylim(-0.02, 1.02)
    a3.set_ylabel("confidence")
    a3.set_xlabel("time (s)")
    for ax in (a1, a2, a3):
        for t in s.reversals:
            ax.axvline(t, color="r", lw=1.0)
        for t in true_reversals:
            ax.axvline(t, color="k", lw=1.0, ls="--")
        ax.grid(alpha=0.25)
    note = []
    if len(s.reversals):
        note.append("red: reversal decided")
    if len(true_reversals):
        note.append("black dashed: true reversal")
    a1.set_title((title or "angular fingerprint track") +
                 (f"  ({'; '.join(note)})" if note else ""), fontsize=10)
    return save(fig, out)
