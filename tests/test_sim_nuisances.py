"""The simulator's real-device and real-room nuisances against their closed forms."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bladesonar import config
from bladesonar.errors import ConfigError
from bladesonar.io.scene_file import load_scene
from bladesonar.sim import device
from bladesonar.sim.nuisances import Nuisances, parse, parse_assignments
from bladesonar.sim.render import Simulator, simulate
from bladesonar.sim.reverb import Tail

FS = 44100.0
FULL = 32767.0 / 32768.0


@pytest.fixture(scope="module")
def scene(repo_root):
    return load_scene(repo_root / "config/scenes/paper-room.yaml")


def _sim(scene, seconds=1.0, **kw):
    kw.setdefault("snr_db", None)
    kw.setdefault("seed", 3)
    kw.setdefault("start_offset", 100.25)
    return simulate(scene, config.Config(), seconds, "ccw:0.45:10", include_paths=False, **kw)


def test_a_coupling_above_full_scale_is_clipped_at_the_converter(scene):
    """Coupling peak amplitude x gain = 0.5 x 20 = 10 x full scale: the converter holds
    it at full scale (never beyond), and the clipped samples are counted."""
    loud = dataclasses.replace(scene, coupling_gain=20.0)
    x, truth = _sim(loud)
    assert np.abs(x).max() <= FULL
    assert truth["summary"]["clipped_samples"] >= 20      # at least one per pulse
    x0, t0 = _sim(scene)
    assert t0["summary"]["clipped_samples"] == 0 and np.abs(x0).max() < 0.6


def test_small_speaker_response_blocks_dc_and_rings_at_its_resonance():
    nz = Nuisances(speaker_highpass_hz=400.0, speaker_resonance_hz=2500.0, speaker_q=3.0,
                   speaker_resonance_db=10.0)
    h = device.speaker_response(nz, FS)
    assert abs(h.sum()) < 1e-3 * np.abs(h).sum()          # a high-pass: no DC gain
    H = np.abs(np.fft.rfft(h, 1 << 16))
    f = np.fft.rfftfreq(1 << 16, 1 / FS)
    peak = f[np.argmax(H)]
    assert 2000 < peak < 3200                              # rings at the resonance
    ref = np.median(H[(f > 8000) & (f < 12000)])           # flat part
    assert 7.0 < 20 * math.log10(H.max() / ref) < 13.0     # the +10 dB peak (+- the hp)
    assert device.speaker_response(Nuisances(), FS).tolist() == [1.0]


def test_agc_gain_wanders_within_its_bound():
    nz = Nuisances(agc_db=3.0, agc_period_s=4.0)
    g = device.agc_gain(nz, seed=1, n0=0, n=int(20 * FS), fs=FS)
    db = 20 * np.log10(g)
    assert db.max() <= 3.0 + 1e-9 and db.min() >= -3.0 - 1e-9
    assert db.max() - db.min() > 3.0                       # it does wander
    # chunked == one-shot (a closed form of the sample index)
    part = device.agc_gain(nz, seed=1, n0=12345, n=1000, fs=FS)
    assert np.array_equal(part, g[12345:13345])


def test_quantisation_puts_every_sample_on_the_16_bit_grid(scene):
    x, _ = _sim(scene, snr_db=10.0, nuisances=Nuisances(capture_gain_db=-50.0, bits=16))
    q = x * 32768.0
    assert np.array_equal(q, np.round(q))
    # the fan echo is a few LSB: the loudest sample (the coupling, 0.5 at 0 dB) is 50 dB
    # down, about 52 LSB
    assert 30 <= np.abs(q).max() <= 70


def test_bursts_cover_their_share_of_the_time_at_their_level(scene):
    nz = Nuisances(burst_fraction=0.1, burst_db=10.0, burst_s=0.3)
    sim = Simulator(scene, config.Config(), "ccw:0.45:10", snr_db=10.0, seed=4, nuisances=nz)
    meta = sim.prepare(20.0)
    runs = meta["nuisances"]["bursts"]
    covered = sum(r["samples"] for r in runs) / meta["capture_samples"]
    assert abs(covered - 0.1) < 0.3 * 0.1 / len(runs) + 1e-9 + 0.015
    starts = [r["capture_index"] for r in runs]
    assert all(b >= a + r["samples"] for a, b, r in zip(starts, starts[1:], runs, strict=False))
    z = device.burst_samples(sim.bursts, 0, sim.burst_rms, 4, FS)
    assert math.isclose(math.sqrt(np.mean(z * z)), sim.burst_rms, rel_tol=1e-9)
    # 10 dB over the mean power of all echoes in the gate
    assert math.isclose(sim.burst_rms ** 2, 10.0 * sim._p_echo, rel_tol=1e-9)


def test_the_late_tail_decays_at_its_rt60_and_belongs_to_the_room():
    rt = 0.5
    t = Tail(rt, start=200.0, level=0.01, fan_share=0.0, shape=np.ones(1), fs=FS, seed=7)
    w = t.waveforms(0)[0].astype(np.float64)
    a, b = int(0.05 * FS), int(0.25 * FS)
    win = int(0.05 * FS)
    e1 = np.mean(w[a:a + win] ** 2)
    e2 = np.mean(w[b:b + win] ** 2)
    drop_db = 10 * math.log10(e1 / e2)
    assert abs(drop_db - 60.0 * (b - a) / FS / rt) < 3.0      # 24 dB expected
    # the fan's part is a function of the blade phase only
    tf = Tail(rt, 200.0, 0.01, 0.5, np.ones(1), FS, seed=7)
    out1, out2 = np.zeros(60000), np.zeros(60000)
    tf.add(out1, 0, np.array([1000.0]), np.array([0.3]))
    tf.add(out2, 0, np.array([1000.0]), np.array([1.3]))
    assert np.allclose(out1, out2)


def test_reverberant_runs_of_one_room_share_their_tail(scene):
    nz = Nuisances(rt60_s=0.4, reverb_fan_share=0.0)
    x1, _ = _sim(scene, seed=1, nuisances=nz, start_offset=100.0)
    x2, _ = _sim(scene, seed=2, nuisances=nz, start_offset=100.0)
    assert np.array_equal(x1, x2)        # no noise: the seed changes nothing in the room
    xd, _ = _sim(scene, seed=1, start_offset=100.0)
    late = slice(30000, 44100)
    assert np.sum((x1 - xd)[late] ** 2) > 0                  # and there is a tail


def test_warmer_room_brings_every_echo_earlier(scene):
    cfg = config.Config()
    s0 = Simulator(scene, cfg, "ccw:0.45:10", nuisances=Nuisances())
    s1 = Simulator(scene, cfg, "ccw:0.45:10", nuisances=Nuisances(speed_of_sound=346.0))
    d0, _, v0 = s0._block(0)
    d1, _, v1 = s1._block(0)
    m = v0 & v1
    assert np.allclose(d1[m] * 346.0, d0[m] * 343.0)
    assert s1.prepare(1.0)["nuisances"]["speed_of_sound_room"] == 346.0


def test_a_walker_echoes_only_while_in_the_room(scene):
    from bladesonar.sim.walker import walker_paths
    nz = Nuisances(walker_speed_m_s=1.0, walker_start_s=2.0, walker_y_m=1.0)
    t = np.array([1.0, 2.5, 4.0, 7.0])
    length, gain, here = walker_paths(nz, scene, t)
    assert here.tolist() == [False, True, True, False]      # the room is 4.2 m wide
    # at 4 s the walker is at x = 2 on y = 1: distance to the sensor (0.5, 0.6)
    d = math.hypot(2.0 - 0.5, 1.0 - 0.6)
    assert math.isclose(length[2], 2 * d) and math.isclose(gain[2], 1.0 / d ** 2)


def test_nuisances_render_the_same_in_chunks(scene):
    nz = Nuisances(rt60_s=0.3, agc_db=2.0, burst_fraction=0.1, burst_s=0.05,
                   speaker_highpass_hz=300.0, walker_speed_m_s=2.0, walker_start_s=0.1,
                   bits=16)
    a, _ = _sim(scene, 1.0, snr_db=10.0, nuisances=nz, chunk_samples=7001)
    b, _ = _sim(scene, 1.0, snr_db=10.0, nuisances=nz)
    assert np.array_equal(a, b)


@pytest.mark.parametrize("data, key", [
    ({"rt60": 0.5}, "nuisances.rt60"), ({"rt60_s": -1}, "nuisances.rt60_s"),
    ({"bits": 3}, "nuisances.bits"), ({"agc_db": "x"}, "nuisances.agc_db")])
def test_bad_nuisances_are_refused_naming_the_key(data, key):
    with pytest.raises(ConfigError) as e:
        parse(data)
    assert key in str(e.value)
    if "rt60" == next(iter(data)):
        assert "did you mean nuisances.rt60_s" in str(e.value)


def test_command_line_nuisances_override_the_scene():
    base = parse({"rt60_s": 0.5, "agc_db": 2})
    nz = parse_assignments(["agc_db=4", "burst_fraction=0.1"], base=base)
    assert (nz.rt60_s, nz.agc_db, nz.burst_fraction) == (0.5, 4.0, 0.1)
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_assignments(["agc_db"])
