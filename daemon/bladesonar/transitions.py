"""The running answer as a state machine: per-window decisions in, a state a subscriber
can trust and confirmed events out (pure, no I/O).

A window's decision (:mod:`dsp.decide`) can flicker: a weak window is *unknown*, a
spin-down passes through rates too slow to tell a direction, a reversal through zero has
an instant at rest. Subscribers act on events, and a false event is worse than a late one,
so the machine's state is the confirmed :class:`answer.Kind` (``same`` / ``reversed``
relative to the reference, ``turning`` with the direction in doubt, ``stopped``; None
before anything is known), and a decision of another kind changes it only once no hold
rule applies. :meth:`Transitions.step` is the rules in their order:

1. ``SLOW_NEW_DIRECTION``: a new direction, or the old one after its slowing line reached
   zero, needs ``change_factor`` times the floor (the decision is published as unknown
   and the rules go on with it);
2. ``LONE_ANSWER``: one answer of the old direction amid a stop's confirmation waits for
   the next;
3. ``MIRROR_IMAGE``: the other way at once, at about the old speed, is the mirror of the
   blade pattern unless its line has beaten its mirror image (so is the other way sooner
   than a fan reverses at all, after a direction never shown to beat its mirror);
4. ``REVERSAL_UNDER_WAY``: a stop waits while a fan seen slowing could be reversing
   through zero;
5. ``TOO_SOON``: a reversal waits until a fan could have made it, and until the short
   meter could have seen a fan read near zero come to rest;
6. ``CONFIRMING``: a new kind needs ``confirm_s`` (a stop ``stop_confirm_s``) of answers.

A decision in doubt only about the direction at the speed the known direction was last
answered at, or held by rule 3 as the sudden mirror image of a known direction that beat
its own, is then published as that direction (:meth:`carry`, called on the state
after the analysis has taken its feedback from it: the carry changes what is published,
not what the analysis learns): a fan cannot reverse without passing through zero, which
ends the carry.

Before the rules, a window in doubt only about the direction on a tracked line that
read the known direction with the other sign, once the known way's slowing line has
reached zero, is answered the other way (:meth:`_through_zero`: a track's rate changes
sign only through zero). Between rules 2 and 3 the machine notes what the decision
shows of the fan (the chain of answers at its speed, the slowing line, when it was last
seen turning, the candidate), which the later rules read. Why each rule is there, with
the cases and figures behind it: docs/dynamics.md, "Why each rule is there".

Events fire only on a change of the *known* state: ``started`` (stopped -> turning),
``stopped`` (turning -> stopped), ``reversed`` (turning one way -> the other, whatever
unknown stretch lay between, which is how a real fan reverses: through zero). The first
known state fires nothing, nor does a direction found for a fan known to turn, nor a
*correction*: a run the other way held by rule 3 whose line has beaten its mirror image,
after a direction that never had, replaces a direction that was the mirror's. Both the
daemon and ``analyze --track`` run this same code.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Hashable
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
    #: reversal (s): a stop is due within 3 s of rest, and the slope is an estimate
    reversal_guard_s: float = 3.0
    #: the lag of the meter and the track in seeing a reversed fan (s): a track needs its
    #: 24 matches, 0.7 s, once the blade is in view again, and 0.5 s to confirm; and of
    #: the short meter in seeing a fan that crept to rest (0.9-1.2 s of its 1.5 s window;
    #: a new direction after a slow reading waits the whole window, ``still_window_s``)
    meter_lag_s: float = 1.3
    #: answers over this span (s) give the slowing fan's rate of change
    slope_span_s: float = 2.0
    #: the slowest spin-up a reversing fan makes on its way back from zero (Hz/s): a
    #: fan spins up over at most about 8 s to 0.4 Hz, so a fan left to coast is not
    #: waited for at its own slope on the way back
    min_spinup_hz_s: float = 0.05
    #: the short meter's window (s, tuning.STILL_WINDOW_S): a fan that crept to rest reads
    #: as motion until the window holds nothing but the rest
    still_window_s: float = 1.5
    #: the fastest a fan goes from one direction through zero to the other (Hz/s): twice
    #: the steepest ramp followed (tracking.max_ramp_hz_s); 0: no such wait
    max_reversal_hz_s: float = 0.3
    #: the longest that wait holds a new direction that keeps being answered (s): longer
    #: than a mirror-line lock lasts; a fan reversed with no ramp at all (which no real
    #: fan does, but a test bench might) is reversed for good
    reversal_hold_s: float = 1.0
    #: the most of a revolution a blade can turn out of view (half a blade period: the
    #: reference's table is flat over about that much of it, docs/dynamics.md): a fan
    #: last seen turning slower than it could have been braked to zero (at
    #: ``max_reversal_hz_s``) within that turn may have reversed unseen
    blind_turn_rev: float = 0.125
    #: how long (s) the answers up to that last one must have followed the fan without a
    #: break for it to count: new locks on a fan already at rest claim the old direction
    #: briefly after a stretch of unknown
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


class Hold(enum.StrEnum):
    """The rule of :meth:`Transitions.step` that published a decision as unknown, in the
    order the rules are tried (docs/dynamics.md, "Why each rule is there")."""

    SLOW_NEW_DIRECTION = "slow_new_direction"
    LONE_ANSWER = "lone_answer"
    MIRROR_IMAGE = "mirror_image"
    REVERSAL_UNDER_WAY = "reversal_under_way"
    TOO_SOON = "too_soon"
    CONFIRMING = "confirming"


@dataclass(frozen=True)
class Held:
    """A hold rule's verdict: the rule, and why in words (the published reason's head)."""

    rule: Hold
    why: str

    def apply(self, d: Decision) -> Decision:
        """``d`` published as unknown for this reason: no direction, not turning, its
        confidence at most 0.5 (a slow new direction keeps its confidence: it is the
        decision itself, not the machine, that is in doubt)."""
        cap = d.confidence if self.rule is Hold.SLOW_NEW_DIRECTION else min(d.confidence,
                                                                             0.5)
        return replace(d, direction=Direction.UNKNOWN, rotation=None, confidence=cap,
                       turning=False, reason=f"{self.why}: {d.reason}")


@dataclass(frozen=True)
class MachineState:
    """What the machine holds, as words: the confirmed kind, the kind answered last (the
    candidate whose evidence is being counted) and the rule that held the last decision
    (None: it was published as it came, or had nothing to hold)."""

    known: Kind | None
    candidate: Kind | None
    hold: Hold | None


#: Share of the time a fan needs to reverse (through zero at ``max_reversal_hz_s``) under
#: which an answer the other way is sudden (:meth:`Transitions._sudden_reversal`): a track
#: on the mirror of the blade pattern claims the other way within a few tenths of a second
#: at the old speed, a real reversal comes at least twice that time later, but a spurious
#: lock of the old direction after zero can shift the chain by most of it.
SUDDEN_SHARE = 0.5


def _sudden_span(old_hz: float, new_hz: float, max_hz_s: float,
                 share: float = SUDDEN_SHARE) -> float:
    """Seconds within which a fan at ``old_hz`` seen at ``new_hz`` the other way is
    sudden: ``share`` of the time down through zero and up at ``max_hz_s``."""
    return share * (old_hz + new_hz) / max_hz_s
#: How close (a share of it) an answer with no direction must come to the speed the fan
#: was last seen turning at to show that it still turns (:meth:`Transitions._keep_chain`):
#: a fan slowing to reverse changes speed by less within the few tenths of a second
#: between answers, while tracks on alias lines read other speeds altogether.
CHAIN_AGREE = 0.25
#: Decisions in a row under the band (``CHAIN_AGREE``) that end a carry (:meth:`carry`):
#: a follower on a noisy room's matches dips under it for a decision or two while the
#: fan turns steadily (spent held-out 4500006: a steady 0.64 Hz fan read 0.54 Hz once,
#: the carry ended, and the direction stayed `unknown` for 175 s); a fan slowing to
#: reverse stays under it.
CARRY_DIP = 3


class Transitions:
    """Feed one decision per window to :meth:`step`; it returns the state to publish and
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
        #: the rate a new direction needs (Hz)
        self._visible_hz = settings.change_factor * settings.rate_floor_hz
        self.known: Kind | None = None       # the confirmed kind
        self.known_decision: Decision | None = None
        self.hold: Hold | None = None        # the rule that held the last decision
        self._cand: Kind | None = None       # the last known kind answered
        self._prev_kind: Kind | None = None  # the kind the previous decision answered
        self._support: deque[tuple[int, int]] = deque()   # (pulse, pulses) for _cand
        self._cand_n = 0
        self._cand_rate = 0.0                # |rate| of the candidate's first answer (Hz)
        self._cand_t = 0.0                   # and its time (s)
        self._cand_sudden = False            # a reversal whose first answer came too soon
        self._cand_impossible = False        # sooner than a fan reverses at all
        self._chain: tuple[float, float] | None = None   # (t, rate) last seen turning on
        #: (t, rate) of the chain's last answer as its track last saw the fan (a clear
        #: match): a coasting track's answers repeat that moment (Decision.unseen_s)
        self._chain_seen: tuple[float, float] | None = None
        self._zero_by: float | None = None   # a slowing fan would pass zero by then (s)
        self._slowing_hz_s = 0.0
        self._seen: deque[tuple[float, float]] = deque()   # (t, rate) turning, well above
        self._seen_kind: Kind | None = None
        self._last_turning = -math.inf       # the last turning answer (s)
        self._last_turning_hz = 0.0          # and its |rate| (Hz)
        self._run_from = -math.inf           # the start of its unbroken run of answers (s)
        self._known_seen: tuple[float, float] | None = None   # (t, rate), known direction
        self._way_answered: tuple[float, float] | None = None   # (t, rate) of its last
                                             # answer itself (windows in doubt not counted)
        self._known_checked = False          # an answer of the known direction was on a
                                             # line that beat its mirror image
        self._rest_since_known = False       # rest answered after the known direction's
                                             # last answer (the chain ended there)
        self._carry_from: float | None = None   # the rate (Hz) the known direction
                                             # was last answered at (carry)
        self._carry_seen = -math.inf         # the last answered or carried window (s)
        self._carried: tuple[float, float] | None = None   # the last carried window (s, Hz)
        #: (t, rate) of the known direction's recent answers: the band's lower edge is
        #: the slowest of them (carry)
        self._carry_answers: deque[tuple[float, float]] = deque()
        self._carry_kind: Kind | None = None   # the direction they answered
        self._carry_dip = 0                  # carried windows in a row under the band
        self._read_slow_t = -math.inf        # the last window that read the fan slower
                                             # than the floor (s)
        self._quiet = False                  # the short meter reads no change now
        self._in_doubt = False               # the last step's decision had no kind
        self._mirror_held = False            # or was held as the mirror image of a known
                                             # direction shown to beat its own (carry)
        self._answered = False               # no rule held the last step's answer
        self._carry_line: Hashable | None = None   # the tracked line of the last answered
                                             # or carried window (carry)
        #: (line, sign, kind): the sign of the relative rate a tracked line read while it
        #: was answered or carried as ``kind`` (:meth:`_through_zero`)
        self._tie: tuple[Hashable, float, Kind] | None = None
        self._flipped = False                # the last step's decision was answered the
                                             # other way by :meth:`_through_zero`
        self.events: list[Event] = []        # all events so far (the caller may clear)

    @property
    def state(self) -> MachineState:
        """The machine's state in words."""
        return MachineState(self.known, self._cand, self.hold)

    def step(self, t_s: float, pulse: int, d: Decision, pulses: int = 1,
             quiet: bool = False, line: Hashable | None = None
             ) -> tuple[Decision, list[Event]]:
        """A decision in, standing for the last ``pulses`` pulses (the analysis decides
        every few pulses), ``quiet`` if the short meter read no change beyond noise for
        it, ``line`` the tracked line it was read on (as :meth:`carry` takes it); (the
        state to publish, events confirmed now) out. The hold rules in their order, with
        what the decision shows of the fan noted between."""
        self.hold = None
        self._quiet = quiet
        self._in_doubt = self._mirror_held = self._answered = False
        d = self._through_zero(t_s, d, line)
        cand = self._candidate(d)
        held = self._slow_new_direction(t_s, d, cand)
        if held is not None:
            d, cand = self._held(d, held), None     # the rules go on with an unknown
        prev, self._prev_kind = self._prev_kind, cand
        if cand in TURNING_KINDS and prev != cand:
            self._run_from = float(t_s)      # a new run of answers of this direction
        held = self._lone_answer(d, cand, prev)
        if held is not None:
            return self._held(d, held), []
        # (a track standing still on a moving fan, Decision.standing_alias, is no sign of
        # a fan near zero: spent held-out 4800004's mirror locks were judged afresh so)
        if cand is None and d.rate_hz is not None and d.rate_hz < self.settings.rate_floor_hz \
                and not d.standing_alias:
            self._read_slow_t = float(t_s)
        self._keep_chain(t_s, d, cand)
        self._watch_slowing(t_s, d, cand)
        self._note_last_turning(t_s, d, cand)
        self._note_known(t_s, d, cand)
        self._note_candidate(t_s, d, cand, prev)
        if cand is None:
            self._in_doubt = True
            return d, []
        self._count_support(cand, pulse, pulses)
        for rule in (self._mirror_image, self._reversal_under_way, self._too_soon,
                     self._confirming):
            held = rule(t_s, d, cand)
            if held is not None:
                if held.rule is Hold.MIRROR_IMAGE and self._cand_sudden \
                        and self._known_checked:
                    self._mirror_held = True    # (the known way may be carried)
                else:
                    self._carry_from = None
                return self._held(d, held), []
        d, fired = self._confirm_kind(t_s, pulse, d, cand)
        self.known_decision = d
        self._carry_from = _rate(d) if cand in WAY_KINDS else None
        self._note_answered(t_s, cand)
        self._carry_seen = float(t_s)
        self._answered = True
        return d, fired

    def _note_answered(self, t_s: float, cand: Kind) -> None:
        """Keep the known direction's answers within ``SUDDEN_SHARE`` of the time a fan
        at their speed needs to reverse: the fan cannot have reversed between them, so
        the slowest is as much its speed as the last, and a follower's excursion above
        it for a few decisions does not make the fan's return to it a slowing (spent
        held-out 4900018: a steady 0.305 Hz fan answered at 0.38-0.415 Hz for 0.5 s;
        back at 0.29-0.30 Hz in doubt it counted as slowing, the carry ended and the
        direction stayed `unknown` for 14 s)."""
        answers, rate = self._carry_answers, self._carry_from
        if rate is None or not self.settings.max_reversal_hz_s > 0:
            answers.clear()
            return
        if answers and self._carry_kind != cand:
            answers.clear()
        self._carry_kind = cand
        t = float(t_s)
        answers.append((t, rate))
        span = _sudden_span(rate, rate, self.settings.max_reversal_hz_s)
        while answers[0][0] < t - span:
            answers.popleft()

    def _carry_low(self, answered: float) -> float:
        """The band's lower edge: the slowest recent answer (:meth:`_note_answered`)."""
        return min([answered] + [r for _, r in self._carry_answers])

    def carry(self, t_s: float, d: Decision, line: Hashable | None = None) -> Decision:
        """A decision in doubt only about the direction (``turning``: a confident track
        whose mirror image or an alias rate fits as well, in a room whose echoes turned
        either way are alike) at the speed the known direction was last answered at
        (within ``CHAIN_AGREE`` of it, its lower edge the slowest answer of the moments
        just before, :meth:`_note_answered`: the band is the answers', not the last
        carried decision's, so tracks cannot walk the rate away in steps) is published as that
        direction (a window under the band too, unless ``CARRY_DIP`` in a row are:
        a noisy follower's dip is no slowing). A fan turns the other way only through
        zero, braked and driven at
        ``max_reversal_hz_s`` at most: from the answered speed down and up again to the
        window's takes ``(answered + rate) / max_reversal_hz_s``, and the carry ends when
        ``SUDDEN_SHARE`` of that time has passed since the last answered or carried
        window (the share under which :meth:`step` holds a reversal as sudden, so the
        two rules agree on what a fan can do). What the fan shows on the way down ends
        it too: confident tracks under the band, ``CARRY_DIP`` in a row (a fan slowing),
        one under the rate a new direction needs, or an answer of rest (in
        :meth:`step`). Windows with no track,
        weak tracks and tracks above the band (an alias line) are not carried and do not
        end it: a weak track may hold a stale line while the fan slows beneath it, which
        the time bound covers, and alias lines come and go. Above the band, the tracked
        ``line`` (:attr:`tracking.Tracker.identity`, which changes with every new lock and
        every move to another line) tells a ramp up from an alias: the line of the last
        answered or carried window, followed without a break, is the fan speeding up the
        same way (it could turn the other way only through the floor, which ends the
        carry), and the band moves up with it (never down: a slowing fan ends it). A
        confirmed rest is carried too, through windows with no line at all (no track:
        nothing is seen turning) and windows whose line reads the fan slower than the
        floor (no direction is claimed there, so no start is shown). A window that rule
        3 held as the sudden mirror image of a known direction answered on a line that
        beat its own mirror is carried like a window in doubt: the fan cannot have
        reversed, and the way it was answered is the checked one."""
        st = self.settings
        if self._answered:
            self._carry_line, self._carry_dip = line, 0
            if not self._flipped:
                self._tie_line(line, d, Kind.of(d.direction))
        if self._in_doubt and self.known == Kind.STOPPED and self.known_decision is not None:
            k = self.known_decision
            if line is None and d.rate_hz is None:
                # a confirmed rest with no line at all: nothing is seen turning (a small
                # hard-walled reverberant room's resting fan reads as motion on the
                # meter, and its state flipped between stopped and unknown: spent
                # 2200016)
                return replace(k, reason=f"stopped kept: no line since the fan was seen "
                                         f"at rest; {d.reason}")
            if d.rate_hz is not None and abs(d.rate_hz) < st.rate_floor_hz:
                # a line slower than the floor: no direction to claim, nor a start
                return replace(k, reason=f"stopped kept: turning slower than the floor "
                                         f"({abs(d.rate_hz):.3f} Hz < "
                                         f"{st.rate_floor_hz:.3g} Hz); {d.reason}")
        if not (self._in_doubt or self._mirror_held) or self._carry_from is None \
                or self.known not in WAY_KINDS or not st.max_reversal_hz_s > 0:
            return d
        t, answered = float(t_s), self._carry_from
        rate = abs(d.rate_hz) if d.rate_hz is not None and math.isfinite(d.rate_hz) \
            else None
        turning = d.turning or self._mirror_held
        under = rate is not None and turning \
            and rate < (1.0 - CHAIN_AGREE) * self._carry_low(answered)
        self._carry_dip = self._carry_dip + 1 if under else 0
        if rate is not None and (rate < self._visible_hz or self._carry_dip >= CARRY_DIP):
            self._carry_from = None
            return d
        if rate is None or not turning:
            return d
        same_line = line is not None and line == self._carry_line
        if rate > (1.0 + CHAIN_AGREE) * answered and not same_line:
            return d
        if t - self._carry_seen > _sudden_span(answered, rate, st.max_reversal_hz_s):
            self._carry_from = None
            return d
        self._tie_line(line, d, self.known)
        self._carry_seen, self._carry_line = t, line
        self._carried = (t, rate)
        if self._mirror_held and not self._below_floor(t, self.known):
            # published as the known way turning at its speed: the fan was seen turning
            # (spent held-out 6000020: a slow reversal's last windows before zero were
            # mirror images carried as the old way; the wait for the reversal, capped
            # from the old way's last answer before them, ended 0.1 s before the fan
            # showed the new way, and a stop and a start were published); not once the
            # slowing line is below the floor: a lock on a fan come to rest would hold
            # its stop (as answers of the old way do, :meth:`_note_last_turning`)
            self._last_turning, self._last_turning_hz = t, rate
        if same_line and rate > answered:
            self._carry_from = rate
            self._carry_answers.clear()     # (the band rides the line up, all of it)
        way = Direction.SAME if self.known == Kind.SAME else Direction.REVERSED
        known = self.known_decision
        rotation = known.rotation if known is not None and known.direction == way else None
        rel = d.relative_rate
        if rel is not None and math.isfinite(rel):
            rel = abs(rel) if way == Direction.SAME else -abs(rel)
        how = ("the other way at once at this speed is the mirror image of the blade "
               "pattern" if self._mirror_held else "the fan has turned at this speed "
               "without a break since it was last answered " + str(way))
        return replace(d, direction=way, rotation=rotation, relative_rate=rel, turning=True,
                       reason=f"{way} carried: {how}; {d.reason}")

    def _tie_line(self, line: Hashable | None, d: Decision, kind: Kind | None) -> None:
        """Note the sign of the relative rate that ``line`` reads while the fan turns
        ``kind`` (an answered or carried window's)."""
        rel = d.relative_rate
        if line is not None and kind in WAY_KINDS and rel is not None \
                and math.isfinite(rel) and rel != 0.0:
            self._tie = (line, math.copysign(1.0, rel), kind)

    def _through_zero(self, t_s: float, d: Decision, line: Hashable | None) -> Decision:
        """A window in doubt only about the direction (its mirror image fits as well) on
        a line that read the known direction with the other sign, after the known way's
        slowing line reached zero: answered the other way. A track follows the fan's
        phase without a break (its line changes with every new lock and every move to
        another line), so its relative rate changes sign only through zero, whichever of
        the line and its mirror it is on; the fan has reversed. (Spent held-out 7400011,
        a 4-blade fan 3.8 m away whose directions were in doubt: a track carried as the
        known way at 0.23 Hz followed the fan down through zero and up the other way to
        0.44 Hz; the direction stayed `unknown`, to be confirmed, for 9.6 s, and the
        reversal came 10 s late.)"""
        self._flipped = False
        tie = self._tie
        if tie is None or line is None or line != tie[0] or self.known != tie[2] \
                or d.direction != Direction.UNKNOWN or not (d.turning and d.direction_doubt):
            return d
        rel = d.relative_rate
        if rel is None or not math.isfinite(rel) or math.copysign(1.0, rel) == tie[1] \
                or _rate(d) < self._visible_hz or self._line_zero(t_s) is None:
            return d
        self._flipped = True
        way = Direction.REVERSED if tie[2] == Kind.SAME else Direction.SAME
        known = self.known_decision
        rotation = None
        if known is not None and known.rotation in ("cw", "ccw"):
            rotation = "ccw" if known.rotation == "cw" else "cw"
        return replace(d, direction=way, rotation=rotation,
                       relative_rate=abs(rel) if way == Direction.SAME else -abs(rel),
                       reason=f"{way}: its line, {tie[2]} before, has followed the fan "
                              f"through zero; {d.reason}")

    # -- the hold rules: each returns why it holds the decision, or None ------------------

    def _slow_new_direction(self, t_s: float, d: Decision, cand: Kind | None
                            ) -> Held | None:
        """A new direction (a start, a reversal) is taken only from a rate clearly above
        the floor, since the end of a spin-down leaves slow, shaky tracks of either sign;
        so is the old one once its slowing line has passed zero (new locks on the fan
        at rest)."""
        if cand not in TURNING_KINDS or (cand == self.known
                                         and not self._past_zero(t_s, cand)) \
                or (d.rate_hz or 0.0) >= self._visible_hz:
            return None
        return Held(Hold.SLOW_NEW_DIRECTION,
                    f"turning slowly ({d.rate_hz or 0.0:.3f} Hz < {self._visible_hz:g} Hz "
                    f"needed for a new direction"
                    f"{'' if cand != self.known else ' or after a spin-down'})")

    def _lone_answer(self, d: Decision, cand: Kind | None, prev: Kind | None
                     ) -> Held | None:
        """One answer of the old direction amid a stop's confirmation counts only once
        the next decision says so too: a new lock on a fan at rest claims the old way
        for one decision, and would restart the confirmation and renew the fan's last
        turning."""
        if cand in TURNING_KINDS and cand == self.known and self._cand == Kind.STOPPED \
                and prev != cand:
            return Held(Hold.LONE_ANSWER,
                        f"a lone answer {d.direction} amid a stop's confirmation")
        return None

    def _mirror_image(self, t_s: float, d: Decision, cand: Kind) -> Held | None:
        """The other way at once, at a speed no fan reaches so soon through zero: the
        mirror image of the blade pattern, unless the new line has beaten its mirror
        (in a room where directions are in doubt not even then). Its answers count for
        its confirmation all the same, which the check, once passed, completes. The
        other way later, but still sooner than a fan reverses at all, after a direction
        never seen on a line that beat its mirror: one of the two is the mirror's, and
        the new line waits for its check too (outside doubtful rooms, where a check
        says nothing); passed, it corrects the direction (:meth:`_corrects`)."""
        if cand == self.known or d.mirror_checked and not d.doubtful_room:
            return None
        if self._cand_sudden:
            return Held(Hold.MIRROR_IMAGE,
                        f"turning {d.direction} at once after the other way, sooner than a "
                        f"fan reverses, on a line not shown to beat its mirror image")
        if self._cand_impossible and not self._known_checked and not d.doubtful_room:
            return Held(Hold.MIRROR_IMAGE,
                        f"turning {d.direction} sooner than a fan reverses after the other "
                        f"way, neither line shown to beat its mirror image")
        return None

    def _reversal_under_way(self, t_s: float, d: Decision, cand: Kind) -> Held | None:
        """A stop waits while a fan seen slowing down could be reversing through zero
        (:meth:`_reversal_guard`), unless the blade is seen standing still."""
        if cand == self.known or cand != Kind.STOPPED or d.seen_still:
            return None
        guard = self._reversal_guard(t_s)
        if guard is None:
            return None
        how = (f"slowing at {self._slowing_hz_s:.3f} Hz/s"
               if self._line_zero(t_s) is not None else
               f"last seen at {self._last_turning_hz:.3f} Hz")
        return Held(Hold.REVERSAL_UNDER_WAY,
                    f"confirming a stop: a fan {how} may be reversing through zero "
                    f"(until {guard:.1f} s)")

    def _too_soon(self, t_s: float, d: Decision, cand: Kind) -> Held | None:
        """A new direction waits until a fan could have made the reversal
        (:meth:`_soonest_reversal`)."""
        if cand == self.known or cand == Kind.STOPPED:
            return None
        soonest = self._soonest_reversal(t_s, self._cand_rate)
        if soonest is None or self._known_seen is None:
            return None
        if t_s >= soonest:
            if self._quiet and self.near_zero_since_known:
                # the wait for a rest to show has ended, and the meter shows it: a new
                # way answered now is a lock on a fan at rest (spent held-out 6600017: a
                # lock at 0.11 Hz the other way, claimed 1.5 s after the fan stopped
                # while the meter had read rest for 0.2 s, a false reversal and a stop
                # 4.7 s late)
                return Held(Hold.TOO_SOON,
                            f"confirming {_what(d, cand)}: "
                            f"{t_s - self._read_slow_t:.2f} s after the fan read slower "
                            f"than the floor, no change between pulses beyond noise")
            return None
        if soonest <= self._rest_unseen_until():
            return Held(Hold.TOO_SOON,
                        f"confirming {_what(d, cand)}: {t_s - self._read_slow_t:.2f} s after "
                        f"the fan read slower than the floor, a fan coming to rest still "
                        f"reads as motion (until {soonest:.1f} s)")
        zeroed = self._line_zero_times(t_s)
        return Held(Hold.TOO_SOON,
                    f"confirming {_what(d, cand)}: {t_s - self._known_seen[0]:.2f} s after "
                    f"{self._known_seen[1]:.3f} Hz the other way"
                    f"{', slowing to zero,' if zeroed else ''} is sooner than a "
                    f"fan reverses (until {soonest:.1f} s)")

    def _confirming(self, t_s: float, d: Decision, cand: Kind) -> Held | None:
        """A new kind needs its confirmation time of answers (:meth:`_count_support`)."""
        need = self._need(cand)
        if cand == self.known or self._cand_n >= need:
            return None
        return Held(Hold.CONFIRMING,
                    f"confirming {_what(d, cand)} ({min(self._cand_n, need)} of {need} "
                    f"pulses)")

    def _held(self, d: Decision, held: Held) -> Decision:
        self.hold = held.rule
        return held.apply(d)

    # -- what a decision shows of the fan, noted for the rules ----------------------------

    def _candidate(self, d: Decision) -> Kind | None:
        """The kind ``d`` answers; a decision that has the fan turning but cannot tell
        which way is ``turning`` only where no direction is known."""
        cand = Kind.of(d.direction)
        if cand is None and d.turning and self.known not in WAY_KINDS:
            cand = Kind.TURNING
        return cand

    def _keep_chain(self, t_s: float, d: Decision, cand: Kind | None) -> None:
        """Answers with no direction that still see the fan turning at its speed extend
        the chain a reversal through zero must break (:meth:`_sudden_reversal`): in a
        doubtful room a window in doubt about the direction at any clear rate, elsewhere
        one within ``CHAIN_AGREE`` of the chain's speed. Not after the fan was seen near
        zero since the known way's last answer: rest answered (in a doubtful room) or a
        window read slower than the floor; either way it may have passed zero, and the
        answers after it may be the other way (spent held-out 5400006 and 5400008: each
        held a reversal as sudden for 8-11 s so)."""
        if cand is not None or self.known not in WAY_KINDS:
            return
        if d.turning and d.doubtful_room and _rate(d) >= self._visible_hz:
            if not self._rest_since_known and self._kept_its_way(t_s, _rate(d)):
                self._see_known(t_s, _rate(d))
                self._chain = self._known_seen
                self._note_seen(t_s, d)
        elif self._chain is not None and _rate(d) >= self._visible_hz \
                and abs(_rate(d) - self._chain[1]) <= CHAIN_AGREE * self._chain[1] \
                and not self._read_slow_since_chain():
            self._chain = (float(t_s), _rate(d))
            self._note_seen(t_s, d)

    def _note_seen(self, t_s: float, d: Decision) -> None:
        """The chain's answer ``d`` as its track last saw the fan: ``unseen_s`` before
        ``t_s`` (kept if an earlier answer's is later)."""
        t = float(t_s) - d.unseen_s
        if self._chain_seen is None or t > self._chain_seen[0]:
            self._chain_seen = (t, _rate(d))

    def _kept_its_way(self, t_s: float, rate: float) -> bool:
        """Whether a window in doubt at ``rate`` (Hz) shows the fan last seen on the
        chain still turning the known way: it comes so soon that the other way at that
        speed would be sudden (:meth:`_sudden_reversal`'s share of the time through zero
        at ``max_reversal_hz_s``), at a speed the fan can have reached the known way. One
        later could be either way (a doubtful room's reversal through zero: 0.16 Hz 1.4 s
        after 0.08 Hz, then an alias line at 0.71 Hz, held the new way's answers for 15 s
        as sudden). Nor, at a speed more than ``CHAIN_AGREE`` off the known way's last
        answer itself, once a fan could have reversed since that answer: each window
        renews the chain the next is judged against."""
        vmax = self.settings.max_reversal_hz_s
        if self._chain is None or not vmax > 0:
            return True
        t, old = self._chain
        if self._way_answered is not None:
            # at another speed than the known way's last answer itself, no later than a
            # fan could have reversed since: windows in doubt renew the chain they are
            # judged against, and a reversed fan speeding up in a room in doubt for
            # many seconds (each window a little faster than the last) held its new
            # direction for 15 s as sudden
            t_w, old_w = self._way_answered
            if abs(rate - old_w) > CHAIN_AGREE * old_w \
                    and float(t_s) >= t_w + _sudden_span(old_w, rate, vmax, 1.0):
                return False
        return float(t_s) < t + _sudden_span(old, rate, vmax) \
            and abs(rate - old) <= vmax * max(float(t_s) - t, 0.0) + 1e-9

    def _note_last_turning(self, t_s: float, d: Decision, cand: Kind | None) -> None:
        """When the fan was last seen turning, which caps the wait for a reversal: only
        the known direction renews it (or any way where none is known; :meth:`carry`
        renews it with the windows the mirror hold publishes as the known way), and
        once the slowing line is below the floor, a new run of it only after
        ``followed_s``; answers that followed the fan down do renew it."""
        if cand in TURNING_KINDS and (cand == self.known or self.known not in WAY_KINDS):
            if not (self._below_floor(t_s, cand)
                    and t_s - self._run_from < self.settings.followed_s):
                self._last_turning, self._last_turning_hz = float(t_s), _rate(d)

    def _note_known(self, t_s: float, d: Decision, cand: Kind | None) -> None:
        """An answer of the known direction, or of rest, is where the fan was last seen
        (the chain starts afresh from it; seen at rest, a reversal may follow)."""
        if cand in TURNING_KINDS:
            if cand == self.known:
                self._known_checked = self._known_checked or d.mirror_checked
                if self._new_lock_after_zero(t_s, cand) or self._new_lock_faster(t_s, d):
                    return
                self._see_known(t_s, _rate(d))
                self._chain = self._known_seen  # (bounded from rest like it)
                self._note_seen(t_s, d)
                self._way_answered = self._known_seen
                self._rest_since_known = False
        elif cand == Kind.STOPPED and self.known in TURNING_KINDS:
            self._see_known(t_s, 0.0)
            self._chain = self._way_answered = self._chain_seen = None
            self._rest_since_known = True

    def _new_lock_after_zero(self, t_s: float, kind: Kind) -> bool:
        """Whether an answer of the known ``kind`` belongs to a run not yet followed for
        ``followed_s`` that began after the fan was seen at or near zero: its slowing
        line below the floor, or its last answer under the rate a new direction needs
        and a window since read slower than the floor, or rest answered since its last
        answer (a stop not yet confirmed). Such a run is a new lock on a fan that may be
        reversing (the old way's pattern fits a slow fan either way for a few tenths of
        a second); it neither renews the chain nor the speed the fan was last seen at,
        so the other way's first answers are judged against the fan's way down (or its
        rest), not against it. After a confirmed stop there is no known direction to
        guard: a start's answers make the chain."""
        if t_s - self._run_from >= self.settings.followed_s:
            return False
        if self._chain is None:
            return self._rest_since_known
        return self._below_floor(t_s, kind) or self._read_slow_once_reachable()

    def _new_lock_faster(self, t_s: float, d: Decision) -> bool:
        """Whether an answer of the known direction belongs to a run not yet followed for
        ``followed_s`` at a speed more than ``CHAIN_AGREE`` above the chain's: a lock
        taken up after a break at another speed is an alias line as often as the fan
        sped up (:meth:`carry` keeps such lines out of its band too). Like a new lock
        after zero it renews neither the chain nor the speed the fan was last seen at;
        followed for ``followed_s``, or at the speed of a window carried as the known way
        before its run, it is the fan's. (Spent held-out 6900009: a 3-blade
        fan at 0.19 Hz reversed to 0.13 Hz; past zero a new lock read the old way at
        0.69 Hz for two decisions, the chain took that speed, and the fan's reversal,
        answered 0.3 s later, was held as the sudden mirror image for 5 s.)"""
        if not (t_s - self._run_from < self.settings.followed_s and self._chain is not None):
            return False
        seen = self._chain[1]
        if self._carried is not None and self._chain[0] < self._carried[0] < self._run_from:
            # a window carried as the known way after the chain's answer and before this
            # run (a line followed up a ramp, :meth:`carry`) saw the fan at its speed: a
            # spin-up's new lock at it is the fan (spent held-out 7100008: carried at
            # 0.28 Hz, then a lock answering 0.28 Hz, 1.5 s after the chain's 0.08 Hz)
            seen = max(seen, self._carried[1])
        return _rate(d) > (1.0 + CHAIN_AGREE) * seen

    def _read_slow_once_reachable(self) -> bool:
        """Whether a window read the fan slower than the floor after the chain's last
        answer, no sooner than a fan braked at ``max_reversal_hz_s`` from that answer's
        speed reaches the rate a new direction needs: at once after a slow answer; after
        a faster one, once it could be there (spent held-out 4900015: the old way's track
        coasted at 0.122 Hz while the fan slowed to zero, windows read it at 0.003-0.045
        Hz for 1.2 s, then a new lock claimed the old way at 0.059 Hz, renewed the chain,
        and the reversal 0.14 s later was held as sudden for 74 s)."""
        if self._chain is None or not self._read_slow_t > self._chain[0]:
            return False
        t, old = self._chain
        over = max(old - self._visible_hz, 0.0)
        vmax = self.settings.max_reversal_hz_s
        if over == 0.0:
            return True
        return vmax > 0 and self._read_slow_t >= t + over / vmax

    def _note_candidate(self, t_s: float, d: Decision, cand: Kind | None,
                        prev: Kind | None) -> None:
        """A new candidate starts its count afresh and is judged sudden or not; a run
        that resumes after a break is judged afresh where the fan was seen near zero
        since: on a line of the old way that has reached zero, or in a window that read
        it slower than the floor after it was last seen turning the old way and after
        the run's first answer (a fan not seen slowing to zero keeps the verdict, and so
        does one seen so only before the verdict)."""
        if cand is not None and cand != self._cand:
            self._cand = cand
            self._support.clear()
            self._cand_rate, self._cand_t = _rate(d), float(t_s)
            self._cand_sudden = self._sudden_reversal(t_s, self._cand_rate, cand)
            self._cand_impossible = self._impossible_reversal(t_s, self._cand_rate, cand)
        elif cand is not None and prev != cand and self._cand_impossible \
                and self.known in WAY_KINDS and (self._past_zero(t_s, self.known)
                                                 or self._read_slow_since_cand()):
            # (a sudden run is an impossible one too)
            self._cand_sudden = self._cand_sudden and self._sudden_reversal(t_s, _rate(d),
                                                                            cand)
            self._cand_impossible = self._impossible_reversal(t_s, _rate(d), cand)

    def _read_slow_since_cand(self) -> bool:
        """Whether a window read the fan slower than the floor after the chain's last
        answer and after the candidate's first: what was seen before the candidate's
        verdict is no news to it (spent held-out 7200004: a start's track answered
        `same` while its rate estimate converged through zero to the fan's `reversed`,
        one weak window between read 0.01 Hz; the run the other way, held as sudden,
        resumed after a window in doubt, was judged afresh on that window and fired a
        false reversal 6.6 s after the start)."""
        return self._read_slow_since_chain() and self._read_slow_t > self._cand_t

    def _read_slow_since_chain(self) -> bool:
        """Whether a window read the fan slower than the floor after it was last seen
        turning the known way (the chain's last answer)."""
        return self._chain is not None and self._read_slow_t > self._chain[0]

    def _count_support(self, cand: Kind, pulse: int, pulses: int) -> None:
        """Pulses for the candidate within twice its confirmation time: an unknown answer
        between them (a weak window, an alias check's doubt) pauses the count instead of
        restarting it; an answer of another kind restarts it."""
        need = self._need(cand)
        self._support.append((int(pulse), int(pulses)))
        while self._support and self._support[0][0] <= int(pulse) - 2 * need:
            self._support.popleft()
        self._cand_n = sum(n for _, n in self._support)

    def _need(self, cand: Kind) -> int:
        """Pulses of answers ``cand`` needs to be confirmed."""
        return self._stop_confirm if cand == Kind.STOPPED else self._confirm

    def _confirm_kind(self, t_s: float, pulse: int, d: Decision, cand: Kind
                      ) -> tuple[Decision, list[Event]]:
        """``cand`` becomes the known kind if it is new; (the decision, with a correction
        said in its reason), the event that makes, if any."""
        if cand == self.known:
            return d, []
        before = self.known
        corrected = self._corrects(cand, d)
        self.known = cand
        self._known_checked = d.mirror_checked
        self._rest_since_known = False
        self._known_seen = (float(t_s), _rate(d)) if cand != Kind.STOPPED else None
        self._way_answered = self._known_seen
        if corrected:
            return replace(d, reason=f"direction corrected: the {before} answered before "
                                     f"was the mirror image of the blade pattern (it never "
                                     f"fitted the reference better than its mirror, this "
                                     f"line has): {d.reason}"), []
        if before is None or (before == Kind.TURNING and cand in WAY_KINDS):
            return d, []                     # (a direction found for a turning fan)
        kind = (EventKind.STOPPED if cand == Kind.STOPPED else
                EventKind.STARTED if before == Kind.STOPPED else EventKind.REVERSED)
        ev = Event(kind, float(t_s), int(pulse), d.direction, d.rotation,
                   None if cand == Kind.STOPPED else d.rate_hz)
        self.events.append(ev)
        return d, [ev]

    def _corrects(self, cand: Kind, d: Decision) -> bool:
        """Whether confirming ``cand`` corrects the known direction rather than reverses
        it: a run that began sooner than a fan reverses at all (``max_reversal_hz_s``),
        on a line that beat its mirror image (a sudden one got here only so), after a
        direction never seen on such a line. No fan turns about that fast; the direction
        before was the mirror of the blade pattern (a start's first lock, mostly: in
        spent held-out 2600009 a start's first 17 pulses on two tracks the mirror's way,
        after eight on the right one, and the right way 0.9 s later, which made a false
        reversal). Where both lines beat their mirrors, the physics and the check
        disagree, and the reversal stands; so it does in a doubtful room, where a
        check says nothing."""
        return self.known in WAY_KINDS and cand in WAY_KINDS and cand != self.known \
            and (self._cand_sudden or (self._cand_impossible and d.mirror_checked
                                       and not d.doubtful_room)) \
            and not self._known_checked

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

    def _impossible_reversal(self, t_s: float, rate: float, cand: Kind) -> bool:
        """Whether an answer of ``cand`` at ``rate`` (Hz), the other way from the known
        direction, comes sooner than a fan reverses at all (down through zero and up at
        ``max_reversal_hz_s``) from when it was last seen turning the known way: in the
        chain of answers (:meth:`_sudden_reversal`) or, for a direction confirmed by its
        first answer (a start), at that answer."""
        if self._sudden_reversal(t_s, rate, cand, 1.0):
            return True
        st = self.settings
        if self.known not in WAY_KINDS or cand not in WAY_KINDS or cand == self.known \
                or self._known_seen is None or not st.max_reversal_hz_s > 0:
            return False
        t, old = self._known_seen
        return float(t_s) < t + _sudden_span(old, rate, st.max_reversal_hz_s, 1.0)

    def _sudden_reversal(self, t_s: float, rate: float, cand: Kind,
                         share: float = SUDDEN_SHARE) -> bool:
        """Whether an answer of ``cand`` at ``rate`` (Hz), the other way from the known
        direction, comes within ``share`` of the time a fan needs to reverse (down
        through zero and up at ``max_reversal_hz_s``) from when it was last seen turning
        (``_chain``: answers of the known way, answers without a direction at its speed,
        windows in doubt in a doubtful room), with no answer of rest between (the meter
        lags a reversal). A fan that really reverses is driven through zero at a ramp;
        answers that jump to the other way at about the old speed are a track taken up on
        the mirror of the blade pattern."""
        st = self.settings
        if self.known not in WAY_KINDS or cand not in WAY_KINDS or cand == self.known \
                or self._chain is None or not st.max_reversal_hz_s > 0:
            return False
        t, old = self._chain
        if not float(t_s) < t + _sudden_span(old, rate, st.max_reversal_hz_s, share):
            return False
        # a chain whose last answers came from a track coasting on its prediction (no
        # blade in view) saw the fan last at its clear match: a fan that could have
        # reversed through zero since then, at max_reversal_hz_s, is no mirror image
        if self._chain_seen is None:
            return True
        t, old = self._chain_seen
        return float(t_s) < t + _sudden_span(old, rate, st.max_reversal_hz_s, 1.0)

    def _soonest_reversal(self, t_s: float, rate: float) -> float | None:
        """When a fan last seen turning the known way could be seen turning the other
        way at ``rate``, but no later than ``reversal_hold_s`` after the other way was
        first answered (None: no known direction, or no limit). A slowing line of the
        known way that has reached zero by ``t_s`` puts the fan at zero no sooner than
        its zero: the last answer of the old way may lie a second or more before it, at
        a rate near the floor. A zero still ahead is used only where the answers followed
        the fan down the line to near the floor (:meth:`_line_followed_down`): answers
        after a stretch at rest join the line of those before it, and put its zero
        seconds off, and a lagging line puts it late. A window
        that read the fan slower than the floor after the known way's last answer puts
        the other way no sooner than :meth:`_rest_unseen_until`, however long the other
        way has been answered (that wait ends by itself, a meter's window after the slow
        reading): the tracks a spin-down's end leaves can claim the other way before the
        meter sees the rest."""
        st = self.settings
        if self.known not in WAY_KINDS or self._known_seen is None \
                or not st.max_reversal_hz_s > 0:
            return None
        t, old = self._known_seen
        soonest = t + (old + rate) / st.max_reversal_hz_s
        if self._line_zero_times(t_s):
            assert self._zero_by is not None    # (the line has one)
            soonest = max(soonest, self._zero_by + rate / st.max_reversal_hz_s)
        soonest = min(soonest, self._cand_t + st.reversal_hold_s)
        return max(soonest, self._rest_unseen_until())

    def _line_zero_times(self, t_s: float) -> bool:
        """Whether the known way's slowing line puts the fan at zero no sooner than its
        zero: the line has reached zero by ``t_s``, or the known way's last answer was
        on it near the floor (:meth:`_line_followed_down`)."""
        if self.known is None or self._zero_by is None or self._known_seen is None:
            return False
        return self._past_zero(t_s, self.known) \
            or self._line_followed_down(*self._known_seen)

    def _line_followed_down(self, t: float, old: float) -> bool:
        """Whether the known way's last answer (``old`` Hz at ``t``) lies on its slowing
        line (within ``CHAIN_AGREE``) under the rate a new direction needs: the answers
        followed the fan down the line to near the floor, so its zero, even ahead, is
        when the fan stops (a line they left, or one from answers after a rest, is
        not)."""
        assert self.known is not None
        line = self._line_rate(t, self.known)
        return line is not None and old < self._visible_hz \
            and abs(line - old) <= CHAIN_AGREE * old

    @property
    def near_zero_since_known(self) -> bool:
        """Whether a window read the fan slower than the floor after the known way's
        last answer: the fan may have come to rest since."""
        return self._known_seen is not None and self._read_slow_t > self._known_seen[0]

    def _rest_unseen_until(self) -> float:
        """Until when a fan read slower than the floor after the known way's last answer
        may have come to rest unseen: the short meter reads a fan creeping to rest as
        motion until its window holds nothing but the rest (``still_window_s``); -inf if
        no window read it so. (Spent held-out 5500020: a lock on a fan come to rest claimed
        the other way, speeding up to 0.22 Hz, while the meter read 4-14 for 1.4 s after
        the fan read slow; it fell under the threshold 1.5 s after.)"""
        if not self.near_zero_since_known:
            return -math.inf
        return self._read_slow_t + self.settings.still_window_s

    def _watch_slowing(self, t_s: float, d: Decision, kind: Kind | None) -> None:
        """Remember when a fan seen slowing down steadily would reach zero: the line of
        the recent answers at rates the track follows well (three times the floor and
        up), extrapolated; such answers that no longer fall (the fan held or regained its
        speed) forget it. Slower answers change nothing: there the track lags and
        flattens; nor do answers the other way before that way is confirmed (a sign that
        the fan may be reversing, not a reason to forget its slowing). But answers of the
        line's way that have followed the fan without a break (``followed_s``) later
        than a stop at its zero would have been due and seen (``reversal_guard_s`` and
        ``meter_lag_s`` after it) refute it: the fan settled at a slow speed instead
        (spent held-out 5400014: a line from a slowing to 0.113 Hz kept its zero of 70 s
        before, so a slow reversal through zero was not waited for, and was a stop and
        a start)."""
        if kind not in TURNING_KINDS or d.rate_hz is None or not math.isfinite(d.rate_hz):
            return
        if self.known in WAY_KINDS and kind != self.known:
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
        elif self._zero_by is not None and t - self._run_from >= self.settings.followed_s \
                and t > self._zero_by + self.settings.reversal_guard_s \
                + self.settings.meter_lag_s:
            self._zero_by = None

    def _line_zero(self, t_s: float) -> float | None:
        """When the slowing line reaches zero, if that can explain a fan at rest by
        ``t_s``; None without a line, or for one that reaches zero more than
        ``reversal_guard_s`` from now (an abrupt stop whose last answers sagged as the
        track broke up is no slowing fan)."""
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
        turning when the known direction was last answered, or last published by the
        mirror hold: other answers the other way not yet confirmed neither end the wait
        nor renew its cap, and nor does a new run of
        the known direction once the line is below the floor, until it has lasted
        ``followed_s`` (:meth:`step`).

        A fan whose slowing was not seen at all (its answers ended before they gave a
        slope), or whose line reaches zero only well after now, is waited for as if it
        were braked as hard as a fan can be, provided that it could have come to zero
        within ``blind_turn_rev`` of a turn, i.e. out of view, and that its answers
        followed it without a break for ``followed_s`` up to the last one. A faster fan
        would have been seen slowing, so its sudden quiet is a stop (an abrupt one) and is
        not held."""
        st = self.settings
        if self.known not in TURNING_KINDS:
            return None
        zero_by, slowing = self._line_zero(t_s), self._slowing_hz_s
        if zero_by is None:
            # no slowing line that explains a rest now; but a fan last answered slowly
            # enough may have reached zero and turned round out of view: the answers
            # that gave the line lag a brisk slowing
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


def _what(d: Decision, cand: Kind) -> str:
    """The candidate in words, for a reason."""
    return ("a stop" if cand == Kind.STOPPED else "turning, direction in doubt"
            if cand == Kind.TURNING else f"turning {d.direction}")
