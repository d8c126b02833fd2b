"""ISAR picture: the backprojected image in the fan's rotating frame, blade circle marked."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..imaging import IsarImage
from . import pyplot, save


def draw(img: IsarImage, out: str | Path, *, title: str = "", floor_db: float = -20.0,
         tip_m: float | None = None, hub_m: float | None = None) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.6, 5.2), layout="constrained")
    e = img.extent_m
    db = 20.0 * np.log10(img.image / max(float(img.image.max()), 1e-300) + 1e-12)
    im = ax.imshow(db, origin="lower", extent=[-e, e, -e, e], cmap="magma", vmin=floor_db,
                   vmax=0.0, interpolation="bilinear")
    th = np.linspace(0, 2 * math.pi, 361)
    for r, lab, col, ls in ((tip_m, "blade tips", "c", "--"), (hub_m, "hub", "w", ":")):
        if r:
            ax.plot(r * np.cos(th), r * np.sin(th), color=col, lw=0.8, ls=ls, label=lab)
    if tip_m or hub_m:
        ax.legend(loc="upper right", fontsize=8, framealpha=0.6)
    ax.set_xlabel("x in the rotating fan frame (m from the fan centre)")
    ax.set_ylabel("y in the rotating fan frame (m)")
    ax.set_aspect("equal")
    sense = "ccw" if img.rate_hz > 0 else "cw"
    ax.set_title(title or f"ISAR backprojection ({img.mode}), {img.pulses} pulses, "
                 f"{abs(img.rate_hz):.3g} Hz {sense}", fontsize=10)
    cb = fig.colorbar(im, ax=ax, shrink=0.9)
    cb.set_label("brightness (dB re. image peak)")
    return save(fig, out)
