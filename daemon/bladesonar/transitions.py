"""The running answer as a state machine: per-pulse decisions in, a state a subscriber can
trust and confirmed events out (pure, no I/O).

The decision of one window (:mod:`dsp.decide`) can flicker: a weak window is *unknown*, a
spin-down passes through rates too slow to tell a direction, a reversal through zero has
an instant at rest. Subscribers act on events, and a false event is worse than a late one,
so the state is a small machine with three known kinds, each entered only once its
evidence has held for a while:

* ``stopped``: the short motion meter has seen no change beyond noise over its window
  and for ``stop_confirm_s`` more (a fan reversed through zero passes slowly through
  rest, but not for that long). A fan seen slowing down steadily is not called stopped
  before it could have come back, if it were reversing through zero, to a rate the meter
  sees (``change_factor`` times the floor) at the same rate of change: a slow reversal
  (0.06 Hz/s) is below the meter's reach for about a second on each side of zero;
* ``turning`` one way or the other (``same`` / ``reversed`` relative to the reference):
  a confident track at or above ``rate_floor_hz`` for ``confirm_s``; a *new* direction
  (a start, a reversal) needs ``change_factor`` times the floor, since the end of a
  spin-down leaves slow, shaky tracks of either sign;
* everything else is ``unknown`` and leaves the last known state in place.

Events fire only on a change of the *known* state: ``started`` (stopped -> turning),
``stopped`` (turning -> stopped), ``reversed`` (turning one way -> the other, whatever
unknown stretch lay between, which is how a real fan reverses: through zero). The first
known state fires nothing. Both the daemon and ``analyze --track`` run this same code.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

from .dsp.decide import Decision


class Direction(str, enum.Enum):
    """Values of the answer's ``direction`` (relative to the reference's own)."""

    SAME = "same"
    REVERSED = "reversed"
    STOPPED = "stopped"
    UNKNOWN = "unknown"


#: Event kinds about the fan's motion (the daemon adds ``reference_missing``).
MOTION_EVENTS = ("started", "stopped", "reversed")


@dataclass(frozen=True)
class TransitionSettings:
    """Tuning of :class:`Transitions` (config ``tracking``)."""

    rate_floor_hz: float = 0.05
    confirm_s: float = 0.5
    stop_confirm_s: float = 0.75
    change_factor: float = 2.0
    #: longest wait (after the meter fell quiet) for a slowing fan to show a reversal,
    #: and the meter's own lag (s)
    reversal_guard_s: float = 2.0
    meter_lag_s: float = 0.5


@dataclass(frozen=True)
class Event:
    """A confirmed transition; ``t_s`` is the stream time of the pulse that confirmed it."""

    kind: str
    t_s: float
    pulse: int
    direction: str
    rotation: str | None
    rate_hz: float | None

    def details(self) -> dict:
        """The event's payload details (what MQTT subscribers get)."""
        return {"direction": self.direction, "rotation": self.rotation,
                "rate_hz": None if self.rate_hz is None or not math.isfinite(self.rate_hz)
                else round(float(self.rate_hz), 5)}


def _kind(direction: str) -> str | None:
    """The known kind of a direction: 'stopped', '+', '-', or None for unknown."""
    return {"stopped": "stopped", "same": "+", "reversed": "-"}.get(direction)


class Transitions:
    """Feed one decision per pulse to :meth:`step`; it returns the state to publish and
    the events confirmed by that pulse.

    Parameters
    ----------
    settings : TransitionSettings
    prf_hz : float
        Pulses per second (confirmation times are counted in pulses).
    """

    def __init__(self, settings: TransitionSettings, prf_hz: float) -> None:
        self.settings = settings
        self._confirm = max(int(round(settings.confirm_s * prf_hz)), 1)
        self._stop_confirm = max(int(round(settings.stop_confirm_s * prf_hz)), 1)
        self.known: str | None = None        # confirmed kind: 'stopped', '+', '-'
        self.known_decision: Decision | None = None
        self._cand: str | None = None
        self._cand_n = 0
        self._zero_by: float | None = None   # a slowing fan would pass zero by then (s)
        self._quiet_since = 0.0              # when the current candidate state began (s)
        self._slowing_hz_s = 0.0
        self.events: list[Event] = []        # all events so far (the caller may clear)

    @property
    def stopped(self) -> bool:
        """The confirmed state is stopped (the static-room estimate then holds still)."""
        return self.known == "stopped"

    def step(self, t_s: float, pulse: int, d: Decision, pulses: int = 1
             ) -> tuple[Decision, list[Event]]:
        """A decision in, standing for the last ``pulses`` pulses (the analysis decides
        every few pulses); (the state to publish, events confirmed now) out."""
        cand = _kind(d.direction)
        slow = self.settings.change_factor * self.settings.rate_floor_hz
        if cand in ("+", "-") and cand != self.known and not (d.rate_hz or 0.0) >= slow:
            # a new direction (a start, a reversal) is taken only from a rate clearly above
            # the floor: the end of a spin-down leaves slow, shaky tracks of either sign
            d = replace(d, direction=Direction.UNKNOWN.value, rotation=None,
                        reason=f"turning slowly ({d.rate_hz or 0.0:.3f} Hz < {slow:g} Hz "
                               f"needed for a new direction): {d.reason}")
            cand = None
        self._watch_slowing(t_s, d)
        if cand == self._cand:
            self._cand_n += pulses
        else:
            self._cand, self._cand_n = cand, pulses
            self._quiet_since = float(t_s)
        fired: list[Event] = []
        if cand is None:
            return d, fired
        need = self._stop_confirm if cand == "stopped" else self._confirm
        if cand != self.known:
            guard = self._reversal_guard(t_s) if cand == "stopped" else None
            if self._cand_n < need or guard is not None:
                what = "a stop" if cand == "stopped" else f"turning {d.direction}"
                why = (f"confirming {what} ({min(self._cand_n, need)} of {need} pulses)"
                       if guard is None else
                       f"confirming a stop: a fan slowing at {self._slowing_hz_s:.3f} Hz/s "
                       f"may be reversing through zero (until {guard:.1f} s)")
                return replace(d, direction=Direction.UNKNOWN.value, rotation=None,
                               confidence=min(d.confidence, 0.5),
                               reason=f"{why}: {d.reason}"), fired
            before = self.known
            self.known = cand
            if before is not None:
                kind = ("stopped" if cand == "stopped" else
                        "started" if before == "stopped" else "reversed")
                ev = Event(kind, float(t_s), int(pulse), d.direction, d.rotation,
                           None if cand == "stopped" else d.rate_hz)
                fired.append(ev)
                self.events.append(ev)
        self.known_decision = d
        return d, fired

    def _watch_slowing(self, t_s: float, d: Decision) -> None:
        """Remember when a fan seen slowing down steadily would reach zero. A turning
        answer well above that ramp's line (the fan held or regained its speed) forgets
        it; one on the line keeps it (near the floor the rate often reads 'settled')."""
        if _kind(d.direction) not in ("+", "-") or d.rate_hz is None or \
                not math.isfinite(d.rate_hz):
            return
        change = d.rate_change_hz_s
        if d.rate_state == "changing" and change is not None and change < 0:
            self._zero_by = float(t_s) + float(d.rate_hz) / -float(change)
            self._slowing_hz_s = -float(change)
        elif self._zero_by is not None:
            on_line = self._slowing_hz_s * max(self._zero_by - float(t_s), 0.0)
            if d.rate_hz > on_line + 0.05 + 0.2 * on_line:
                self._zero_by = None

    def _reversal_guard(self, t_s: float) -> float | None:
        """Until when a stop must wait for a slowing fan to show a reversal (None: no
        wait): the time it would take, after zero, to reach ``change_factor`` times the
        floor at its rate of change, plus the meter's lag, at most ``reversal_guard_s``."""
        st = self.settings
        if self._zero_by is None or self.known not in ("+", "-"):
            return None
        visible = st.change_factor * st.rate_floor_hz
        wait = min(visible / max(self._slowing_hz_s, 1e-9) + st.meter_lag_s,
                   st.reversal_guard_s)
        until = self._zero_by + wait
        # the rate of change is a noisy estimate and the zero time an extrapolation: the
        # wait never runs beyond reversal_guard_s after the meter fell quiet
        until = min(until, self._quiet_since + st.reversal_guard_s)
        return until if t_s < until else None
