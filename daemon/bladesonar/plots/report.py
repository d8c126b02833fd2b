"""Report curves: direction accuracy and rate error against the observation window (one
line per SNR), and compute time against the window."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from . import FIGSIZE, pyplot, save


def _plain_ticks(ax: Any) -> None:
    """Log axes labelled 0.2, 1, 4 rather than 2x10^-1."""
    from matplotlib.ticker import FuncFormatter

    f = FuncFormatter(lambda v, _: f"{v:g}")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(f)
        axis.set_minor_formatter(FuncFormatter(lambda v, _: ""))


def _by_snr(rows: list[dict[str, Any]], family: str = "window_snr"
            ) -> Iterator[tuple[float, list[dict[str, Any]]]]:
    ws = [r for r in rows if r["family"] == family]
    for s in sorted({r["snr_db"] for r in ws}):
        g = sorted((r for r in ws if r["snr_db"] == s), key=lambda r: r["window_s"])
        yield s, g


def error_vs_time(rows: list[dict[str, Any]], out: str | Path, *, title: str = "",
                  prf_hz: float | None = None) -> Path:
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=FIGSIZE, layout="constrained")
    cmap = plt.get_cmap("viridis")
    groups = list(_by_snr(rows))
    for i, (s, g) in enumerate(groups):
        col = cmap(i / max(len(groups) - 1, 1))
        w = np.array([r["window_s"] for r in g])
        a1.plot(w, [100 * r["correct"] for r in g], "o-", color=col, ms=3, lw=1.2,
                label=f"{s:g} dB")
        a1.plot(w, [100 * r["unknown"] for r in g], ":", color=col, lw=0.9)
        e = [(r["window_s"], 100 * r["rate_err_median"], 100 * r["rate_err_p95"]) for r in g
             if r["rate_err_median"] is not None]
        if e:
            x, m, p = map(np.array, zip(*e, strict=True))
            a2.plot(x, m, "o-", color=col, ms=3, lw=1.2, label=f"{s:g} dB")
            a2.plot(x, p, "--", color=col, lw=0.8)
    a1.axhline(99, color="0.5", lw=0.7, ls="--")
    a1.set_xscale("log")
    a1.set_ylim(-2, 102)
    a1.set_xlabel("observation window (s)")
    a1.set_ylabel("direction correct (%)  [dotted: unknown %]")
    a1.legend(title="SNR", fontsize=7, title_fontsize=8, loc="center right")
    a2.set_xscale("log")
    a2.set_yscale("log")
    a2.set_xlabel("observation window (s)")
    a2.set_ylabel("rate error (%)  [solid: median, dashed: 95th pct]")
    _plain_ticks(a2)
    for a in (a1, a2):
        a.grid(alpha=0.3, which="both")
    fig.suptitle(title or "accuracy against observation time (paper-room, 4 blades, "
                 "same rate as the reference)", fontsize=10)
    return save(fig, out)


def compute_vs_window(rows: list[dict[str, Any]], out: str | Path, *, title: str = "") -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=FIGSIZE, layout="constrained")
    ws = [r for r in rows if r["cpu_per_audio_s"] is not None]
    wins = sorted({r["window_s"] for r in ws})
    per = [[r["cpu_per_audio_s"] for r in ws if r["window_s"] == w] for w in wins]
    med = [1e3 * float(np.median(p)) for p in per]
    lo = [1e3 * float(np.min(p)) for p in per]
    hi = [1e3 * float(np.max(p)) for p in per]
    ax.fill_between(wins, lo, hi, color="C0", alpha=0.2, lw=0, label="range over sweep points")
    ax.plot(wins, med, "o-", color="C0", label="median")
    ax.set_xscale("log")
    ax.set_yscale("log")
    _plain_ticks(ax)
    ax.set_xlabel("observation window (s)")
    ax.set_ylabel("analyze CPU time per second of audio (ms/s)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(title or "analyze CPU time per second of audio (windows under 3 s: partly "
                 "refused recordings, which cost little)", fontsize=10)
    return save(fig, out)
