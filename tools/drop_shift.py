"""How far a few lost pulses move a reversal's confirmation (issue 35: a PipeWire quantum
change costs a pulse per latency step, and the comparison with the ALSA loopback allows
0.3 s). A measuring tool, not a test.

  .venv/bin/python tools/drop_shift.py --seeds 3-8 --at 6,10,11.5,12.5,13.5 --lost 5

The daemon's path (``LiveAnalyzer``, blocks of 8) on the paper room at 20 dB, the fan
at 0.45 Hz ccw reversed through zero over 3 s from 12 s (0.3 Hz/s: the PipeWire tests'
schedule until 2026-11-29; theirs now, over 6 s: ``--schedule
"ccw:0.45:12,cw:0.45:600~6"``), each seed once
intact and once per time in ``--at`` with ``--lost`` pulses silenced from there (the
aligner marks them dropped, as it does the pulse a latency step costs). Printed per
seed: the pulse of the intact run's ``reversed`` and the shift of each silenced run's, in
pulses (34 a second).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bladesonar import config
from bladesonar.io.scene_file import load_scene
from bladesonar.live import LiveAnalyzer
from bladesonar.reference_build import Reference, build_reference
from bladesonar.sim.render import simulate
from bladesonar.sim.schedule import Schedule, parse

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ramp_trace import seeds_of  # noqa: E402  (tools/ramp_trace.py: "1-4,7")

ROOT = Path(__file__).resolve().parents[1]
#: tests/test_daemon_pipewire.py's schedule until 2026-11-29 (its reversal now takes 6 s)
SCHEDULE = "ccw:0.45:12,cw:0.45:600~3"


def reversed_at(x: np.ndarray, cfg: config.Config, ref: Reference) -> int | None:
    """The pulse of the first ``reversed`` the daemon's path confirms in ``x``."""
    la = LiveAnalyzer(cfg, ref, block_pulses=8)
    pri, pos = cfg.waveform.pri_samples, 0
    while pos < len(x):
        n = la.wanted() * pri
        la.feed(x[pos:pos + n], pos)
        pos += n
        for e in la.take_events():
            if e.kind.value == "reversed":
                return e.pulse
    return None


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="1-4")
    p.add_argument("--at", default="6,10,12.5", help="times (s) the pulses are lost")
    p.add_argument("--lost", type=int, default=2, help="pulses lost each time")
    p.add_argument("--schedule", default=SCHEDULE,
                   help=f"the fan (simulate's grammar; default {SCHEDULE})")
    args = p.parse_args(argv)
    cfg = config.Config()
    scene = load_scene(ROOT / "config" / "scenes" / "paper-room.yaml")
    pri, fs = cfg.waveform.pri_samples, cfg.audio.sample_rate
    xr, _ = simulate(scene, cfg, 10.0, schedule=Schedule.constant(0.45, "ccw"), snr_db=20.0,
                     seed=99)
    ref = build_reference(xr, cfg, "ccw")
    for seed in seeds_of(args.seeds):
        x, _ = simulate(scene, cfg, 20.0, schedule=parse(args.schedule), snr_db=20.0, seed=seed)
        base = reversed_at(x, cfg, ref)
        shifts = []
        for t in (float(v) for v in args.at.split(",")):
            y = x.copy()
            i0 = int(t * fs) // pri * pri
            y[i0:i0 + args.lost * pri] = 0.0
            got = reversed_at(y, cfg, ref)
            shifts.append((t, None if got is None or base is None else got - base))
        print(f"seed {seed}: reversed at pulse {base}; lost {args.lost} at (s, shift in "
              f"pulses) {shifts}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
