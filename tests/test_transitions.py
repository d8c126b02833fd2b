"""Fan dynamics: the running answer and its events against the simulator's truth.

Each scene is rendered with a ramped schedule (spin-down, reversal through zero, spin-up
from rest, speed steps, a slow fan against a fast reference) at 10 dB SNR and 40 ppm of
clock drift, run through the same per-pulse pipeline the daemon runs (``analyze --track``
rows), and scored with sim/score.py: every truth event found once, with its latency
bound, no false event, never a wrong direction claimed.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from bladesonar import config
from bladesonar.answer import Decision, Direction, EventKind, Kind
from bladesonar.io.scene_file import load_scene
from bladesonar.offline import analyze
from bladesonar.reference_build import build_reference
from bladesonar.sim.nuisances import Nuisances
from bladesonar.sim.render import simulate
from bladesonar.sim.schedule import parse
from bladesonar.sim.score import (
    Score,
    TruthEvent,
    merge,
    score_events,
    score_gaps,
    score_state,
    true_time,
    truth_events,
)
from bladesonar.transitions import Transitions, TransitionSettings

pytestmark = pytest.mark.slow   # simulated scenes with transitions: outside the fast tier

SCENE = "config/scenes/paper-room.yaml"
#: the issue's test condition; stream times are scored at the schedule's (true) time
DRIFT_PPM = 40.0


@pytest.fixture(scope="module")
def scene(repo_root):
    return load_scene(repo_root / SCENE)


@pytest.fixture(scope="module")
def reference(scene):
    x, _ = simulate(scene, config.Config(), 20.0, schedule="ccw:0.45:20", seed=1, snr_db=20.0)
    return build_reference(x, config.Config(), "ccw")


def _run(scene, ref, schedule, seconds, seed=3, snr_db=10.0):
    cfg = config.Config()
    x, _ = simulate(scene, cfg, seconds, schedule=schedule, seed=seed, snr_db=snr_db,
                    drift_ppm=DRIFT_PPM)
    summary, rows = analyze(x, cfg, ref, track=True)
    sch = parse(schedule)
    score = score_events(truth_events(sch, seconds),
                         [(r["event"], true_time(r["t_s"], DRIFT_PPM))
                          for r in rows if r["event"]])
    for r in rows:
        t = true_time(r["t_s"], DRIFT_PPM)
        true = float(sch.rate_at(np.array([t]))[0])
        score_state(score, t, true, r["direction"], r["rotation"], r["rate_hz"],
                    ref_sign=1)
    return score, rows, summary


# (schedule, seconds, truth kinds in order, latency bound per kind)
SCENES = {
    "spin-down": ("ccw:0.45:10,stop:0:12~8", 22, ["stopped"]),
    "abrupt-stop": ("ccw:0.45:10,stop:0:8", 18, ["stopped"]),
    "reversal-through-zero": ("ccw:0.45:10,cw:0.45:14~10", 24, ["reversed"]),
    "spin-up-from-rest": ("stop:0:6,ccw:0.45:12~5", 18, ["started"]),
    "stop-and-start": ("cw:0.4:8,stop:0:10~6,cw:0.3:10~4", 28, ["stopped", "started"]),
    # 0.067 Hz/s: below the short meter's reach for about a second on each side of zero
    # (it was read as a stop and a start, bench_day)
    "slow-reversal": ("ccw:0.45:6,cw:0.55:16~15", 22, ["reversed"]),
    "speed-steps": ("ccw:0.25:8,ccw:0.5:10~3,ccw:0.3:10~2", 28, []),
    # 0.12 Hz/s from a slow 0.2 Hz: the blade turns round zero out of view and no answer
    # shows the slowing (read as a stop at 9.21 s and a start at 9.91 s before the wait
    # for a reversal out of view; a simulated hour had one such)
    "brisk-reversal-of-a-slow-fan": ("ccw:0.2:6.5,cw:0.4:12~5", 18.5, ["reversed"]),
}
# the issue's targets (measured on these scenes, seeds 3-5: started 0.15-0.24 s, stopped
# 1.9-2.2 s, reversed within 0.05 s of the truth; an instant stop of a blade resting out
# of view once took 3.9 s, seed 4, see docs/dynamics.md)
LATENCY = {"started": 2.0, "stopped": 3.0, "reversed": 2.0}
# An abrupt stop, which no real fan makes, with the blade at rest out of view: the track
# coasts on as through the blind part of a turning fan's blade period (0.6 of it, 0.33 s),
# and the answers that follow sag before the short meter sees the rest, so the old
# direction stands for up to 0.9 s (0.4 s before the track coasted). Seeds 3-7: 25-29 of
# 610 states, the last at 0.72-0.83 s (before matches on the table's flat part lost their
# quality: 25-41, up to 1.20 s; the weak matches after the stop no longer pull a re-lock
# off the old line, so it holds a little longer in seed 3 and much less in seed 4)
WRONG_SHARE = {"abrupt-stop": 0.05}


@pytest.mark.parametrize("name", list(SCENES))
def test_transitions_give_each_event_once_and_in_time(scene, reference, name):
    schedule, seconds, kinds = SCENES[name]
    score, rows, _ = _run(scene, reference, schedule, seconds)
    assert [e.kind for e in score.truth] == kinds
    assert not score.false, score.summary()
    assert not score.missed, score.summary()
    for ev, lat in score.hits:
        assert lat <= LATENCY[ev.kind], (ev, lat)
    # no direction is published with a rate under the floor (tracking.rate_floor_hz)
    slow = [(r["t_s"], r["rate_hz"]) for r in rows
            if r["direction"] in ("same", "reversed") and not r["rate_hz"] >= 0.05]
    assert not slow, slow[:5]
    # a wrong direction (or a stop while turning) is hardly ever published
    assert score.wrong <= WRONG_SHARE.get(name, 0.025) * score.states, score.summary()


def test_a_stop_is_never_a_reversal(scene, reference):
    """The old runner turned every spin-down into a 'reversed' event (demo: 0.029 Hz)."""
    _, rows, _ = _run(scene, reference, "ccw:0.45:8,stop:0:14~8", 22, seed=9)
    events = [r["event"] for r in rows if r["event"]]
    assert events == ["stopped"], events


@pytest.mark.parametrize("snr_db", [20.0, 30.0, 40.0, 50.0, 60.0])
def test_a_stop_is_called_at_high_snr(scene, reference, snr_db):
    """The issue asks for a stop within 3 s at 10 dB *or better*. With 40 ppm of drift a
    fan at rest stayed unknown for good: at 30 dB through the aligner's residual error
    (once), at 40 dB through the coupling's edge timed off by a function of its
    sub-sample position (dsp/pulses.EDGE_BAND), at 50-60 dB through the short meter's
    static estimate approaching the resting fan (tuning.SLOW_FACTOR)."""
    score, _, _ = _run(scene, reference, "ccw:0.45:10,stop:0:14~6", 24, seed=4,
                       snr_db=snr_db)
    assert [e.kind for e, _ in score.hits] == ["stopped"], score.summary()
    assert not score.false
    assert score.hits[0][1] <= LATENCY["stopped"]


@pytest.mark.parametrize("snr_db", [30.0, 60.0])
def test_a_stop_is_called_on_a_clipping_device_at_high_snr(scene, snr_db):
    """A small speaker whose coupling clips (12 dB of capture gain), two clocks 40 ppm
    apart: the coupling timed from its plateaus' edges was off by 0.11 sample rms, a
    change between pulses that at 30 dB and more kept the rest unknown and made the start
    after it a false 'reversed'; timed from its ringing (dsp/pulses._tail_offset) the rest
    is called and the start is a start."""
    nz = Nuisances(capture_gain_db=12.0, speaker_highpass_hz=300.0,
                   speaker_resonance_hz=3000.0, speaker_resonance_db=10.0)
    cfg = config.Config()
    xr, _ = simulate(scene, cfg, 20.0, schedule="ccw:0.45:20", seed=1, snr_db=20.0,
                     nuisances=nz)
    ref = build_reference(xr, cfg, "ccw")
    schedule, seconds = "ccw:0.45:10,stop:0:14~6,cw:0.4:10~4", 34.0
    x, truth = simulate(scene, cfg, seconds, schedule=schedule, seed=4, snr_db=snr_db,
                        drift_ppm=DRIFT_PPM, nuisances=nz)
    assert truth["summary"]["clipped_samples"] > 0.9 * len(truth["pulses"])   # they clip
    _, rows = analyze(x, cfg, ref, track=True)
    score = score_events(truth_events(parse(schedule), seconds),
                         [(r["event"], true_time(r["t_s"], DRIFT_PPM))
                          for r in rows if r["event"]])
    assert [e.kind for e, _ in score.hits] == ["stopped", "started"], score.summary()
    assert not score.false and not score.missed
    assert all(lat <= LATENCY[e.kind] for e, lat in score.hits), score.summary()


def test_no_direction_below_the_rate_floor(scene, reference):
    """A fan at 0.03 Hz (under the 0.05 Hz default floor) is stopped or unknown."""
    _, rows, _ = _run(scene, reference, "ccw:0.03:12", 12, seed=4, snr_db=15.0)
    claims = {r["direction"] for r in rows}
    assert claims <= {"stopped", "unknown"}, claims


def test_fan_at_rest_from_the_start_is_stopped(scene, reference):
    """At 10 dB (the issue's bound) a fan at rest from the start is stopped: its echo is
    static, not noise (the old noise-only gate asked the static echo to stand 6 dB over a
    single pulse's noise and answered unknown)."""
    for snr_db in (10.0, 20.0):
        _, rows, summary = _run(scene, reference, "stop:0:8", 8, seed=5, snr_db=snr_db)
        assert summary["direction"] == "stopped", summary
        assert not [r for r in rows if r["event"]]      # the first known state fires none


def test_noise_is_not_a_fan_at_rest(scene, reference):
    """A gate holding nothing but noise must not read as a fan at rest: the mean pulse of
    noise alone is about 1/(pulses averaged) of one pulse's noise energy, far below the
    scene threshold. A fan at rest at -10 dB gives a static echo of about 0.01 of that
    noise energy (measured 0.009): noise for all purposes, from the first pulse on."""
    cfg = config.Config()
    x, _ = simulate(scene, cfg, 8.0, schedule="stop:0:8", seed=5, snr_db=-10.0,
                    drift_ppm=40.0)
    summary, rows = analyze(x, cfg, reference, track=True)
    assert summary["direction"] == "unknown" and "noise" in summary["reason"], summary
    assert {r["direction"] for r in rows} == {"unknown"}


@pytest.mark.parametrize("schedule, seed", [("ccw:0.2:6,ccw:0.5:14~6", 6),
                                            ("cw:0.5:6,cw:0.25:14~5", 7),
                                            ("ccw:0.3:8,ccw:0.6:12~4", 8)])
def test_rate_follows_a_ramp(scene, reference, schedule, seed):
    """Ramps of 0.05-0.075 Hz/s at 10 dB: the published rate against the simulator's
    (issue target: 95th percentile error at most 10 %; measured 4-7 % on these),
    'changing' over much of the ramp and 'settled' once it holds."""
    _, rows, _ = _run(scene, reference, schedule, 20, seed=seed)
    sch = parse(schedule)
    t = np.array([r["t_s"] for r in rows])
    true = np.abs(sch.rate_at(t - 0.03))
    slope = np.abs(sch.rate_at(t + 0.05) - sch.rate_at(t - 0.05)) / 0.1
    ramp = slope > 1e-6
    err = np.array([1.0 if r["rate_hz"] is None else abs(r["rate_hz"] - a) / a
                    for r, a in zip(rows, true, strict=True)])
    assert np.percentile(err[ramp], 95) <= 0.10, np.percentile(err[ramp], 95)
    assert np.median(err[ramp]) <= 0.03, np.median(err[ramp])
    changing = np.array([r["rate_state"] == "changing" for r in rows])
    assert changing[ramp].mean() >= 0.25
    assert not changing[t > t[ramp].max() + 2.0].any()
    assert rows[-1]["rate_state"] == "settled"
    assert abs(rows[-1]["rate_hz"] - true[-1]) < 0.02 * true[-1]



@pytest.fixture(scope="module")
def slow_reference(scene):
    x, _ = simulate(scene, config.Config(), 20.0, schedule="ccw:0.2:20", seed=1, snr_db=20.0)
    return build_reference(x, config.Config(), "ccw")


# (reference, schedule, seed, direction, 95th percentile rate error against the truth):
# a slow fan against a fast reference (0.15-0.18 Hz against 0.45 Hz: few clear matches
# per second, a blind half-period of up to 1.7 s), a fast one against a slow reference
# (0.7 Hz against 0.2 Hz, 3.5x: the table is stepped through 3.5 times faster than it was
# recorded), and a speed wobble of 3-4 % (measured: 5.1-7.9 %, 0.3-0.7 %, 6.9-9.2 %)
STEADY = {
    "slow-cw-against-fast": ("fast", "cw:0.18:30", 3, "reversed", 0.10),
    "slowest-ccw-against-fast": ("fast", "ccw:0.15:30", 4, "same", 0.10),
    "fast-ccw-against-slow": ("slow", "ccw:0.7:30", 3, "same", 0.02),
    "fast-cw-against-slow": ("slow", "cw:0.7:30", 4, "reversed", 0.02),
    "wobble-3pc": ("fast", "ccw:0.45:30,wobble:0.03:1.7", 3, "same", 0.10),
    "wobble-4pc": ("fast", "cw:0.3:30,wobble:0.04:2.3", 4, "reversed", 0.12),
}


@pytest.mark.parametrize("name", list(STEADY))
def test_slow_fast_and_wobbling_fans_hold_their_answer(scene, reference, slow_reference,
                                                       name):
    """A fan that keeps turning (at a speed far from the reference's, or with a wobble of
    a few per cent) is one known direction from its first answer on: no event, no wrong
    answer, no unknown over 0.5 s, a published rate within the bound of the simulator's, and
    a wobble is not a speed change ('settled' throughout)."""
    which, schedule, seed, direction, p95 = STEADY[name]
    ref = reference if which == "fast" else slow_reference
    score, rows, _ = _run(scene, ref, schedule, 30, seed=seed)
    assert not score.truth and not score.false, score.summary()
    assert score.wrong == 0, score.summary()
    t = np.array([r["t_s"] for r in rows])
    first = next(i for i, r in enumerate(rows) if r["direction"] != "unknown")
    assert t[first] <= 4.0                       # one window (3 s) and the confirmation
    late = [r["direction"] for r in rows[first:]]
    assert set(late) <= {direction, "unknown"} and late.count(direction) >= 0.98 * len(late)
    sc = Score(truth=[])
    score_gaps(sc, list(t), [r["direction"] for r in rows], parse(schedule).rate_at(t - 0.03))
    assert not any(d > 0.5 for _, d in sc.gaps), sc.gaps
    true = np.abs(parse(schedule).rate_at(t[first:] - 0.03))
    err = np.array([1.0 if r["rate_hz"] is None else abs(r["rate_hz"] - a) / a
                    for r, a in zip(rows[first:], true, strict=True)])
    assert np.percentile(err, 95) <= p95, np.percentile(err, 95)
    if name.startswith("slow"):
        # issue 31: a slow fan against a fast reference within 1 % at the median pulse
        # (measured 0.03-0.11 % at 0.15-0.2 Hz against 0.5 Hz, paper room, 10 dB, 40 ppm)
        assert np.median(err) <= 0.01, np.median(err)
    settled = [r["rate_state"] == "settled" for r, tr in zip(rows, t, strict=True) if tr > 5.0]
    assert np.mean(settled) >= 0.95, np.mean(settled)


def _d(direction, rate=0.4, checked=True):
    """A decision; a turning one's line has beaten its mirror (``checked``) unless told."""
    turning = direction in ("same", "reversed")
    return Decision(direction, None, None, rate if turning else 0.0, None, 0.9, "test",
                    mirror_checked=turning and checked)


def test_state_machine_needs_confirmation_and_fires_between_known_states():
    """Closed-form walk: 34 pulses/s, confirm 0.5 s = 17 pulses, stop confirm 1 s (no
    wait for a reversal to be physically possible: the flips here are instant)."""
    tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=1.0,
                                        max_reversal_hz_s=0.0), 34.0)
    seq = ["same"] * 30 + ["unknown"] * 10 + ["reversed"] * 16 + ["same"] * 5 \
        + ["reversed"] * 20 + ["stopped"] * 40 + ["same"] * 20
    events, published = [], []
    for i, d in enumerate(seq):
        out, fired = tr.step(i / 34.0, i, _d(d))
        published.append(out.direction)
        events += [(e.kind, e.pulse) for e in fired]
    # same confirmed at pulse 16 (no event: first); 16 reversed are not enough; the
    # next 20 confirm at their 17th; 34 stopped pulses (1 s) confirm; same again at 17
    assert events == [("reversed", 61 + 16), ("stopped", 81 + 33), ("started", 121 + 16)]
    assert published[:16] == ["unknown"] * 16 and published[16] == "same"
    assert "reversed" not in published[40:56]      # unconfirmed: published as unknown


def _doubt(rate=0.4):
    """A fan turning at ``rate`` whose direction is in doubt (its mirror fits as well)."""
    return Decision(Direction.UNKNOWN, None, None, rate, None, 0.3, "direction in doubt",
                    turning=True, direction_doubt=True)


def test_a_fan_turning_either_way_starts_and_stops_in_a_doubtful_room():
    """Closed form, 34 pulses/s, confirm 17 pulses, stop confirm 34: where no direction
    is known, 'turning, direction in doubt' is a known kind of its own (a start and a
    stop fire); a direction found for it later fires nothing, a reversal from there
    fires as usual; where a direction is known, doubt is only unknown."""
    def run(seq):
        tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=1.0,
                                            max_reversal_hz_s=0.0), 34.0)
        fired, out = [], []
        for i, d in enumerate(seq):
            o, f = tr.step(i / 34.0, i, _doubt() if d == "doubt" else _d(d))
            fired += [(e.kind, e.pulse, e.direction) for e in f]
            out.append((o.direction, o.turning))
        return fired, out
    fired, out = run(["stopped"] * 40 + ["doubt"] * 30 + ["stopped"] * 40)
    assert fired == [("started", 40 + 16, "unknown"), ("stopped", 70 + 33, "stopped")]
    # while the start is confirmed the fan is not yet said to turn; then it is
    assert out[40 + 15] == ("unknown", False) and out[40 + 16] == ("unknown", True)
    fired, _ = run(["stopped"] * 40 + ["doubt"] * 30 + ["same"] * 30 + ["reversed"] * 30)
    assert fired == [("started", 56, "unknown"), ("reversed", 100 + 16, "reversed")]
    # a known direction: doubt changes nothing, and a stop after it is timed as before
    fired, out = run(["same"] * 30 + ["doubt"] * 30 + ["stopped"] * 40)
    assert fired == [("stopped", 60 + 33, "stopped")]
    assert out[40] == ("unknown", True)


def _lost():
    """A window with no track at all (no consistent match against the reference)."""
    return Decision(Direction.UNKNOWN, None, None, None, None, 0.0, "no consistent match")


def _weak(rate=0.4):
    """A window whose track is too weak to claim the fan turns (weak evidence)."""
    return Decision(Direction.UNKNOWN, None, None, rate, None, 0.3, "weak evidence")


def test_a_known_direction_is_carried_through_doubt_at_its_speed_until_the_fan_could_reverse():
    """Closed form, 34 pulses/s, the default reversal physics (through zero at 0.3 Hz/s,
    a new direction from 0.1 Hz): a fan confirmed turning one way at 0.4 Hz cannot turn
    the other way and be seen there at 0.4 Hz sooner than 0.8 / 0.3 = 2.67 s later. So
    windows in doubt only about the direction (a doubtful room's mirror, an alias rate)
    at the known speed publish the known direction while half that time (1.33 s, the
    share under which a reversal is held as sudden) has not passed since the last
    answered or carried window; an alias speed above the band is left unknown without
    ending the carry; three confident tracks in a row under the band (``CARRY_DIP``),
    or one under 0.1 Hz, end it, and then doubt is unknown again; one or two under the
    band are a noisy follower's dip and are carried (spent held-out 4500006: one
    decision at 0.54 Hz of a steady 0.64 Hz fan ended the carry, 175 s unknown)."""
    def run(seq):
        tr = Transitions(TransitionSettings(confirm_s=0.5), 34.0)
        out = []
        for i, d in enumerate(["stopped"] * 40 + ["same"] * 30 + seq):
            o, _ = tr.step(i / 34.0, i, d if isinstance(d, Decision) else _d(d))
            o = tr.carry(i / 34.0, o)
            out.append((o.direction.value, o.rate_hz))
        return out[70:]
    # doubt at the speed, at a slowly changing speed, an alias speed between: carried
    out = run([_doubt(0.4)] * 10 + [_weak(0.4)] * 5 + [_doubt(1.2)] * 5
              + [_doubt(0.4 + 0.002 * i) for i in range(40)])
    assert out[:10] == [("same", 0.4)] * 10
    # a weak track or an alias speed is not carried, but bridged
    assert [d for d, _ in out[10:20]] == ["unknown"] * 10
    assert [d for d, _ in out[20:]] == ["same"] * 40 and out[-1][1] == pytest.approx(0.478)
    # 1.26 s of an alias line above the band is bridged, 1.38 s is not
    out = run([_doubt(0.4)] * 10 + [_doubt(1.2)] * 42 + [_doubt(0.4)] * 5)
    assert [d for d, _ in out[52:]] == ["same"] * 5
    out = run([_doubt(0.4)] * 10 + [_doubt(1.2)] * 46 + [_doubt(0.4)] * 5)
    assert [d for d, _ in out[56:]] == ["unknown"] * 5
    # three confident tracks in a row under the band end the carry: the fan may be
    # slowing; one or two are a dip, carried
    out = run([_doubt(0.4)] * 10 + [_doubt(0.2)] * 3 + [_doubt(0.4)] * 5)
    assert [d for d, _ in out[10:]] == ["same"] * 2 + ["unknown"] * 6
    out = run([_doubt(0.4)] * 10 + [_doubt(0.29)] * 2 + [_doubt(0.4)] * 5)
    assert [d for d, _ in out[10:]] == ["same"] * 7
    # the band is the answered speed's: tracks 20 % apart do not walk the rate away
    out = run([_doubt(0.4 * 1.2 ** i) for i in range(4)])
    assert [d for d, _ in out] == ["same", "same", "unknown", "unknown"]
    # a reversal at 0.3 Hz/s, the direction in doubt throughout: down to 0.1 Hz in 1 s,
    # through zero to 0.1 Hz the other way in 0.67 s (23 pulses) seen as windows with no
    # track, as slow tracks or as a stop's first answers, then up: the way back up is
    # unknown, though it passes the answered speed again
    down = [_doubt(0.4 - 0.3 * i / 34) for i in range(34)]
    up = [_doubt(0.1 + 0.3 * i / 34) for i in range(34)]
    for zero in ([_lost()] * 23, [_weak(0.05)] * 23, [_d("stopped")] * 2 + [_lost()] * 21):
        out = run(down + zero + up)
        # carried while within a quarter of the answered 0.4 Hz (down to 0.303 Hz), and
        # two windows under it (a dip is not yet a slowing)
        assert [d for d, _ in out[:34]] == ["same"] * 14 + ["unknown"] * 20
        assert [d for d, _ in out[34:]] == ["unknown"] * 57
    # the same reversal unseen (a weak track held the old line over it): the way up,
    # 2 s after the last carried window, is unknown
    out = run(down[:12] + [_weak(0.4)] * 57 + [_doubt(0.3 + 0.1 * i / 34) for i in range(34)])
    assert [d for d, _ in out[:12]] == ["same"] * 12
    assert [d for d, _ in out[12:]] == ["unknown"] * 91
    # 1.29 s with no track between carried answers is bridged, 1.38 s is not
    gap = [_lost()] * 43
    assert [d for d, _ in run(gap + [_doubt(0.4)] * 5)[43:]] == ["same"] * 5
    gap = [_lost()] * 46
    assert [d for d, _ in run(gap + [_doubt(0.4)] * 5)[46:]] == ["unknown"] * 5


def test_a_carry_is_not_ended_by_the_fan_back_at_its_speed_after_an_excursion():
    """Closed form, 34 pulses/s, the default reversal physics (through zero at 0.3 Hz/s):
    a fan answered 'same' at 0.4 Hz, then for 6 answers (0.18 s) at 0.5 Hz (a follower's
    excursion), then in doubt at 0.36 Hz. A fan cannot have reversed between answers
    0.18 s apart (half the time through zero from 0.4 Hz is 1.33 s), so 0.36 Hz is within
    a quarter of the slowest of them and the known way is carried; measured against the
    last answer alone (0.36 < 0.75 x 0.5) it was a slowing, and three such windows ended
    the carry (spent held-out 4900018: 14 s of `unknown` for a steady 0.305 Hz fan
    answered at 0.38-0.415 Hz for 0.5 s). A fan answered at 0.5 Hz for 2 s, longer than a
    reversal from 0.4 Hz takes, is measured against 0.5 Hz: three windows at 0.36 Hz end
    its carry as before."""
    def run(excursion):
        tr = Transitions(TransitionSettings(confirm_s=0.5), 34.0)
        seq = [_d("stopped")] * 40 + [_d("same", 0.4)] * 30 + [_d("same", 0.5)] * excursion \
            + [_doubt(0.36)] * 10
        out = []
        for i, d in enumerate(seq):
            o, _ = tr.step(i / 34.0, i, d)
            out.append(tr.carry(i / 34.0, o).direction.value)
        return out[-10:]
    assert run(6) == ["same"] * 10
    assert run(68) == ["same"] * 2 + ["unknown"] * 8


def test_a_fan_read_near_zero_once_it_could_be_there_makes_a_lock_of_its_old_way_new():
    """Closed form, 10 answers/s, the default reversal physics (through zero at 0.3 Hz/s,
    a new direction from 0.1 Hz), lines not shown to beat their mirror: a fan answered
    'same' at 0.122 Hz, then read slower than the floor (0.03 Hz) for 1.2 s, then one
    answer 'same' at 0.059 Hz (a new lock on a fan reversing), then 'reversed' at 0.14
    Hz. From 0.122 Hz a fan brakes under 0.1 Hz in 0.07 s, so the slow windows are the
    fan near zero and the lone slow answer does not renew the last speed the fan was
    seen turning the old way at; against that (1.4 s earlier) the reversal is not
    sudden, and it fires (spent held-out 4900015: held as the mirror image for 74 s).
    Read slow only 0.1 s after an answer at 0.5 Hz (braking under 0.1 Hz takes 1.33 s),
    then the old way again and at once the other way at 0.5 Hz: a mirror lock, held."""
    def run(seq):
        tr = Transitions(TransitionSettings(confirm_s=0.5), 10.0)
        fired = []
        for i, d in enumerate([_d("stopped")] * 10 + seq):
            _, ev = tr.step(i * 0.1, i, d)
            fired += [e.kind for e in ev]
        return fired
    reversing = [_d("same", 0.122)] * 30 + [_weak(0.03)] * 12 + [_d("same", 0.059)] \
        + [_d("reversed", 0.14, checked=False)] * 30
    assert run(reversing) == ["started", "reversed"]
    mirror = [_d("same", 0.5)] * 30 + [_weak(0.03)] + [_d("same", 0.5)] \
        + [_d("reversed", 0.5, checked=False)] * 12
    assert run(mirror) == ["started"]


def test_the_mirror_image_of_a_checked_direction_publishes_that_direction():
    """Closed form, 10 answers/s, the default reversal physics (through zero at 0.3 Hz/s):
    a fan answered 'same' at 0.36 Hz on a line that beat its mirror image, then at once
    'reversed' at the same speed for 15 s, in a room where directions have been in doubt
    (so the new line's own check says nothing), then 'same' again. Through zero and back
    to 0.36 Hz takes 2.4 s: the other way at once is the mirror of the blade pattern, held
    (no event), and the fan is still turning the way it was answered, so that way is
    published, not unknown (spent held-out 4200020: 18 s of `unknown` while a 5-blade
    fan turned steadily at 0.36 Hz). Not where the known direction never beat its mirror
    (either could be the mirror's), nor at a speed off the answered one."""
    def run(first_checked, other_hz):
        tr = Transitions(TransitionSettings(confirm_s=0.5), 10.0)
        seq = [_d("stopped")] * 10 + [_d("same", 0.36, checked=first_checked)] * 30 \
            + [replace(_d("reversed", other_hz), doubtful_room=True)] * 150 \
            + [_d("same", 0.36, checked=first_checked)] * 20
        out, fired = [], []
        for i, d in enumerate(seq):
            o, ev = tr.step(i * 0.1, i, d)
            fired += [e.kind for e in ev]
            out.append(tr.carry(i * 0.1, o).direction.value)
        return out[40:], fired
    out, fired = run(True, 0.36)
    assert fired == ["started"] and set(out) == {"same"}
    out, fired = run(False, 0.36)
    assert fired == ["started"] and set(out[:150]) == {"unknown"} and set(out[150:]) == {"same"}
    out, fired = run(True, 0.6)
    assert fired == ["started"] and set(out[:150]) == {"unknown"}


def test_a_known_direction_is_carried_up_a_ramp_on_the_line_that_answered_it():
    """Closed form, 34 pulses/s: a fan answered `same` at 0.4 Hz on one tracked line,
    then in doubt on that line while it speeds up at 0.1 Hz/s to 1.2 Hz. The line was
    followed without a break, and a fan turns the other way only through the floor: the
    ramp is `same` all the way. The speeds above the band on another line (a new lock,
    a move to an alias) are left unknown, as a line with no identity is; three windows
    of the line under the band in a row (it slows down) end the carry."""
    def run(seq, lines):
        tr = Transitions(TransitionSettings(confirm_s=0.5), 34.0)
        out = []
        pre = ["stopped"] * 40 + ["same"] * 30
        for i, (d, line) in enumerate(zip(pre + seq, [None] * 40 + ["A"] * 30 + lines,
                                          strict=True)):
            o, _ = tr.step(i / 34.0, i, d if isinstance(d, Decision) else _d(d))
            o = tr.carry(i / 34.0, o, line)
            out.append(o.direction.value)
        return out[70:]
    n = 272                                  # 8 s at 0.1 Hz/s: 0.4 -> 1.2 Hz
    ramp = [_doubt(0.4 + 0.1 * i / 34) for i in range(n)]
    assert run(ramp, ["A"] * n) == ["same"] * n
    band = 35                                # within 25 % of the answered 0.4 Hz
    # a jump to another line at three times the speed (an alias) is not carried
    assert run(ramp[:band] + [_doubt(1.5)] * 10, ["A"] * band + ["B"] * 10) == \
        ["same"] * band + ["unknown"] * 10
    assert run(ramp, [None] * n) == ["same"] * band + ["unknown"] * (n - band)
    # a new lock carried at the answered speed is the fan the same way: its line goes on
    assert run(ramp, ["B"] * n) == ["same"] * n
    # up to 1.2 Hz on its line, then three windows of it at 0.8 Hz: the fan may be
    # slowing to reverse, so the carry ends at the third and doubt is unknown again
    out = run(ramp + [_doubt(0.8)] * 3 + [_doubt(1.2)] * 5, ["A"] * (n + 8))
    assert out[:n + 2] == ["same"] * (n + 2) and out[n + 2:] == ["unknown"] * 6


def test_a_confirmed_stop_is_kept_while_nothing_is_seen_turning_above_the_floor():
    """Closed form, 34 pulses/s: a fan confirmed at rest, then windows with no line at
    all (no consistent match: in a small hard-walled reverberant room the resting fan's
    echoes change between pulses as a turning fan's do, spent held-out 2200016) stay
    `stopped`: with no line there is nothing turning to tell. A window with a line (a
    lock, turning or not) is kept only while it reads the fan slower than the floor
    (0.05 Hz, under which no direction is claimed: a start not yet shown), nor is a
    window with no line when the known state is a direction; the events are the
    machine's as before (a start fires as it did)."""
    def run(seq, lines):
        tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=1.0), 34.0)
        out, fired = [], []
        for i, (d, line) in enumerate(zip(seq, lines, strict=True)):
            o, f = tr.step(i / 34.0, i, d if isinstance(d, Decision) else _d(d))
            o = tr.carry(i / 34.0, o, line)
            out.append(o.direction.value)
            fired += [(e.kind, e.pulse) for e in f]
        return out, fired
    rest = ["same"] * 40 + ["stopped"] * 60
    out, _ = run(rest + [_lost()] * 30 + [_weak(0.01)] * 5 + [_weak(0.08)] * 5,
                 [None] * 130 + ["A"] * 10)
    assert out[100:135] == ["stopped"] * 35 and out[135:] == ["unknown"] * 5
    # a start: the lost windows before its first line stay stopped, the start fires as
    # it does without the rule (the machine's events are untouched)
    seq = rest + [_lost()] * 5 + ["same"] * 40
    out, fired = run(seq, [None] * 105 + ["B"] * 40)
    assert out[100:105] == ["stopped"] * 5
    tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=1.0), 34.0)
    plain = []
    for i, d in enumerate(seq):
        plain += [(e.kind, e.pulse) for e in
                  tr.step(i / 34.0, i, d if isinstance(d, Decision) else _d(d))[1]]
    assert fired == plain and ("started", 105 + 16) in fired
    # a known direction: a window with no line is unknown, as before
    out, _ = run(["same"] * 40 + [_lost()] * 5, [None] * 45)
    assert out[40:] == ["unknown"] * 5


def test_a_slow_doubtful_answer_starts_nothing():
    """Below the rate a new direction needs (twice the floor) a doubtful answer is no
    start either: the end of a spin-down leaves slow, shaky tracks."""
    tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.0), 34.0)
    fired = []
    for i in range(40):
        fired += tr.step(i / 34.0, i, _d("stopped"))[1]
    for i in range(40, 100):
        fired += tr.step(i / 34.0, i, _doubt(rate=0.08))[1]
    assert fired == []


def test_unknown_answers_pause_the_confirmation_within_twice_its_time():
    """Closed form, 34 pulses/s, confirm 17 pulses: 10 'reversed', 5 unknown, 7 more
    confirm at the 7th (17 within 34 pulses); 9, then 30 unknown, then 9 never do (at
    most 9 within any 34 pulses); another known kind in between restarts the count."""
    def run(seq):
        tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.0), 34.0)
        fired = []
        for i, d in enumerate(["same"] * 20 + seq):
            fired += [(e.kind, e.pulse) for e in tr.step(i / 34.0, i, _d(d))[1]]
        return fired
    assert run(["reversed"] * 10 + ["unknown"] * 5 + ["reversed"] * 7) == [("reversed", 41)]
    assert run(["reversed"] * 9 + ["unknown"] * 30 + ["reversed"] * 9) == []
    assert run(["reversed"] * 10 + ["same"] + ["reversed"] * 16) == []


def test_a_reversal_waits_until_a_fan_could_have_made_it():
    """Closed form, 34 pulses/s, 0.3 Hz/s: 'same' at 0.21 Hz until pulse 99 (2.912 s),
    then the other way at 0.2 Hz. From 0.21 Hz through zero to 0.2 Hz the other way
    takes 0.41 / 0.3 = 1.367 s: 18 pulses of the mirror line (0.53 s, a lost track taken
    up on the mirror of the blade pattern) fire nothing and are published as unknown, and
    the old direction goes on without an event; held on, the reversal fires at the first
    pulse from 4.278 s (pulse 146), the count of 17 having been met long before. The wait
    lasts at most reversal_hold_s of answers the other way: 0.8 s from pulse 100 (2.941 s)
    ends at 3.741 s, pulse 128, and still outlasts the mirror line."""
    def run(n_other, then_same=0, hold=10.0):
        tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.3,
                                            reversal_hold_s=hold), 34.0)
        fired, published = [], []
        seq = [("same", 0.21)] * 100 + [("reversed", 0.2)] * n_other + \
            [("same", 0.21)] * then_same
        for i, (d, r) in enumerate(seq):
            out, ev = tr.step(i / 34.0, i, _d(d, r))
            fired += [(e.kind, e.pulse) for e in ev]
            published.append(out.direction)
        return fired, published, tr
    for hold in (10.0, 0.8):
        fired, published, tr = run(18, then_same=40, hold=hold)
        assert fired == [] and tr.known == Kind.SAME
        assert set(published[100:118]) == {"unknown"} and set(published[118:]) == {"same"}
    fired, published, _ = run(60)
    assert fired == [("reversed", 146)]
    assert set(published[100:146]) == {"unknown"} and set(published[146:]) == {"reversed"}
    assert run(60, hold=0.8)[0] == [("reversed", 128)]


@pytest.mark.parametrize(("between_hz", "fires"), [(0.03, True), (0.21, False)])
def test_a_run_the_other_way_after_the_fan_read_slow_is_judged_afresh(between_hz, fires):
    """Closed form, 34 pulses/s, 0.3 Hz/s: 'same' at 0.21 Hz until pulse 99, then 4
    pulses the other way at 0.14 Hz (an early lock: sudden, 0.12 s after 0.21 Hz), then
    51 pulses (1.5 s) without a direction reading ``between_hz``, then the other way at
    0.17 Hz on a line never shown to beat its mirror. Read under the floor (0.05 Hz),
    the fan was near zero: the new run is judged afresh, no longer sudden (3.2 s after
    0.21 Hz against 0.5 x 1.27 s), and the reversal fires, its count long met, once the
    short meter's window (1.5 s, 51 pulses) has passed since the fan last read slow
    (pulse 154 + 51): the fan may have come to rest there, unseen till then. Read at the
    old speed the whole time, the new run is still the mirror image and is held. (Seen:
    spent scene 2300001's reversal held 5.9 s, until its line's check.)"""
    tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.3), 34.0)
    between = Decision(Direction.UNKNOWN, None, None, between_hz, None, 0.4, "weak evidence")
    seq = [_d("same", 0.21)] * 100 + [_d("reversed", 0.14, checked=False)] * 4 \
        + [between] * 51 + [_d("reversed", 0.17, checked=False)] * 60
    fired = []
    for i, d in enumerate(seq):
        fired += [(e.kind, e.pulse) for e in tr.step(i / 34.0, i, d)[1]]
    assert fired == ([("reversed", 154 + 51)] if fires else [])


@pytest.mark.parametrize(("fast_pulses", "fires"), [(10, True), (40, False)])
def test_a_short_faster_lock_of_the_old_direction_does_not_make_a_reversal_sudden(
        fast_pulses, fires):
    """Closed form, 34 pulses/s, 0.3 Hz/s, runs followed for 1 s: 'same' at 0.19 Hz
    until pulse 99 (2.912 s), 60 pulses with no track, ``fast_pulses`` of 'same' at
    0.69 Hz (a new lock, more than a quarter above the fan's last speed), then the other
    way at 0.13 Hz on a line never shown to beat its mirror. From 0.19 Hz through zero to
    0.13 Hz takes 0.32 / 0.3 = 1.07 s, long passed: a lock of 10 pulses (0.29 s, under
    the 1 s a run must be followed) is an alias line as likely as the fan, and the
    reversal fires at its 17th pulse (160 + 10 + 16). Followed for 40 pulses (1.18 s) it
    is the fan's speed, from which the other way 0.03 s later would need 2.7 s: the
    mirror image, held. (Seen: spent held-out 6900009's reversal held 5 s after a
    two-decision lock at 0.69 Hz.)"""
    tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.3), 34.0)
    seq = [_d("same", 0.19)] * 100 + [_lost()] * 60 \
        + [_d("same", 0.69, checked=False)] * fast_pulses \
        + [_d("reversed", 0.13, checked=False)] * 60
    fired = []
    for i, d in enumerate(seq):
        fired += [(e.kind, e.pulse) for e in tr.step(i / 34.0, i, d)[1]]
    assert fired == ([("reversed", 160 + fast_pulses + 16)] if fires else [])


@pytest.mark.parametrize("carried", [True, False])
def test_a_faster_lock_renews_the_chain_once_the_fan_was_seen_at_its_speed_before(carried):
    """Closed form, 34 pulses/s, 0.3 Hz/s, runs followed for 1 s: a start answered `same`
    at 0.15 Hz, then once at 0.08 Hz (a follower's dip: the chain's speed), then a lock
    answering `same` at 0.3 Hz for 6 pulses on line B (faster than the chain by more than
    a quarter, not yet followed: it does not renew the chain), 30 windows in doubt at
    0.3 Hz on B (carried as `same`: its line followed without a break), a second lock
    answering `same` at 0.3 Hz for 4 pulses, then `reversed` at 0.3 Hz on a line never
    shown to beat its mirror. The fan was seen at 0.3 Hz before the second lock (answered
    and carried): the second lock renews the chain, and the other way 0.12 s later,
    which would need 2 s through zero, is the mirror image, held (no event). Without the
    carried windows (30 windows with no track instead) nothing vouches for 0.3 Hz, the
    chain is the dip 1.1 s before, and the reversal fires once a fan could have made it
    from 0.08 Hz (1.27 s after the dip). (Spent held-out 7100008: a
    start's mirror lock corrected so; held-out 6900009's single blip is the other case.)"""
    tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.3), 34.0)
    seq = [_d("stopped")] * 40 + [_d("same", 0.15)] * 30 + [_d("same", 0.08)] * 4 \
        + [_d("same", 0.3, checked=False)] * 6 + [_doubt(0.3) if carried else _lost()] * 30 \
        + [_d("same", 0.3, checked=False)] * 4 + [_d("reversed", 0.3, checked=False)] * 40
    lines = [None] * 40 + ["A"] * 34 + ["B"] * 6 + (["B"] if carried else [None]) * 30 \
        + ["C"] * 4 + ["D"] * 40
    fired = []
    for i, (d, line) in enumerate(zip(seq, lines, strict=True)):
        o, ev = tr.step(i / 34.0, i, d)
        tr.carry(i / 34.0, o, line)
        fired += [e.kind for e in ev]
    assert fired == (["started"] if carried else ["started", "reversed"])


@pytest.mark.parametrize("continuous", [True, False])
def test_a_line_followed_through_zero_in_a_doubtful_room_reverses(continuous):
    """Closed form, 10 decisions/s, 0.3 Hz/s, confirm 0.5 s (5 pulses), a room whose
    directions are in doubt: `same` answered at 0.4 Hz for 1 s on line A, then slowing at
    0.1 Hz/s to 0.15 Hz at 3.5 s (its line reaches zero at 5.0 s); a new track B reads
    the fan in doubt of its direction (its mirror fits as well) at +0.14 Hz, carried as
    `same`, down through zero at 5.0 s and up the other way (-0.01 Hz more per decision).
    A track's relative rate changes sign only through zero, whichever of the line and
    its mirror it follows: its windows at the rate a new direction needs (0.1 Hz, from
    6.0 s) are `reversed`, waited for until the meter could have seen a rest (the last
    window under the floor at 5.4 s, plus 1.5 s) and fired at 6.9 s. The same windows on
    a new lock C after zero say nothing of the way: no event, the direction `unknown`.
    (Spent held-out 7400011: a reversal so came 10 s late, to be confirmed.)"""
    tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.3), 10.0)

    def answer(r):
        return Decision(Direction.SAME, None, r / 0.4, r, None, 0.9, "test", turning=True,
                        doubtful_room=True)

    def doubt(r):
        return Decision(Direction.UNKNOWN, None, r / 0.4, abs(r), None, 0.3,
                        "direction to be confirmed", turning=abs(r) >= 0.1,
                        direction_doubt=True, doubtful_room=True)

    seq = [(answer(0.4), "A")] * 10 + [(answer(0.4 - 0.1 * j / 10), "A") for j in range(26)]
    seq += [(doubt(0.15 - 0.01 * j), "B" if j < 16 or continuous else "C")
            for j in range(1, 40)]
    fired, published = [], []
    for i, (d, line) in enumerate(seq):
        o, ev = tr.step(i / 10.0, i, d, line=line)
        published.append(tr.carry(i / 10.0, o, line).direction)
        fired += [(e.kind, round(e.t_s, 2)) for e in ev]
    assert published[36:40] == ["same"] * 4           # carried on B (0.14-0.11 Hz)
    if continuous:
        assert fired == [("reversed", 6.9)]
        assert published[-1] == "reversed"
    else:
        assert fired == [] and published[-1] == "unknown"


def test_a_sudden_run_is_judged_afresh_only_on_what_was_seen_after_its_verdict():
    """Closed form, 10 decisions/s, 0.3 Hz/s, confirm 0.5 s: a start's first lock answers
    `same` at 0.12 Hz (a start fires), once more at 0.10 Hz at 2.6 s, then one window
    reading 0.01 Hz (weak evidence), then `reversed` at 0.13 Hz from 2.8 s: sooner than
    half the 0.77 s a fan needs from 0.10 Hz through zero to 0.13 Hz, the mirror image,
    held. A window in doubt breaks the run at 5.9 s; it resumes at 6.0 s on a line that
    beat its mirror image. The slow window came before the run's verdict, which it did
    not change then; the resumed run keeps it and corrects the start's direction: no
    event. A slow window after the run's first answer (the variant) is news of a fan
    near zero: the resumed run is judged afresh, no longer sudden, and fires `reversed`.
    (Spent held-out 7200004: a start's track answered `same` while its rate estimate
    converged through zero to the fan's `reversed`; judged afresh on the slow window
    before it, the run fired a false reversal 6.6 s after the start.)"""
    def run(slow_after):
        tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=0.5,
                                            max_reversal_hz_s=0.3), 10.0)
        weak = Decision(Direction.UNKNOWN, None, 0.01, 0.01, None, 0.15, "weak evidence")
        rev = [_d("reversed", 0.13 + 0.01 * j, checked=False) for j in range(31)]
        seq = [_d("stopped")] * 20 + [_d("same", 0.12, checked=False)] * 6 \
            + [_d("same", 0.10, checked=False)] \
            + ([rev[0], weak] + rev[1:] if slow_after else [weak] + rev) \
            + [_doubt(0.45)] + [_d("reversed", 0.45)] * 10
        fired, published = [], []
        for i, d in enumerate(seq):
            o, ev = tr.step(i / 10.0, i, d)
            published.append(o.direction)
            fired += [e.kind for e in ev]
        return fired, published
    fired, published = run(False)
    assert fired == ["started"]
    assert published[30:59] == ["unknown"] * 29 and published[-1] == "reversed"
    assert run(True)[0] == ["started", "reversed"]


def test_the_old_direction_is_bounded_by_rest_and_by_how_fast_a_fan_speeds_up():
    """Closed form, 10 answers/s, 0.3 Hz/s: 'same' at 0.4 Hz, then at rest ('stopped')
    until 5.0 s, then a lock claiming 'same' at 0.26 Hz at 5.1 and 5.2 s, then
    'reversed' at 0.2 Hz. The two 'same' answers are a run not yet followed for
    ``followed_s`` (1 s) after rest was answered: a new lock on a fan that may be
    reversing, so they do not move where the fan was last seen (at rest at 5.0 s), and
    'reversed' at 0.2 Hz is possible from 5.0 + 0.2 / 0.3 = 5.667 s; the count (5
    answers from 5.3 s) is met by 5.7 s. (Counted, the lock would put the fan at
    0.06 Hz at 5.2 s, bounded from rest, and hold the reversal to 6.067 s: held-out
    1400010 waited 3.6 s so, the other way's answers judged a sudden mirror image.)"""
    tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=10.0,
                                        max_reversal_hz_s=0.3), 10.0)
    seq = [("same", 0.4)] * 40 + [("stopped", 0.0)] * 11 + [("same", 0.26)] * 2 + \
        [("reversed", 0.2)] * 20
    fired = []
    for i, (d, r) in enumerate(seq):
        fired += [(e.kind, round(e.t_s, 3)) for e in tr.step(i * 0.1, i, _d(d, r))[1]]
    assert fired == [("reversed", 5.7)]


def test_a_followed_run_after_rest_is_bounded_by_how_fast_a_fan_speeds_up():
    """Closed form, 10 answers/s, 0.3 Hz/s, no cap on the wait (``reversal_hold_s``
    10 s): 'same' at 0.4 Hz, at rest until 5.0 s, then 'same' at 0.4 Hz from 5.1 to
    6.3 s, followed for more than ``followed_s``: it counts, bounded by how fast a fan
    at rest at 5.0 s can speed up (0.39 Hz at 6.3 s), and 'reversed' at 0.2 Hz from
    6.4 s is possible from 6.3 + (0.39 + 0.2) / 0.3 = 8.267 s, fired at 8.3 s."""
    tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=10.0,
                                        max_reversal_hz_s=0.3, reversal_hold_s=10.0), 10.0)
    seq = [("same", 0.4)] * 40 + [("stopped", 0.0)] * 11 + [("same", 0.4)] * 13 + \
        [("reversed", 0.2)] * 30
    fired = []
    for i, (d, r) in enumerate(seq):
        fired += [(e.kind, round(e.t_s, 3)) for e in tr.step(i * 0.1, i, _d(d, r))[1]]
    assert fired == [("reversed", 8.3)]


@pytest.mark.parametrize("other, first", [
    # new locks on a fan just at rest, 0.33 Hz the other way for 0.7 s from 5.4 s:
    # possible from the last answer (0.06 Hz at 4.4 s) at 4.4 + 0.39 / 0.3 = 5.7 s, and
    # the count is met at 5.8 s; from the line's zero (5.0 s) only at 5.0 + 0.33 / 0.3
    # = 6.1 s, when they have ended
    ({j: ("reversed", 0.33) for j in range(9, 16)}, None),
    # a true reversal through zero at 5.0 s, answered the other way from 0.1 Hz at
    # 5.7 s on at 0.15 Hz/s: possible from 5.0 + 0.1 / 0.3 = 5.33 s, but the fan was
    # read slower than the floor until 5.3 s (the windows within 0.05 / 0.15 s of zero),
    # and a fan that came to rest there would read as motion on the short meter until
    # 5.3 + still_window_s (1.5 s) = 6.8 s: it fires then, its count long met
    ({j: ("reversed", 0.1 + 0.15 * 0.1 * (j - 12)) for j in range(12, 40)}, 6.8),
])
def test_a_reversal_is_timed_from_the_zero_of_the_slowing_line(other, first):
    """Closed form, 10 answers/s, 0.3 Hz/s: 'same' slowing from 0.4 Hz at 1 s at 0.1 Hz/s
    (its line reaches zero at 5.0 s), answered down to 0.06 Hz at 4.4 s, then unknown
    from 4.5 s (read slower than the floor up to 5.3 s, with no rate after) but for the
    answers ``other`` (index from 4.5 s). A fan cannot be turning the other way at some
    rate sooner than that rate's ramp from the zero of its line (a simulated day: new
    locks 0.4 s after the line's zero claimed 0.32-0.35 Hz for 0.8 s, and the wait,
    timed from the last answer of the old way, 1.2 s before, let them through as a
    'reversed')."""
    tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=10.0), 10.0)
    for i in range(10):
        tr.step(i * 0.1, i, _d("same", 0.4))
    k = _slow_down(tr, 1.0, 4.4, 0.4, -0.1, pulse=10)
    fired = []
    for j in range(40):
        t = round(4.5 + 0.1 * j, 3)
        d = _d(*other[j]) if j in other else _d("unknown", 0.0) if t <= 5.3 else _none()
        fired += [(e.kind, t) for e in tr.step(t, k + j, d)[1]]
    assert fired == ([] if first is None else [("reversed", first)])


@pytest.mark.parametrize("after", ["a lock the other way", "a reversal"])
def test_a_new_direction_waits_for_the_zero_of_a_line_followed_down_to_the_floor(after):
    """Closed form, 10 answers/s, 0.3 Hz/s: 'same' slowing at 0.044 Hz/s from 0.3 Hz,
    answered on its line down to 0.054 Hz (at 5.6 s; the line reaches zero at 6.82 s).
    Then at once (spent held-out 4300001, a 6-blade fan at 7.8 dB): a lock the other
    way at 0.125-0.155 Hz for 0.6 s (an alias line; no window reads the fan slower than
    the floor), no track, and rest. A fan on that line turns the other way at 0.125 Hz
    no sooner than 6.82 + 0.125 / 0.3 = 7.24 s: the lock is held and only the stop
    fires. (Timed from the last answer alone, 5.6 + 0.179 / 0.3 = 6.2 s, its count met
    at 6.1 s, it fired a 'reversed' before the stop.) A true reversal through the line's
    zero at about its slope is not held: from 0.1 Hz at 9.2 s on, it fires at its
    count (9.6 s)."""
    tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=0.75), 10.0)
    seq = [_d("same", round(0.3 - 0.044 * 0.1 * j, 4)) for j in range(57)]
    assert seq[-1].rate_hz == pytest.approx(0.0536, abs=0.002)
    if after == "a lock the other way":
        seq += [_d("reversed", 0.125 + 0.006 * j) for j in range(6)] + [_none()] * 10 \
            + [_d("stopped")] * 40
    else:
        seq += [_none()] * 35 + [_d("reversed", 0.1 + 0.044 * 0.1 * j) for j in range(40)]
    fired = []
    for i, d in enumerate(seq):
        fired += [(e.kind, round(e.t_s, 3)) for e in tr.step(round(i * 0.1, 3), i, d)[1]]
    if after == "a lock the other way":
        assert [k for k, _ in fired] == ["stopped"]
    else:
        assert fired == [("reversed", 9.6)]


def _none():
    """A window with no track: no direction, no rate."""
    return Decision(Direction.UNKNOWN, None, None, None, None, 0.0, "no lock")


def test_a_new_direction_waits_for_the_meter_to_see_a_fan_read_near_zero_come_to_rest():
    """Closed form, 10 answers/s: 'same' at 0.2 Hz, then slowing to 0.05 Hz at 5.0 s
    (at 0.05 Hz/s, the line of answers from 0.15 Hz up put its zero near 8 s), read
    slower than the floor until 6.5 s, then the other way at 0.13 Hz for 0.8 s (the
    tracks a spin-down's end leaves, spent held-out 4100011, twice: a fan 3.5 m away at
    30 dB creeping to rest reads as motion on the short meter for about 1.1 s after it
    stops), then at rest. The other way is not taken before 6.5 + still_window_s
    (1.5 s) = 8.0 s, by which time rest is answered: only the stop fires. (Before, its
    count met at 7.1 s, a false 'reversed' came 0.8 s before the stop.)"""
    assert _after_a_spin_down(0.13, 8) == ["stopped"]


def _after_a_spin_down(other_hz: float, answers: int, quiet_from: int | None = None
                       ) -> list[EventKind]:
    """The events of: 'same' at 0.2 Hz for 2 s, slowing at 0.05 Hz/s for 3 s, read
    slower than the floor for 1.5 s, the other way at ``other_hz`` for ``answers``
    answers, then at rest (10 answers/s); the short meter quiet from answer
    ``quiet_from`` on (None: never)."""
    tr = Transitions(TransitionSettings(confirm_s=0.5, stop_confirm_s=0.75), 10.0)
    seq = [_d("same", 0.2)] * 20 + [_d("same", 0.2 - 0.05 * 0.1 * j) for j in range(31)] \
        + [_d("unknown", 0.04 - 0.0027 * j) for j in range(15)] \
        + [_d("reversed", other_hz)] * answers + [_d("stopped")] * 60
    fired = []
    for i, d in enumerate(seq):
        quiet = quiet_from is not None and i >= quiet_from
        fired += [e.kind for e in tr.step(round(i * 0.1, 3), i, d, quiet=quiet)[1]]
    return fired


@pytest.mark.parametrize("meter_moves, fired_kinds", [(False, ["stopped"]),
                                                      (True, ["reversed"])])
def test_a_new_direction_after_the_wait_for_rest_needs_the_meter_to_see_motion(
        meter_moves, fired_kinds):
    """Closed form, 10 answers/s: as above, but the other way is answered at 0.11 Hz
    from 6.5 s for 3 s, past the wait (8.0 s). A lock on a fan at rest (spent held-out
    6600017: the fan stopped at 360.9 s, a lock the other way at 0.11 Hz from 361.3 s,
    the short meter quiet from 362.3 s) was published at 362.5 s as a reversal, and its
    stop came 4.7 s late: with the meter quiet from 7.8 s nothing but the stop fires. A
    fan that reversed moves its echoes: with the meter reading motion the reversal is
    published once the wait ends."""
    fired = _after_a_spin_down(0.11, 30, quiet_from=None if meter_moves else 78)
    assert fired[:1] == fired_kinds


def _slow_down(tr, t0, t1, r0, slope, pulse=0):
    """Answers 'same' every 0.1 s from t0 to t1 on the line r0 + slope (t - t0)."""
    n = int(round((t1 - t0) / 0.1))
    for j in range(n + 1):
        t = t0 + 0.1 * j
        tr.step(t, pulse + j, _d("same", r0 + slope * (t - t0)))
    return pulse + n + 1


def _quiet_with(tr, t0, pulse, answers, until=20.0):
    """'stopped' answers every 0.1 s from t0, with ``answers`` (index: decision) in
    their place; (the time the stop fires, None: never; the states published up to it)."""
    states = []
    for j in range(int(round((until - t0) / 0.1))):
        t = t0 + 0.1 * j
        state, ev = tr.step(t, pulse + j, answers.get(j, _d("stopped")))
        states.append(state)
        if ev:
            assert [e.kind for e in tr.events] == ["stopped"]
            return round(t, 3), states
    return None, states


def _stop_time(tr, t0, pulse, until=20.0):
    """'stopped' answers every 0.1 s from t0; the time the stop fires (None: never),
    every state before it unknown."""
    t, states = _quiet_with(tr, t0, pulse, {}, until)
    assert all(s.direction == "unknown" for s in (states[:-1] if t is not None else states))
    return t


def _slowed(st, t1, slope):
    """Known turning at 0.3 Hz (10 answers/s), slowing at ``slope`` Hz/s from t = 1 s
    to ``t1``; (the machine, its next pulse)."""
    tr = Transitions(st, 10.0)
    for i in range(10):
        tr.step(i * 0.1, i, _d("same", 0.3))
    return tr, _slow_down(tr, 1.0, t1, 0.3, slope, pulse=10)


def _slowing_then_quiet(st):
    """Known turning at 0.3 Hz, slowing at 0.05 Hz/s from t = 1 s to 4 s (0.15 Hz),
    then quiet from 4.1 s; the time the stop fires."""
    tr, k = _slowed(st, 4.0, -0.05)
    return _stop_time(tr, 4.1, k)


def test_a_slowing_fan_is_not_stopped_before_it_could_show_a_reversal():
    """Closed form: the answers' line reaches zero at 4 + 0.15/0.05 = 7 s; reversing, the
    fan would be back at 0.1 Hz 2 s later, and seen 0.5 s after that: no stop before
    9.5 s (the cap after the last turning answer set out of reach)."""
    t = _slowing_then_quiet(TransitionSettings(reversal_guard_s=10.0, meter_lag_s=0.5))
    assert t is not None and 9.5 - 1e-9 <= t < 9.7


def test_a_coasting_fan_is_not_waited_for_at_its_own_slow_slope():
    """Slowing at 0.025 Hz/s, 0.275 Hz at 1 s to 0.15 Hz at 6 s (a fan left to coast):
    zero by 6 + 0.15/0.025 = 12 s from the answers' line; a reversing fan is driven back
    up at 0.05 Hz/s at least, back at 0.1 Hz 2 s after zero and seen 0.5 s later: no
    stop before 14.5 s, and no wait for the 16.5 s the coast's own slope would give."""
    tr = Transitions(TransitionSettings(reversal_guard_s=20.0, meter_lag_s=0.5), 10.0)
    for i in range(10):
        tr.step(i * 0.1, i, _d("same", 0.275))
    k = _slow_down(tr, 1.0, 6.0, 0.275, -0.025, pulse=10)
    t = _stop_time(tr, 6.1, k, until=25.0)
    assert t is not None and 14.5 - 1e-9 <= t < 14.7, t


def test_the_wait_for_a_reversal_is_capped_after_the_fan_was_last_seen_turning():
    """A stop is due within 3 s of rest: the wait never runs beyond reversal_guard_s
    (3 s) after the last turning answer (4.0 s)."""
    t = _slowing_then_quiet(TransitionSettings())
    assert t is not None and 7.0 - 1e-9 <= t < 7.2


def test_without_a_slowing_line_a_stop_needs_only_its_confirmation():
    """Quiet right after a steady 0.3 Hz (an abrupt stop): stop_confirm_s (0.75 s) after
    the first quiet answer, whatever the guard."""
    tr = Transitions(TransitionSettings(reversal_guard_s=10.0), 10.0)
    for i in range(40):
        tr.step(i * 0.1, i, _d("same", 0.3))
    t = _stop_time(tr, 4.0, 40)
    assert t is not None and 4.7 - 1e-9 <= t < 4.9


def test_a_slow_fans_sudden_quiet_is_waited_for_as_a_reversal_out_of_view():
    """Quiet right after a steady 0.2 Hz, no slowing seen: braked as hard as a fan can be
    (0.3 Hz/s) it was at zero 0.2/0.3 s after its last answer (3.9 s), having turned
    0.2^2/0.6 = 0.067 of a revolution, inside half a blade period (0.125 of 4 blades): a
    reversal may have turned there unseen. Back at 0.1 Hz at 0.05 Hz/s 2 s later, seen
    1.3 s after that: no stop before 3.9 + 0.667 + 2 + 1.3 = 7.867 s, or, with the
    default cap, 3 s after the last answer (6.9 s)."""
    for guard_s, due in ((10.0, 3.9 + 0.2 / 0.3 + 2.0 + 1.3), (3.0, 6.9)):
        tr = Transitions(TransitionSettings(reversal_guard_s=guard_s), 10.0)
        for i in range(40):
            tr.step(i * 0.1, i, _d("same", 0.2))
        t = _stop_time(tr, 4.0, 40)
        assert t is not None and due - 1e-9 <= t < due + 0.1 + 1e-9, (guard_s, t)


@pytest.mark.parametrize("slow_answers", [True, False])
def test_a_slow_last_answer_holds_a_stop_whatever_a_lagging_line_says(slow_answers):
    """Answers sagging at 0.02 Hz/s from 0.34 Hz (1-3 s: their line reaches zero at 18 s,
    no rest now), then two at 0.06 Hz (3.1, 3.2 s: too slow for the line) and quiet:
    the fan may have turned round zero out of view. Braked at 0.3 Hz/s it was at zero
    by 3.4 s, back at 0.1 Hz (0.05 Hz/s) 2 s later and seen 1.3 s after that (6.7 s),
    capped 3 s after its last answer: no stop before 6.2 s. Without the slow answers the
    last one was 0.30 Hz, beyond the reach of a turn out of view (0.274 Hz): an abrupt
    stop, called stop_confirm_s after the quiet begins (3.1 s)."""
    tr = Transitions(TransitionSettings(), 10.0)
    for i in range(10):
        tr.step(i * 0.1, i, _d("same", 0.34))
    k = _slow_down(tr, 1.0, 3.0, 0.34, -0.02, pulse=10)
    t0 = 3.1
    if slow_answers:
        for j in range(2):
            tr.step(3.1 + 0.1 * j, k + j, _d("same", 0.06))
        k, t0 = k + 2, 3.3
    t = _stop_time(tr, t0, k)
    assert t is not None
    if slow_answers:
        assert 6.2 - 1e-9 <= t < 6.4, t
    else:
        assert 3.8 - 1e-9 <= t < 4.0, t


@pytest.mark.parametrize("run, held", [(3, False), (12, True)])
def test_only_answers_that_followed_the_fan_hold_a_sudden_quiet(run, held):
    """A steady 0.3 Hz (beyond a turn out of view), 1 s of unknown, then answers of the
    same direction at 0.12 Hz and quiet from their end. Three of them (0.3 s: a new lock
    on a fan already at rest claiming the old direction) are not a fan followed down to
    0.12 Hz: the stop comes stop_confirm_s after the quiet begins. Twelve (1.2 s,
    followed_s 1.0) are: braked at 0.3 Hz/s the fan was at zero 0.4 s after the last
    one, and the wait runs to the cap, 3 s after it."""
    tr = Transitions(TransitionSettings(), 10.0)
    for i in range(30):
        tr.step(i * 0.1, i, _d("same", 0.3))
    for i in range(30, 40):
        tr.step(i * 0.1, i, _d("unknown", 0.3))
    for i in range(40, 40 + run):
        tr.step(i * 0.1, i, _d("same", 0.12))
    last = (40 + run - 1) * 0.1
    t = _stop_time(tr, last + 0.1, 40 + run)
    assert t is not None
    if held:
        assert last + 3.0 - 1e-9 <= t < last + 3.2, (t, last)
    else:
        assert last + 0.8 - 1e-9 <= t < last + 1.0, (t, last)


@pytest.mark.parametrize("rate, held", [(0.27, True), (0.28, False)])
def test_only_a_fan_that_could_reach_zero_out_of_view_holds_a_sudden_quiet(rate, held):
    """The edge: braked at 0.3 Hz/s a fan turns r^2 / 0.6 of a revolution to zero, which
    fits into half a blade period of 4 blades (0.125) below r = sqrt(0.075) = 0.2739 Hz.
    A faster fan would have been seen slowing: its sudden quiet is an abrupt stop,
    called after stop_confirm_s (0.75 s)."""
    assert 0.27 < math.sqrt(2 * 0.3 * 0.125) < 0.28
    tr = Transitions(TransitionSettings(reversal_guard_s=10.0), 10.0)
    for i in range(40):
        tr.step(i * 0.1, i, _d("same", rate))
    t = _stop_time(tr, 4.0, 40)
    assert t is not None
    assert (t > 7.0) == held, t


def test_a_line_that_reaches_zero_only_much_later_does_not_hold_a_stop():
    """Answers sagging at 0.02 Hz/s from 0.45 Hz (a track breaking up after an abrupt
    stop) put zero 20 s off: the rest seen now is not the end of that line, and the stop
    needs only stop_confirm_s (0.75 s) after the first quiet answer."""
    tr = Transitions(TransitionSettings(), 10.0)
    k = _slow_down(tr, 0.0, 3.0, 0.45, -0.02)
    t = _stop_time(tr, 3.1, k)
    assert t is not None and 3.8 - 1e-9 <= t < 4.0, t


def test_a_lone_answer_of_the_old_direction_does_not_restart_a_stop():
    """Quiet after a steady 0.3 Hz, 10 answers/s, one 'same' at 0.13 Hz at 4.3 s (a new
    lock on a fan at rest): published unknown, it pauses the count of eight quiet answers
    as an unknown answer would (4.8 s, one answer after 4.7 s without it; restarted, the
    count would end at 5.1 s); two in a row (4.3, 4.4 s) are the fan turning again: the
    count restarts after them (4.5 + 0.7 = 5.2 s). (Without the wait for a reversal out
    of view, blind_turn_rev 0, which the answers at 0.13 Hz would start: the count alone.)"""
    def run(blips):
        tr = Transitions(TransitionSettings(reversal_guard_s=10.0, blind_turn_rev=0.0), 10.0)
        for i in range(40):
            tr.step(i * 0.1, i, _d("same", 0.3))
        t, states = _quiet_with(tr, 4.0, 40, {j: _d("same", 0.13) for j in blips}, 7.0)
        assert states[min(blips)].direction == "unknown"
        return t
    assert run({3}) == 4.8
    assert run({3, 4}) == 5.2


def test_a_lone_answer_of_the_old_direction_does_not_move_the_cap_of_the_wait():
    """The slowing fan of the capped wait (last turning answer at 4.0 s, stop due at
    7.0 s), with one 'same' at 0.12 Hz at 5.0 s amid the quiet answers: still 7.0 s."""
    tr, k = _slowed(TransitionSettings(), 4.0, -0.05)
    fired, _ = _quiet_with(tr, 4.1, k, {9: _d("same", 0.12)}, 10.1)
    assert fired is not None and 7.0 - 1e-9 <= fired < 7.2, fired


def test_past_the_zero_of_its_slowing_line_the_old_direction_needs_a_new_directions_rate():
    """Slowing at 0.1 Hz/s, 0.3 Hz at 1 s to 0.15 Hz at 2.5 s: the line reaches zero at
    4.0 s; quiet from 2.6 s, the stop is due at the cap, 2.5 + 3 = 5.5 s. Four 'same'
    answers at 0.07 Hz at 4.5-4.8 s (a new lock on the fan at rest) are under the 0.1 Hz
    a new direction needs: published unknown, they neither restart the count nor move
    the cap (renewed, the stop would wait for 4.0 + 0.1/0.1 + 1.3 = 6.3 s). At 0.12 Hz
    they are the fan turning again: no stop before 4.9 + 0.7 = 5.6 s."""
    def run(rate):
        tr, k = _slowed(TransitionSettings(), 2.5, -0.1)
        t, states = _quiet_with(tr, 2.6, k, {j: _d("same", rate) for j in range(19, 23)},
                                8.6)
        if rate < 0.1:
            assert all(s.direction == "unknown" and "0.1 Hz needed" in s.reason
                       for s in states[19:23])
        return t
    assert run(0.07) == 5.5
    assert run(0.12) >= 5.6


@pytest.mark.parametrize("run, due", [(7, 5.5), (12, 6.3)])
def test_a_new_run_of_the_old_direction_near_zero_renews_the_cap_only_once_it_lasts(run, due):
    """The line of the test above (zero at 4.0 s, below the floor from 3.5 s), quiet from
    2.6 s, then a run of 'same' answers at 0.12 Hz from 3.6 s (over the 0.1 Hz a new
    direction needs, so they are taken). Seven of them (0.7 s: a new lock on a fan just
    at rest; one claimed 0.11-0.125 Hz for 0.6 s in a simulated day) do not renew the
    cap: the stop comes at 2.5 + 3 = 5.5 s (renewed, the wait would end where the line
    says, 4.0 + 0.1/0.1 + 1.3 = 6.3 s). Twelve (1.2 s, over followed_s) are a fan
    followed without a break: they renew it, and the wait ends at 6.3 s."""
    tr = Transitions(TransitionSettings(), 10.0)
    k = _slow_down(tr, 0.0, 2.5, 0.4, -0.1)
    fired, _ = _quiet_with(tr, 2.6, k, {10 + j: _d("same", 0.12) for j in range(run)}, 8.6)
    assert fired is not None and due - 1e-9 <= fired < due + 0.2, fired


def test_an_early_answer_the_other_way_neither_ends_the_wait_nor_renews_its_cap():
    """A fan slowing at 0.1 Hz/s from 0.3 Hz at 1 s to 0.15 Hz at 2.5 s, quiet from 2.6
    s, with one 'reversed' at 0.14 Hz at 3.5 s: too soon for a fan to have reversed, it
    is not taken. It is a sign of a reversal, not a reason to drop the wait (dropped, the
    stop came at 3.6 + 0.7 = 4.3 s); and it is no answer of the known direction, so the
    wait is capped 3 s after the last of those, at 2.5 + 3 = 5.5 s (renewed, at 6.5 s:
    a new lock on the demo's fan at rest held its stop 3.2 s after rest that way)."""
    tr, k = _slowed(TransitionSettings(), 2.5, -0.1)
    fired, states = _quiet_with(tr, 2.6, k, {9: _d("reversed", 0.14)}, 6.6)
    assert all(s.direction == "unknown" for s in states[:-1])
    assert fired == 5.5, fired
    assert [e.kind for e in tr.events] == ["stopped"]


def test_a_fan_that_holds_its_speed_forgets_the_slowing():
    """Slowing at 0.1 Hz/s from 0.5 to 0.3 Hz, then holding 0.3 Hz for 2.1 s (the slope
    of the last 2 s of answers is 0): a stop after that needs only stop_confirm_s."""
    tr = Transitions(TransitionSettings(reversal_guard_s=10.0), 10.0)
    for i in range(10):
        tr.step(i * 0.1, i, _d("same", 0.5))
    k = _slow_down(tr, 1.0, 3.0, 0.5, -0.1, pulse=10)
    for j in range(21):
        tr.step(3.1 + 0.1 * j, k + j, _d("same", 0.3))
    t = _stop_time(tr, 5.3, k + 21)
    assert t is not None and 6.0 - 1e-9 <= t < 6.2


def test_slow_answers_keep_the_guard():
    """Below three times the floor the answers neither move the line nor end the wait,
    not even answers stuck at one rate (near the floor the track lags and flattens);
    zero by 5 s from the line, + 0.1/0.1 + 0.5 s."""
    tr = Transitions(TransitionSettings(reversal_guard_s=10.0, meter_lag_s=0.5), 10.0)
    for i in range(10):
        tr.step(i * 0.1, i, _d("same", 0.4))
    k = _slow_down(tr, 1.0, 3.0, 0.4, -0.1, pulse=10)      # 0.2 Hz at 3 s: zero by 5 s
    k = _slow_down(tr, 3.1, 4.0, 0.14, 0.0, pulse=k)       # stuck at 0.14 Hz
    t = _stop_time(tr, 4.1, k)
    assert t is not None and 5.0 + 1.5 - 1e-9 <= t < 6.7


def test_slow_new_direction_is_not_taken():
    """Below change_factor x floor (0.1 Hz) a new direction is never confirmed."""
    tr = Transitions(TransitionSettings(), 34.0)
    for i in range(40):
        tr.step(i / 34.0, i, _d("same", 0.4))
    fired = [e for i in range(40, 200) for e in tr.step(i / 34.0, i, _d("reversed", 0.07))[1]]
    assert fired == [] and tr.known == Kind.SAME


def test_truth_events_of_a_schedule():
    """Closed forms: a 10 s ramp from +0.45 to -0.45 Hz reaches -0.15 Hz at 10 + 6.667 s;
    a spin-down to rest ends at its ramp's end; a start from rest passes 0.15 Hz at 1/3
    of a 6 s ramp to 0.45 Hz."""
    sch = parse("ccw:0.45:10,cw:0.45:15~10,stop:0:10~5,ccw:0.45:10~6")
    ev = truth_events(sch, 50.0)
    assert [e.kind for e in ev] == ["reversed", "stopped", "started"]
    assert ev[0].t_s == pytest.approx(10 + 10 * 0.6 / 0.9, abs=0.01)
    assert ev[1].t_s == pytest.approx(30.0, abs=0.01)
    assert ev[2].t_s == pytest.approx(35 + 6 / 3, abs=0.01)
    # true since: the zero crossing at the ramp's middle, the departure from rest
    assert ev[0].since_s == pytest.approx(15.0, abs=0.01)
    assert ev[1].since_s is None
    assert ev[2].since_s == pytest.approx(35.0, abs=0.01)


def test_a_start_called_on_the_way_to_the_timing_rate_is_a_hit():
    """A start is right from the moment the fan leaves rest, though its latency is
    timed from 0.15 Hz: called 1.5 s before that on a slow spin-up it is a hit (with
    a negative latency); one called while the fan still rests is false."""
    truth = [TruthEvent("started", 20.0, 1, since_s=17.0)]
    sc = score_events(truth, [("started", 18.5)])
    assert [(e.kind, lat) for e, lat in sc.hits] == [("started", -1.5)] and not sc.false
    sc = score_events(truth, [("started", 16.5)])
    assert not sc.hits and sc.false == [("started", 16.5)] and len(sc.missed) == 1


def test_score_matches_in_order_and_counts_false_and_missed():
    truth = [TruthEvent("stopped", 10.0, 0), TruthEvent("started", 20.0, 1)]
    sc = score_events(truth, [("reversed", 9.0), ("stopped", 12.0), ("started", 30.0)])
    assert [(e.kind, lat) for e, lat in sc.hits] == [("stopped", 2.0)]
    assert [e.kind for e in sc.missed] == ["started"]
    assert sc.false == [("reversed", 9.0), ("started", 30.0)]


def test_an_event_too_near_the_end_to_be_due_counts_only_if_found():
    """A rest that began 2.2 s before the end of a run (bench_day: 7197.8 s of 7200) is
    not a missed stop, a stop allowed 3 s; one found in time still counts."""
    truth = [TruthEvent("started", 100.0, 1), TruthEvent("stopped", 197.8, 0)]
    sc = score_events(truth, [("started", 100.5)], due_by=197.0)
    assert not sc.missed and len(sc.truth) == 1 and len(sc.hits) == 1
    sc = score_events(truth, [("started", 100.5), ("stopped", 199.5)], due_by=197.0)
    assert not sc.missed and len(sc.truth) == 2 and len(sc.hits) == 2
    sc = score_events(truth, [], due_by=197.0)
    assert [e.kind for e in sc.missed] == ["started"]


def test_score_names_the_slowest_events_of_each_kind():
    """Stops at 10, 20, 30, 40 s detected 2.0, 2.9, 1.5 and 2.5 s later: the summary
    names the three slowest, slowest first, by their truth time (where to trace)."""
    truth = [TruthEvent("stopped", t, 0) for t in (10.0, 20.0, 30.0, 40.0)]
    sc = score_events(truth, [("stopped", 12.0), ("stopped", 22.9), ("stopped", 31.5),
                              ("stopped", 42.5)])
    got = sc.summary()["slowest"]
    assert got["stopped"] == [(20.0, 2.9), (40.0, 2.5), (10.0, 2.0)]
    assert got["started"] == [] and got["reversed"] == []


def test_unknown_stretches_in_the_middle_of_a_turn_are_counted():
    """score_gaps counts an unknown stretch only between two answers of the same
    direction while the fan turns at 0.15 Hz or more throughout; its length runs from
    the first unknown state to the next known one."""
    t = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    d = ["same", "unknown", "unknown", "same", "unknown", "reversed",
         "unknown", "reversed", "unknown", "unknown", "stopped"]
    rate = [0.3, 0.3, 0.3, 0.3, 0.1, -0.3, -0.3, -0.3, -0.2, -0.1, 0.0]
    sc = Score(truth=[])
    score_gaps(sc, t, d, rate)
    assert [(a, round(b, 6)) for a, b in sc.gaps] == [(0.1, 0.2), (0.6, 0.1)]
    g = sc.summary()["unknown_while_turning"]
    assert g["n"] == 2 and g["over_0_5_s"] == 0 and g["max_s"] == 0.2
    slow = list(rate)
    slow[2] = 0.14                                   # a slow moment: not a turn's middle
    sc = Score(truth=[])
    score_gaps(sc, t, d, slow)
    assert [a for a, _ in sc.gaps] == [0.6]


def test_unknown_states_are_split_by_what_the_fan_was_doing():
    """Ten states, four of them unknown: one at rest, one at 0.05 Hz (a stop or a
    reversal on its way through zero), one on a ramp at 0.3 Hz, one steady. The split
    names each once, the known states nowhere, and its shares add up to the unknown
    share; merged runs add their counts."""
    sc = Score(truth=[])
    states = [(0.0, "unknown", False), (0.0, "stopped", False), (0.05, "unknown", True),
              (0.05, "same", True), (0.3, "unknown", True), (0.3, "same", True),
              (-0.3, "unknown", False), (0.3, "same", False), (0.3, "same", False),
              (0.3, "reversed", False)]
    for i, (rate, d, ramping) in enumerate(states):
        score_state(sc, float(i), rate, d, None, abs(rate) or None, ref_sign=1,
                    ramping=ramping)
    s = sc.summary()
    assert s["unknown_by_situation"] == {"at_rest": 0.1, "slow": 0.1, "ramping": 0.1,
                                         "steady": 0.1}
    assert sum(s["unknown_by_situation"].values()) == pytest.approx(
        s["state_share"]["unknown"])
    assert (sc.right, sc.wrong) == (5, 1)
    both = merge([sc, sc]).summary()
    assert both["unknown_by_situation"] == s["unknown_by_situation"]
    assert merge([sc, sc]).unknown_by == {"at_rest": 2, "slow": 2, "ramping": 2,
                                          "steady": 2}


@pytest.mark.parametrize("schedule, seed", [("ccw:0.45:10,ccw:0.25:10~2.5", 9),
                                            ("cw:0.3:10,cw:0.5:10~2.5", 10)])
def test_published_rate_leaves_a_steady_speed_with_the_ramp(scene, reference, schedule,
                                                            seed):
    """A ramp of 0.08 Hz/s from a steady speed: the window's mean and the track hold the
    old speed for a second or more, the follower has the new one within a few matches;
    the published rate is the follower's as soon as the two part (measured 95th
    percentile 7.6-9.5 %; before, the mean's 0.45 Hz was published for 0.7 s into a
    spin-down)."""
    _, rows, _ = _run(scene, reference, schedule, 20, seed=seed)
    sch = parse(schedule)
    t = np.array([r["t_s"] for r in rows])
    true = np.abs(sch.rate_at(t - 0.03))
    ramp = (t > 10.0) & (t < 12.5)
    err = np.array([1.0 if r["rate_hz"] is None else abs(r["rate_hz"] - a) / a
                    for r, a in zip(rows, true, strict=True)])
    assert np.percentile(err[ramp], 95) <= 0.12, np.percentile(err[ramp], 95)
    settled = (t > 3.0) & (t < 10.0)
    assert np.percentile(err[settled], 95) <= 0.01, np.percentile(err[settled], 95)


@pytest.mark.parametrize("schedule, seed", [("ccw:0.30:10,ccw:0.55:20~8", 3),
                                            ("ccw:0.30:10,ccw:0.55:20~8", 4),
                                            ("ccw:0.55:10,ccw:0.25:20~10", 4)])
def test_a_ramp_through_p_q_keeps_its_answer(scene, reference, schedule, seed):
    """A slow ramp passes rates near 1/22, 1/18 and 1/16 blade period per pulse, where
    the pulses see few angles and the rate's mirror fits the table about as well; a
    track that has followed the ramp is no alias (the alias of a changing rate fits no
    match), so the answer stays known (issue target: no unknown over 0.5 s; before,
    1.2 s of 'rate ambiguous' at each)."""
    _, rows, _ = _run(scene, reference, schedule, 30, seed=seed, snr_db=11.0)
    sch = parse(schedule)
    t = [r["t_s"] for r in rows]
    sc = Score(truth=[])
    score_gaps(sc, t, [r["direction"] for r in rows], sch.rate_at(np.array(t) - 0.03))
    assert not any(d > 0.5 for _, d in sc.gaps), sc.gaps
    late = [r["direction"] for r in rows if r["t_s"] > 8.0]
    assert set(late) <= {"same", "unknown"} and late.count("same") >= 0.97 * len(late)


@pytest.mark.parametrize("snr_db, seed", [(20.0, 5), (30.0, 5), (30.0, 3)])
def test_report_transitions_trials_at_high_snr(repo_root, snr_db, seed):
    """The `bladesonar report` transitions trials (their reference, their rendering, 40
    ppm of drift) that went wrong: the four truth events are found once each, in time,
    and nothing else fires.

    - 20 dB, seed 5: near the end of the 8 s spin-down the track had coasted through
      weak matches at 0.02 Hz, its rate follower carrying the deceleration through zero,
      and a lock on that line called the fan coming to rest 'reversed' (a track slower
      than the floor no longer coasts).
    - 30 dB, seeds 5 and 3: while no blade was in view the pulses matched one bin of the
      table's flat (blind) half at a quality of 0.13-0.23, a standing line that dragged
      the track to rest before the fan and the follower through zero: a false 'reversed'
      at the end of the spin-down (seed 5) and 0.14 s before the reversal's zero (seed
      3). Such matches now have next to no quality (fingerprint.FLAT_SHARE). Then, in
      seed 5, the short meter of the fan resting in view hovered about its threshold
      (clock drift) and the 6 s rest was never called stopped: a track standing still
      in view now lets a meter up to SEEN_STILL_FACTOR times the threshold read as
      rest."""
    from bladesonar import runtime_report as rr

    scene = load_scene(repo_root / SCENE)
    grid = rr.Grid(families=(rr.Family("transitions", ("paper-room",), (4,), (1.0,),
                                       (snr_db,), (), 6, transitions=True),))
    job = next(j for j in rr.jobs(grid) if j.seed == seed)
    base = rr.sweep_config(config.Config(), 4)
    ref = rr.make_reference(rr._scene(scene, 4), config.Config(), 4, grid)
    sched, total = rr.transitions_schedule(grid.transitions_schedule, job.true_ratio,
                                           grid.ref_rate_hz)
    clean, unit, p_fan = rr._render(rr._scene(scene, 4), base, sched, total, job.seed,
                                    drift_ppm=grid.transitions_drift_ppm)
    rows, _ = rr._tracked(rr._at_snr(clean, unit, p_fan, snr_db), base, ref)
    score = score_events(truth_events(parse(sched), total),
                         [(r["event"], true_time(r["t_s"], grid.transitions_drift_ppm))
                          for r in rows if r["event"]])
    assert score.false == [] and score.missed == []
    assert all(lat <= LATENCY[e.kind] for e, lat in score.hits)


def test_stream_time_is_scored_at_the_fans_time(scene):
    """The simulator's capture clock runs fast by the drift: against its own truth (each
    pulse's coupling edge in the capture, and its true emission time), a moment at
    stream time t (samples / nominal rate) is true_time(t) of the schedule, to well
    under a sample; the stream time itself is 40 ppm ahead (0.144 s in an hour)."""
    cfg = config.Config()
    _, truth = simulate(scene, cfg, 60.0, schedule="ccw:0.45:60", seed=2, snr_db=10.0,
                        drift_ppm=DRIFT_PPM)
    pulses = truth["pulses"]
    sample = np.array([p["sample"] for p in pulses], dtype=np.float64)
    emitted = np.array([p["time_s"] for p in pulses], dtype=np.float64)
    stream = sample / cfg.audio.sample_rate
    assert np.max(np.abs(true_time(stream, DRIFT_PPM) - emitted)) < 0.1 / cfg.audio.sample_rate
    late = stream[-1] - emitted[-1]
    assert abs(late - 60.0 * DRIFT_PPM * 1e-6) < 1e-3, late


def test_a_speed_published_bounds_new_lines_above_and_below(reference):
    """Closed forms of the bound on new lines (analyzer.RateBound, in Hz): a speed
    published for ANCHOR_TRUST_S (2 s) bounds at itself plus twice the steepest ramp
    (0.3 Hz/s) over the time since plus twice the floor (0.1 Hz); one just published
    (possibly a first answer on a wrong line, 1.8 times too slow) at UNTRUSTED_FACTOR
    (2.5) times itself, and the lower of the two bounds. Just past a reversal in a
    simulated day, 'reversed' at 0.21 Hz for 0.4 s, with the last trusted speed 0.09 Hz
    3 s before: 0.09 + 0.9 + 0.1 = 1.09 Hz let a re-check take a line at 0.92 Hz; now
    2.5 x 0.21 + 0.12 + 0.1 = 0.745 Hz. A trusted speed bounds from below by the same
    ramp and floor (Tracker.rate_least)."""
    from bladesonar.analyzer import new_analyzer
    from bladesonar.tuning import ANCHOR_TRUST_S, UNTRUSTED_FACTOR
    cfg = config.Config()
    an = new_analyzer(cfg, reference)
    hz = float(reference.meta["rate_hz"]) / reference.cycles_per_pulse

    def bound_at(t):
        an.rate_bound.step(t, an.state, an.tracker)
        return an.tracker.rate_bound * hz

    an.state = _d("same", 0.09)
    assert bound_at(10.0) == pytest.approx(0.09 + 0.1)
    an.state = _d("reversed", 0.21)
    assert bound_at(13.0) == pytest.approx(min(0.09 + 0.3 * 3 + 0.1, 2.5 * 0.21 + 0.1))
    an.state = _d("unknown")
    assert bound_at(13.4) == pytest.approx(2.5 * 0.21 + 0.3 * 0.4 + 0.1)
    assert UNTRUSTED_FACTOR == 2.5 and ANCHOR_TRUST_S == 2.0
    # published long enough, the speed is trusted and bounds at itself
    an.state = _d("reversed", 0.3)
    bound_at(20.0)
    assert bound_at(22.0) == pytest.approx(0.3 + 0.1)
    # and from below, by the same ramp and floor: 0.5 Hz trusted at 30 s, no new line
    # under 0.5 - 0.1 = 0.4 Hz then, 0.4 - 0.3 x 0.5 = 0.25 Hz half a second later, and
    # none at all from 31.33 s (a fan may be at rest by then); a stop sets none
    an.state = _d("same", 0.5)
    bound_at(28.0)
    bound_at(30.0)
    assert an.tracker.rate_least * hz == pytest.approx(0.4)
    an.state = _d("unknown")
    bound_at(30.5)
    assert an.tracker.rate_least * hz == pytest.approx(0.25)
    bound_at(31.4)
    assert an.tracker.rate_least == 0.0
    an.state = _d("stopped")
    bound_at(32.0)
    assert an.tracker.rate_least == 0.0


def test_a_speed_whose_direction_alone_is_in_doubt_bounds_new_lines(reference):
    """A fan published as turning with its direction in doubt (its mirror image fits as
    well: the same speed either way) bounds new lines like a known direction, by the
    same closed forms; a speed in doubt itself (an alias rate) does not. Spent held-out
    1700009, a room whose directions stayed in doubt for a whole run: unbounded, the
    tracker took a line at 1.4 Hz as the fan came to rest, and the stop came 4.4 s late
    instead of 2.2 s."""
    from bladesonar.analyzer import new_analyzer
    an = new_analyzer(config.Config(), reference)
    hz = float(reference.meta["rate_hz"]) / reference.cycles_per_pulse

    def bound_at(t):
        an.rate_bound.step(t, an.state, an.tracker)
        return an.tracker.rate_bound * hz

    an.state = _doubt(0.35)
    bound_at(10.0)
    assert bound_at(12.0) == pytest.approx(0.35 + 0.1)
    assert bound_at(13.0) == pytest.approx(0.35 + 0.1)
    an.state = Decision(Direction.UNKNOWN, None, None, None, None, 0.0, "weak evidence")
    assert bound_at(14.0) == pytest.approx(0.35 + 0.3 * 1.0 + 0.1)
    fresh = new_analyzer(config.Config(), reference)
    fresh.state = Decision(Direction.UNKNOWN, None, None, 0.35, None, 0.3,
                           "rate ambiguous: rate near 1/3 blade period per pulse",
                           turning=True)
    fresh.rate_bound.step(10.0, fresh.state, fresh.tracker)
    assert fresh.tracker.rate_bound == math.inf


def _walk(seq, prf=34.0):
    """Step a fresh machine (confirm 0.5 s, 0.3 Hz/s) through ``seq``; (events as (kind,
    pulse), published directions, the machine)."""
    tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.3,
                                        reversal_hold_s=1.0), prf)
    fired, published = [], []
    for i, d in enumerate(seq):
        out, ev = tr.step(i / prf, i, d)
        fired += [(e.kind, e.pulse) for e in ev]
        published.append(out.direction)
    return fired, published, tr


def test_a_sudden_reversal_needs_a_line_that_beat_its_mirror():
    """Closed form, 34 pulses/s, 0.3 Hz/s: 'same' at 0.21 Hz to pulse 99, then the other
    way at 0.2 Hz from pulse 100, 0.03 s later, where through zero a fan needs 0.41 / 0.3
    = 1.37 s: a track taken up on the mirror of the blade pattern. On a line not shown to
    beat its mirror (a new lock) it is never a reversal, however long it lasts; on one
    that has, it is one after reversal_hold_s (1 s: from pulse 100, at pulse 134)."""
    same = [_d("same", 0.21)] * 100
    fired, published, tr = _walk(same + [_d("reversed", 0.2, checked=False)] * 200)
    assert fired == [] and tr.known == Kind.SAME
    assert set(published[100:]) == {"unknown"}
    fired, _, _ = _walk(same + [_d("reversed", 0.2)] * 60)
    assert fired == [("reversed", 134)]


def test_a_reversal_through_zero_needs_no_mirror_check():
    """Closed form: 'same' slowing from 0.3 Hz at 0.15 Hz/s to 0.1 Hz (pulse 45, 1.32
    s), nothing for 1 s (34 pulses), then the other way from 0.1 Hz: 1.0 s after 0.1 Hz
    is later than the 0.67 s a fan needs through zero at 0.3 Hz/s, so a new line, not
    yet checked against its mirror, confirms at its 17th answer (pulse 79 + 16)."""
    down = [_d("same", 0.3 - 0.15 * i / 34) for i in range(46)]
    gap = [Decision(Direction.UNKNOWN, None, None, None, None, 0.0, "no match")] * 33
    up = [_d("reversed", 0.1 + 0.15 * i / 34, checked=False) for i in range(40)]
    fired, _, _ = _walk(down + gap + up)
    assert fired == [("reversed", 79 + 16)]


def test_a_reversal_after_a_coast_through_zero_is_judged_from_the_last_clear_match():
    """Closed form, 34 pulses/s, 0.3 Hz/s: 'same' at 0.15 Hz to pulse 99, then 44
    answers 'same' at 0.135 Hz from a track coasting on its prediction (no clear match
    since pulse 99: ``unseen_s`` growing to 1.3 s; a fan under ~0.14 Hz passes zero out
    of sight, spent held-out 4600019 at 1092 s), then the other way from 0.12 Hz on a
    line not yet checked against its mirror (pulse 144, 4.24 s). By the answers (0.135
    Hz at 4.21 s) it comes sooner than a fan reverses; but the fan was last seen at
    pulse 99 (2.91 s), and through zero at 0.3 Hz/s it needs (0.15 + 0.12) / 0.3 =
    0.9 s: no mirror image. It waits until a fan could have reversed after the last
    answer (4.21 + 0.85 s: pulse 172) and confirms there. The same answers from a
    track that sees the blade (a clear match at each) put the fan at 0.135 Hz a pulse
    before: the mirror image, held for its check; and so is a lock the other way after a
    short coast (0.4 s) of a steady fan (spent 4500010: 0.14 Hz after 0.2 Hz), which no
    fan could have made since its last clear match."""
    up = [_d("reversed", 0.12 + 0.15 * i / 34, checked=False) for i in range(60)]
    steady = [_d("same", 0.15)] * 100
    coast = [replace(_d("same", 0.135), unseen_s=(i + 1) / 34) for i in range(44)]
    fired, published, _ = _walk(steady + coast + up)
    assert fired == [("reversed", 172)]
    assert set(published[144:172]) == {"unknown"}
    fired, published, _ = _walk(steady + [_d("same", 0.135)] * 44 + up)
    assert fired == [] and set(published[144:]) == {"unknown"}
    short = [replace(_d("same", 0.2), unseen_s=(i + 1) / 34) for i in range(14)]
    mirror = [_d("reversed", 0.14, checked=False)] * 60
    fired, published, _ = _walk([_d("same", 0.2)] * 100 + short + mirror)
    assert fired == [] and set(published[114:]) == {"unknown"}


def test_a_standing_alias_is_no_sign_of_a_fan_near_zero():
    """Closed form, 34 pulses/s, 0.3 Hz/s: 'same' at 0.236 Hz to pulse 99 (checked), three
    answers the other way at 0.23 Hz at once (a lock on the mirror line: sudden), 27
    with no answer, one window whose track stands still at 0.044 Hz while the alias
    check finds another line fitting (``standing_alias``: the fan moves), then the other
    way at 0.23 Hz again from pulse 131 (3.85 s). A window that read the fan slower
    than the floor would have the resumed run judged afresh, as after a zero (no
    longer sudden 0.94 s after the last 'same'), and it would confirm as a reversal
    (spent held-out 4800004 at 135 s: a false one); a standing alias on a moving fan
    says nothing of a zero, and the run stays the mirror image, held for its check."""
    lock = [_d("reversed", 0.23, checked=False)] * 3
    gap = [Decision(Direction.UNKNOWN, None, None, None, None, 0.0, "no match")] * 27
    standing = Decision(Direction.UNKNOWN, None, 0.02, 0.044, None, 0.2,
                        "rate ambiguous: the track stands still while the fan moves")
    tail = [_d("reversed", 0.23, checked=False)] * 60
    head = [_d("same", 0.236)] * 100 + lock + gap
    fired, published, _ = _walk(head + [replace(standing, standing_alias=True)] + tail)
    assert fired == [] and set(published[131:]) == {"unknown"}
    fired, _, _ = _walk(head + [standing] + tail)
    assert [k for k, _ in fired] == ["reversed"]


def test_a_run_that_resumes_after_a_break_is_judged_afresh():
    """Closed form, 34 pulses/s: 'same' slowing from 0.45 Hz at 0.15 Hz/s for 2 s (pulses
    0-67, to 0.154 Hz; its line reaches zero at 3 s), three answers the other way at
    0.16 Hz at once (a lock on the mirror image: sudden, as through zero a fan needs
    (0.154 + 0.16) / 0.3 = 1.05 s), 1.5 s with no answer, then the other way rising from
    0.1 Hz on a line not yet checked against its mirror. When it resumes (pulse 122,
    3.59 s) the slowing line has passed zero and the fan was last seen turning 1.6 s
    before: no longer sooner than a fan reverses, so the earlier run's verdict must not
    stick to it; the resumed run confirms at its 17th answer (pulse 122 + 16; the three
    early answers have left the 2 x 17-pulse support window). After a fan seen steady at
    0.154 Hz, not slowing to zero, the same answers are still the mirror's."""
    down = [_d("same", 0.45 - 0.15 * i / 34) for i in range(68)]
    lock = [_d("reversed", 0.16, checked=False)] * 3
    gap = [Decision(Direction.UNKNOWN, None, None, None, None, 0.0, "no match")] * 51
    up = [_d("reversed", 0.1 + 0.15 * i / 34, checked=False) for i in range(40)]
    fired, published, _ = _walk(down + lock + gap + up)
    assert set(published[68:71]) == {"unknown"}
    assert fired == [("reversed", 122 + 16)]
    fired, _, _ = _walk([_d("same", 0.154)] * 68 + lock + gap + up)
    assert fired == []


def test_in_a_doubtful_room_a_fan_seen_turning_throughout_does_not_reverse():
    """Closed form: 'same' at 0.2 Hz, then 10 s (340 pulses) in which the direction is in
    doubt but the fan is seen turning at 0.2 Hz, then a line the other way at 0.2 Hz that
    has beaten its mirror once (a chance in a room whose echoes turned either way fit
    alike). In a doubtful room the answers in doubt carry the chain: no reversal, the
    other way is published as unknown. Where the room is not doubtful they do not, and
    the 10 s suffice for a reversal: it fires at the 17th answer."""
    def doubt(room):
        return Decision(Direction.UNKNOWN, None, None, 0.2, None, 0.3, "direction in doubt",
                        turning=True, doubtful_room=room)
    def other(room):
        return Decision(Direction.REVERSED, None, None, 0.2, None, 0.9, "test",
                        mirror_checked=True, doubtful_room=room)
    same = [_d("same", 0.2)] * 40
    fired, published, tr = _walk(same + [doubt(True)] * 340 + [other(True)] * 100)
    assert fired == [] and tr.known == Kind.SAME and set(published[380:]) == {"unknown"}
    fired, _, _ = _walk(same + [doubt(False)] * 340 + [other(False)] * 100)
    assert fired == [("reversed", 380 + 16)]


def test_in_a_doubtful_room_doubt_at_another_speed_ends_the_chain_once_a_reversal_could_be_made():
    """Closed form (the spent held-out scene 2700002 at 1320 s): 'same' at 0.14 Hz to
    pulse 39, then 10 s in doubt at 0.23 Hz (the reversed fan spun up again, its
    direction in doubt in a room whose echoes fit either way alike), then the other way
    at 0.23 Hz on a line that beat its mirror. From 0.14 Hz the known way, 0.23 Hz the
    other way is reached through zero in (0.14 + 0.23) / 0.3 = 1.23 s (pulse 81): doubt
    after that, at a speed more than CHAIN_AGREE off the known way's last answer, no
    longer shows the fan kept its way, and the chain ends within half that time of its
    last renewal. The other way at pulse 380 is a reversal at its 17th answer. (Each
    window in doubt renewing the chain it was judged against held it for 15 s.)"""
    def doubt(rate):
        return Decision(Direction.UNKNOWN, None, None, rate, None, 0.3, "direction in doubt",
                        turning=True, doubtful_room=True)
    other = [Decision(Direction.REVERSED, None, None, 0.23, None, 0.9, "test",
                      mirror_checked=True, doubtful_room=True)] * 100
    same = [_d("same", 0.14)] * 40
    fired, published, tr = _walk(same + [doubt(0.23)] * 340 + other)
    assert fired == [("reversed", 380 + 16)] and tr.known == Kind.REVERSED
    assert published[-1] == "reversed"
    # doubt at the known way's own speed still carries it (a steady fan on its mirror)
    fired, published, tr = _walk(same + [doubt(0.15)] * 340 + other)
    assert fired == [] and tr.known == Kind.SAME and set(published[380:]) == {"unknown"}


def test_in_a_doubtful_room_doubt_after_a_slow_fan_does_not_hide_its_reversal():
    """Closed form (the spent held-out scene 1200008 at 750 s): 'same' slowing from
    0.3 Hz at 0.15 Hz/s to 0.084 Hz (pulse 49, 1.44 s), 1.4 s with no answer, 0.4 s in
    doubt at 0.156 Hz (a fan can reach that either way: through zero it needs
    (0.084 + 0.156) / 0.3 = 0.8 s), 1 s in doubt at 0.71 Hz (an alias line: no fan gets
    there from 0.084 Hz in 2-3 s at 0.3 Hz/s), then the other way from 0.27 Hz on a line
    not checked against its mirror. Neither doubt shows the fan kept its way, so the
    other way comes 2.85 s after the fan was last seen turning the known way, later than
    the 1.18 s a fan needs through zero: a reversal at its 17th answer (pulse 146 + 16).
    With the doubt read as the old way still turning, it was held as sudden for as long
    as the line was not checked."""
    def doubt(rate):
        return Decision(Direction.UNKNOWN, None, None, rate, None, 0.3, "direction in doubt",
                        turning=True, doubtful_room=True)
    down = [_d("same", 0.3 - 0.15 * i / 34) for i in range(50)]
    gap = [Decision(Direction.UNKNOWN, None, None, None, None, 0.0, "no match")] * 48
    up = [Decision(Direction.REVERSED, None, None, 0.27 + 0.05 * i / 100, None, 0.9, "test",
                   doubtful_room=True) for i in range(100)]
    fired, published, tr = _walk(down + gap + [doubt(0.156)] * 14 + [doubt(0.71)] * 34 + up)
    assert fired == [("reversed", 146 + 16)] and tr.known == Kind.REVERSED
    assert published[-1] == "reversed"


def test_weak_answers_at_the_same_speed_keep_a_fan_from_reversing_at_once():
    """Closed form: 'same' at 0.36 Hz, then 10 s (340 pulses) of answers too weak for a
    direction at 0.33-0.38 Hz (a track on the mirror line), then the other way at 0.36 Hz
    on a line not yet checked against its mirror: the weak answers at the fan's speed
    show it never slowed, so the other way came at once: no reversal. Weak answers at
    speeds far from it (alias lines, 1.1 Hz) show nothing, and 10 s suffice for a
    reversal: it fires at the 17th answer."""
    def weak(rate):
        return Decision(Direction.UNKNOWN, None, None, rate, None, 0.3, "weak evidence")
    same = [_d("same", 0.36)] * 40
    near = [weak(0.33 + 0.05 * (i % 2)) for i in range(340)]
    other = [_d("reversed", 0.36, checked=False)] * 100
    fired, published, tr = _walk(same + near + other)
    assert fired == [] and tr.known == Kind.SAME and set(published[380:]) == {"unknown"}
    fired, _, _ = _walk(same + [weak(1.1)] * 340 + other)
    assert fired == [("reversed", 380 + 16)]


def test_each_hold_names_its_rule():
    """Closed-form walks (34 pulses/s, confirm 17 pulses, 0.3 Hz/s, floor 0.05 Hz): every
    decision published as unknown names the rule of Transitions.step that held it
    (``Transitions.hold``), and one published as it came names none. 'same' at 0.21 Hz
    is confirmed at its 17th answer; a stop 1.7 s into it waits for a reversal out of
    view (0.21 Hz could reach zero within an eighth of a turn at 0.3 Hz/s); one 'same'
    amid that stop's confirmation is a lone answer; the other way at once on a line not
    shown to beat its mirror is the mirror image, on one that has, sooner than a fan
    reverses (0.41 / 0.3 = 1.37 s); 0.05 Hz is too slow for a new direction (0.1 Hz)."""
    from bladesonar.transitions import Hold

    def walk(seq):
        tr = Transitions(TransitionSettings(confirm_s=0.5, max_reversal_hz_s=0.3,
                                            reversal_hold_s=1.0), 34.0)
        holds = []
        for i, d in enumerate(seq):
            out, _ = tr.step(i / 34.0, i, d)
            holds.append(tr.hold)
            assert (tr.hold is None) == (out.direction == d.direction), (i, tr.hold, out)
            assert tr.state.hold == tr.hold and tr.state.known == tr.known
        return holds, tr

    same = [_d("same", 0.21)] * 60
    holds, tr = walk(same + [_d("stopped")] * 5 + [_d("same", 0.21)])
    assert holds[:16] == [Hold.CONFIRMING] * 16 and holds[16:60] == [None] * 44
    assert holds[60:65] == [Hold.REVERSAL_UNDER_WAY] * 5
    assert holds[65] == Hold.LONE_ANSWER and tr.state.candidate == Kind.STOPPED
    holds, _ = walk(same + [_d("reversed", 0.2, checked=False)] * 3)
    assert holds[60:] == [Hold.MIRROR_IMAGE] * 3
    holds, tr = walk(same + [_d("reversed", 0.2)] * 3 + [_d("reversed", 0.05)])
    assert holds[60:63] == [Hold.TOO_SOON] * 3 and holds[63] == Hold.SLOW_NEW_DIRECTION
    assert tr.known == Kind.SAME


def test_a_sudden_run_that_beats_its_mirror_corrects_an_unchecked_direction():
    """Closed form, 34 pulses/s, 0.3 Hz/s: a fan starts and is taken 'same' at 0.21 Hz
    on a line never shown to beat its mirror image (a first lock on the mirror of the
    blade pattern), then the other way at 0.2 Hz at once, sooner than a fan reverses
    (1.37 s through zero), on a line that has beaten its mirror. No fan turns about that
    fast: the first direction was the mirror's, and the new one corrects it with no
    `reversed` event (at pulse 134, reversal_hold_s after the run began, the state turns
    'reversed'). After a 'same' that had beaten its mirror too, the same answers are a
    reversal, as before."""
    rest = [_d("stopped")] * 40
    same = [_d("same", 0.21, checked=False)] * 100
    fired, published, tr = _walk(rest + same + [_d("reversed", 0.2)] * 35)
    assert fired == [("started", 40 + 16)]
    assert tr.known == Kind.REVERSED and published[40 + 134] == "reversed"
    assert "unknown" == published[40 + 133]
    assert tr.known_decision is not None and "corrected" in tr.known_decision.reason
    fired, _, _ = _walk(rest + [_d("same", 0.21)] * 100 + [_d("reversed", 0.2)] * 60)
    assert fired == [("started", 40 + 16), ("reversed", 40 + 134)]


def test_a_run_the_other_way_sooner_than_any_reversal_after_an_unchecked_start_waits():
    """Closed form, 34 pulses/s, 0.3 Hz/s: a fan starts 'same' at 0.22 Hz on a line
    never shown to beat its mirror image (confirmed at pulse 56, 1.65 s), then nothing
    is seen, then the other way at 0.35 Hz from pulse 97 (2.85 s): later than a sudden
    run (0.95 s), sooner than a fan reverses at all ((0.22 + 0.35) / 0.3 = 1.9 s). One
    of the two lines is the mirror's (spent held-out 2600009: a false `reversed`
    1.9 s after a start taken the mirror's way). Neither shown to beat its mirror, the
    run is held, however long; once its line has, it corrects the start's direction
    with no event. The same run after a fan could have reversed is a reversal."""
    from bladesonar.transitions import Hold
    start = [_d("stopped")] * 40 + [_d("same", 0.22, checked=False)] * 17
    gap = [_lost()] * 40
    run = [_d("reversed", 0.35, checked=False)] * 60
    fired, published, tr = _walk(start + gap + run)
    assert fired == [("started", 56)]
    assert tr.known == Kind.SAME and tr.hold == Hold.MIRROR_IMAGE
    assert set(published[97:]) == {"unknown"}
    fired, published, tr = _walk(start + gap + run + [_d("reversed", 0.35)])
    assert fired == [("started", 56)] and tr.known == Kind.REVERSED
    assert published[157] == "reversed"
    assert tr.known_decision is not None and "corrected" in tr.known_decision.reason
    fired, _, tr = _walk(start + [_lost()] * 80 + run)
    assert fired == [("started", 56), ("reversed", 137 + 16)]
    # in a doubtful room a mirror check says nothing: the checked run is a reversal
    # once a fan could have made it (pulse 121), as before
    checked = [replace(d, doubtful_room=True)
               for d in start + gap + [_d("reversed", 0.35)] * 60]
    fired, _, tr = _walk(checked)
    assert fired == [("started", 56), ("reversed", 121)] and tr.known == Kind.REVERSED


def test_a_decided_turn_is_no_rest_for_the_mirror_check_while_the_static_is_held(
        reference):
    """The alias watch skips its mirror check while the fan rests. A held static
    estimate (RestHold, from a stop decided on the way through zero) is released only by
    a published turn, and a sudden turn is published only once its line beats its mirror:
    if the held estimate counted as rest the turn would wait for good (spent held-out
    700002: a reversal `unknown` for 20 s at 0.35 Hz, missed). A decided turn at three
    times the floor or more is no rest; a held estimate with no such turn, a stop, or a
    decided turn under that rate still is. The watch's own check is wrapped to record
    what it is told (a spy on our own call, not a stand-in: it runs as it does)."""
    from bladesonar.analyzer import new_analyzer
    an = new_analyzer(config.Config(), reference)
    told: list[bool] = []
    check = an.aliases.check

    def spy(tr, *, accel, moving, resting=False):
        told.append(resting)
        check(tr, accel=accel, moving=moving, resting=resting)

    an.aliases.check = spy          # type: ignore[method-assign]
    an.static.frozen = True
    floor3 = an.rest_hold.turning_hz
    for d in (_d("reversed", 0.35, checked=False), _d("reversed", 0.9 * floor3),
              _d("stopped"), None):
        an.decided = d
        an._check_aliases()
    assert told == [False, True, True, True]
    an.static.frozen = False
    an.decided = _d("same", 0.35)
    an._check_aliases()
    assert told[-1] is False


@pytest.mark.parametrize("way_down", ["steep, no line", "a slowing line"])
def test_a_new_lock_of_the_old_way_after_zero_does_not_make_a_reversal_sudden(way_down):
    """Closed form (the spent held-out scene 1300004 at 373 s and 686 s, 34 pulses/s,
    0.3 Hz/s): 'same' slows to 0.054 Hz (from a steady 0.168 Hz in half a second, too
    slow for a slowing line; or at 0.068 Hz/s from 0.25 Hz, whose line reaches zero),
    0.6 s of windows read slower than the floor, 0.3 s with no match, then a new lock
    answers 'same' at 0.14 Hz for 0.3 s and the other way follows at once from 0.105 Hz,
    on a line not checked against its mirror. The fan was seen at zero: a run of the old
    way that has not lasted ``followed_s`` (1 s) is a new lock on a fan that may be
    reversing, so the other way is judged against 0.054 Hz 1.2 s before (through zero a
    fan needs (0.054 + 0.105) / 0.3 = 0.53 s), and it waits for the short meter to have
    seen a fan that crept to rest after the last slow window (``still_window_s``, 1.5 s
    = 51 answers after it, 21 before the other way's first): a reversal at its 31st
    answer. Judged against the lock, it came at once and was held as the mirror image
    until its line was checked (4 s in the scene). A lock of the old way followed for
    1.2 s does vouch for it: then the other way at once is sudden, and held."""
    if way_down == "steep, no line":
        down = [_d("same", 0.168)] * 60 + [_d("same", 0.11 - 0.056 * i / 16)
                                           for i in range(17)]
    else:
        down = [_d("same", 0.25 - 0.068 * i / 34) for i in range(98)]
    assert down[-1].rate_hz == pytest.approx(0.054, abs=0.004)
    slow = [Decision(Direction.UNKNOWN, None, None, 0.04, None, 0.9,
                     "turning slower than the floor")] * 20
    lost = [Decision(Direction.UNKNOWN, None, None, None, None, 0.0, "no match")] * 10
    other = [_d("reversed", 0.105 + 0.085 * i / 34, checked=False) for i in range(100)]
    start, last_slow = len(down) + 20 + 10 + 10, len(down) + 19
    fired, published, tr = _walk(down + slow + lost + [_d("same", 0.14)] * 10 + other)
    assert [k for k, _ in fired] == ["reversed"] and tr.known == Kind.REVERSED
    assert last_slow + 51 <= fired[0][1] <= last_slow + 52     # (1.5 s, to the pulse)
    fired, published, _ = _walk(down + slow + lost + [_d("same", 0.14)] * 40 + other)
    assert fired == [] and set(published[start + 30:]) == {"unknown"}


def test_a_mirror_lock_just_after_a_start_is_still_sudden():
    """Closed form, 34 pulses/s, 0.3 Hz/s: 'same' slowing at 0.068 Hz/s from 0.25 Hz to
    0.06 Hz (a slowing line that reaches zero), 4 s at rest (a stop), then 'same' at
    0.12 Hz (a slow start, confirmed at its 17th answer; too slow to forget the line),
    five more, and the other way at once at 0.12 Hz on a line not checked against its
    mirror: a mirror lock, sudden against the start's answers, never a reversal. The
    spin-down's line is still below the floor then, but after a stop there is no chain
    for a new lock to move: the start's answers make one."""
    down = [_d("same", 0.25 - 0.068 * i / 34) for i in range(96)]
    rest = [_d("stopped")] * 136
    start = [_d("same", 0.12)] * 22
    fired, published, tr = _walk(down + rest + start
                                 + [_d("reversed", 0.12, checked=False)] * 100)
    assert [k for k, _ in fired] == ["stopped", "started"] and tr.known == Kind.SAME
    assert set(published[96 + 136 + 22:]) == {"unknown"}


def test_a_slowing_line_refuted_by_a_fan_followed_long_after_its_zero_guards_no_stop():
    """Closed form (the spent held-out scene 5400014 at 734 s): 'same' slowing from 0.3 Hz
    at 0.05 Hz/s to 0.15 Hz (1-4 s: the line reaches zero at 7 s), then 20 s at 0.12 Hz
    (under three times the floor: too slow to move the line), then quiet. The answers
    followed the fan long after the line's zero (past 7 + 3 + 1.3 s): it settled at
    0.12 Hz, and the line says nothing of now. Its sudden quiet is waited for as a
    reversal out of view (0.12 Hz is within reach of a turn out of view): no stop before
    3 s after its last answer (23.9 + 3 = 26.9 s). Kept, the line's old zero let the stop
    fire at its confirmation (24.7 s), though the fan was reversing through zero."""
    tr, k = _slowed(TransitionSettings(), 4.0, -0.05)
    for j in range(200):
        tr.step(4.0 + 0.1 * (j + 1), k + j, _d("same", 0.12))
    t = _stop_time(tr, 24.1, k + 200, until=40.0)
    assert t is not None and 26.9 - 1e-9 <= t < 27.1, t


def test_weak_answers_after_the_fan_read_slow_do_not_carry_the_old_way():
    """Closed form (the spent held-out scene 5400008 at 278 s): 'reversed' at 0.15 Hz to
    pulse 101, then 0.5 s of windows that read the fan at 0.03 Hz (slower than the floor:
    it may have passed zero), then weak answers at 0.17 Hz (within CHAIN_AGREE of the
    old way's speed, but after the fan was read near zero: they may be either way), then
    'same' at 0.17 Hz on a line not checked against its mirror, 2.4 s after the old way's
    last answer, later than the 1.07 s a fan needs through zero. A reversal at its 17th
    answer; read as the old way still turning, the weak answers held it as sudden."""
    old = [_d("reversed", 0.15)] * 102
    slow = [_weak(0.03)] * 17
    weak = [_weak(0.17)] * 34
    new = [_d("same", 0.17, checked=False)] * 60
    fired, published, tr = _walk(old + slow + weak + new)
    assert fired == [("reversed", 153 + 16)] and tr.known == Kind.SAME
    # without the slow windows the weak answers at the fan's speed do carry the old way
    fired, published, tr = _walk(old + weak + new)
    assert fired == [] and set(published[136:]) == {"unknown"}


def test_in_a_doubtful_room_doubt_after_a_rest_answer_does_not_carry_the_old_way():
    """Closed form (the spent held-out scene 5400006 at 254 s): in a doubtful room,
    'same' at 0.17 Hz to pulse 101, a rest answered for 0.2 s (the fan passing zero),
    0.3 s with no answer, then 3.5 s in doubt speeding up from 0.14 Hz, then 'reversed'
    at 0.3 Hz. The rest ended the known way's chain: doubt after it may be either way,
    and the other way, 4 s after the rest (a fan needs 1 s from rest to 0.3 Hz), is a
    reversal at its 17th answer. Read as the old way speeding up again from rest (within
    0.3 Hz/s), the doubt held the reversal as sudden."""
    def doubt(rate):
        return Decision(Direction.UNKNOWN, None, None, rate, None, 0.3,
                        "direction to be confirmed", turning=True, doubtful_room=True)
    same = [replace(_d("same", 0.17), doubtful_room=True)] * 102
    rest = [replace(_d("stopped"), doubtful_room=True)] * 7
    up = [doubt(0.14 + 0.16 * i / 119) for i in range(119)]
    other = [Decision(Direction.REVERSED, None, None, 0.3, None, 0.9, "test",
                      doubtful_room=True)] * 60
    fired, published, tr = _walk(same + rest + [_lost()] * 10 + up + other)
    assert fired == [("reversed", 238 + 16)] and tr.known == Kind.REVERSED
