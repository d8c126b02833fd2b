"""deploy/bladesonar-user.service: the systemd --user unit for phones and desktop images.
Checked by systemd-analyze, held to the system unit's notify/watchdog/restart settings,
and its command line started as the unit would start it (its Environment=, %h and %E
expanded) against a private headless PipeWire, with a real sd_notify socket."""

from __future__ import annotations

import json
import shlex
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from loopback import ROOT, bladesonar_cmd, require_alsa, write_config
from pipewire_server import PipeWireServer, PwRoomProcess, require_pipewire
from test_daemon_e2e import NotifySocket
from test_deploy import SYSTEMD_ANALYZE, UNIT, analyze, needs_analyze, unit_value, unit_values

USER_UNIT = ROOT / "deploy" / "bladesonar-user.service"
EXAMPLE = ROOT / "config" / "bladesonar-pipewire.example.yaml"
VENV_PREFIX = "%h/.local/share/bladesonar/"

#: What a supervisor sees of the daemon: the same in both units.
SAME = ("Type", "NotifyAccess", "ExecReload", "TimeoutStartSec", "TimeoutStopSec",
        "WatchdogSec", "Restart", "RestartSec", "RestartPreventExitStatus", "UMask")


def test_user_unit_keeps_the_system_units_notify_watchdog_and_restarts():
    u, s = USER_UNIT.read_text(), UNIT.read_text()
    for key in SAME:
        assert unit_value(u, "Service", key) == unit_value(s, "Service", key), key
    assert unit_values(u, "Service", "Environment") == unit_values(s, "Service", "Environment")
    assert unit_value(u, "Install", "WantedBy") == "default.target"
    assert "pipewire.service" in unit_value(u, "Unit", "After")
    argv = shlex.split(unit_value(u, "Service", "ExecStart"))
    assert argv[0] == VENV_PREFIX + ".venv/bin/bladesonar"
    assert argv[1:] == ["run", "--config", "%E/bladesonar/bladesonar.yaml"]
    # a user manager runs as the user: no User=, no device or group settings
    assert not unit_values(u, "Service", "User")
    assert not unit_values(u, "Service", "SupplementaryGroups")


@needs_analyze
def test_user_unit_verifies_clean(tmp_path):
    prefix = tmp_path / "prefix"
    exe = prefix / ".venv" / "bin" / "bladesonar"
    exe.parent.mkdir(parents=True)
    exe.write_text("#!/bin/sh\nexit 0\n")
    exe.chmod(0o755)
    unit = tmp_path / "bladesonar.service"
    unit.write_text(USER_UNIT.read_text().replace(VENV_PREFIX, f"{prefix}/"))
    assert SYSTEMD_ANALYZE is not None
    r = analyze("verify", str(unit))
    assert r.returncode == 0 and r.stdout.strip() == "" and r.stderr.strip() == "", \
        r.stdout + r.stderr
    broken = tmp_path / "broken" / "bladesonar.service"
    broken.parent.mkdir()
    broken.write_text(unit.read_text().replace("WatchdogSec=", "WatchdogSecs="))
    assert "WatchdogSecs" in analyze("verify", str(broken)).stderr


def unit_command(home: Path, config_home: Path) -> tuple[list[str], dict[str, str]]:
    """ExecStart and Environment= as systemd --user runs them (%h, %E expanded), with
    this checkout's virtualenv in place of the installed one."""
    text = USER_UNIT.read_text()
    exec_start = unit_value(text, "Service", "ExecStart") \
        .replace(VENV_PREFIX + ".venv/", f"{ROOT}/.venv/") \
        .replace("%h", str(home)).replace("%E", str(config_home))
    assert "%" not in exec_start
    env = {}
    for line in unit_values(text, "Service", "Environment"):
        for item in shlex.split(line):
            k, _, v = item.partition("=")
            env[k] = v
    return shlex.split(exec_start), env


@pytest.mark.slow
@pytest.mark.pipewire
def test_the_units_command_line_runs_the_daemon_through_pipewire(tmp_path):
    """The example config (only the node names, the state folder and the broker set
    for this machine) under the unit's command line: READY, WATCHDOG and tracking
    states through the headless PipeWire, a SIGHUP reload, a clean SIGTERM."""
    require_alsa()
    require_pipewire()
    home, config_home = tmp_path / "home", tmp_path / "home" / ".config"
    cfg_path = config_home / "bladesonar" / "bladesonar.yaml"
    cfg_path.parent.mkdir(parents=True)
    cfg = yaml.safe_load(EXAMPLE.read_text())
    cfg["audio"].update(playback_device="bladesonar_sink", capture_device="bladesonar_source")
    cfg["daemon"]["state_dir"] = str(tmp_path / "state")
    cfg["mqtt"].update(publish_interval_s=1, stats_interval_s=2)
    cfg_path.write_text(yaml.safe_dump(cfg))
    room_cfg = write_config(tmp_path / "room.yaml", tmp_path / "state",
                            audio={"sample_rate": cfg["audio"]["sample_rate"]},
                            waveform=cfg["waveform"])
    argv, unit_env = unit_command(home, config_home)
    with PipeWireServer(tmp_path / "pw", rate=48000) as server, \
            PwRoomProcess(server, room_cfg, "ccw:0.45:600", noise=1e-4):
        env = dict(server.env, HOME=str(home), **unit_env)
        r = subprocess.run(bladesonar_cmd("reference", "--live", "--seconds", "10",
                                          "--direction", "ccw", "--config", str(cfg_path)),
                           env=env, capture_output=True, text=True, timeout=120, cwd=ROOT)
        assert r.returncode == 0, r.stderr
        notify = NotifySocket(tmp_path / "notify.sock")
        env["NOTIFY_SOCKET"] = notify.path
        proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, cwd=tmp_path)
        try:
            notify.wait_for("READY=1", 30)
            notify.wait_for("WATCHDOG=1", 10)
            proc.send_signal(signal.SIGHUP)
            time.sleep(4)
        finally:
            proc.send_signal(signal.SIGTERM)
            out, err = proc.communicate(timeout=30)
            notify.close()
    assert proc.returncode == 0, err[-3000:]
    states = [json.loads(ln)["payload"] for ln in out.splitlines()
              if json.loads(ln)["topic"].endswith("/state")]
    tracking = [s for s in states if s.get("direction") == "same"]
    assert tracking and tracking[-1]["rate_hz"] == pytest.approx(0.45, rel=0.05)
    assert "RELOADING=1" in notify.lines() and "STOPPING=1" in notify.lines()
    assert "configuration reloaded" in err
