"""End-to-end analysis on recordings of the project's scene simulator (known truth)."""

from __future__ import annotations

import dataclasses
import itertools
import subprocess
import sys

import numpy as np
import pytest

from bladesonar import config
from bladesonar.errors import InputError
from bladesonar.io.scene_file import load_scene
from bladesonar.offline import analyze
from bladesonar.reference_build import build_reference
from bladesonar.sim.render import simulate

pytestmark = pytest.mark.slow   # whole analyses of simulated scenes: outside the fast tier

SCENE = "config/scenes/paper-room.yaml"


@pytest.fixture(scope="module")
def scene(repo_root):
    return load_scene(repo_root / SCENE)


def _cfg(blades=4):
    return config.replace(config.Config(), scene={"blades": blades})


def _sim(scene, seconds, schedule, blades=4, **kw):
    sc = dataclasses.replace(scene, blades=blades)
    kw.setdefault("seed", 11)
    kw.setdefault("snr_db", 20.0)
    x, truth = simulate(sc, _cfg(blades), seconds, schedule=schedule, **kw)
    return x, truth


_refs: dict = {}


@pytest.fixture(scope="module")
def reference(scene):
    """One reference per blade count: ccw at 0.5 Hz, 12 s (cached for the module)."""
    def get(blades=4):
        if blades not in _refs:
            x, _ = _sim(scene, 12.0, "ccw:0.5:12", blades=blades, seed=1)
            _refs[blades] = build_reference(x, _cfg(blades), "ccw")
        return _refs[blades]
    return get


def test_reference_rate_matches_the_simulated_rate(reference):
    ref = reference(4)
    assert abs(ref.meta["rate_hz"] - 0.5) < 0.005
    assert ref.meta["periods_folded"] > 20 and ref.meta["quality"] > 0.5


@pytest.mark.parametrize("schedule, direction, rotation, rel", [
    ("ccw:0.5:6", "same", "ccw", 1.0),
    ("ccw:0.3333333:6", "same", "ccw", 2 / 3),
    ("cw:0.5:6", "reversed", "cw", -1.0),
    ("cw:0.25:6", "reversed", "cw", -0.5),
    ("ccw:1.0:6", "same", "ccw", 2.0),
])
def test_direction_and_relative_rate(scene, reference, schedule, direction, rotation, rel):
    x, _ = _sim(scene, 6.0, schedule, seed=21)
    s, _ = analyze(x, _cfg(), reference(4))
    assert (s["direction"], s["rotation"]) == (direction, rotation), s
    assert abs(s["relative_rate"] - rel) < 0.03 * abs(rel), s
    assert abs(s["rate_hz"] - abs(rel) * 0.5) < 0.03 * abs(rel) * 0.5
    assert s["confidence"] >= 0.5


def test_stopped_fan(scene, reference):
    x, _ = _sim(scene, 6.0, "stop:0:6", seed=22)
    s, _ = analyze(x, _cfg(), reference(4))
    assert s["direction"] == "stopped" and s["rate_hz"] == 0.0, s


@pytest.mark.parametrize("blades", [3, 5])
def test_other_blade_counts(scene, reference, blades):
    x, _ = _sim(scene, 6.0, "cw:0.4:6", blades=blades, seed=23)
    s, _ = analyze(x, _cfg(blades), reference(blades))
    assert s["direction"] == "reversed" and s["rotation"] == "cw", s
    assert abs(s["relative_rate"] + 0.8) < 0.03 * 0.8, s


def test_low_snr(scene, reference):
    x, _ = _sim(scene, 6.0, "ccw:0.5:6", snr_db=0.0, seed=24)
    s, _ = analyze(x, _cfg(), reference(4))
    assert s["direction"] == "same", s
    assert abs(s["relative_rate"] - 1.0) < 0.05, s


def test_clock_drift_200ppm(scene, reference):
    x, _ = _sim(scene, 6.0, "cw:0.5:6", drift_ppm=200.0, seed=25)
    s, _ = analyze(x, _cfg(), reference(4))
    assert s["direction"] == "reversed", s
    assert abs(s["relative_rate"] + 1.0) < 0.03, s
    assert abs(s["clock_ppm"] - 200.0) < 10


def test_dropouts(scene, reference):
    x, truth = _sim(scene, 6.0, "ccw:0.5:6", dropouts=3, dropout_samples=300, seed=26)
    s, _ = analyze(x, _cfg(), reference(4))
    assert s["direction"] == "same", s
    assert abs(s["relative_rate"] - 1.0) < 0.03, s
    assert s["dropped_pulses"] >= 1


def test_reversal_mid_recording_is_seen_in_the_track(scene, reference):
    x, _ = _sim(scene, 10.0, "ccw:0.5:4,cw:0.5:6", seed=27)
    _, rows = analyze(x, _cfg(), reference(4), track=True)
    t = np.array([r["t_s"] for r in rows])
    d = [r["direction"] for r in rows]
    assert d[int(np.searchsorted(t, 3.8))] == "same"
    # after the reversal at 4 s: reversed within 2.5 s, and it stays so. The flip here is
    # instant, which no fan makes (a real one passes through zero at a ramp): a line the
    # other way at once, at the old speed, is what a track taken up on the mirror of the
    # blade pattern gives, so it waits for its line to beat its mirror image (2.05 s here;
    # reversals through zero are timed in test_transitions)
    after = [i for i in range(len(rows)) if t[i] > 4.0 and d[i] == "reversed"]
    assert after and t[after[0]] - 4.0 < 2.5, (t[after[0]] if after else None)
    assert all(x == "reversed" for x in d[int(np.searchsorted(t, 6.5)):])


@pytest.mark.parametrize("seed", [2, 3, 8])
def test_recording_shorter_than_the_static_window_is_analysed(scene, reference, seed):
    """2 s (66 valid pulses) < analysis.static_window_s (3 s); with these seeds the
    aligner's final flush emits no pulse, which used to leave the analyzer unmade and the
    recording refused ("only 66 usable pulses (of 67)") although it holds more than
    analysis.min_pulses."""
    cfg = _cfg()
    assert 2.0 < cfg.analysis.static_window_s
    x, _ = _sim(scene, 2.0, "ccw:0.5:2", seed=seed)
    s, _ = analyze(x, cfg, reference(4))
    assert s["used_pulses"] >= cfg.analysis.min_pulses, s
    assert s["window_s"] <= 2.0, s
    assert s["direction"] in ("same", "unknown") and s["rotation"] in ("ccw", None), s
    # fewer than analysis.min_pulses is still refused, naming the count
    short = config.replace(cfg, analysis={"min_pulses": 67})
    with pytest.raises(InputError,
                       match=r"only 66 usable pulses \(of 67\) in 2\.00 s; at least 67 are "
                             r"needed: record at least 2\.1 s$"):
        analyze(x, short, reference(4))


def _true_rate_hz(truth) -> float:
    """Signed rotation rate (+ ccw) over the simulated pulses, from the truth records."""
    return float(np.mean([p["rate_hz"] for p in truth["pulses"]]))


@pytest.mark.parametrize("seed", [2, 8])
def test_three_second_probe_gets_direction_and_rate(scene, reference, seed):
    """A 3 s probe (cw 0.4 Hz) holds fewer pulses than the static window: the analyzer is
    primed from what it holds, the answer is the simulated one within 3 %, and the end of
    the file, wherever it cuts the last PRI, is neither a drop-out nor a warning."""
    cfg = _cfg()
    ref = reference(4)
    x, truth = _sim(scene, 3.0, "cw:0.4:3", seed=seed)
    want_rel = _true_rate_hz(truth) / 0.5            # the reference turns ccw at 0.5 Hz
    assert want_rel == pytest.approx(-0.8)
    static_pulses = round(cfg.analysis.static_window_s * cfg.prf_hz)
    pri = cfg.waveform.pri_samples
    for cut in range(0, pri, pri // 4):              # the file ends anywhere in a PRI
        s, _ = analyze(x[:len(x) - cut], cfg, ref)
        assert cfg.analysis.min_pulses <= s["used_pulses"] < static_pulses, s
        assert s["dropped_pulses"] == 0, (cut, s)
        assert not any("dropped" in w for w in s["warnings"]), (cut, s)
        assert (s["direction"], s["rotation"]) == ("reversed", "cw"), (cut, s)
        assert abs(s["relative_rate"] - want_rel) < 0.03 * abs(want_rel), (cut, s)
        assert abs(s["rate_hz"] - abs(_true_rate_hz(truth))) < 0.03 * 0.4, (cut, s)
        assert s["confidence"] >= cfg.tracking.min_confidence, (cut, s)
        assert s["window_s"] <= 3.0


def test_short_probe_still_reports_a_real_dropout(scene, reference):
    """A capture drop-out inside a 3 s probe is counted and warned about, unlike the end."""
    x, truth = _sim(scene, 3.0, "cw:0.4:3", seed=8, dropouts=[(44100, 300)])
    runs = truth["meta"]["dropouts"]["runs"]
    assert len(runs) == 1
    s, _ = analyze(x, _cfg(), reference(4))
    # one 300-sample gap spoils the pulse it falls in, and the one after it when it
    # reaches that pulse's direct coupling
    assert 1 <= s["dropped_pulses"] <= 2 * len(runs), s
    assert f"{s['dropped_pulses']} pulses dropped or corrupt (skipped)" in s["warnings"], s
    assert s["direction"] == "reversed", s
    assert abs(s["relative_rate"] + 0.8) < 0.03 * 0.8, s


def test_too_short_recordings_are_refused_with_pulses_and_seconds(scene, reference, tmp_path):
    """Below analysis.min_pulses (64 = 1.9 s) the refusal names the pulses and the
    shortest length that works (2.0 s); a recording of exactly that length is analysed."""
    cfg = _cfg()
    ref = reference(4)
    pri, fs = cfg.waveform.pri_samples, cfg.audio.sample_rate
    x, _ = _sim(scene, 1.5, "cw:0.4:1.5", seed=2)
    with pytest.raises(InputError, match=rf"holds {len(x) // pri} pulses \(1\.50 s at {pri} "
                                         r"samples per pulse\) but at least 64 usable pulses "
                                         r"are needed: record at least 2\.0 s$"):
        analyze(x, cfg, ref)
    x, _ = _sim(scene, 1.9, "cw:0.4:1.9", seed=2)
    with pytest.raises(InputError, match=r"only 6\d usable pulses \(of 6\d\) in 1\.90 s; at "
                                         r"least 64 are needed: record at least 2\.0 s$"):
        analyze(x, cfg, ref)
    for offset in (0, pri - 1):                      # wherever the first pulse falls
        x2, _ = _sim(scene, 2.0, "cw:0.4:2", seed=2, start_offset=offset)
        s, _ = analyze(x2, cfg, ref)
        assert s["used_pulses"] >= cfg.analysis.min_pulses and s["dropped_pulses"] == 0, s
    # the command line: exit code 2 and that one line on stderr
    from bladesonar.io.reference import save_reference
    from bladesonar.io.wav import WavWriter
    wav = tmp_path / "short.wav"
    with WavWriter(wav, fs) as w:
        w.write(x)
    save_reference(ref, tmp_path / "ref.npz")
    r = subprocess.run([sys.executable, "-m", "bladesonar", "analyze", "--reference",
                        str(tmp_path / "ref.npz"), str(wav)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and r.stdout == "", r
    assert r.stderr.count("\n") == 1 and "usable pulses" in r.stderr, r.stderr
    assert "record at least 2.0 s" in r.stderr, r.stderr


def test_end_of_the_pulse_train_is_not_counted_as_dropped(scene, reference):
    """The capture runs on after the last pulse (no direct pulse in the last PRI): the
    pulses at the end are not used, but neither counted nor warned as drop-outs."""
    x, _ = _sim(scene, 6.0, "ccw:0.5:6", seed=21)
    tail = 1e-4 * np.random.default_rng(0).standard_normal(1400)
    y = np.concatenate([x, tail])
    s, _ = analyze(y, _cfg(), reference(4))
    assert s["dropped_pulses"] == 0 and not any("dropped" in w for w in s["warnings"]), s
    ref = build_reference(np.concatenate([_sim(scene, 12.0, "ccw:0.5:12", seed=1)[0], tail]),
                          _cfg(), "ccw")
    assert ref.meta["dropped_pulses"] == 0, ref.meta
    assert not any("dropped" in w for w in ref.meta["warnings"]), ref.meta["warnings"]
    assert s["direction"] == "same" and abs(s["relative_rate"] - 1.0) < 0.03, s


# ---- rates near p/q blade periods per pulse (the pulses see only q angles) -------------

def _commensurate_hz(p: int, q: int) -> float:
    """Rotation rate (Hz) at which the blades advance p/q period per pulse."""
    cfg = _cfg()
    return p / q * cfg.prf_hz / cfg.scene.blades


@pytest.mark.parametrize("direction, p, q, seed, expect", [
    # before the alias check each of these was answered confidently wrong
    ("cw", 1, 5, 3, "resolved"),       # was: same, +3.40, confidence 1.0
    ("ccw", 1, 5, 3, "ambiguous"),     # was: reversed, -3.40, confidence 1.0
    ("cw", 1, 9, 3, "resolved"),       # was: same, +3.78
    ("cw", 1, 12, 21, "resolved"),     # was: same, +1.42
    # was: reversed, -3.19. Resolved (0.94) while the coupling's edge was timed through
    # a full-band interpolant; with the band-limited one (dsp/pulses.EDGE_BAND) this
    # seed's matches fit a line near -3/13 better than the true one (coherence 0.80
    # against 0.64 over 24 pulses) and the answer stays unknown under 0.5 for 20 s. The
    # same case at seeds 30-49 resolved 20 of 20 either way; the eight cases at those
    # seeds gave 147 right, 13 unknown, none wrong, with either interpolant
    ("ccw", 1, 16, 21, "safe"),
    ("cw", 3, 16, 21, "resolved"),     # was: reversed, -2.13 (true -3.19)
    ("ccw", 2, 9, 3, "resolved"),      # was: same, +1.88 (true +3.78)
    ("cw", 5, 24, 3, "resolved"),      # was: same, +0.08 (a track standing still)
])
def test_commensurate_probe_is_never_confidently_wrong(scene, reference, direction, p, q,
                                                       seed, expect):
    """At p/q blade period per pulse the probe shows q angles and its matches fit several
    alias rates; the line fit against the reference table finds the simulated rate, or the
    answer is unknown with the reason ("safe": right, or unknown under the confidence
    that claims a direction)."""
    hz = _commensurate_hz(p, q)
    x, truth = _sim(scene, 6.0, f"{direction}:{hz:.6f}:6", seed=seed)
    want_rel = _true_rate_hz(truth) / 0.5
    s, _ = analyze(x, _cfg(), reference(4))
    if expect == "resolved":
        assert s["direction"] == ("same" if want_rel > 0 else "reversed"), s
        assert abs(s["relative_rate"] - want_rel) < 0.03 * abs(want_rel), s
        assert s["confidence"] >= 0.5, s
    elif expect == "safe":
        if s["direction"] != "unknown":
            assert s["direction"] == ("same" if want_rel > 0 else "reversed"), s
            assert abs(s["relative_rate"] - want_rel) < 0.03 * abs(want_rel), s
        else:
            assert s["confidence"] < 0.5, s
    else:
        assert s["direction"] == "unknown" and s["confidence"] < 0.5, s
        assert s["reason"].startswith("rate ambiguous") and f"{p}/{q} blade period" in \
            s["reason"].replace("-", ""), s


def test_half_hertz_probe_stays_confident(scene, reference):
    """0.5 Hz is 2.6e-6 from 1/17 period per pulse: the alias check runs, finds the
    tracked rate clearly best, and leaves the answer as it was (same, +1.00)."""
    x, truth = _sim(scene, 10.0, "ccw:0.5:10", seed=3)
    s, _ = analyze(x, _cfg(), reference(4))
    want = _true_rate_hz(truth) / 0.5
    assert s["direction"] == "same" and abs(s["relative_rate"] - want) < 0.03, s
    assert s["confidence"] >= 0.9, s
    assert "ambiguous" not in s["reason"] and not any("alias" in w for w in s["warnings"])


@pytest.mark.parametrize("schedule, seed", [("ccw:0.45:6", 21), ("cw:0.61:6", 5)])
def test_ordinary_rates_are_left_alone(scene, reference, schedule, seed):
    x, truth = _sim(scene, 6.0, schedule, seed=seed)
    s, _ = analyze(x, _cfg(), reference(4))
    want = _true_rate_hz(truth) / 0.5
    assert s["direction"] == ("same" if want > 0 else "reversed"), s
    assert abs(s["relative_rate"] - want) < 0.03 * abs(want) and s["confidence"] >= 0.9, s
    assert "ambiguous" not in s["reason"] and not any("alias" in w for w in s["warnings"])


def test_reference_near_a_small_fraction_is_warned_about(scene, reference):
    """A reference at 1/8 blade period per pulse folds onto 8 angles: warned, with the
    fix; 3 % faster it is not. The 0.5 Hz reference (1/17) is warned about too."""
    cfg = _cfg()
    hz = _commensurate_hz(1, 8)
    x, truth = _sim(scene, 12.0, f"ccw:{hz:.6f}:12", seed=1)
    ref = build_reference(x, cfg, "ccw")
    assert abs(ref.meta["rate_hz"] - _true_rate_hz(truth)) < 0.005 * hz
    got = [w for w in ref.meta["warnings"] if "blade angles" in w]
    assert len(got) == 1 and "of 1/8:" in got[0] and "another fan speed" in got[0], got
    x, _ = _sim(scene, 12.0, f"ccw:{1.03 * hz:.6f}:12", seed=1)
    ref = build_reference(x, cfg, "ccw")
    assert not any("blade angles" in w for w in ref.meta["warnings"]), ref.meta["warnings"]
    assert any("of 1/17:" in w for w in reference(4).meta["warnings"])


def test_reference_whose_pulses_leave_angles_unseen_is_warned_about(scene):
    """At 1/40 blade period per pulse (past the fractions the alias check looks at) every
    period shows the same 40 angles, one pulse step apart, and nothing fills the steps
    between: warned, with the gap (one step, less what the estimated rate slips over the
    recording) and the fix. 3 % faster, 408 pulses slip through 12 steps and fill them."""
    cfg = _cfg()
    hz = _commensurate_hz(1, 40)
    x, _ = _sim(scene, 12.0, f"ccw:{hz:.6f}:12", seed=1)
    ref = build_reference(x, cfg, "ccw")
    got = [w for w in ref.meta["warnings"] if "leave gaps" in w]
    assert len(got) == 1 and "another fan speed" in got[0], ref.meta["warnings"]
    assert not any("blade angles, so" in w for w in ref.meta["warnings"])
    steps = float(got[0].split("leave gaps of ")[1].split()[0])
    r = ref.meta["cycles_per_pulse"]
    assert 1.0 - 400 * abs(r - 1 / 40) * 40 - 0.02 <= steps <= 1.0, (steps, r)
    x, _ = _sim(scene, 12.0, f"ccw:{1.03 * hz:.6f}:12", seed=1)
    ref = build_reference(x, cfg, "ccw")
    assert not any("leave gaps" in w for w in ref.meta["warnings"]), ref.meta["warnings"]


def test_reference_whose_rate_may_be_an_alias_is_warned_about(scene):
    """At 1/9 blade period per pulse the paper room shows the blades at few of the 9
    angles and the period search cannot order them: whatever rate it settles on (2/9
    here, twice the simulated one), the reference says that it may be an alias."""
    hz = _commensurate_hz(1, 9)
    x, truth = _sim(scene, 12.0, f"ccw:{hz:.6f}:12", seed=1)
    ref = build_reference(x, _cfg(), "ccw")
    r = ref.meta["cycles_per_pulse"]
    assert abs(r * 9 - round(r * 9)) < 1e-3             # some m/9
    got = [w for w in ref.meta["warnings"] if "blade angles" in w]
    assert len(got) == 1 and "/9:" in got[0] and "alias" in got[0], ref.meta["warnings"]


def test_daemon_path_resolves_the_alias_too(scene, reference):
    """The daemon runs the same check pulse by pulse: fed one capture period at a time,
    the cw 1.7 Hz probe (1/5 period per pulse) ends as the offline analysis does, right."""
    from bladesonar.live import LiveAnalyzer
    cfg = _cfg()
    x, truth = _sim(scene, 6.0, f"cw:{_commensurate_hz(1, 5):.6f}:6", seed=3)
    offline, _ = analyze(x, cfg, reference(4))
    live = LiveAnalyzer(cfg, reference(4))
    pri = cfg.waveform.pri_samples
    est = None
    for i in range(0, len(x), pri):
        est = live.push(x[i:i + pri], i) or est
    want = _true_rate_hz(truth) / 0.5
    assert est is not None
    got = est.fields()      # the state message's fields (live.Estimate)
    assert got["direction"] == "reversed" and abs(got["relative_rate"] - want) < 0.03 * 3.4
    for key in ("direction", "relative_rate", "confidence"):
        assert got[key] == offline[key], key



def _report_trial(repo_root, scene_name: str, pick, seconds: float, snr_db: float):
    """Recordings of the report sweep (runtime_report's own rendering and reference):
    ``pick(job)`` selects the jobs; yields (job, recording, reference, rr module)."""
    import math

    from bladesonar import runtime_report as rr
    grid = rr.default_grid()
    cfg = config.Config()
    scene = load_scene(repo_root / "config" / "scenes" / f"{scene_name}.yaml")
    refs = {}
    for job in (j for j in rr.jobs(grid) if j.scene == scene_name and pick(j)):
        if job.blades not in refs:
            refs[job.blades] = rr.make_reference(scene, cfg, job.blades, grid)
        rate = job.true_ratio * grid.ref_rate_hz
        clean, unit, p_fan = rr._render(rr._scene(scene, job.blades),
                                        rr.sweep_config(cfg, job.blades),
                                        rr._schedule(rate, seconds), seconds, job.seed)
        yield job, clean + math.sqrt(p_fan / 10 ** (snr_db / 10)) * unit, refs[job.blades], rr


@pytest.mark.parametrize("family, scene_name, seed, snr_db", [
    # +0.955 of the reference, 2e-4 blade period per pulse from 1/19: one alias check
    # found the mirror line better by a cost gap of 0.32 and moved the track there
    # ('reversed' at confidence 0.92 for a while; the final answer unknown)
    ("window_snr", "paper-room", 21, 20.0),
    # a weakly asymmetric room: with the near-p/q gate widened by the full rate standard
    # deviation every ordinary rate was checked, and this one ended cw -0.944 at
    # confidence 0.86 (truth ccw +0.96)
    ("rooms", "narrow-hall", 5, 10.0),
])
def test_alias_check_never_flips_an_ordinary_rate(repo_root, family, scene_name, seed, snr_db):
    """Report trials (30 s, same rate as the 0.47 Hz reference within 5 %): no pulse of
    the track may say 'reversed' with confidence, and the answer is right. Truth: ccw."""
    job, x, ref, rr = next(_report_trial(
        repo_root, scene_name, lambda j: j.family == family and j.seed == seed
        and j.ratio == 1.0, 30.0, snr_db))
    s, rows = analyze(x, rr.sweep_config(config.Config(), job.blades, 30.0), ref, track=True)
    wrong = [r["t_s"] for r in rows if r["direction"] == "reversed"
             and r["confidence"] >= 0.5]
    assert wrong == []
    assert s["direction"] == "same" and abs(s["relative_rate"] - job.true_ratio) < 0.03, s


def test_a_window_shorter_than_a_blade_period_of_lags_never_says_stopped(repo_root):
    """1 s windows (34 pulses: lags up to 17, a blade period at the 0.47 Hz reference is
    18 pulses) of a fan turning at the reference rate in the corner-sensor room were
    called stopped in 39 of 120 report trials. Truth: moving, so never 'stopped'."""
    trials = _report_trial(repo_root, "corner-sensor", lambda j: j.family == "rooms", 4.0,
                           10.0)
    answers = []
    for job, x, ref, rr in itertools.islice(trials, 4):
        n = 44100
        for seg in range(4):
            s, _ = analyze(x[seg * n:(seg + 1) * n],
                           rr.sweep_config(config.Config(), job.blades, 1.0), ref)
            answers.append(s["direction"])
    assert "stopped" not in answers, answers


def test_a_recording_given_in_blocks_gives_the_same_answer(scene, reference):
    """analyze on an iterable of blocks (a WAV read block by block, memory independent of
    its length) answers exactly as on the whole array, and a stream's bad input gets the
    same one-line errors."""
    x, _ = _sim(scene, 8.0, "cw:0.4:8", seed=5)
    whole, rows_w = analyze(x, _cfg(), reference(4), track=True)
    odd = 4999                                         # blocks that cut pulses anywhere
    parts, rows_p = analyze((x[i:i + odd] for i in range(0, len(x), odd)), _cfg(),
                            reference(4), track=True)
    assert parts == whole
    assert rows_p == rows_w
    from bladesonar.errors import InputError
    with pytest.raises(InputError, match="silent"):
        analyze(iter([np.zeros(44100)] * 8), _cfg(), reference(4))
    y = x.copy()
    y[100_000] = np.nan
    with pytest.raises(InputError, match="NaN/inf samples .first at sample 100000"):
        analyze((y[i:i + odd] for i in range(0, len(y), odd)), _cfg(), reference(4))
    with pytest.raises(InputError, match="pulses"):
        analyze(iter([x[:20000]]), _cfg(), reference(4))
