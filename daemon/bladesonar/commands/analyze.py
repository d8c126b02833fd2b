"""``bladesonar analyze``: direction and rate of a recording against a reference.

A thin edge: read config, reference and WAV, run analysis.analyze, print one JSON object
(or, with --track, one JSON line per pulse followed by nothing else).
"""

from __future__ import annotations

import argparse
import json
import sys

EPILOG = """\
output keys: direction (same|reversed|stopped|unknown, against the reference), rotation
(cw|ccw when the reference knows its own, else null), relative_rate (signed, this
recording / reference), rate_hz and rpm (magnitude), confidence (0..1), pulses,
dropped_pulses, window_s (the estimate describes the last window_s seconds), warnings.
Limits: |rate| < PRF / (2 K); |relative_rate| up to tracking.slew_limit.

example:
  bladesonar analyze --config cfg.yaml --reference ref.npz probe.wav
  bladesonar analyze --config cfg.yaml --reference ref.npz --track probe.wav | tail -1
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="rotation direction and rate of a recording against "
                       "a reference", description="Match every pulse of a recording against "
                       "a reference's angular table, track the matched phase and report "
                       "direction and rate.", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", metavar="CFG", help="YAML config (default: built-in defaults)")
    p.add_argument("--reference", required=True, metavar="REF",
                   help="reference file made by 'bladesonar reference'")
    p.add_argument("--track", action="store_true",
                   help="print one JSON line per pulse with the running estimate")
    p.add_argument("wav", metavar="IN.wav", help="mono WAV recording")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..analysis import analyze
    from ..io.config_file import load_config
    from ..io.reference import load_reference
    from ..io.wav import stream_wav

    cfg = load_config(args.config)
    ref = load_reference(args.reference)
    # read in blocks: memory independent of the recording's length (rows aside)
    with stream_wav(args.wav, expect_rate=cfg.audio.sample_rate) as blocks:
        summary, rows = analyze(blocks, cfg, ref, track=args.track)
    if args.track:
        out = sys.stdout
        for row in rows:
            out.write(json.dumps(row) + "\n")
    else:
        print(json.dumps(summary))
    return 0
