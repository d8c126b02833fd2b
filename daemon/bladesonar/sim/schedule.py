"""Rotation schedule: segments with optional linear ramps and a speed wobble; the angle is
the exact integral of the rate (pure).

Sign convention: positive rate = counter-clockwise in the scene's floor plan (x right,
y up, seen from above). A segment is (direction, rate_hz >= 0, seconds, ramp_s >= 0); the
last segment continues past its stated length to the end of the run, so ``"ccw:0.5:1"`` is
a constant 0.5 Hz for any duration.

Ramps: during the first ``ramp_s`` seconds of a segment (part of its ``seconds``) the
SIGNED rate changes linearly from the previous segment's signed rate to this one's (the
first segment ramps from rest, 0 Hz). A ramp from +r to -r passes through zero halfway (a
reversal through zero); a ramp into ``stop`` is a spin-down. Without a ramp the rate steps.

Wobble (optional, one per schedule): rate(t) = base(t) * (1 + A * sin(2*pi*t / T)), t in
seconds from the start of the run, 0 <= A < 0.5, so the wobble never changes the sign and
stopped stretches (base 0) stay exactly stopped.

Grammar (``parse``): comma-separated items, each ``DIR:RATE_HZ:SECONDS`` or
``DIR:RATE_HZ:SECONDS~RAMP_S`` (DIR cw, ccw or stop), plus at most one ``wobble:A:T``
anywhere, e.g. ``ccw:0.45:30,cw:0.45:20~10,stop:0:15~8,wobble:0.03:2``.

``turns_at`` is the closed-form integral of ``rate_at`` (piecewise quadratic base; the
wobble term integrates (b0 + b1 u) sin(w t) exactly), so speed changes, ramps and reversals
are exact at every pulse time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from ..errors import ConfigError

DIRECTIONS = ("cw", "ccw", "stop")
_SIGN = {"cw": -1.0, "ccw": 1.0, "stop": 0.0}
#: The wobble amplitude must stay below this (a fraction of the base rate).
MAX_WOBBLE = 0.5


@dataclass(frozen=True)
class Segment:
    """``seconds`` is the whole segment, ramp included; the ramp is its first ``ramp_s``."""

    direction: str
    rate_hz: float
    seconds: float
    ramp_s: float = 0.0

    @property
    def signed_hz(self) -> float:
        return _SIGN[self.direction] * self.rate_hz


@dataclass(frozen=True)
class Wobble:
    """Multiplicative speed wobble: factor 1 + amplitude * sin(2*pi*t / period_s)."""

    amplitude: float
    period_s: float

    @property
    def omega(self) -> float:
        """Angular frequency 2*pi / period_s in rad/s."""
        return 2.0 * math.pi / self.period_s

    def factor(self, t: np.ndarray) -> np.ndarray:
        return 1.0 + self.amplitude * np.sin(self.omega * np.asarray(t, dtype=np.float64))


@dataclass(frozen=True)
class Piece:
    """A stretch where the base (wobble-free) signed rate is linear: ``start_hz`` at
    ``start_s`` to ``end_hz`` at ``end_s``; constant if equal. The last piece has
    ``end_s`` = inf (the last segment continues)."""

    start_s: float
    end_s: float
    start_hz: float
    end_hz: float

    @property
    def is_ramp(self) -> bool:
        return self.start_hz != self.end_hz


@dataclass(frozen=True)
class Schedule:
    """Segments in order (plus an optional wobble); ``angle_at`` / ``rate_at`` /
    ``turns_at`` evaluate it at any times (vectorised, float64)."""

    segments: tuple[Segment, ...]
    wobble: Wobble | None = None

    @classmethod
    def constant(cls, rate_hz: float, direction: str = "ccw") -> Schedule:
        """One segment forever; ``rate_hz`` 0 means stopped."""
        return parse([(direction if rate_hz else "stop", rate_hz, 1.0)], key="--rate")

    @cached_property
    def pieces(self) -> tuple[Piece, ...]:
        """The base rate as linear pieces in time order (ramps and constant stretches;
        no zero-length pieces), the last one open-ended."""
        out: list[Piece] = []
        t, prev = 0.0, 0.0
        n = len(self.segments)
        for i, s in enumerate(self.segments):
            r, end = s.signed_hz, t + s.seconds
            a = t
            if s.ramp_s > 0 and t + s.ramp_s > t and prev != r:
                a = min(t + s.ramp_s, end)
                out.append(Piece(t, a, prev, r))
            if i == n - 1:
                out.append(Piece(a, math.inf, r, r))
            elif end > a:
                out.append(Piece(a, end, r, r))
            t, prev = end, r
        return tuple(out)

    @cached_property
    def _table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(piece start, start rate, slope, turns at piece start) as float64 arrays."""
        p = self.pieces
        a = np.array([x.start_s for x in p], dtype=np.float64)
        e = np.array([x.end_s for x in p], dtype=np.float64)
        r0 = np.array([x.start_hz for x in p], dtype=np.float64)
        r1 = np.array([x.end_hz for x in p], dtype=np.float64)
        slope = np.zeros_like(r0)
        ramp = r0 != r1
        slope[ramp] = (r1[ramp] - r0[ramp]) / (e[ramp] - a[ramp])
        full = self._piece_turns(a[:-1], r0[:-1], slope[:-1], e[:-1])
        turns0 = np.concatenate([[0.0], np.cumsum(full)])
        return a, r0, slope, turns0

    def _piece_turns(self, a: np.ndarray, r0: np.ndarray, b1: np.ndarray, t: np.ndarray
                     ) -> np.ndarray:
        """Integral from ``a`` to ``t`` of (r0 + b1 (tau - a)) * wobble factor, in turns."""
        u = t - a
        base: np.ndarray = r0 * u + 0.5 * b1 * u * u
        w = self.wobble
        if w is None or w.amplitude == 0:
            return base
        om = w.omega
        # A * integral_0^u (r0 + b1 s) sin(om (a + s)) ds, antiderivative
        # -(r0 + b1 s) cos(om (a+s))/om + b1 sin(om (a+s))/om^2; the cos/sin differences
        # written as products (exact to rounding also for tiny u)
        h = 0.5 * om * u
        m = 0.5 * om * (a + t)
        sh = np.sin(h)
        osc = (2.0 * r0 * np.sin(m) * sh / om - b1 * u * np.cos(om * t) / om
               + 2.0 * b1 * np.cos(m) * sh / (om * om))
        turns: np.ndarray = base + w.amplitude * osc
        return turns

    def _locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                              np.ndarray, np.ndarray]:
        a, r0, slope, turns0 = self._table
        i = np.clip(np.searchsorted(a, t, side="right") - 1, 0, len(a) - 1)
        # before t = 0 the rate holds its value at 0 (at rest if the first segment ramps)
        b1 = np.where(t < a[0], 0.0, slope[i])
        return i, a[i], r0[i], b1, turns0[i]

    def base_rate_at(self, t: np.ndarray) -> np.ndarray:
        """Signed rate without the wobble, Hz (+ = ccw); right-continuous at steps."""
        t = np.asarray(t, dtype=np.float64)
        _, a, r0, b1, _ = self._locate(t)
        rate: np.ndarray = r0 + b1 * (t - a)
        return rate

    def rate_at(self, t: np.ndarray) -> np.ndarray:
        """Signed instantaneous rate in Hz (+ = ccw) at times ``t`` (s), wobble included;
        continuous through ramps, right-continuous at steps (segments without a ramp)."""
        t = np.asarray(t, dtype=np.float64)
        base = self.base_rate_at(t)
        return base if self.wobble is None else base * self.wobble.factor(t)

    def turns_at(self, t: np.ndarray) -> np.ndarray:
        """Integral of ``rate_at`` from 0 to ``t``, in turns (exact closed form)."""
        t = np.asarray(t, dtype=np.float64)
        _, a, r0, b1, turns0 = self._locate(t)
        turns: np.ndarray = turns0 + self._piece_turns(a, r0, b1, t)
        return turns

    def angle_at(self, t: np.ndarray, start_rad: float = 0.0) -> np.ndarray:
        """Unwrapped fan angle in radians (+ = ccw) at times ``t``."""
        return start_rad + 2.0 * math.pi * self.turns_at(t)

    @property
    def max_abs_hz(self) -> float:
        """Largest |rate|: the fastest segment times (1 + wobble amplitude). The wobble peak
        is reached whenever the fastest constant stretch lasts a wobble period (always on
        the open-ended last segment); otherwise this is an upper bound."""
        top = max(abs(s.signed_hz) for s in self.segments)
        return top * (1.0 + (self.wobble.amplitude if self.wobble else 0.0))

    def to_string(self) -> str:
        """The ``parse`` form; segments without a ramp keep the plain DIR:RATE:SECONDS."""
        items = []
        for s in self.segments:
            item = f"{s.direction}:{_num(s.rate_hz)}:{_num(s.seconds)}"
            items.append(item + (f"~{_num(s.ramp_s)}" if s.ramp_s else ""))
        if self.wobble is not None:
            items.append(f"wobble:{_num(self.wobble.amplitude)}:{_num(self.wobble.period_s)}")
        return ",".join(items)


def _num(x: float) -> str:
    """Short form (``%g``) when it reads back exactly, else the exact repr."""
    s = f"{x:g}"
    return s if float(s) == x else repr(float(x))


def direction_of(rate_hz: np.ndarray) -> np.ndarray:
    """'ccw', 'cw' or 'stopped' for each signed rate."""
    r = np.asarray(rate_hz)
    return np.where(r > 0, "ccw", np.where(r < 0, "cw", "stopped"))


_GRAMMAR = ("DIR:RATE_HZ:SECONDS[~RAMP_S],... (DIR cw, ccw or stop) plus at most one "
            "wobble:A:PERIOD_S, e.g. ccw:0.45:30,cw:0.45:20~10,stop:0:15~8,wobble:0.03:2")


def parse(spec: Any, *, key: str = "schedule", source: str | None = None) -> Schedule:
    """A schedule from ``"ccw:0.5:3,stop:0:2~1,cw:0.4:5~2,wobble:0.03:2"``, a list of such
    items (or of tuples ``(dir, rate, seconds[, ramp_s])`` / ``("wobble", A, T)``), or a
    list of mappings ``{direction, rate_hz, seconds[, ramp_s]}`` / ``{wobble: A,
    period_s: T}``. Errors name ``key`` and the bad item."""
    if isinstance(spec, Schedule):
        return spec
    if isinstance(spec, str):
        items: Sequence[Any] = [s for s in spec.split(",") if s.strip()]
    elif isinstance(spec, (list, tuple)):
        items = spec
    else:
        raise ConfigError(key, spec, f"must be {_GRAMMAR}", source=source)
    segs: list[Segment] = []
    wobble: Wobble | None = None
    wobble_item: Any = None
    for item in items:
        if _is_wobble(item):
            w = _wobble(item, key, source)
            if wobble is not None:
                raise ConfigError(key, item, f"a schedule has at most one wobble item (already "
                                  f"{wobble_item!r}); keep one", source=source)
            wobble, wobble_item = w, item
        else:
            segs.append(_segment(item, key, source))
    if not segs:
        raise ConfigError(key, spec, "must hold at least one segment, e.g. ccw:0.5:10",
                          source=source)
    return Schedule(tuple(segs), wobble)


def _is_wobble(item: Any) -> bool:
    if isinstance(item, str):
        return item.split(":", 1)[0].strip().lower() == "wobble"
    if isinstance(item, dict):
        return "wobble" in item
    if isinstance(item, (list, tuple)) and item:
        return str(item[0]).strip().lower() == "wobble"
    return False


def _wobble(item: Any, key: str, source: str | None) -> Wobble:
    fix = ("write wobble:A:PERIOD_S with A a fraction 0 <= A < 0.5 and PERIOD_S > 0 "
           "seconds, e.g. wobble:0.03:2 (+-3 % every 2 s)")
    if isinstance(item, str):
        parts = [p.strip() for p in item.split(":")]
        if len(parts) != 3:
            raise ConfigError(key, item, fix, source=source)
        _, a, t = parts
    elif isinstance(item, dict):
        unknown = set(item) - {"wobble", "period_s"}
        if unknown or "period_s" not in item:
            raise ConfigError(key, item, "a wobble mapping is {wobble: A, period_s: T}, e.g. "
                              "{wobble: 0.03, period_s: 2}", source=source)
        a, t = item["wobble"], item["period_s"]
    elif len(item) == 3:
        _, a, t = item
    else:
        raise ConfigError(key, item, fix, source=source)
    try:
        amp, period = float(a), float(t)
    except (TypeError, ValueError):
        raise ConfigError(key, item, f"wobble amplitude and period must be numbers; {fix}",
                          source=source) from None
    if not math.isfinite(amp) or not 0.0 <= amp < MAX_WOBBLE:
        raise ConfigError(key, item, f"wobble amplitude {amp:g} is not a fraction in "
                          f"[0, {MAX_WOBBLE:g}); {fix}", source=source)
    if not math.isfinite(period) or period <= 0:
        raise ConfigError(key, item, f"wobble period {period:g} s must be finite and > 0; "
                          f"{fix}", source=source)
    return Wobble(amp, period)


def _segment(item: Any, key: str, source: str | None) -> Segment:  # noqa: C901  one check a field
    fix = ("write DIR:RATE_HZ:SECONDS[~RAMP_S] with DIR cw, ccw or stop, e.g. cw:0.4:5, "
           "stop:0:2 or cw:0.4:20~8 (ramp over the first 8 s)")
    ramp: Any = 0.0
    d: Any   # direction, rate and seconds as written: checked below
    r: Any
    s: Any
    if isinstance(item, str):
        main, sep, ramp_txt = item.partition("~")
        if sep:
            ramp = ramp_txt.strip()
        parts = [p.strip() for p in main.split(":")]
        if len(parts) != 3 or "~" in ramp_txt:
            raise ConfigError(key, item, fix, source=source)
        d, r, s = parts
    elif isinstance(item, dict):
        unknown = set(item) - {"direction", "rate_hz", "seconds", "ramp_s"}
        if unknown:
            raise ConfigError(key, item, f"unknown field(s) {sorted(unknown)}; a segment has "
                              "direction, rate_hz, seconds and optionally ramp_s",
                              source=source)
        d, r, s = item.get("direction"), item.get("rate_hz", 0.0), item.get("seconds")
        ramp = item.get("ramp_s", 0.0)
    elif isinstance(item, (list, tuple)) and len(item) in (3, 4):
        d, r, s = item[:3]
        if len(item) == 4:
            ramp = item[3]
    else:
        raise ConfigError(key, item, fix, source=source)
    d = str(d).strip().lower()
    if d == "stopped":
        d = "stop"
    if d not in DIRECTIONS:
        raise ConfigError(key, item, f"direction {d!r} is not cw, ccw or stop; {fix}",
                          source=source)
    try:
        rate, secs, ramp_s = float(r), float(s), float(ramp)
    except (TypeError, ValueError):
        raise ConfigError(key, item, f"rate, seconds and ramp must be numbers; {fix}",
                          source=source) from None
    if not math.isfinite(rate) or rate < 0:
        raise ConfigError(key, item, "rate must be a finite number >= 0 Hz (the direction "
                          "gives the sign)", source=source)
    if d == "stop" and rate != 0:
        raise ConfigError(key, item, "a stop segment must have rate 0, e.g. stop:0:2",
                          source=source)
    if not math.isfinite(secs) or secs <= 0:
        raise ConfigError(key, item, "seconds must be a finite number > 0", source=source)
    if not math.isfinite(ramp_s) or ramp_s < 0:
        raise ConfigError(key, item, f"ramp {ramp_s:g} s must be a finite number >= 0 "
                          "seconds (0 = step)", source=source)
    if ramp_s > secs:
        raise ConfigError(key, item, f"ramp {ramp_s:g} s is longer than the segment "
                          f"({secs:g} s); the ramp is the first part of the segment, so make "
                          f"SECONDS >= RAMP_S (e.g. {d}:{rate:g}:{ramp_s:g}~{ramp_s:g}) or "
                          "shorten the ramp", source=source)
    return Segment(d, rate, secs, ramp_s)


def ordinary_use(rng: np.random.Generator, seconds: float, *,
                 rates: tuple[float, float] = (0.2, 0.6),
                 first: tuple[str, float] = ("ccw", 0.45)) -> str:
    """A schedule of ordinary use (what tools/bench_day and tools/soak simulate): 60 s at
    ``first`` (0.45 Hz ccw), then segments of 20-120 s, each off (a spin-down of 5-12 s,
    longer from above 0.6 Hz: at most 0.12 Hz/s) or on at a speed drawn from ``rates``
    (0.2-0.6 Hz) in a random direction (a spin-up of 3-8 s from rest, a change or a
    reversal through zero, longer for a larger change: at most 0.15 Hz/s), until
    ``seconds``. Draws from ``rng`` in a fixed order, so a seed gives the same day."""
    lo, hi = rates
    if not 0.0 < lo <= hi:
        raise ValueError(f"rates must be 0 < lo <= hi Hz, got {rates!r}")
    segs, t = [f"{first[0]}:{first[1]:g}:60"], 60.0
    rate = first[1] * _SIGN[first[0]]
    while t < seconds:
        dur = float(rng.uniform(20, 120))
        if rate != 0 and rng.uniform() < 0.3:
            ramp = float(rng.uniform(5, 12)) * max(abs(rate) / 0.6, 1.0)
            rate = 0.0
            segs.append(f"stop:0:{max(dur, ramp + 1):.2f}~{ramp:.2f}")
        else:
            new = float(rng.uniform(lo, hi)) * (1 if rng.uniform() < 0.5 else -1)
            ramp = float(rng.uniform(3, 8)) * max(abs(new - rate) / 0.45, 0.5)
            rate = new
            segs.append(f"{'ccw' if new > 0 else 'cw'}:{abs(new):.3f}:"
                        f"{max(dur, ramp + 1):.2f}~{ramp:.2f}")
        t += dur
    return ",".join(segs)
