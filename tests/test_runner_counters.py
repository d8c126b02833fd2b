"""The runner's published counters survive a reopened audio path (reload, stall).

Real pieces: the sim audio backend (the in-process scene simulator, unpaced), the live
analyzer and a reference folded from a simulated recording. The publisher is a collector:
the MQTT edge is tested against a real broker in test_publish.py; here only what the
runner hands it matters.
"""

from __future__ import annotations

import threading
import time

import pytest

from bladesonar.io.config_file import load_config
from bladesonar.io.scene_file import load_scene
from bladesonar.live import LiveAnalyzer
from bladesonar.reference_build import build_reference
from bladesonar.service.backends import open_audio
from bladesonar.service.messages import state_payload
from bladesonar.service.notify import NullNotifier
from bladesonar.service.runner import Service
from bladesonar.sim.render import simulate
from loopback import SCENE, write_config

pytestmark = pytest.mark.slow   # runs the service: outside the fast tier


class Collector:
    """Keeps the state payloads the runner publishes (as the broker would carry them)."""

    def __init__(self, cfg):
        self.states, self.events, self.stats, self.statuses = [], [], [], []
        self.commands = []

    def start(self):
        pass

    def close(self):
        pass

    def publish_state(self, est, *, status="ok", detail=None):
        self.states.append(state_payload(est, status=status, detail=detail))

    def publish_status(self, fields):
        self.statuses.append(dict(fields))

    def publish_event(self, kind, **details):
        self.events.append(kind)

    def publish_stats(self, stats):
        self.stats.append(stats)

    def take_commands(self):
        got, self.commands = self.commands, []
        return got

    def counters(self):
        return {}


def _wait(pred, timeout=60.0):
    t_end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < t_end, "timed out"
        time.sleep(0.02)


def _start_service(tmp_path, sections):
    """The service on the sim backend in a thread, with a collecting publisher and a
    reference from 12 s of the same scene: (service, config path, publishers, thread)."""
    cfg_path = write_config(tmp_path / "cfg.yaml", tmp_path, **sections)
    cfg = load_config(cfg_path)
    x, _ = simulate(load_scene(SCENE), cfg, 12.0, schedule="ccw:0.45:12", seed=2,
                    snr_db=20.0)
    ref = build_reference(x, cfg, "ccw")
    pubs: list[Collector] = []

    def publisher(c):
        pubs.append(Collector(c))
        return pubs[-1]

    svc = Service(cfg, config_path=str(cfg_path), audio_factory=open_audio,
                  publisher_factory=publisher,
                  analyzer_factory=lambda c, r: LiveAnalyzer(c, r, reference_id="t"),
                  reference_loader=lambda c: ref, notifier=NullNotifier())
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    return svc, cfg_path, pubs, th


def test_audio_counters_accumulate_across_a_reopen(tmp_path):
    sections = {"audio": {"backend": "sim"}, "mqtt": {"publish_interval_s": 0.1},
                "sim": {"schedule": "ccw:0.45:60", "realtime": False}}
    svc, cfg_path, pubs, th = _start_service(tmp_path, sections)
    _wait(lambda: svc.counters.pulses_processed >= 300)
    # an audio setting changes: the reload closes the sim device and opens a new one
    write_config(cfg_path, tmp_path, **{**sections, "audio": {"backend": "sim",
                                                              "ring_pulses": 512}})
    svc.request_reload()
    _wait(lambda: svc.counters.reloads == 1 and svc.counters.pulses_processed >= 700)
    svc.request_stop()
    th.join(30)
    assert not th.is_alive()
    final = pubs[-1].stats[-1]
    assert final["reloads"] == 1 and final["reload_errors"] == 0
    # every processed pulse was delivered by one of the two device sessions
    assert final["audio"]["periods_delivered"] >= final["pulses_processed"] >= 700
    assert final["xruns"] == 0
    # and the fan was tracked after the reopen (ccw = same as the reference)
    assert pubs[-1].states[-1]["direction"] == "same"
    # the status says what audio path was found and chosen (none before it opened)
    assert pubs[-1].statuses[0]["audio"] is None
    assert pubs[-1].statuses[-1]["audio"] == {"backend": "sim", "server": None,
                                              "chosen": "sim", "path": "sim"}


def test_reloads_that_change_nothing_the_analysis_uses_keep_tracking(tmp_path):
    """A reload storm with an unchanged config (or only the broker's keys changed) keeps
    the running analyzer: no re-alignment, no pause in the published states. A tracking
    key changed restarts it."""
    sections = {"audio": {"backend": "sim"}, "mqtt": {"publish_interval_s": 0.1},
                "sim": {"schedule": "ccw:0.45:120", "realtime": False}}
    svc, cfg_path, pubs, th = _start_service(tmp_path, sections)
    try:
        # (the service thread makes its publisher first: none may exist yet)
        _wait(lambda: bool(pubs) and any(s.get("status") == "ok" for s in pubs[-1].states))
        running = svc.analyzer
        for i in range(20):
            svc.request_reload()
            _wait(lambda i=i: svc.counters.reloads == i + 1)
        # only the broker's publish interval changes: the publisher restarts, tracking not
        write_config(cfg_path, tmp_path, **{**sections, "mqtt": {"publish_interval_s": 0.2}})
        svc.request_reload()
        _wait(lambda: svc.counters.reloads == 21)
        n = len(pubs[-1].states)
        _wait(lambda: len(pubs[-1].states) >= n + 3)
        assert svc.analyzer is running
        assert pubs[-1].states[-1].get("status") == "ok"
        # a tracking key changed: a new analyzer (it re-aligns)
        write_config(cfg_path, tmp_path, **{**sections, "tracking": {"gate_sigma": 5.0}})
        svc.request_reload()
        _wait(lambda: svc.counters.reloads == 22 and svc.analyzer is not None
              and svc.analyzer is not running)
    finally:
        svc.request_stop()
        th.join(30)
    assert not th.is_alive()
