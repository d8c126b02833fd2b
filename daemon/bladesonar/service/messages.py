"""What the daemon says on MQTT: topic names, payloads and Home Assistant discovery (pure).

No I/O here: every function turns settings and estimates into :class:`Message` values that
a publisher (``publish.py``: a broker, or JSON lines on stdout) sends as they are. Topics
live under ``<mqtt.topic_prefix>/<device_id>/``:

==========================  ====  ======  ==========================================
topic                       QoS   retain  payload
==========================  ====  ======  ==========================================
availability                1     yes     ``online`` / ``offline`` (also the last will)
state                       1     yes     JSON: the current estimate and its ``time``
status                      1     yes     JSON: status and reference, on change only
event                       1     no      JSON: ``kind``, ``time``, ``details``
stats                       0     yes     JSON: health counters and ``time``
command/reference           (in)          ``learn`` / ``forget`` (subscribed)
command/reference_direction (in)          ``cw`` / ``ccw`` / ``unknown`` (subscribed)
==========================  ====  ======  ==========================================

Payloads are JSON with NaN and infinities turned into ``null`` and floats rounded to six
significant digits; times are ISO-8601 in UTC with an explicit ``+00:00``.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import math
import numbers
import re
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from ..live import Estimate

#: Availability payloads (Home Assistant's defaults, so no payload_* keys are needed).
ONLINE = "online"
OFFLINE = "offline"

#: Values of the state's ``direction`` (relative to the reference's own direction).
DIRECTIONS = ("same", "reversed", "stopped", "unknown")
#: Values of the state's ``rotation`` (absolute, seen from the device), or null.
ROTATIONS = ("cw", "ccw")
#: The words Home Assistant shows for a rotation, and for a reference's direction.
ROTATION_WORDS = {"cw": "clockwise", "ccw": "counterclockwise"}
#: Motion events (transitions.py) and the reference's events (the runner).
MOTION_EVENTS = ("started", "stopped", "reversed")
REFERENCE_EVENTS = ("learned", "learn_failed", "forgotten", "direction_set", "stale",
                    "missing", "invalid")
#: Event kinds the daemon publishes (``reference_<x>`` for each of REFERENCE_EVENTS).
EVENT_KINDS = (*MOTION_EVENTS, *(f"reference_{k}" for k in REFERENCE_EVENTS))

#: The daemon's status (state ``status``, the status topic, Home Assistant's Status):
#: ``starting`` until the first estimate or problem; ``learning`` while it records and
#: folds a reference of its own; ``reference_stale`` when the stored one no longer fits
#: the room (the estimates go on, less sure).
STATUSES = ("starting", "ok", "learning", "reference_missing", "reference_invalid",
            "reference_stale", "no_signal")

#: The state payload's keys, in order; missing estimate fields are sent as null.
STATE_KEYS = ("direction", "rotation", "rotating", "rate_hz", "rpm", "relative_rate",
              "rate_state", "rate_change_hz_s", "confidence", "window_s", "reference",
              "status")
#: The status payload's keys, in order.
STATUS_KEYS = ("status", "detail", "reference", "reference_direction", "reference_rate_hz",
               "fit", "learning", "since")

#: Significant digits kept in float payload values.
FLOAT_DIGITS = 6


class Message(NamedTuple):
    """One MQTT message as a publisher sends it."""

    topic: str
    payload: Any
    """A str (sent as is), a JSON-able dict, or None (empty payload)."""
    qos: int = 0
    retain: bool = False

    def encode(self) -> str:
        """The payload on the wire."""
        if self.payload is None:
            return ""
        if isinstance(self.payload, str):
            return self.payload
        return dumps(self.payload)


@dataclasses.dataclass(frozen=True)
class Topics:
    """The daemon's topic names, from ``mqtt.topic_prefix``, ``device_id`` and
    ``mqtt.discovery_prefix``."""

    base: str
    """``<topic_prefix>/<device_id>``."""
    discovery_prefix: str
    """Home Assistant's discovery prefix (``homeassistant``)."""

    @classmethod
    def for_config(cls, cfg: Any) -> Topics:
        prefix = cfg.mqtt.topic_prefix.strip("/")
        return cls(base=f"{prefix}/{cfg.device_id}",
                   discovery_prefix=cfg.mqtt.discovery_prefix.strip("/"))

    @property
    def availability(self) -> str:
        return f"{self.base}/availability"

    @property
    def state(self) -> str:
        return f"{self.base}/state"

    @property
    def event(self) -> str:
        return f"{self.base}/event"

    @property
    def stats(self) -> str:
        return f"{self.base}/stats"

    @property
    def status(self) -> str:
        """The daemon's status and its reference (retained, published on change)."""
        return f"{self.base}/status"

    @property
    def command_reference(self) -> str:
        """Commands: ``learn`` or ``forget`` the reference."""
        return f"{self.base}/command/reference"

    @property
    def command_direction(self) -> str:
        """Commands: the reference's direction, ``cw``, ``ccw`` or ``unknown``."""
        return f"{self.base}/command/reference_direction"

    @property
    def commands(self) -> tuple[str, ...]:
        return (self.command_reference, self.command_direction)

    @property
    def ha_status(self) -> str:
        """Home Assistant's birth/last-will topic (``online`` after HA starts)."""
        return f"{self.discovery_prefix}/status"


# -- JSON --------------------------------------------------------------------------------


def clean(value: Any, digits: int = FLOAT_DIGITS) -> Any:
    """A JSON-safe copy: NaN/inf -> None, floats rounded to ``digits`` significant digits,
    numpy scalars and arrays -> Python numbers and lists, tuples -> lists, other objects
    -> str."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        x = float(value)
        if not math.isfinite(x):
            return None
        return float(f"{x:.{digits}g}")
    if isinstance(value, Mapping):
        return {str(k): clean(v, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [clean(v, digits) for v in value]
    if hasattr(value, "tolist"):  # numpy scalar or array (np.bool_ is not a bool)
        return clean(value.tolist(), digits)
    return str(value)


def dumps(obj: Any) -> str:
    """Compact JSON of :func:`clean` ``(obj)``; never emits NaN or Infinity."""
    return json.dumps(clean(obj), separators=(",", ":"), allow_nan=False)


def utc_iso(t: float | None = None) -> str:
    """ISO-8601 time in UTC with its offset, millisecond precision (``t``: Unix seconds)."""
    when = dt.datetime.fromtimestamp(time.time() if t is None else t, tz=dt.UTC)
    return when.isoformat(timespec="milliseconds")


# -- payloads ----------------------------------------------------------------------------


def state_payload(estimate: Estimate | Mapping[str, Any] | None, t: float | None = None, *,
                  status: str | None = None, detail: str | None = None) -> dict[str, Any]:
    """The state message: :data:`STATE_KEYS` first (null when the estimate lacks one),
    then ``detail`` (when given) and the estimate's further fields (``reason``...), then
    ``time``.

    ``estimate`` is a :class:`live.Estimate` (or a mapping of its fields; None: nothing
    known). ``status`` is ``ok`` unless given (or the mapping says otherwise).
    """
    fields = dict(estimate or {}) if estimate is None or isinstance(estimate, Mapping) \
        else dict(estimate.fields())
    out: dict[str, Any] = {k: fields.get(k) for k in STATE_KEYS}
    if out["direction"] is None:
        out["direction"] = "unknown"
    out["status"] = status or fields.get("status") or "ok"
    if detail:
        out["detail"] = detail
    for k, v in fields.items():
        if k not in out and k != "time":
            out[k] = v
    out["time"] = utc_iso(t)
    return clean(out)


def status_payload(fields: Mapping[str, Any]) -> dict[str, Any]:
    """The status message: :data:`STATUS_KEYS` in order (null when missing). No time of
    its own beyond ``since`` (when this status began): it is published only on change,
    so Home Assistant records a change only when something changed."""
    out = {k: fields.get(k) for k in STATUS_KEYS}
    if out["status"] not in STATUSES:
        raise ValueError(f"status {out['status']!r}: use one of {', '.join(STATUSES)}")
    return clean(out)


def event_payload(kind: str, details: Mapping[str, Any],
                  t: float | None = None) -> dict[str, Any]:
    """An event message: ``{"kind": ..., "time": ..., "details": {...}}``."""
    return clean({"kind": kind, "time": utc_iso(t), "details": dict(details)})


def stats_payload(stats: Mapping[str, Any], t: float | None = None,
                  extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The stats message: the runner's counters, ``extra`` keys it lacks, and ``time``."""
    out = dict(stats)
    for k, v in (extra or {}).items():
        out.setdefault(k, v)
    out["time"] = utc_iso(t)
    return clean(out)


def availability_message(topics: Topics, online: bool) -> Message:
    return Message(topics.availability, ONLINE if online else OFFLINE, qos=1, retain=True)


def state_message(topics: Topics, payload: Mapping[str, Any]) -> Message:
    return Message(topics.state, dict(payload), qos=1, retain=True)


def status_message(topics: Topics, payload: Mapping[str, Any]) -> Message:
    return Message(topics.status, dict(payload), qos=1, retain=True)


def event_message(topics: Topics, payload: Mapping[str, Any]) -> Message:
    return Message(topics.event, dict(payload), qos=1, retain=False)


def stats_message(topics: Topics, payload: Mapping[str, Any]) -> Message:
    return Message(topics.stats, dict(payload), qos=0, retain=True)


# -- commands ------------------------------------------------------------------------------

#: Longest command payload read, bytes (the longest valid one is 16).
MAX_COMMAND_BYTES = 64
#: Payloads of ``command/reference``.
REFERENCE_COMMANDS = ("learn", "forget")
#: Payloads of ``command/reference_direction`` and the direction each stands for.
DIRECTION_WORDS = {"cw": "cw", "ccw": "ccw", "unknown": "unknown", "clockwise": "cw",
                   "counterclockwise": "ccw", "not set": "unknown"}


class Command(NamedTuple):
    """A validated command: ``learn``, ``forget`` or ``direction`` (with its value)."""

    name: str
    value: str | None = None


class CommandError(ValueError):
    """A command message that is not understood; the text names it and what is allowed."""


def parse_command(topics: Topics, topic: str, payload: bytes) -> Command:
    """A command from an MQTT message on one of ``topics.commands`` (pure).

    Payloads are compared without case and surrounding white space. Raises
    :class:`CommandError` for anything else (too long, not UTF-8, unknown).
    """
    from ..text import short_repr

    if len(payload) > MAX_COMMAND_BYTES:
        raise CommandError(f"{topic}: a payload of {len(payload)} bytes, longer than any "
                           f"command ({MAX_COMMAND_BYTES}); ignored")
    try:
        word = payload.decode("utf-8").strip().lower()
    except UnicodeDecodeError:
        raise CommandError(f"{topic}: payload {short_repr(payload)} is not UTF-8 text; "
                           "ignored") from None
    if topic == topics.command_reference:
        if word in REFERENCE_COMMANDS:
            return Command(word)
        raise CommandError(f"{topic}: unknown command {short_repr(word)}; send one of "
                           f"{', '.join(REFERENCE_COMMANDS)}")
    if topic == topics.command_direction:
        if word in DIRECTION_WORDS:
            return Command("direction", DIRECTION_WORDS[word])
        raise CommandError(f"{topic}: unknown direction {short_repr(word)}; send one of "
                           f"{', '.join(DIRECTION_WORDS)}")
    raise CommandError(f"{topic}: not a command topic of this device")


# -- Home Assistant discovery ------------------------------------------------------------


def node_id(device_id: str) -> str:
    """The discovery node id: ``device_id`` with anything outside [a-zA-Z0-9_-] as ``_``."""
    return re.sub(r"[^a-zA-Z0-9_-]", "_", device_id) or "bladesonar"


def friendly_name(device_id: str) -> str:
    """A device name for people from an id: ``living-room_fan`` -> ``Living room fan``."""
    words = re.sub(r"[-_.]+", " ", device_id).strip()
    return (words[:1].upper() + words[1:]) if words else "Bladesonar"


def _version() -> str:
    try:
        from .. import __version__
    except ImportError:  # pragma: no cover - the package always defines it
        return "unknown"
    return str(__version__)


def _none_or(key: str, expr: str) -> str:
    """A template that renders ``None`` (Home Assistant's unknown) for a null ``key``."""
    return (f"{{% if value_json.{key} is none %}}None{{% else %}}{{{{ {expr} }}}}"
            "{% endif %}")


def _event_template(kinds: dict[str, str], attrs: tuple[str, ...]) -> str:
    """An event entity's template: the event JSON Home Assistant wants (``event_type``
    plus attributes) for the kinds given, an empty string (ignored) for the others."""
    mapping = "{" + ", ".join(f"'{k}': '{v}'" for k, v in kinds.items()) + "}"
    items = ", ".join(f"'{a}': value_json.details.get('{a}')" for a in attrs)
    return (f"{{% set t = {mapping}.get(value_json.kind) %}}"
            f"{{% if t %}}{{{{ {{'event_type': t{', ' if items else ''}{items}}} | tojson }}}}"
            "{% endif %}")


_ROTATION_TEMPLATE = ("{% set r = value_json.rotation %}"
                      "{% if r == 'cw' %}clockwise{% elif r == 'ccw' %}counterclockwise"
                      "{% elif value_json.direction == 'stopped' %}stopped"
                      "{% else %}None{% endif %}")
_DIRECTION_TEMPLATE = ("{% set d = value_json.direction %}"
                       "{% if d in ['same', 'reversed', 'stopped'] %}{{ d }}"
                       "{% else %}None{% endif %}")
_REF_DIRECTION_TEMPLATE = ("{% set d = value_json.reference_direction %}"
                           "{% if d == 'cw' %}clockwise{% elif d == 'ccw' %}counterclockwise"
                           "{% elif d == 'unknown' %}not set{% else %}None{% endif %}")

#: (component, object_id, topic key, entity fields) of every discovered entity. Names
#: read after the device's name ("Living room fan Rotation"). No state carries ``unknown``
#: or ``unavailable`` as a value of its own: what is not known renders ``None``, which
#: Home Assistant shows as its own unknown.
_ENTITIES: tuple[tuple[str, str, str, dict[str, Any]], ...] = (
    ("sensor", "rotation", "state", {
        "name": "Rotation", "device_class": "enum",
        "options": ["clockwise", "counterclockwise", "stopped"],
        "value_template": _ROTATION_TEMPLATE, "icon": "mdi:rotate-right"}),
    ("sensor", "rpm", "state", {
        "name": "Speed", "unit_of_measurement": "rpm", "state_class": "measurement",
        "suggested_display_precision": 0,
        "value_template": _none_or("rpm", "value_json.rpm | round(1)"), "icon": "mdi:fan"}),
    ("binary_sensor", "rotating", "state", {
        "name": "Running", "device_class": "running", "payload_on": "ON",
        "payload_off": "OFF",
        "value_template": ("{% if value_json.rotating is none %}None"
                           "{% elif value_json.rotating %}ON{% else %}OFF{% endif %}")}),
    ("sensor", "direction", "state", {
        "name": "Direction to reference", "device_class": "enum",
        "options": ["same", "reversed", "stopped"],
        "value_template": _DIRECTION_TEMPLATE, "icon": "mdi:rotate-3d-variant"}),
    ("sensor", "rate", "state", {
        "name": "Rotation rate", "device_class": "frequency", "unit_of_measurement": "Hz",
        "state_class": "measurement", "suggested_display_precision": 3,
        "value_template": _none_or("rate_hz", "value_json.rate_hz | round(3)"),
        "icon": "mdi:fan", "entity_category": "diagnostic"}),
    ("sensor", "confidence", "state", {
        "name": "Confidence", "unit_of_measurement": "%", "state_class": "measurement",
        "suggested_display_precision": 0, "entity_category": "diagnostic",
        "value_template": _none_or("confidence", "(value_json.confidence * 100) | round(0)"),
        "icon": "mdi:check-decagram"}),
    ("event", "motion", "event", {
        "name": "Motion", "event_types": list(MOTION_EVENTS),
        "value_template": _event_template({k: k for k in MOTION_EVENTS},
                                          ("rotation", "rate_hz")),
        "icon": "mdi:fan-alert"}),
    ("sensor", "status", "status", {
        "name": "Status", "device_class": "enum", "options": list(STATUSES),
        "entity_category": "diagnostic", "value_template": "{{ value_json.status }}",
        "json_attributes_topic": "status",
        "json_attributes_template": ("{{ {'detail': value_json.detail, "
                                     "'reference': value_json.reference, "
                                     "'reference_rate_hz': value_json.reference_rate_hz} "
                                     "| tojson }}"),
        "icon": "mdi:list-status"}),
    ("sensor", "reference_fit", "status", {
        "name": "Reference fit", "unit_of_measurement": "%", "state_class": "measurement",
        "suggested_display_precision": 0, "entity_category": "diagnostic",
        "value_template": _none_or("fit", "(value_json.fit * 100) | round(0)"),
        "icon": "mdi:puzzle-check"}),
    ("event", "reference", "event", {
        "name": "Reference", "event_types": list(REFERENCE_EVENTS),
        "value_template": _event_template({f"reference_{k}": k for k in REFERENCE_EVENTS},
                                          ("detail",)),
        "entity_category": "diagnostic", "icon": "mdi:fingerprint"}),
    ("button", "learn_reference", "command_reference", {
        "name": "Learn reference", "payload_press": "learn", "entity_category": "config",
        "icon": "mdi:school"}),
    ("button", "forget_reference", "command_reference", {
        "name": "Forget reference", "payload_press": "forget", "entity_category": "config",
        "icon": "mdi:delete-outline"}),
    ("select", "reference_direction", "command_direction", {
        "name": "Reference direction", "options": ["clockwise", "counterclockwise", "not set"],
        "state_topic": "status", "value_template": _REF_DIRECTION_TEMPLATE,
        "entity_category": "config", "icon": "mdi:rotate-left"}),
    ("sensor", "started", "stats", {
        "name": "Started", "device_class": "timestamp", "entity_category": "diagnostic",
        "value_template": _none_or("started_at", "value_json.started_at")}),
    ("sensor", "xruns", "stats", {
        "name": "Audio xruns", "state_class": "total_increasing",
        "entity_category": "diagnostic", "value_template": "{{ value_json.xruns }}",
        "icon": "mdi:waveform"}),
    ("sensor", "dropped_pulses", "stats", {
        "name": "Dropped pulses", "state_class": "total_increasing",
        "entity_category": "diagnostic", "value_template": "{{ value_json.dropped_pulses }}",
        "icon": "mdi:pulse"}),
    ("sensor", "reconnects", "stats", {
        "name": "MQTT reconnects", "state_class": "total_increasing",
        "entity_category": "diagnostic", "value_template": "{{ value_json.reconnects }}",
        "icon": "mdi:lan-disconnect"}),
    ("sensor", "cpu", "stats", {
        "name": "CPU share", "unit_of_measurement": "%", "state_class": "measurement",
        "entity_category": "diagnostic", "suggested_display_precision": 1,
        "value_template": _none_or("cpu_share", "(value_json.cpu_share * 100) | round(1)"),
        "icon": "mdi:cpu-64-bit"}),
)

#: Entities earlier versions announced and this one does not: an empty retained config
#: removes each from Home Assistant (``sensor/uptime`` became ``sensor/started``).
_RETIRED = (("sensor", "uptime"),)

#: Entities whose commands need ``mqtt.commands``.
_COMMAND_SOURCES = ("command_reference", "command_direction")


def device_block(cfg: Any) -> dict[str, Any]:
    """The Home Assistant device all entities belong to; its name is ``mqtt.device_name``
    or one made from ``device_id``."""
    name = getattr(cfg.mqtt, "device_name", None) or friendly_name(cfg.device_id)
    return {"identifiers": [f"bladesonar_{node_id(cfg.device_id)}"], "name": name,
            "manufacturer": "bladesonar", "model": "Pulsed-sonar rotation sensor",
            "sw_version": _version()}


def discovery_messages(cfg: Any, topics: Topics | None = None) -> list[Message]:
    """Home Assistant discovery: one retained config per entity, at
    ``<discovery_prefix>/<component>/<node_id>/<object_id>/config``, one device trigger
    per motion event (``device_automation/<node_id>/motion_<kind>``), and an empty
    retained config for each retired entity (which removes it).

    Every entity reads the state, status, event or stats topic through a
    ``value_template``, is wired to the availability topic, and has a ``unique_id`` of
    ``bladesonar_<node_id>_<object_id>``. The command entities (buttons, select) are
    left out with ``mqtt.commands: false``.
    """
    topics = topics or Topics.for_config(cfg)
    node = node_id(cfg.device_id)
    device = device_block(cfg)
    origin = {"name": "bladesonar", "sw_version": _version()}
    by_key = {"state": topics.state, "stats": topics.stats, "status": topics.status,
              "event": topics.event, "command_reference": topics.command_reference,
              "command_direction": topics.command_direction}
    commands = getattr(cfg.mqtt, "commands", True)
    out = []
    for component, object_id, source, fields in _ENTITIES:
        if source in _COMMAND_SOURCES and not commands:
            continue
        conf: dict[str, Any] = {"unique_id": f"bladesonar_{node}_{object_id}"}
        if source in _COMMAND_SOURCES:
            conf["command_topic"] = by_key[source]
            conf["qos"] = 1
            conf["retain"] = False
        else:
            conf["state_topic"] = by_key[source]
            conf["qos"] = 1
        conf.update({"availability_topic": topics.availability,
                     "payload_available": ONLINE, "payload_not_available": OFFLINE})
        for k, v in fields.items():
            conf[k] = by_key[v] if k in ("json_attributes_topic", "state_topic") else v
        conf["device"] = device
        conf["origin"] = origin
        out.append(Message(f"{topics.discovery_prefix}/{component}/{node}/{object_id}/config",
                           conf, qos=1, retain=True))
    # device triggers (Home Assistant's automation editor: "Device" -> "reversed"): MQTT
    # device automations on the event topic, one per motion event
    for kind in MOTION_EVENTS:
        out.append(Message(
            f"{topics.discovery_prefix}/device_automation/{node}/motion_{kind}/config",
            {"automation_type": "trigger", "topic": topics.event, "type": kind,
             "subtype": "fan", "payload": kind, "value_template": "{{ value_json.kind }}",
             "qos": 1, "device": device, "origin": origin}, qos=1, retain=True))
    for component, object_id in _RETIRED:
        out.append(Message(f"{topics.discovery_prefix}/{component}/{node}/{object_id}/config",
                           None, qos=1, retain=True))
    return out
