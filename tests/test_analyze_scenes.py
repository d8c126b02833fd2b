"""End-to-end analysis on recordings of the project's scene simulator (known truth)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bladesonar import config
from bladesonar.analysis import analyze, build_reference
from bladesonar.errors import InputError
from bladesonar.sim import load_scene
from bladesonar.sim.render import simulate

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
    # after the reversal at 4 s: reversed within 2 s, and it stays so
    after = [i for i in range(len(rows)) if t[i] > 4.0 and d[i] == "reversed"]
    assert after and t[after[0]] - 4.0 < 2.0, (t[after[0]] if after else None)
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
                       match=r"only 66 usable pulses \(of 67\); at least 67 are needed: record "
                             r"longer$"):
        analyze(x, short, reference(4))


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
    assert ref.meta["dropped_pulses"] == 0 and not ref.meta["warnings"], ref.meta
    assert s["direction"] == "same" and abs(s["relative_rate"] - 1.0) < 0.03, s
