"""The loopback rooms' capture noise is a function of the position from the answer to the
session's pulse 0, so the FIFO room and the PipeWire room (other latencies, other write
sizes) give pulse k the same noise: the PipeWire tests compare the two paths on the same
data (tests/test_daemon_pipewire.py). Pure computation: no FIFO or graph is opened."""

from __future__ import annotations

import numpy as np

from bladesonar.io.config_file import load_config
from bladesonar.io.scene_file import load_scene
from bladesonar.loopback.room import Room
from loopback import write_config

SIGMA = 1e-4


def _room(tmp_path, latency: int, seed: int = 0) -> Room:
    cfg = load_config(write_config(tmp_path / "cfg.yaml", tmp_path / "state"))
    scene = load_scene(cfg.path(cfg.sim.scene))
    buffer = cfg.audio.buffer_periods * cfg.audio.period_pulses * cfg.waveform.pri_samples
    return Room(scene, cfg, "ccw:0.45:60", fifo_play="-", fifo_cap="-",
                latency_samples=buffer + latency, noise_sigma=SIGMA, seed=seed)


def _chunks(room: Room, start: int, sizes: list[int]) -> np.ndarray:
    out, at = [], start
    for n in sizes:
        out.append(room._noise(at, n))
        at += n
    return np.concatenate(out)


def test_noise_is_the_same_per_pulse_whatever_the_latency_and_the_chunks(tmp_path):
    a, b = _room(tmp_path, 321), _room(tmp_path, 4000)
    pri, n = a.pri, 20 * a.pri
    # from the answer to pulse 0 on, in the FIFO room's periods and in odd pieces
    x = _chunks(a, a._noise_origin, [a.unit] * 5)
    y = _chunks(b, b._noise_origin, [1024] * (5 * a.unit // 1024) + [5 * a.unit % 1024])
    assert len(x) == len(y) == n
    np.testing.assert_array_equal(x, y)
    # a session that began elsewhere in the stream (the PipeWire room: per session)
    b._noise_origin = 123_457
    np.testing.assert_array_equal(b._noise(123_457 + 3 * pri + 17, 500),
                                  x[3 * pri + 17:3 * pri + 517])
    # before pulse 0's answer too (the lead-in the daemon reads first)
    np.testing.assert_array_equal(_chunks(a, a._noise_origin - 5000, [777] * 9)[:5000 + pri],
                                  a._noise(a._noise_origin - 5000, 5000 + pri))


def test_noise_is_white_at_its_sigma_and_another_seed_draws_another(tmp_path):
    a, c = _room(tmp_path, 321), _room(tmp_path, 321, seed=1)
    x = a._noise(a._noise_origin, 200 * a.pri)
    assert abs(np.std(x) / SIGMA - 1.0) < 0.01          # 259 400 draws: 0.14 % s.e.
    assert abs(np.corrcoef(x[:-1], x[1:])[0, 1]) < 0.01
    # one PRI's draw is not another's
    assert abs(np.corrcoef(x[:a.pri], x[a.pri:2 * a.pri])[0, 1]) < 0.1
    assert abs(np.corrcoef(x, c._noise(c._noise_origin, 200 * a.pri))[0, 1]) < 0.01
