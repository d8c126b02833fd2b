"""publish.py: what a real subscriber on a real mosquitto receives, and the stdout stand-in.

Broker tests start mosquitto on a free 127.0.0.1 port (tests/mosquitto.py) and use short
reconnect delays; each stays well under a few seconds.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import io
import json
import logging
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bladesonar import config
from bladesonar.errors import ConfigError
from bladesonar.service.messages import STATE_KEYS, Topics, discovery_messages
from bladesonar.service.publish import MqttPublisher, StdoutPublisher, make_publisher
from mosquitto import Mosquitto, Subscriber, wait

SECRET = "s3cret-Pa55"


def make_cfg(tmp_path: Path, port: int, device_id: str = "t1", **mqtt) -> config.Config:
    cfg = config.from_mapping({"device_id": device_id,
                               "mqtt": {"host": "127.0.0.1", "port": port, **mqtt}})
    return dataclasses.replace(cfg, base_dir=str(tmp_path))


def estimate(rate: float = 0.5, direction: str = "same") -> dict:
    return {"direction": direction, "rotation": "ccw", "relative_rate": 1.0, "rate_hz": rate,
            "rpm": rate * 60, "confidence": 0.93, "reason": "test", "rotating": True,
            "window_s": 4.0, "reference": "abc123", "status": "ok"}


@pytest.fixture
def publishers():
    """Make fast-reconnecting publishers; all are closed at the end of the test."""
    made: list[MqttPublisher] = []

    def make(cfg: config.Config, **kw) -> MqttPublisher:
        kw = {"reconnect_min_delay": 0.05, "reconnect_max_delay": 0.2,
              "ha_delay": (0.0, 0.05), **kw}
        p = MqttPublisher(cfg, **kw)
        made.append(p)
        return p

    yield make
    for p in made:
        p.close()


def connected(pub: MqttPublisher, timeout: float = 5.0) -> None:
    wait(lambda: pub.counters()["connected"], timeout, "publisher connected")


def payloads(msgs) -> list:
    return [json.loads(m.payload) for m in msgs]


# -- without a broker --------------------------------------------------------------------


def test_make_publisher_chooses_by_host(tmp_path):
    assert isinstance(make_publisher(config.Config()), StdoutPublisher)
    pub = make_publisher(make_cfg(tmp_path, 1883))
    assert isinstance(pub, MqttPublisher)
    pub.close()  # never started: nothing to do, no error
    # built directly, a null host is the config's error (it failed later, in paho)
    with pytest.raises(ConfigError) as exc:
        MqttPublisher(config.Config())
    assert "mqtt.host" in str(exc.value) and "make_publisher" in str(exc.value)


def test_stdout_publisher_prints_the_messages_as_json_lines():
    out = io.StringIO()
    pub = StdoutPublisher(config.from_mapping({"device_id": "demo"}), stream=out)
    pub.start()
    pub.publish_state({**estimate(), "confidence": float("nan")})
    pub.publish_event("reversed", direction="reversed", rate_hz=0.5)
    pub.publish_stats({"uptime_s": 3.0, "xruns": 0})
    pub.close()
    lines = [json.loads(x) for x in out.getvalue().splitlines()]
    assert [(x["topic"], x["retain"]) for x in lines] == [
        ("bladesonar/demo/availability", True), ("bladesonar/demo/state", True),
        ("bladesonar/demo/event", False), ("bladesonar/demo/stats", True),
        ("bladesonar/demo/availability", True)]
    assert lines[0]["payload"] == "online" and lines[-1]["payload"] == "offline"
    state = lines[1]["payload"]
    assert state["confidence"] is None and set(STATE_KEYS) <= set(state)
    assert dt.datetime.fromisoformat(state["time"]).utcoffset() == dt.timedelta(0)
    assert lines[2]["payload"]["kind"] == "reversed"
    assert lines[3]["payload"]["reconnects"] == 0
    assert pub.counters() == {"connected": True, "reconnects": 0, "dropped_events": 0,
                              "queued_events": 0}


def test_stdout_publisher_survives_a_closed_pipe(caplog):
    class Broken(io.StringIO):
        def write(self, s):
            raise BrokenPipeError(32, "Broken pipe")

    pub = StdoutPublisher(config.Config(), stream=Broken())
    pub.start()
    pub.publish_event("stopped")
    pub.publish_state(estimate())
    pub.close()
    assert pub.counters()["dropped_events"] == 1
    assert "stdout is closed" in caplog.text


def test_password_file_errors_name_the_key(tmp_path, monkeypatch):
    def err(**mqtt) -> str:
        with pytest.raises(ConfigError) as exc:
            MqttPublisher(make_cfg(tmp_path, 1883, **mqtt))
        return str(exc.value)

    msg = err(username="u", password_file="missing.pw")
    assert "mqtt.password_file" in msg and "missing.pw" in msg and "cannot be read" in msg
    (tmp_path / "empty.pw").write_text("")
    assert "mqtt.password_file" in err(username="u", password_file="empty.pw")
    (tmp_path / "dir.pw").mkdir()
    assert "mqtt.password_file" in err(username="u", password_file="dir.pw")
    monkeypatch.delenv("BS_TEST_PW", raising=False)
    msg = err(username="u", password_env="BS_TEST_PW")
    assert "mqtt.password_env" in msg and "BS_TEST_PW" in msg
    monkeypatch.setenv("BS_TEST_PW", "")
    assert "mqtt.password_env" in err(username="u", password_env="BS_TEST_PW")
    (tmp_path / "ok.pw").write_text(SECRET + "\n")
    msg = err(password_file="ok.pw")  # a password needs a user name
    assert "mqtt.username" in msg and SECRET not in msg
    assert "only one" in err(username="u", password_file="ok.pw", password_env="BS_TEST_PW")


def test_tls_file_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match=r"mqtt\.ca_certs .*cannot be read"):
        MqttPublisher(make_cfg(tmp_path, 8883, tls=True, ca_certs="nope.pem"))
    (tmp_path / "bad.pem").write_text("not a certificate\n")
    with pytest.raises(ConfigError, match=r"mqtt\.tls .*TLS setup failed"):
        MqttPublisher(make_cfg(tmp_path, 8883, tls=True, ca_certs="bad.pem"))


# -- against a real broker ---------------------------------------------------------------


@pytest.mark.broker
def test_state_is_retained_and_availability_goes_online_then_offline(broker, publishers,
                                                                     tmp_path):
    cfg = make_cfg(tmp_path, broker.port, discovery=False)
    t = Topics.for_config(cfg)
    with Subscriber(broker.port, [f"{t.base}/#"]) as sub:
        pub = publishers(cfg)
        pub.start()
        assert sub.wait_for(t.availability)[0].text == "online"
        pub.publish_state(estimate(0.42))
        pub.publish_stats({"uptime_s": 1.5, "xruns": 0, "cpu_share": float("inf")})
        state = payloads(sub.wait_for(t.state))[0]
        assert set(STATE_KEYS) | {"time", "reason"} == set(state)
        assert state["rate_hz"] == 0.42 and state["reference"] == "abc123"
        when = dt.datetime.fromisoformat(state["time"])
        assert when.utcoffset() == dt.timedelta(0)
        assert abs((dt.datetime.now(dt.UTC) - when).total_seconds()) < 5
        stats = payloads(sub.wait_for(t.stats))[0]
        assert stats["cpu_share"] is None and stats["reconnects"] == 0 and "time" in stats
        # a subscriber arriving later gets the retained state and availability
        with Subscriber(broker.port, [t.state, t.availability]) as late:
            got = late.wait_for(t.state)[0]
            assert got.retain and json.loads(got.payload)["rate_hz"] == 0.42
            assert late.wait_for(t.availability)[0].text == "online"
        pub.close()
        offline = sub.wait_until(lambda ms: [m for m in ms if m.topic == t.availability
                                             and m.text == "offline"])
        assert offline and pub.counters()["connected"] is False
    with Subscriber(broker.port, [t.availability]) as late:
        msg = late.wait_for(t.availability)[0]
        assert msg.retain and msg.text == "offline"


@pytest.mark.broker
def test_starts_without_a_broker_never_blocks_and_delivers_when_it_comes(tmp_path, publishers):
    b = Mosquitto(tmp_path / "broker")  # not started: the device boots before the broker
    cfg = make_cfg(tmp_path, b.port, discovery=False)
    t = Topics.for_config(cfg)
    pub = publishers(cfg)
    t0 = time.monotonic()
    pub.start()
    pub.publish_event("started", direction="same")
    pub.publish_state(estimate(0.3))
    pub.publish_state(estimate(0.31))
    assert time.monotonic() - t0 < 0.5
    assert pub.counters()["queued_events"] == 1 and not pub.counters()["connected"]
    with b:
        with Subscriber(b.port, [f"{t.base}/#"]) as sub:
            ev = payloads(sub.wait_for(t.event))[0]
            assert ev["kind"] == "started" and ev["details"] == {"direction": "same"}
            assert payloads(sub.wait_until(lambda ms: [m for m in ms if m.topic == t.state]))[
                -1]["rate_hz"] == 0.31
        assert pub.counters()["reconnects"] == 0  # the first connection is not a reconnect
        t0 = time.monotonic()
        pub.close()
        assert time.monotonic() - t0 < 2.0


@pytest.mark.broker
def test_last_will_marks_a_killed_daemon_offline(broker, tmp_path):
    script = (
        "import sys, time\n"
        "from bladesonar import config\n"
        "from bladesonar.service.publish import make_publisher\n"
        "cfg = config.from_mapping({'device_id': 'lwt', 'mqtt': {'host': '127.0.0.1',"
        " 'port': int(sys.argv[1]), 'discovery': False}})\n"
        "p = make_publisher(cfg)\n"
        "p.start()\n"
        "p.publish_state({'direction': 'same'})\n"
        "while not p.counters()['connected']:\n"
        "    time.sleep(0.01)\n"
        "print('connected', flush=True)\n"
        "time.sleep(60)\n")
    t = Topics.for_config(make_cfg(tmp_path, broker.port, device_id="lwt"))
    with Subscriber(broker.port, [t.availability]) as sub:
        proc = subprocess.Popen([sys.executable, "-c", script, str(broker.port)],
                                stdout=subprocess.PIPE, text=True)
        assert proc.stdout is not None   # stdout=PIPE
        try:
            assert proc.stdout.readline().strip() == "connected"
            sub.wait_until(lambda ms: [m for m in ms if m.text == "online"])
            proc.kill()  # SIGKILL: no chance to say goodbye
            proc.wait(5)
            sub.wait_until(lambda ms: ms[-1].text == "offline", timeout=5)
        finally:
            proc.kill()
            proc.stdout.close()
    with Subscriber(broker.port, [t.availability]) as late:
        assert late.wait_for(t.availability)[0].text == "offline"


@pytest.mark.broker
def test_events_wait_for_the_broker_in_order_and_the_queue_is_bounded(tmp_path, publishers):
    with Mosquitto(tmp_path / "broker", persistence=True) as b:
        cfg = make_cfg(tmp_path, b.port, discovery=False, event_queue=3)
        t = Topics.for_config(cfg)
        # a persistent session: the broker keeps what arrives while the subscriber is away
        with Subscriber(b.port, [t.event, t.state], client_id="q-sub", clean=False) as sub:
            pub = publishers(cfg)
            pub.start()
            connected(pub)
            pub.publish_state(estimate(1.0))
            sub.wait_for(t.state)
            b.stop()
            wait(lambda: not pub.counters()["connected"], what="publisher disconnected")
            for n in range(5):
                pub.publish_event("started", n=n)
            pub.publish_state(estimate(2.0))
            pub.publish_state(estimate(3.0))
            c = pub.counters()
            assert (c["dropped_events"], c["queued_events"]) == (2, 3)
            b.start()
            events = payloads(sub.wait_for(t.event, 3, timeout=10))
            assert [e["details"]["n"] for e in events] == [2, 3, 4]
            wait(lambda: pub.counters()["reconnects"] == 1, what="one reconnect")
            time.sleep(0.2)
            assert len(sub.on(t.event)) == 3
            assert payloads(sub.on(t.state))[-1]["rate_hz"] == 3.0
        with Subscriber(b.port, [t.state]) as late:  # retained: the latest, not a stale one
            assert json.loads(late.wait_for(t.state)[0].payload)["rate_hz"] == 3.0
        assert pub.counters()["dropped_events"] == 2


@pytest.mark.broker
def test_messages_stuck_in_a_stalled_connection_do_not_overwrite_newer_ones(tmp_path,
                                                                           publishers):
    """A broker that stops answering (SIGSTOP) and dies: what paho sent into the dead
    connection must arrive before what came after, once, and the retained state must be
    the newest."""
    with Mosquitto(tmp_path / "broker", persistence=True) as b:
        cfg = make_cfg(tmp_path, b.port, discovery=False)
        t = Topics.for_config(cfg)
        with Subscriber(b.port, [t.event, t.state], client_id="s-sub", clean=False) as sub:
            pub = publishers(cfg)
            pub.start()
            connected(pub)
            pub.publish_state(estimate(1.0))
            sub.wait_for(t.state)
            b.pause()
            t0 = time.monotonic()
            pub.publish_state(estimate(2.0))
            pub.publish_event("reversed", n=1)
            assert time.monotonic() - t0 < 0.1  # handing over never waits for the broker
            time.sleep(0.3)  # paho writes them into the stalled connection
            b.kill()
            wait(lambda: not pub.counters()["connected"], what="publisher disconnected")
            pub.publish_state(estimate(3.0))
            pub.publish_event("reversed", n=2)
            b.start()
            events = payloads(sub.wait_for(t.event, 2, timeout=10))
            assert [e["details"]["n"] for e in events] == [1, 2]
            time.sleep(0.3)
            assert len(sub.on(t.event)) == 2
        with Subscriber(b.port, [t.state]) as late:
            assert json.loads(late.wait_for(t.state)[0].payload)["rate_hz"] == 3.0


@pytest.mark.broker
def test_discovery_device_config_migration_and_home_assistant_restart(broker, publishers,
                                                                      tmp_path):
    """Per-entity configs of an earlier version, retained on the broker, are handed over
    to the one device config the way Home Assistant's migrate_discovery path wants:
    migrate_discovery on the kept ones, empty retained payloads on all of them (which
    removes the retired uptime sensor), then the device config. Another device's config is
    not touched. Home Assistant's 'online' brings the device config again, nothing else."""
    cfg = make_cfg(tmp_path, broker.port, device_id="fan_1")
    t = Topics.for_config(cfg)
    old_rotation = "homeassistant/sensor/fan_1/rotation/config"
    old_trigger = "homeassistant/device_automation/fan_1/motion_stopped/config"
    old_uptime = "homeassistant/sensor/fan_1/uptime/config"
    other = "homeassistant/sensor/other/rotation/config"
    with Subscriber(broker.port, ["#"]) as old:
        for topic in (old_rotation, old_trigger, old_uptime, other):
            old.client.publish(topic, json.dumps({"unique_id": topic, "state_topic": "x"}),
                               qos=1, retain=True).wait_for_publish()
    with Subscriber(broker.port, ["homeassistant/#", t.state]) as sub:
        sub.wait_until(lambda ms: len(ms) >= 4)
        pub = publishers(cfg)
        pub.publish_state(estimate(0.5))  # before the connection: sent on connect
        pub.start()
        sub.wait_until(lambda ms: [m for m in ms if m.topic == t.device_config])
        live = [(m.topic, m.payload) for m in sub.messages
                if not m.retain and m.topic.startswith("homeassistant/")]
        migrate = json.dumps({"migrate_discovery": True}, separators=(",", ":")).encode()
        assert live[:2] == [(old_trigger, migrate), (old_rotation, migrate)]
        assert live[2:5] == [(old_trigger, b""), (old_rotation, b""), (old_uptime, b"")]
        assert live[5][0] == t.device_config and len(live) == 6
        dev = json.loads(live[5][1])
        assert dev["cmps"]["rotation"]["unique_id"] == "bladesonar_fan_1_rotation"
        assert dev["cmps"]["rate"]["availability_topic"] == t.availability
        sub.wait_for(t.state)
        # Home Assistant restarts: it announces itself; the device config comes again
        n = len(sub.messages)
        sub.client.publish(t.ha_status, "online", qos=1)
        sub.wait_until(lambda ms: [m for m in ms[n:] if m.topic == t.device_config],
                       timeout=5)
        sub.wait_for(t.state, 2, timeout=5)
        # anything else on the status topic is ignored
        sub.client.publish(t.ha_status, "offline", qos=1)
        time.sleep(0.3)
        again = [m.topic for m in sub.messages[n:] if m.topic.endswith("/config")]
        assert again == [t.device_config]
    # what a Home Assistant that starts later finds: the device config, the other
    # device's config, none of the old per-entity ones
    with Subscriber(broker.port, ["homeassistant/#"]) as late:
        time.sleep(0.5)
        assert sorted(m.topic for m in late.messages) == sorted([t.device_config, other])
        assert all(m.retain and m.payload for m in late.messages)


@pytest.mark.broker
def test_running_is_held_through_a_reversal_and_off_at_the_confirmed_stop(broker, publishers,
                                                                          tmp_path):
    """The answers of a reversal and a stop (unknown for a moment around each) as a
    subscriber receives them: running on, on, on, on, off; numbers only when known."""
    cfg = make_cfg(tmp_path, broker.port)
    t = Topics.for_config(cfg)
    unknown = {"direction": "unknown", "rate_hz": 0.004, "rpm": 0.24, "confidence": 0.5,
               "reason": "confirming"}
    seq = [estimate(0.5), unknown, {**estimate(0.5, "reversed"), "rotation": "cw"}, unknown,
           {**estimate(0.0, "stopped"), "rotation": None, "rotating": False}]
    with Subscriber(broker.port, [t.state]) as sub:
        pub = publishers(cfg)
        pub.start()
        connected(pub)
        for e in seq:
            pub.publish_state(e)
        got = payloads(sub.wait_for(t.state, len(seq)))
    assert [p["running"] for p in got] == [True, True, True, True, False]
    assert [p["confidence"] for p in got] == [0.93, None, 0.93, None, 0.93]


@pytest.mark.broker
def test_a_flood_on_the_home_assistant_status_topic_logs_one_line(broker, publishers,
                                                                 tmp_path, caplog):
    """Any client of the broker can write homeassistant/status: 300 'online' messages
    give one log line (not 300) and still end in a republish."""
    cfg = make_cfg(tmp_path, broker.port, device_id="flood")
    t = Topics.for_config(cfg)
    n = len(discovery_messages(cfg))
    with Subscriber(broker.port, ["homeassistant/device/flood/config"]) as sub:
        pub = publishers(cfg)
        pub.start()
        sub.wait_until(lambda ms: len(ms) >= n and ms)
        caplog.set_level(logging.INFO, logger="bladesonar.service.publish")
        for _ in range(300):
            sub.client.publish(t.ha_status, "online", qos=0)
        sub.wait_until(lambda ms: len(ms) >= 2 * n and ms, timeout=10)
        time.sleep(0.5)
    lines = [r for r in caplog.records if "Home Assistant is online" in r.getMessage()]
    assert len(lines) == 1


def test_password_and_tls_files_that_are_devices_or_huge_are_refused_unread(tmp_path):
    """mqtt.password_file: /dev/zero, or a CA file that is a device, would be read until
    the memory runs out; they are refused in one line instead."""
    from bladesonar.service.publish import read_password, tls_files

    cfg = config.replace(config.Config(), mqtt={"host": "x", "username": "u",
                                                "password_file": "/dev/zero"})
    with pytest.raises(ConfigError, match="larger than 64 KiB"):
        read_password(cfg)
    cfg = config.replace(config.Config(), mqtt={"host": "x", "username": "u",
                                                "password_file": str(tmp_path)})
    with pytest.raises(ConfigError, match="directory"):
        read_password(cfg)
    cfg = config.replace(config.Config(), mqtt={"host": "x", "tls": True,
                                                "ca_certs": "/dev/zero"})
    with pytest.raises(ConfigError, match="regular file"):
        tls_files(cfg)


@pytest.mark.broker
def test_password_from_file_is_used_and_never_logged(tmp_path, publishers, caplog):
    passwd = shutil.which("mosquitto_passwd")
    if passwd is None:
        pytest.skip("mosquitto_passwd not installed")
    pwdb = tmp_path / "passwd"
    subprocess.run([passwd, "-c", "-b", str(pwdb), "bs", SECRET], check=True,
                   capture_output=True)
    caplog.set_level(logging.DEBUG)
    with Mosquitto(tmp_path / "broker", password_file=pwdb) as b:
        (tmp_path / "mqtt.pw").write_text(SECRET + "\n")
        os.chmod(tmp_path / "mqtt.pw", 0o600)
        cfg = make_cfg(tmp_path, b.port, username="bs", password_file="mqtt.pw",
                       discovery=False)
        t = Topics.for_config(cfg)
        with Subscriber(b.port, [t.state], username="bs", password=SECRET) as sub:
            pub = publishers(cfg)
            pub.start()
            pub.publish_state(estimate(0.7))
            assert json.loads(sub.wait_for(t.state)[0].payload)["rate_hz"] == 0.7
            pub.close()
        # a wrong password: refused, said clearly, retried quietly
        (tmp_path / "wrong.pw").write_text("not-the-" + SECRET + "\n")
        bad = publishers(make_cfg(tmp_path, b.port, username="bs", password_file="wrong.pw",
                                  discovery=False))
        bad.start()
        wait(lambda: "refused the connection" in caplog.text, what="refusal logged")
        time.sleep(0.3)
        assert not bad.counters()["connected"]
        refusals = [r for r in caplog.records if "refused the connection" in r.getMessage()]
        assert len(refusals) == 1 and refusals[0].levelno == logging.ERROR
        assert "mqtt.username" in refusals[0].getMessage()
    assert any(r.name.startswith("bladesonar.service.publish") for r in caplog.records)
    assert SECRET not in caplog.text


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def _make_ca_and_server_cert(d: Path, name: str) -> None:
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    _openssl("req", "-x509", *ec, "-keyout", f"{name}-ca.key", "-out", f"{name}-ca.crt",
             "-subj", f"/CN={name} test CA", "-days", "2", cwd=d)
    _openssl("req", *ec, "-keyout", f"{name}-server.key", "-out", f"{name}-server.csr",
             "-subj", "/CN=127.0.0.1", cwd=d)
    (d / "san.ext").write_text("subjectAltName=IP:127.0.0.1\n")
    _openssl("x509", "-req", "-in", f"{name}-server.csr", "-CA", f"{name}-ca.crt",
             "-CAkey", f"{name}-ca.key", "-CAcreateserial", "-out", f"{name}-server.crt",
             "-days", "2", "-extfile", "san.ext", cwd=d)


@pytest.mark.broker
def test_tls_verifies_the_broker(tmp_path, publishers, caplog):
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed (needed to make test certificates)")
    _make_ca_and_server_cert(tmp_path, "good")
    _make_ca_and_server_cert(tmp_path, "other")
    tls = [f"cafile {tmp_path}/good-ca.crt", f"certfile {tmp_path}/good-server.crt",
           f"keyfile {tmp_path}/good-server.key"]
    with Mosquitto(tmp_path / "broker", extra_conf=tls) as b:
        cfg = make_cfg(tmp_path, b.port, tls=True, ca_certs="good-ca.crt", discovery=False)
        t = Topics.for_config(cfg)
        with Subscriber(b.port, [t.state], ca_certs=str(tmp_path / "good-ca.crt")) as sub:
            pub = publishers(cfg)
            pub.start()
            pub.publish_state(estimate(0.8))
            assert json.loads(sub.wait_for(t.state)[0].payload)["rate_hz"] == 0.8
        # a broker whose certificate the configured CA did not sign is not trusted
        untrusted = publishers(make_cfg(tmp_path, b.port, tls=True, ca_certs="other-ca.crt",
                                        discovery=False, client_id="untrusted"))
        untrusted.start()
        wait(lambda: "TLS handshake failed" in caplog.text, what="TLS failure logged")
        assert not untrusted.counters()["connected"]


# -- commands (any client of the broker can send them) ------------------------------------


def _commands(pub: MqttPublisher, n: int, timeout: float = 5.0) -> list:
    got: list = []

    def arrived() -> bool:
        got.extend(pub.take_commands())
        return len(got) >= n

    wait(arrived, timeout, f"{n} commands")
    return got


@pytest.mark.broker
def test_commands_from_the_broker_reach_the_loop(broker, publishers, tmp_path):
    from bladesonar.service.messages import Command

    cfg = make_cfg(tmp_path, broker.port, device_id="cmd")
    t = Topics.for_config(cfg)
    pub = publishers(cfg)
    pub.start()
    connected(pub)
    with Subscriber(broker.port, ["bladesonar/#"]) as sub:
        time.sleep(0.3)     # our subscription is made in on_connect
        sub.client.publish(t.command_reference, "learn", qos=1)
        sub.client.publish(t.command_direction, " Clockwise ", qos=0)
        got = _commands(pub, 2)
    assert got == [Command("learn"), Command("direction", "cw")]
    assert pub.counters()["commands"] == 2


@pytest.mark.broker
def test_bad_hostile_and_retained_commands_are_ignored_and_logged_sparingly(
        broker, publishers, tmp_path, caplog):
    cfg = make_cfg(tmp_path, broker.port, device_id="cmd")
    t = Topics.for_config(cfg)
    caplog.set_level(logging.INFO, logger="bladesonar.service.publish")
    with Subscriber(broker.port, ["bladesonar/#"]) as sub:
        # a retained command left on the broker must not run at every start
        sub.client.publish(t.command_reference, "forget", qos=1, retain=True).wait_for_publish()
        pub = publishers(cfg)
        pub.start()
        connected(pub)
        time.sleep(0.3)
        hostile = [b"", b"LEARNX", b"\xff\xfe\x00", b"x" * 100_000, "fórget".encode(),
                   b"{\"cmd\": \"learn\"}", b"learn\x00"] * 30
        for p in hostile:
            sub.client.publish(t.command_reference, p, qos=0)
        sub.client.publish(t.command_direction, b"sideways", qos=1).wait_for_publish()
        wait(lambda: pub.counters()["commands_refused"] >= len(hostile) + 2, 10,
             "all refused")
        assert pub.take_commands() == []
        # the loop still takes a good one afterwards (the bucket refilled meanwhile? no:
        # refused messages cost no token)
        sub.client.publish(t.command_reference, "learn", qos=1)
        assert [c.name for c in _commands(pub, 1)] == ["learn"]
    lines = [r.getMessage() for r in caplog.records if "MQTT: " in r.getMessage()
             and ("ignored" in r.getMessage() or "refused" in r.getMessage()
                  or "unknown" in r.getMessage())]
    assert len(lines) == 1, lines          # at most one line a minute
    assert "retained command is ignored" in lines[0]
    assert "mosquitto_pub -r -n -t bladesonar/cmd/command/reference" in lines[0]


@pytest.mark.broker
def test_a_burst_of_commands_is_rate_limited(broker, publishers, tmp_path):
    cfg = make_cfg(tmp_path, broker.port, device_id="cmd")
    t = Topics.for_config(cfg)
    pub = publishers(cfg)
    pub.start()
    connected(pub)
    with Subscriber(broker.port, ["bladesonar/#"]) as sub:
        time.sleep(0.3)
        for _ in range(50):
            sub.client.publish(t.command_reference, "learn", qos=1)
        wait(lambda: pub.counters()["commands"] + pub.counters()["commands_refused"] >= 50,
             10, "50 handled")
    got = pub.take_commands()
    assert len(got) == 3 and pub.counters()["commands_refused"] == 47


@pytest.mark.broker
def test_commands_off_subscribes_to_nothing(broker, publishers, tmp_path):
    cfg = make_cfg(tmp_path, broker.port, device_id="cmd", commands=False)
    t = Topics.for_config(cfg)
    pub = publishers(cfg)
    pub.start()
    connected(pub)
    with Subscriber(broker.port, ["bladesonar/#"]) as sub:
        time.sleep(0.3)
        sub.client.publish(t.command_reference, "learn", qos=1).wait_for_publish()
        time.sleep(0.5)
    assert pub.take_commands() == [] and pub.counters()["commands_refused"] == 0


def test_command_inbox_refills_its_tokens_with_time():
    from bladesonar.service.publish import CommandInbox

    now = [0.0]
    inbox = CommandInbox(Topics.for_config(config.Config()), burst=2, interval_s=5.0,
                         clock=lambda: now[0])
    topic = inbox.topics.command_reference
    assert [inbox.offer(topic, b"learn") is not None for _ in range(3)] == [True, True, False]
    now[0] = 5.0
    assert inbox.offer(topic, b"learn") is not None
    assert inbox.offer(topic, b"learn") is None
    assert len(inbox.take()) == 3 and inbox.take() == []


@pytest.mark.broker
def test_retained_values_go_out_before_availability_online(broker, publishers, tmp_path):
    """A subscriber (Home Assistant) sees the new run's state before 'online': never the
    previous run's retained values shown as current."""
    cfg = make_cfg(tmp_path, broker.port, device_id="order")
    t = Topics.for_config(cfg)
    with Subscriber(broker.port, ["bladesonar/#"]) as sub:
        pub = publishers(cfg)
        pub.publish_state(None, status="starting")
        pub.publish_status({"status": "starting"})
        pub.start()
        sub.wait_until(lambda ms: any(m.topic == t.availability for m in ms))
        order = [m.topic for m in sub.messages]
    assert order.index(t.state) < order.index(t.availability)
    assert order.index(t.status) < order.index(t.availability)


@pytest.mark.broker
def test_retire_removes_the_device_and_its_retained_topics(broker, publishers, tmp_path):
    """`bladesonar retire`: an empty device config (Home Assistant deletes the device),
    the old per-entity configs and the retained topics cleared; other devices untouched."""
    cfg = make_cfg(tmp_path, broker.port, device_id="gone")
    t = Topics.for_config(cfg)
    other = "homeassistant/sensor/other/rotation/config"
    with Subscriber(broker.port, ["#"]) as old:
        for topic in ("homeassistant/sensor/gone/rpm/config", other):
            old.client.publish(topic, '{"unique_id": "x"}', qos=1,
                               retain=True).wait_for_publish()
    pub = publishers(cfg)
    pub.publish_state(estimate())
    pub.start()
    with Subscriber(broker.port, [t.device_config]) as sub:
        sub.wait_for(t.device_config)
    pub.close()
    cfg_file = tmp_path / "cfg.yaml"
    cfg_file.write_text(json.dumps({"device_id": "gone", "mqtt": {"host": "127.0.0.1",
                                                                  "port": broker.port}}))
    out = subprocess.run([sys.executable, "-m", "bladesonar", "retire", "--config",
                          str(cfg_file)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    cleared = json.loads(out.stdout)["cleared"]
    assert t.device_config in cleared and t.state in cleared and t.availability in cleared
    with Subscriber(broker.port, ["#"]) as late:
        time.sleep(0.5)
        left = sorted(m.topic for m in late.messages if m.retain)
    assert left == [other], left
    bad = subprocess.run([sys.executable, "-m", "bladesonar", "retire", "--config",
                          str(cfg_file), "--timeout", "1"], capture_output=True, text=True,
                         timeout=60)
    assert bad.returncode == 0    # nothing left to clear is not an error
    broker.stop()
    down = subprocess.run([sys.executable, "-m", "bladesonar", "retire", "--config",
                           str(cfg_file), "--timeout", "1"], capture_output=True, text=True,
                          timeout=60)
    assert down.returncode != 0 and "cannot reach the broker" in down.stderr, down.stderr
    assert "Traceback" not in down.stderr
