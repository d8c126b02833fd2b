"""Range scaling: a reference recorded at another temperature (pure numpy, float64).

Sound travels about 0.6 m/s faster per degree C, so a few degrees between the reference
and now move every echo: an echo at delay d in the reference comes at d / s now, with
``s = c_now / c_ref`` (delays count from the direct coupling, so the scaling is about
delay 0). At 5 m from the sensor 3 degrees move an echo by 6 samples, enough to spoil the
match. The static room shows it: the probe's mean pulse is the reference's stretched.
:func:`estimate_scale` finds s by correlating their envelopes over a grid of scales, and
:class:`Rescaler` reads each pulse's features at delays d / s, so that they line up with
the reference table again.
"""

from __future__ import annotations

import math

import numpy as np

from .analytic import analytic_magnitude

#: Largest |s - 1| searched: 5 % is about 28 degrees C.
MAX_SCALE_DEV = 0.05
#: Step of the search grid (then refined by a parabola).
SCALE_STEP = 2.5e-4
#: Below this |s - 1| (about 0.6 degree C) nothing is rescaled.
MIN_SCALE_DEV = 1e-3
#: Speed of sound change per degree C, m/s.
C_PER_DEGREE = 0.6


def envelope(x: np.ndarray, smooth: int = 9) -> np.ndarray:
    """Smoothed magnitude of the analytic signal of one pulse, mean removed."""
    env = analytic_magnitude(x)
    if smooth > 1:
        env = np.convolve(env, np.ones(smooth) / smooth, mode="same")
    centred: np.ndarray = env - env.mean()
    return centred


def _read(y: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """``y`` read at fractional indices ``pos`` (linear; 0 outside)."""
    read: np.ndarray = np.interp(pos, np.arange(len(y), dtype=np.float64), y, left=0.0,
                                 right=0.0)
    return read


def estimate_scale(ref_mean: np.ndarray, now_mean: np.ndarray, start: int
                   ) -> tuple[float, float]:
    """The scale s = c_now / c_ref that best maps the reference's static window on now's.

    Parameters
    ----------
    ref_mean, now_mean : ndarray, shape (L,)
        Mean gated pulses (the static room) of the reference and of now, delays
        ``start .. start + L`` samples from the coupling edge.
    start : int
        The gate's first delay, samples.

    Returns
    -------
    s : float
        Best scale (1 when nothing correlates).
    corr : float
        Correlation coefficient of the envelopes at s, in [-1, 1].
    """
    a = envelope(ref_mean)
    b = envelope(now_mean)
    L = len(a)
    d = start + np.arange(L, dtype=np.float64)
    grid = np.arange(1.0 - MAX_SCALE_DEV, 1.0 + MAX_SCALE_DEV + SCALE_STEP / 2, SCALE_STEP)
    na = float(np.sqrt(a @ a))
    if not na > 0:
        return 1.0, 0.0
    cs = np.empty(len(grid))
    for i, s in enumerate(grid):
        # now's window read where the reference's echoes have moved to: d / s
        w = _read(b, d / s - start)
        nw = float(np.sqrt(w @ w))
        cs[i] = float(a @ w) / (na * nw) if nw > 0 else -1.0
    j = int(np.argmax(cs))
    s = float(grid[j])
    if 0 < j < len(grid) - 1:
        den = cs[j - 1] - 2 * cs[j] + cs[j + 1]
        if den < 0:
            s += SCALE_STEP * min(max(0.5 * (cs[j - 1] - cs[j + 1]) / den, -0.5), 0.5)
    return s, float(cs[j])


def degrees(s: float, c: float) -> float:
    """The temperature change a scale means, degrees C (+: warmer now)."""
    return (s - 1.0) * c / C_PER_DEGREE


class Rescaler:
    """Reads features of pulses taken at scale s on the reference's delay grid."""

    def __init__(self, s: float, start: int, length: int) -> None:
        self.s = float(s)
        pos = (start + np.arange(length, dtype=np.float64)) / self.s - start
        self.i0 = np.clip(np.floor(pos).astype(np.int64), 0, length - 1)
        self.i1 = np.clip(self.i0 + 1, 0, length - 1)
        self.w = np.clip(pos - np.floor(pos), 0.0, 1.0)
        self.w[(pos < 0) | (pos > length - 1)] = 0.0
        self.inside = (pos >= 0) & (pos <= length - 1)

    @property
    def active(self) -> bool:
        return abs(self.s - 1.0) >= MIN_SCALE_DEV

    def __call__(self, features: np.ndarray) -> np.ndarray:
        """Rows of features (n, L) read at delays d / s (0 beyond the window)."""
        f = np.asarray(features, dtype=np.float64)
        out = (1.0 - self.w) * f[:, self.i0] + self.w * f[:, self.i1]
        out[:, ~self.inside] = 0.0
        return out


def within(s: float, limit: float) -> bool:
    """Whether a scale is close enough to 1 for the reference to fit after rescaling."""
    return math.isfinite(s) and abs(s - 1.0) <= limit
