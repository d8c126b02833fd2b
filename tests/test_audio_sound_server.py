"""Finding the sound server (real unix sockets, no server needed), reading a PipeWire
graph dump, and following the latency between the two streams (closed forms)."""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np
import pytest

from bladesonar import config
from bladesonar.errors import AudioDeviceError
from bladesonar.service import sound_server
from bladesonar.service.alsa_audio import AlsaAudio
from bladesonar.service.backends import audio_choice, choose_backend, open_audio
from bladesonar.service.pipewire_audio import (
    STREAM_PROPS,
    StreamLatency,
    pcm_name,
    stream_props_text,
)


def listen(path: Path) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.bind(str(path))
    s.listen(4)
    return s


def test_a_live_pipewire_socket_wins_over_pulse_and_a_stale_one_does_not(tmp_path):
    run = tmp_path / "run"
    (run / "pulse").mkdir(parents=True)
    env = {"XDG_RUNTIME_DIR": str(run)}
    assert sound_server.detect(env).kind == "none"
    pulse = listen(run / "pulse" / "native")
    try:
        found = sound_server.detect(env)
        assert found.kind == "pulseaudio" and found.socket == str(run / "pulse" / "native")
        pw = listen(run / "pipewire-0")        # pipewire-pulse serves both sockets
        assert sound_server.detect(env).kind == "pipewire"
        pw.close()                              # the file stays, nobody listens: stale
        assert sound_server.detect(env).kind == "pulseaudio"
    finally:
        pulse.close()


def test_pipewire_remote_and_pulse_server_variables_are_honoured(tmp_path):
    s = listen(tmp_path / "elsewhere")
    try:
        assert sound_server.detect({"PIPEWIRE_REMOTE": str(tmp_path / "elsewhere")}).kind \
            == "pipewire"
        assert sound_server.detect({"PULSE_SERVER": f"unix:{tmp_path / 'elsewhere'}"}).kind \
            == "pulseaudio"
    finally:
        s.close()


def test_auto_refuses_pulseaudio_with_the_fix_and_picks_alsa_without_a_server(
        tmp_path, monkeypatch):
    run = tmp_path / "run"
    (run / "pulse").mkdir(parents=True)
    for k in ("PIPEWIRE_REMOTE", "PIPEWIRE_RUNTIME_DIR", "PULSE_SERVER", "PULSE_RUNTIME_PATH"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(run))
    cfg = config.from_mapping({"audio": {"backend": "auto"}})
    assert choose_backend(cfg) == "alsa"
    s = listen(run / "pulse" / "native")
    try:
        with pytest.raises(AudioDeviceError, match="PulseAudio.*pipewire-pulse"):
            choose_backend(cfg)
    finally:
        s.close()
    assert choose_backend(config.from_mapping({"audio": {"backend": "alsa"}})) == "alsa"


def test_what_was_found_and_chosen_goes_with_the_audio_path(tmp_path, monkeypatch):
    """The status topic and stats show it (runner: the path's ``choice``); real sockets."""
    run = tmp_path / "run"
    run.mkdir()
    for k in ("PIPEWIRE_REMOTE", "PIPEWIRE_RUNTIME_DIR", "PULSE_SERVER", "PULSE_RUNTIME_PATH"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(run))
    auto = config.from_mapping({"audio": {"backend": "auto"}})
    assert audio_choice(auto) == {"backend": "auto", "server": "none", "chosen": "alsa",
                                  "path": "alsa"}
    pw = listen(run / "pipewire-0")
    try:
        assert audio_choice(auto) == {"backend": "auto", "server": "pipewire",
                                      "chosen": "pipewire", "path": "pipewire-alsa"}
        # named in the config: used as named, with the server that answers beside it
        alsa = config.from_mapping({"audio": {"backend": "alsa"}})
        assert audio_choice(alsa) == {"backend": "alsa", "server": "pipewire",
                                      "chosen": "alsa", "path": "alsa"}
        audio = open_audio(alsa)                       # not started: no device is opened
        assert isinstance(audio, AlsaAudio) and audio.choice == audio_choice(alsa)
        assert audio.stats()["sound_server"] == {"server": "pipewire", "path": "alsa",
                                                 "backend": "alsa"}
    finally:
        pw.close()
    sim = config.from_mapping({"audio": {"backend": "sim"}})
    assert audio_choice(sim) == {"backend": "sim", "server": None, "chosen": "sim",
                                 "path": "sim"}


def test_node_names_become_plugin_pcm_names_and_odd_ones_are_refused():
    assert pcm_name("default", "playback_device") == "pipewire"
    assert pcm_name("alsa_output.platform-sound.HiFi__hw_0__sink", "playback_device") \
        == "pipewire:NODE=alsa_output.platform-sound.HiFi__hw_0__sink"
    with pytest.raises(AudioDeviceError, match="audio.capture_device"):
        pcm_name("a,b}", "capture_device")
    text = stream_props_text()
    assert text.startswith("{ ") and text.endswith(" }")
    assert all(f'{k} = "{v}"' in text for k, v in STREAM_PROPS.items())


DUMP = [
    {"id": 0, "type": "PipeWire:Interface:Core", "info": {"version": "0.3.65"}},
    {"id": 30, "type": "PipeWire:Interface:Metadata", "props": {"metadata.name": "settings"},
     "metadata": [{"subject": 0, "key": "clock.rate", "value": 48000},
                  {"subject": 0, "key": "clock.allowed-rates", "value": "[ 44100 48000 ]"},
                  {"subject": 0, "key": "clock.quantum", "value": 1024},
                  {"subject": 0, "key": "clock.force-quantum", "value": 256},
                  {"subject": 0, "key": "clock.force-rate", "value": 0}]},
    {"id": 31, "type": "PipeWire:Interface:Metadata", "props": {"metadata.name": "default"},
     "metadata": [{"subject": 0, "key": "default.audio.sink",
                   "value": {"name": "alsa_output.speaker"}},
                  {"subject": 0, "key": "default.audio.source",
                   "value": '{"name": "echo-cancel-source"}'}]},
    {"id": 70, "type": "PipeWire:Interface:Client",
     "info": {"props": {"application.process.id": 4242}}},
    {"id": 50, "type": "PipeWire:Interface:Node",
     "info": {"props": {"node.name": "alsa_output.speaker", "media.class": "Audio/Sink"},
              "params": {"Format": [{"rate": 48000, "channels": 2}]}}},
    {"id": 51, "type": "PipeWire:Interface:Node",
     "info": {"props": {"node.name": "echo-cancel-source", "media.class": "Audio/Source",
                        "factory.name": "support.null-audio-sink"},
              "params": {"Format": [{"rate": 48000}]}}},
    {"id": 60, "type": "PipeWire:Interface:Node",
     "info": {"state": "running", "props": {"node.name": "ALSA Playback", "client.id": 70,
                                            "media.class": "Stream/Output/Audio"},
              "params": {"Format": [{"rate": 48000}]}}},
    {"id": 61, "type": "PipeWire:Interface:Node",
     "info": {"state": "running", "props": {"node.name": "ALSA Capture", "client.id": 70,
                                            "media.class": "Stream/Input/Audio"}}},
    {"id": 62, "type": "PipeWire:Interface:Node",       # another program's stream
     "info": {"props": {"node.name": "ALSA Playback", "application.process.id": 1,
                        "media.class": "Stream/Output/Audio"}}},
    {"id": 80, "type": "PipeWire:Interface:Link",
     "info": {"output-node-id": 60, "input-node-id": 50}},
    {"id": 81, "type": "PipeWire:Interface:Link",
     "info": {"output-node-id": 51, "input-node-id": 61}},
]


def test_graph_facts_find_our_streams_their_targets_and_an_echo_canceller():
    f = sound_server.graph_facts(DUMP, 4242)
    assert f["version"] == "0.3.65" and f["clock_rate"] == 48000 and f["quantum"] == 1024
    assert f["force_quantum"] == 256 and f["force_rate"] is None
    assert f["playback"]["target"] == "alsa_output.speaker"
    assert f["playback"]["target_rate"] == 48000 and not f["playback"]["echo_cancel"]
    assert f["capture"]["target"] == "echo-cancel-source" and f["capture"]["echo_cancel"]
    assert sound_server.graph_rate(f) == 48000
    assert "playback" not in sound_server.graph_facts(DUMP, 1234)   # not our process


def _pri_blocks(pri: int, latency: list[int], n: int) -> list[tuple[np.ndarray, int]]:
    """Capture of pulse k (played at k * pri) arriving latency[k] samples later."""
    stream = np.zeros((n + 4) * pri)
    for k in range(n):
        stream[k * pri + latency[k]] = 0.5
    return [(stream[i * pri:(i + 1) * pri], i * pri) for i in range(n)]


def test_stream_latency_is_the_first_edge_then_followed_through_drift_and_a_jump():
    pri, n = 1412, 60
    lat = [3000 + (k // 10) for k in range(30)] + [3000 + 2 + 512] * 30   # drift, then a jump
    sl = StreamLatency(pri)
    for x, at in _pri_blocks(pri, lat, n):
        sl.push(x, at)
    assert sl.first == 3000
    assert sl.samples == 3000 + 2 + 512
    assert (sl.lo, sl.hi) == (3000, 3514)
    assert sl.jumps == 1                 # one-sample drift steps are not jumps


def test_stream_latency_ignores_pris_without_a_clear_edge():
    sl = StreamLatency(100)
    sl.push(np.full(100, 0.1), 0)         # flat: no coupling peak
    assert sl.samples is None
    rng = np.random.default_rng(1)
    sl.push(rng.normal(0, 0.01, 100), 100)
    assert sl.samples is None


def test_targets_are_read_before_the_streams_open_from_names_or_the_defaults():
    t = sound_server.target_facts(DUMP, "default", "default")
    assert t["playback"]["target"] == "alsa_output.speaker"
    assert t["playback"]["target_rate"] == 48000 and not t["playback"]["echo_cancel"]
    assert t["capture"]["target"] == "echo-cancel-source" and t["capture"]["echo_cancel"]
    t = sound_server.target_facts(DUMP, "alsa_output.speaker", "no_such_node")
    assert t["playback"]["target_class"] == "Audio/Sink"
    assert t["capture"] == {"target": "no_such_node", "missing": True}
