"""messages.py: topic names, payloads and discovery configs against fixed expectations."""

from __future__ import annotations

import datetime as dt
import json
import math
import re

import numpy as np
import pytest

from bladesonar import __version__, config
from bladesonar.dsp.decide import Decision
from bladesonar.service import messages as M

T0 = 1_700_000_000.25  # 2023-11-14T22:13:20.250Z


def cfg_with(**mqtt):
    return config.from_mapping({"device_id": "fan-1", "mqtt": mqtt})


def live_estimate() -> dict:
    """What LiveAnalyzer.estimate() returns: Decision.as_dict() plus the live fields."""
    d = Decision("reversed", "cw", -0.70069, 0.35036, 21.021, 0.9718,
                 "relative rate -0.7007 +- 0.0208", rate_state="changing",
                 rate_change_hz_s=-0.04512).as_dict()
    d.update(rotating=True, window_s=4.0, reference="0123456789ab")
    return d


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
    p = M.state_payload(live_estimate(), t=T0)
    assert list(p) == [*M.STATE_KEYS, "reason", "time"]
    assert p == {
        "direction": "reversed", "rotation": "cw", "rotating": True, "rate_hz": 0.35036,
        "rpm": 21.021, "relative_rate": -0.70069, "rate_state": "changing",
        "rate_change_hz_s": -0.0451, "confidence": 0.9718, "window_s": 4.0,
        "reference": "0123456789ab", "status": "ok",
        "reason": "relative rate -0.7007 +- 0.0208", "time": "2023-11-14T22:13:20.250+00:00"}


def test_state_payload_fills_missing_keys_with_null_and_keeps_status():
    p = M.state_payload({"direction": "unknown", "rate_hz": math.nan,
                         "status": "reference_missing"}, t=T0)
    assert p["rate_hz"] is None and p["rotation"] is None and p["window_s"] is None
    assert p["status"] == "reference_missing"
    assert set(M.STATE_KEYS) <= set(p)


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

TOPIC_RE = re.compile(r"homeassistant/(sensor|binary_sensor)/fan-1/([a-zA-Z0-9_-]+)/config")


def discovery(**mqtt):
    return {m.topic: m for m in M.discovery_messages(cfg_with(**mqtt))}


def test_discovery_topics_ids_and_availability():
    msgs = discovery()
    t = M.Topics.for_config(cfg_with())
    ids = set()
    for topic, m in msgs.items():
        assert TOPIC_RE.fullmatch(topic), topic
        assert m.retain and m.qos == 1
        c = json.loads(m.encode())
        assert c["unique_id"] == f"bladesonar_fan-1_{TOPIC_RE.fullmatch(topic).group(2)}"
        ids.add(c["unique_id"])
        assert c["availability_topic"] == t.availability
        assert (c["payload_available"], c["payload_not_available"]) == ("online", "offline")
        assert c["state_topic"] in (t.state, t.stats)
        assert c["device"] == {"identifiers": ["bladesonar_fan-1"], "name": "fan-1",
                               "manufacturer": "bladesonar",
                               "model": "Pulsed-sonar rotation sensor",
                               "sw_version": __version__}
        assert c["origin"]["name"] == "bladesonar"
    assert len(ids) == len(msgs)


def test_discovery_entities():
    c = {TOPIC_RE.fullmatch(t).group(2): json.loads(m.encode()) for t, m in discovery().items()}
    assert {"rate", "rpm", "direction", "confidence", "rotating", "xruns",
            "dropped_pulses"} <= set(c)
    rate = c["rate"]
    assert (rate["device_class"], rate["unit_of_measurement"], rate["state_class"]) == \
        ("frequency", "Hz", "measurement")
    assert (c["rpm"]["unit_of_measurement"], c["rpm"]["state_class"]) == ("rpm", "measurement")
    assert c["direction"]["device_class"] == "enum"
    assert c["direction"]["options"] == ["same", "reversed", "stopped", "unknown"]
    assert c["rotation"]["options"] == ["cw", "ccw", "none"]
    assert c["xruns"]["entity_category"] == "diagnostic"
    assert c["dropped_pulses"]["entity_category"] == "diagnostic"
    assert "entity_category" not in rate
    rot = c["rotating"]
    assert (rot["payload_on"], rot["payload_off"]) == ("ON", "OFF")
    assert "ON" in rot["value_template"] and "OFF" in rot["value_template"]


def test_value_templates_read_keys_the_payloads_have():
    t = M.Topics.for_config(cfg_with())
    state_keys = set(M.state_payload(live_estimate()))
    stats_keys = {"uptime_s", "cpu_share", "pulses_processed", "dropped_pulses", "xruns",
                  "reconnects", "dropped_events"}  # what runner.Service.stats() builds
    for m in discovery().values():
        c = m.payload
        used = set(re.findall(r"value_json\.(\w+)", c["value_template"]))
        assert used, c["value_template"]
        assert used <= (state_keys if c["state_topic"] == t.state else stats_keys), c
        # balanced Jinja delimiters
        tpl = c["value_template"]
        assert tpl.count("{{") == tpl.count("}}") and tpl.count("{%") == tpl.count("%}")


def test_discovery_follows_the_prefixes():
    msgs = discovery(discovery_prefix="ha", topic_prefix="home")
    assert all(t.startswith("ha/") for t in msgs)
    assert all(m.payload["availability_topic"] == "home/fan-1/availability"
               for m in msgs.values())
