"""Test helper: the loopback room (``bladesonar room``) as a real subprocess, and a config
whose ALSA devices are its FIFO PCMs. Used by the ALSA and end-to-end daemon tests."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "config" / "scenes" / "paper-room.yaml"


def require_alsa() -> None:
    try:
        import alsaaudio  # noqa: F401
    except ImportError:
        pytest.skip("pyalsaaudio is not installed (tools/setup --test installs it)")
    if not Path("/usr/share/alsa/alsa.conf").is_file():
        pytest.skip("alsa-lib's configuration is missing (apt install libasound2)")


def write_config(path: Path, state_dir: Path, **sections: Any) -> Path:
    """A daemon config on the loopback PCMs; ``sections`` override keys per section."""
    data: dict[str, Any] = {
        "device_id": "loopback",
        "audio": {"backend": "alsa", "playback_device": "bladesonar_play",
                  "capture_device": "bladesonar_cap"},
        "daemon": {"state_dir": str(state_dir)},
        "sim": {"scene": str(SCENE)},
    }
    for sec, values in sections.items():
        if isinstance(values, dict):
            data.setdefault(sec, {}).update(values)
        else:
            data[sec] = values
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def bladesonar_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "bladesonar", *args]


class RoomProcess:
    """``bladesonar room`` in the background; ``env`` is what a daemon needs to see it."""

    def __init__(self, cfg_path: Path, room_dir: Path, schedule: str, *, realtime: bool,
                 keep_serving: bool = False, noise: float = 0.0, truth: Path | None = None,
                 connect_timeout: float = 60.0, latency: int | None = None) -> None:
        args = ["room", "--config", str(cfg_path), "--dir", str(room_dir),
                "--schedule", schedule, "--connect-timeout", str(connect_timeout)]
        if realtime:
            args.append("--realtime")
        if keep_serving:
            args.append("--keep-serving")
        if noise:
            args += ["--noise", str(noise)]
        if truth is not None:
            args += ["--truth", str(truth)]
        if latency is not None:
            args += ["--latency", str(latency)]
        self.log = room_dir / "room.log"
        room_dir.mkdir(parents=True, exist_ok=True)
        self._log = open(self.log, "w", encoding="utf-8")
        self.proc = subprocess.Popen(bladesonar_cmd(*args), stdout=subprocess.PIPE,
                                     stderr=self._log, text=True, cwd=ROOT)
        self.env = dict(os.environ)
        deadline = time.monotonic() + 30
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith("export "):
                k, v = line[len("export "):].strip().split("=", 1)
                self.env[k] = v
            if line.strip() == "ready":
                break
            if time.monotonic() > deadline:
                break
        else:
            raise AssertionError(f"room did not start: {self.log.read_text()}")
        assert "ALSA_CONFIG_PATH" in self.env

    def stop(self, grace: float = 0.0) -> str:
        """Stop the room (after ``grace`` seconds for its session to end by itself); its
        log."""
        if grace > 0:
            try:
                self.proc.wait(grace)
            except subprocess.TimeoutExpired:
                pass
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.log.read_text(encoding="utf-8")

    def __enter__(self) -> RoomProcess:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()
