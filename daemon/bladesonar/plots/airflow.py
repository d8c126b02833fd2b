"""Range-time picture of the moving echoes (``plot airflow``): the glint streaks and the
slope the airflow stage measured, drawn through the brightest glint.

A streak that falls (range shrinking with time) is a glint while the blade approaches: a
down-draft; one that rises, an up-draft (docs/airflow.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..airflow_recording import RangeTime
from ..imaging import RANGE_LABEL
from . import FIGSIZE, pyplot, save

#: Half length of the slope guide, s.
GUIDE_S = 0.4


def draw(rt: RangeTime, out: str | Path, *, title: str = "",
         max_range_m: float | None = None) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=FIGSIZE, layout="constrained")
    r, t = rt.range_m, rt.time_s
    keep = r <= (max_range_m if max_range_m else r[-1])
    img = rt.image[:, keep]
    top = float(np.percentile(img, 99.7)) if img.size else 0.0
    dt = t[1] - t[0] if len(t) > 1 else 1.0
    dr = r[1] - r[0] if len(r) > 1 else 1.0
    im = ax.imshow(img.T, origin="lower", aspect="auto", cmap="magma", vmin=0.0,
                   vmax=top if top > 0 else 1.0, interpolation="nearest",
                   extent=[t[0] - dt / 2, t[-1] + dt / 2, r[0] - dr / 2, r[keep][-1] + dr / 2])
    a = rt.airflow
    if a.airflow != "unknown" and img.size and top > 0:
        # through the brightest glint a guide's length away from either edge
        inner = (t >= t[0] + GUIDE_S) & (t <= t[-1] - GUIDE_S)
        look = np.where(inner[:, None], img, -1.0) if inner.any() else img
        i, j = np.unravel_index(int(np.argmax(look)), img.shape)
        tt = np.array([t[i] - GUIDE_S, t[i] + GUIDE_S])
        ax.plot(tt, r[keep][j] + rt.slope_m_s * (tt - t[i]), color="cyan", lw=1.5, ls="--",
                label=f"measured glint slope {rt.slope_m_s:+.3f} m/s")
        ax.legend(loc="upper right", fontsize=9)
    ax.set_xlim(t[0] - dt / 2, t[-1] + dt / 2)
    ax.set_ylim(r[0] - dr / 2, r[keep][-1] + dr / 2)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(RANGE_LABEL, fontsize=9)
    what = {"down": "glints approach: down (summer)", "up": "glints recede: up (winter)"}
    ax.set_title(title or f"moving echoes, static removed; airflow {a.airflow}"
                 + (f" ({what[a.airflow]}, t {a.t:+.1f})" if a.airflow in what else
                    f" ({a.reason})"), fontsize=10)
    cb = fig.colorbar(im, ax=ax)
    cb.set_label("envelope of the moving echoes")
    return save(fig, out)
