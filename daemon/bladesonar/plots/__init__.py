"""Drawing only: matplotlib figures of what :mod:`bladesonar.imaging` and the report compute.

matplotlib is the optional extra ``bladesonar[plots]``; it is imported here, on first use,
with the non-interactive Agg backend, and never by the analysis or the daemon.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import BladesonarError

SUFFIXES = {".png": "png", ".svg": "svg"}
#: Default figure size (inches) and resolution: 800 x 500 pixels.
FIGSIZE = (8.0, 5.0)
DPI = 100


class PlotsUnavailable(BladesonarError):
    """matplotlib (the ``plots`` extra) is not installed."""


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend, or a clear error naming the extra."""
    try:
        import matplotlib
    except ImportError as exc:
        raise PlotsUnavailable("pictures need matplotlib: install the plots extra, e.g. "
                               "pip install 'bladesonar[plots]' (or tools/setup)") from exc
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def out_format(path: str | Path) -> str:
    """'png' or 'svg' from the file suffix; anything else is refused before any work."""
    suf = Path(path).suffix.lower()
    if suf not in SUFFIXES:
        from ..errors import InputError

        raise InputError(f"--out {path}: the picture format comes from the suffix; use .png "
                         "or .svg")
    return SUFFIXES[suf]


def save(fig: Any, path: str | Path) -> Path:
    """Write the figure (format from the suffix), creating folders; close it."""
    from ..errors import InputError

    p = Path(path)
    fmt = out_format(p)
    plt = pyplot()
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        if fmt == "png":
            _save_png(fig, p)
        else:
            fig.savefig(p, format=fmt, dpi=DPI)
    except OSError as exc:
        raise InputError(f"--out {p}: cannot be written ({exc.strerror}); choose a "
                         "writable path") from exc
    finally:
        plt.close(fig)
    return p


def _save_png(fig: Any, path: Path) -> None:
    """PNG with a 256-colour octree palette (no dithering; keeps rare annotation colours,
    unlike median cut): pictures of noisy maps stay small enough to commit."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - matplotlib depends on Pillow
        path.write_bytes(buf.getvalue())
        return
    buf.seek(0)
    with Image.open(buf) as im:
        q = im.convert("RGB").quantize(colors=256, method=Image.Quantize.FASTOCTREE,
                                         dither=Image.Dither.NONE)
        q.save(path, format="PNG", optimize=True)
