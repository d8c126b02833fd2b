"""The end-to-end check against a real Home Assistant (run by tools/ha_check, with the
Python of Home Assistant's own venv: it uses aiohttp from there; MQTT chores go through
tools/ha_mqtt.py in the project's venv).

A day of a fan as Home Assistant sees it: discovery migrated from the per-entity configs
of an earlier version, zero-config learning, the direction select, a speed ramp, a
reversal, a stop and a start (the exact sequence of Running, Speed and Fan events
asserted at each), a daemon restart with the reference kept, Forget and Learn from the
buttons, the config entities (checked, persisted across a restart), kill -9, broker and
Home Assistant restarts, and every Home Assistant log file (rotated ones too) free of any
MQTT or bladesonar warning.

Everything listens on 127.0.0.1 only; every process started here is stopped at the end
(by pid). Prints what Home Assistant made and one line per check (PASS/FAIL); exit
status 1 if any check failed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
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
NAME = "Hacheck fan"
RESULTS: list[tuple[bool, str]] = []
#: Start Home Assistant with only its interpreter version check skipped (2026.x wants a
#: newer Python 3.13 than pyenv's 3.13.0; nothing of Home Assistant is changed)
SKIP_PYTHON_CHECK = ("import sys, homeassistant.__main__ as m; m.validate_python = "
                     "lambda: None; sys.argv[0] = 'hass'; sys.exit(m.main())")
#: The simulated fan of the first run (seconds from the daemon's start): ccw 0.45 Hz,
#: slowed to 0.3 Hz over 35-40 s, reversed through zero over 50-58 s (zero at 53.4 s),
#: spun down to rest over 80-86 s, started cw again over 100-105 s
DAY = "ccw:0.45:35,ccw:0.3:15~5,cw:0.4:30~8,stop:0:20~6,cw:0.4:600~5"
T_REVERSAL, T_STOP, T_START = 53.4, 86.0, 100.0
#: after the restart: a steady fan (Forget and Learn need one)
STEADY = "ccw:0.45:600"


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
        #: (monotonic time, entity_id, state, event_type) of every state change seen
        self.timeline: list[tuple[float, str, str, str | None]] = []
        self._watch: asyncio.Task | None = None

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
        try:
            async with self.s.get(f"{self.url}/api/states", headers=self.h) as r:
                return await r.json() if r.status == 200 else []
        except aiohttp.ClientError:
            return []

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

    def watch(self) -> None:
        """Record every state change from now on (a websocket subscription)."""
        self._watch = asyncio.create_task(self._record())

    async def _record(self) -> None:
        while True:
            try:
                async with self.s.ws_connect(f"{self.url}/api/websocket") as w:
                    await w.receive_json()
                    await w.send_json({"type": "auth", "access_token": self.token})
                    await w.receive_json()
                    await w.send_json({"id": 1, "type": "subscribe_events",
                                       "event_type": "state_changed"})
                    async for msg in w:
                        if msg.type != aiohttp.WSMsgType.TEXT:
                            break
                        ev = json.loads(msg.data)
                        if ev.get("type") != "event":
                            continue
                        d = ev["event"]["data"]
                        new = d.get("new_state") or {}
                        self.timeline.append((time.monotonic(), d["entity_id"],
                                              str(new.get("state")),
                                              (new.get("attributes") or {}).get(
                                                  "event_type")))
            except (aiohttp.ClientError, TimeoutError, ConnectionError):
                pass
            await asyncio.sleep(1.0)     # Home Assistant restarting: subscribe again

    def changes(self, eid: str, t0: float = 0.0, t1: float = float("inf")) -> list[str]:
        """The states ``eid`` went through in [t0, t1] (the one it had at t0 first),
        repeats merged; for an event entity: the event types fired in [t0, t1]."""
        out: list[str] = []
        before = [st for t, e, st, _ in self.timeline if e == eid and t < t0]
        if before and not eid.startswith("event."):
            out.append(before[-1])
        for t, e, st, et in self.timeline:
            if e != eid or not t0 <= t <= t1:
                continue
            v = (et or st) if eid.startswith("event.") and st not in ("unavailable",
                                                                       "unknown") else st
            if not out or out[-1] != v or eid.startswith("event."):
                out.append(v)
        return out


def kind(v: str) -> str:
    """A Speed state as a class: N (turning), 0 (stopped), U (unknown), X (unavailable)."""
    if v == "unknown":
        return "U"
    if v == "unavailable":
        return "X"
    try:
        return "0" if float(v) == 0.0 else "N"
    except ValueError:
        return f"?{v}"


def merged(xs: list[str]) -> list[str]:
    out: list[str] = []
    for x in xs:
        if not out or out[-1] != x:
            out.append(x)
    return out


def table(states: dict[str, dict]) -> str:
    rows = [("entity", "name", "state", "unit")]
    for x in sorted(states.values(), key=lambda x: x["entity_id"]):
        a = x["attributes"]
        rows.append((x["entity_id"], a.get("friendly_name", "").removeprefix(f"{NAME} "),
                     str(x["state"])[:32], a.get("unit_of_measurement", "")))
    w = [max(len(r[i]) for r in rows) for i in range(4)]
    return "\n".join("  ".join(c.ljust(w[i]) for i, c in enumerate(r)).rstrip() for r in rows)


#: What Home Assistant's MQTT client logs when the broker goes away (the check stops it)
BROKER_GONE = re.compile(r"failed to receive on socket|connection was lost|"
                         r"Disconnected from MQTT server")


def log_problems(conf: Path, broker_down: list[tuple[float, float]]
                 ) -> tuple[list[str], list[str], list[str]]:
    """(log files read, WARNING/ERROR lines about MQTT or bladesonar in any of them,
    those among them that only say the broker was gone while the check had stopped it:
    within 2 s of such a stretch, ``broker_down`` as time.time() pairs)."""
    import datetime as dt

    files = sorted(conf.glob("home-assistant.log*"))
    bad, expected = [], []
    for f in files:
        for ln in f.read_text(errors="replace").splitlines():
            if not (re.search(r"\b(WARNING|ERROR|CRITICAL)\b", ln)
                    and re.search(r"mqtt|bladesonar|hacheck", ln, re.IGNORECASE)):
                continue
            try:
                t = dt.datetime.strptime(ln[:23], "%Y-%m-%d %H:%M:%S.%f").timestamp()
            except ValueError:
                t = None
            if BROKER_GONE.search(ln) and t is not None and \
                    any(a - 2 <= t <= b + 2 for a, b in broker_down):
                expected.append(f"{f.name}: {ln}")
            else:
                bad.append(f"{f.name}: {ln}")
    return [f.name for f in files], bad, expected


async def main() -> int:  # noqa: C901 - one day, in order
    ap = argparse.ArgumentParser()
    ap.add_argument("--repo", required=True)
    ap.add_argument("--skip-python-check", action="store_true",
                    help="start Home Assistant with its interpreter version check skipped")
    ap.add_argument("--keep", action="store_true", help="keep the work folder")
    a = ap.parse_args()
    repo = Path(a.repo)
    from homeassistant.const import __version__ as ha_version

    skipped = (" (its start-up Python version check skipped: nothing else changed)"
               if a.skip_python_check else "")
    print(f"Home Assistant {ha_version} on Python {sys.version.split()[0]}{skipped}",
          flush=True)
    work = Path(tempfile.mkdtemp(prefix="bladesonar-ha-"))
    print(f"work folder {work}", flush=True)
    mport, hport = free_port(), free_port()
    (work / "mosquitto.conf").write_text(
        f"listener {mport} 127.0.0.1\nallow_anonymous true\npersistence true\n"
        f"persistence_location {work}/\n")
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
    hass_cmd = [sys.executable, "-c", SKIP_PYTHON_CHECK, "-c", str(conf)] \
        if a.skip_python_check else [str(Path(sys.executable).parent / "hass"), "-c", str(conf)]
    hass = Proc("hass", hass_cmd, work / "hass.out").start()
    state_dir = work / "state"
    cfg = work / "bladesonar.yaml"

    def write_cfg(schedule: str) -> None:
        cfg.write_text(json.dumps({
            "device_id": DEVICE, "audio": {"backend": "sim"},
            "sim": {"scene": str(repo / "config/scenes/paper-room.yaml"),
                    "schedule": schedule, "realtime": True, "seed": 5},
            "daemon": {"state_dir": str(state_dir), "window_s": 4},
            "mqtt": {"host": "127.0.0.1", "port": mport, "publish_interval_s": 5,
                     "stats_interval_s": 10, "device_name": NAME},
            "reference": {"learn_seconds": 12}}))

    venv_py = str(repo / ".venv/bin/python")

    def mqtt_tool(*args: str) -> object:
        out = subprocess.run([venv_py, str(repo / "tools/ha_mqtt.py"), *args, "--port",
                              str(mport), "--device-id", DEVICE, "--device-name", NAME],
                             capture_output=True, text=True, timeout=60, check=True)
        return json.loads(out.stdout)

    bs = str(repo / ".venv/bin/bladesonar")
    daemon = Proc("daemon", [bs, "run", "--config", str(cfg)], work / "daemon.log")
    procs = [daemon, hass, broker]
    broker_down: list[tuple[float, float]] = []
    t0 = time.monotonic()
    try:
        async with aiohttp.ClientSession() as s:
            ha = HA(s, hport)
            if not check(await wait_for(ha.up, 240, 1.0), "Home Assistant answers on 127.0.0.1"):
                return 1
            await ha.onboard()
            res = await ha.add_mqtt(mport)
            check(res.get("type") == "create_entry", f"MQTT integration added ({res.get('type')})")
            ha.watch()

            async def registry() -> dict[str, dict]:
                """unique_id -> registry entry, ours only."""
                got = (await ha.ws({"type": "config/entity_registry/list"}))[0]["result"]
                return {e["unique_id"]: e for e in got
                        if str(e.get("unique_id", "")).startswith(f"bladesonar_{DEVICE}_")}

            # 0. what an earlier version left: per-entity configs; Home Assistant makes them
            n_old = mqtt_tool("legacy")["published"]
            old = await wait_for(lambda: _count(registry, n_old - 3), 60, 0.5)
            reg0 = await registry()
            check(bool(old), f"earlier version's per-entity discovery: {len(reg0)} entities "
                             f"(+3 device triggers) made from {n_old} retained configs")
            ids0 = {u: e["entity_id"] for u, e in reg0.items()}
            # 1. the daemon: the device config takes them over
            write_cfg(DAY)
            daemon.start()
            t_d = time.monotonic()
            eid: dict[str, str] = {}

            async def ours():
                st = {x["entity_id"]: x for x in await ha.states()}
                return {k: st[v] for k, v in eid.items() if v in st}

            learning = await wait_for(lambda: _status_is(ha, registry, eid, "Learning"), 40)
            reg = await registry()
            eid.update({u.removeprefix(f"bladesonar_{DEVICE}_"): e["entity_id"]
                        for u, e in reg.items()})
            check(len(reg) == len(reg0) and all(ids0.get(u) == e["entity_id"]
                                                for u, e in reg.items() if u in ids0),
                  f"migration to the device config: {len(reg)} entities, none duplicated, "
                  f"every entity id kept ({len([u for u in reg if u in ids0])} of "
                  f"{len(ids0)} old ones)")
            left = mqtt_tool("retained")
            per_entity = rf"homeassistant/[^/]+/{DEVICE}/[^/]+/config$"
            check(not [x for x in left if re.match(per_entity, x)]
                  and f"homeassistant/device/{DEVICE}/config" in left,
                  "the broker keeps only the device config (old per-entity topics cleared)")
            dev = [d for d in (await ha.ws({"type": "config/device_registry/list"}))[0]
                   ["result"] if d.get("name") == NAME]
            check(len(dev) == 1, f"one device named '{NAME}'")
            check(bool(learning), "Status: Learning (no reference on the device)")
            ok = await wait_for(lambda: _state_is(ha, eid["status"], "Direction not set"), 60,
                                0.5)
            check(bool(ok), f"Status 'Direction not set' once learned by itself "
                            f"({time.monotonic() - t_d:.0f} s after the daemon started)")
            await wait_for(lambda: _state_is(ha, eid["direction"], "same"), 30)
            st = await ours()
            check(st["rotation"]["state"] == "unknown" and st["direction"]["state"] == "same",
                  f"Rotation unknown, Direction to reference same, while the direction is "
                  f"not set ({st['rotation']['state']}, {st['direction']['state']})")
            af = st.get("airflow")
            check(af is not None and af["state"] == "unknown"
                  and af["attributes"].get("options") == ["Down (summer)", "Up (winter)"],
                  f"Airflow made (enum Down (summer) / Up (winter)) and unknown over the 2-D "
                  f"room's flat blades ({af['state'] if af else 'missing'})")
            if dev:
                trig = (await ha.ws({"type": "device_automation/trigger/list",
                                     "device_id": dev[0]["id"]}))[0]["result"]
                kinds = sorted({(t.get("type"), t.get("subtype")) for t in trig
                                if t.get("domain") == "mqtt"})
                check({k[0] for k in kinds} == {"started", "stopped", "reversed"},
                      f"device triggers {kinds}")
            code = await ha.service("select", "select_option", {
                "entity_id": eid["reference_direction"], "option": "counterclockwise"})
            ccw = await wait_for(lambda: _state_is(ha, eid["rotation"], "counterclockwise"), 30)
            okst = await wait_for(lambda: _state_is(ha, eid["status"], "OK"), 10)
            check(code == 200 and bool(ccw) and bool(okst),
                  "select Reference direction = counterclockwise -> Rotation "
                  "counterclockwise, Status OK")
            st = await ours()
            print(f"\nWhat Home Assistant {ha_version} shows (reference learned by itself, "
                  "direction chosen):")
            print(table(st), flush=True)
            check(st["confidence"]["state"] not in ("0", "0.0", "unknown"),
                  f"Confidence at start: {st['confidence']['state']} %")
            # 2. the day: ramp, reversal, stop, start
            await asyncio.sleep(max(T_START + 12 - (time.monotonic() - t_d), 0))
            tr = lambda t: t_d + t  # noqa: E731 - daemon time -> monotonic time
            run = merged(ha.changes(eid["rotating"], t_d, tr(T_START + 12)))
            first_on = run.index("on") if "on" in run else len(run)
            check(run[first_on:] == ["on", "off", "on"] and run[first_on - 1:first_on] ==
                  ["unknown"],
                  f"Running through the day: {run} (unknown until the first answer, on "
                  "through the ramp and the reversal, off at the confirmed stop, on at the "
                  "start)")
            evs = [v for v in ha.changes(eid["motion"], tr(30), tr(T_START + 12))]
            check(evs == ["reversed", "stopped", "started"],
                  f"Fan events through the day: {evs}")
            at = lambda e, a_, b_: merged([kind(v) for v in ha.changes(  # noqa: E731
                eid[e], tr(a_), tr(b_))])
            ramp = at("rpm", 33, 45)
            check(ramp == ["N"], f"Speed through the ramp 0.45 -> 0.3 Hz: {ramp}")
            rev = at("rpm", 45, T_REVERSAL + 8)
            check(rev in (["N", "U", "N"], ["N"]) ,
                  f"Speed through the reversal: {rev} (no 0 while turning)")
            stop = at("rpm", 76, T_START - 2)
            check(stop in (["N", "U", "0"], ["N", "0"]),
                  f"Speed through the stop: {stop} (0 only once stopped)")
            start = at("rpm", T_START - 2, T_START + 12)
            check(start in (["0", "U", "N"], ["0", "N"]), f"Speed through the start: {start}")
            run_at_stop = [t for t, e, v, _ in ha.timeline if e == eid["rotating"] and v == "off"]
            ev_stop = [t for t, e, v, et in ha.timeline if e == eid["motion"] and et == "stopped"]
            if run_at_stop and ev_stop:
                check(abs(run_at_stop[0] - ev_stop[0]) < 1.0,
                      f"Running off with the 'stopped' event ({run_at_stop[0] - t_d:.1f} s, "
                      f"event at {ev_stop[0] - t_d:.1f} s; the fan at rest from {T_STOP:.0f} s)")
            zero = [v for t, e, v, _ in ha.timeline if e == eid["rpm"] and kind(v) == "0"
                    and t < (run_at_stop[0] if run_at_stop else 0) - 0.1]
            check(not zero, f"no 0 rpm before the confirmed stop ({len(zero)})")
            # 3. daemon restart: the reference is kept; Running unknown, then on
            write_cfg(STEADY)
            daemon.stop()
            t_r = time.monotonic()
            un = await wait_for(lambda: _state_is(ha, eid["rotation"], "unavailable"), 10, 0.05)
            daemon.start()
            back = await wait_for(lambda: _state_is(ha, eid["rotating"], "on"), 60, 0.2)
            await asyncio.sleep(1.0)   # the websocket's record may trail the REST state
            run = merged(ha.changes(eid["rotating"], t_r, time.monotonic()))
            check(bool(un) and bool(back) and run == ["on", "unavailable", "unknown", "on"],
                  f"daemon restart: Running {run}")
            ccw = await wait_for(lambda: _state_is(ha, eid["rotation"], "counterclockwise"), 30)
            check(bool(ccw), "the reference and its direction kept across the restart")
            # 4. Forget: one step to Learning, the direction kept for the next reference
            await asyncio.sleep(3)
            t_f = time.monotonic()
            code = await ha.service("button", "press", {"entity_id": eid["forget_reference"]})
            learned = await wait_for(lambda: _event_type(ha, eid["reference"], "learned"), 60,
                                     0.5)
            ok = await wait_for(lambda: _state_is(ha, eid["rotation"], "counterclockwise"), 30)
            stat = merged(ha.changes(eid["status"], t_f, time.monotonic()))
            refev = ha.changes(eid["reference"], t_f, time.monotonic())
            sel = merged(ha.changes(eid["reference_direction"], t_f, time.monotonic()))
            run = merged(ha.changes(eid["rotating"], t_f, time.monotonic()))
            check(code == 200 and bool(learned) and stat == ["OK", "Learning", "OK"],
                  f"Forget: Status {stat}")
            check(refev == ["forgotten", "learned"], f"Forget: Reference events {refev}")
            check(sel == ["counterclockwise"] and bool(ok),
                  f"Forget: Reference direction stays counterclockwise ({sel}), Rotation "
                  "counterclockwise again")
            check(run == ["on"], f"Forget: Running {run}")
            # 5. Learn: a new reference while tracking goes on
            old_ref = await _attr(ha, eid["status"], "reference")
            await asyncio.sleep(2)
            t_l = time.monotonic()
            code = await ha.service("button", "press", {"entity_id": eid["learn_reference"]})
            new_ref = await wait_for(lambda: _attr_changed(ha, eid["status"], "reference",
                                                           old_ref), 60, 0.5)
            await wait_for(lambda: _state_is(ha, eid["rotation"], "counterclockwise"), 30)
            run = merged(ha.changes(eid["rotating"], t_l, time.monotonic()))
            check(code == 200 and bool(new_ref) and run == ["on"],
                  f"Learn: reference {old_ref} -> {new_ref}, Running {run}")
            # 6. the select the other way, and back
            await ha.service("select", "select_option", {
                "entity_id": eid["reference_direction"], "option": "clockwise"})
            cw = await wait_for(lambda: _state_is(ha, eid["rotation"], "clockwise"), 30)
            await asyncio.sleep(5)     # commands pass one per 5 s after a burst
            await ha.service("select", "select_option", {
                "entity_id": eid["reference_direction"], "option": "counterclockwise"})
            ccw = await wait_for(lambda: _state_is(ha, eid["rotation"], "counterclockwise"), 30)
            check(bool(cw) and bool(ccw), "select clockwise -> Rotation clockwise; back")
            # 7. config entities: checked like the YAML, used, stored
            await asyncio.sleep(5)
            await ha.service("number", "set_value", {"entity_id": eid["learn_seconds"],
                                                     "value": 10})
            n10 = await wait_for(lambda: _number_is(ha, eid["learn_seconds"], 10.0), 20)
            await asyncio.sleep(5)
            await ha.service("number", "set_value", {"entity_id": eid["stale_fit"],
                                                     "value": 45})
            n45 = await wait_for(lambda: _number_is(ha, eid["stale_fit"], 45.0), 20)
            await asyncio.sleep(5)
            await ha.service("switch", "turn_off", {"entity_id": eid["auto_learn"]})
            off = await wait_for(lambda: _state_is(ha, eid["auto_learn"], "off"), 20)
            stored = json.loads((state_dir / "settings.json").read_text()) \
                if (state_dir / "settings.json").exists() else {}
            check(bool(n10) and bool(n45) and bool(off) and
                  {k: v["value"] for k, v in stored.items()} ==
                  {"learn_seconds": 10.0, "stale_fit": 0.45, "auto_learn": False},
                  f"config entities: Learning length 10 s, Stale below fit 45 %, Learn "
                  f"automatically off; stored {stored}")
            daemon.stop()
            daemon.start()
            await wait_for(lambda: _state_is(ha, eid["rotating"], "on"), 60, 0.2)
            st = await ours()
            check((_num(st["learn_seconds"]["state"]), _num(st["stale_fit"]["state"]),
                   st["auto_learn"]["state"]) == (10.0, 45.0, "off"),
                  "config entities kept across a daemon restart")
            st = await ours()
            print(f"\nWhat Home Assistant {ha_version} shows at the end of the day:")
            print(table(st), flush=True)
            check(all(x["state"] != "unavailable" for x in st.values()),
                  "no entity unavailable while the daemon runs")
            # 8. kill -9: unavailable within 2 s (the last will)
            daemon.stop(signal.SIGKILL)
            t_kill = time.monotonic()
            un = await wait_for(lambda: _state_is(ha, eid["rotation"], "unavailable"), 10,
                                0.02)
            check(bool(un) and time.monotonic() - t_kill < 2.0,
                  f"kill -9: unavailable after {time.monotonic() - t_kill:.2f} s")
            daemon.start()
            await wait_for(lambda: _state_is(ha, eid["status"], "OK"), 60, 0.5)
            # 9. broker restart
            t_down = time.time()
            broker.stop()
            await asyncio.sleep(2)
            broker.start()
            back = await wait_for(lambda: _state_is(ha, eid["status"], "OK"), 60, 0.5)
            broker_down.append((t_down, time.time()))
            check(bool(back), "broker restart: Status OK again")
            # 10. Home Assistant restart
            hass.stop()
            hass.start()
            await wait_for(ha.up, 120, 1.0)
            await asyncio.sleep(3)
            await ha.login()
            back = await wait_for(lambda: _state_is(ha, eid["status"], "OK"), 60, 0.5)
            reg = await registry()
            check(bool(back) and len(reg) == len(reg0),
                  f"Home Assistant restart: Status OK again, {len(reg)} entities")
    finally:
        for p in procs:
            p.stop()
        files, bad, expected = log_problems(conf, broker_down)
        check(not bad, f"no MQTT or bladesonar warning or error in Home Assistant's logs "
                       f"({', '.join(files)}): {len(bad)}")
        for ln in bad[:10]:
            print("   ", ln[:300])
        if expected:
            print(f"    (expected: {len(expected)} line{'s' if len(expected) > 1 else ''} "
                  "saying only that the broker was gone while this check had stopped it)")
            for ln in expected[:4]:
                print("   ", ln[:300])
        print(f"\nHome Assistant {ha_version}: {sum(ok for ok, _ in RESULTS)} passed, "
              f"{sum(not ok for ok, _ in RESULTS)} failed ({time.monotonic() - t0:.0f} s)")
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
    return 0 if all(ok for ok, _ in RESULTS) else 1


async def _count(registry, n: int):
    return len(await registry()) >= n


async def _get(ha: HA, eid: str) -> dict | None:
    return next((s for s in await ha.states() if s["entity_id"] == eid), None)


async def _status_is(ha: HA, registry, eid: dict, want: str):
    if "status" not in eid:
        reg = await registry()
        e = reg.get(f"bladesonar_{DEVICE}_status")
        if e is None:
            return False
        eid["status"] = e["entity_id"]
    return await _state_is(ha, eid["status"], want)


async def _state_is(ha: HA, eid: str, want: str):
    s = await _get(ha, eid)
    return s is not None and s["state"] == want


def _num(v: str) -> float | None:
    try:
        return float(v)
    except ValueError:
        return None


async def _number_is(ha: HA, eid: str, want: float):
    s = await _get(ha, eid)
    return s is not None and _num(s["state"]) == want


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
