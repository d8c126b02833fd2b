"""Test helper: a private, headless PipeWire (pipewire + wireplumber on a private session
bus, no sound card: a Dummy-Driver clocks the graph in real time) and the PipeWire
loopback room (``bladesonar room --pipewire``) as real processes.

Everything lives in one temporary runtime directory; ``env`` is what a client (the
daemon, the room, pw-cli) needs to reach this server and no other. Stopped by PID.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from bladesonar.service.sound_server import _live_socket
from loopback import ROOT, bladesonar_cmd

BINARIES = ("pipewire", "wireplumber", "dbus-daemon", "pw-cli", "pw-dump", "pw-link",
            "pw-metadata")


def require_pipewire() -> None:
    missing = [b for b in BINARIES if shutil.which(b) is None]
    if missing:
        pytest.skip(f"PipeWire is not installed ({', '.join(missing)} missing; tools/setup "
                    "installs pipewire pipewire-bin pipewire-alsa wireplumber dbus-daemon)")
    if not Path("/usr/share/alsa/alsa.conf.d/50-pipewire.conf").is_file():
        pytest.skip("PipeWire's ALSA plugin is missing (apt install pipewire-alsa)")


def _stop(proc: subprocess.Popen | None, sig: int = signal.SIGTERM) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(sig)
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


class PipeWireServer:
    """pipewire + wireplumber at ``rate`` Hz in ``base`` (a private runtime dir and
    config); ``restart()`` kills and starts both again, as a crash and systemd would."""

    def __init__(self, base: Path, rate: int = 48000, quantum: int = 1024) -> None:
        self.base = base
        self.rate, self.quantum = int(rate), int(quantum)
        run = base / "run"
        run.mkdir(parents=True, exist_ok=True)
        run.chmod(0o700)
        conf = base / "config" / "pipewire" / "pipewire.conf.d"
        conf.mkdir(parents=True, exist_ok=True)
        (conf / "10-bladesonar-test.conf").write_text(
            "context.properties = {\n"
            f"    default.clock.rate = {self.rate}\n"
            f"    default.clock.allowed-rates = [ {self.rate} ]\n"
            f"    default.clock.quantum = {self.quantum}\n"
            "}\n", encoding="utf-8")
        self.env = dict(os.environ)
        for k in ("PIPEWIRE_REMOTE", "PIPEWIRE_RUNTIME_DIR", "PULSE_SERVER",
                  "PULSE_RUNTIME_PATH", "PIPEWIRE_PROPS", "ALSA_CONFIG_PATH"):
            self.env.pop(k, None)
        self.env.update(XDG_RUNTIME_DIR=str(run), XDG_CONFIG_HOME=str(base / "config"),
                        XDG_STATE_HOME=str(base / "state"), XDG_DATA_HOME=str(base / "data"),
                        DBUS_SESSION_BUS_ADDRESS=f"unix:path={run}/bus")
        self.logs = base / "logs"
        self.logs.mkdir(exist_ok=True)
        self._dbus_pid: int | None = None
        self.pipewire: subprocess.Popen | None = None
        self.wireplumber: subprocess.Popen | None = None
        self.starts = 0

    # -- life cycle ------------------------------------------------------------------------

    def start(self) -> PipeWireServer:
        if self._dbus_pid is None:
            r = subprocess.run(["dbus-daemon", "--session", "--fork", "--print-pid",
                                f"--address={self.env['DBUS_SESSION_BUS_ADDRESS']}"],
                               capture_output=True, text=True, env=self.env, timeout=10,
                               check=True)
            self._dbus_pid = int(r.stdout.split()[0])
        self.starts += 1
        n = self.starts
        run = Path(self.env["XDG_RUNTIME_DIR"])
        for stale in ("pipewire-0", "pipewire-0.lock"):    # left by a killed server
            (run / stale).unlink(missing_ok=True)
        self.pipewire = subprocess.Popen(["pipewire"], env=self.env, stdin=subprocess.DEVNULL,
                                         stdout=open(self.logs / f"pipewire{n}.log", "w"),
                                         stderr=subprocess.STDOUT)
        self._wait(lambda: _live_socket(run / "pipewire-0"), "the pipewire socket")
        self.wireplumber = subprocess.Popen(["wireplumber"], env=self.env,
                                            stdin=subprocess.DEVNULL,
                                            stdout=open(self.logs / f"wireplumber{n}.log", "w"),
                                            stderr=subprocess.STDOUT)
        self._wait(lambda: self.metadata("settings") is not None, "the settings metadata")
        return self

    def _wait(self, ok: Any, what: str, timeout: float = 15.0) -> None:
        deadline = time.monotonic() + timeout
        while not ok():
            if self.pipewire is not None and self.pipewire.poll() is not None:
                raise AssertionError(f"pipewire exited: {self.log_text()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"{what} did not appear in {timeout} s: {self.log_text()}")
            time.sleep(0.1)

    def stop_server(self) -> None:
        """pipewire and wireplumber, not the bus."""
        _stop(self.wireplumber)
        _stop(self.pipewire)

    def restart(self) -> None:
        self.stop_server()
        self.start()

    def stop(self) -> None:
        self.stop_server()
        if self._dbus_pid is not None:
            try:
                os.kill(self._dbus_pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            self._dbus_pid = None

    def __enter__(self) -> PipeWireServer:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def log_text(self) -> str:
        return "\n".join(f"== {p.name}\n{p.read_text(errors='replace')[-3000:]}"
                         for p in sorted(self.logs.glob("*.log")))

    # -- the graph ---------------------------------------------------------------------------

    def run(self, *args: str, timeout: float = 10.0) -> subprocess.CompletedProcess:
        return subprocess.run(list(args), env=self.env, capture_output=True, text=True,
                              timeout=timeout, check=False)

    def metadata(self, name: str) -> dict[str, str] | None:
        r = self.run("pw-metadata", "-n", name)
        if r.returncode != 0 or "Found" not in r.stdout:
            return None
        out = {}
        for line in r.stdout.splitlines():
            if "key:'" in line:
                key = line.split("key:'", 1)[1].split("'", 1)[0]
                out[key] = line.split("value:'", 1)[1].split("'", 1)[0]
        return out

    def force_quantum(self, quantum: int) -> None:
        r = self.run("pw-metadata", "-n", "settings", "0", "clock.force-quantum", str(quantum))
        assert r.returncode == 0, r.stderr

    def node_id(self, name: str) -> int | None:
        import json
        r = self.run("pw-dump")
        for o in json.loads(r.stdout or "[]"):
            if ((o.get("info") or {}).get("props") or {}).get("node.name") == name:
                return int(o["id"])
        return None


class PwRoomProcess:
    """``bladesonar room --pipewire`` on ``server``; ``truth`` gets its session starts."""

    def __init__(self, server: PipeWireServer, cfg_path: Path, schedule: str, *,
                 noise: float = 0.0, truth: Path | None = None) -> None:
        args = ["room", "--pipewire", "--config", str(cfg_path), "--schedule", schedule]
        if noise:
            args += ["--noise", str(noise)]
        if truth is not None:
            args += ["--truth", str(truth)]
        self.log = server.base / "logs" / "room.log"
        self._log = open(self.log, "a", encoding="utf-8")
        self.proc = subprocess.Popen(bladesonar_cmd(*args), stdout=subprocess.PIPE,
                                     stderr=self._log, text=True, cwd=ROOT, env=server.env)
        self.env = server.env
        assert self.proc.stdout is not None
        self.header = []
        for line in self.proc.stdout:
            self.header.append(line.strip())
            if line.strip() == "ready":
                break
        else:
            raise AssertionError(f"room did not start: {self.log.read_text()}")

    def stop(self) -> str:
        _stop(self.proc)
        self._log.close()
        return self.log.read_text(encoding="utf-8")

    def __enter__(self) -> PwRoomProcess:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()
