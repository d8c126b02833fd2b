"""What a subscriber should have been told, from a schedule's truth, and how a run did
(pure).

Truth events of a schedule (the fan's signed rate over time):

* ``stopped`` when the fan comes to rest (rate exactly 0 for at least ``min_rest_s``, 2 s:
  the short motion window plus its confirmation cannot see a shorter rest)
  after turning;
* ``started`` when, after a rest, |rate| first reaches ``moving_hz``;
* ``reversed`` when the rate reaches ``moving_hz`` in the other direction without a
  rest in between (a reversal through zero).

A run's events are matched to these in order, kind by kind: a detected event within
``[t - early_s, t + late_s]`` of a truth event of its kind is a hit (its latency is
``t_detected - t``), and a start or a reversal from the moment it is true (the fan left
rest, the rate passed zero) if that is earlier; any other detected event is false, any
truth event without one is missed. Optional truth events (a change to a speed under
``moving_hz``: ``truth_events(low_hz=...)``) take a detection if one comes, and are
neither hits nor misses. Published states are scored pulse by pulse: right,
unknown or wrong, where stretches of transition (0 < |rate| < ``moving_hz``) count any
known answer that does not claim the wrong direction as right. All times here are the
schedule's: a run's stream times are converted with :func:`true_time` first.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, overload

import numpy as np

from ..answer import MOTION_EVENTS, WAYS, Direction, EventKind
from .schedule import Schedule

#: |rate| at which a fan counts as turning for the truth events (Hz).
MOVING_HZ = 0.15

#: What the fan was doing at a scored state: at rest; turning under MOVING_HZ (a
#: start, a stop or a reversal through zero); ramping at MOVING_HZ or more; steady.
SITUATIONS = ("at_rest", "slow", "ramping", "steady")


def situation(rate_hz: float, ramping: bool, moving_hz: float = MOVING_HZ) -> str:
    """Which of SITUATIONS a true rate (and whether it is changing) falls in."""
    if rate_hz == 0.0:
        return "at_rest"
    if abs(rate_hz) < moving_hz:
        return "slow"
    return "ramping" if ramping else "steady"


@overload
def true_time(stream_s: float, drift_ppm: float) -> float: ...
@overload
def true_time(stream_s: np.ndarray, drift_ppm: float) -> np.ndarray: ...
def true_time(stream_s: float | np.ndarray, drift_ppm: float) -> float | np.ndarray:
    """The schedule's (true) time of a moment given in capture-stream seconds (samples
    counted / the nominal rate). The simulator's capture clock runs fast by
    ``drift_ppm`` (sim/render.py: sample n is taken at n / (fs (1 + drift_ppm 1e-6))), so
    stream time runs ahead of the fan's: by 0.14 s after an hour at 40 ppm, which scored
    against the schedule at stream time reads on a 0.09 Hz/s ramp at 0.2 Hz as 6 % of
    rate error and adds as much to every event's latency."""
    return stream_s / (1.0 + drift_ppm * 1e-6)


@dataclass(frozen=True)
class TruthEvent:
    kind: str
    t_s: float
    sign: int            # +1 ccw, -1 cw, 0 for stopped
    #: from when the event is true (a start: the fan leaves rest; a reversal: the rate
    #: passes zero); None: only the matching window's early tolerance
    since_s: float | None = None
    #: a change to a speed between ``low_hz`` and ``moving_hz`` (truth_events): a detection
    #: of it is neither false nor timed, and missing it is not a miss
    optional: bool = False


def truth_events(schedule: Schedule, seconds: float, *, moving_hz: float = MOVING_HZ,
                 low_hz: float | None = None, min_rest_s: float = 2.0,
                 step_s: float = 0.005) -> list[TruthEvent]:
    """The events an ideal observer reports for ``schedule`` over ``[0, seconds]``.

    With ``low_hz`` (below ``moving_hz``: the product claims a new direction from twice
    its rate floor) the fan's direction is known from ``low_hz`` on: a start or a
    reversal to a speed that stays under ``moving_hz`` (a fan set to 0.12 Hz), and the
    stop that ends such a turn, are optional events; one that goes on to ``moving_hz`` is
    timed there as before."""
    low = moving_hz if low_hz is None else min(float(low_hz), moving_hz)
    t = np.arange(0.0, seconds, step_s)
    r = schedule.rate_at(t)
    out: list[TruthEvent] = []
    known: int | None = None          # +1 / -1 turning, 0 at rest
    rest_from: float | None = None
    moved = 0.0                       # the fan last left rest or passed zero (s)
    prev = 0.0
    pending: TruthEvent | None = None  # a change past low_hz, not yet at moving_hz
    reached = False                   # the turn since the last change reached moving_hz
    for ti, ri in zip(t, r, strict=True):
        if ri == 0.0:
            if pending is not None:
                out.append(pending)
                pending = None
            if rest_from is None:
                rest_from = float(ti)
            if known not in (None, 0) and ti - rest_from >= min_rest_s:
                out.append(TruthEvent(EventKind.STOPPED, rest_from, 0, optional=not reached))
                known = 0
            elif known is None and ti - rest_from >= min_rest_s:
                known = 0
            prev = 0.0
            continue
        if rest_from is not None or prev * ri < 0:
            moved = float(ti)
            if pending is not None and prev * ri < 0:
                out.append(pending)
                pending = None
        rest_from = None
        prev = float(ri)
        if abs(ri) >= low:
            s = 1 if ri > 0 else -1
            if known is not None and known != s:
                pending = TruthEvent(EventKind.STARTED if known == 0 else EventKind.REVERSED,
                                     float(ti), s,
                                     since_s=moved, optional=True)
                reached = False
            known = s
        if abs(ri) >= moving_hz:
            reached = True
            if pending is not None:
                out.append(TruthEvent(pending.kind, float(ti), pending.sign,
                                      since_s=pending.since_s))
                pending = None
    if pending is not None:
        out.append(pending)
    return out


@dataclass
class Score:
    """Events and states of one run against the truth."""

    truth: list[TruthEvent]
    hits: list[tuple[TruthEvent, float]] = field(default_factory=list)   # (truth, latency)
    false: list[tuple[str, float]] = field(default_factory=list)         # (kind, time)
    missed: list[TruthEvent] = field(default_factory=list)
    right: int = 0
    unknown: int = 0
    wrong: int = 0
    rate_errors: list[float] = field(default_factory=list)   # relative, while turning
    ramp_errors: list[float] = field(default_factory=list)   # the same, while ramping
    #: (start, seconds) of unknown stretches in the middle of a turn (score_gaps)
    gaps: list[tuple[float, float]] = field(default_factory=list)
    #: unknown states by what the fan was doing (SITUATIONS): where the unknown time goes
    unknown_by: dict[str, int] = field(default_factory=lambda: dict.fromkeys(SITUATIONS, 0))

    @property
    def states(self) -> int:
        return self.right + self.unknown + self.wrong

    def latencies(self, kind: str) -> list[float]:
        return [lat for ev, lat in self.hits if ev.kind == kind]

    def summary(self) -> dict[str, Any]:
        """JSON-able figures: counts, latency median/max per kind, state shares, rate
        error percentiles."""
        def stats(xs: Sequence[float]) -> dict[str, float] | None:
            return None if not xs else {"n": len(xs), "median": round(float(np.median(xs)), 2),
                                        "p95": round(float(np.percentile(xs, 95)), 2),
                                        "max": round(float(np.max(xs)), 2)}
        def pct(xs: Sequence[float]) -> dict[str, float] | None:
            return None if not len(xs) else {
                "median": round(float(np.median(xs)), 4),
                "p95": round(float(np.percentile(xs, 95)), 4), "n": int(len(xs))}
        n = max(self.states, 1)
        return {
            "truth_events": len(self.truth), "hits": len(self.hits),
            "false": len(self.false), "missed": len(self.missed),
            "false_detail": [(k, round(t, 2)) for k, t in self.false],
            "missed_detail": [(e.kind, round(e.t_s, 2)) for e in self.missed],
            "latency_s": {k.value: stats(self.latencies(k)) for k in MOTION_EVENTS},
            # the three slowest of each kind, (truth time, latency): where to trace
            "slowest": {k.value: [(round(ev.t_s, 2), round(lat, 2)) for ev, lat in
                            sorted(((e, x) for e, x in self.hits if e.kind == k),
                                   key=lambda h: -h[1])[:3]]
                        for k in MOTION_EVENTS},
            "state_share": {"right": round(self.right / n, 4),
                            "unknown": round(self.unknown / n, 4),
                            "wrong": round(self.wrong / n, 4)},
            "rate_error": pct(self.rate_errors),
            "ramp_rate_error": pct(self.ramp_errors),
            # shares of all states, summing to state_share's unknown
            "unknown_by_situation": {k: round(v / n, 4) for k, v in self.unknown_by.items()},
            "unknown_while_turning": {
                "n": len(self.gaps),
                "over_0_5_s": sum(1 for _, d in self.gaps if d > 0.5),
                "max_s": round(max((d for _, d in self.gaps), default=0.0), 2),
                "longest": [(round(t, 2), round(d, 2)) for t, d in
                            sorted(self.gaps, key=lambda g: -g[1])[:5]]},
        }


def merge(scores: Iterable[Score]) -> Score:
    """Several runs' scores as one (a sweep over scenes): events, states and errors
    pooled."""
    out = Score(truth=[])
    for sc in scores:
        out.truth += sc.truth
        out.hits += sc.hits
        out.false += sc.false
        out.missed += sc.missed
        out.right += sc.right
        out.unknown += sc.unknown
        out.wrong += sc.wrong
        out.rate_errors += sc.rate_errors
        out.ramp_errors += sc.ramp_errors
        out.gaps += sc.gaps
        for k, v in sc.unknown_by.items():
            out.unknown_by[k] += v
    return out


def score_events(truth: list[TruthEvent], detected: Iterable[tuple[str, float]], *,
                 early_s: float = 1.0, late_s: float = 6.0,
                 due_by: float | None = None) -> Score:
    """Match detected (kind, time) events to the truth, in time order. A detected event
    matches from ``early_s`` before its truth event, or from when it became true if that
    is earlier (a start as soon as the fan leaves rest, a reversal as soon as the rate
    passes zero: a slow spin-up takes seconds to reach the 0.15 Hz the latency is timed
    from, and a start called on the way is right), until ``late_s`` after. A truth event
    after ``due_by`` (the end of a run less the longest latency allowed) counts only if
    it was found: a rest that began 2.2 s before the end was not yet due."""
    sc = Score(truth=[ev for ev in truth if not ev.optional])
    pending = sorted(detected, key=lambda e: e[1])
    used = [False] * len(pending)
    for ev in sorted(truth, key=lambda e: e.t_s):
        first = ev.t_s - early_s
        if ev.since_s is not None:
            first = min(first, ev.since_s)
        for i, (kind, t) in enumerate(pending):
            if not used[i] and kind == ev.kind and first <= t <= ev.t_s + late_s:
                used[i] = True
                if not ev.optional:
                    sc.hits.append((ev, t - ev.t_s))
                break
        else:
            if not ev.optional:
                sc.missed.append(ev)
    if due_by is not None:
        found = {id(ev) for ev, _ in sc.hits}
        sc.truth = [ev for ev in sc.truth if ev.t_s <= due_by or id(ev) in found]
        sc.missed = [ev for ev in sc.missed if ev.t_s <= due_by]
    sc.false = [pending[i] for i in range(len(pending)) if not used[i]]
    return sc


def score_state(sc: Score, t_s: float, rate_hz: float, direction: str,
                rotation: str | None, est_rate_hz: float | None, *, ref_sign: int,
                moving_hz: float = MOVING_HZ, lag_s: float = 0.0,
                ramping: bool = False) -> None:
    """Add one published state at time ``t_s`` to ``sc``.

    ``rate_hz`` is the true signed rate (+ ccw); ``ref_sign`` the reference's own sign
    (+1 ccw, -1 cw), so that same/reversed can be turned into a signed claim.
    ``ramping``: the true rate is changing at ``t_s`` (its rate error also counts among
    the ramp errors). Rate errors count only states with the right direction (unknown
    and wrong states are counted as such).
    """
    claims: dict[str, int] = {Direction.SAME: ref_sign, Direction.REVERSED: -ref_sign,
                              Direction.STOPPED: 0}
    claim = claims.get(direction)
    if claim is None:
        sc.unknown += 1
        sc.unknown_by[situation(rate_hz, ramping, moving_hz)] += 1
        return
    true = 0 if rate_hz == 0.0 else (1 if rate_hz > 0 else -1)
    if abs(rate_hz) >= moving_hz or rate_hz == 0.0:
        ok = claim == true
    else:                                    # slow, in a transition
        ok = claim in (0, true)
    if ok:
        sc.right += 1
    else:
        sc.wrong += 1
    if ok and claim != 0 and abs(rate_hz) >= moving_hz and est_rate_hz is not None \
            and math.isfinite(est_rate_hz):
        e = abs(est_rate_hz - abs(rate_hz)) / abs(rate_hz)
        sc.rate_errors.append(e)
        if ramping:
            sc.ramp_errors.append(e)


def score_gaps(sc: Score, times: Sequence[float], directions: Sequence[str],
               true_rates: Sequence[float] | np.ndarray, *,
               moving_hz: float = MOVING_HZ) -> None:
    """Record in ``sc.gaps`` the stretches of ``unknown`` states in the middle of a turn:
    the fan turns at ``moving_hz`` or more throughout, and the states just before and
    just after give the same direction (a ramp through a rate near p/q blade period per
    pulse, a weak stretch of matches). A stretch lasts from its first unknown state to the
    next known one."""
    n = len(directions)
    i = 0
    while i < n:
        if directions[i] != Direction.UNKNOWN or i == 0:
            i += 1
            continue
        j = i
        while j < n and directions[j] == Direction.UNKNOWN:
            j += 1
        if j < n and directions[i - 1] == directions[j] \
                and directions[j] in WAYS \
                and min(abs(float(r)) for r in true_rates[i - 1:j + 1]) >= moving_hz:
            sc.gaps.append((float(times[i]), float(times[j]) - float(times[i])))
        i = j
