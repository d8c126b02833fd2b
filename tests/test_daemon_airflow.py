"""The daemon's live airflow end to end: the real daemon on the sim backend rendering a
3-D room (unpaced), a real mosquitto on 127.0.0.1 and a paho subscriber. Truth: the
scene's fan is pitched +12 degrees and turns cw seen from below, so it blows up.

Zero-config: before its first reference the daemon publishes the airflow, the rotation
it means and the rate from the blade period; the reference it learns gets its direction
from the airflow; a direction set the wrong way by hand becomes the
``airflow_contradiction`` status once sustained, and clears when set right."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from loopback import ROOT, write_config
from mosquitto import Mosquitto, Subscriber, require_mosquitto
from test_daemon_e2e import start_daemon, stop_daemon

pytestmark = [pytest.mark.slow, pytest.mark.broker]

BASE = "bladesonar/loopback"
SCENE3D = ROOT / "config" / "scenes" / "living-room-3d.yaml"


def jpayloads(sub: Subscriber, topic: str) -> list:
    return [json.loads(m.text) for m in sub.on(topic) if m.payload]


def first(sub: Subscriber, topic: str, pred, timeout: float) -> dict:
    return sub.wait_until(lambda ms: [p for p in jpayloads(sub, f"{BASE}/{topic}")
                                      if pred(p)][:1], timeout)[0]


def test_zero_config_airflow_direction_and_a_contradiction(tmp_path: Path):
    require_mosquitto()
    with Mosquitto(tmp_path / "broker") as broker:
        cfg = write_config(tmp_path / "cfg.yaml", tmp_path / "state",
                           audio={"backend": "sim"},
                           sim={"scene": str(SCENE3D), "schedule": "cw:0.6:3000",
                                "realtime": False, "seed": 4, "snr_db": 15},
                           daemon={"window_s": 3},
                           mqtt={"host": "127.0.0.1", "port": broker.port,
                                 "publish_interval_s": 0.5, "stats_interval_s": 5},
                           reference={"learn_seconds": 22, "retry_s": 2})
        sub = Subscriber(broker.port, ["bladesonar/#"])
        proc = start_daemon(cfg, dict(os.environ), None, tmp_path / "daemon.log")
        try:
            # 1. no reference yet: airflow, rotation and the blade period's rate
            early = first(sub, "state", lambda p: p["status"] == "learning"
                          and p["airflow"] != "unknown" and p["rate_hz"] is not None, 120)
            assert early["reference"] is None and early["direction"] == "unknown"
            assert early["airflow"] == "up" and early["airflow_confidence"] >= 0.68
            assert early["rotation"] == "cw" and early["rotating"] is True
            assert early["rate_hz"] == pytest.approx(0.6, rel=0.02)
            assert early["running"] is True
            # 2. the learned reference's direction comes from the airflow
            ev = first(sub, "event", lambda e: e["kind"] == "reference_learned", 120)
            d = ev["details"]
            assert (d["direction"], d["direction_source"], d["airflow"]) == \
                ("cw", "airflow", "up")
            st = first(sub, "state", lambda p: p.get("reference") == d["reference"]
                       and p["direction"] == "same" and p["airflow"] == "up", 120)
            assert st["rotation"] == "cw" and st["rate_hz"] == pytest.approx(0.6, rel=0.03)
            assert st["airflow_confidence"] >= 0.68 and st["status"] == "ok"
            # 3. a person sets the direction the wrong way: sustained, it is a status
            sub.client.publish(f"{BASE}/command/reference_direction", "counterclockwise",
                               qos=1)
            first(sub, "event", lambda e: e["kind"] == "reference_direction_set", 30)
            bad = first(sub, "status", lambda p: p["status"] == "airflow_contradiction", 240)
            assert bad["reference_direction"] == "ccw"
            for part in ("is up", "means cw", "says ccw", "set it to cw"):
                assert part in bad["detail"], bad["detail"]
            st = first(sub, "state", lambda p: p["status"] == "airflow_contradiction", 30)
            assert st["rotation"] == "ccw" and st["running"] is True
            # 4. set right: the contradiction is gone
            n = len(jpayloads(sub, f"{BASE}/status"))
            sub.client.publish(f"{BASE}/command/reference_direction", "clockwise", qos=1)
            sub.wait_until(lambda ms: [p for p in jpayloads(sub, f"{BASE}/status")[n:]
                                       if p["status"] == "ok"
                                       and p["reference_direction"] == "cw"], 60)
            assert proc.poll() is None
        finally:
            rc = stop_daemon(proc)
            sub.close()
        log = (tmp_path / "daemon.log").read_text()
        assert rc == 0, log
        assert "Traceback" not in log
