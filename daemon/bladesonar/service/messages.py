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
command/setting/<key>       (in)          a value of ``reference.<key>`` (SETTINGS)
==========================  ====  ======  ==========================================

Home Assistant reads them through one retained device-based discovery config
(``<discovery_prefix>/device/<node_id>/config``), which takes over the per-entity configs
of earlier versions (:func:`migration_messages`).

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
from typing import TYPE_CHECKING, Any, NamedTuple, TypedDict, cast

from ..answer import (
    MOTION_EVENTS,
    SIGNIFICANT_DIGITS,
    WAYS,
    Direction,
    Estimate,
    EventKind,
    Kind,
    significant,
)

if TYPE_CHECKING:
    from ..config import Config

#: Availability payloads (Home Assistant's defaults, so no payload_* keys are needed).
ONLINE = "online"
OFFLINE = "offline"

#: The reference's events (service/reference_keeper.py) as Home Assistant's event types
#: name them: each ``reference_<x>`` of :class:`answer.EventKind` as ``<x>``.
REFERENCE_EVENTS = tuple(k.removeprefix("reference_") for k in EventKind if not k.motion)
#: Event kinds the daemon publishes: the fan's (:data:`answer.MOTION_EVENTS`), then the
#: reference's.
EVENT_KINDS = tuple(EventKind)

#: The daemon's status (state ``status``, the status topic, Home Assistant's Status):
#: ``starting`` until the first estimate or problem; ``learning`` while it records and
#: folds a reference of its own; ``reference_stale`` when the stored one no longer fits
#: the room (the estimates go on, less sure); ``airflow_contradiction`` when the live
#: airflow has confidently contradicted the reference's direction for a sustained time
#: (service/airflow_watch.py; the estimates go on).
STATUSES = ("starting", "ok", "learning", "reference_missing", "reference_invalid",
            "reference_stale", "no_signal", "airflow_contradiction")
#: What Home Assistant's Status shows for each status; ``ok`` with a reference whose
#: direction is not set shows DIRECTION_UNSET instead (Rotation stays unknown until then).
STATUS_WORDS = {"starting": "Starting", "ok": "OK", "learning": "Learning",
                "reference_missing": "No reference", "reference_invalid": "Reference unusable",
                "reference_stale": "Reference stale", "no_signal": "No echo",
                "airflow_contradiction": "Airflow contradicts reference"}
DIRECTION_UNSET = "Direction not set"

#: The settings Home Assistant can change (config entities), as ``reference.<key>``.
SETTINGS = ("auto_learn", "learn_seconds", "stale_fit")

#: The state payload's keys, in order; missing estimate fields are sent as null.
STATE_KEYS = ("direction", "rotation", "rotating", "running", "rate_hz", "rpm", "relative_rate",
              "rate_state", "rate_change_hz_s", "confidence", "airflow", "airflow_confidence",
              "window_s", "reference", "status")
#: The status payload's keys, in order.
STATUS_KEYS = ("status", "detail", "reference", "reference_direction", "reference_rate_hz",
               "fit", "learning", "settings", "audio", "since")

#: How long ``running`` keeps its last known value through answers that are not known
#: (a reversal's or a stop's confirmation, a relearned reference), seconds.
RUNNING_HOLD_S = 60.0
#: Statuses under which ``running`` is held: the analysis (or the learning that follows
#: a Forget) goes on and will name the state again. Any other status makes it unknown.
HOLD_STATUSES = ("starting", "ok", "learning", "airflow_contradiction")


class _StateExtras(TypedDict, total=False):
    """The state message's keys that only some states have."""

    detail: str
    """The status's detail, when the status has one."""
    reason: str
    """Why the answer is what it is (every estimate has one)."""
    warnings: list[str]
    """Only when there are some."""


class StatePayload(_StateExtras):
    """The state message (:func:`state_payload`): :data:`STATE_KEYS` in that order, then
    the keys of :class:`_StateExtras` a state has, then ``time``; floats as
    :func:`clean` leaves them (None where not finite)."""

    direction: str
    """same / reversed / stopped / unknown (:class:`answer.Direction`)."""
    rotation: str | None
    rotating: bool | None
    running: bool | None
    """The held value of :class:`RunningHold`."""
    rate_hz: float | None
    rpm: float | None
    relative_rate: float | None
    rate_state: str | None
    rate_change_hz_s: float | None
    confidence: float | None
    """Null while the direction is unknown."""
    airflow: str
    """down / up / unknown."""
    airflow_confidence: float | None
    window_s: float | None
    reference: str | None
    status: str
    time: str


class StatsPayload(TypedDict):
    """The runner's stats (``Service.stats``): the health counters a user can alert on,
    then the detail; :func:`stats_payload` adds ``time``."""

    started_at: str
    uptime_s: float
    cpu_share: float | None
    pulses_processed: int
    dropped_pulses: int
    xruns: int
    reconnects: int
    dropped_events: int
    clock_ppm: float | None
    device: dict[str, Any] | None
    """Clipped coupling, gain wander, bursts, the room's tail (docs/audio.md)."""
    audio_restarts: int
    latency_ms: dict[str, float] | None
    """From a completed capture period to its state sent: median, max, n."""
    reloads: int
    reload_errors: int
    signal_errors: int
    references_learned: int
    learn_failures: int
    commands: int
    commands_refused: int
    fit: float | None
    audio: dict[str, Any]


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
    node: str = "bladesonar"
    """The discovery node id (:func:`node_id` of ``device_id``)."""

    @classmethod
    def for_config(cls, cfg: Config) -> Topics:
        prefix = cfg.mqtt.topic_prefix.strip("/")
        return cls(base=f"{prefix}/{cfg.device_id}",
                   discovery_prefix=cfg.mqtt.discovery_prefix.strip("/"),
                   node=node_id(cfg.device_id))

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

    def command_setting(self, key: str) -> str:
        """Commands: a new value of the setting ``reference.<key>`` (:data:`SETTINGS`)."""
        return f"{self.base}/command/setting/{key}"

    @property
    def commands(self) -> tuple[str, ...]:
        return (self.command_reference, self.command_direction,
                *(self.command_setting(k) for k in SETTINGS))

    @property
    def device_config(self) -> str:
        """Home Assistant's device-based discovery config of this device (retained)."""
        return f"{self.discovery_prefix}/device/{self.node}/config"

    @property
    def legacy_configs(self) -> str:
        """The per-entity discovery configs earlier versions published (a subscription
        pattern: ``<prefix>/<component>/<node_id>/<object_id>/config``)."""
        return f"{self.discovery_prefix}/+/{self.node}/+/config"

    @property
    def ha_status(self) -> str:
        """Home Assistant's birth/last-will topic (``online`` after HA starts)."""
        return f"{self.discovery_prefix}/status"


# -- JSON --------------------------------------------------------------------------------


def clean_dict(fields: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`clean` for a message's top level, which stays a dict."""
    out: dict[str, Any] = clean(dict(fields))
    return out


def clean(value: Any, digits: int = SIGNIFICANT_DIGITS) -> Any:
    """A JSON-safe copy: NaN/inf -> None, floats rounded to ``digits`` significant digits,
    numpy scalars and arrays -> Python numbers and lists, tuples -> lists, other objects
    -> str."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return significant(float(value), digits)
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
                  status: str | None = None, detail: str | None = None,
                  running: bool | None = None) -> StatePayload:
    """The state message: :data:`STATE_KEYS` first (null when the estimate lacks one),
    then ``detail`` (when given) and the estimate's further fields (``reason``...), then
    ``time``.

    ``estimate`` is a :class:`live.Estimate` (or a mapping of its fields; None: nothing
    known). ``status`` is ``ok`` unless given (or the mapping says otherwise).
    ``running`` is the held value of :class:`RunningHold`. ``confidence`` is null while
    the direction is unknown: it says how sure a known answer is, and there is none.
    """
    fields = dict(estimate or {}) if estimate is None or isinstance(estimate, Mapping) \
        else dict(estimate.fields())
    out: dict[str, Any] = {k: fields.get(k) for k in STATE_KEYS}
    if out["direction"] is None:
        out["direction"] = Direction.UNKNOWN.value
    if out["direction"] == Direction.UNKNOWN:
        out["confidence"] = None
    if out["airflow"] not in ("down", "up"):
        out["airflow"] = "unknown"
    out["running"] = running
    out["status"] = status or fields.get("status") or "ok"
    if detail:
        out["detail"] = detail
    for k, v in fields.items():
        if k not in out and k != "time":
            out[k] = v
    out["time"] = utc_iso(t)
    return cast(StatePayload, clean_dict(out))


class RunningHold:
    """``running`` as an automation needs it (pure; the publisher keeps one).

    The analysis answers *unknown* for about a second around every reversal and stop
    while it confirms them. Running keeps its last known value through such answers, so
    a fan that reverses stays on and a fan that stops goes from on to off once, at the
    confirmed stop. It becomes unknown only when nothing is known for longer than
    ``hold_s``, or under a status that is not :data:`HOLD_STATUSES` (no signal, a stale
    or missing reference: then nobody knows).
    """

    def __init__(self, hold_s: float = RUNNING_HOLD_S) -> None:
        self.hold_s = hold_s
        self.value: bool | None = None
        self._unknown_since: float | None = None

    def update(self, kind: str | None, status: str, now: float) -> bool | None:
        """The held value after an answer of ``kind`` (a :class:`answer.Kind`: ``turning``
        for a fan turning whose direction is in doubt; None or any other word: nothing
        known) at monotonic time ``now``."""
        if kind in tuple(Kind):
            self.value = kind != Kind.STOPPED
            self._unknown_since = None
        elif status not in HOLD_STATUSES:
            self.value, self._unknown_since = None, None
        elif self.value is not None:
            if self._unknown_since is None:
                self._unknown_since = now
            elif now - self._unknown_since > self.hold_s:
                self.value, self._unknown_since = None, None
        return self.value


def status_payload(fields: Mapping[str, Any]) -> dict[str, Any]:
    """The status message: :data:`STATUS_KEYS` in order (null when missing). No time of
    its own beyond ``since`` (when this status began): it is published only on change,
    so Home Assistant records a change only when something changed."""
    out = {k: fields.get(k) for k in STATUS_KEYS}
    if out["status"] not in STATUSES:
        raise ValueError(f"status {out['status']!r}: use one of {', '.join(STATUSES)}")
    return clean_dict(out)


def event_payload(kind: str, details: Mapping[str, Any],
                  t: float | None = None) -> dict[str, Any]:
    """An event message: ``{"kind": ..., "time": ..., "details": {...}}``."""
    return clean_dict({"kind": kind, "time": utc_iso(t), "details": dict(details)})


def stats_payload(stats: Mapping[str, Any], t: float | None = None,
                  extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The stats message: the runner's counters, ``extra`` keys it lacks, and ``time``."""
    out = dict(stats)
    for k, v in (extra or {}).items():
        out.setdefault(k, v)
    out["time"] = utc_iso(t)
    return clean_dict(out)


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


#: Words a switch setting takes for on and off.
SWITCH_WORDS = {"on": True, "off": False, "true": True, "false": False}


class Command(NamedTuple):
    """A validated command: ``learn``, ``forget``, ``direction`` (with its value) or
    ``setting`` (``key`` and its value, checked against the config schema by the
    runner)."""

    name: str
    value: Any = None
    key: str | None = None


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
    for key in SETTINGS:
        if topic != topics.command_setting(key):
            continue
        if key == "auto_learn":
            if word in SWITCH_WORDS:
                return Command("setting", SWITCH_WORDS[word], key)
            raise CommandError(f"{topic}: {short_repr(word)} is not a switch value; send ON "
                               "or OFF")
        try:
            x = float(word)
        except ValueError:
            x = math.nan
        if not math.isfinite(x):
            raise CommandError(f"{topic}: {short_repr(word)} is not a number; send one "
                               f"(reference.{key})")
        return Command("setting", x, key)
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


def support_url() -> str | None:
    """The project's address from the installed package's metadata (``Project-URL``
    or ``Home-page``), for the discovery's ``origin.support_url``; None when it names
    none."""
    try:
        from importlib.metadata import PackageNotFoundError, metadata
    except ImportError:  # pragma: no cover - in the standard library since 3.8
        return None
    try:
        md = metadata("bladesonar")
    except PackageNotFoundError:
        return None
    for entry in md.get_all("Project-URL") or []:
        label, _, url = entry.partition(",")
        if label.strip().lower() in ("support", "issues", "homepage", "source") \
                and url.strip().startswith("https://"):
            return str(url.strip())
    home = md.get_all("Home-page", [None])[0]
    if isinstance(home, str) and home.startswith("https://"):
        return home
    return None


def _none_or(key: str, expr: str) -> str:
    """A template that renders ``None`` (Home Assistant's unknown) for a null ``key``."""
    return (f"{{% if value_json.{key} is none %}}None{{% else %}}{{{{ {expr} }}}}"
            "{% endif %}")


def _stat(key: str, expr: str = "v") -> str:
    """A stats template: ``expr`` of the stats key ``key`` (as ``v``), ``None`` when the
    message lacks it or it is null (a counter added in a later version)."""
    return (f"{{% set v = value_json.get('{key}') %}}"
            f"{{% if v is none %}}None{{% else %}}{{{{ {expr} }}}}{{% endif %}}")


def _when_known(key: str, expr: str, stopped: str) -> str:
    """A number of the state that exists only while the fan is known to turn (its
    direction known, or in doubt with the speed known: ``rotating`` true) or to rest:
    ``expr`` while turning, ``stopped`` when stopped, else ``None`` (never a 0 that
    means nothing)."""
    return ("{% set d = value_json.direction %}"
            "{% if (d in ['same', 'reversed'] or (d == 'unknown' and value_json.rotating))"
            f" and value_json.{key} is not none %}}"
            f"{{{{ {expr} }}}}{{% elif d == 'stopped' %}}{stopped}"
            "{% else %}None{% endif %}")


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
#: the words Home Assistant's Airflow shows (what people ask of a ceiling fan)
AIRFLOW_WORDS = {"down": "Down (summer)", "up": "Up (winter)"}
_AIRFLOW_TEMPLATE = ("{% set a = value_json.airflow %}"
                     "{% if a == 'down' %}" + AIRFLOW_WORDS["down"]
                     + "{% elif a == 'up' %}" + AIRFLOW_WORDS["up"]
                     + "{% else %}None{% endif %}")
_DIRECTION_TEMPLATE = ("{% set d = value_json.direction %}"
                       "{% if d in ['same', 'reversed', 'stopped'] %}{{ d }}"
                       "{% else %}None{% endif %}")
_REF_DIRECTION_TEMPLATE = ("{% set d = value_json.reference_direction %}"
                           "{% if d == 'cw' %}clockwise{% elif d == 'ccw' %}counterclockwise"
                           "{% elif d == 'unknown' %}not set{% else %}None{% endif %}")
_STATUS_TEMPLATE = ("{% set s = value_json.status %}"
                    "{% if s == 'ok' and value_json.reference is not none and "
                    "value_json.reference_direction not in ['cw', 'ccw'] %}"
                    f"{DIRECTION_UNSET}"
                    "{% else %}{{ "
                    + "{" + ", ".join(f"'{k}': '{v}'" for k, v in STATUS_WORDS.items()) + "}"
                    + ".get(s, 'None') }}{% endif %}")
#: the fit in 0-100 %: a room that fits better than the reference promised is 100 %
_FIT_TEMPLATE = _none_or("fit",
                         "(([[value_json.fit, 0.0] | max, 1.0] | min) * 100) | round(0)")

#: (component, object_id, topic key, entity fields) of every discovered entity. Names
#: read after the device's name ("Living room fan Rotation"). No state carries ``unknown``
#: or ``unavailable`` as a value of its own: what is not known renders ``None``, which
#: Home Assistant shows as its own unknown. Icons are neutral where the state can be
#: either way (a fixed icon cannot follow it). The object ids are kept across versions:
#: they make the unique ids, and Home Assistant's entity ids hang on those.
_ENTITIES: tuple[tuple[str, str, str, dict[str, Any]], ...] = (
    ("sensor", "rotation", "state", {
        "name": "Rotation", "device_class": "enum",
        "options": ["clockwise", "counterclockwise", "stopped"],
        "value_template": _ROTATION_TEMPLATE, "icon": "mdi:rotate-3d-variant"}),
    ("sensor", "airflow", "state", {
        "name": "Airflow", "device_class": "enum", "options": list(AIRFLOW_WORDS.values()),
        "value_template": _AIRFLOW_TEMPLATE, "icon": "mdi:weather-windy"}),
    ("sensor", "rpm", "state", {
        "name": "Speed", "unit_of_measurement": "rpm", "state_class": "measurement",
        "suggested_display_precision": 0,
        "value_template": _when_known("rpm", "value_json.rpm | round(1)", "0"),
        "icon": "mdi:speedometer"}),
    ("binary_sensor", "rotating", "state", {
        "name": "Running", "device_class": "running", "payload_on": "ON",
        "payload_off": "OFF",
        "value_template": ("{% if value_json.running is none %}None"
                           "{% elif value_json.running %}ON{% else %}OFF{% endif %}")}),
    ("sensor", "direction", "state", {
        "name": "Direction to reference", "device_class": "enum",
        "options": [d.value for d in (*WAYS, Direction.STOPPED)],
        "value_template": _DIRECTION_TEMPLATE, "icon": "mdi:compare-horizontal"}),
    ("sensor", "rate", "state", {
        "name": "Rotation rate", "device_class": "frequency", "unit_of_measurement": "Hz",
        "state_class": "measurement", "suggested_display_precision": 3,
        "value_template": _when_known("rate_hz", "value_json.rate_hz | round(3)", "0.0"),
        "icon": "mdi:sine-wave", "entity_category": "diagnostic"}),
    ("sensor", "confidence", "state", {
        "name": "Confidence", "unit_of_measurement": "%", "state_class": "measurement",
        "suggested_display_precision": 0, "entity_category": "diagnostic",
        "value_template": _none_or("confidence", "(value_json.confidence * 100) | round(0)"),
        "icon": "mdi:check-decagram"}),
    ("event", "motion", "event", {
        "name": "Fan events", "event_types": list(MOTION_EVENTS),
        "value_template": _event_template({k: k for k in MOTION_EVENTS},
                                          ("rotation", "rate_hz")),
        "icon": "mdi:fan-alert"}),
    ("sensor", "status", "status", {
        "name": "Status", "device_class": "enum",
        "options": [*STATUS_WORDS.values(), DIRECTION_UNSET],
        "entity_category": "diagnostic", "value_template": _STATUS_TEMPLATE,
        "json_attributes_topic": "status",
        "json_attributes_template": ("{{ {'detail': value_json.detail, "
                                     "'reference': value_json.reference, "
                                     "'reference_rate_hz': value_json.reference_rate_hz} "
                                     "| tojson }}"),
        "icon": "mdi:list-status"}),
    ("sensor", "reference_fit", "status", {
        "name": "Reference fit", "unit_of_measurement": "%", "state_class": "measurement",
        "suggested_display_precision": 0, "entity_category": "diagnostic",
        "value_template": _FIT_TEMPLATE, "icon": "mdi:puzzle-check"}),
    ("event", "reference", "event", {
        "name": "Reference events", "event_types": list(REFERENCE_EVENTS),
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
        "entity_category": "config", "icon": "mdi:swap-horizontal"}),
    ("switch", "auto_learn", "setting:auto_learn", {
        "name": "Learn automatically", "payload_on": "ON", "payload_off": "OFF",
        "state_topic": "status",
        "value_template": ("{% set v = (value_json.settings or {}).get('auto_learn') %}"
                           "{% if v is none %}None{% elif v %}ON{% else %}OFF{% endif %}"),
        "entity_category": "config", "icon": "mdi:school-outline"}),
    ("number", "learn_seconds", "setting:learn_seconds", {
        "name": "Learning length", "unit_of_measurement": "s", "min": 3, "max": 23,
        "step": 1, "mode": "box", "state_topic": "status",
        "value_template": ("{% set v = (value_json.settings or {}).get('learn_seconds') %}"
                           "{% if v is none %}None{% else %}{{ v }}{% endif %}"),
        "entity_category": "config", "icon": "mdi:timer-outline"}),
    ("number", "stale_fit", "setting:stale_fit", {
        "name": "Stale below fit", "unit_of_measurement": "%", "min": 0, "max": 100,
        "step": 5, "mode": "box", "state_topic": "status",
        "command_template": "{{ value / 100 }}",
        "value_template": ("{% set v = (value_json.settings or {}).get('stale_fit') %}"
                           "{% if v is none %}None{% else %}{{ (v * 100) | round(0) }}"
                           "{% endif %}"),
        "entity_category": "config", "icon": "mdi:puzzle-remove-outline"}),
    ("sensor", "started", "stats", {
        "name": "Started", "device_class": "timestamp", "entity_category": "diagnostic",
        "value_template": _stat("started_at")}),
    ("sensor", "xruns", "stats", {
        "name": "Audio xruns", "state_class": "total_increasing",
        "entity_category": "diagnostic", "value_template": _stat("xruns"),
        "icon": "mdi:waveform"}),
    ("sensor", "dropped_pulses", "stats", {
        "name": "Dropped pulses", "state_class": "total_increasing",
        "entity_category": "diagnostic", "value_template": _stat("dropped_pulses"),
        "icon": "mdi:pulse"}),
    ("sensor", "reconnects", "stats", {
        "name": "MQTT reconnects", "state_class": "total_increasing",
        "entity_category": "diagnostic", "value_template": _stat("reconnects"),
        "icon": "mdi:lan-disconnect"}),
    ("sensor", "dropped_events", "stats", {
        "name": "Dropped events", "state_class": "total_increasing",
        "entity_category": "diagnostic",
        "value_template": _stat("dropped_events"),
        "icon": "mdi:message-alert-outline"}),
    ("sensor", "commands_refused", "stats", {
        "name": "Refused commands", "state_class": "total_increasing",
        "entity_category": "diagnostic",
        "value_template": _stat("commands_refused"),
        "icon": "mdi:shield-alert-outline"}),
    ("sensor", "clock_ppm", "stats", {
        "name": "Clock offset", "unit_of_measurement": "ppm", "state_class": "measurement",
        "suggested_display_precision": 1, "entity_category": "diagnostic",
        "value_template": _stat("clock_ppm", "v + 0.0"),   # + 0.0: no "-0.0"
        "icon": "mdi:clock-fast"}),
    ("sensor", "latency", "stats", {
        "name": "Latency", "unit_of_measurement": "ms", "device_class": "duration",
        "state_class": "measurement", "suggested_display_precision": 0,
        "entity_category": "diagnostic",
        "value_template": _stat("latency_ms", "v.median"),
        "icon": "mdi:timer-sand"}),
    ("sensor", "cpu", "stats", {
        "name": "CPU share", "unit_of_measurement": "%", "state_class": "measurement",
        "entity_category": "diagnostic", "suggested_display_precision": 1,
        "value_template": _stat("cpu_share", "(v * 100) | round(1)"),
        "icon": "mdi:cpu-64-bit"}),
)

def device_block(cfg: Config) -> dict[str, Any]:
    """The Home Assistant device all entities belong to; its name is ``mqtt.device_name``
    or one made from ``device_id``."""
    name = getattr(cfg.mqtt, "device_name", None) or friendly_name(cfg.device_id)
    return {"identifiers": [f"bladesonar_{node_id(cfg.device_id)}"], "name": name,
            "manufacturer": "bladesonar", "model": "Pulsed-sonar rotation sensor",
            "sw_version": _version()}


def origin_block() -> dict[str, Any]:
    """Who made the discovery config (Home Assistant names it in its log)."""
    out: dict[str, Any] = {"name": "bladesonar", "sw_version": _version()}
    url = support_url()
    if url:
        out["support_url"] = url
    return out


def components(cfg: Config, topics: Topics | None = None) -> dict[str, dict[str, Any]]:
    """The device's components for device-based discovery: {object_id: config with its
    platform ``p``}. Entities, then one device trigger per motion event
    (``motion_<kind>``).

    Every entity reads the state, status, event or stats topic through a
    ``value_template``, is wired to the availability topic, and has a ``unique_id`` of
    ``bladesonar_<node_id>_<object_id>``. The command entities (buttons, select, the
    settings) are left out with ``mqtt.commands: false``.
    """
    topics = topics or Topics.for_config(cfg)
    node = topics.node
    by_key = {"state": topics.state, "stats": topics.stats, "status": topics.status,
              "event": topics.event, "command_reference": topics.command_reference,
              "command_direction": topics.command_direction,
              **{f"setting:{k}": topics.command_setting(k) for k in SETTINGS}}
    commands = getattr(cfg.mqtt, "commands", True)
    out: dict[str, dict[str, Any]] = {}
    for component, object_id, source, fields in _ENTITIES:
        command = source.startswith("command") or source.startswith("setting:")
        if command and not commands:
            continue
        conf: dict[str, Any] = {"p": component, "unique_id": f"bladesonar_{node}_{object_id}"}
        if command:
            conf["command_topic"] = by_key[source]
            conf["retain"] = False
        else:
            conf["state_topic"] = by_key[source]
        conf["qos"] = 1
        conf.update({"availability_topic": topics.availability,
                     "payload_available": ONLINE, "payload_not_available": OFFLINE})
        for k, v in fields.items():
            conf[k] = by_key[v] if k in ("json_attributes_topic", "state_topic") else v
        if component == "number" and object_id == "learn_seconds":
            # at most 2^20 samples are folded (config.py): 23 s at 44.1 kHz, 21 s at 48 kHz
            conf["max"] = min(int((1 << 20) / cfg.audio.sample_rate), 60)
        out[object_id] = conf
    # device triggers (Home Assistant's automation editor: "Device" -> "reversed"): MQTT
    # device automations on the event topic, one per motion event
    for kind in MOTION_EVENTS:
        out[f"motion_{kind}"] = {
            "p": "device_automation", "automation_type": "trigger", "topic": topics.event,
            "type": kind, "subtype": "fan", "payload": kind,
            "value_template": "{{ value_json.kind }}", "qos": 1}
    return out


def device_config(cfg: Config, topics: Topics | None = None) -> dict[str, Any]:
    """The device-based discovery payload: ``dev``, ``o`` (origin) and ``cmps``."""
    return {"dev": device_block(cfg), "o": origin_block(), "cmps": components(cfg, topics)}


def discovery_messages(cfg: Config, topics: Topics | None = None) -> list[Message]:
    """Home Assistant discovery: one retained device-based config at
    ``<discovery_prefix>/device/<node_id>/config``."""
    topics = topics or Topics.for_config(cfg)
    return [Message(topics.device_config, device_config(cfg, topics), qos=1, retain=True)]


def legacy_topic(topics: Topics, component: str, object_id: str) -> str:
    """Where earlier versions put one entity's own discovery config."""
    return f"{topics.discovery_prefix}/{component}/{topics.node}/{object_id}/config"


def is_legacy_config(topics: Topics, topic: str) -> bool:
    """Whether ``topic`` is a per-entity discovery config of this device."""
    head = f"{topics.discovery_prefix}/"
    if not topic.startswith(head):
        return False
    parts = topic[len(head):].split("/")
    return len(parts) == 4 and parts[1] == topics.node and parts[3] == "config" \
        and parts[0] != "device"


def migration_messages(cfg: Config, found: list[str],
                       topics: Topics | None = None) -> list[Message]:
    """Home Assistant's path from per-entity configs (``found``: their topics, as
    retained on the broker) to the device-based one, without a duplicate or an orphan:
    what goes out before the device config.

    First ``{"migrate_discovery": true}`` on each old topic of an entity the device
    config still has: Home Assistant unloads the entity and keeps its registry entry
    (entity id, name, history). Then an empty retained payload on every old topic: the
    unloaded ones take no notice, what the device config no longer has
    (``sensor/uptime``) is removed. The device config then loads the kept entities from
    their registry entries. (An empty payload sent after the device config instead, as
    Home Assistant's log suggests, draws a "conflicting MQTT discovery message" warning
    per entity from Home Assistant 2025.4: measured with tools/ha_check.)
    """
    topics = topics or Topics.for_config(cfg)
    cmps = components(cfg, topics)
    kept = {legacy_topic(topics, c["p"], oid) for oid, c in cmps.items()}
    return [*(Message(t, {"migrate_discovery": True}, qos=1, retain=True)
              for t in sorted(found) if t in kept),
            *(Message(t, None, qos=1, retain=True) for t in sorted(found))]


def retire_messages(cfg: Config, topics: Topics | None = None) -> list[Message]:
    """What removes the device from Home Assistant and the broker for good: an empty
    device config (Home Assistant deletes the device and its entities), and empty
    retained state, status, stats and availability."""
    topics = topics or Topics.for_config(cfg)
    return [Message(t, None, qos=1, retain=True)
            for t in (topics.device_config, topics.state, topics.status, topics.stats,
                      topics.availability)]
