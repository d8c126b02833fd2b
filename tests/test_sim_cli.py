"""``bladesonar simulate`` through the real entry point (a subprocess)."""

from __future__ import annotations

import json
import subprocess
import sys
import wave
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = str(ROOT / "config/scenes/paper-room.yaml")


def bladesonar(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bladesonar", "simulate", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def test_simulate_writes_wav_and_truth(tmp_path):
    out = tmp_path / "tmp" / "x.wav"
    r = bladesonar("--scene", SCENE, "--seconds", "2", "--out", str(out))
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    with wave.open(str(out)) as w:
        assert (w.getnchannels(), w.getsampwidth(), w.getframerate()) == (1, 2, 44100)
        assert w.getnframes() == 88200
    truth = json.loads((tmp_path / "tmp" / "x.truth.json").read_text())
    off = truth["meta"]["start_offset_samples"]
    n = sum(1 for k in range(100) if off + k * 1297 < 88200)
    assert len(truth["pulses"]) == n == summary["pulses"] == truth["meta"]["pulses"]
    assert summary["samples"] == 88200 and summary["truth"].endswith("x.truth.json")
    assert truth["summary"]["complete"] is True
    assert truth["meta"]["snr"]["snr_db"] == 20.0
    assert {p["kind"] for r in truth["pulses"] for p in r["paths"]} >= {"coupling", "wall"}


def test_simulate_options(tmp_path):
    out = tmp_path / "y.wav"
    r = bladesonar("--scene", SCENE, "--seconds", "1", "--out", str(out), "--rate", "1.5",
                   "--direction", "cw", "--snr-db", "inf", "--seed", "4", "--start-offset",
                   "0", "--drift-ppm", "20", "--dropouts", "2", "--dropout-samples", "10",
                   "--dc-offset", "0.1", "--clip", "0.2", "--no-wall-bounces", "--no-paths",
                   "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    t = json.loads((tmp_path / "y.truth.json").read_text())
    assert t["meta"]["snr"]["noise_sigma"] == 0 and t["meta"]["wall_bounces"] is False
    assert t["pulses"][5]["rate_hz"] == -1.5 and "paths" not in t["pulses"][5]
    assert json.loads(r.stdout)["clipped_samples"] > 0     # the coupling peak exceeds 0.2


@pytest.mark.parametrize("args,needle", [
    (["--seconds", "0"], "--seconds"),
    (["--seconds", "x"], "--seconds"),
    (["--seconds", "1", "--snr-db", "loud"], "--snr-db"),
    (["--seconds", "1", "--rate", "1", "--schedule", "cw:1:1"], "--rate"),
    (["--seconds", "1", "--schedule", "left:1:1"], "--schedule"),
    (["--seconds", "1", "--start-offset", "1297"], "--start-offset"),
    (["--seconds", "1", "--config", "/nonexistent.yaml"], "--config"),
])
def test_bad_options_exit_2_without_traceback(tmp_path, args, needle):
    r = bladesonar("--scene", SCENE, "--out", str(tmp_path / "z.wav"), *args)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and needle in r.stderr


def test_sensor_outside_the_room_is_refused(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("room:\n  vertices: [[0,0],[4,0],[4,3],[0,3]]\nsensor: [5, 1]\n"
                   "fan:\n  centre: [2, 1.5]\n")
    r = bladesonar("--scene", str(bad), "--seconds", "1", "--out", str(tmp_path / "z.wav"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "sensor" in r.stderr and "not inside the room" in r.stderr


def test_help_documents_every_option():
    r = subprocess.run([sys.executable, "-m", "bladesonar", "simulate", "--help"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0
    for opt in ("--scene", "--seconds", "--out", "--config", "--schedule", "--rate",
                "--direction", "--snr-db", "--seed", "--start-offset", "--drift-ppm",
                "--dropouts", "--dropout-samples", "--dropout-mode", "--dc-offset", "--clip",
                "--no-wall-bounces", "--no-paths", "--quiet"):
        assert opt in r.stdout


def test_a_live_reference_longer_than_a_reference_uses_is_refused(repo_root, tmp_path):
    """A reference uses at most 2^20 samples (23.8 s at 44.1 kHz), as from a file: asking
    --live for an hour once recorded it all into memory. Refused before recording."""
    from loopback import bladesonar_cmd
    r = subprocess.run(bladesonar_cmd("reference", "--live", "--seconds", "3600",
                                      "--direction", "ccw", "--config",
                                      str(repo_root / "config" / "demo.yaml"),
                                      "--out", str(tmp_path / "r.npz")),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    assert "between 0.5 and 23.8 s" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "r.npz").exists()
