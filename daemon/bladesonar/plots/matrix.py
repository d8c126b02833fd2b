"""Pairwise matching-distance picture (the paper's stripe plots), stripes drawn.

By default the matrix is shown with its row and column means removed: what stays is how
much closer (red) or farther (blue) two pulses are than each pulse is to everything on
average, so the stripes of matching blade phase stand out from the pulses' own levels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..imaging import Stripes
from . import FIGSIZE, pyplot, save


def draw(d: np.ndarray, prf: float, out: str | Path, *, stripes: Stripes | None = None,
         label_a: str = "A", label_b: str = "B", title: str = "", centred: bool = True
         ) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=FIGSIZE, layout="constrained")
    nA, nB = d.shape
    ext = [-0.5, nB - 0.5, -0.5, nA - 0.5]
    if centred:
        z = d - d.mean(axis=1, keepdims=True) - d.mean(axis=0, keepdims=True) + d.mean()
        v = float(np.percentile(np.abs(z), 99)) or 1.0
        im = ax.imshow(z / v, origin="lower", aspect="auto", cmap="RdBu", vmin=-1, vmax=1,
                       interpolation="nearest", extent=ext)
        clabel = "distance, row and column means removed\n(red: closer than usual)"
    else:
        scale = float(np.median(d)) or 1.0
        im = ax.imshow(d / scale, origin="lower", aspect="auto", cmap="viridis_r",
                       interpolation="nearest", extent=ext, vmin=0.0,
                       vmax=float(np.percentile(d / scale, 99)))
        clabel = "squared distance of the match features (re. median)"
    ax.set_xlabel(f"pulse of {label_b} (PRF {prf:.2f} Hz)")
    ax.set_ylabel(f"pulse of {label_a}")
    txt = title or f"pulse-to-pulse matching distance: {label_a} vs {label_b}"
    if stripes is not None:
        s = stripes.slope
        sense = "same direction" if s > 0 else "reversed"
        txt += f"\nstripe slope {s:+.3f} = rate ratio {label_b}/{label_a} ({sense})"
        jj = np.linspace(-0.5, nB - 0.5, 200)
        for k, ii in enumerate(stripes.lines(jj, nA)):
            ax.plot(jj, ii, color="k", lw=0.8, ls=":", alpha=0.8,
                    label=f"stripes, slope {s:+.3f}" if k == 0 else None)
        ax.set_ylim(-0.5, nA - 0.5)
        ax.set_xlim(-0.5, nB - 0.5)
        ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    ax.set_title(txt, fontsize=10)
    cb = fig.colorbar(im, ax=ax)
    cb.set_label(clabel, fontsize=9)
    return save(fig, out)
