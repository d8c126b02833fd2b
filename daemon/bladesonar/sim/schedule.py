"""Rotation schedule: piecewise-constant rate, angle as its exact integral (pure).

Sign convention: positive rate = counter-clockwise in the scene's floor plan (x right,
y up, seen from above). A segment is (direction, rate_hz >= 0, seconds); the last segment
continues past its stated length to the end of the run, so ``"ccw:0.5:1"`` is a constant
0.5 Hz for any duration. Angle(t) = start + integral of rate, piecewise linear, so speed
changes and reversals are exact at every pulse time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..errors import ConfigError

DIRECTIONS = ("cw", "ccw", "stop")
_SIGN = {"cw": -1.0, "ccw": 1.0, "stop": 0.0}


@dataclass(frozen=True)
class Segment:
    direction: str
    rate_hz: float
    seconds: float

    @property
    def signed_hz(self) -> float:
        return _SIGN[self.direction] * self.rate_hz


@dataclass(frozen=True)
class Schedule:
    """Segments in order; ``angle_at`` / ``rate_at`` evaluate it at any times (vectorised)."""

    segments: tuple[Segment, ...]

    @classmethod
    def constant(cls, rate_hz: float, direction: str = "ccw") -> "Schedule":
        """One segment forever; ``rate_hz`` 0 means stopped."""
        return parse([(direction if rate_hz else "stop", rate_hz, 1.0)], key="--rate")

    def _knots(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t0 = np.concatenate([[0.0], np.cumsum([s.seconds for s in self.segments])[:-1]])
        r = np.array([s.signed_hz for s in self.segments], dtype=np.float64)
        turns0 = np.concatenate([[0.0], np.cumsum(r[:-1] * np.diff(t0))])
        return t0, r, turns0

    def rate_at(self, t: np.ndarray) -> np.ndarray:
        """Signed rate in Hz (+ = ccw) at times ``t`` (s); right-continuous at knots."""
        t0, r, _ = self._knots()
        i = np.clip(np.searchsorted(t0, np.asarray(t, dtype=np.float64), side="right") - 1,
                    0, len(r) - 1)
        return r[i]

    def turns_at(self, t: np.ndarray) -> np.ndarray:
        """Integral of the signed rate from 0 to ``t``, in turns (exact, piecewise linear)."""
        t = np.asarray(t, dtype=np.float64)
        t0, r, turns0 = self._knots()
        i = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(r) - 1)
        return turns0[i] + r[i] * (t - t0[i])

    def angle_at(self, t: np.ndarray, start_rad: float = 0.0) -> np.ndarray:
        """Unwrapped fan angle in radians (+ = ccw) at times ``t``."""
        return start_rad + 2.0 * math.pi * self.turns_at(t)

    @property
    def max_abs_hz(self) -> float:
        return max(abs(s.signed_hz) for s in self.segments)

    def to_string(self) -> str:
        return ",".join(f"{s.direction}:{s.rate_hz:g}:{s.seconds:g}" for s in self.segments)


def direction_of(rate_hz: np.ndarray) -> np.ndarray:
    """'ccw', 'cw' or 'stopped' for each signed rate."""
    r = np.asarray(rate_hz)
    return np.where(r > 0, "ccw", np.where(r < 0, "cw", "stopped"))


def parse(spec: Any, *, key: str = "schedule", source: str | None = None) -> Schedule:
    """A schedule from ``"ccw:0.5:3,stop:0:2,cw:0.4:5"``, a list of such items, or a list of
    mappings ``{direction, rate_hz, seconds}``. Errors name ``key`` and the bad item."""
    if isinstance(spec, Schedule):
        return spec
    if isinstance(spec, str):
        items: Sequence[Any] = [s for s in spec.split(",") if s.strip()]
    elif isinstance(spec, (list, tuple)):
        items = spec
    else:
        raise ConfigError(key, spec, "must be DIR:RATE_HZ:SECONDS,... (DIR cw, ccw or stop), "
                          "e.g. ccw:0.5:3,stop:0:2,cw:0.4:5", source=source)
    if not items:
        raise ConfigError(key, spec, "must hold at least one segment, e.g. ccw:0.5:10",
                          source=source)
    segs = []
    for item in items:
        segs.append(_segment(item, key, source))
    return Schedule(tuple(segs))


def _segment(item: Any, key: str, source: str | None) -> Segment:
    fix = "write DIR:RATE_HZ:SECONDS with DIR cw, ccw or stop, e.g. cw:0.4:5 or stop:0:2"
    if isinstance(item, str):
        parts = [p.strip() for p in item.split(":")]
        if len(parts) != 3:
            raise ConfigError(key, item, fix, source=source)
        d, r, s = parts
    elif isinstance(item, dict):
        unknown = set(item) - {"direction", "rate_hz", "seconds"}
        if unknown:
            raise ConfigError(key, item, f"unknown field(s) {sorted(unknown)}; a segment has "
                              "direction, rate_hz and seconds", source=source)
        d, r, s = item.get("direction"), item.get("rate_hz", 0.0), item.get("seconds")
    elif isinstance(item, (list, tuple)) and len(item) == 3:
        d, r, s = item
    else:
        raise ConfigError(key, item, fix, source=source)
    d = str(d).strip().lower()
    if d == "stopped":
        d = "stop"
    if d not in DIRECTIONS:
        raise ConfigError(key, item, f"direction {d!r} is not cw, ccw or stop; {fix}",
                          source=source)
    try:
        rate, secs = float(r), float(s)
    except (TypeError, ValueError):
        raise ConfigError(key, item, f"rate and seconds must be numbers; {fix}",
                          source=source) from None
    if not math.isfinite(rate) or rate < 0:
        raise ConfigError(key, item, "rate must be a finite number >= 0 Hz (the direction "
                          "gives the sign)", source=source)
    if d == "stop" and rate != 0:
        raise ConfigError(key, item, "a stop segment must have rate 0, e.g. stop:0:2",
                          source=source)
    if not math.isfinite(secs) or secs <= 0:
        raise ConfigError(key, item, "seconds must be a finite number > 0", source=source)
    return Segment(d, rate, secs)
