"""service/deferred_imports.py: the daemon's MQTT client without OpenSSL loaded while TLS
is off, and with the real ``ssl`` as soon as TLS is used, against a real mosquitto.

Each case runs a publisher in a fresh interpreter (the test process has imported ``ssl``
long before), driven over stdin: what it reports is read from its own /proc maps and
``sys.modules``, and what it publishes is received by a real subscriber.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bladesonar.service.messages import Topics
from mosquitto import Mosquitto, Subscriber, wait
from test_publish import _make_ca_and_server_cert, make_cfg

pytestmark = pytest.mark.broker

CLIENT = r"""
import dataclasses, json, sys
from bladesonar.service.deferred_imports import defer, loaded
deferred = defer()
from bladesonar import config
from bladesonar.service.publish import MqttPublisher
spec = json.loads(sys.argv[1])
cfg = dataclasses.replace(config.from_mapping(spec["cfg"]), base_dir=spec["base"])
pub = MqttPublisher(cfg, reconnect_min_delay=0.05, reconnect_max_delay=0.2,
                    ha_delay=(0.0, 0.05))
pub.start()
for line in sys.stdin:
    cmd = line.split()
    if cmd[0] == "publish":
        pub.publish_state({"direction": "same", "rotation": "ccw", "relative_rate": 1.0,
                           "rate_hz": float(cmd[1]), "rpm": 60 * float(cmd[1]),
                           "confidence": 0.9, "reason": "t", "rotating": True,
                           "window_s": 4.0, "reference": "abc", "status": "ok"})
    elif cmd[0] == "report":
        import hashlib
        maps = open("/proc/self/maps").read()
        print(json.dumps({"deferred": deferred, "ssl_loaded": loaded("ssl"),
                          "urllib_request_loaded": loaded("urllib.request"),
                          "libcrypto": "libcrypto" in maps,
                          "connected": pub.counters()["connected"],
                          "sha256_abc": hashlib.sha256(b"abc").hexdigest()}), flush=True)
    elif cmd[0] == "quit":
        break
pub.close()
"""

#: FIPS 180-2's test vector: SHA-256 of "abc".
SHA256_ABC = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"


class Client:
    """The publisher in its own interpreter."""

    def __init__(self, cfg_map: dict, base: Path) -> None:
        self.p = subprocess.Popen([sys.executable, "-c", CLIENT,
                                   json.dumps({"cfg": cfg_map, "base": str(base)})],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def send(self, line: str) -> None:
        assert self.p.stdin is not None
        self.p.stdin.write(line + "\n")
        self.p.stdin.flush()

    def report(self) -> dict:
        self.send("report")
        assert self.p.stdout is not None
        return json.loads(self.p.stdout.readline())

    def connected(self, timeout: float = 5.0) -> dict:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            got = self.report()
            if got["connected"]:
                return got
            time.sleep(0.05)
        raise AssertionError("the publisher did not connect")

    def close(self) -> None:
        if self.p.poll() is None:
            self.send("quit")
            self.p.wait(10)


def test_without_tls_openssl_stays_out_through_a_broker_restart(tmp_path):
    with Mosquitto(tmp_path / "broker") as b:
        cfg = {"device_id": "lean", "mqtt": {"host": "127.0.0.1", "port": b.port,
                                             "discovery": False}}
        t = Topics.for_config(make_cfg(tmp_path, b.port, device_id="lean"))
        c = Client(cfg, tmp_path)
        try:
            got = c.connected()
            assert got["deferred"] == ["ssl", "urllib.request", "_hashlib"]
            with Subscriber(b.port, [t.state]) as sub:
                c.send("publish 0.4")
                assert json.loads(sub.wait_for(t.state)[-1].payload)["rate_hz"] == 0.4
            # the broker goes away and comes back: the client's socket calls raise and
            # its except clauses name ssl's errors; it reconnects and publishes again
            b.restart()
            wait(lambda: c.report()["connected"], 10.0, "reconnected")
            with Subscriber(b.port, [t.state]) as sub:
                c.send("publish 0.6")
                wait(lambda: any(json.loads(m.payload)["rate_hz"] == 0.6
                                 for m in sub.on(t.state)), 5.0, "state after restart")
            got = c.report()
        finally:
            c.close()
    assert not got["ssl_loaded"] and not got["urllib_request_loaded"]
    assert not got["libcrypto"]
    assert got["sha256_abc"] == SHA256_ABC      # Python's own SHA-256, the same digest


def test_with_tls_the_real_ssl_is_loaded_and_verifies_the_broker(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed (needed to make test certificates)")
    _make_ca_and_server_cert(tmp_path, "good")
    tls = [f"cafile {tmp_path}/good-ca.crt", f"certfile {tmp_path}/good-server.crt",
           f"keyfile {tmp_path}/good-server.key"]
    with Mosquitto(tmp_path / "broker", extra_conf=tls) as b:
        cfg = {"device_id": "tls", "mqtt": {"host": "127.0.0.1", "port": b.port,
                                            "discovery": False, "tls": True,
                                            "ca_certs": "good-ca.crt"}}
        t = Topics.for_config(make_cfg(tmp_path, b.port, device_id="tls"))
        c = Client(cfg, tmp_path)
        try:
            got = c.connected()
            with Subscriber(b.port, [t.state], ca_certs=str(tmp_path / "good-ca.crt")) as sub:
                c.send("publish 0.8")
                assert json.loads(sub.wait_for(t.state)[-1].payload)["rate_hz"] == 0.8
        finally:
            c.close()
    assert got["ssl_loaded"] and got["libcrypto"]
