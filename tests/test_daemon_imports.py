"""The daemon's hot path imports only what it runs: no plotting, imaging or the report,
and no scipy at all (scipy.signal cost 75 MiB of resident memory and a second of
start-up on a small board; scipy.fft with scipy.special, for an FFT and a Bessel
function numpy has too, 18 MiB more: the daemon's RSS target is 45 MiB)."""

from __future__ import annotations

import json
import subprocess
import sys

DAEMON_MODULES = ("bladesonar.commands.run", "bladesonar.live", "bladesonar.service.runner",
                  "bladesonar.service.audio", "bladesonar.service.alsa_audio",
                  "bladesonar.service.sim_audio", "bladesonar.service.publish",
                  "bladesonar.service.notify", "bladesonar.service.learner",
                  "bladesonar.io.reference")
FORBIDDEN = ("matplotlib", "scipy",
             "bladesonar.imaging", "bladesonar.plots", "bladesonar.runtime_report")


def test_daemon_modules_leave_out_the_optional_stages(repo_root):
    code = ("import importlib, json, sys\n"
            f"for m in {DAEMON_MODULES!r}: importlib.import_module(m)\n"
            "print(json.dumps(sorted(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=repo_root).stdout
    loaded = json.loads(out)
    bad = [m for m in loaded if any(m == f or m.startswith(f + ".") for f in FORBIDDEN)]
    assert bad == []
    assert "bladesonar.live" in loaded   # the check itself ran
