"""The audio edge without a device: sample formats, the capture ring, gap flags, and the
simulator backend's real-time pacing (with an injected clock, so no test sleeps)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bladesonar import config
from bladesonar.errors import AudioDeviceError, ConfigError
from bladesonar.service.audio import BlockDecoder, CaptureRing, RawPeriod, decode, encode
from bladesonar.service.backends import open_audio
from conftest import ROOT


@pytest.mark.parametrize("fmt,bits", [("S16_LE", 16), ("S32_LE", 32)])
def test_pcm_codes_are_the_two_complement_values(fmt, bits):
    full = 2.0 ** (bits - 1)
    x = np.array([0.0, 0.5, -0.5, 1.0, -1.0, 2.0, -3.0, 1.0 / full])
    raw = encode(x, fmt)
    assert len(raw) == len(x) * bits // 8
    ints = np.frombuffer(raw, dtype=f"<i{bits // 8}")
    # +1.0 and beyond clip to the largest code, -1.0 is exactly representable
    want = [0, full / 2, -full / 2, full - 1, -full, full - 1, -full, 1]
    assert ints.tolist() == [int(v) for v in want]
    back = decode(raw, fmt)
    assert back.dtype == np.float64
    assert back[1] == 0.5 and back[4] == -1.0 and back[7] == 1.0 / full


def test_ring_drops_the_oldest_and_flags_the_next_delivered():
    ring = CaptureRing(maxlen=3)
    for k in range(5):
        ring.put(RawPeriod(bytes([k]), k * 10, False))
    assert ring.overflows == 2 and len(ring) == 3
    got = [g for g in (ring.get(0.0) for _ in range(3)) if g is not None]
    assert [g.start_sample for g in got] == [20, 30, 40]   # newest kept
    assert [g.discontinuity for g in got] == [True, False, False]
    assert ring.get(0.0) is None


def test_ring_batch_waits_for_the_whole_batch_then_takes_it_oldest_first():
    """get_batch(n): all n once they are queued; on timeout what is there (possibly
    nothing); never more than the ring holds; a closed ring hands out what is left at
    once, and a closed, empty one is waited out (a loop polling a dead device must not
    spin). A real producer thread puts periods; the consumer wakes once for the batch."""
    import threading
    import time

    ring = CaptureRing(maxlen=16)
    assert ring.get_batch(4, 0.0) == []
    ring.put(RawPeriod(b"a", 0, False))
    t0 = time.monotonic()
    got = ring.get_batch(4, 0.05)                 # only one arrives: taken at the timeout
    assert [g.start_sample for g in got] == [0] and time.monotonic() - t0 >= 0.05

    def produce() -> None:
        for k in range(1, 9):
            time.sleep(0.005)
            ring.put(RawPeriod(bytes([k]), k * 10, False))

    th = threading.Thread(target=produce)
    th.start()
    first = ring.get_batch(4, 5.0)
    second = ring.get_batch(4, 5.0)
    th.join()
    assert [g.start_sample for g in first + second] == [10 * k for k in range(1, 9)]
    for k in range(20):
        ring.put(RawPeriod(bytes([k]), k, False))
    assert len(ring.get_batch(100, 0.0)) == 16    # at most the ring's length
    ring.put(RawPeriod(b"z", 99, False))
    ring.close()
    t0 = time.monotonic()
    got = ring.get_batch(4, 5.0)                 # closed: the last one, at once
    assert [g.start_sample for g in got] == [99] and time.monotonic() - t0 < 1.0
    t0 = time.monotonic()
    assert ring.get_batch(4, 0.05) == [] and time.monotonic() - t0 >= 0.05
    assert ring.get(0.05) is None and time.monotonic() - t0 >= 0.1


def test_decoder_flags_a_jump_in_the_capture_index():
    dec = BlockDecoder("S16_LE")
    z = encode(np.zeros(4), "S16_LE")
    a = dec(RawPeriod(z, 0, False))
    b = dec(RawPeriod(z, 4, False))
    c = dec(RawPeriod(z, 12, False))      # 8 samples went missing
    d = dec(RawPeriod(z, 16, True))       # the audio thread says so itself
    assert [x.discontinuity for x in (a, b, c, d)] == [False, False, True, True]
    assert dec.delivered == 4


def test_unknown_backend_is_a_clear_error():
    cfg = config.from_mapping({})
    # past validation on purpose (load_config refuses it earlier, naming the key)
    bad = dataclasses.replace(cfg, audio=dataclasses.replace(cfg.audio, backend="pulse"))
    with pytest.raises(AudioDeviceError, match="alsa, pipewire, auto or sim"):
        open_audio(bad)


class FakeClock:
    """Stands in for time.monotonic/time.sleep: pacing is checked without sleeping."""

    def __init__(self) -> None:
        self.t = 100.0
        self.slept = 0.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        assert s >= 0
        self.t += s
        self.slept += s


def sim_cfg(**sim):
    scene = str(ROOT / "config" / "scenes" / "paper-room.yaml")
    return config.from_mapping({"audio": {"backend": "sim", "ring_pulses": 8},
                                "sim": {"scene": scene, "schedule": "ccw:0.5:5",
                                        "snr_db": 20, **sim}})


def test_sim_backend_hands_out_periods_no_sooner_than_a_card_would():
    from bladesonar.service.sim_audio import SimAudio

    cfg = sim_cfg(realtime=True)
    clk = FakeClock()
    a = SimAudio(cfg, clock=clk, sleep=clk.sleep)
    a.start()
    pri_s = cfg.waveform.pri_samples / cfg.audio.sample_rate
    blocks = [b for b in (a.read_pulse(timeout=1.0) for _ in range(10)) if b is not None]
    # period k is complete (k + 1) PRIs after the stream started
    assert clk.slept == pytest.approx(10 * pri_s, rel=1e-9)
    assert [b.start_sample for b in blocks] == [k * cfg.waveform.pri_samples for k in range(10)]
    assert not any(b.discontinuity for b in blocks)
    # a timeout shorter than the wait for the next period returns None, not a block
    assert a.read_pulse(timeout=pri_s / 10) is None


def test_sim_backend_hands_out_a_batch_once_its_last_period_is_complete():
    """read_pulses(n): one wait, until the n-th period is complete, then the n periods in
    order; the same blocks as n single reads."""
    from bladesonar.service.sim_audio import SimAudio

    cfg = sim_cfg(realtime=True)
    pri = cfg.waveform.pri_samples
    pri_s = pri / cfg.audio.sample_rate
    clk = FakeClock()
    a = SimAudio(cfg, clock=clk, sleep=clk.sleep)
    a.start()
    got = a.read_pulses(8, timeout=1.0)
    assert clk.slept == pytest.approx(8 * pri_s, rel=1e-9)
    assert [b.start_sample for b in got] == [k * pri for k in range(8)]
    clk2 = FakeClock()
    single = SimAudio(cfg, clock=clk2, sleep=clk2.sleep)
    single.start()
    for b in got:
        s1 = single.read_pulse(1.0)
        assert s1 is not None and np.array_equal(s1.samples, b.samples)
    # a timeout shorter than the batch's wait: what is complete by then
    part = a.read_pulses(8, timeout=2.5 * pri_s)
    assert [b.start_sample // pri for b in part] == [8, 9]


def test_sim_backend_loses_the_oldest_periods_when_the_consumer_falls_behind():
    from bladesonar.service.sim_audio import SimAudio

    cfg = sim_cfg(realtime=True)
    clk = FakeClock()
    a = SimAudio(cfg, clock=clk, sleep=clk.sleep)
    a.start()
    pri = cfg.waveform.pri_samples
    pri_s = pri / cfg.audio.sample_rate
    a.read_pulse(1.0)
    clk.t += 30 * pri_s                    # the loop stalled for 30 PRIs; the ring holds 8
    b = a.read_pulse(1.0)
    assert b is not None and b.discontinuity
    assert a.stats()["ring_overflows"] == b.start_sample // pri - 1 > 0
    # what is handed out is at most one ring behind the capture clock
    captured = int((clk.t - 100.0) / pri_s)
    assert captured - b.start_sample // pri <= 8


def test_sim_backend_keeps_the_simulators_snr_definition():
    """The noise the sim backend adds gives the configured SNR as the offline simulator
    defines it (fan-echo power inside the gate over noise power)."""
    from bladesonar.io.scene_file import load_scene
    from bladesonar.service.sim_audio import SimAudio
    from bladesonar.sim.render import simulate

    def periods(snr_db):
        a = SimAudio(sim_cfg(realtime=False, snr_db=snr_db))
        a.start()
        got = [a.read_pulse(1.0) for _ in range(170)]
        return np.concatenate([b.samples for b in got if b is not None])

    noise = periods(10) - periods(120)        # same seed: same echoes, different noise
    cfg = sim_cfg()
    _, truth = simulate(load_scene(cfg.path(cfg.sim.scene)), cfg, 5.0, "ccw:0.5:5",
                        snr_db=10, seed=cfg.sim.seed)
    p_fan = truth["meta"]["snr"]["fan_power"]
    snr = 10 * np.log10(p_fan / np.mean(noise ** 2))
    assert snr == pytest.approx(10.0, abs=0.3)


def test_sim_backend_names_the_scene_key_when_the_file_is_missing(tmp_path):
    from bladesonar.service.sim_audio import SimAudio

    cfg = sim_cfg(scene=str(tmp_path / "nope.yaml"))
    with pytest.raises(ConfigError, match="sim.scene"):
        SimAudio(cfg).start()
