"""What the daemon says on MQTT: topic names, payloads and Home Assistant discovery (pure).

No I/O here: every function turns settings and estimates into :class:`Message` values that
a publisher (``publish.py``: a broker, or JSON lines on stdout) sends as they are. Topics
live under ``<mqtt.topic_prefix>/<device_id>/``:

=============  ====  ======  ======================================================
topic          QoS   retain  payload
=============  ====  ======  ======================================================
availability   1     yes     ``online`` / ``offline`` (also the last will)
state          1     yes     JSON: the current estimate and its ``time``
event          1     no      JSON: ``kind``, ``time``, ``details``
stats          0     yes     JSON: health counters and ``time``
=============  ====  ======  ======================================================

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
from typing import Any, Mapping, NamedTuple

#: Availability payloads (Home Assistant's defaults, so no payload_* keys are needed).
ONLINE = "online"
OFFLINE = "offline"

#: Values of the state's ``direction`` (relative to the reference's own direction).
DIRECTIONS = ("same", "reversed", "stopped", "unknown")
#: Values of the state's ``rotation`` (absolute, seen from the device), or null.
ROTATIONS = ("cw", "ccw")
#: Event kinds the daemon publishes.
EVENT_KINDS = ("reversed", "started", "stopped", "reference_missing", "reference_invalid")

#: The state payload's keys, in order; missing estimate fields are sent as null.
STATE_KEYS = ("direction", "rotation", "rotating", "rate_hz", "rpm", "relative_rate",
              "rate_state", "rate_change_hz_s", "confidence", "window_s", "reference",
              "status")

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
    when = dt.datetime.fromtimestamp(time.time() if t is None else t, tz=dt.timezone.utc)
    return when.isoformat(timespec="milliseconds")


# -- payloads ----------------------------------------------------------------------------


def state_payload(estimate: Mapping[str, Any], t: float | None = None) -> dict[str, Any]:
    """The state message: :data:`STATE_KEYS` first (null when the estimate lacks one),
    then any further estimate fields (``reason``, ``pulses``...), then ``time``.

    ``status`` is ``ok`` unless the estimate says otherwise (``reference_missing``).
    """
    out: dict[str, Any] = {k: estimate.get(k) for k in STATE_KEYS}
    if out["status"] is None:
        out["status"] = "ok"
    for k, v in estimate.items():
        if k not in out and k != "time":
            out[k] = v
    out["time"] = utc_iso(t)
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


def event_message(topics: Topics, payload: Mapping[str, Any]) -> Message:
    return Message(topics.event, dict(payload), qos=1, retain=False)


def stats_message(topics: Topics, payload: Mapping[str, Any]) -> Message:
    return Message(topics.stats, dict(payload), qos=0, retain=True)


# -- Home Assistant discovery ------------------------------------------------------------


def node_id(device_id: str) -> str:
    """The discovery node id: ``device_id`` with anything outside [a-zA-Z0-9_-] as ``_``."""
    return re.sub(r"[^a-zA-Z0-9_-]", "_", device_id) or "bladesonar"


def _version() -> str:
    try:
        from .. import __version__
    except ImportError:  # pragma: no cover - the package always defines it
        return "unknown"
    return str(__version__)


#: (component, object_id, topic key, entity fields) of every discovered entity.
_ENTITIES: tuple[tuple[str, str, str, dict[str, Any]], ...] = (
    ("sensor", "rate", "state", {
        "name": "Rotation rate", "device_class": "frequency", "unit_of_measurement": "Hz",
        "state_class": "measurement", "suggested_display_precision": 3,
        "value_template": "{{ value_json.rate_hz }}", "icon": "mdi:fan"}),
    ("sensor", "rpm", "state", {
        "name": "Rotation speed", "unit_of_measurement": "rpm", "state_class": "measurement",
        "suggested_display_precision": 1, "value_template": "{{ value_json.rpm }}",
        "icon": "mdi:fan"}),
    ("sensor", "direction", "state", {
        "name": "Direction", "device_class": "enum", "options": list(DIRECTIONS),
        "value_template": "{{ value_json.direction }}", "icon": "mdi:rotate-3d-variant",
        "json_attributes_topic": "state"}),
    ("sensor", "rotation", "state", {
        # an enum sensor must stay within its options: null (stopped, unknown) -> "none"
        "name": "Rotation", "device_class": "enum", "options": [*ROTATIONS, "none"],
        "value_template": "{{ value_json.rotation or 'none' }}", "icon": "mdi:rotate-right"}),
    ("sensor", "confidence", "state", {
        "name": "Confidence", "state_class": "measurement", "suggested_display_precision": 2,
        "value_template": "{{ value_json.confidence }}", "icon": "mdi:check-decagram"}),
    ("binary_sensor", "rotating", "state", {
        "name": "Rotating", "device_class": "running", "payload_on": "ON", "payload_off": "OFF",
        "value_template": ("{% if value_json.rotating is none %}None"
                           "{% elif value_json.rotating %}ON{% else %}OFF{% endif %}")}),
    ("sensor", "xruns", "stats", {
        "name": "Audio xruns", "state_class": "total_increasing", "entity_category": "diagnostic",
        "value_template": "{{ value_json.xruns }}", "icon": "mdi:waveform"}),
    ("sensor", "dropped_pulses", "stats", {
        "name": "Dropped pulses", "state_class": "total_increasing",
        "entity_category": "diagnostic", "value_template": "{{ value_json.dropped_pulses }}",
        "icon": "mdi:pulse"}),
    ("sensor", "reconnects", "stats", {
        "name": "MQTT reconnects", "state_class": "total_increasing",
        "entity_category": "diagnostic", "value_template": "{{ value_json.reconnects }}",
        "icon": "mdi:lan-disconnect"}),
    ("sensor", "uptime", "stats", {
        "name": "Uptime", "device_class": "duration", "unit_of_measurement": "s",
        "state_class": "measurement", "entity_category": "diagnostic",
        "value_template": "{{ value_json.uptime_s }}"}),
    ("sensor", "cpu", "stats", {
        "name": "CPU share", "unit_of_measurement": "%", "state_class": "measurement",
        "entity_category": "diagnostic", "suggested_display_precision": 1,
        "value_template": ("{% if value_json.cpu_share is none %}None"
                           "{% else %}{{ (value_json.cpu_share * 100) | round(2) }}{% endif %}"),
        "icon": "mdi:cpu-64-bit"}),
)


def device_block(cfg: Any) -> dict[str, Any]:
    """The Home Assistant device all entities belong to."""
    return {"identifiers": [f"bladesonar_{node_id(cfg.device_id)}"], "name": cfg.device_id,
            "manufacturer": "bladesonar", "model": "Pulsed-sonar rotation sensor",
            "sw_version": _version()}


def discovery_messages(cfg: Any, topics: Topics | None = None) -> list[Message]:
    """Home Assistant discovery: one retained config per entity, at
    ``<discovery_prefix>/<component>/<node_id>/<object_id>/config``.

    Every entity reads the state (or stats) topic through a ``value_template``, is wired
    to the availability topic, and has a ``unique_id`` of ``bladesonar_<node_id>_<object_id>``.
    A null number renders as ``None``, which Home Assistant shows as unknown; the rotation
    enum shows ``none`` instead (an enum sensor accepts only its options).
    """
    topics = topics or Topics.for_config(cfg)
    node = node_id(cfg.device_id)
    device = device_block(cfg)
    origin = {"name": "bladesonar", "sw_version": _version()}
    by_key = {"state": topics.state, "stats": topics.stats}
    out = []
    for component, object_id, source, fields in _ENTITIES:
        conf: dict[str, Any] = {
            "unique_id": f"bladesonar_{node}_{object_id}",
            "has_entity_name": True,
            "state_topic": by_key[source],
            "availability_topic": topics.availability,
            "payload_available": ONLINE,
            "payload_not_available": OFFLINE,
            "qos": 1,
        }
        for k, v in fields.items():
            conf[k] = by_key.get(v, v) if k == "json_attributes_topic" else v
        conf["device"] = device
        conf["origin"] = origin
        out.append(Message(f"{topics.discovery_prefix}/{component}/{node}/{object_id}/config",
                           conf, qos=1, retain=True))
    return out
