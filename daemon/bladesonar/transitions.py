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
  before it could have come back, if it were reversing through zero, to a rate that is
  seen again (``change_factor`` times the floor) at the same rate of change: a slow
  reversal (0.06 Hz/s) is out of the meter's and the track's reach for about two seconds
  on each side of zero. The rate of change is the slope of the recent answers at rates
  the track follows well (three times the floor and up): nearer rest the track lags and
  flattens, and an estimate from there put the zero seconds late. One answer of the old
  direction amid the stop's confirmation (a new lock on the fan at rest) is published
  as unknown and changes nothing unless the next decision says so too;
* ``turning`` one way or the other (``same`` / ``reversed`` relative to the reference):
  a confident track at or above ``rate_floor_hz`` for ``confirm_s``; a *new* direction
  (a start, a reversal) needs ``change_factor`` times the floor, since the end of a
  spin-down leaves slow, shaky tracks of either sign; so does the old direction once the
  line of a slowing fan has reached zero (new locks on the fan at rest). A reversal is
  not taken sooner than a fan could make it: from the old direction's last rate, down
  through zero and up to the rate of the new direction's first answer, at
  ``max_reversal_hz_s`` (the first: a track follows a fan speeding up, and its later
  rates would put the time further off), though for no more than ``reversal_hold_s`` of
  answers the other way. A track lost on a steadily turning fan and taken up again on
  the mirror of its blade pattern claims the other direction at once, at about the same
  rate; it had held for 0.5-0.6 s (a two-hour soak, a steady 0.21 Hz fan), and a lock at
  the end of a spin-down claimed 0.15 Hz the other way 0.1 s after 0.08 Hz the old way.
  The old direction's rate is bounded by the same physics from its earlier answers and
  from rest (a ``stopped`` answer): a new lock near zero once claimed the old direction
  at 0.26 Hz 0.15 s after the meter saw the fan at rest, and timed from that a true
  reversal waited 0.7 s more;
* ``turning`` with the direction in doubt (``Kind.TURNING``): where no direction is known, a
  decision that has the fan turning well above the floor but cannot tell which way
  (:attr:`Decision.turning`: a room whose echoes fit the fan's mirror image as well as
  the fan) is a known kind of its own, so a start and a stop still fire in such a room;
  a direction confirmed after it fires nothing (the fan did not change). Where a
  direction is known, such a decision is ``unknown``;
* a *sudden* reversal (its first answer sooner than half the time a fan needs through
  zero from when it was last seen turning: ``SUDDEN_SHARE``) is what a track taken up on
  the mirror of the blade pattern gives; it counts only on a line that has beaten its
  mirror image (:attr:`Decision.mirror_checked`), and not at all in a room whose
  directions have lately been in doubt (:attr:`Decision.doubtful_room`);
* everything else is ``unknown`` and leaves the last known state in place.

Events fire only on a change of the *known* state: ``started`` (stopped -> turning),
``stopped`` (turning -> stopped), ``reversed`` (turning one way -> the other, whatever
unknown stretch lay between, which is how a real fan reverses: through zero). The first
known state fires nothing. Both the daemon and ``analyze --track`` run this same code.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

from .answer import TURNING_KINDS, WAY_KINDS, Decision, Direction, EventKind, Kind, published


@dataclass(frozen=True)
class TransitionSettings:
    """Tuning of :class:`Transitions` (config ``tracking``)."""

    rate_floor_hz: float = 0.05
    confirm_s: float = 0.5
    stop_confirm_s: float = 0.75
    change_factor: float = 2.0
    #: longest wait, after the fan was last seen turning, for a slowing fan to show a
    #: reversal; the lag of the meter and the track in seeing it (s: a track needs its
    #: 24 matches, 0.7 s, once the blade is in view again, and 0.5 s to confirm; 0.5 s
    #: let two reversals at 0.08-0.09 Hz/s through a blind part of the blade period read
    #: as stop and start, 1.0 s one at 0.065 Hz/s whose slope the lagging answers put at
    #: 0.094 Hz/s; 1.3 s costs a coasting stop 0.3 s, up to 3.4 s after rest)
    reversal_guard_s: float = 3.0
    meter_lag_s: float = 1.3
    #: answers over this span (s) give the slowing fan's rate of change
    slope_span_s: float = 2.0
    #: the slowest spin-up a reversing fan makes on its way back from zero (Hz/s): a
    #: fan spins up over at most about 8 s to 0.4 Hz. A slow spin-down (a fan left to
    #: coast, 0.03 Hz/s) need not be waited for at its own slope on the way back: that
    #: held stops back 3.4 s after rest
    min_spinup_hz_s: float = 0.05
    #: the fastest a fan goes from one direction through zero to the other (Hz/s): twice
    #: the steepest ramp followed (tracking.max_ramp_hz_s); 0: no such wait
    max_reversal_hz_s: float = 0.3
    #: the longest that wait holds a new direction that keeps being answered (s): a
    #: mirror-line lock had held 0.5-0.6 s; a fan reversed with no ramp at all (which no
    #: real fan does, but a test bench might) is reversed for good
    reversal_hold_s: float = 1.0
    #: the most of a revolution a blade can turn out of view (half a blade period: the
    #: reference's table is flat over about that much of it, docs/dynamics.md): a fan
    #: last seen turning slower than it could have been braked to zero (at
    #: ``max_reversal_hz_s``) within that turn may have reversed unseen
    blind_turn_rev: float = 0.125
    #: how long (s) the answers up to that last one must have followed the fan without a
    #: break for it to count: new locks on a fan already at rest claimed the old
    #: direction for 0.1-0.4 s after a stretch of unknown, and a wait from them held
    #: two stops to 3.4-3.55 s after rest (a simulated four-hour day)
    followed_s: float = 1.0


@dataclass(frozen=True)
class Event:
    """A confirmed transition; ``t_s`` is the stream time of the pulse that confirmed it."""

    kind: EventKind
    t_s: float
    pulse: int
    direction: Direction
    rotation: str | None
    rate_hz: float | None

    def details(self) -> dict[str, Any]:
        """The event's payload details (what MQTT subscribers get)."""
        return {"direction": self.direction.value, "rotation": self.rotation,
                "rate_hz": published("rate_hz", self.rate_hz)}


#: Share of the time a fan needs to reverse (through zero at ``max_reversal_hz_s``, itself
#: twice the steepest ramp followed) under which an answer the other way is sudden
#: (:meth:`Transitions._sudden_reversal`): a track taken up on the mirror of the blade
#: pattern claims the other way within a few tenths of a second at the old speed, a
#: real reversal comes at least twice that time later, but a spurious lock of the old
#: direction after zero (0.2 Hz, 1.3 s before the new direction's first answer at 0.19
#: Hz) can shift the chain by most of it.
SUDDEN_SHARE = 0.5
#: How close (a share of it) an answer with no direction must come to the speed the fan
#: was last seen turning at to show that it still turns (:meth:`Transitions.step`): a
#: fan slowing to reverse changes speed by less within the few tenths of a second
#: between answers, while tracks on alias lines read other speeds altogether.
CHAIN_AGREE = 0.25


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
        self.known: Kind | None = None       # the confirmed kind
        self.known_decision: Decision | None = None
        self._cand: Kind | None = None       # the last known kind answered
        self._prev_kind: Kind | None = None  # the kind the previous decision answered
        self._support: deque[tuple[int, int]] = deque()   # (pulse, pulses) for _cand
        self._cand_n = 0
        self._cand_rate = 0.0                # |rate| of the candidate's first answer (Hz)
        self._cand_t = 0.0                   # and its time (s)
        self._cand_sudden = False            # a reversal whose first answer came too soon
        self._chain: tuple[float, float] | None = None   # (t, rate) last seen turning on
        self._zero_by: float | None = None   # a slowing fan would pass zero by then (s)
        self._slowing_hz_s = 0.0
        self._seen: deque[tuple[float, float]] = deque()   # (t, rate) turning, well above
        self._seen_kind: Kind | None = None
        self._last_turning = -math.inf       # the last turning answer (s)
        self._last_turning_hz = 0.0          # and its |rate| (Hz)
        self._run_from = -math.inf           # the start of its unbroken run of answers (s)
        self._known_seen: tuple[float, float] | None = None   # (t, rate), known direction
        self.events: list[Event] = []        # all events so far (the caller may clear)

    def step(self, t_s: float, pulse: int, d: Decision, pulses: int = 1
             ) -> tuple[Decision, list[Event]]:
        """A decision in, standing for the last ``pulses`` pulses (the analysis decides
        every few pulses); (the state to publish, events confirmed now) out."""
        cand = Kind.of(d.direction)
        if cand is None and d.turning and self.known not in WAY_KINDS:
            cand = Kind.TURNING
        slow = self.settings.change_factor * self.settings.rate_floor_hz
        if cand in TURNING_KINDS and (cand != self.known or self._past_zero(t_s, cand)) \
                and not (d.rate_hz or 0.0) >= slow:
            # a new direction (a start, a reversal) is taken only from a rate clearly above
            # the floor: the end of a spin-down leaves slow, shaky tracks of either sign.
            # So is the old one once its slowing line has passed zero: the fan has come
            # to rest, and a new lock on it claimed 0.07-0.09 Hz the old way 1.3 s later
            d = replace(d, direction=Direction.UNKNOWN, rotation=None, turning=False,
                        reason=f"turning slowly ({d.rate_hz or 0.0:.3f} Hz < {slow:g} Hz "
                               f"needed for a new direction"
                               f"{'' if cand != self.known else ' or after a spin-down'}"
                               f"): {d.reason}")
            cand = None
        prev, self._prev_kind = self._prev_kind, cand
        if cand in TURNING_KINDS and prev != cand:
            self._run_from = float(t_s)      # a new run of answers of this direction
        if cand in TURNING_KINDS and cand == self.known and self._cand == Kind.STOPPED \
                and prev != cand:
            # one answer of the old direction amid a stop's confirmation counts only once
            # the next decision says so too: new locks on a fan at rest claimed 0.12-0.13
            # Hz for one decision, twice, and each restarted the confirmation and renewed
            # the fan's last turning (a stop 3.4 s after rest in a simulated hour)
            return replace(d, direction=Direction.UNKNOWN, rotation=None,
                           confidence=min(d.confidence, 0.5), turning=False,
                           reason=f"a lone answer {d.direction} amid a stop's "
                                  f"confirmation: {d.reason}"), []
        if cand is None and d.turning and d.doubtful_room and self.known in WAY_KINDS \
                and _rate(d) >= slow:
            # in a room whose echoes turned either way fit alike, a window in doubt about
            # the direction still shows the fan turning at its rate: it has not passed
            # through zero since (the chain that a reversal must break)
            self._see_known(t_s, _rate(d))
            self._chain = self._known_seen
        elif cand is None and self.known in WAY_KINDS and self._chain is not None \
                and _rate(d) >= slow \
                and abs(_rate(d) - self._chain[1]) <= CHAIN_AGREE * self._chain[1]:
            # a window too weak for a direction that still sees the fan at the speed it
            # had: no reversal through zero lies between (a track on the mirror line at
            # 0.33-0.38 Hz with weak evidence for 10 s, then one confident answer the
            # other way: a false reversal in a room at 7 dB)
            self._chain = (float(t_s), _rate(d))
        self._watch_slowing(t_s, d, cand)
        if cand in TURNING_KINDS and (cand == self.known or self.known not in WAY_KINDS):
            # only the known direction renews the cap of the wait for a reversal: a new
            # lock on a fan at rest claiming the other way for 0.2 s held a stop to 3.2 s
            if not (self._below_floor(t_s, cand)
                    and t_s - self._run_from < self.settings.followed_s):
                # nor, once the slowing line is below the floor, does a new run of it
                # until it has lasted followed_s: new locks on a fan just at rest
                # claimed the old way at 0.097 Hz for 0.2 s and at 0.11-0.125 Hz for
                # 0.6 s, and held stops to 3.05 and 3.4 s after rest (simulated
                # four-hour days). Answers that followed the fan down do renew it:
                # refused below twice the floor once the line was below the floor, they
                # cut the wait short, and a reversal at 0.08 Hz/s read as a stop and a
                # start
                self._last_turning, self._last_turning_hz = float(t_s), _rate(d)
        if cand in TURNING_KINDS:
            if cand == self.known:
                self._see_known(t_s, _rate(d))
                self._chain = self._known_seen  # (bounded from rest like it)
        elif cand == Kind.STOPPED and self.known in TURNING_KINDS:
            self._see_known(t_s, 0.0)
            self._chain = None              # seen at rest: a reversal may follow
        if cand is not None and cand != self._cand:
            self._cand = cand
            self._support.clear()
            self._cand_rate, self._cand_t = _rate(d), float(t_s)
            self._cand_sudden = self._sudden_reversal(t_s, self._cand_rate, cand)
        elif cand is not None and prev != cand and self._cand_sudden \
                and self.known in WAY_KINDS and self._past_zero(t_s, self.known):
            # the run resumes after a break, and the old way was last seen slowing on a
            # line that has reached zero since: judged afresh, or a lock on the mirror
            # image before a real reversal's zero would hold the real one to the mirror
            # check (a reversal at 0.15 Hz/s confirmed 1.5 s later than without the early
            # lock). A fan not seen slowing to zero keeps the verdict (false reversals in
            # a room at 7 dB when any resumed run was judged afresh)
            self._cand_sudden = self._sudden_reversal(t_s, _rate(d), cand)
        fired: list[Event] = []
        if cand is None:
            return d, fired
        need = self._stop_confirm if cand == Kind.STOPPED else self._confirm
        # pulses for the candidate within twice its confirmation time: an unknown answer
        # between them (a weak window, an alias check's doubt) pauses the count instead
        # of restarting it; an answer of another kind restarts it
        self._support.append((int(pulse), int(pulses)))
        while self._support and self._support[0][0] <= int(pulse) - 2 * need:
            self._support.popleft()
        self._cand_n = sum(n for _, n in self._support)
        if self._cand_sudden and cand != self.known and (d.doubtful_room
                                                         or not d.mirror_checked):
            # the other way at once, at a speed no fan reaches so soon through zero: the
            # mirror image of the blade pattern, unless the new line has beaten its mirror
            # (in a room where directions are in doubt not even then); its answers count
            # for its confirmation all the same, which the check, once passed, completes
            return replace(d, direction=Direction.UNKNOWN, rotation=None,
                           confidence=min(d.confidence, 0.5), turning=False,
                           reason=f"turning {d.direction} at once after the other way, "
                                  f"sooner than a fan reverses, on a line not shown to "
                                  f"beat its mirror image: {d.reason}"), fired
        if cand != self.known:
            guard = self._reversal_guard(t_s) \
                if cand == Kind.STOPPED and not d.seen_still else None
            soonest = self._soonest_reversal(t_s, self._cand_rate) \
                if cand != Kind.STOPPED else None
            if soonest is not None and t_s >= soonest:
                soonest = None
            if self._cand_n < need or guard is not None or soonest is not None:
                what = ("a stop" if cand == Kind.STOPPED else "turning, direction in doubt"
                        if cand == Kind.TURNING else f"turning {d.direction}")
                if guard is not None:
                    how = (f"slowing at {self._slowing_hz_s:.3f} Hz/s"
                           if self._line_zero(t_s) is not None else
                           f"last seen at {self._last_turning_hz:.3f} Hz")
                    why = (f"confirming a stop: a fan {how} may be reversing through zero "
                           f"(until {guard:.1f} s)")
                elif soonest is not None and self._known_seen is not None:
                    zeroed = self.known is not None and self._past_zero(t_s, self.known)
                    why = (f"confirming {what}: {t_s - self._known_seen[0]:.2f} s after "
                           f"{self._known_seen[1]:.3f} Hz the other way"
                           f"{', slowing to zero,' if zeroed else ''} is sooner than a "
                           f"fan reverses (until {soonest:.1f} s)")
                else:
                    why = f"confirming {what} ({min(self._cand_n, need)} of {need} pulses)"
                return replace(d, direction=Direction.UNKNOWN, rotation=None,
                               confidence=min(d.confidence, 0.5), turning=False,
                               reason=f"{why}: {d.reason}"), fired
            before = self.known
            self.known = cand
            self._known_seen = (float(t_s), _rate(d)) if cand != Kind.STOPPED else None
            if before is not None and not (before == Kind.TURNING and cand in WAY_KINDS):
                # (a direction found for a fan already known to turn is no event)
                kind = (EventKind.STOPPED if cand == Kind.STOPPED else
                        EventKind.STARTED if before == Kind.STOPPED else EventKind.REVERSED)
                ev = Event(kind, float(t_s), int(pulse), d.direction, d.rotation,
                           None if cand == Kind.STOPPED else d.rate_hz)
                fired.append(ev)
                self.events.append(ev)
        self.known_decision = d
        return d, fired

    def _line_rate(self, t_s: float, kind: Kind) -> float | None:
        """The rate (Hz) at ``t_s`` of the line on which answers of ``kind`` were last
        seen slowing (below zero once it has passed zero); None without such a line."""
        if self._seen_kind != kind or self._zero_by is None:
            return None
        return self._slowing_hz_s * (self._zero_by - float(t_s))

    def _past_zero(self, t_s: float, kind: Kind) -> bool:
        """Whether answers of ``kind`` were last seen slowing on a line that has reached
        zero by ``t_s``."""
        rate = self._line_rate(t_s, kind)
        return rate is not None and rate < 0.0

    def _below_floor(self, t_s: float, kind: Kind) -> bool:
        """Whether answers of ``kind`` were last seen slowing on a line that is below the
        floor by ``t_s``."""
        rate = self._line_rate(t_s, kind)
        return rate is not None and rate < self.settings.rate_floor_hz

    def _see_known(self, t_s: float, rate: float) -> None:
        """Note an answer of the known direction at ``rate`` (0: at rest), bounded by
        how fast the fan could have sped up since the last one."""
        st = self.settings
        if self._known_seen is not None and st.max_reversal_hz_s > 0:
            t0, r0 = self._known_seen
            rate = min(rate, r0 + st.max_reversal_hz_s * max(float(t_s) - t0, 0.0))
        self._known_seen = (float(t_s), rate)

    def _sudden_reversal(self, t_s: float, rate: float, cand: Kind) -> bool:
        """Whether an answer of ``cand`` at ``rate`` (Hz), the other way from the known
        direction, comes within ``SUDDEN_SHARE`` of the time a fan needs to reverse (down
        through zero and up at ``max_reversal_hz_s``) from when it was last seen turning
        (``_chain``: answers of the known way, answers without a direction at its speed,
        windows in doubt in a doubtful room), with no answer of rest between (the meter
        lags: a fan reversed at 0.12 Hz/s read as at rest 0.5 s after it was turning the
        other way at 0.16 Hz). A fan that really reverses is driven through zero at a
        ramp; answers that jump to the other way at about the old speed are a track taken
        up on the mirror of the blade pattern (false reversals at 0.19-0.74 Hz in random
        rooms, the same speed either side)."""
        st = self.settings
        if self.known not in WAY_KINDS or cand not in WAY_KINDS or cand == self.known \
                or self._chain is None or not st.max_reversal_hz_s > 0:
            return False
        t, old = self._chain
        return float(t_s) < t + SUDDEN_SHARE * (old + rate) / st.max_reversal_hz_s

    def _soonest_reversal(self, t_s: float, rate: float) -> float | None:
        """When a fan last seen turning the known way could be seen turning the other
        way at ``rate``, but no later than ``reversal_hold_s`` after the other way was
        first answered (None: no known direction, or no limit). A slowing line of the
        known way that has reached zero by ``t_s`` puts the fan at zero no sooner than
        its zero: the last answer of the old way may lie a second or more before it, at
        a rate near the floor (0.057 Hz 1.2 s before new locks on a fan just at rest
        claimed 0.32-0.35 Hz the other way, 0.4 s after the line's zero: a false
        'reversed' in a simulated day). A zero still ahead is not used: answers after a
        stretch at rest join the line of those before it, and put its zero seconds off."""
        st = self.settings
        if self.known not in WAY_KINDS or self._known_seen is None \
                or not st.max_reversal_hz_s > 0:
            return None
        t, old = self._known_seen
        soonest = t + (old + rate) / st.max_reversal_hz_s
        if self._past_zero(t_s, self.known) and self._zero_by is not None:
            soonest = max(soonest, self._zero_by + rate / st.max_reversal_hz_s)
        return min(soonest, self._cand_t + st.reversal_hold_s)

    def _watch_slowing(self, t_s: float, d: Decision, kind: Kind | None) -> None:
        """Remember when a fan seen slowing down steadily would reach zero: the line of
        the recent answers at rates the track follows well (three times the floor and
        up), extrapolated; such answers that no longer fall (the fan held or regained its
        speed) forget it. Slower answers change nothing: there the track lags and
        flattens (it read 0.13 Hz for a second while the fan went from 0.08 Hz to 0.04);
        nor do answers the other way before that way is confirmed."""
        if kind not in TURNING_KINDS or d.rate_hz is None or not math.isfinite(d.rate_hz):
            return
        if self.known in WAY_KINDS and kind != self.known:
            # the other way, not confirmed yet: a sign that the fan may be reversing, not
            # a reason to forget its slowing (one early answer the other way dropped the
            # wait, and a reversal at 0.11 Hz/s read as a stop and a start)
            return
        t, rate = float(t_s), float(d.rate_hz)
        if kind != self._seen_kind:
            self._seen.clear()
            self._seen_kind, self._zero_by = kind, None
        if rate >= 3.0 * self.settings.rate_floor_hz:
            self._seen.append((t, rate))
            while self._seen and self._seen[0][0] < t - self.settings.slope_span_s:
                self._seen.popleft()
            slope = _slope(self._seen, min_span_s=0.5 * self.settings.slope_span_s)
            if slope is not None and slope < -0.01:
                self._slowing_hz_s = -slope
                self._zero_by = t + rate / -slope
            else:
                self._zero_by = None

    def _line_zero(self, t_s: float) -> float | None:
        """When the slowing line reaches zero, if that can explain a fan at rest by
        ``t_s``; None without a line, or for one that reaches zero more than
        ``reversal_guard_s`` from now (an abrupt stop whose last answers sagged as the
        track broke up: 0.016 Hz/s from 0.45 Hz held a stop back by 2.7 s)."""
        z = self._zero_by
        return z if z is not None and z <= t_s + self.settings.reversal_guard_s else None

    def _reversal_guard(self, t_s: float) -> float | None:
        """Until when a stop must wait for a slowing fan to show a reversal (None: no
        wait): the time it would take, after zero, to reach the rate a new direction
        needs (``change_factor`` times the floor) at its rate of change (or
        ``min_spinup_hz_s`` if that is faster: a reversing fan is driven back up), plus
        the lag of a track locking on it, but never beyond
        ``reversal_guard_s`` after the fan was last seen turning (a stop is due within
        3 s of rest, and the slope is an estimate), and not at all for a line that
        reaches zero more than ``reversal_guard_s`` from now. The fan was last seen
        turning when the known direction was last answered: answers the other way not
        yet confirmed neither end the wait nor renew its cap, and nor does a new run of
        the known direction once the line is below the floor, until it has lasted
        ``followed_s`` (:meth:`step`).

        A fan whose slowing was not seen at all (its answers ended before they gave a
        slope: 0.2 Hz reversed at 0.12 Hz/s left 0.4 s of them above three times the
        floor), or whose line reaches zero only well after now, is waited for as if it
        were braked as hard as a fan can be, provided that it could have come to zero
        within ``blind_turn_rev`` of a turn, i.e. out of view (a reversal whose turn lay
        in the blind part of the blade period had read as a stop and a start in a
        simulated hour), and that its answers followed it without a break for
        ``followed_s`` up to the last one. A faster fan would have been seen slowing, so
        its sudden quiet is a stop (an abrupt one) and is not held."""
        st = self.settings
        if self.known not in TURNING_KINDS:
            return None
        zero_by, slowing = self._line_zero(t_s), self._slowing_hz_s
        if zero_by is None:
            # no slowing line that explains a rest now; but a fan last answered slowly
            # enough may have reached zero and turned round out of view: the answers
            # that gave the line lag a brisk slowing (a 0.23 Hz fan reversed at 0.08
            # Hz/s was answered down to 0.05 Hz while the line of those above 0.15 Hz
            # put zero 6 s off)
            r, brake = self._last_turning_hz, st.max_reversal_hz_s
            if not (brake > 0 and r * r < 2.0 * brake * st.blind_turn_rev) \
                    or self._last_turning - self._run_from < st.followed_s:
                return None
            zero_by, slowing = self._last_turning + r / brake, 0.0
        visible = st.change_factor * st.rate_floor_hz
        comeback = max(slowing, st.min_spinup_hz_s)
        until = zero_by + visible / comeback + st.meter_lag_s
        until = min(until, self._last_turning + st.reversal_guard_s)
        return until if t_s < until else None


def _rate(d: Decision) -> float:
    """The decision's |rate| (Hz), 0 when it has none."""
    r = d.rate_hz
    return abs(float(r)) if r is not None and math.isfinite(r) else 0.0


def _slope(points: deque[tuple[float, float]], *, min_span_s: float) -> float | None:
    """Least-squares slope of (t, rate) points (Hz/s); None over less than
    ``min_span_s`` or fewer than four points."""
    if len(points) < 4:
        return None
    t = [p[0] for p in points]
    if t[-1] - t[0] < min_span_s:
        return None
    n = float(len(points))
    mt = sum(t) / n
    mr = sum(p[1] for p in points) / n
    stt = sum((ti - mt) ** 2 for ti in t)
    if not stt > 0:
        return None
    return sum((ti - mt) * (p[1] - mr) for ti, p in zip(t, points, strict=True)) / stt
