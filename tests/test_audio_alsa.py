"""The ALSA backend through real alsa-lib: the loopback room on two FIFO PCMs (file
plugin, no sound card) answers what the backend plays with the scene's echoes."""

from __future__ import annotations

import json
import subprocess
import threading

import numpy as np
import pytest

from bladesonar import config
from bladesonar.io.config_file import load_config
from loopback import RoomProcess, bladesonar_cmd, require_alsa, write_config

pytestmark = [pytest.mark.alsa, pytest.mark.slow]


@pytest.fixture(autouse=True)
def _alsa():
    require_alsa()


@pytest.mark.parametrize("period_pulses", [1, 4])
def test_capture_is_prf_locked_and_sample_exact(tmp_path, monkeypatch, period_pulses):
    """Pulse k is played at sample k * pri, so its direct coupling (gain 1 in the scene,
    amplitude 0.5, an exact S16 code) sits at the same place in every captured PRI,
    whatever the ALSA period (one PRI, or several: one wake-up of the threads each)."""
    from bladesonar.service.alsa_audio import AlsaAudio

    cfg_path = write_config(tmp_path / "cfg.yaml", tmp_path / "state",
                            audio={"period_pulses": period_pulses})
    cfg = load_config(cfg_path)
    pri = cfg.waveform.pri_samples
    with RoomProcess(cfg_path, tmp_path / "room", "ccw:0.45:60", realtime=False) as room:
        monkeypatch.setenv("ALSA_CONFIG_PATH", room.env["ALSA_CONFIG_PATH"])
        audio = AlsaAudio(cfg)
        audio.start()
        try:
            got = [audio.read_pulse(timeout=5.0) for _ in range(400)]
        finally:
            audio.stop()
        log = room.stop()
    assert all(b is not None for b in got), log
    blocks = [b for b in got if b is not None]
    assert [b.start_sample for b in blocks] == [k * pri for k in range(400)]
    assert not any(b.discontinuity for b in blocks)
    # the room's documented default: one ALSA buffer and 321 samples
    latency = cfg.audio.buffer_periods * cfg.audio.period_pulses * pri + 321
    first = latency // pri
    at = latency % pri
    x = np.array([b.samples for b in blocks[first:]])
    assert np.all(np.argmax(np.abs(x), axis=1) == at)
    assert np.all(x[:, at] == 0.5)
    assert np.all(np.array([b.samples for b in blocks[:first]]) == 0.0)   # pre-roll silence
    st = audio.stats()
    assert st["xruns_capture"] == st["xruns_playback"] == st["ring_overflows"] == 0


def test_reference_live_records_through_alsa_and_finds_the_true_rate(tmp_path):
    cfg_path = write_config(tmp_path / "cfg.yaml", tmp_path / "state")
    with RoomProcess(cfg_path, tmp_path / "room", "ccw:0.45:60", realtime=False) as room:
        r = subprocess.run(bladesonar_cmd("reference", "--live", "--seconds", "12",
                                          "--direction", "ccw", "--config", str(cfg_path)),
                           env=room.env, capture_output=True, text=True, timeout=120)
        log = room.stop()
    assert r.returncode == 0, r.stderr + log
    summary = json.loads(r.stdout)
    assert summary["rate_hz"] == pytest.approx(0.45, rel=0.005)   # the room's schedule
    assert summary["direction"] == "ccw"
    assert (tmp_path / "state" / "reference.npz").is_file()        # where the daemon looks


def test_reference_live_holds_the_same_pulses_whatever_the_latency(tmp_path):
    """``--seconds`` of recording count from the first pulse heard, not from the
    capture's start: two rooms that differ only in the latency before the first echo
    (one ALSA buffer + 321 samples, and 7 PRIs + 185 more, as through PipeWire) give the
    same reference, bit for bit (the same noise per pulse: Room._noise). Counted from
    the capture's start, the two held 324 and 331 pulses, and the daemons on them
    confirmed one reversal 0.35 s apart (docs/audio.md)."""
    from bladesonar.io.reference import load_reference

    refs = []
    for name, extra in (("near", 321), ("far", 7 * 1297 + 185 + 321)):
        cfg_path = write_config(tmp_path / f"{name}.yaml", tmp_path / name)
        c = load_config(cfg_path)
        buffer = c.audio.buffer_periods * c.audio.period_pulses * c.waveform.pri_samples
        with RoomProcess(cfg_path, tmp_path / f"room-{name}", "ccw:0.45:60", realtime=False,
                         noise=1e-4, latency=buffer + extra) as room:
            r = subprocess.run(bladesonar_cmd("reference", "--live", "--seconds", "10",
                                              "--direction", "ccw", "--config",
                                              str(cfg_path)),
                               env=room.env, capture_output=True, text=True, timeout=120)
            log = room.stop()
        assert r.returncode == 0, r.stderr + log
        refs.append(load_reference(tmp_path / name / "reference.npz"))
    near, far = refs
    assert near.meta["pulses"] == far.meta["pulses"] == 340      # 10 s of 29.4 ms PRIs
    assert np.array_equal(near.table, far.table)
    assert near.meta["rate_hz"] == far.meta["rate_hz"]


def test_a_missing_pcm_is_a_clear_error_naming_the_key(tmp_path):
    cfg_path = write_config(tmp_path / "cfg.yaml", tmp_path / "state",
                            audio={"playback_device": "no_such_pcm"})
    r = subprocess.run(bladesonar_cmd("reference", "--live", "--seconds", "5",
                                      "--direction", "ccw", "--config", str(cfg_path)),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "no_such_pcm" in r.stderr and "audio.playback_device" in r.stderr
    assert "Traceback" not in r.stderr


class FakePCM:
    """Stands in for alsaaudio.PCM to inject xruns: a real overrun needs a device paced in
    real time, which the file plugin is not. Returns one period per read, -32 on cue."""

    def __init__(self, pri: int, script: list[str]) -> None:
        self.pri, self.script = pri, list(script)
        self.n = 0
        self.done = threading.Event()

    def read(self):
        if not self.script:
            self.done.set()
            self.done.wait()
            return 0, b""
        step = self.script.pop(0)
        if step == "xrun":
            return -32, b""
        self.n += 1
        return self.pri, np.full(self.pri, self.n, dtype="<i2").tobytes()

    def write(self, data):
        if self.script and self.script[0] == "underrun":
            self.script.pop(0)
            return -32
        self.done.wait(0.01)
        return len(data) // 2

    def close(self):
        pass


def test_an_overrun_counts_and_flags_the_gap_instead_of_shifting_ranges():
    from bladesonar.service.alsa_audio import AlsaAudio

    cfg = config.from_mapping({"audio": {"backend": "alsa", "ring_pulses": 64}})
    pri = cfg.waveform.pri_samples
    a = AlsaAudio(cfg)
    a._cap = FakePCM(pri, ["ok", "ok", "xrun", "ok", "ok"])
    threading.Thread(target=a._capture_loop, daemon=True).start()
    got = [a.read_pulse(timeout=2.0) for _ in range(4)]
    a._stop.set()
    a._cap.done.set()
    assert all(b is not None for b in got)
    blocks = [b for b in got if b is not None]
    starts = [b.start_sample for b in blocks]
    assert starts[:2] == [0, pri]
    assert starts[2] >= 3 * pri                # at least one period lost, never reused
    assert [b.discontinuity for b in blocks] == [False, False, True, False]
    assert a.stats()["xruns_capture"] == 1
    assert [int(b.samples[0] * 32768) for b in blocks] == [1, 2, 3, 4]
