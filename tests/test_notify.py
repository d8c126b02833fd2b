"""sd_notify messages, read from a real AF_UNIX datagram socket standing in for systemd.

Each test binds the socket systemd would own (a path in a temporary folder, or a name in
the abstract namespace written ``@name``), points NOTIFY_SOCKET at it and reads what the
notifier sends. Both senders run: systemd-python's ``systemd.daemon.notify`` (libsystemd's
sd_notify) and the built-in fallback, chosen by ``make_notifier(use_systemd=...)``.
"""

from __future__ import annotations

import logging
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import pytest

from bladesonar.service import notify as notify_mod
from bladesonar.service.notify import Notifier, NullNotifier, make_notifier, watchdog_interval_s

ROOT = Path(__file__).resolve().parents[1]

try:
    import systemd.daemon  # noqa: F401
    HAVE_SYSTEMD_PYTHON = True
except ImportError:
    HAVE_SYSTEMD_PYTHON = False

SENDERS = [
    pytest.param(True, id="systemd-python", marks=pytest.mark.skipif(
        not HAVE_SYSTEMD_PYTHON, reason="systemd-python not installed (the systemd extra)")),
    pytest.param(False, id="fallback"),
]


class Receiver:
    """The service manager's end: a bound SOCK_DGRAM socket that also learns the sender's
    pid (SO_PASSCRED), which is what NotifyAccess=main checks."""

    def __init__(self, sock: socket.socket, address: str) -> None:
        self.sock = sock
        self.address = address  # the NOTIFY_SOCKET value

    def recv(self, timeout: float = 2.0) -> tuple[dict[str, str], int]:
        """One datagram as {KEY: value} and the sending pid."""
        self.sock.settimeout(timeout)
        data, anc, _flags, _addr = self.sock.recvmsg(4096, socket.CMSG_SPACE(12))
        pid = -1
        for level, kind, payload in anc:
            if level == socket.SOL_SOCKET and kind == socket.SCM_CREDENTIALS:
                pid = struct.unpack("3i", payload[:12])[0]
        text = data.decode("utf-8")
        fields = dict(line.split("=", 1) for line in text.splitlines() if line)
        return fields, pid

    def pending(self) -> list[dict[str, str]]:
        """Every datagram already queued (none are in flight: AF_UNIX sends are synchronous)."""
        out = []
        self.sock.setblocking(False)
        try:
            while True:
                data = self.sock.recv(4096).decode("utf-8")
                out.append(dict(ln.split("=", 1) for ln in data.splitlines() if ln))
        except BlockingIOError:
            return out


def _bind(address_for_env: str, bind_to: str) -> Receiver:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
    s.bind(bind_to)
    return Receiver(s, address_for_env)


@pytest.fixture
def path_socket(tmp_path):
    # sun_path holds 108 bytes; pytest's tmp_path can be longer for long test names
    folder = tmp_path if len(str(tmp_path)) < 80 else Path(tempfile.mkdtemp(prefix="bsn-"))
    path = str(folder / "notify.sock")
    r = _bind(path, path)
    yield r
    r.sock.close()
    os.unlink(path)


@pytest.fixture
def abstract_socket():
    name = f"bladesonar-test-{uuid.uuid4().hex}"
    r = _bind("@" + name, "\0" + name)
    yield r
    r.sock.close()


@pytest.fixture(params=["path", "abstract"])
def receiver(request, path_socket, abstract_socket):
    return path_socket if request.param == "path" else abstract_socket


@pytest.fixture
def clean_env(monkeypatch):
    for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"):
        monkeypatch.delenv(k, raising=False)
    return monkeypatch


class FakeClock:
    """A settable monotonic clock (the watchdog rate limit is a function of time)."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.mark.parametrize("use_systemd", SENDERS)
def test_ready_sends_ready_and_status(receiver, clean_env, use_systemd):
    clean_env.setenv("NOTIFY_SOCKET", receiver.address)
    n = make_notifier(use_systemd=use_systemd)
    assert n.sender_name == ("systemd-python" if use_systemd else "socket")
    n.ready("ccw, 0.500 Hz,\nconfidence 0.93")
    fields, pid = receiver.recv()
    assert fields == {"READY": "1", "STATUS": "ccw, 0.500 Hz, confidence 0.93"}
    assert pid == os.getpid()
    assert receiver.pending() == []


@pytest.mark.parametrize("use_systemd", SENDERS)
def test_stopping_and_reloading(receiver, clean_env, use_systemd):
    clean_env.setenv("NOTIFY_SOCKET", receiver.address)
    n = make_notifier(use_systemd=use_systemd)
    n.stopping()
    assert receiver.recv()[0] == {"STOPPING": "1"}
    before = time.monotonic_ns() // 1000
    n.reloading()
    after = time.monotonic_ns() // 1000
    fields, _ = receiver.recv()
    assert fields["RELOADING"] == "1"
    assert before <= int(fields["MONOTONIC_USEC"]) <= after
    assert set(fields) == {"RELOADING", "MONOTONIC_USEC"}


@pytest.mark.parametrize("use_systemd", SENDERS)
def test_watchdog_is_rate_limited_by_watchdog_usec(path_socket, clean_env, use_systemd):
    clean_env.setenv("NOTIFY_SOCKET", path_socket.address)
    clean_env.setenv("WATCHDOG_USEC", "2000000")  # WatchdogSec=2 -> ping every 0.5 s
    clean_env.setenv("WATCHDOG_PID", str(os.getpid()))
    clock = FakeClock()
    n = make_notifier(use_systemd=use_systemd, clock=clock)
    assert n.watchdog_interval_s == pytest.approx(0.5)
    sent_at = []
    for _ in range(100):  # 100 pulses at ~34 pulses/s: 2.9 s
        before = n.sent
        n.watchdog()
        if n.sent > before:
            sent_at.append(clock.t)
        clock.t += 1 / 34
    gaps = [b - a for a, b in zip(sent_at, sent_at[1:], strict=False)]
    assert len(sent_at) == 6  # at 0, ~0.5, ~1.0, ..., ~2.5 s
    assert path_socket.pending() == [{"WATCHDOG": "1"}] * 6
    assert all(0.5 <= g < 0.5 + 1 / 34 + 1e-9 for g in gaps)


def test_watchdog_datagrams_on_the_wire(path_socket, clean_env):
    clean_env.setenv("NOTIFY_SOCKET", path_socket.address)
    clean_env.setenv("WATCHDOG_USEC", "30000000")  # WatchdogSec=30 as in the unit
    clock = FakeClock()
    n = make_notifier(use_systemd=False, clock=clock)
    for _ in range(34 * 20):  # 20 s of pulses
        n.watchdog()
        clock.t += 1 / 34
    got = path_socket.pending()
    assert got == [{"WATCHDOG": "1"}] * 3  # at 0, 7.5 and 15 s


def test_watchdog_with_the_real_clock_sends_once_per_burst(path_socket, clean_env):
    clean_env.setenv("NOTIFY_SOCKET", path_socket.address)
    n = make_notifier(use_systemd=False)  # no WATCHDOG_USEC: at most once a second
    for _ in range(200):
        n.watchdog()
    assert path_socket.pending() == [{"WATCHDOG": "1"}]


def test_watchdog_interval_from_environment():
    pid = 4242
    assert watchdog_interval_s({}, pid) == notify_mod.WATCHDOG_DEFAULT_INTERVAL_S
    assert watchdog_interval_s({"WATCHDOG_USEC": "30000000"}, pid) == pytest.approx(7.5)
    assert watchdog_interval_s({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": "4242"},
                               pid) == pytest.approx(7.5)
    # a watchdog meant for another process (inherited environment) is not ours
    assert watchdog_interval_s({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": "1"},
                               pid) == notify_mod.WATCHDOG_DEFAULT_INTERVAL_S
    assert watchdog_interval_s({"WATCHDOG_USEC": "soon"}, pid) == \
        notify_mod.WATCHDOG_DEFAULT_INTERVAL_S


@pytest.mark.parametrize("use_systemd", SENDERS)
def test_status_skips_repeats_and_is_one_line(path_socket, clean_env, use_systemd):
    clean_env.setenv("NOTIFY_SOCKET", path_socket.address)
    n = make_notifier(use_systemd=use_systemd)
    n.ready("aligned")
    n.status("aligned")            # same as the READY's status: skipped
    n.status("waiting for a reference:\n  no such file")
    n.status("waiting for a reference: no such file")  # same once flattened
    n.status("x" * 1000)
    n.status("aligned")
    got = path_socket.pending()
    assert [g.get("STATUS") for g in got] == [
        "aligned", "waiting for a reference: no such file",
        "x" * (notify_mod.STATUS_MAX_CHARS - 3) + "...", "aligned"]
    assert got[0]["READY"] == "1"


def test_no_notify_socket_is_a_silent_no_op(path_socket, clean_env):
    for use_systemd in (None, False):
        n = make_notifier(use_systemd=use_systemd)
        assert isinstance(n, NullNotifier)
        n.ready("up")
        n.watchdog()
        n.status("s")
        n.reloading()
        n.stopping()
    assert path_socket.pending() == []


@pytest.mark.parametrize("use_systemd", SENDERS)
def test_a_missing_socket_never_raises_and_logs_once(tmp_path, clean_env, caplog,
                                                     use_systemd):
    clean_env.setenv("NOTIFY_SOCKET", str(tmp_path / "gone.sock"))
    n = make_notifier(use_systemd=use_systemd)
    assert isinstance(n, Notifier)
    with caplog.at_level(logging.DEBUG, logger="bladesonar.service.notify"):
        for _ in range(3):
            n.ready("up")
            n.watchdog()
            n.status("s")
            n.reloading()
            n.stopping()
    failures = [r for r in caplog.records if "notification failed" in r.getMessage()]
    assert len(failures) == 1 and failures[0].levelno == logging.DEBUG
    assert n.sent == 0


def test_fallback_refuses_socket_kinds_it_does_not_speak(clean_env):
    clean_env.setenv("NOTIFY_SOCKET", "vsock:2:1234")
    assert isinstance(make_notifier(use_systemd=False), NullNotifier)


@pytest.mark.parametrize("use_systemd", SENDERS)
def test_notify_from_a_subprocess(receiver, use_systemd):
    """What `bladesonar run` under systemd does: a fresh process reads NOTIFY_SOCKET from
    its environment and its own pid is the sender systemd sees."""
    code = ("from bladesonar.service.notify import make_notifier\n"
            f"n = make_notifier(use_systemd={use_systemd})\n"
            "n.ready('up'); n.watchdog(); n.status('still up'); n.stopping()\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("WATCHDOG_USEC", "WATCHDOG_PID")}
    env["NOTIFY_SOCKET"] = receiver.address
    env["PYTHONPATH"] = str(ROOT / "daemon")
    proc = subprocess.Popen([sys.executable, "-c", code], env=env)
    messages = [receiver.recv(timeout=20) for _ in range(4)]
    assert proc.wait(timeout=20) == 0
    assert [m for m, _ in messages] == [{"READY": "1", "STATUS": "up"}, {"WATCHDOG": "1"},
                                       {"STATUS": "still up"}, {"STOPPING": "1"}]
    assert {pid for _, pid in messages} == {proc.pid}


def test_the_default_sender_never_blocks_on_a_socket_nobody_reads(path_socket, clean_env):
    """A supervisor that sets NOTIFY_SOCKET but never reads it: the default notifier (the
    built-in sender for a socket path) drops what does not fit and returns at once; the
    processing loop goes on. 3000 distinct STATUS lines fill the socket's queue."""
    import threading

    clean_env.setenv("NOTIFY_SOCKET", path_socket.address)
    n = make_notifier()
    assert n.sender_name == "socket"
    done = threading.Event()

    def spam() -> None:
        for i in range(3000):
            n.status(f"line {i}")
        done.set()

    th = threading.Thread(target=spam, daemon=True)
    th.start()
    th.join(10.0)
    assert done.is_set(), "the notifier blocked on a full socket"
    dropped = n.dropped
    assert dropped > 0 and n.sent + dropped == 3000
    # what was queued is intact and in order
    got = path_socket.pending()
    assert len(got) == n.sent and got[0]["STATUS"] == "line 0"


@pytest.mark.skipif(not HAVE_SYSTEMD_PYTHON, reason="systemd-python not installed")
def test_libsystemd_sd_notify_blocks_on_a_socket_nobody_reads(path_socket):
    """Why the built-in sender is the default: libsystemd's sd_notify (systemd-python)
    waits for room in the socket for as long as it takes. Measured in a subprocess that
    is given 3 s for 3000 messages to an unread socket: it is still blocked."""
    code = ("from systemd import daemon\n"
            "for i in range(3000):\n"
            "    daemon.notify(f'STATUS=line {i}')\n")
    env = {**os.environ, "NOTIFY_SOCKET": path_socket.address}
    proc = subprocess.Popen([sys.executable, "-c", code], env=env)
    try:
        with pytest.raises(subprocess.TimeoutExpired):
            proc.wait(timeout=3.0)
    finally:
        proc.kill()
        proc.wait()
