"""The streaming renderer: reproducibility, chunking, clock drift, drop-outs, the SNR
definition, stiff cases and bounded memory."""

from __future__ import annotations

import logging
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from bladesonar import config
from bladesonar.errors import ConfigError
from bladesonar.io.scene_file import load_scene
from bladesonar.sim import Scene
from bladesonar.sim.render import Simulator, echo_response, simulate
from test_waveform import band_limited_peak

ROOT = Path(__file__).resolve().parents[1]
CFG = config.Config()
PRI = CFG.waveform.pri_samples


@pytest.fixture(scope="module")
def room() -> Scene:
    return load_scene(ROOT / "config/scenes/paper-room.yaml")


def test_same_seed_same_output_other_seed_other_noise(room):
    a, ta = simulate(room, CFG, 2.0, snr_db=10, seed=5)
    b, tb = simulate(room, CFG, 2.0, snr_db=10, seed=5)
    c, _ = simulate(room, CFG, 2.0, snr_db=10, seed=6)
    assert np.array_equal(a, b) and ta == tb
    assert not np.array_equal(a, c)
    assert len(a) == 88200


def test_chunked_output_is_identical_to_one_shot(room):
    cfg = config.replace(CFG, waveform={"pulse": "hann", "pulse_samples": 9})
    kw = dict(snr_db=15, seed=2, drift_ppm=37.5, dropouts=3, dropout_samples=100,
              dc_offset=0.01, clip=0.3)
    whole, tw = simulate(room, cfg, 4.0, chunk_samples=1 << 20, **kw)
    for chunk in (1, 4097, 44100):
        if chunk == 1:   # one-sample chunks over a short stretch only (slow by nature)
            part, tp = simulate(room, cfg, 0.05, chunk_samples=1, **kw)
            ref, tr = simulate(room, cfg, 0.05, **kw)
            assert np.array_equal(part, ref) and tp["pulses"] == tr["pulses"]
            continue
        part, tp = simulate(room, cfg, 4.0, chunk_samples=chunk, **kw)
        assert np.array_equal(part, whole)
        assert tp["pulses"] == tw["pulses"]


def test_truth_records_follow_the_schedule(room):
    _, t = simulate(room, CFG, 12.0, "ccw:0.5:3,stop:0:2,cw:0.4:5", start_offset=0.0)
    m = t["meta"]
    assert m["pulses"] == math.ceil(12 * 44100 / PRI)
    assert [p["pulse"] for p in t["pulses"]] == list(range(m["pulses"]))
    for p in t["pulses"]:
        ts = p["time_s"]
        assert ts == pytest.approx(p["pulse"] * PRI / 44100)
        turns = (0.5 * min(ts, 3) - 0.4 * max(0.0, ts - 5))
        assert p["angle_rad"] == pytest.approx(room.start_angle_rad + 2 * math.pi * turns)
        assert p["phase"] == pytest.approx((4 * p["angle_rad"] / (2 * math.pi)) % 1.0)
        expect = "ccw" if ts < 3 else ("stopped" if ts < 5 else "cw")
        assert p["direction"] == expect
        assert p["rate_hz"] == {"ccw": 0.5, "stopped": 0.0, "cw": -0.4}[expect]
        assert p["sample"] == pytest.approx(p["pulse"] * PRI)
        assert p["paths"][0] == {"kind": "coupling", "delay": 0.0, "gain": 1.0}


def test_direct_coupling_lands_where_the_drifted_clock_puts_it(room):
    ppm, off = 250.0, 123.25
    x, t = simulate(room, CFG, 3.0, drift_ppm=ppm, start_offset=off, seed=1)
    for k in (0, 40, len(t["pulses"]) - 2):
        expect = (off + k * PRI) * (1 + ppm * 1e-6)
        assert t["pulses"][k]["sample"] == pytest.approx(expect)
        lo = int(expect) - 64
        peak = lo + band_limited_peak(x[lo:lo + 128])
        assert abs(peak - expect) < 0.05
    # without drift the last pulse would be ~25 samples earlier: the shift is real
    assert (off + k * PRI) * ppm * 1e-6 > 20


def test_dropouts_remove_exactly_the_reported_samples(room):
    kw = dict(snr_db=20, seed=3, start_offset=10.0)
    x, t = simulate(room, CFG, 3.0, dropouts=4, dropout_samples=300, **kw)
    runs = t["meta"]["dropouts"]["runs"]
    assert len(runs) == 4 and all(r["samples"] == 300 for r in runs)
    # the same capture without losses (same length, so the same pulses and noise level)
    full, _ = simulate(room, CFG, (3 * 44100 + 1200) / 44100, **kw)
    lost = np.concatenate([np.arange(r["capture_index"], r["capture_index"] + 300)
                           for r in runs])
    assert np.array_equal(x, np.delete(full, lost))
    assert len(x) == 3 * 44100
    for r in runs:   # output_index = capture_index minus what was lost before it
        before = sum(q["samples"] for q in runs if q["capture_index"] < r["capture_index"])
        assert r["output_index"] == r["capture_index"] - before
    # pulse edges shift earlier by the samples lost before them
    for p in t["pulses"]:
        edge = 10.0 + p["pulse"] * PRI
        before = sum(q["samples"] for q in runs if q["capture_index"] + q["samples"] <= edge)
        inside = any(q["capture_index"] <= edge < q["capture_index"] + q["samples"]
                     for q in runs)
        assert (p["sample"] is None) == inside
        if not inside:
            assert p["sample"] == pytest.approx(edge - before)


def test_zeroed_dropouts(room):
    x, t = simulate(room, CFG, 2.0, snr_db=20, seed=3, dropouts=[(1000, 50), (40000, 7)],
                    dropout_mode="zero")
    full, _ = simulate(room, CFG, 2.0, snr_db=20, seed=3)
    assert np.all(x[1000:1050] == 0) and np.all(x[40000:40007] == 0)
    keep = np.ones(len(x), bool)
    keep[1000:1050] = keep[40000:40007] = False
    assert np.array_equal(x[keep], full[keep])


def test_snr_is_fan_echo_power_in_the_gate_over_noise_power(room):
    """Measured independently: the fan echo is the difference between the scene and the
    same scene with non-reflecting blades (which shadow the same paths)."""
    import dataclasses

    snr = 6.0
    kw = dict(start_offset=0.0, seed=9)
    clean, _ = simulate(room, CFG, 20.0, "ccw:0.7:1", **kw)
    dark = dataclasses.replace(room, blade_reflectivity=0.0)
    static, _ = simulate(dark, CFG, 20.0, "ccw:0.7:1", **kw)
    noisy, t = simulate(room, CFG, 20.0, "ccw:0.7:1", snr_db=snr, **kw)
    fan = clean - static
    g0 = math.ceil(0.3 * 2 * 44100 / 343.0)
    g1 = math.floor(CFG.max_range_m * 2 * 44100 / 343.0)
    n = t["meta"]["pulses"] - 1
    rows = np.arange(n)[:, None] * PRI + np.arange(g0, g1 + 1)[None, :]
    p_fan = np.mean(fan[rows] ** 2)
    p_noise = np.var(noisy - clean)
    assert 10 * math.log10(p_fan / p_noise) == pytest.approx(snr, abs=0.1)
    assert t["meta"]["snr"]["noise_sigma"] ** 2 == pytest.approx(p_noise, rel=0.01)
    assert t["meta"]["snr"]["reference"] == "fan"


def test_zero_rate_gives_identical_pulses(room):
    x, t = simulate(room, CFG, 2.0, "stop:0:1", start_offset=0.0)
    pulses = x[:PRI * 60].reshape(60, PRI)
    assert np.abs(pulses[1:] - pulses[1]).max() < 1e-10 * np.abs(pulses).max()
    assert all(p["direction"] == "stopped" for p in t["pulses"])


def test_rate_beyond_the_aliasing_limit_still_runs(room, caplog):
    limit = CFG.prf_hz / 8
    with caplog.at_level(logging.WARNING):
        x, t = simulate(room, CFG, 1.0, f"cw:{2.5 * limit}:1")
    assert "aliasing limit" in caplog.text
    assert t["meta"]["aliasing_limit_hz"] == pytest.approx(limit)
    assert t["pulses"][3]["rate_hz"] == pytest.approx(-2.5 * limit)
    assert np.all(np.isfinite(x))


def _scene(sensor, centre, hub=0.1) -> Scene:
    return Scene.from_mapping(dict(room=dict(vertices=[[0, 0], [5, 0], [5, 4], [0, 4]]),
                                   sensor=list(sensor),
                                   fan=dict(centre=list(centre), hub_radius_m=hub)))


def test_sensor_at_the_fan_centre_does_not_crash():
    s = _scene((2.5, 2.0), (2.5, 2.0))
    x, t = simulate(s, CFG, 1.0, "ccw:1:1", snr_db=20)
    assert np.all(np.isfinite(x))
    assert not any(p["kind"] in ("blade", "wall_blade", "blade_wall")
                   for r in t["pulses"] for p in r["paths"])
    assert t["meta"]["snr"]["reference"] == "all_echoes"


def test_blades_that_never_reach_a_specular_angle(caplog):
    s = _scene((2.7, 2.0), (2.5, 2.0), hub=0.3)      # sensor inside the hub
    with caplog.at_level(logging.WARNING):
        x, t = simulate(s, CFG, 1.0, "ccw:1:1", snr_db=20, wall_bounces=False)
    assert "inside the fan hub" in caplog.text
    assert np.all(np.isfinite(x)) and t["meta"]["snr"]["noise_sigma"] > 0


def test_echo_response_puts_each_path_at_its_range(room):
    from bladesonar.sim import geometry

    a = 0.9
    h = echo_response(room, CFG, a, PRI)
    assert h[0] == pytest.approx(room.coupling_gain)
    p = geometry.paths(room, a)
    for L, k in zip(p.length_m, p.kind, strict=True):
        if k == "wall":   # separated static echoes: the peak sits at 2 d / c * fs
            d = L / 343.0 * 44100
            lo = int(d) - 20
            assert abs(lo + band_limited_peak(h[lo:lo + 40]) - d) < 0.05
    h2 = echo_response(room, CFG, a, PRI, include_coupling=False)
    assert h2[0] == pytest.approx(0, abs=1e-12)
    assert np.allclose(h2[1:], h[1:], atol=1e-12)


def test_bad_arguments_name_the_key(room):
    for kw, key in ((dict(start_offset=PRI), "start_offset"), (dict(drift_ppm=1e6), "drift_ppm"),
                    (dict(clip=0.0), "clip"), (dict(dropout_mode="x"), "dropout_mode"),
                    (dict(snr_db=float("nan")), "snr_db")):
        with pytest.raises(ConfigError) as e:
            Simulator(room, CFG, **kw)
        assert e.value.key == key
    with pytest.raises(ConfigError, match="do not fit"):
        simulate(room, CFG, 0.01, dropouts=10, dropout_samples=100)
    with pytest.raises(ConfigError) as e:
        simulate(room, CFG, -1.0)
    assert e.value.key == "seconds"


@pytest.mark.slow
def test_ten_minutes_stream_in_bounded_memory(room):
    sim = Simulator(room, CFG, "ccw:0.5:100,cw:1:100", snr_db=20, seed=1, include_paths=False)
    seconds = 600.0
    total, pulses = 0, 0
    tracemalloc.start()
    try:
        for x, recs in sim.chunks(seconds):
            total += len(x)
            pulses += len(recs)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sim.meta is not None
    assert total == 600 * 44100 and pulses == sim.meta["pulses"]
    assert peak < total * 8 / 20          # whole output as float64 would be 212 MB
