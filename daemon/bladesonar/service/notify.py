"""Tell systemd how the daemon is doing: the sd_notify protocol (READY, WATCHDOG, STATUS, ...).

``make_notifier()`` returns an object with ``ready(status)``, ``watchdog()``,
``status(text)``, ``stopping()`` and ``reloading()``. Under systemd (``NOTIFY_SOCKET`` set)
each call sends one datagram to the service manager; anywhere else (a terminal, a phone
without systemd, the tests) the calls do nothing and cost nothing.

Two senders, same messages:

- A tiny built-in datagram sender for the socket kinds systemd gives a service: one
  datagram on an AF_UNIX socket (a path, or an abstract name written with a leading
  ``@``), documented by systemd as a stable interface, so twenty lines cover it. It
  sends without blocking: a full socket drops the message (counted in ``dropped``).
  libsystemd's ``sd_notify`` blocks instead, for as long as nobody reads the socket
  (measured: a notify socket that a supervisor set but never read held the processing
  loop for good once the kernel's queue was full: about ten messages by default,
  ``net.unix.max_dgram_qlen``); the sonar must not stop for a
  notification.
- ``systemd.daemon.notify`` from systemd-python (the ``systemd`` extra) for the rarer
  socket kinds (``vsock:`` and the like), which only libsystemd speaks.

The processing loop calls ``watchdog()`` on every pass (once a block of pulses): it is rate
limited to one datagram per ``WATCHDOG_USEC / 4`` (systemd's advice is to ping at least
twice per interval), or per second when systemd set no watchdog. ``status()`` skips a
line identical to the last one sent. No call ever raises: a failure is logged once at
debug level and the daemon carries on (a lost notification must not stop the sonar).
"""

from __future__ import annotations

import logging
import os
import socket
import time
from collections.abc import Callable, Mapping
from typing import Any

log = logging.getLogger(__name__)

#: Watchdog pings per WATCHDOG_USEC interval (systemd advises at least 2).
WATCHDOG_PINGS_PER_INTERVAL = 4
#: Ping interval when systemd set no WATCHDOG_USEC (the ping is then harmless).
WATCHDOG_DEFAULT_INTERVAL_S = 1.0
#: Longest STATUS= text sent; longer lines are cut (systemctl shows one line anyway).
STATUS_MAX_CHARS = 200


def _one_line(text: str) -> str:
    """STATUS= must be one line (the protocol separates assignments by newlines)."""
    line = " ".join(str(text).split())
    return line if len(line) <= STATUS_MAX_CHARS else line[:STATUS_MAX_CHARS - 3] + "..."


def watchdog_interval_s(env: Mapping[str, str], pid: int | None = None) -> float:
    """Seconds between two watchdog pings for this process, from systemd's environment.

    ``WATCHDOG_USEC / WATCHDOG_PINGS_PER_INTERVAL`` when a watchdog is set for this
    process (``WATCHDOG_PID``, when present, names the process it is meant for), else
    ``WATCHDOG_DEFAULT_INTERVAL_S``.
    """
    pid = os.getpid() if pid is None else pid
    try:
        usec = int(env.get("WATCHDOG_USEC", "0"))
        wpid = int(env["WATCHDOG_PID"]) if env.get("WATCHDOG_PID") else pid
    except ValueError:
        return WATCHDOG_DEFAULT_INTERVAL_S
    if usec <= 0 or wpid != pid:
        return WATCHDOG_DEFAULT_INTERVAL_S
    return usec / 1e6 / WATCHDOG_PINGS_PER_INTERVAL


class SocketSender:
    """The built-in sender: one datagram per message to ``NOTIFY_SOCKET``.

    A leading ``@`` names a socket in Linux's abstract namespace (its first byte is NUL
    on the wire). The socket is opened on first use and kept, and never blocks: when the
    receiver's queue is full the message is dropped (``dropped``; the caller sees the
    error once), so a stuck or absent reader cannot stall the processing loop.
    """

    def __init__(self, address: str) -> None:
        if not address or address[0] not in "/@":
            raise ValueError(f"NOTIFY_SOCKET {address!r}: only a socket path or an "
                             "@abstract name is supported without systemd-python")
        self.address = "\0" + address[1:] if address[0] == "@" else address
        self._sock: socket.socket | None = None
        self.dropped = 0
        """Messages dropped because the receiver's queue was full."""

    def __call__(self, message: str) -> None:
        if self._sock is None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            self._sock.setblocking(False)
        try:
            self._sock.sendto(message.encode("utf-8"), self.address)
        except BlockingIOError:
            self.dropped += 1
            raise

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _systemd_sender() -> Callable[[str], None] | None:
    """``systemd.daemon.notify`` if systemd-python is installed, else None."""
    try:
        from systemd import daemon
    except ImportError:
        return None

    def send(message: str) -> None:
        daemon.notify(message)  # reads NOTIFY_SOCKET itself; raises OSError on failure

    return send


class Notifier:
    """Sends sd_notify messages through ``send`` (see the module docstring).

    Parameters
    ----------
    send
        Callable taking one message (newline-separated ``KEY=value`` assignments).
    watchdog_interval_s
        Least time between two WATCHDOG=1 datagrams, in seconds.
    clock
        Monotonic clock in seconds (for the watchdog rate limit).
    """

    def __init__(self, send: Callable[[str], None], *, watchdog_interval_s: float,
                 clock: Callable[[], float] = time.monotonic, sender_name: str = "") -> None:
        self._send = send
        self.watchdog_interval_s = float(watchdog_interval_s)
        self.clock = clock
        self.sender_name = sender_name
        self._last_watchdog: float | None = None
        self._last_status: str | None = None
        self._failed = False
        self.sent = 0
        """Datagrams sent successfully (for tests and stats)."""

    @property
    def dropped(self) -> int:
        """Messages the built-in sender dropped on a full socket (0 for other senders)."""
        return int(getattr(self._send, "dropped", 0))

    enabled = True

    def _notify(self, *assignments: str) -> bool:
        try:
            self._send("\n".join(assignments))
        except Exception as exc:  # noqa: BLE001 - a lost notification must not stop the sonar
            if not self._failed:
                self._failed = True
                log.debug("systemd notification failed (%s); further failures not logged: %s",
                          self.sender_name or "sender", exc)
            return False
        self.sent += 1
        return True

    def ready(self, status: str = "") -> None:
        """READY=1 (start-up or a reload is complete), with a STATUS= line if given."""
        parts = ["READY=1"]
        if status:
            line = _one_line(status)
            parts.append(f"STATUS={line}")
            self._last_status = line
        self._notify(*parts)

    def watchdog(self) -> None:
        """WATCHDOG=1, at most once per ``watchdog_interval_s``; call it from the loop."""
        now = self.clock()
        if (self._last_watchdog is not None
                and now - self._last_watchdog < self.watchdog_interval_s):
            return
        if self._notify("WATCHDOG=1"):
            self._last_watchdog = now

    def status(self, text: str) -> None:
        """STATUS=<one line> for ``systemctl status``; a repeat of the last line is skipped."""
        line = _one_line(text)
        if line == self._last_status:
            return
        if self._notify(f"STATUS={line}"):
            self._last_status = line

    def stopping(self) -> None:
        """STOPPING=1: the daemon is shutting down."""
        self._notify("STOPPING=1")

    def reloading(self) -> None:
        """RELOADING=1 with MONOTONIC_USEC= (CLOCK_MONOTONIC, what Type=notify-reload
        checks; older systemd ignores it); READY=1 must follow when the reload is done."""
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        self._notify("RELOADING=1", f"MONOTONIC_USEC={usec}")


class NullNotifier:
    """No service manager: every call is a no-op (terminals, phones, tests)."""

    enabled = False
    sent = 0
    dropped = 0

    def ready(self, status: str = "") -> None:
        pass

    def watchdog(self) -> None:
        pass

    def status(self, text: str) -> None:
        pass

    def stopping(self) -> None:
        pass

    def reloading(self) -> None:
        pass


def make_notifier(*, use_systemd: bool | None = None, env: Mapping[str, str] | None = None,
                  clock: Callable[[], float] = time.monotonic) -> Any:
    """The notifier for this process, from its environment.

    Parameters
    ----------
    use_systemd
        None: the built-in sender for a socket path or @name (what systemd gives), else
        systemd-python when importable. False: always the built-in sender. True:
        systemd-python or nothing (the tests exercise both).
    env
        Environment to read ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID``
        from (default ``os.environ``). systemd-python's sender reads ``os.environ``
        itself, so pass a different ``env`` only with the built-in sender.
    clock
        Monotonic clock in seconds for the watchdog rate limit.

    Returns
    -------
    Notifier or NullNotifier
        A ``NullNotifier`` when ``NOTIFY_SOCKET`` is unset or unusable.
    """
    env = os.environ if env is None else env
    address = env.get("NOTIFY_SOCKET", "")
    if not address:
        return NullNotifier()
    interval = watchdog_interval_s(env)
    if use_systemd is None and address[0] in "/@":
        use_systemd = False          # never blocks (module docstring)
    send = _systemd_sender() if use_systemd is not False else None
    if send is not None:
        return Notifier(send, watchdog_interval_s=interval, clock=clock,
                        sender_name="systemd-python")
    if use_systemd:
        log.debug("NOTIFY_SOCKET is set but systemd-python is not installed; not notifying")
        return NullNotifier()
    try:
        sender = SocketSender(address)
    except ValueError as exc:
        log.debug("%s; not notifying systemd", exc)
        return NullNotifier()
    return Notifier(sender, watchdog_interval_s=interval, clock=clock, sender_name="socket")
