"""``bladesonar analyze``: direction and rate of a recording against a reference, and the
airflow from the echoes alone (with or without a reference).

A thin edge: read config, reference and WAV, run offline.analyze and the airflow stage
(airflow_recording.py) on the first ``AIRFLOW_SAMPLES`` samples, print one JSON object
(or, with --track, one JSON line per pulse followed by nothing else).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from typing import Any

EPILOG = """\
output keys: airflow (down|up|unknown, from the echoes alone, no reference needed),
airflow_confidence (0..1), airflow_rotation (cw|ccw seen from below, by
scene.downdraft_rotation; null when the airflow is unknown), airflow_shift (the glints'
range shift, samples per pulse, + = receding) and airflow_reason; with --reference also:
direction (same|reversed|stopped|unknown, against the reference), rotation
(cw|ccw when the reference knows its own, else null), relative_rate (signed, this
recording / reference), rate_hz and rpm (magnitude), confidence (0..1), pulses,
dropped_pulses, window_s (the estimate describes the last window_s seconds), warnings.
Limits: |rate| < PRF / (2 K); |relative_rate| up to tracking.slew_limit.

example:
  bladesonar analyze --config cfg.yaml probe.wav
  bladesonar analyze --config cfg.yaml --reference ref.npz probe.wav
  bladesonar analyze --config cfg.yaml --reference ref.npz --track probe.wav | tail -1
"""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("analyze", help="airflow of a recording, and its rotation direction "
                       "and rate against a reference", description="Tell the fan's airflow "
                       "(down or up) from the echoes alone; with --reference also match "
                       "every pulse against the reference's angular table, track the matched "
                       "phase and report direction and rate.", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", metavar="CFG", help="YAML config (default: built-in defaults)")
    p.add_argument("--reference", metavar="REF",
                   help="reference file made by 'bladesonar reference' (without one: the "
                        "airflow only, from the first 23.8 s)")
    p.add_argument("--track", action="store_true",
                   help="print one JSON line per pulse with the running estimate")
    p.add_argument("wav", metavar="IN.wav", help="mono WAV recording")
    p.set_defaults(func=run)


#: Samples the airflow stage reads (the first 2^20: 23.8 s at 44.1 kHz; memory stays
#: bounded whatever the recording's length).
AIRFLOW_SAMPLES = 1 << 20


def _airflow(x: Any, cfg: Any, *, quiet_errors: bool = False) -> dict[str, Any]:
    """The airflow keys; with ``quiet_errors`` a recording the stage cannot use gives
    ``unknown`` with the reason instead of an error (the reference's answer still
    stands)."""
    from ..airflow_recording import airflow_keys, recording_airflow
    from ..errors import InputError

    try:
        a = recording_airflow(x, cfg)
    except InputError as exc:
        if not quiet_errors:
            raise
        return dict(airflow="unknown", airflow_confidence=0.0, airflow_rotation=None,
                    airflow_reason=str(exc))
    return airflow_keys(a, cfg)


def run(args: argparse.Namespace) -> int:
    from ..io.config_file import load_config
    from ..io.wav import read_wav

    cfg = load_config(args.config)
    if args.reference is None:
        if args.track:
            from ..errors import ConfigError
            raise ConfigError("--track", True, "needs --reference REF (the per-pulse track "
                              "follows the reference's angles)")
        x, _ = read_wav(args.wav, expect_rate=cfg.audio.sample_rate,
                        max_samples=AIRFLOW_SAMPLES, cut=True)
        print(json.dumps(_airflow(x, cfg)))
        return 0
    return _with_reference(args, cfg)


def _with_reference(args: argparse.Namespace, cfg: Any) -> int:
    from ..io.reference import load_reference
    from ..io.wav import stream_wav
    from ..offline import analyze

    ref = load_reference(args.reference)
    # read in blocks: memory independent of the recording's length (rows aside)
    with stream_wav(args.wav, expect_rate=cfg.audio.sample_rate) as blocks:
        summary, rows = analyze(blocks, cfg, ref, track=args.track)
    if args.track:
        out = sys.stdout
        for row in rows:
            out.write(json.dumps(row) + "\n")
    else:
        # the airflow stage's samples read again once analyze is done and aligned as
        # they are read: none held during analyze, nor all at once after it
        with stream_wav(args.wav, expect_rate=cfg.audio.sample_rate) as blocks:
            air = _airflow(_head(blocks), cfg, quiet_errors=True)
        print(json.dumps({**summary, **air}))
    return 0


def _head(blocks: Iterator[Any]) -> Iterator[Any]:
    """The blocks of the first ``AIRFLOW_SAMPLES`` samples (no warning that it is cut)."""
    n = 0
    for b in blocks:
        if n >= AIRFLOW_SAMPLES:
            return
        yield b[:AIRFLOW_SAMPLES - n]
        n += len(b)
