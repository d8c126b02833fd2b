"""The end-to-end check against a real Home Assistant (run by tools/ha_check, with the
Python of Home Assistant's own venv: it uses aiohttp from there).

Everything listens on 127.0.0.1 only; every process started here is stopped at the end.
Prints what Home Assistant made and one line per check (PASS/FAIL); exit status 1 if any
check failed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import aiohttp

DEVICE = "hacheck"
BASE = f"bladesonar/{DEVICE}"
RESULTS: list[tuple[bool, str]] = []


def check(ok: bool, what: str) -> bool:
    RESULTS.append((bool(ok), what))
    print(f"{'PASS' if ok else 'FAIL'}  {what}", flush=True)
    return bool(ok)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def mosquitto_exe() -> str:
    for c in (shutil.which("mosquitto"), "/usr/sbin/mosquitto"):
        if c and os.access(c, os.X_OK):
            return c
    sys.exit("ha_check: mosquitto not found (tools/setup installs it)")


class Proc:
    """A child process with its log; stopped by pid, never by name."""

    def __init__(self, name: str, cmd: list[str], log: Path, **kw) -> None:
        self.name, self.cmd, self.log, self.kw = name, cmd, log, kw
        self.p: subprocess.Popen | None = None

    def start(self) -> Proc:
        self.p = subprocess.Popen(self.cmd, stdout=open(self.log, "ab"),
                                  stderr=subprocess.STDOUT, **self.kw)
        return self

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> None:
        if self.p is None or self.p.poll() is not None:
            return
        self.p.send_signal(sig)
        try:
            self.p.wait(timeout)
        except subprocess.TimeoutExpired:
            self.p.kill()
            self.p.wait()


async def wait_for(pred, timeout: float, step: float = 0.2):
    end = time.monotonic() + timeout
    while True:
        v = await pred()
        if v:
            return v
        if time.monotonic() > end:
            return v
        await asyncio.sleep(step)


class HA:
    def __init__(self, session: aiohttp.ClientSession, port: int) -> None:
        self.s, self.url = session, f"http://127.0.0.1:{port}"
        self.token = ""
        self._id = 0

    @property
    def h(self) -> dict:
        return {"Authorization": f"Bearer {self.token}"}

    async def up(self) -> bool:
        try:
            async with self.s.get(f"{self.url}/api/onboarding") as r:
                return r.status < 500
        except aiohttp.ClientError:
            return False

    async def onboard(self) -> None:
        cid = f"{self.url}/"
        async with self.s.post(f"{self.url}/api/onboarding/users", json={
                "client_id": cid, "name": "Check", "username": "check",
                "password": "check-password-1", "language": "en"}) as r:
            code = (await r.json())["auth_code"]
        async with self.s.post(f"{self.url}/auth/token", data={
                "grant_type": "authorization_code", "code": code, "client_id": cid}) as r:
            self.token = (await r.json())["access_token"]
        for step, body in (("core_config", {}), ("analytics", {}),
                           ("integration", {"client_id": cid, "redirect_uri": cid})):
            async with self.s.post(f"{self.url}/api/onboarding/{step}", json=body,
                                   headers=self.h) as r:
                await r.read()

    async def login(self) -> None:
        """A token again after a restart (the refresh token is not kept here: log in)."""
        cid = f"{self.url}/"
        async with self.s.post(f"{self.url}/auth/login_flow", json={
                "client_id": cid, "handler": ["homeassistant", None],
                "redirect_uri": cid}) as r:
            flow = await r.json()
        async with self.s.post(f"{self.url}/auth/login_flow/{flow['flow_id']}", json={
                "client_id": cid, "username": "check", "password": "check-password-1"}) as r:
            code = (await r.json())["result"]
        async with self.s.post(f"{self.url}/auth/token", data={
                "grant_type": "authorization_code", "code": code, "client_id": cid}) as r:
            self.token = (await r.json())["access_token"]

    async def add_mqtt(self, port: int) -> dict:
        async with self.s.post(f"{self.url}/api/config/config_entries/flow",
                               json={"handler": "mqtt"}, headers=self.h) as r:
            flow = await r.json()
        async with self.s.post(f"{self.url}/api/config/config_entries/flow/{flow['flow_id']}",
                               json={"broker": "127.0.0.1", "port": port},
                               headers=self.h) as r:
            return await r.json()

    async def states(self) -> list[dict]:
        async with self.s.get(f"{self.url}/api/states", headers=self.h) as r:
            return await r.json() if r.status == 200 else []

    async def service(self, domain: str, name: str, data: dict) -> int:
        async with self.s.post(f"{self.url}/api/services/{domain}/{name}", json=data,
                               headers=self.h) as r:
            await r.read()
            return r.status

    async def ws(self, *msgs: dict) -> list[dict]:
        async with self.s.ws_connect(f"{self.url}/api/websocket") as w:
            await w.receive_json()
            await w.send_json({"type": "auth", "access_token": self.token})
            await w.receive_json()
            out = []
            for m in msgs:
                self._id += 1
                await w.send_json({"id": self._id, **m})
                while True:
                    got = await w.receive_json()
                    if got.get("id") == self._id and got.get("type") == "result":
                        out.append(got)
                        break
            return out


def ours(states: list[dict]) -> dict[str, dict]:
    return {s["entity_id"]: s for s in states if f"{DEVICE}" in s["entity_id"]
            or s["attributes"].get("friendly_name", "").startswith("Hacheck")}


def table(states: dict[str, dict]) -> str:
    rows = [("entity", "state", "unit", "device class")]
    for eid in sorted(states):
        a = states[eid]["attributes"]
        rows.append((eid, str(states[eid]["state"])[:32], a.get("unit_of_measurement", ""),
                     a.get("device_class", "")))
    w = [max(len(r[i]) for r in rows) for i in range(4)]
    return "\n".join("  ".join(c.ljust(w[i]) for i, c in enumerate(r)).rstrip() for r in rows)


async def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repo", required=True)
    ap.add_argument("--hass", required=True)
    ap.add_argument("--keep", action="store_true", help="keep the work folder")
    a = ap.parse_args()
    repo = Path(a.repo)
    work = Path(tempfile.mkdtemp(prefix="bladesonar-ha-"))
    print(f"work folder {work}", flush=True)
    mport, hport = free_port(), free_port()
    (work / "mosquitto.conf").write_text(
        f"listener {mport} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    broker = Proc("mosquitto", [mosquitto_exe(), "-c", str(work / "mosquitto.conf")],
                  work / "mosquitto.log").start()
    conf = work / "ha"
    conf.mkdir()
    (conf / "configuration.yaml").write_text(f"""\
http:
  server_host: 127.0.0.1
  server_port: {hport}
api:
websocket_api:
config:
onboarding:
auth:
person:
device_automation:
logger:
  default: warning
  logs:
    homeassistant.components.mqtt.discovery: debug
""")
    hass = Proc("hass", [a.hass, "-c", str(conf)], work / "hass.out").start()
    state_dir = work / "state"
    cfg = work / "bladesonar.yaml"
    cfg.write_text(json.dumps({
        "device_id": DEVICE,
        "audio": {"backend": "sim"},
        # the fan turns ccw, is reversed through zero from 75 s (over 6 s), and so on
        "sim": {"scene": str(repo / "config/scenes/paper-room.yaml"),
                "schedule": "ccw:0.45:75,cw:0.45:45~6,ccw:0.45:600~6", "realtime": True,
                "seed": 5},
        "daemon": {"state_dir": str(state_dir), "window_s": 4},
        "mqtt": {"host": "127.0.0.1", "port": mport, "publish_interval_s": 5,
                 "stats_interval_s": 30, "device_name": "Hacheck fan"},
        "reference": {"learn_seconds": 12},
    }))
    bs = str(repo / ".venv/bin/bladesonar")
    daemon = Proc("daemon", [bs, "run", "--config", str(cfg)], work / "daemon.log")
    procs = [daemon, hass, broker]
    t0 = time.monotonic()
    try:
        async with aiohttp.ClientSession() as s:
            ha = HA(s, hport)
            if not check(await wait_for(ha.up, 180, 1.0), "Home Assistant answers on 127.0.0.1"):
                return 1
            await ha.onboard()
            res = await ha.add_mqtt(mport)
            check(res.get("type") == "create_entry", f"MQTT integration added ({res.get('type')})")
            daemon.start()
            t_daemon = time.monotonic()

            async def entities(n):
                st = ours(await ha.states())
                return st if len(st) >= n else None

            got = await wait_for(lambda: entities(18), 60, 0.5)
            st = ours(await ha.states())
            check(got is not None, f"{len(st)} entities of the device in Home Assistant "
                                   "(18 expected)")
            # zero-config: learning, then a reference and tracking
            status = "sensor.hacheck_fan_status"
            learning = await wait_for(lambda: _state_is(ha, status, "learning"), 30)
            check(bool(learning), "Status shows learning (no reference on the device)")
            ok = await wait_for(lambda: _state_is(ha, status, "ok"), 90, 0.5)
            check(bool(ok), f"Status ok after learning by itself "
                            f"({time.monotonic() - t_daemon:.0f} s after the daemon started)")
            await asyncio.sleep(6)
            st = ours(await ha.states())
            print("\nWhat Home Assistant shows (zero-config reference, direction not set):")
            print(table(st), flush=True)
            rot = st.get("sensor.hacheck_fan_rotation", {}).get("state")
            check(rot == "unknown", f"Rotation is HA's unknown while the reference's "
                                    f"direction is not set ({rot})")
            rel = st.get("sensor.hacheck_fan_direction_to_reference", {}).get("state")
            check(rel == "same", f"Direction to reference: same ({rel})")
            check(all(s["state"] != "unavailable" for s in st.values()),
                  "no entity unavailable while the daemon runs")
            # device triggers for the event entities
            dev = [d for d in (await ha.ws({"type": "config/device_registry/list"}))[0]
                   ["result"] if d.get("name") == "Hacheck fan"]
            check(len(dev) == 1, "one device named 'Hacheck fan'")
            if dev:
                trig = (await ha.ws({"type": "device_automation/trigger/list",
                                     "device_id": dev[0]["id"]}))[0]["result"]
                kinds = sorted({(t.get("type"), t.get("subtype")) for t in trig
                                if t.get("domain") == "mqtt"})
                print(f"\nMQTT device triggers of the device: {kinds}")
                check({k[0] for k in kinds} >= {"started", "stopped", "reversed"},
                      "device triggers started, stopped, reversed")
            # the select: the reference's direction
            code = await ha.service("select", "select_option", {
                "entity_id": "select.hacheck_fan_reference_direction",
                "option": "counterclockwise"})
            ccw = await wait_for(lambda: _state_is(ha, "sensor.hacheck_fan_rotation",
                                                   "counterclockwise"), 30)
            check(code == 200 and bool(ccw),
                  "select Reference direction = counterclockwise -> Rotation counterclockwise")
            # the reversal at 75 s (daemon time): the Motion event entity fires
            left = 75 + 30 - (time.monotonic() - t_daemon)
            ev = await wait_for(lambda: _event_type(ha, "event.hacheck_fan_motion",
                                                    "reversed"), max(left, 5), 0.5)
            check(bool(ev), "Motion event entity fired 'reversed' on the simulated reversal")
            cw = await wait_for(lambda: _state_is(ha, "sensor.hacheck_fan_rotation",
                                                  "clockwise"), 20)
            check(bool(cw), "Rotation clockwise after the reversal")
            # the Learn button: a new reference learned live, tracking goes on
            old_ref = (await _attr(ha, status, "reference"))
            code = await ha.service("button", "press",
                                    {"entity_id": "button.hacheck_fan_learn_reference"})
            learned = await wait_for(lambda: _event_type(ha, "event.hacheck_fan_reference",
                                                         "learned"), 60, 0.5)
            new_ref = await wait_for(lambda: _attr_changed(ha, status, "reference", old_ref),
                                     30)
            check(code == 200 and bool(learned) and bool(new_ref),
                  f"Learn reference button: event 'learned', reference {old_ref} -> {new_ref}")
            same = await wait_for(lambda: _state_is(
                ha, "sensor.hacheck_fan_direction_to_reference", "same"), 30)
            ok = await wait_for(lambda: _state_is(ha, "sensor.hacheck_fan_rotation",
                                                  "clockwise"), 30)
            sel = await wait_for(lambda: _state_is(
                ha, "select.hacheck_fan_reference_direction", "clockwise"), 10)
            check(bool(same) and bool(ok) and bool(sel),
                  "the learned reference tracks: Direction to reference same, Rotation "
                  "clockwise, Reference direction clockwise (taken from the estimates "
                  "during the recording)")
            st = ours(await ha.states())
            print("\nWhat Home Assistant shows after the reversal and the Learn button:")
            print(table(st), flush=True)
            # kill -9: unavailable within 2 s (the last will)
            daemon.stop(signal.SIGKILL)
            t_kill = time.monotonic()
            un = await wait_for(lambda: _state_is(ha, "sensor.hacheck_fan_rotation",
                                                  "unavailable"), 10, 0.02)
            check(bool(un) and time.monotonic() - t_kill < 2.0,
                  f"kill -9: unavailable after {time.monotonic() - t_kill:.2f} s")
            # restart: no previous run's values shown as current
            daemon.start()
            t_re = time.monotonic()
            back = await wait_for(lambda: _available(ha, "sensor.hacheck_fan_status"), 30,
                                  0.05)
            first = await ha.states()
            rot = next((s["state"] for s in first if s["entity_id"] ==
                        "sensor.hacheck_fan_rotation"), None)
            check(bool(back) and rot in ("unknown", "clockwise"),
                  f"daemon restart: available again after {time.monotonic() - t_re:.1f} s, "
                  f"Rotation at that moment: {rot}")
            stt = next((s["state"] for s in first if s["entity_id"] == status), None)
            check(stt in ("starting", "ok"), f"Status right after the restart: {stt}")
            # broker restart
            broker.stop()
            await asyncio.sleep(2)
            broker.start()
            back = await wait_for(lambda: _state_is(ha, status, "ok"), 60, 0.5)
            check(bool(back), "broker restart: Status ok again")
            # HA restart
            hass.stop()
            hass.start()
            await wait_for(ha.up, 120, 1.0)
            await asyncio.sleep(3)
            await ha.login()
            back = await wait_for(lambda: _state_is(ha, status, "ok"), 60, 0.5)
            check(bool(back), "Home Assistant restart: Status ok again")
    finally:
        for p in procs:
            p.stop()
        log = (conf / "home-assistant.log").read_text(errors="replace") \
            if (conf / "home-assistant.log").exists() else ""
        bad = [ln for ln in log.splitlines()
               if ("WARNING" in ln or "ERROR" in ln) and "mqtt" in ln.lower()]
        check(not bad, f"no MQTT warning or error in Home Assistant's log ({len(bad)})")
        for ln in bad[:10]:
            print("   ", ln[:240])
        print(f"\n{sum(ok for ok, _ in RESULTS)} passed, "
              f"{sum(not ok for ok, _ in RESULTS)} failed "
              f"({time.monotonic() - t0:.0f} s)")
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
    return 0 if all(ok for ok, _ in RESULTS) else 1


async def _get(ha: HA, eid: str) -> dict | None:
    return next((s for s in await ha.states() if s["entity_id"] == eid), None)


async def _state_is(ha: HA, eid: str, want: str):
    s = await _get(ha, eid)
    return s is not None and s["state"] == want


async def _available(ha: HA, eid: str):
    s = await _get(ha, eid)
    return s is not None and s["state"] != "unavailable"


async def _attr(ha: HA, eid: str, key: str):
    s = await _get(ha, eid)
    return None if s is None else s["attributes"].get(key)


async def _attr_changed(ha: HA, eid: str, key: str, old):
    v = await _attr(ha, eid, key)
    return v if v and v != old else None


async def _event_type(ha: HA, eid: str, want: str):
    s = await _get(ha, eid)
    return s is not None and s["attributes"].get("event_type") == want


if __name__ == "__main__":
    sys.exit(asyncio.run(main()))
