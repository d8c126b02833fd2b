"""The answer's vocabulary and its record: the words the analysis, the state machine,
``analyze`` and the MQTT payloads use for what the fan does, one :class:`Decision` per
window, and the precision every published float of it keeps (pure; the ground floor:
nothing of the package is imported here).

The enums are ``StrEnum``: a member is its word (``Direction.SAME == "same"``; ``str``,
f-strings and ``json.dumps`` give the word), so payloads and reasons read as before.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields
from typing import Any, Self


class Direction(enum.StrEnum):
    """The answer's ``direction``, relative to the reference's own."""

    SAME = "same"
    REVERSED = "reversed"
    STOPPED = "stopped"
    UNKNOWN = "unknown"


#: The two directions a fan turns (a direction is claimed).
WAYS = (Direction.SAME, Direction.REVERSED)


class Kind(enum.StrEnum):
    """What is known of the fan's motion: turning one way, the other, either way (the
    direction in doubt: :attr:`Decision.turning`), or at rest; None when nothing is. The
    state machine confirms kinds (transitions.py); Home Assistant's Running holds them
    (service/messages.py ``RunningHold``)."""

    SAME = "same"
    REVERSED = "reversed"
    TURNING = "turning"
    STOPPED = "stopped"

    @classmethod
    def of(cls, direction: str | None) -> Kind | None:
        """The kind a direction names (None for unknown or no direction)."""
        return _KIND_OF.get(direction) if direction is not None else None


_KIND_OF: dict[str, Kind] = {Direction.SAME: Kind.SAME, Direction.REVERSED: Kind.REVERSED,
                             Direction.STOPPED: Kind.STOPPED}
#: The kinds that turn a known way, and those that turn at all.
WAY_KINDS = (Kind.SAME, Kind.REVERSED)
TURNING_KINDS = (*WAY_KINDS, Kind.TURNING)


class RateState(enum.StrEnum):
    """The answer's ``rate_state`` while turning."""

    SETTLED = "settled"
    CHANGING = "changing"


class EventKind(enum.StrEnum):
    """The ``kind`` of an event message: the fan's (confirmed by transitions.py) and the
    reference's (service/reference_keeper.py)."""

    STARTED = "started"
    STOPPED = "stopped"
    REVERSED = "reversed"
    REFERENCE_LEARNED = "reference_learned"
    REFERENCE_LEARN_FAILED = "reference_learn_failed"
    REFERENCE_FORGOTTEN = "reference_forgotten"
    REFERENCE_DIRECTION_SET = "reference_direction_set"
    REFERENCE_STALE = "reference_stale"
    REFERENCE_MISSING = "reference_missing"
    REFERENCE_INVALID = "reference_invalid"

    @property
    def motion(self) -> bool:
        """An event of the fan's, not of the reference's."""
        return not self.startswith("reference_")


#: The fan's events, in the order they are listed (Home Assistant's event types).
MOTION_EVENTS = tuple(k for k in EventKind if k.motion)


#: Decimal places each float of an answer keeps where it is published (``analyze``'s
#: JSON and ``--track`` rows, the MQTT state and events): a rate to 10 micro-Hz, far
#: below what the estimate resolves, so rounding never changes what it says.
DECIMALS = {"relative_rate": 5, "rate_hz": 5, "rpm": 3, "rate_change_hz_s": 4,
            "confidence": 4}
#: Significant digits of every other float in an MQTT payload (service/messages.clean).
SIGNIFICANT_DIGITS = 6


def published(name: str, value: float | None) -> float | None:
    """``value`` as the answer's float ``name`` is published (:data:`DECIMALS` places);
    None when there is none or it is not finite."""
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), DECIMALS[name])


def significant(value: float, digits: int = SIGNIFICANT_DIGITS) -> float | None:
    """``value`` to ``digits`` significant digits, as a payload carries it; None when not
    finite (JSON has no NaN)."""
    x = float(value)
    if not math.isfinite(x):
        return None
    return float(f"{x:.{digits}g}")


@dataclass(frozen=True)
class Decision:
    """The answer for one window (:func:`dsp.decide.decide`, then as the state machine
    confirms it); :meth:`as_dict` gives the JSON keys of ``analyze``."""

    direction: Direction
    rotation: str | None
    """cw or ccw when the reference's direction is known and the fan turns, else None."""
    relative_rate: float | None
    rate_hz: float | None
    rpm: float | None
    confidence: float
    reason: str
    warnings: tuple[str, ...] = ()
    rate_state: RateState | None = None
    """Settled or changing while turning, else None."""
    rate_change_hz_s: float | None = None
    """How fast the rotation rate changes (Hz per second, + faster), while turning."""
    seen_still: bool = False
    """A 'stopped' answer whose matches show the blade standing still in view (not only
    a quiet meter): no reversal through zero can be under way (transitions.py)."""
    turning: bool = False
    """The fan turns by this window's evidence, whichever way: set with a direction, and
    on an ``unknown`` whose only doubt is the direction (a confident track well above
    the floor, in doubt because its mirror image or an alias rate fits as well)."""
    direction_doubt: bool = False
    """An ``unknown`` whose only doubt is which way the fan turns: its mirror image fits
    as well, at the same speed (``direction in doubt``, ``direction to be confirmed``),
    not an alias rate. Its speed is known all the same (the rate bound anchors on it)."""
    mirror_checked: bool = False
    """The track's line has fitted the reference clearly better than its mirror image
    (:meth:`aliasing.AliasWatch.mirror_checked`): its direction is no mirror lock."""
    doubtful_room: bool = False
    """Directions have lately been in doubt in this room (its echoes turned either way
    fit about equally: :attr:`aliasing.AliasWatch.doubtful`)."""
    standing_alias: bool = False
    """The alias check found the track standing still while another line fits the
    matches (the fan moves): its slow rate is no sign of a fan near zero."""
    unseen_s: float = 0.0
    """Seconds since the track last accepted a clear match (a blade in view): it has
    coasted on its prediction since, so its answer tells where the fan was then, not
    now (transitions.py: the last time the fan was seen turning)."""

    def __post_init__(self) -> None:
        # the words as members (a caller may give the word itself), the warnings a tuple
        # (a member is kept as it is: the enum's call, which returns it, is the cost of
        # the analyzer's many decisions)
        if type(self.direction) is not Direction:
            object.__setattr__(self, "direction", Direction(self.direction))
        if self.rate_state is not None and type(self.rate_state) is not RateState:
            object.__setattr__(self, "rate_state", RateState(self.rate_state))
        if type(self.warnings) is not tuple:
            object.__setattr__(self, "warnings", tuple(self.warnings))

    def as_dict(self) -> dict[str, Any]:
        """``analyze``'s answer keys, the floats as published."""
        return dict(direction=self.direction.value, rotation=self.rotation,
                    relative_rate=published("relative_rate", self.relative_rate),
                    rate_hz=published("rate_hz", self.rate_hz),
                    rpm=published("rpm", self.rpm),
                    rate_state=None if self.rate_state is None else self.rate_state.value,
                    rate_change_hz_s=published("rate_change_hz_s", self.rate_change_hz_s),
                    confidence=published("confidence", self.confidence),
                    reason=self.reason)

    def replaced(self, **changes: Any) -> Self:
        """``dataclasses.replace(self, **changes)``: the same record (the fields set, then
        ``__post_init__``), at a third of the cost (no ``__init__`` called with every
        field by name), for the analyzer's two per-decision changes."""
        bad = changes.keys() - _FIELD_NAMES
        if bad:
            raise TypeError(f"Decision has no field(s) {sorted(bad)}: use one of "
                            f"{sorted(_FIELD_NAMES)}")
        c = object.__new__(type(self))
        c.__dict__.update(self.__dict__)
        c.__dict__.update(changes)
        c.__post_init__()
        return c

    @property
    def kind(self) -> Kind | None:
        """What this answer knows of the motion (None: nothing; a turning fan whose
        direction is in doubt is ``Kind.TURNING``)."""
        k = Kind.of(self.direction)
        return Kind.TURNING if k is None and self.turning else k


#: Decision's fields (Decision.replaced)
_FIELD_NAMES = frozenset(f.name for f in fields(Decision))


@dataclass(frozen=True)
class Estimate(Decision):
    """The daemon's current answer: a decision as published (its floats rounded) plus
    what the service adds at run time, the window it covers and the reference it was
    matched against. A decision itself rather than a wrapper of one, so a reader of a
    decision's fields reads an estimate's the same way. The runner and the messages
    receive it (``service/messages.py`` turns it into the state payload with
    :meth:`fields`)."""

    window_s: float | None = None
    """Seconds of pulses the decision covers (shorter during the warm-up)."""
    reference: str | None = None
    """Id of the reference in use (first 12 hex digits of its file's sha256)."""

    @classmethod
    def from_decision(cls, d: Decision, *, window_s: float | None,
                      reference: str | None) -> Self:
        """``d`` as published, for the window and the reference given (a stopped fan is
        not ``turning``)."""
        rounded = {k: published(k, getattr(d, k)) for k in DECIMALS}
        rounded["confidence"] = rounded["confidence"] or 0.0
        own = {f.name: getattr(d, f.name) for f in fields(Decision)}
        return cls(**{**own, **rounded,
                      "turning": d.turning and d.direction != Direction.STOPPED},
                   window_s=window_s, reference=reference)

    @classmethod
    def unknown(cls, reason: str, *, reference: str | None = None) -> Self:
        """Nothing is known (no reference yet, no signal, re-aligning)."""
        return cls(Direction.UNKNOWN, None, None, None, None, 0.0, reason,
                   reference=reference)

    @property
    def rotating(self) -> bool | None:
        """True when turning either way (its direction known or not), False when
        stopped, None when not known."""
        if self.direction is Direction.UNKNOWN:
            return True if self.turning else None
        return self.direction is not Direction.STOPPED

    @property
    def known(self) -> bool:
        return self.direction is not Direction.UNKNOWN

    def fields(self) -> dict[str, Any]:
        """The state message's estimate fields, in the published order (warnings only
        when there are some)."""
        out: dict[str, Any] = {
            "direction": self.direction.value, "rotation": self.rotation,
            "rotating": self.rotating, "rate_hz": self.rate_hz, "rpm": self.rpm,
            "relative_rate": self.relative_rate,
            "rate_state": None if self.rate_state is None else self.rate_state.value,
            "rate_change_hz_s": self.rate_change_hz_s, "confidence": self.confidence,
            "window_s": self.window_s, "reference": self.reference, "reason": self.reason}
        if self.warnings:
            out["warnings"] = list(self.warnings)
        return out
