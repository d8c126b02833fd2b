"""``bladesonar reference``: fold a recording of the turning fan into a reference file.

A thin edge: read the config and the WAV, build the reference (analysis.build_reference),
write it atomically, print a JSON summary.
"""

from __future__ import annotations

import argparse
import json

EPILOG = """\
The recording must show the fan turning at a steady rate for at least
analysis.min_periods blade periods (a few seconds). Ranges are one-way, c * delay / 2 from
the direct-coupling edge. The summary's rate_hz is the fan's rotation rate (blade-pass
frequency / blades).

example:
  bladesonar reference --config cfg.yaml --direction ccw --out ref.npz reference.wav
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reference", help="make a reference (angular fingerprint) from a "
                       "recording of the fan turning steadily",
                       description="Estimate the blade period of a recording of the turning "
                       "fan, fold all its periods into an angular table and store it.",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", metavar="CFG", help="YAML config (default: built-in defaults)")
    p.add_argument("--direction", required=True, choices=("cw", "ccw", "unknown"),
                   help="the fan's rotation during this recording, seen from the sensor")
    p.add_argument("--out", required=True, metavar="REF", help="reference file to write (.npz)")
    p.add_argument("wav", metavar="IN.wav", help="mono WAV recording")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .. import config
    from ..analysis import build_reference
    from ..io.reference import save_reference
    from ..io.wav import read_wav

    cfg = config.load(args.config)
    x, _ = read_wav(args.wav, expect_rate=cfg.audio.sample_rate)
    ref = build_reference(x, cfg, args.direction)
    save_reference(ref, args.out)
    out = ref.summary()
    out["out"] = str(args.out)
    print(json.dumps(out))
    return 0
