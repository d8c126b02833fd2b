"""The answer module: its words are the published words, its one rounding is what every
published answer carries, and its records are what the rest of the package reads."""

from __future__ import annotations

import json
import math

import pytest

from bladesonar.answer import (
    DECIMALS,
    MOTION_EVENTS,
    Decision,
    Direction,
    Estimate,
    EventKind,
    Kind,
    RateState,
    published,
    significant,
)
from bladesonar.service import messages as M
from bladesonar.transitions import Event


def test_a_member_is_its_word_on_the_wire_and_in_text():
    """JSON, f-strings, str() and dict keys give the word itself, so payloads and reasons
    read as they did when the words were spelled by hand."""
    for member in (*Direction, *Kind, *RateState, *EventKind):
        word = member.value
        assert json.dumps({"k": member, member: 1}) == json.dumps({"k": word, word: 1})
        assert f"{member}" == str(member) == word
        assert {word: 1}[member] == 1 and member == word


def test_the_published_words_are_pinned():
    """The words subscribers and Home Assistant automations match on (a renamed member
    would change the wire)."""
    assert [d.value for d in Direction] == ["same", "reversed", "stopped", "unknown"]
    assert list(MOTION_EVENTS) == ["started", "stopped", "reversed"]
    assert list(M.EVENT_KINDS) == [
        "started", "stopped", "reversed", "reference_learned", "reference_learn_failed",
        "reference_forgotten", "reference_direction_set", "reference_stale",
        "reference_missing", "reference_invalid"]
    assert list(M.REFERENCE_EVENTS) == ["learned", "learn_failed", "forgotten",
                                        "direction_set", "stale", "missing", "invalid"]
    assert [r.value for r in RateState] == ["settled", "changing"]


def test_published_rounds_to_its_decimals_and_drops_what_json_cannot_carry():
    assert published("rate_hz", 0.123456789) == 0.12346
    assert published("rpm", 7.4074074) == 7.407
    assert published("confidence", 0.91236) == 0.9124
    assert published("relative_rate", -0.7006949) == -0.70069
    assert published("rate_change_hz_s", -0.0451249) == -0.0451
    for bad in (None, math.nan, math.inf, -math.inf):
        assert published("rate_hz", bad) is None
    assert significant(123.456789) == 123.457 and significant(1.23456789e-7) == 1.23457e-7
    assert significant(math.nan) is None
    with pytest.raises(KeyError):
        published("window_s", 1.0)           # not an answer's float: no precision of its own


def test_every_published_form_of_a_decision_rounds_the_same_way():
    """analyze's JSON (as_dict), the daemon's state (Estimate) and the event details carry
    each float exactly as :func:`published` gives it: one precision, wherever it goes."""
    d = Decision(Direction.REVERSED, "cw", -0.700694949, 0.350347474, 21.02084848,
                 0.971849999, "r", rate_state=RateState.CHANGING,
                 rate_change_hz_s=-0.045124999)
    off = d.as_dict()
    est = Estimate.from_decision(d, window_s=4.0, reference="ab").fields()
    for k in DECIMALS:
        want = published(k, getattr(d, k))
        assert want is not None and want != getattr(d, k)      # the case does round
        assert off[k] == want and est[k] == want, k
    ev = Event(EventKind.REVERSED, 1.0, 34, d.direction, d.rotation, d.rate_hz)
    assert ev.details() == {"direction": "reversed", "rotation": "cw",
                            "rate_hz": published("rate_hz", d.rate_hz)}
    assert M.state_payload(est, t=0.0)["rate_hz"] == published("rate_hz", d.rate_hz)


def test_a_decision_takes_the_words_and_refuses_others():
    d = Decision("same", None, 1.0, 0.4, 24.0, 0.9, "r", ["w"], "settled")  # type: ignore[arg-type]
    assert d.direction is Direction.SAME and d.rate_state is RateState.SETTLED
    assert d.warnings == ("w",)
    with pytest.raises(ValueError, match="sideways"):
        Decision("sideways", None, None, None, None, 0.0, "r")  # type: ignore[arg-type]


def test_kinds_of_decisions():
    """The kind a state machine and Running read: the direction's own, ``turning`` for a
    fan turning whose direction is in doubt, None when nothing is known."""
    def dec(direction: Direction, turning: bool = False) -> Decision:
        return Decision(direction, None, None, 0.4, None, 0.3, "r", turning=turning)
    assert dec(Direction.SAME).kind is Kind.SAME
    assert dec(Direction.REVERSED).kind is Kind.REVERSED
    assert dec(Direction.STOPPED).kind is Kind.STOPPED
    assert dec(Direction.UNKNOWN, turning=True).kind is Kind.TURNING
    assert dec(Direction.UNKNOWN).kind is None
    assert Kind.of("unknown") is None and Kind.of(None) is None


def test_an_estimate_is_a_decision_plus_window_and_reference():
    d = Decision(Direction.STOPPED, None, 0.0, 0.0, 0.0, 0.8, "still", turning=True)
    e = Estimate.from_decision(d, window_s=5.0, reference="ab")
    assert isinstance(e, Decision) and (e.window_s, e.reference) == (5.0, "ab")
    assert not e.turning and e.rotating is False and e.kind is Kind.STOPPED
    u = Estimate.unknown("starting", reference="cd")
    assert u.rotating is None and not u.known and u.fields()["reference"] == "cd"


def test_replaced_is_dataclasses_replace():
    """Decision.replaced (the analyzer's cheap copy with changes) gives the record
    dataclasses.replace gives, words turned into members by __post_init__ as there, for
    a Decision and an Estimate; a name that is no field is an error, as there."""
    import dataclasses
    d = Decision(Direction.SAME, "ccw", 1.0, 0.45, 27.0, 0.9, "ok", ("w",),
                 RateState.SETTLED, 0.01)
    for rec in (d, Estimate.from_decision(d, window_s=5.0, reference="abc")):
        for ch in ({"mirror_checked": True, "doubtful_room": True},
                   {"relative_rate": -0.5, "rate_hz": 0.2, "rpm": 12.0},
                   {"direction": "reversed", "rate_state": "changing", "warnings": ["x"]}):
            got, want = rec.replaced(**ch), dataclasses.replace(rec, **ch)
            assert type(got) is type(want) and got == want
            assert got.__dict__ == want.__dict__
            assert isinstance(got.direction, Direction) and isinstance(got.warnings, tuple)
        assert rec.mirror_checked is False          # the original untouched
        with pytest.raises(TypeError, match="no field"):
            rec.replaced(speed=1.0)
