"""Does the stored reference still fit the room? A running figure and a verdict (pure).

A reference is a fingerprint of the room as it was: a device or fan moved, large
furniture moved, or a room far warmer or colder than at the reference (beyond what the
analysis rescales, about 3 % in the speed of sound) leave the matches barely better than
chance. The figure watched is the mean match quality (dsp/fingerprint.py ``match``: 1 -
nearest / far distance) of the pulses while the fan moves, over the last ``span_s`` of
moving time, relative to what the reference promised: its own quality (the share of its
recording explained by its table) times :data:`FIT_NOMINAL`, the ratio measured in rooms
that fit. So ``fit`` is about 1 where the reference fits and falls towards 0 where it
does not; a stopped fan says nothing and is not counted.

Measured on the simulator (tools/fit_table: paper room, reference 20 s at 0.45 Hz, probes
40 s at 0.4 Hz; docs/mqtt.md): mean quality / reference quality 0.41 in the same room at
0 and 20 dB, 0.39-0.41 with a wall moved by 0.2-0.3 m, 0.37 with two walls made more
absorbing, 0.41-0.42 at +5 and +15 degrees C (rescaled by the analysis); 0.15 with the
sensor moved by 5 cm, 0.01-0.02 by 20 cm, 0.07 at +20 degrees C (beyond the rescaling).
With the default ``stale_fit`` 0.6 the fitting rooms (fit 0.90-1.02) and the others
(0.03-0.36) are far apart.
"""

from __future__ import annotations

import math
from collections import deque

#: Mean live match quality over the reference's own quality in a room that fits
#: (measured, see the module doc).
FIT_NOMINAL = 0.41
#: The verdict goes back to fitting only above stale_fit + this (no flapping).
HYSTERESIS = 0.1


class FitWatch:
    """Feed :meth:`update` with samples (time, moving, mean quality) as they come; read
    :attr:`fit` (None until half of ``span_s`` of moving time is seen) and :attr:`stale`.

    Parameters
    ----------
    ref_quality : float
        The reference's ``quality`` (explained fraction of its recording), > 0.
    stale_fit : float
        Below this fit (over a full span) the reference is stale.
    span_s : float
        Seconds of moving time the fit is averaged over.
    """

    def __init__(self, ref_quality: float, *, stale_fit: float, span_s: float) -> None:
        if not ref_quality > 0:
            raise ValueError(f"ref_quality must be positive, got {ref_quality!r}")
        if not span_s > 0:
            raise ValueError(f"span_s must be positive, got {span_s!r}")
        self.expect = float(ref_quality) * FIT_NOMINAL
        self.stale_fit, self.span_s = float(stale_fit), float(span_s)
        self._samples: deque[tuple[float, float]] = deque()   # (seconds, quality)
        self._moving_s = 0.0
        self._sum = 0.0
        self._last_t: float | None = None
        self.stale = False

    def update(self, t_s: float, moving: bool, quality: float) -> None:
        """One sample: the time it stands for is the gap since the previous one (at most
        10 s: a gap longer than that is a pause, not moving time)."""
        t = float(t_s)
        dt = 0.0 if self._last_t is None else min(max(t - self._last_t, 0.0), 10.0)
        self._last_t = t
        if not moving or not math.isfinite(quality) or dt <= 0:
            return
        self._samples.append((dt, float(quality)))
        self._moving_s += dt
        self._sum += dt * float(quality)
        while self._samples and self._moving_s - self._samples[0][0] >= self.span_s:
            d, q = self._samples.popleft()
            self._moving_s -= d
            self._sum -= d * q
        f = self.fit
        if f is None:
            return
        if not self.stale and f < self.stale_fit and self._moving_s >= 0.95 * self.span_s:
            self.stale = True
        elif self.stale and f >= self.stale_fit + HYSTERESIS:
            self.stale = False

    @property
    def moving_s(self) -> float:
        """Seconds of moving time behind the current figure."""
        return self._moving_s

    @property
    def fit(self) -> float | None:
        """Mean match quality while moving over the span, relative to the reference's
        promise (1: fits as it did; 0: chance); None with less than half a span seen."""
        if self._moving_s < 0.5 * self.span_s or self._moving_s <= 0:
            return None
        return max(self._sum / self._moving_s / self.expect, 0.0)
