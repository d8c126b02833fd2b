"""messages.py: topic names, payloads and discovery configs against fixed expectations."""

from __future__ import annotations

import datetime as dt
import json
import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest

from bladesonar import __version__, config
from bladesonar.answer import Decision, Direction, Estimate, RateState
from bladesonar.service import messages as M
from bladesonar.service import publish

T0 = 1_700_000_000.25  # 2023-11-14T22:13:20.250Z


def cfg_with(**mqtt):
    return config.from_mapping({"device_id": "fan-1", "mqtt": mqtt})


def live_estimate() -> Estimate:
    """What LiveAnalyzer.estimate() returns: a Decision plus the live fields."""
    d = Decision(Direction.REVERSED, "cw", -0.70069, 0.35036, 21.021, 0.9718,
                 "relative rate -0.7007 +- 0.0208", rate_state=RateState.CHANGING,
                 rate_change_hz_s=-0.04512)
    return Estimate.from_decision(d, window_s=4.0, reference="0123456789ab")


# -- topics ------------------------------------------------------------------------------


def test_topics_default_prefixes():
    t = M.Topics.for_config(cfg_with())
    assert t.availability == "bladesonar/fan-1/availability"
    assert t.state == "bladesonar/fan-1/state"
    assert t.event == "bladesonar/fan-1/event"
    assert t.stats == "bladesonar/fan-1/stats"
    assert t.ha_status == "homeassistant/status"


def test_topics_custom_prefixes_lose_stray_slashes():
    t = M.Topics.for_config(cfg_with(topic_prefix="home/sonar/", discovery_prefix="ha/"))
    assert t.state == "home/sonar/fan-1/state"
    assert t.ha_status == "ha/status"


def test_node_id_keeps_only_allowed_characters():
    assert M.node_id("fan-1_a") == "fan-1_a"
    assert M.node_id("living room.fan") == "living_room_fan"
    assert M.node_id("") == "bladesonar"


# -- JSON --------------------------------------------------------------------------------


def test_nan_and_infinities_become_null():
    assert M.dumps({"a": math.nan, "b": math.inf, "c": -math.inf, "d": [1.0, math.nan]}) == \
        '{"a":null,"b":null,"c":null,"d":[1.0,null]}'


def test_floats_rounded_to_six_significant_digits_ints_kept():
    assert M.clean(0.123456789) == 0.123457
    assert M.clean(12345.6789) == 12345.7
    assert M.clean(-2.5e-9) == -2.5e-09
    assert M.clean(123456789) == 123456789
    assert M.clean(True) is True


def test_numpy_values_become_plain_json():
    out = M.clean({"f": np.float32(0.5), "i": np.int64(7), "b": np.bool_(True),
                   "a": np.array([1.0, np.nan]), "t": (1, 2)})
    assert out == {"f": 0.5, "i": 7, "b": True, "a": [1.0, None], "t": [1, 2]}
    assert type(out["i"]) is int and type(out["b"]) is bool
    json.dumps(out, allow_nan=False)


def test_utc_iso_has_offset_and_milliseconds():
    assert M.utc_iso(0) == "1970-01-01T00:00:00.000+00:00"
    parsed = dt.datetime.fromisoformat(M.utc_iso(T0))
    assert parsed.utcoffset() == dt.timedelta(0)
    assert parsed.timestamp() == pytest.approx(T0)


def test_message_encoding():
    assert M.Message("t", "online").encode() == "online"
    assert M.Message("t", None).encode() == ""
    assert M.Message("t", {"x": math.nan}).encode() == '{"x":null}'


# -- payloads ----------------------------------------------------------------------------


def test_state_payload_from_a_live_estimate():
    p = M.state_payload(live_estimate(), t=T0, running=True)
    assert list(p) == [*M.STATE_KEYS, "reason", "time"]
    assert p == {
        "direction": "reversed", "rotation": "cw", "rotating": True, "running": True,
        "rate_hz": 0.35036,
        "rpm": 21.021, "relative_rate": -0.70069, "rate_state": "changing",
        "rate_change_hz_s": -0.0451, "confidence": 0.9718, "airflow": "unknown",
        "airflow_confidence": None, "window_s": 4.0,
        "reference": "0123456789ab", "status": "ok",
        "reason": "relative rate -0.7007 +- 0.0208", "time": "2023-11-14T22:13:20.250+00:00"}


def test_state_payload_keys_are_its_typed_dicts():
    """Every state payload the messages make has the keys StatePayload declares, each
    required one always, an optional one only where the state has it, in the published
    order (STATE_KEYS, then the optional ones, then time); a key added to the payload
    and not to the TypedDict (or the other way) fails here."""
    declared = M.StatePayload.__annotations__
    required, optional = M.StatePayload.__required_keys__, M.StatePayload.__optional_keys__
    assert [k for k in declared if k in required] == [*M.STATE_KEYS, "time"]
    assert set(optional) == {"detail", "reason", "warnings"}
    warned = Estimate.from_decision(
        Decision(Direction.SAME, "cw", 0.5, 0.2, 12.0, 0.9, "r", warnings=("w",)),
        window_s=4.0, reference="ab")
    for p in (M.state_payload(live_estimate(), t=T0, running=True),
              M.state_payload(Estimate.unknown("learning"), t=T0, status="learning",
                              detail="recording"),
              M.state_payload(warned, t=T0), M.state_payload(None, t=T0)):
        assert required <= set(p) <= set(declared), set(p) ^ set(declared)
        extras = [k for k in p if k in optional]
        assert list(p) == [*M.STATE_KEYS, *extras, "time"]
        assert extras == sorted(extras, key=["detail", "reason", "warnings"].index)


def test_state_payload_carries_the_live_airflow():
    fields = {**live_estimate().fields(), "airflow": "down", "airflow_confidence": 0.97}
    p = M.state_payload(fields, t=T0)
    assert (p["airflow"], p["airflow_confidence"]) == ("down", 0.97)
    assert M.state_payload({**fields, "airflow": "sideways"}, t=T0)["airflow"] == "unknown"


def test_state_payload_fills_missing_keys_with_null_and_keeps_status():
    p = M.state_payload({"direction": "unknown", "rate_hz": math.nan,
                         "status": "reference_missing"}, t=T0)
    assert p["rate_hz"] is None and p["rotation"] is None and p["window_s"] is None
    assert p["status"] == "reference_missing"
    assert set(M.STATE_KEYS) <= set(p)


def test_state_payload_of_nothing_known_has_a_status_and_its_detail():
    p = M.state_payload(Estimate.unknown("learning"), t=T0, status="learning",
                        detail="recording")
    assert p["direction"] == "unknown" and p["rotating"] is None and p["rate_hz"] is None
    assert (p["status"], p["detail"]) == ("learning", "recording")
    assert M.state_payload(None, t=T0)["direction"] == "unknown"
    # no answer, so no confidence in one: null (Home Assistant's unknown), never 0
    assert p["confidence"] is None and M.state_payload(None, t=T0)["confidence"] is None


def test_confidence_only_of_a_known_answer():
    d = Decision(Direction.UNKNOWN, None, 0.1, 0.045, 2.7, 0.5, "confirming a stop")
    e = Estimate.from_decision(d, window_s=4.0, reference="ab")
    p = M.state_payload(e, t=T0)
    assert p["confidence"] is None and p["rate_hz"] == 0.045     # the raw rate stays
    assert M.state_payload(live_estimate(), t=T0)["confidence"] == 0.9718


def test_running_is_held_through_unknown_and_goes_off_at_the_confirmed_stop():
    """What the analysis says around a reversal and a stop (same, ~1 s of unknown,
    reversed; unknown, stopped) against what Running shows: one value per answer."""
    h = M.RunningHold(hold_s=60.0)
    seq = [(0.0, "unknown", "starting"), (1.0, "same", "ok"), (2.0, "unknown", "ok"),
           (2.7, "unknown", "ok"), (3.0, "reversed", "ok"), (10.0, "unknown", "ok"),
           (11.2, "stopped", "ok"), (12.0, "unknown", "ok"), (13.0, "same", "ok"),
           (14.0, "unknown", "learning"), (70.0, "unknown", "learning"),
           (74.5, "unknown", "learning"), (75.0, "same", "ok"),
           (76.0, "unknown", "reference_stale")]
    got = [h.update(d, st, t) for t, d, st in seq]
    assert got == [None, True, True, True, True, True, False, False, True,
                   True, True, None, True, None]


def test_running_goes_unknown_after_the_hold_and_on_any_other_status():
    for status in ("no_signal", "reference_missing", "reference_invalid"):
        h = M.RunningHold(hold_s=5.0)
        h.update("stopped", "ok", 0.0)
        assert h.update(None, status, 0.1) is None
    h = M.RunningHold(hold_s=5.0)
    h.update("stopped", "ok", 0.0)
    assert [h.update("unknown", "ok", t) for t in (1.0, 5.9, 6.1)] == [False, False, None]


def test_estimate_from_a_decision_rounds_like_the_offline_answer():
    d = Decision(Direction.SAME, "ccw", 0.123456789, 0.4567891, 27.4073, 0.912345, "r",
                 warnings=("w",), rate_state=RateState.SETTLED, rate_change_hz_s=0.0012345)
    e = Estimate.from_decision(d, window_s=5.0, reference="ab")
    off = d.as_dict()
    for k in ("relative_rate", "rate_hz", "rpm", "rate_change_hz_s", "confidence"):
        assert getattr(e, k) == off[k], k
    assert e.rotating is True and e.known and e.fields()["warnings"] == ["w"]
    assert Estimate.unknown("x").rotating is None


def test_event_payload():
    assert M.event_payload("reversed", {"direction": "reversed", "rate_hz": 0.3503612},
                           t=T0) == {
        "kind": "reversed", "time": "2023-11-14T22:13:20.250+00:00",
        "details": {"direction": "reversed", "rate_hz": 0.350361}}


def test_stats_payload_adds_missing_counters_and_time():
    p = M.stats_payload({"xruns": 2, "reconnects": 5, "cpu_share": math.nan},
                        t=T0, extra={"reconnects": 0, "dropped_events": 1})
    assert p == {"xruns": 2, "reconnects": 5, "cpu_share": None, "dropped_events": 1,
                 "time": "2023-11-14T22:13:20.250+00:00"}


def test_message_qos_and_retain():
    t = M.Topics.for_config(cfg_with())
    assert M.availability_message(t, True) == M.Message(t.availability, "online", 1, True)
    assert M.availability_message(t, False).payload == "offline"
    assert M.state_message(t, {}).qos == 1 and M.state_message(t, {}).retain
    assert M.event_message(t, {}).qos == 1 and not M.event_message(t, {}).retain
    assert M.stats_message(t, {}).retain


# -- discovery ---------------------------------------------------------------------------
#
# What Home Assistant accepts in a discovery config, per platform (the MQTT integration's
# DISCOVERY_SCHEMA of Home Assistant 2025.4.4, as documented on home-assistant.io:
# integrations sensor.mqtt, binary_sensor.mqtt, event.mqtt, button.mqtt, select.mqtt, and
# the discovery page's "device" and "origin" blocks). An unknown key is refused by Home
# Assistant (the whole entity is dropped with an error in its log), so the test refuses it.

_COMMON = {"availability", "availability_mode", "availability_template", "availability_topic",
           "device", "enabled_by_default", "encoding", "entity_category", "entity_picture",
           "icon", "json_attributes_template", "json_attributes_topic", "name", "object_id",
           "origin", "payload_available", "payload_not_available", "qos", "unique_id"}
HA_SCHEMA = {
    "sensor": (_COMMON | {"device_class", "expire_after", "force_update",
                          "last_reset_value_template", "options", "state_class",
                          "state_topic", "suggested_display_precision",
                          "unit_of_measurement", "value_template"}, {"state_topic"}),
    "binary_sensor": (_COMMON | {"device_class", "expire_after", "force_update", "off_delay",
                                 "payload_off", "payload_on", "state_topic",
                                 "value_template"}, {"state_topic"}),
    "event": (_COMMON | {"device_class", "event_types", "state_topic", "value_template"},
              {"state_topic", "event_types"}),
    "button": (_COMMON | {"command_template", "command_topic", "device_class",
                          "payload_press", "retain"}, {"command_topic"}),
    "select": (_COMMON | {"command_template", "command_topic", "optimistic", "options",
                          "retain", "state_topic", "value_template"},
               {"command_topic", "options"}),
    # MQTT device triggers (integrations/device_trigger.mqtt): not entities
    "device_automation": ({"automation_type", "device", "encoding", "origin", "payload",
                           "qos", "subtype", "topic", "type", "value_template"},
                          {"automation_type", "device", "subtype", "topic", "type"}),
}
#: entity_category values each platform allows (sensors cannot be "config")
HA_CATEGORIES = {"sensor": {"diagnostic"}, "binary_sensor": {"diagnostic"},
                 "event": {"diagnostic"}, "button": {"config", "diagnostic"},
                 "select": {"config", "diagnostic"}, "device_automation": set()}
HA_DEVICE_KEYS = {"configuration_url", "connections", "hw_version", "identifiers",
                  "manufacturer", "model", "model_id", "name", "serial_number",
                  "suggested_area", "sw_version", "via_device"}
HA_ORIGIN_KEYS = {"name", "sw_version", "support_url"}
HA_STATE_CLASSES = {"measurement", "total", "total_increasing"}
#: Home Assistant's own state words: no entity may use them as a value of its own
HA_RESERVED = {"unknown", "unavailable"}

HA_SCHEMA.update({
    "switch": (_COMMON | {"command_template", "command_topic", "device_class", "optimistic",
                          "payload_off", "payload_on", "retain", "state_off", "state_on",
                          "state_topic", "value_template"}, {"command_topic"}),
    "number": (_COMMON | {"command_template", "command_topic", "device_class", "max", "min",
                          "mode", "optimistic", "payload_reset", "retain", "state_topic",
                          "step", "unit_of_measurement", "value_template"},
               {"command_topic"}),
})
HA_CATEGORIES.update({"switch": {"config", "diagnostic"}, "number": {"config", "diagnostic"}})
#: device-based discovery (2024.11 and later): the payload's own keys, abbreviated
HA_DEVICE_PAYLOAD_KEYS = {"dev", "o", "cmps", "availability", "availability_topic", "qos",
                          "state_topic", "command_topic", "encoding"}


def discovery(**mqtt):
    return {m.topic: m for m in M.discovery_messages(cfg_with(**mqtt))}


def device_payload(**mqtt):
    msgs = M.discovery_messages(cfg_with(**mqtt))
    assert len(msgs) == 1
    return json.loads(msgs[0].encode())


def configs(**mqtt):
    """{(component, object_id): config} of the device's components, as Home Assistant
    makes them: each with the device and origin of the device payload."""
    dev = device_payload(**mqtt)
    out = {}
    for oid, c in dev["cmps"].items():
        c = dict(c)
        component = c.pop("p")
        c["device"], c["origin"] = dev["dev"], dev["o"]
        out[(component, oid)] = c
    return out


def test_one_retained_device_config_with_origin():
    msgs = discovery()
    assert list(msgs) == ["homeassistant/device/fan-1/config"]
    m = msgs["homeassistant/device/fan-1/config"]
    assert m.retain and m.qos == 1
    dev = json.loads(m.encode())
    assert set(dev) <= HA_DEVICE_PAYLOAD_KEYS and {"dev", "o", "cmps"} <= set(dev)
    assert dev["o"]["name"] == "bladesonar" and dev["o"]["sw_version"] == __version__


def test_origin_support_url_comes_from_the_package_metadata(monkeypatch):
    import importlib.metadata as md

    class Meta:
        def __init__(self, urls, home=None):
            self.urls, self.home = urls, home

        def get_all(self, key, default=None):
            return self.urls if key == "Project-URL" else [self.home] if self.home else \
                default

    monkeypatch.setattr(md, "metadata", lambda name: Meta(
        ["Documentation, https://x.example/docs", "Issues, https://x.example/issues"]))
    assert M.origin_block()["support_url"] == "https://x.example/issues"
    monkeypatch.setattr(md, "metadata", lambda name: Meta([], "http://insecure.example"))
    assert "support_url" not in M.origin_block()


def test_discovery_configs_pass_home_assistants_schema():
    for (component, object_id), c in configs().items():
        allowed, required = HA_SCHEMA[component]
        assert set(c) <= allowed, (object_id, set(c) - allowed)
        assert required <= set(c), (object_id, required - set(c))
        assert set(c["device"]) <= HA_DEVICE_KEYS and set(c["origin"]) <= HA_ORIGIN_KEYS
        assert c["origin"]["name"]
        if "entity_category" in c:
            assert c["entity_category"] in HA_CATEGORIES[component], object_id
        if c.get("device_class") == "enum":
            # an enum sensor has options and neither a unit nor a state class
            assert c["options"] and "unit_of_measurement" not in c and "state_class" not in c
        if "options" in c:
            assert not HA_RESERVED & set(c["options"]), (object_id, c["options"])
            assert len(set(c["options"])) == len(c["options"])
        if component == "event":
            assert c["event_types"] and not HA_RESERVED & set(c["event_types"])
        if "state_class" in c:
            assert c["state_class"] in HA_STATE_CLASSES
            assert c.get("device_class") not in ("enum", "timestamp")
        if c.get("device_class") == "timestamp":
            assert "unit_of_measurement" not in c
        if component == "number":
            assert c["min"] < c["max"] and c["step"] > 0 and c["mode"] in ("box", "slider")
        for key in ("state_topic", "command_topic", "availability_topic",
                    "json_attributes_topic"):
            if key in c:
                assert "+" not in c[key] and "#" not in c[key]


def test_discovery_ids_and_availability():
    t = M.Topics.for_config(cfg_with())
    ids = set()
    for (component, oid), c in configs().items():
        if component == "device_automation":
            assert c["topic"] == t.event and c["automation_type"] == "trigger"
            continue
        assert c["unique_id"] == f"bladesonar_fan-1_{oid}"
        ids.add(c["unique_id"])
        assert c["availability_topic"] == t.availability
        assert (c["payload_available"], c["payload_not_available"]) == ("online", "offline")
        assert c.get("state_topic", t.state) in (t.state, t.stats, t.status, t.event)
        assert c.get("command_topic", t.command_reference) in t.commands
        assert c["device"] == {"identifiers": ["bladesonar_fan-1"], "name": "Fan 1",
                               "manufacturer": "bladesonar",
                               "model": "Pulsed-sonar rotation sensor",
                               "sw_version": __version__}
    assert len(ids) == len(configs()) - 3


def test_device_triggers_fire_on_their_event_only():
    c = configs()
    trig = {k[1]: v for k, v in c.items() if k[0] == "device_automation"}
    assert set(trig) == {"motion_started", "motion_stopped", "motion_reversed"}
    for name, x in trig.items():
        for kind in M.EVENT_KINDS:
            got = render(x["value_template"], M.event_payload(kind, {}, t=T0))
            assert (got == x["payload"]) == (kind == name.split("_", 1)[1]), (name, kind)


def test_device_name_from_config_and_entity_names_do_not_repeat_it():
    c = configs(device_name="Living room fan")
    assert {x["device"]["name"] for x in c.values()} == {"Living room fan"}
    names = [x["name"] for x in c.values() if "name" in x]
    assert len(set(names)) == len(names)
    assert not any("fan 1" in n.lower() or "bladesonar" in n.lower() for n in names)
    assert M.friendly_name("living-room_fan") == "Living room fan"
    assert M.friendly_name("x") == "X"


def test_discovery_entities():
    c = configs()
    assert {("sensor", "rotation"), ("sensor", "rpm"), ("binary_sensor", "rotating"),
            ("sensor", "direction"), ("sensor", "status"), ("event", "motion"),
            ("event", "reference"), ("button", "learn_reference"),
            ("button", "forget_reference"), ("select", "reference_direction"),
            ("sensor", "started"), ("switch", "auto_learn"), ("number", "learn_seconds"),
            ("number", "stale_fit"), ("sensor", "dropped_events"),
            ("sensor", "commands_refused"), ("sensor", "clock_ppm"),
            ("sensor", "latency")} <= set(c)
    assert ("sensor", "uptime") not in c
    assert c[("sensor", "rotation")]["options"] == ["clockwise", "counterclockwise", "stopped"]
    assert c[("sensor", "direction")]["options"] == ["same", "reversed", "stopped"]
    assert c[("sensor", "status")]["options"] == [*M.STATUS_WORDS.values(), M.DIRECTION_UNSET]
    assert set(M.STATUS_WORDS) == set(M.STATUSES)
    assert c[("sensor", "status")]["entity_category"] == "diagnostic"
    assert c[("event", "motion")]["event_types"] == ["started", "stopped", "reversed"]
    assert c[("event", "motion")]["name"] == "Fan events"
    assert c[("sensor", "started")]["device_class"] == "timestamp"
    rate = c[("sensor", "rate")]
    assert (rate["device_class"], rate["unit_of_measurement"], rate["state_class"]) == \
        ("frequency", "Hz", "measurement")
    assert (c[("sensor", "rpm")]["unit_of_measurement"],
            c[("sensor", "rpm")]["state_class"]) == ("rpm", "measurement")
    learn = c[("button", "learn_reference")]
    t = M.Topics.for_config(cfg_with())
    assert learn["command_topic"] == t.command_reference and learn["payload_press"] == "learn"
    assert c[("button", "forget_reference")]["payload_press"] == "forget"
    sel = c[("select", "reference_direction")]
    assert sel["command_topic"] == t.command_direction and sel["state_topic"] == t.status
    for opt in sel["options"]:      # every option the select sends is a command we take
        assert M.parse_command(t, t.command_direction, opt.encode()).name == "direction"
    # no entity carries the whole state as attributes (each message would be a change)
    assert not any(x.get("json_attributes_topic") == t.state for x in c.values())
    rot = c[("binary_sensor", "rotating")]
    assert (rot["payload_on"], rot["payload_off"]) == ("ON", "OFF")
    # settings: config entities whose commands the parser takes, bounds of the schema
    for key in M.SETTINGS:
        ent = next(x for (comp, oid), x in c.items() if oid == key)
        assert ent["entity_category"] == "config" and ent["state_topic"] == t.status
        assert ent["command_topic"] == t.command_setting(key)
    assert c[("number", "learn_seconds")]["max"] == 23        # 2^20 samples at 44.1 kHz
    assert c[("number", "learn_seconds")]["min"] == 3


def test_icons_never_name_a_direction():
    """A fixed icon cannot follow the state: none of an entity that can say either way
    may point one way."""
    for (_component, oid), x in configs().items():
        icon = x.get("icon", "")
        assert not any(w in icon for w in ("rotate-right", "rotate-left", "clockwise",
                                           "arrow-left", "arrow-right")), (oid, icon)


def test_commands_off_leaves_out_the_command_entities():
    c = configs(commands=False)
    assert not any(k[0] in ("button", "select", "switch", "number") for k in c)
    assert ("device_automation", "motion_reversed") in c
    assert ("sensor", "status") in c


def test_discovery_follows_the_prefixes():
    msgs = discovery(discovery_prefix="ha", topic_prefix="home")
    assert list(msgs) == ["ha/device/fan-1/config"]
    for c in configs(discovery_prefix="ha", topic_prefix="home").values():
        assert c.get("availability_topic", "home/fan-1/availability") == \
            "home/fan-1/availability"
        assert c.get("topic", "home/fan-1/event") == "home/fan-1/event"


def test_migration_from_per_entity_configs_keeps_entities_and_removes_retired_ones():
    """Home Assistant's migrate_discovery path (its discovery.py and entity.py):
    migrate_discovery on each old topic the device config still has (unloaded, registry
    kept), then an empty retained payload on every old topic, all before the device
    config (an empty payload after it draws a warning per entity in 2025.4)."""
    cfg = cfg_with()
    t = M.Topics.for_config(cfg)
    found = ["homeassistant/sensor/fan-1/rotation/config",
             "homeassistant/device_automation/fan-1/motion_reversed/config",
             "homeassistant/sensor/fan-1/uptime/config"]
    assert all(M.is_legacy_config(t, x) for x in found)
    assert not M.is_legacy_config(t, t.device_config)
    assert not M.is_legacy_config(t, "homeassistant/sensor/other/rotation/config")
    assert not M.is_legacy_config(t, "homeassistant/status")
    msgs = M.migration_messages(cfg, found)
    migrate = {"migrate_discovery": True}
    assert [(m.topic, m.payload) for m in msgs] == [
        ("homeassistant/device_automation/fan-1/motion_reversed/config", migrate),
        ("homeassistant/sensor/fan-1/rotation/config", migrate),
        ("homeassistant/device_automation/fan-1/motion_reversed/config", None),
        ("homeassistant/sensor/fan-1/rotation/config", None),
        ("homeassistant/sensor/fan-1/uptime/config", None)]
    assert all(m.retain and m.qos == 1 for m in msgs)
    # the device config's components have the discovery ids of the old topics:
    # (component, "<node_id> <object_id>") in Home Assistant
    cmps = device_payload()["cmps"]
    assert cmps["rotation"]["p"] == "sensor" and cmps["motion_reversed"]["p"] == \
        "device_automation"


def test_retiring_clears_the_device_and_the_retained_topics():
    msgs = M.retire_messages(cfg_with())
    t = M.Topics.for_config(cfg_with())
    assert [m.topic for m in msgs][0] == t.device_config
    assert {m.topic for m in msgs} == {t.device_config, t.state, t.status, t.stats,
                                      t.availability}
    assert all(m.payload is None and m.retain for m in msgs)


# -- the templates, rendered by Jinja2 (Home Assistant's template engine) ---------------


def render(template: str, payload: Mapping[str, Any]) -> str:
    """What Home Assistant computes from a message: its templates are Jinja2 in a
    sandbox, with ``value_json`` the decoded payload."""
    pytest.importorskip("jinja2")
    from jinja2.sandbox import ImmutableSandboxedEnvironment

    env = ImmutableSandboxedEnvironment()
    return env.from_string(template).render(value_json=json.loads(M.dumps(payload)),
                                            value=M.dumps(payload)).strip()


def states_of(payload: Mapping[str, Any], topic_key: str) -> dict[str, str]:
    t = M.Topics.for_config(cfg_with())
    topic = getattr(t, topic_key)
    return {k[1]: render(c["value_template"], payload) for k, c in configs().items()
            if c.get("state_topic") == topic and "value_template" in c}


def _estimate(direction, rotation, rate):
    return Estimate(Direction(direction), rotation, None if rate is None else 1.0, rate,
                    None if rate is None else rate * 60, 0.9, "r", rate_state=RateState.SETTLED,
                    rate_change_hz_s=0.0, window_s=4.0, reference="ab")


def test_state_templates_give_words_for_people_and_none_when_not_known():
    """What Home Assistant shows for a day's answers in order, Running held by the
    publisher's RunningHold: Speed is a number only while the direction is known (0
    only when stopped), Running never unknown between known states."""
    c = configs()
    hold = M.RunningHold()
    confirming = Estimate(Direction.UNKNOWN, None, 0.01, 0.004, 0.24, 0.5,
                          "confirming a stop", window_s=4.0, reference="ab")
    doubt = Estimate(Direction.UNKNOWN, None, None, 0.4, 24.0, 0.3, "direction in doubt",
                     rate_state=RateState.SETTLED, turning=True, window_s=4.0,
                     reference="ab")
    cases = [
        (_estimate("unknown", None, None), {"rotation": "None", "direction": "None",
                                            "rotating": "None", "rate": "None",
                                            "rpm": "None", "confidence": "None"}),
        (_estimate("same", "ccw", 0.4512345), {"rotation": "counterclockwise",
                                               "direction": "same", "rotating": "ON",
                                               "rate": "0.451", "rpm": "27.1",
                                               "confidence": "90.0"}),
        (confirming, {"rotation": "None", "rotating": "ON", "rpm": "None", "rate": "None",
                      "confidence": "None"}),
        (_estimate("reversed", "cw", 0.3), {"rotation": "clockwise",
                                            "direction": "reversed", "rotating": "ON"}),
        (_estimate("reversed", None, 0.3), {"rotation": "None", "direction": "reversed"}),
        (confirming, {"rotating": "ON", "rpm": "None"}),
        (_estimate("stopped", None, 0.0), {"rotation": "stopped", "direction": "stopped",
                                           "rotating": "OFF", "rate": "0.0", "rpm": "0"}),
        (confirming, {"rotating": "OFF", "rpm": "None", "rate": "None"}),
        # turning with the direction in doubt (a room whose wall echoes are weak): the
        # speed is known, Running is on, the direction and the rotation are not
        (doubt, {"rotation": "None", "direction": "None", "rotating": "ON", "rpm": "24.0",
                 "rate": "0.4", "confidence": "None"}),
        (confirming, {"rotating": "ON", "rpm": "None"}),
    ]
    for i, (est, want) in enumerate(cases):
        running = hold.update(publish._kind_of(est), "ok", float(i))
        got = states_of(M.state_payload(est, t=T0, running=running), "state")
        for k, v in want.items():
            assert got[k] == v, (i, est.direction, k, got[k])
        for k, v in got.items():
            opts = c.get(("sensor", k), {}).get("options")
            assert opts is None or v in opts or v == "None", (k, v)
            assert v not in HA_RESERVED
    unknown = M.state_payload(None, t=T0, status="reference_missing", detail="no file")
    assert states_of(unknown, "state")["confidence"] == "None"


def test_airflow_sensor_says_down_or_up_and_none_when_not_known():
    c = configs()[("sensor", "airflow")]
    assert c["name"] == "Airflow" and c["device_class"] == "enum"
    assert c["options"] == ["Down (summer)", "Up (winter)"]
    base = _estimate("same", "ccw", 0.45).fields()
    for word, shown in (("down", "Down (summer)"), ("up", "Up (winter)"),
                        ("unknown", "None"), (None, "None")):
        p = M.state_payload({**base, "airflow": word, "airflow_confidence": 0.9}, t=T0)
        assert states_of(p, "state")["airflow"] == shown, word
    # before the first reference: the airflow and the rate with the direction unknown
    early = M.state_payload({"direction": "unknown", "rotating": True, "rotation": "cw",
                             "rate_hz": 0.6, "rpm": 36.0, "airflow": "up",
                             "airflow_confidence": 0.99}, t=T0, status="learning")
    got = states_of(early, "state")
    assert (got["airflow"], got["rotation"], got["rate"], got["rpm"]) == \
        ("Up (winter)", "clockwise", "0.6", "36.0")


def test_status_and_select_templates():
    p = M.status_payload({"status": "reference_stale", "detail": "fit 0.3", "reference": "ab",
                          "reference_direction": "cw", "reference_rate_hz": 0.45,
                          "fit": 0.31, "since": "x"})
    got = states_of(p, "status")
    assert got["status"] == "Reference stale"
    assert got["reference_fit"] == "31.0"
    assert got["reference_direction"] == "clockwise"
    none = states_of(M.status_payload({"status": "reference_missing"}), "status")
    assert none["reference_fit"] == "None" and none["reference_direction"] == "None"
    assert none["status"] == "No reference"
    attrs = configs()[("sensor", "status")]["json_attributes_template"]
    assert json.loads(render(attrs, p)) == {"detail": "fit 0.3", "reference": "ab",
                                            "reference_rate_hz": 0.45}
    with pytest.raises(ValueError, match="learning"):
        M.status_payload({"status": "unknown"})
    opts = configs()[("sensor", "status")]["options"]
    for st in M.STATUSES:
        assert states_of(M.status_payload({"status": st, "reference_direction": "cw"}),
                         "status")["status"] in opts


def test_status_says_when_the_direction_is_not_set():
    base = {"status": "ok", "reference": "ab", "reference_direction": "unknown"}
    assert states_of(M.status_payload(base), "status")["status"] == M.DIRECTION_UNSET
    ok = states_of(M.status_payload({**base, "reference_direction": "ccw"}), "status")
    assert ok["status"] == "OK"


@pytest.mark.parametrize("fit, shown", [(1.02, "100.0"), (0.996, "100.0"), (0.5, "50.0"),
                                        (-0.01, "0.0")])
def test_reference_fit_stays_within_0_and_100_percent(fit, shown):
    assert states_of(M.status_payload({"status": "ok", "fit": fit}), "status")[
        "reference_fit"] == shown


def test_setting_templates_and_commands():
    t = M.Topics.for_config(cfg_with())
    p = M.status_payload({"status": "ok", "settings": {"auto_learn": False,
                                                       "learn_seconds": 12.0,
                                                       "stale_fit": 0.6}})
    got = states_of(p, "status")
    assert (got["auto_learn"], got["learn_seconds"], got["stale_fit"]) == \
        ("OFF", "12.0", "60.0")
    none = states_of(M.status_payload({"status": "ok"}), "status")
    assert none["auto_learn"] == none["learn_seconds"] == "None"
    number = configs()[("number", "stale_fit")]
    assert render(number["command_template"].replace("value", "value_json.v"),
                  {"v": 45}) == "0.45"
    assert M.parse_command(t, t.command_setting("auto_learn"), b"ON") == \
        M.Command("setting", True, "auto_learn")
    assert M.parse_command(t, t.command_setting("stale_fit"), b" 0.45 ") == \
        M.Command("setting", 0.45, "stale_fit")
    for key, bad, match in (("auto_learn", b"maybe", "not a switch value"),
                            ("learn_seconds", b"nan", "not a number"),
                            ("learn_seconds", b"12s", "not a number")):
        with pytest.raises(M.CommandError, match=match):
            M.parse_command(t, t.command_setting(key), bad)


def test_event_templates_give_home_assistant_event_json_or_nothing():
    c = configs()
    motion = c[("event", "motion")]["value_template"]
    ref = c[("event", "reference")]["value_template"]
    ev = M.event_payload("reversed", {"direction": "reversed", "rotation": "cw",
                                      "rate_hz": 0.35}, t=T0)
    assert json.loads(render(motion, ev)) == {"event_type": "reversed", "rotation": "cw",
                                              "rate_hz": 0.35}
    assert render(ref, ev) == ""            # empty: Home Assistant ignores it
    learned = M.event_payload("reference_learned", {"reference": "ab", "detail": None}, t=T0)
    assert json.loads(render(ref, learned))["event_type"] == "learned"
    assert render(motion, learned) == ""
    for kind in M.EVENT_KINDS:
        out = [render(tpl, M.event_payload(kind, {}, t=T0)) for tpl in (motion, ref)]
        assert sum(1 for o in out if o) == 1, kind


def test_stats_templates():
    stats = M.stats_payload({"started_at": "2026-11-23T09:29:18.904+00:00", "xruns": 2,
                             "dropped_pulses": 3, "reconnects": 1, "cpu_share": 0.0734},
                            t=T0)
    got = states_of(stats, "stats")
    assert got["started"] == "2026-11-23T09:29:18.904+00:00"
    assert dt.datetime.fromisoformat(got["started"]).utcoffset() == dt.timedelta(0)
    assert got["cpu"] == "7.3" and got["xruns"] == "2"
    # counters an older daemon's message lacks are unknown, not an error in the template
    assert got["dropped_events"] == got["commands_refused"] == got["latency"] == "None"
    full = M.stats_payload({"dropped_events": 4, "commands_refused": 1, "clock_ppm": -0.0,
                            "latency_ms": {"median": 120.5, "max": 300.0, "n": 12}}, t=T0)
    got = states_of(full, "stats")
    assert (got["dropped_events"], got["commands_refused"], got["clock_ppm"],
            got["latency"]) == ("4", "1", "0.0", "120.5")


# -- commands ------------------------------------------------------------------------------


def test_commands_are_parsed_without_case_and_space():
    t = M.Topics.for_config(cfg_with())
    assert M.parse_command(t, t.command_reference, b" Learn\n") == M.Command("learn")
    assert M.parse_command(t, t.command_reference, b"FORGET") == M.Command("forget")
    assert M.parse_command(t, t.command_direction, b"clockwise") == M.Command("direction",
                                                                              "cw")
    assert M.parse_command(t, t.command_direction, b"ccw").value == "ccw"
    assert M.parse_command(t, t.command_direction, b"unknown").value == "unknown"
    assert M.parse_command(t, t.command_direction, b"Not set").value == "unknown"


@pytest.mark.parametrize("topic_key, payload, match", [
    ("command_reference", b"", "unknown command ''"),
    ("command_reference", b"learnx", "unknown command 'learnx'"),
    ("command_reference", b"\xff\xfe", "not UTF-8"),
    ("command_reference", b"x" * 65, "65 bytes"),
    ("command_reference", b"learn" * 10000, "50000 bytes"),
    ("command_direction", b"up", "unknown direction 'up'; send one of cw, ccw"),
    ("command_direction", b"not  set", "unknown direction"),
    ("command_direction", "lëarn\u202e".encode(), "unknown direction"),
    ("state", b"learn", "not a command topic"),
])
def test_bad_and_hostile_commands_are_refused_with_the_value_and_the_fix(topic_key, payload,
                                                                         match):
    t = M.Topics.for_config(cfg_with())
    with pytest.raises(M.CommandError, match=re.escape(match) if "'" in match else match):
        M.parse_command(t, getattr(t, topic_key), payload)


def test_every_stats_key_is_documented():
    """docs/mqtt.md's stats table names every key the runner sends (and no other)."""
    from pathlib import Path

    from bladesonar.service.notify import NullNotifier
    from bladesonar.service.runner import Service

    def unused(*_a):
        raise AssertionError("not started in this test")

    svc = Service(cfg_with(), config_path=None, audio_factory=unused,
                  publisher_factory=unused, analyzer_factory=unused, reference_loader=unused,
                  notifier=NullNotifier())
    sent = set(M.stats_payload(svc.stats(0.0), extra={"reconnects": 0,
                                                      "dropped_events": 0}))
    doc = (Path(__file__).resolve().parents[1] / "docs" / "mqtt.md").read_text()
    table = doc[doc.index("### stats"):doc.index("## Commands")]
    documented = set()
    for line in table.splitlines():
        if line.startswith("| `"):
            documented |= set(re.findall(r"`([a-z_]+)`", line.split("|")[1]))
    assert sent == documented, (sent - documented, documented - sent)
