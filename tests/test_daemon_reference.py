"""The reference managed from MQTT and by the daemon itself, end to end: the real daemon
process on the sim backend (unpaced: as fast as it computes), a real mosquitto on
127.0.0.1 and a real paho client sending what Home Assistant's buttons and select send.
Assertions are on what a subscriber receives and on the files left in the state folder."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from bladesonar.io.reference import previous_path, read_reference
from bladesonar.reference_build import SPEED_ADVICE
from loopback import ROOT, SCENE, bladesonar_cmd, write_config
from mosquitto import Mosquitto, Subscriber, require_mosquitto
from test_daemon_e2e import NotifySocket, start_daemon, stop_daemon

pytestmark = [pytest.mark.slow, pytest.mark.broker]

BASE = "bladesonar/loopback"


def jpayloads(sub: Subscriber, topic: str) -> list:
    return [json.loads(m.text) for m in sub.on(topic) if m.payload]


def events(sub: Subscriber, kind: str | None = None) -> list:
    return [e for e in jpayloads(sub, f"{BASE}/event") if kind is None or e["kind"] == kind]


def wait_event(sub: Subscriber, kind: str, count: int = 1, timeout: float = 60.0) -> dict:
    return sub.wait_until(lambda ms: (got := events(sub, kind)) and len(got) >= count
                          and got[count - 1], timeout)


def wait_state(sub: Subscriber, pred, timeout: float = 60.0) -> dict:
    return sub.wait_until(lambda ms: [p for p in jpayloads(sub, f"{BASE}/state")
                                      if pred(p)][-1:], timeout)[0]


def daemon_config(tmp_path: Path, port: int, **reference) -> Path:
    return write_config(tmp_path / "cfg.yaml", tmp_path / "state", audio={"backend": "sim"},
                        sim={"schedule": "ccw:0.45:600", "realtime": False, "seed": 4},
                        daemon={"window_s": 3},
                        mqtt={"host": "127.0.0.1", "port": port, "publish_interval_s": 0.5,
                              "stats_interval_s": 5},
                        reference={"learn_seconds": 8, "retry_s": 2, **reference})


def test_zero_config_learning_and_the_reference_commands(tmp_path):
    """No reference: the daemon learns one from the turning fan (status learning, then
    ok, relative directions); the select sets its direction (absolute rotation at once,
    same reference table, no re-alignment); the Learn button learns a new one, keeping
    the old file; Forget removes it and the daemon learns again; hostile commands change
    nothing. The previous run's retained state never shows as current."""
    require_mosquitto()
    with Mosquitto(tmp_path / "broker") as broker:
        cfg = daemon_config(tmp_path, broker.port)
        state = tmp_path / "state"
        ref_path = state / "reference.npz"
        with Subscriber(broker.port, ["bladesonar/#"]) as old:
            # what a previous run left on the broker
            old.client.publish(f"{BASE}/state", json.dumps({"direction": "same",
                                                            "rate_hz": 0.3,
                                                            "status": "ok"}),
                               qos=1, retain=True).wait_for_publish()
            old.client.publish(f"{BASE}/availability", "offline", qos=1,
                               retain=True).wait_for_publish()
            # and a command someone left retained: replayed at every subscription, so
            # the daemon must ignore it (a live message with it would act once)
            old.client.publish(f"{BASE}/command/reference", "forget", qos=1,
                               retain=True).wait_for_publish()
        sub = Subscriber(broker.port, ["bladesonar/#"])
        notify = NotifySocket(tmp_path / "notify.sock")
        proc = start_daemon(cfg, dict(os.environ), notify, tmp_path / "daemon.log")
        try:
            # 1. before availability online, the state is the new run's (unknown)
            sub.wait_until(lambda ms: any(m.topic == f"{BASE}/availability"
                                          and m.text == "online" for m in ms), 30)
            seq = [(m.topic, m.text) for m in sub.messages if not m.retain]
            first_online = seq.index((f"{BASE}/availability", "online"))
            new_states = [json.loads(t) for topic, t in seq[:first_online]
                          if topic == f"{BASE}/state"]
            # (the latest state made before the connection: starting, or already
            # reference_missing)
            assert new_states and "time" in new_states[0]
            assert new_states[0]["status"] in ("starting", "reference_missing", "learning")
            assert new_states[0]["rate_hz"] is None

            # 2. zero-config: missing -> learning -> learned (relative only) -> ok
            wait_event(sub, "reference_missing", timeout=30)
            sub.wait_until(lambda ms: any(p["status"] == "learning"
                                          for p in jpayloads(sub, f"{BASE}/status")), 30)
            learned = wait_event(sub, "reference_learned", timeout=90)
            assert learned["details"]["direction"] == "unknown"
            assert learned["details"]["source"] == "auto"
            first_id = learned["details"]["reference"]
            st = wait_state(sub, lambda p: p.get("reference") == first_id
                            and p["direction"] == "same" and p["status"] == "ok")
            assert st["rotation"] is None and st["rate_hz"] == pytest.approx(0.45, rel=0.05)
            notify.wait_for("READY=1", 10)
            ref, digest = read_reference(ref_path)
            assert digest[:12] == first_id and ref.meta["direction"] == "unknown"

            # 3. the select: the reference's direction, stored in the file, used at once
            sub.client.publish(f"{BASE}/command/reference_direction", "counterclockwise",
                               qos=1)
            ev = wait_event(sub, "reference_direction_set", timeout=30)
            assert ev["details"]["direction"] == "ccw"
            st = wait_state(sub, lambda p: p.get("rotation") == "ccw", timeout=30)
            assert st["direction"] == "same"
            ref2, digest2 = read_reference(ref_path)
            assert ref2.meta["direction"] == "ccw" and digest2[:12] == st["reference"]
            status = jpayloads(sub, f"{BASE}/status")[-1]
            assert status["reference_direction"] == "ccw" and status["status"] == "ok"

            # 4. hostile commands (and the retained forget) change nothing
            for p in (b"", b"\xff" * 70, b"learn" * 100, b"reboot"):
                sub.client.publish(f"{BASE}/command/reference", p, qos=0)
            time.sleep(1.0)
            assert len(events(sub, "reference_learned")) == 1
            assert not events(sub, "reference_forgotten")
            assert read_reference(ref_path)[1] == digest2
            sub.client.publish(f"{BASE}/command/reference", b"", qos=1,
                               retain=True).wait_for_publish()    # clear the retained one

            # 5. the Learn button: a new reference, direction carried from the estimates
            sub.client.publish(f"{BASE}/command/reference", "learn", qos=1)
            learned = wait_event(sub, "reference_learned", 2, timeout=90)
            assert learned["details"]["source"] == "command"
            assert learned["details"]["direction"] == "ccw"
            assert previous_path(ref_path).is_file()
            assert read_reference(previous_path(ref_path))[1] == digest2
            wait_state(sub, lambda p: p.get("reference") == learned["details"]["reference"]
                       and p["rotation"] == "ccw", timeout=30)

            # 6. a setting from Home Assistant: checked like the YAML, used, stored
            sub.client.publish(f"{BASE}/command/setting/learn_seconds", "100", qos=1)
            time.sleep(5.5)     # commands pass one per 5 s after a burst of 3
            sub.client.publish(f"{BASE}/command/setting/learn_seconds", "9", qos=1)
            sub.wait_until(lambda ms: [p for p in jpayloads(sub, f"{BASE}/status")
                                       if (p.get("settings") or {}).get("learn_seconds")
                                       == 9.0], 30)
            stored = json.loads((state / "settings.json").read_text())
            assert stored == {"learn_seconds": {"value": 9.0, "yaml": 8.0}}

            # 7. Forget: one step to learning (no starting, no reference_missing, no
            # advice to run a command), the file kept as .previous, the fan's direction
            # carried to the new reference
            n_status = len(jpayloads(sub, f"{BASE}/status"))
            n_events = len(events(sub))
            time.sleep(5.5)     # the rate limit again
            sub.client.publish(f"{BASE}/command/reference", "forget", qos=1)
            wait_event(sub, "reference_forgotten", timeout=30)
            learned = wait_event(sub, "reference_learned", 3, timeout=90)
            assert learned["details"]["source"] == "auto"
            assert learned["details"]["direction"] == "ccw"
            assert ref_path.is_file() and previous_path(ref_path).is_file()
            after = jpayloads(sub, f"{BASE}/status")[n_status:]
            kinds = [e["kind"] for e in events(sub)[n_events:]]
            assert kinds[:2] == ["reference_forgotten", "reference_learned"], kinds
            until_learned = [p for p in after if p["reference"] is None]
            assert until_learned and {p["status"] for p in until_learned} == {"learning"}
            assert "forgotten" in until_learned[0]["detail"]
            assert "recording 9 s" in until_learned[0]["detail"]
            assert all(p["reference_direction"] == "ccw" for p in until_learned)
            assert not any("bladesonar reference" in json.dumps(x)
                           for x in [*after, *events(sub)[n_events:]])
            wait_state(sub, lambda p: p.get("reference") == learned["details"]["reference"]
                       and p["rotation"] == "ccw" and p["running"] is True, timeout=30)
            assert proc.poll() is None
        finally:
            rc = stop_daemon(proc)
            notify.close()
            sub.close()
        log = (tmp_path / "daemon.log").read_text()
        assert rc == 0, log
        assert "retained command is ignored" in log
        assert "setting from MQTT refused: reference.learn_seconds = 100.0" in log
        assert "Traceback" not in log


def test_a_reference_that_no_longer_fits_is_called_stale_and_relearned(tmp_path):
    """The room changed after the reference was made (the sensor moved by 20 cm: the
    old reference gives confident wrong answers): the fit falls, the status says
    reference_stale with the figure, no estimate from it is published, and with
    reference.auto_relearn a new reference is learned and fits."""
    require_mosquitto()
    import subprocess

    moved = tmp_path / "moved.yaml"
    moved.write_text(SCENE.read_text().replace("sensor: [0.5, 0.6]", "sensor: [0.7, 0.6]"))
    assert "sensor: [0.7, 0.6]" in moved.read_text()
    ref_cfg = write_config(tmp_path / "ref.yaml", tmp_path / "state", audio={"backend": "sim"},
                           sim={"schedule": "ccw:0.45:600", "realtime": False, "seed": 3})
    r = subprocess.run(bladesonar_cmd("reference", "--live", "--seconds", "10",
                                      "--direction", "ccw", "--config", str(ref_cfg)),
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    with Mosquitto(tmp_path / "broker") as broker:
        cfg = daemon_config(tmp_path, broker.port, stale_after_s=20, auto_relearn=True)
        text = cfg.read_text().replace(str(SCENE), str(moved))
        cfg.write_text(text)
        with Subscriber(broker.port, ["bladesonar/#"]) as sub:
            proc = start_daemon(cfg, dict(os.environ), None, tmp_path / "daemon.log")
            try:
                stale = wait_event(sub, "reference_stale", timeout=120)
                assert stale["details"]["fit"] < 0.3
                # auto_relearn starts learning at once: the status goes from ok to
                # learning, and says why (with reference.auto_relearn off it would stay
                # reference_stale, "learn a new reference")
                st = sub.wait_until(lambda ms: [p for p in jpayloads(sub, f"{BASE}/status")
                                                if p["status"] in ("reference_stale",
                                                                   "learning")], 30)[0]
                assert st["fit"] < 0.3
                assert ("learn a new reference" in st["detail"]) if \
                    st["status"] == "reference_stale" else \
                    (st["learning"] == "relearn" and "no longer fits" in st["detail"])
                learned = wait_event(sub, "reference_learned", timeout=120)
                assert learned["details"]["source"] == "relearn"
                new = learned["details"]["reference"]
                wait_state(sub, lambda p: p.get("reference") == new
                           and p["direction"] == "same" and p["status"] == "ok", 60)
                # from the stale verdict on, nothing from the old reference was published
                # as known (while stale, and while the new one was being learned): every
                # state in arrival order from the stale event to the first one from the
                # new reference. (Picked out by their status instead, the states of that
                # stretch were once none at all: the simulator runs faster than real
                # time and states go out every 0.5 s of wall time.)
                order = [(m.topic, json.loads(m.text)) for m in sub.messages
                         if m.payload and m.topic in (f"{BASE}/state", f"{BASE}/event")]
                start = next(i for i, (t, p) in enumerate(order)
                             if t.endswith("/event") and p["kind"] == "reference_stale")
                end = next(i for i, (t, p) in enumerate(order)
                           if i > start and t.endswith("/state") and p.get("reference") == new)
                states = [p for t, p in order[start:end] if t.endswith("/state")]
                assert all(p["direction"] == "unknown" and p["rotation"] is None
                           for p in states), states
                # and published as what it was
                assert all(p["status"] in ("reference_stale", "learning") for p in states), \
                    states
            finally:
                rc = stop_daemon(proc, signal.SIGTERM)
        assert rc == 0


def test_a_reference_learned_at_a_poor_speed_is_learned_again_at_another(tmp_path):
    """Zero-config, a fan at exactly 1/40 blade period per pulse: the reference the daemon
    learns shows the same 40 angles every period and warns that it needs another fan
    speed (reference_build.SPEED_ADVICE). The fan then turns 4 % faster: the daemon learns
    again by itself (the event's source `speed`), and the new file, learned at the new
    speed, carries no such warning and says why it was learned."""
    require_mosquitto()
    from bladesonar import config

    c = config.Config()
    poor = c.prf_hz / 40.0 / c.scene.blades                    # Hz: 1/40 period per pulse
    with Mosquitto(tmp_path / "broker") as broker:
        cfg = daemon_config(tmp_path, broker.port)
        cfg.write_text(cfg.read_text().replace(
            "ccw:0.45:600", f"ccw:{poor:.6f}:40,ccw:{1.04 * poor:.6f}:600~2"))
        assert f"ccw:{poor:.6f}:40" in cfg.read_text()
        ref_path = tmp_path / "state" / "reference.npz"
        with Subscriber(broker.port, ["bladesonar/#"]) as sub:
            proc = start_daemon(cfg, dict(os.environ), None, tmp_path / "daemon.log")
            try:
                first = wait_event(sub, "reference_learned", timeout=120)["details"]
                assert first["source"] == "auto"
                assert first["rate_hz"] == pytest.approx(poor, rel=0.01)
                assert any(SPEED_ADVICE in w for w in first["warnings"]), first["warnings"]
                again = wait_event(sub, "reference_learned", 2, timeout=180)["details"]
                assert again["source"] == "speed"
                assert again["rate_hz"] == pytest.approx(1.04 * poor, rel=0.01)
                assert not any(SPEED_ADVICE in w for w in again["warnings"])
                ref, digest = read_reference(ref_path)
                assert digest[:12] == again["reference"]
                assert ref.meta["learned_by"] == "speed"
                assert read_reference(previous_path(ref_path))[0].meta["learned_by"] == "auto"
                time.sleep(2.0)
                assert len(events(sub, "reference_learned")) == 2     # and no more
            finally:
                rc = stop_daemon(proc, signal.SIGTERM)
        assert rc == 0
