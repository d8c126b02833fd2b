"""Rotation schedules with ramps and a speed wobble: the angle is the exact integral of the
rate (checked against numerical quadrature and hand-derived closed forms), reversals through
zero, the grammar's round trip and errors, and a rendered recording's truth."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

from bladesonar import config, imaging
from bladesonar.errors import ConfigError
from bladesonar.io.scene_file import load_scene
from bladesonar.sim.render import simulate
from bladesonar.sim.schedule import (
    Schedule,
    Segment,
    Wobble,
    direction_of,
    ordinary_use,
    parse,
)

ROOT = Path(__file__).resolve().parents[1]
CFG = config.Config()
PRI = CFG.waveform.pri_samples

SCHEDULES = {
    "spin-up from rest": "cw:0.4:10~5",
    "reversal through zero": "ccw:0.45:30,cw:0.45:20~10",
    "spin-down": "ccw:0.45:10,stop:0:15~8",
    "everything": "ccw:0.45:30~6,cw:0.45:20~10,stop:0:15~8,ccw:0.35:30~5,ccw:0.6:10",
    "wobble on ramps": "ccw:0.45:30~6,cw:0.45:20~10,stop:0:15~8,ccw:0.35:30~5,wobble:0.04:1.7",
    "ramp fills segment": "ccw:0.3:4~4,cw:0.2:3~3,wobble:0.1:0.9",
}


def rate(s: Schedule, t: float) -> float:
    return float(s.rate_at(np.array([t]))[0])


def turns(s: Schedule, t: float) -> float:
    return float(s.turns_at(np.array([t]))[0])


def quad_turns(s: Schedule, t: float) -> float:
    """Numerical integral of rate_at from 0 to t, split at every knot (smooth in between)."""
    knots = [0.0] + [p.start_s for p in s.pieces if 0 < p.start_s < t] + [t]
    return sum(integrate.quad(lambda x: rate(s, x), a, b, epsabs=1e-13, epsrel=1e-13,
                              limit=500)[0] for a, b in itertools.pairwise(knots))


@pytest.mark.parametrize("name", sorted(SCHEDULES))
def test_turns_are_the_integral_of_the_rate(name):
    s = parse(SCHEDULES[name])
    end = max(p.start_s for p in s.pieces) + 7.3
    ts = np.concatenate([np.linspace(0.0, end, 23), [p.start_s for p in s.pieces]])
    got = s.turns_at(ts)
    assert got.dtype == np.float64
    for t, g in zip(ts, got, strict=True):
        assert g == pytest.approx(quad_turns(s, float(t)), abs=1e-10)
    assert np.allclose(s.angle_at(ts, 0.3), 0.3 + 2 * math.pi * got, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", sorted(SCHEDULES))
def test_turns_and_rate_are_continuous_at_ramp_knots(name):
    s = parse(SCHEDULES[name])
    d = 1e-7
    for p in s.pieces[1:]:
        k = p.start_s
        lo, hi = turns(s, k - d), turns(s, k + d)
        assert abs(hi - lo) <= 2 * d * s.max_abs_hz + 1e-12      # turns never jump
        prev = [q for q in s.pieces if q.end_s == k][0]
        if prev.end_hz == p.start_hz:                            # ramped knots: no step
            assert rate(s, k - d) == pytest.approx(rate(s, k), abs=1e-6)
    # inside a ramp the base rate moves linearly from the old signed rate to the new one
    ramp = [p for p in s.pieces if p.is_ramp][0]
    mid = 0.5 * (ramp.start_s + ramp.end_s)
    assert s.base_rate_at(np.array([mid]))[0] == pytest.approx(
        0.5 * (ramp.start_hz + ramp.end_hz), abs=1e-15)


def test_spin_up_from_rest_is_uniform_acceleration():
    s = parse("cw:0.4:10~5")
    t = np.array([0.0, 1.0, 2.5, 5.0])
    assert np.allclose(s.rate_at(t), -0.4 * t / 5, rtol=0, atol=1e-15)
    assert np.allclose(s.turns_at(t), -0.5 * (0.4 / 5) * t**2, rtol=0, atol=1e-14)
    # after the ramp: the ramp's average speed (half the rate) over 5 s, then full speed
    assert turns(s, 12.0) == pytest.approx(-0.4 * 5 / 2 - 0.4 * 7, abs=1e-13)
    assert rate(s, 100.0) == -0.4                                  # last segment continues
    assert rate(s, -1.0) == 0.0 and turns(s, -1.0) == 0.0          # at rest before t = 0


def test_spin_down_covers_half_rate_times_ramp():
    s = parse("ccw:0.45:10,stop:0:15~8")
    assert turns(s, 18.0) - turns(s, 10.0) == pytest.approx(0.45 * 8 / 2, abs=1e-13)
    assert turns(s, 40.0) == turns(s, 18.0) == pytest.approx(4.5 + 1.8, abs=1e-13)
    assert rate(s, 14.0) == pytest.approx(0.45 / 2, abs=1e-15)
    t = np.linspace(18.0, 40.0, 50)
    assert np.all(s.rate_at(t) == 0.0)
    assert list(direction_of(s.rate_at(np.array([5.0, 17.9, 18.0])))) == \
        ["ccw", "ccw", "stopped"]


@pytest.mark.parametrize("spec, zero", [
    ("ccw:0.45:30,cw:0.45:20~10", 35.0),                   # symmetric: half-way through
    ("ccw:0.6:10,cw:0.2:8~4", 10.0 + 4 * 0.6 / 0.8),        # 0.6 -> -0.2 over 4 s
    ("cw:0.3:7,ccw:0.9:6~2,wobble:0.05:0.8", 7.0 + 2 * 0.3 / 1.2),
])
def test_reversal_through_zero_at_the_expected_time(spec, zero):
    s = parse(spec)
    assert rate(s, zero) == pytest.approx(0.0, abs=1e-14)
    before, after = rate(s, zero - 1e-3), rate(s, zero + 1e-3)
    assert before * after < 0
    assert np.allclose(imaging.reversal_times(spec), [zero], rtol=0, atol=1e-12)
    # the turn count peaks (or bottoms out) at the zero crossing
    assert abs(turns(s, zero)) > abs(turns(s, zero - 0.01))
    assert abs(turns(s, zero)) > abs(turns(s, zero + 0.01))


def test_reversal_times_with_ramps_stops_and_wobble():
    sched = "ccw:0.45:30,cw:0.45:20~10,stop:0:15~8,ccw:0.35:30~5"
    assert np.allclose(imaging.reversal_times(sched), [35.0, 65.0])       # 65: leaves rest
    assert np.allclose(imaging.reversal_times(sched + ",wobble:0.4:0.3"), [35.0, 65.0])
    # spin-down and spin-up in the same direction: no reversal
    assert imaging.reversal_times("cw:0.4:10~3,stop:0:5~4,cw:0.5:10~6").size == 0
    # unramped steps keep their old meaning
    assert np.allclose(imaging.reversal_times("ccw:0.5:3,stop:0:2,cw:0.4:5,cw:0.2:1"), [5.0])
    assert np.allclose(imaging.reversal_times("ccw:0.5:3,cw:0.4:5"), [3.0])


def test_wobble_on_a_constant_rate_averages_out_over_whole_periods():
    a, T, r = 0.04, 2.0, 0.5
    s = parse(f"ccw:{r}:10,wobble:{a}:{T}")
    t = np.linspace(0.0, 30.0, 301)
    assert np.allclose(s.rate_at(t), r * (1 + a * np.sin(2 * np.pi * t / T)), rtol=0,
                       atol=1e-15)
    expect = r * t + r * a * T / (2 * np.pi) * (1 - np.cos(2 * np.pi * t / T))
    assert np.allclose(s.turns_at(t), expect, rtol=0, atol=1e-13)
    assert turns(s, 20 * T) == pytest.approx(r * 20 * T, abs=1e-12)
    assert s.max_abs_hz == pytest.approx(r * (1 + a))
    assert s.rate_at(np.linspace(0, 10, 100001)).max() == pytest.approx(r * (1 + a), rel=1e-8)
    assert set(direction_of(s.rate_at(t))) == {"ccw"}


def test_wobble_keeps_stops_stopped():
    s = parse("wobble:0.3:1.1,cw:0.5:4~2,stop:0:6~2,cw:0.5:5~1")
    t = np.linspace(8.0, 10.0, 77)
    assert np.all(s.rate_at(t) == 0.0)
    assert np.all(s.turns_at(t) == turns(s, 8.0))
    assert turns(s, 8.0) == pytest.approx(quad_turns(s, 8.0), abs=1e-10)


@pytest.mark.parametrize("spec", [
    "ccw:0.5:3,stop:0:2,cw:0.4:5",
    "ccw:0.45:30,cw:0.45:20~10,stop:0:15~8,ccw:0.35:30~5",
    "ccw:0.45:60,wobble:0.03:2",
    "cw:0.4:10~10,wobble:0:3",
    "ccw:0.1234567:0.3333333333333333~0.1111111111111111,wobble:0.0123456789:1.23456789",
])
def test_to_string_round_trips(spec):
    s = parse(spec)
    assert s.to_string() == spec
    assert parse(s.to_string()) == s


def test_other_forms_and_wobble_placement():
    want = parse("ccw:0.45:30,cw:0.45:20~10,stop:0:15~8,wobble:0.03:2")
    assert parse("wobble:0.03:2, ccw:0.45:30, CW:0.45:20 ~ 10, stopped:0:15~8") == want
    assert parse([("ccw", 0.45, 30), ("cw", 0.45, 20, 10), "stop:0:15~8",
                  ("wobble", 0.03, 2)]) == want
    assert parse([{"direction": "ccw", "rate_hz": 0.45, "seconds": 30},
                  {"direction": "cw", "rate_hz": 0.45, "seconds": 20, "ramp_s": 10},
                  {"wobble": 0.03, "period_s": 2},
                  {"direction": "stop", "seconds": 15, "ramp_s": 8}]) == want
    assert want.segments[1] == Segment("cw", 0.45, 20.0, 10.0)
    assert want.wobble == Wobble(0.03, 2.0)
    assert sum(x.seconds for x in want.segments) == 65.0       # ramps are inside seconds
    c = Schedule.constant(0.3, "cw")
    assert c.to_string() == "cw:0.3:1" and c.wobble is None and rate(c, 50.0) == -0.3
    assert parse("ccw:0.5:3,stop:0:2,cw:0.8:5~1").max_abs_hz == 0.8


@pytest.mark.parametrize("spec, bad, words", [
    ("ccw:0.5:10,cw:0.5:5~6", "cw:0.5:5~6", "longer than the segment"),
    ("ccw:0.5:3~4", "ccw:0.5:3~4", "SECONDS >= RAMP_S"),              # last segment too
    ("ccw:0.5:10~-1", "ccw:0.5:10~-1", ">= 0"),
    ("ccw:0.5:10~nan", "ccw:0.5:10~nan", ">= 0"),
    ("ccw:0.5:10~", "ccw:0.5:10~", "numbers"),
    ("ccw:0.5:10~1~2", "ccw:0.5:10~1~2", "RAMP_S"),
    ("ccw:0.5:10,wobble:0.5:2", "wobble:0.5:2", "fraction"),
    ("ccw:0.5:10,wobble:-0.1:2", "wobble:-0.1:2", "fraction"),
    ("ccw:0.5:10,wobble:0.1:0", "wobble:0.1:0", "> 0"),
    ("ccw:0.5:10,wobble:0.1:-2", "wobble:0.1:-2", "> 0"),
    ("ccw:0.5:10,wobble:0.1:inf", "wobble:0.1:inf", "> 0"),
    ("ccw:0.5:10,wobble:0.1", "wobble:0.1", "wobble:A:PERIOD_S"),
    ("ccw:0.5:10,wobble:x:2", "wobble:x:2", "numbers"),
    ("ccw:0.5:10,wobble:0.02:2,wobble:0.03:1", "wobble:0.03:1", "at most one wobble"),
    ("wobble:0.02:2", "wobble:0.02:2", "at least one segment"),
])
def test_errors_name_the_item_and_the_fix(spec, bad, words):
    with pytest.raises(ConfigError) as exc:
        parse(spec, key="--schedule")
    msg = str(exc.value)
    assert msg.startswith("--schedule = ") and repr(bad) in msg and words in msg


def test_mapping_errors():
    with pytest.raises(ConfigError, match="ramp 9 s is longer"):
        parse([{"direction": "cw", "rate_hz": 1, "seconds": 2, "ramp_s": 9}])
    with pytest.raises(ConfigError, match="period_s"):
        parse(["ccw:1:2", {"wobble": 0.1}])
    with pytest.raises(ConfigError, match="unknown field"):
        parse([{"direction": "cw", "rate_hz": 1, "seconds": 2, "ramp": 1}])


def test_rendered_truth_follows_a_ramped_schedule():
    room = load_scene(ROOT / "config/scenes/paper-room.yaml")
    spec = "ccw:0.5:1~1,cw:0.5:2~2"          # spin-up, then a reversal through zero at 2 s
    _, t = simulate(room, CFG, 3.6, spec, start_offset=0.0, include_paths=False)
    assert t["meta"]["schedule"] == spec
    assert list(imaging.reversal_times(t["meta"]["schedule"])) == [2.0]

    def closed(ts: float) -> tuple[float, float]:   # (turns, rate) derived by hand
        if ts <= 1:
            return 0.25 * ts**2, 0.5 * ts
        if ts <= 3:
            u = ts - 1
            return 0.25 + 0.5 * u - 0.25 * u**2, 0.5 - 0.5 * u
        return 0.25 - 0.5 * (ts - 3), -0.5

    assert len(t["pulses"]) == math.ceil(3.6 * 44100 / PRI)
    for p in t["pulses"]:
        ts = p["time_s"]
        n, r = closed(ts)
        assert p["angle_rad"] == pytest.approx(room.start_angle_rad + 2 * math.pi * n,
                                               abs=1e-12)
        assert p["rate_hz"] == pytest.approx(r, abs=1e-14)
        assert p["phase"] == pytest.approx((4 * p["angle_rad"] / (2 * math.pi)) % 1.0)
        assert p["direction"] == ("stopped" if ts == 0 else "ccw" if ts < 2 else "cw")


def test_rendered_truth_with_wobble_matches_the_integral():
    room = load_scene(ROOT / "config/scenes/paper-room.yaml")
    spec = "ccw:0.6:1.5~1,stop:0:1~0.5,cw:0.4:1~0.7,wobble:0.08:0.45"
    _, t = simulate(room, CFG, 3.2, spec, start_offset=100.0, include_paths=False)
    s = parse(t["meta"]["schedule"])
    assert s == parse(spec)
    for p in t["pulses"][::3]:
        n = quad_turns(s, p["time_s"])
        assert p["angle_rad"] == pytest.approx(room.start_angle_rad + 2 * math.pi * n,
                                               abs=1e-9)
        stopped = 2.0 <= p["time_s"] < 2.5
        assert (p["direction"] == "stopped") == stopped


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_a_day_of_ordinary_use_stays_within_what_a_fan_does(seed):
    """The day tools/bench_day and tools/soak simulate: a seed gives the same day; it
    covers the time asked; the fan is off or at 0.2-0.6 Hz; no ramp is steeper than the
    steepest one the tracker is tuned for (tracking.max_ramp_hz_s), so the benchmark
    measures the pipeline inside its stated envelope."""
    day = ordinary_use(np.random.default_rng(seed), 3600.0)
    assert day == ordinary_use(np.random.default_rng(seed), 3600.0)
    sch = parse(day)
    assert sum(s.seconds for s in sch.segments) >= 3600.0
    steepest = config.Config().tracking.max_ramp_hz_s
    prev = 0.0
    for s in sch.segments:
        assert s.rate_hz == 0.0 or 0.2 <= s.rate_hz <= 0.6, s
        if s.ramp_s > 0:
            assert s.ramp_s < s.seconds
            assert abs(s.signed_hz - prev) / s.ramp_s <= steepest + 1e-9, s
        prev = s.signed_hz
    assert sch.segments[0] == Segment("ccw", 0.45, 60.0)
