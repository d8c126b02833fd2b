"""MQTT chores of tools/ha_check, run with the project's own venv (paho, bladesonar).

    ha_mqtt.py legacy --port P --device-id D --device-name N
        publish the per-entity discovery configs an earlier version of the daemon left
        retained (one per entity and device trigger: what a migration starts from)
    ha_mqtt.py retained --port P
        print the retained topics under homeassistant/# and bladesonar/# as JSON
"""

from __future__ import annotations

import argparse
import json
import time

import paho.mqtt.client as mqtt

from bladesonar import config
from bladesonar.service import messages as M


def client(port: int) -> mqtt.Client:
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    c.connect("127.0.0.1", port)
    c.loop_start()
    return c


def legacy(port: int, device_id: str, device_name: str) -> None:
    cfg = config.from_mapping({"device_id": device_id, "mqtt": {"device_name": device_name}})
    topics = M.Topics.for_config(cfg)
    dev = M.device_config(cfg, topics)
    c = client(port)
    infos = []
    for oid, comp in dev["cmps"].items():
        conf = {k: v for k, v in comp.items() if k != "p"}
        conf["device"], conf["origin"] = dev["dev"], {"name": "bladesonar",
                                                      "sw_version": "0.1.0"}
        infos.append(c.publish(M.legacy_topic(topics, comp["p"], oid), json.dumps(conf),
                               qos=1, retain=True))
    for info in infos:
        info.wait_for_publish(10)
    c.disconnect()
    c.loop_stop()
    print(json.dumps({"published": len(infos)}))


def retained(port: int) -> None:
    got: dict[str, int] = {}
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    c.on_message = lambda cl, u, m: got.__setitem__(m.topic, len(m.payload)) \
        if m.retain else None
    c.connect("127.0.0.1", port)
    c.subscribe([("homeassistant/#", 0), ("bladesonar/#", 0)])
    c.loop_start()
    time.sleep(1.0)
    c.disconnect()
    c.loop_stop()
    print(json.dumps(sorted(t for t, n in got.items() if n)))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=("legacy", "retained"))
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--device-id", default="hacheck")
    ap.add_argument("--device-name", default="Hacheck fan")
    a = ap.parse_args()
    if a.what == "legacy":
        legacy(a.port, a.device_id, a.device_name)
    else:
        retained(a.port)


if __name__ == "__main__":
    main()
