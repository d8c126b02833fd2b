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


def test_the_live_analysis_leaves_out_what_it_does_not_need(repo_root, tmp_path):
    """Run, not only imported: the live analysis of a few seconds of a turning fan, from
    a reference file, loads neither numpy.ma (np.median's first call imports it for a
    check that never applies to a plain array: 1.9 MiB resident; dsp.stats.median) nor
    statistics or difflib (wanted only for the stats line and a config error)."""
    import numpy as np

    from bladesonar import config
    from bladesonar.io.reference import save_reference
    from bladesonar.io.scene_file import load_scene
    from bladesonar.reference_build import build_reference
    from bladesonar.sim.render import simulate

    cfg = config.Config()
    scene = load_scene(repo_root / "config/scenes/paper-room.yaml")
    x, _ = simulate(scene, cfg, 12.0, schedule="ccw:0.45:12", seed=3, snr_db=20.0)
    save_reference(build_reference(x, cfg, "ccw"), tmp_path / "ref.npz")
    y, _ = simulate(scene, cfg, 6.0, schedule="ccw:0.45:6", seed=4, snr_db=12.0)
    np.save(tmp_path / "audio.npy", y)
    code = ("import json, sys\n"
            "import numpy as np\n"
            "from bladesonar import config\n"
            "from bladesonar.io.reference import load_reference\n"
            "from bladesonar.live import LiveAnalyzer\n"
            f"ref = load_reference({str(tmp_path / 'ref.npz')!r})\n"
            "cfg = config.Config()\n"
            "live = LiveAnalyzer(cfg, ref)\n"
            f"y = np.load({str(tmp_path / 'audio.npy')!r})\n"
            "pri = cfg.waveform.pri_samples\n"
            "out = [live.push(y[i:i + 8 * pri], i) for i in range(0, len(y) - 8 * pri, 8 * pri)]\n"
            "print(json.dumps({'answers': [e.direction.value for e in out if e is not None],\n"
            "                  'modules': sorted(sys.modules)}))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=repo_root)
    assert run.returncode == 0, run.stderr[-2000:]
    got = json.loads(run.stdout)
    assert "same" in got["answers"]          # the analysis ran and answered
    bad = [m for m in got["modules"]
           if m in ("statistics", "difflib") or m == "numpy.ma" or m.startswith("numpy.ma.")]
    assert bad == []
