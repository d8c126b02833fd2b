"""The daemon's MQTT edge: a broker publisher (paho-mqtt 2.x) and a JSON-lines stand-in.

Publishing never blocks the processing loop and never fails it. The paho network thread
connects, reconnects (1 s doubling to 60 s) and writes; the loop only hands over
messages. While the broker is away the publisher keeps the latest state and stats and a
bounded queue of events (``mqtt.event_queue``; the oldest are dropped and counted); on
every (re)connect it publishes availability ``online``, the discovery configs, the latest
state and stats, and then the queued events in order. When Home Assistant announces
``online`` on ``<discovery_prefix>/status`` the discovery configs and state are published
again after a short random delay.

Messages paho still holds from a previous connection (sent but never acknowledged) are
not left to paho's resend: paho would send them *after* the fresh ones published on
reconnect, so an old state would overwrite the new retained one and old events would
arrive after newer ones. The publisher puts such events back at the head of its queue
and drops the rest (availability, discovery, state and stats are republished anyway).
"""

from __future__ import annotations

import collections
import json
import logging
import math
import os
import random
import ssl
import stat
import sys
import threading
import time
from collections.abc import Mapping
from typing import IO, TYPE_CHECKING, Any, Protocol

from ..answer import Direction, Kind
from ..errors import ConfigError
from .messages import (
    Command,
    CommandError,
    Message,
    RunningHold,
    Topics,
    availability_message,
    clean,
    discovery_messages,
    event_message,
    event_payload,
    is_legacy_config,
    migration_messages,
    parse_command,
    retire_messages,
    state_message,
    state_payload,
    stats_message,
    stats_payload,
    status_message,
    status_payload,
)

if TYPE_CHECKING:
    from ..answer import Estimate
    from ..config import Config

log = logging.getLogger(__name__)
#: At most one log line per this many seconds for Home Assistant's ``online`` messages
#: (anyone on the broker can send them; a flood once logged 25,000 lines).
HA_LOG_INTERVAL_S = 60.0
#: Commands (the command topics are writable by any client of the broker): at most
#: COMMAND_BURST at once, then one per COMMAND_INTERVAL_S; more are dropped and counted.
COMMAND_BURST = 3
COMMAND_INTERVAL_S = 5.0
#: Commands waiting for the processing loop (it takes them every pulse).
COMMAND_QUEUE = 8
#: At most one log line per this many seconds about refused commands.
COMMAND_LOG_INTERVAL_S = 60.0
#: Largest password file read, bytes (/dev/zero there must not fill the memory).
MAX_PASSWORD_FILE = 64 << 10
#: Largest TLS certificate or key file (a CA bundle is about 200 kB), bytes.
MAX_PEM_FILE = 16 << 20


class Publisher(Protocol):
    """What the runner needs from a publisher."""

    def start(self) -> None: ...

    def publish_state(self, estimate: Estimate | Mapping[str, Any] | None, *,
                      status: str = "ok", detail: str | None = None) -> None: ...

    def publish_status(self, fields: dict[str, Any]) -> None:
        """The status message (status, reference); the runner calls it on change only."""
        ...

    def publish_event(self, kind: str, **details: Any) -> None: ...

    def publish_stats(self, stats: Mapping[str, Any]) -> None: ...

    def take_commands(self) -> list[Command]:
        """Commands received since the last call, validated and rate-limited."""
        ...

    def counters(self) -> dict[str, Any]:
        """At least ``reconnects`` and ``dropped_events``."""
        ...

    def close(self) -> None: ...


def make_publisher(cfg: Config) -> Publisher:
    """JSON lines on stdout when ``mqtt.host`` is null, else an MQTT publisher (not started).

    Raises :class:`ConfigError` for an unreadable password or TLS file.
    """
    if cfg.mqtt.host is None:
        return StdoutPublisher(cfg)
    return MqttPublisher(cfg)


# -- credentials and TLS -----------------------------------------------------------------


def read_password(cfg: Config) -> str | None:
    """The broker password from ``mqtt.password_file`` (first line) or ``mqtt.password_env``.

    Errors name the key and the fix, never the password.
    """
    m = cfg.mqtt
    if m.password_file is not None and m.password_env is not None:
        raise ConfigError("mqtt.password_env", m.password_env,
                          "set only one of mqtt.password_file and mqtt.password_env")
    if m.password_file is not None:
        from ..io.files import NotAFile, TooLarge, read_capped

        path = cfg.path(m.password_file)
        try:
            text = read_capped(path, MAX_PASSWORD_FILE).decode("utf-8")
        except (TooLarge, NotAFile) as exc:
            raise ConfigError("mqtt.password_file", m.password_file,
                              f"{exc} ({path}); give a small file holding the broker "
                              "password on its first line") from None
        except OSError as exc:
            raise ConfigError("mqtt.password_file", m.password_file,
                              f"cannot be read ({exc.strerror or type(exc).__name__}: {path}); "
                              "give a file the daemon's user can read, holding the broker "
                              "password on its first line") from None
        except UnicodeDecodeError:
            raise ConfigError("mqtt.password_file", m.password_file,
                              f"is not UTF-8 text ({path}); put the broker password on its "
                              "first line") from None
        lines = text.splitlines()
        if not lines or not lines[0]:
            raise ConfigError("mqtt.password_file", m.password_file,
                              f"is empty ({path}); put the broker password on its first line")
        try:
            if path.stat().st_mode & 0o004:
                log.warning("mqtt.password_file %s is readable by every user; chmod 600 it",
                            path)
        except OSError:
            pass
        return lines[0]
    if m.password_env is not None:
        password = os.environ.get(m.password_env)
        if not password:
            raise ConfigError("mqtt.password_env", m.password_env,
                              "names an environment variable that is not set or is empty; set "
                              "it (systemd: Environment= or EnvironmentFile=), or use "
                              "mqtt.password_file")
        return password
    return None


def tls_files(cfg: Config) -> dict[str, str]:
    """``ca_certs``/``certfile``/``keyfile`` for ``tls_set``, checked readable, resolved."""
    m = cfg.mqtt
    files: dict[str, str] = {}
    for key in ("ca_certs", "certfile", "keyfile"):
        value = getattr(m, key)
        if value is None:
            continue
        if not m.tls:
            log.warning("mqtt.%s is set but mqtt.tls is false: connecting without TLS", key)
            continue
        path = cfg.path(value)
        try:
            with open(path, "rb") as f:
                st = os.fstat(f.fileno())
        except OSError as exc:
            raise ConfigError(f"mqtt.{key}", value,
                              f"cannot be read ({exc.strerror or type(exc).__name__}: {path}); "
                              "give a PEM file the daemon's user can read") from None
        # OpenSSL reads the whole file: a device (/dev/zero) or a huge file is refused here
        if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_PEM_FILE:
            raise ConfigError(f"mqtt.{key}", value,
                              f"is not a regular file of at most {MAX_PEM_FILE >> 20} MiB "
                              f"({path}); give a PEM file") from None
        files[key] = str(path)
    if "keyfile" in files and "certfile" not in files:
        raise ConfigError("mqtt.keyfile", m.keyfile,
                          "needs mqtt.certfile (the client certificate) as well")
    return files


# -- commands --------------------------------------------------------------------------------


class CommandInbox:
    """Commands from the broker's network thread to the processing loop.

    Any client of the broker can write the command topics, so nothing here trusts a
    message: retained ones are ignored (a command left on the broker would run again at
    every start), payloads are validated (:func:`messages.parse_command`), at most
    ``burst`` commands pass at once and then one per ``interval_s`` (a token bucket), at
    most ``queue`` wait for the loop, and the log says what was refused at most once per
    ``log_interval_s`` (with a count of the lines not written).
    """

    def __init__(self, topics: Topics, *, burst: int = COMMAND_BURST,
                 interval_s: float = COMMAND_INTERVAL_S, queue: int = COMMAND_QUEUE,
                 log_interval_s: float = COMMAND_LOG_INTERVAL_S,
                 clock: Any = time.monotonic) -> None:
        self.topics = topics
        self.burst, self.interval_s, self.log_interval_s = burst, interval_s, log_interval_s
        self.clock = clock
        self._lock = threading.Lock()
        self._q: collections.deque[Command] = collections.deque(maxlen=queue)
        self._tokens = float(burst)
        self._t = clock()
        self._logged_at = -math.inf
        self._quiet = 0
        self.accepted = 0
        self.refused = 0

    def offer(self, topic: str, payload: bytes, retain: bool = False) -> Command | None:
        """A message from a command topic; the command if it was accepted."""
        why: str | None = None
        cmd: Command | None = None
        if retain:
            why = (f"{topic}: a retained command is ignored (it would run at every start); "
                   f"clear it with: mosquitto_pub -r -n -t {topic}")
        else:
            try:
                cmd = parse_command(self.topics, topic, payload)
            except CommandError as exc:
                why = str(exc)
        with self._lock:
            now = self.clock()
            if cmd is not None:
                self._tokens = min(float(self.burst),
                                   self._tokens + (now - self._t) / self.interval_s)
                self._t = now
                if self._tokens >= 1.0:
                    self._tokens -= 1.0
                    self._q.append(cmd)
                    self.accepted += 1
                    log.info("MQTT: command %s%s received", cmd.name,
                             f" {cmd.value}" if cmd.value else "")
                    return cmd
                why = (f"{topic}: command {cmd.name} refused: more than {self.burst} "
                       f"commands within {self.interval_s * self.burst:g} s")
            self.refused += 1
            if now - self._logged_at >= self.log_interval_s:
                more = f" ({self._quiet} more refused since the last such line)" \
                    if self._quiet else ""
                log.warning("MQTT: %s%s", why, more)
                self._logged_at, self._quiet = now, 0
            else:
                self._quiet += 1
        return None

    def take(self) -> list[Command]:
        with self._lock:
            got = list(self._q)
            self._q.clear()
        return got


# -- MQTT ----------------------------------------------------------------------------------


def _acked(info: Any) -> bool:
    """Whether paho got the broker's acknowledgement for a message (False on any error)."""
    try:
        return bool(info.is_published())
    except (ValueError, RuntimeError):
        return False


class MqttPublisher:
    """Publishes to a broker through paho-mqtt's network thread.

    Parameters
    ----------
    cfg : Config
        ``device_id`` and the ``mqtt`` section.
    reconnect_min_delay, reconnect_max_delay : float
        Reconnect back-off, s (doubles from min to max; tests use short ones).
    ha_delay : (float, float)
        Range of the random delay before republishing after Home Assistant's ``online``, s.
    close_timeout : float
        How long ``close`` waits for the broker to acknowledge ``offline``, s.
    """

    def __init__(self, cfg: Config, *, reconnect_min_delay: float = 1.0,
                 reconnect_max_delay: float = 60.0, ha_delay: tuple[float, float] = (1.0, 5.0),
                 close_timeout: float = 2.0) -> None:
        try:
            import paho.mqtt.client as mqtt
        except ImportError:
            mqtt = None  # type: ignore[assignment]  # said just below, with the fix
        if mqtt is None or not hasattr(mqtt, "CallbackAPIVersion"):
            found = "not installed" if mqtt is None else "installed in a 1.x version"
            raise ConfigError("mqtt.host", cfg.mqtt.host,
                              f"needs paho-mqtt 2.x, which is {found}: install "
                              "bladesonar[mqtt], or set mqtt.host: null to print the messages "
                              "as JSON lines")
        m = cfg.mqtt
        if m.host is None:
            raise ConfigError("mqtt.host", m.host, "give the broker's host name, or use "
                              "make_publisher, which prints JSON lines for a null host")
        self.cfg = cfg
        self.topics = Topics.for_config(cfg)
        self.host: str = m.host
        self.port = m.port
        self.client_id = m.client_id or f"bladesonar-{cfg.device_id}"
        self.ha_delay = ha_delay
        self.close_timeout = close_timeout
        password = read_password(cfg)
        if password is not None and not m.username:
            raise ConfigError("mqtt.username", m.username,
                              "must be set when a password is given (mqtt.password_file or "
                              "mqtt.password_env)")
        files = tls_files(cfg)
        self._discovery = discovery_messages(cfg, self.topics) if m.discovery else []
        self.commands = CommandInbox(self.topics)
        self._subscriptions = [(t, 1) for t in self.topics.commands] if m.commands else []
        if m.discovery:
            self._subscriptions.append((self.topics.ha_status, 1))
        #: per-entity configs of earlier versions found retained on the broker (topics)
        self._legacy: set[str] = set()
        #: mid of the subscription whose SUBACK says the retained legacy configs are in
        self._discovery_mid: int | None = None
        self._running = RunningHold()

        self._lock = threading.RLock()
        self._events: collections.deque[Message] = collections.deque()
        self._event_cap = m.event_queue
        self._inflight: list[tuple[Any, Message]] = []   # (MQTTMessageInfo, event)
        self._state: Message | None = None
        self._status: Message | None = None
        self._stats: Message | None = None
        self._connected = False
        self._ever_connected = False
        self._started = False
        self._closed = False
        self._reconnects = 0
        self._dropped = 0
        self._drop_logged = False
        self._down_logged = False
        self._down_since: float | None = None
        self._refused: str | None = None
        self._ha_timer: threading.Timer | None = None
        #: the HA status topic is writable by any client of the broker: its log line is
        #: rate-limited (monotonic time of the last line, messages not logged since)
        self._ha_logged_at = -math.inf
        self._ha_quiet = 0

        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=self.client_id,
                        protocol=mqtt.MQTTv311, clean_session=True)
        # paho's own lines (socket errors on every broker restart...) only under --debug;
        # connection changes are reported by the callbacks below at info/warning/error
        paho_log = logging.getLogger(f"{__name__}.paho")
        c.on_log = lambda client, userdata, level, buf: paho_log.debug("%s", buf)
        c.suppress_exceptions = True  # a bug in a callback must not end the network thread
        # paho's annotation says int, its code takes seconds as any number
        c.reconnect_delay_set(reconnect_min_delay, reconnect_max_delay)  # type: ignore[arg-type]
        c.will_set(self.topics.availability, "offline", qos=1, retain=True)
        if m.username:
            c.username_pw_set(m.username, password)
        if m.tls:
            try:
                # cert_reqs=CERT_REQUIRED: the broker is verified
                c.tls_set(ca_certs=files.get("ca_certs"), certfile=files.get("certfile"),
                          keyfile=files.get("keyfile"))
            except (ssl.SSLError, OSError, ValueError) as exc:
                raise ConfigError("mqtt.tls", True,
                                  f"TLS setup failed ({exc}); check mqtt.ca_certs, "
                                  "mqtt.certfile and mqtt.keyfile") from None
        c.on_connect = self._on_connect
        c.on_connect_fail = self._on_connect_fail
        c.on_disconnect = self._on_disconnect
        c.on_message = self._on_message
        c.on_subscribe = self._on_subscribe
        self.client = c

    @property
    def where(self) -> str:
        return f"{self.host}:{self.port}"

    # -- the processing loop's side (never blocks) ----------------------------------------

    def start(self) -> None:
        """Begin connecting in the background; returns at once, broker up or not."""
        with self._lock:
            if self._started or self._closed:
                return
            self._started = True
        log.info("MQTT: connecting to %s as %s%s", self.where, self.client_id,
                 " over TLS" if self.cfg.mqtt.tls else "")
        self.client.connect_async(self.host, self.port, keepalive=self.cfg.mqtt.keepalive_s)
        self.client.loop_start()

    def publish_state(self, estimate: Estimate | Mapping[str, Any] | None, *,
                      status: str = "ok", detail: str | None = None) -> None:
        """Retained state; while disconnected only the latest is kept."""
        running = self._running.update(_kind_of(estimate), status, time.monotonic())
        msg = state_message(self.topics, state_payload(estimate, status=status,
                                                       detail=detail, running=running))
        with self._lock:
            self._state = msg
            if self._connected and not self._closed:
                self._send(msg)

    def publish_status(self, fields: dict[str, Any]) -> None:
        """Retained status; while disconnected only the latest is kept."""
        msg = status_message(self.topics, status_payload(fields))
        with self._lock:
            self._status = msg
            if self._connected and not self._closed:
                self._send(msg)

    def take_commands(self) -> list[Command]:
        return self.commands.take()

    def publish_event(self, kind: str, **details: Any) -> None:
        """An event; queued (bounded, in order) while disconnected."""
        msg = event_message(self.topics, event_payload(kind, details))
        with self._lock:
            if self._closed:
                log.debug("MQTT: event %s after close, not sent", kind)
            elif self._connected:
                self._send_event(msg)
            else:
                self._queue([msg])

    def publish_stats(self, stats: Mapping[str, Any]) -> None:
        """Retained stats with ``time`` (and this publisher's counters if missing)."""
        with self._lock:
            extra = {"reconnects": self._reconnects, "dropped_events": self._dropped}
        msg = stats_message(self.topics, stats_payload(stats, extra=extra))
        with self._lock:
            self._stats = msg
            if self._connected and not self._closed:
                self._send(msg)

    def counters(self) -> dict[str, Any]:
        with self._lock:
            return {"connected": self._connected, "reconnects": self._reconnects,
                    "dropped_events": self._dropped, "queued_events": len(self._events),
                    "commands": self.commands.accepted,
                    "commands_refused": self.commands.refused}

    def close(self) -> None:
        """Publish ``offline``, wait briefly for the broker's ack, disconnect."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            if self._ha_timer is not None:
                self._ha_timer.cancel()
            info = self._send(availability_message(self.topics, False)) if self._connected \
                else None
            unsent = len(self._events)
        said = ""
        if info is not None:
            try:
                info.wait_for_publish(self.close_timeout)
            except (ValueError, RuntimeError):
                pass
            if _acked(info):
                said = " (availability offline)"
            else:
                log.warning("MQTT: the broker did not acknowledge 'offline' within %.1f s",
                            self.close_timeout)
        if unsent:
            log.warning("MQTT: %d queued events were never delivered (broker away)", unsent)
        if self._started:
            self.client.disconnect()
            self.client.loop_stop()
        log.info("MQTT: closed%s", said)

    # -- sending (caller holds the lock) --------------------------------------------------

    def _send(self, msg: Message) -> Any:
        return self.client.publish(msg.topic, msg.encode(), qos=msg.qos, retain=msg.retain)

    def _send_event(self, msg: Message) -> None:
        info = self._send(msg)
        self._inflight = [x for x in self._inflight if not _acked(x[0])]
        self._inflight.append((info, msg))

    def _queue(self, msgs: list[Message], front: bool = False) -> None:
        """Add events to the bounded queue (``front``: older than those queued)."""
        merged = [*msgs, *self._events] if front else [*self._events, *msgs]
        over = len(merged) - self._event_cap
        if over > 0:
            self._dropped += over
            merged = merged[over:]
            if not self._drop_logged:
                self._drop_logged = True
                log.warning("MQTT: event queue full (%d, mqtt.event_queue); dropping the "
                            "oldest events until the broker is back", self._event_cap)
        self._events = collections.deque(merged)

    def _publish_all(self, discovery: bool = True) -> None:
        """Latest state, status and stats, availability, discovery: what a fresh
        subscriber needs. The retained values go first, so that availability ``online``
        never shows the previous run's state as current."""
        for msg in (self._state, self._status, self._stats):
            if msg is not None:
                self._send(msg)
        self._send(availability_message(self.topics, True))
        if discovery:
            for msg in self._discovery:
                self._send(msg)

    def _send_discovery(self) -> None:
        """The device config, migrating the per-entity configs found on the broker
        (messages.migration_messages): they are known once the broker acknowledged the
        subscription made after theirs, as it sends retained messages in order."""
        found = sorted(self._legacy)
        self._legacy.clear()
        before = migration_messages(self.cfg, found, self.topics) if found else []
        if found:
            log.info("MQTT: moving %d per-entity discovery configs of an earlier version "
                     "to one device config (Home Assistant keeps the entities)", len(found))
        for msg in (*before, *self._discovery):
            self._send(msg)
        self.client.unsubscribe(self.topics.legacy_configs)

    def _take_back_unacked(self) -> None:
        """Before publishing on a new connection: requeue our unacknowledged events and
        make paho forget every message of the old connection (see the module doc)."""
        unacked = [msg for info, msg in self._inflight if not _acked(info)]
        self._inflight = []
        c = self.client
        if hasattr(c, "drop_out_messages"):  # paho >= 2.2, made for this (call in on_connect)
            c.drop_out_messages()
        else:
            try:  # paho 2.0/2.1: the same by hand
                with c._out_message_mutex:
                    c._out_messages.clear()
                    c._inflight_messages = 0
            except AttributeError:  # unknown layout: paho resends (late, maybe twice)
                log.debug("MQTT: cannot clear paho's resend queue", exc_info=True)
        if unacked:
            self._queue(unacked, front=True)

    # -- paho's network thread ------------------------------------------------------------

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason_code: Any,
                    properties: Any) -> None:
        try:
            if reason_code.is_failure:
                reason = str(reason_code)
                if reason != self._refused:
                    self._refused = reason
                    hint = ""
                    if "authori" in reason.lower() or "password" in reason.lower():
                        hint = " (check mqtt.username and the password)"
                    log.error("MQTT: %s refused the connection: %s%s; retrying", self.where,
                              reason, hint)
                return
            self._refused = None
            with self._lock:
                if self._closed:
                    return
                self._take_back_unacked()
                first = not self._ever_connected
                if not first:
                    self._reconnects += 1
                self._ever_connected = True
                self._connected = True
                self._down_logged = self._drop_logged = False
                down_s = time.monotonic() - self._down_since if self._down_since else None
                self._down_since = None
                self._publish_all(discovery=False)
                n_events = len(self._events)
                while self._events:
                    self._send_event(self._events.popleft())
                dropped = self._dropped
                self._legacy.clear()
                if self._discovery:
                    # the old configs first (QoS 0: the broker sends what it retains
                    # right after its SUBACK), then ours, whose SUBACK says they are in
                    client.subscribe(self.topics.legacy_configs, 0)
                if self._subscriptions:
                    _, mid = client.subscribe(self._subscriptions)
                    self._discovery_mid = mid if self._discovery else None
            if first:
                log.info("MQTT: connected to %s; availability online", self.where)
            else:
                log.info("MQTT: reconnected to %s%s; sent the latest state and %d queued "
                         "events (%d dropped since start)", self.where,
                         f" after {down_s:.0f} s" if down_s is not None else "", n_events,
                         dropped)
        except Exception:  # noqa: BLE001 - keep the network thread alive
            log.exception("MQTT: handling the connection failed")

    def _on_connect_fail(self, client: Any, userdata: Any) -> None:
        with self._lock:
            if self._down_since is None:
                self._down_since = time.monotonic()
            first_report = not self._down_logged
            self._down_logged = True
        if first_report:
            why = " or the TLS handshake failed" if self.cfg.mqtt.tls else ""
            log.warning("MQTT: cannot connect to the broker at %s (unreachable%s); retrying "
                        "in the background, keeping the latest state and up to %d events",
                        self.where, why, self._event_cap)
        else:
            log.debug("MQTT: %s still unreachable", self.where)

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, reason_code: Any,
                       properties: Any) -> None:
        with self._lock:
            was = self._connected
            self._connected = False
            closing = self._closed
            if was and not closing:
                self._down_since = time.monotonic()
                self._down_logged = True
        if closing:
            log.debug("MQTT: disconnected (%s)", reason_code)
        elif was:
            log.warning("MQTT: lost the connection to %s (%s); reconnecting in the "
                        "background, keeping the latest state and up to %d events",
                        self.where, reason_code, self._event_cap)

    def _on_subscribe(self, client: Any, userdata: Any, mid: int, reason_codes: Any,
                      properties: Any) -> None:
        try:
            with self._lock:
                if mid != self._discovery_mid or self._closed or not self._connected:
                    return
                self._discovery_mid = None
                self._send_discovery()
        except Exception:  # noqa: BLE001 - keep the network thread alive
            log.exception("MQTT: publishing the discovery config failed")

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        try:
            if msg.retain and msg.payload and is_legacy_config(self.topics, msg.topic):
                with self._lock:
                    self._legacy.add(msg.topic)
                return
            if msg.topic in self.topics.commands:
                self.commands.offer(msg.topic, bytes(msg.payload), bool(msg.retain))
                return
        except Exception:  # noqa: BLE001 - keep the network thread alive
            log.exception("MQTT: handling a command failed")
            return
        if msg.topic != self.topics.ha_status or msg.payload.strip().lower() != b"online":
            return
        delay = random.uniform(*self.ha_delay)
        now = time.monotonic()
        if now - self._ha_logged_at >= HA_LOG_INTERVAL_S:
            more = (f" ({self._ha_quiet} more 'online' since the last such line)"
                    if self._ha_quiet else "")
            log.info("MQTT: Home Assistant is online; republishing discovery and state in "
                     "%.1f s%s", delay, more)
            self._ha_logged_at, self._ha_quiet = now, 0
        else:
            self._ha_quiet += 1
        with self._lock:
            if self._closed:
                return
            if self._ha_timer is not None:
                self._ha_timer.cancel()
            self._ha_timer = threading.Timer(delay, self._republish)
            self._ha_timer.daemon = True
            self._ha_timer.start()

    def _republish(self) -> None:
        try:
            with self._lock:
                if self._connected and not self._closed:
                    # while the old configs are still being looked for, the device
                    # config waits for them (_send_discovery sends it)
                    self._publish_all(discovery=self._discovery_mid is None)
        except Exception:  # noqa: BLE001 - a timer thread; log and carry on
            log.exception("MQTT: republishing for Home Assistant failed")


def retire(cfg: Config, timeout: float = 10.0) -> list[str]:
    """Remove the device from Home Assistant and its retained topics from the broker:
    the device config, any per-entity config of an earlier version, state, status,
    stats and availability (an empty retained payload each). Run with the daemon
    stopped (it would announce itself again). The topics cleared out.

    Raises ConfigError (no broker configured) or BladesonarError (the broker cannot be
    reached or refuses, or does not acknowledge within ``timeout`` s).
    """
    from ..errors import BladesonarError

    if cfg.mqtt.host is None:
        raise ConfigError("mqtt.host", None, "names no broker: there is nothing to retire")
    pub = MqttPublisher(cfg, close_timeout=timeout)
    c, topics = pub.client, pub.topics
    found: set[str] = set()
    ready = threading.Event()
    problem: list[str] = []
    last_mid: list[int] = []

    def on_connect(client: Any, userdata: Any, flags: Any, reason_code: Any,
                   properties: Any) -> None:
        if reason_code.is_failure:
            problem.append(f"the broker refused the connection: {reason_code}")
            ready.set()
            return
        client.subscribe(topics.legacy_configs, 0)
        last_mid.append(client.subscribe(topics.device_config, 0)[1])

    def on_subscribe(client: Any, userdata: Any, mid: int, reason_codes: Any,
                     properties: Any) -> None:
        if last_mid and mid == last_mid[0]:
            ready.set()     # retained messages of both came before this SUBACK

    def on_message(client: Any, userdata: Any, msg: Any) -> None:
        if msg.retain and msg.payload and is_legacy_config(topics, msg.topic):
            found.add(msg.topic)

    c.on_connect, c.on_subscribe, c.on_message = on_connect, on_subscribe, on_message
    c.on_disconnect = c.on_connect_fail = None
    try:
        c.connect(pub.host, pub.port, keepalive=cfg.mqtt.keepalive_s)
    except OSError as exc:
        raise BladesonarError(f"cannot reach the broker at {pub.where}: "
                              f"{exc.strerror or exc}") from None
    c.loop_start()
    try:
        if not ready.wait(timeout) or problem:
            raise BladesonarError(problem[0] if problem else
                                  f"the broker at {pub.where} did not answer within "
                                  f"{timeout:g} s")
        msgs = [*retire_messages(cfg, topics),
                *(Message(t, None, qos=1, retain=True) for t in sorted(found))]
        infos = [c.publish(m.topic, m.encode(), qos=m.qos, retain=m.retain) for m in msgs]
        end = time.monotonic() + timeout
        for info in infos:
            info.wait_for_publish(max(end - time.monotonic(), 0.01))
        if not all(_acked(i) for i in infos):
            raise BladesonarError(f"the broker at {pub.where} did not acknowledge the "
                                  f"removal within {timeout:g} s; run it again")
        return [m.topic for m in msgs]
    finally:
        c.disconnect()
        c.loop_stop()


def _kind_of(estimate: Estimate | Mapping[str, Any] | None) -> Kind | None:
    """What the answer knows of the motion, for RunningHold: its direction's kind, or
    ``turning`` for a fan known to turn whose direction is in doubt (``rotating`` true
    with the direction unknown)."""
    if estimate is None:
        return None
    if not isinstance(estimate, Mapping):
        return estimate.kind
    d = estimate.get("direction")
    if d == Direction.UNKNOWN and estimate.get("rotating"):
        return Kind.TURNING
    return Kind.of(d) if isinstance(d, str) else None


# -- stdout ------------------------------------------------------------------------------


class StdoutPublisher:
    """The same messages as JSON lines on stdout (``mqtt.host: null``), one per line.

    ``{"topic": ..., "qos": ..., "retain": ..., "payload": ...}``; availability ``online``
    at start and ``offline`` at close; no discovery configs (they are for Home Assistant).
    A closed stdout (the reader went away) is logged once; the daemon keeps running.
    """

    def __init__(self, cfg: Config, stream: IO[str] | None = None) -> None:
        self.topics = Topics.for_config(cfg)
        self._stream = stream
        self._broken = False
        self._dropped = 0
        self._started = self._closed = False
        self._running = RunningHold()

    def _emit(self, msg: Message) -> None:
        if self._broken:
            if msg.topic == self.topics.event:
                self._dropped += 1
            return
        line = json.dumps({"topic": msg.topic, "qos": msg.qos, "retain": msg.retain,
                           "payload": clean(msg.payload)}, allow_nan=False)
        stream = self._stream if self._stream is not None else sys.stdout
        try:
            stream.write(line + "\n")
            stream.flush()
        except (OSError, ValueError) as exc:  # BrokenPipeError, or a closed file
            self._broken = True
            log.warning("stdout is closed (%s); no more messages are printed", exc)

    def start(self) -> None:
        if not self._started:
            self._started = True
            self._emit(availability_message(self.topics, True))

    def publish_state(self, estimate: Estimate | Mapping[str, Any] | None, *,
                      status: str = "ok", detail: str | None = None) -> None:
        running = self._running.update(_kind_of(estimate), status, time.monotonic())
        self._emit(state_message(self.topics, state_payload(estimate, status=status,
                                                            detail=detail, running=running)))

    def publish_status(self, fields: dict[str, Any]) -> None:
        self._emit(status_message(self.topics, status_payload(fields)))

    def take_commands(self) -> list[Command]:
        return []

    def publish_event(self, kind: str, **details: Any) -> None:
        self._emit(event_message(self.topics, event_payload(kind, details)))

    def publish_stats(self, stats: Mapping[str, Any]) -> None:
        extra = {"reconnects": 0, "dropped_events": self._dropped}
        self._emit(stats_message(self.topics, stats_payload(stats, extra=extra)))

    def counters(self) -> dict[str, Any]:
        return {"connected": not self._broken, "reconnects": 0,
                "dropped_events": self._dropped, "queued_events": 0}

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._emit(availability_message(self.topics, False))


__all__ = ["CommandInbox", "MqttPublisher", "Publisher", "StdoutPublisher",
           "make_publisher", "read_password", "retire", "tls_files"]
