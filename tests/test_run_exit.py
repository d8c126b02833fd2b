"""`bladesonar run`'s exit statuses, as systemd sees them: an invalid config file is 78
(EX_CONFIG), which the unit lists in RestartPreventExitStatus so it is not restarted every
5 s forever; other start-up errors are 2 and are retried (a USB card plugged in later)."""

from __future__ import annotations

import subprocess
from pathlib import Path

from loopback import ROOT, bladesonar_cmd, write_config


def _run(cfg: Path) -> subprocess.CompletedProcess:
    return subprocess.run(bladesonar_cmd("run", "--config", str(cfg), "--seconds", "1"),
                          capture_output=True, text=True, timeout=60)


def test_invalid_config_exits_78_naming_the_key(tmp_path):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("audio:\n  backend: sim\n  sample_rate: 5\n")
    r = _run(cfg)
    assert r.returncode == 78, r.stderr
    assert "audio.sample_rate" in r.stderr and "8000" in r.stderr
    assert "Traceback" not in r.stderr


def test_unit_prevents_restart_on_exactly_that_status():
    unit = (ROOT / "deploy" / "bladesonar.service").read_text()
    lines = [ln.split("=", 1)[1].split() for ln in unit.splitlines()
             if ln.startswith("RestartPreventExitStatus=")]
    assert lines == [["78"]]


def test_other_start_errors_exit_2_and_stay_restartable(tmp_path):
    # a reference exists (recorded through the sim backend), but the configured ALSA
    # device does not: retried by Restart=on-failure, e.g. a USB card plugged in later
    sim = write_config(tmp_path / "sim.yaml", tmp_path, audio={"backend": "sim"},
                       sim={"realtime": False, "schedule": "ccw:0.45:20"})
    rec = subprocess.run(bladesonar_cmd("reference", "--live", "--seconds", "8",
                                        "--direction", "ccw", "--config", str(sim)),
                         capture_output=True, text=True, timeout=120)
    assert rec.returncode == 0, rec.stderr
    cfg = write_config(tmp_path / "alsa.yaml", tmp_path,
                       audio={"playback_device": "no_such_pcm_xyz",
                              "capture_device": "no_such_pcm_xyz"})
    r = _run(cfg)
    assert r.returncode == 2, r.stderr
    assert "audio.playback_device" in r.stderr and "Traceback" not in r.stderr
