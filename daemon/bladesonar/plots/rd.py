"""Range-doppler picture: power in dB over doppler (Hz) and one-way range (m), gate marked."""

from __future__ import annotations

from pathlib import Path

from ..imaging import RANGE_LABEL, RDMap
from . import FIGSIZE, pyplot, save


def draw(m: RDMap, out: str | Path, *, title: str = "", floor_db: float | None = None,
         max_range_m: float | None = None) -> Path:
    """``floor_db`` None: 3 dB over the map's median (its noise floor), so the noise
    texture does not bury the echoes (and the PNG stays small)."""
    import numpy as np

    plt = pyplot()
    if floor_db is None:
        floor_db = min(float(np.median(m.power_db)) + 3.0, -10.0)
    fig, ax = plt.subplots(figsize=FIGSIZE, layout="constrained")
    r = m.range_m
    keep = r <= (max_range_m if max_range_m else r[-1])
    dr = r[1] - r[0]
    df = m.doppler_hz[1] - m.doppler_hz[0]
    im = ax.imshow(m.power_db[:, keep].T, origin="lower", aspect="auto", cmap="viridis",
                   vmin=floor_db, vmax=0.0, interpolation="nearest",
                   extent=[m.doppler_hz[0] - df / 2, m.doppler_hz[-1] + df / 2,
                           r[0] - dr / 2, r[keep][-1] + dr / 2])
    g = m.gate
    top = r[keep][-1] + dr / 2
    for y in (g.start_m, g.stop_m):
        if y <= top:
            ax.axhline(y, color="w", lw=1.2, ls="--")
    if g.start_m < top:
        ax.annotate("", xy=(m.doppler_hz[0] + 2 * df, g.start_m),
                    xytext=(m.doppler_hz[0] + 2 * df, min(g.stop_m, top)),
                    arrowprops=dict(arrowstyle="<->", color="w", lw=1.2))
        ax.text(m.doppler_hz[0] + 3 * df, 0.5 * (g.start_m + min(g.stop_m, top)),
                f"analysis gate {g.start_m:.2f}-{g.stop_m:.2f} m", color="w", va="center",
                ha="left", fontsize=9, rotation=90)
    if m.target_m is not None:
        ax.axhline(m.target_m, color="orange", lw=1.0, ls=":")
        ax.text(m.doppler_hz[-1] - df, m.target_m, f"target {m.target_m:.2f} m ", color="orange",
                va="top", ha="right", fontsize=9)
    ax.set_xlabel("doppler (Hz)")
    ax.set_ylabel(RANGE_LABEL, fontsize=9)
    ax.set_title(title or f"range-doppler map, {m.pulses} pulses (static part removed)")
    cb = fig.colorbar(im, ax=ax)
    cb.set_label("power (dB re. map peak)")
    return save(fig, out)
