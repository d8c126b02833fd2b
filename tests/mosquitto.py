"""A real mosquitto broker on 127.0.0.1 for tests, and a real paho subscriber.

    from mosquitto import Mosquitto, Subscriber, broker   # broker: a pytest fixture

    def test_x(broker):                  # started on a free port, stopped afterwards
        with Subscriber(broker.port, ["bladesonar/#"]) as sub:
            ...
            broker.stop(); broker.start()  # same port; retained messages are lost unless
                                           # Mosquitto(persistence=True)

Tests that use it are marked ``@pytest.mark.broker``; without a mosquitto binary they are
skipped with the reason. Tests need paho-mqtt (the ``mqtt`` extra).
"""

from __future__ import annotations

import os
import pwd
import shutil
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, NamedTuple

import pytest


def mosquitto_binary() -> str | None:
    """The mosquitto executable (on PATH or in /usr/sbin), or None."""
    found = shutil.which("mosquitto")
    if found:
        return found
    for d in ("/usr/sbin", "/usr/local/sbin"):
        p = Path(d) / "mosquitto"
        if p.is_file() and os.access(p, os.X_OK):
            return str(p)
    return None


def require_mosquitto() -> str:
    exe = mosquitto_binary()
    if exe is None:
        pytest.skip("mosquitto not installed (tools/setup installs it: apt-get install "
                    "mosquitto)")
    pytest.importorskip("paho.mqtt.client", reason="paho-mqtt not installed (extra: mqtt)")
    return exe


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_open(port: int, timeout: float = 0.2) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout):
            return True
    except OSError:
        return False


class Mosquitto:
    """One mosquitto process listening on 127.0.0.1:``port``; restartable on that port.

    ``persistence``: keep retained messages and persistent sessions across ``stop``/
    ``start`` (and ``kill``: the database is saved after every change).
    ``password_file``: a mosquitto_passwd file; anonymous clients are then refused.
    """

    def __init__(self, workdir: Path, *, port: int | None = None, persistence: bool = False,
                 password_file: Path | None = None, extra_conf: Iterable[str] = ()) -> None:
        self.exe = require_mosquitto()
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.port = port or free_port()
        self.conf = self.workdir / "mosquitto.conf"
        self.log = self.workdir / "mosquitto.log"
        # as root mosquitto would switch to the 'mosquitto' user, who cannot read our files
        lines = [f"user {pwd.getpwuid(os.geteuid()).pw_name}",
                 f"listener {self.port} 127.0.0.1"]
        if password_file is not None:
            lines += ["allow_anonymous false", f"password_file {password_file}"]
        else:
            lines += ["allow_anonymous true"]
        if persistence:
            lines += ["persistence true", f"persistence_location {self.workdir}/",
                      "autosave_on_changes true", "autosave_interval 1"]
        else:
            lines += ["persistence false"]
        lines += ["log_dest stderr", "log_type error", "log_type warning", "log_type notice",
                  "log_type information", *extra_conf]
        self.conf.write_text("\n".join(lines) + "\n")
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self, timeout: float = 5.0) -> Mosquitto:
        assert self.proc is None, "already running"
        with open(self.log, "ab") as logf:
            self.proc = subprocess.Popen([self.exe, "-c", str(self.conf)], stdout=logf,
                                         stderr=subprocess.STDOUT)
        deadline = time.monotonic() + timeout
        while not port_open(self.port):
            if self.proc.poll() is not None:
                self.proc = None
                raise RuntimeError(f"mosquitto exited at start:\n{self.log_text()}")
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"mosquitto not listening after {timeout} s:\n"
                                   f"{self.log_text()}")
            time.sleep(0.02)
        return self

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 5.0) -> None:
        """Stop (SIGTERM: clean, saves persistence) and wait until the port is closed."""
        if self.proc is None:
            return
        if sig != signal.SIGKILL:
            self.proc.send_signal(signal.SIGCONT)  # in case it was paused
        self.proc.send_signal(sig)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.proc = None

    def kill(self) -> None:
        self.stop(signal.SIGKILL)

    def restart(self) -> Mosquitto:
        self.stop()
        return self.start()

    def pause(self) -> None:
        """SIGSTOP: the kernel still accepts bytes, the broker answers nothing (a stall)."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGSTOP)

    def resume(self) -> None:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGCONT)

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def log_text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def __enter__(self) -> Mosquitto:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()


@pytest.fixture
def broker(tmp_path: Path):
    """A fresh broker (no persistence, anonymous) for one test."""
    with Mosquitto(tmp_path / "broker") as b:
        yield b


class Received(NamedTuple):
    topic: str
    payload: bytes
    retain: bool
    qos: int

    @property
    def text(self) -> str:
        return self.payload.decode()


class Subscriber:
    """A real paho client that records every message it receives, in order.

    ``client_id`` with ``clean=False`` makes a persistent session: with a persistent
    broker it gets the QoS 1 messages published while it was away, after a restart too.
    """

    def __init__(self, port: int, topics: Iterable[str] = ("#",), *,
                 client_id: str | None = None, clean: bool = True,
                 username: str | None = None, password: str | None = None,
                 ca_certs: str | None = None, timeout: float = 5.0) -> None:
        import paho.mqtt.client as mqtt

        self.port = port
        self.topics = list(topics)
        self.messages: list[Received] = []
        self._cond = threading.Condition()
        self._subscribed = threading.Event()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2,
                                  client_id=client_id or "", clean_session=clean)
        if username is not None:
            self.client.username_pw_set(username, password)
        if ca_certs is not None:
            self.client.tls_set(ca_certs=ca_certs)
        # paho's annotation says int, its code takes any number of seconds
        self.client.reconnect_delay_set(0.05, 0.2)  # type: ignore[arg-type]
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.on_subscribe = lambda *a: self._subscribed.set()
        self.client.connect("127.0.0.1", port, keepalive=30)
        self.client.loop_start()
        if not self._subscribed.wait(timeout):
            self.close()
            raise TimeoutError(f"subscriber: no SUBACK from 127.0.0.1:{port}")

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason_code: Any,
                    properties: Any) -> None:
        if reason_code.is_failure:
            return
        if not flags.session_present:
            client.subscribe([(t, 1) for t in self.topics])
        else:
            self._subscribed.set()

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        with self._cond:
            self.messages.append(Received(msg.topic, bytes(msg.payload), bool(msg.retain),
                                          msg.qos))
            self._cond.notify_all()

    def on(self, topic: str) -> list[Received]:
        with self._cond:
            return [m for m in self.messages if m.topic == topic]

    def wait_until(self, predicate: Callable[[list[Received]], Any],
                   timeout: float = 5.0) -> Any:
        """Wait until ``predicate(messages)`` is truthy; return its value."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                value = predicate(list(self.messages))
                if value:
                    return value
                left = deadline - time.monotonic()
                if left <= 0:
                    seen = [(m.topic, m.payload[:80]) for m in self.messages]
                    raise TimeoutError(f"condition not met in {timeout} s; received {seen}")
                self._cond.wait(left)

    def wait_for(self, topic: str, count: int = 1, timeout: float = 5.0) -> list[Received]:
        """The first ``count`` messages on ``topic`` (waiting for them)."""
        return self.wait_until(lambda ms: (got := [m for m in ms if m.topic == topic])
                               and len(got) >= count and got[:count], timeout)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def __enter__(self) -> Subscriber:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def wait(predicate: Callable[[], Any], timeout: float = 5.0, what: str = "condition") -> Any:
    """Poll ``predicate`` until truthy (for state that is not a message, e.g. counters)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} not reached in {timeout} s")
        time.sleep(0.01)
