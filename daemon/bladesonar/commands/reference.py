"""``bladesonar reference``: fold a recording of the turning fan into a reference file.

A thin edge: read the config and the WAV, build the reference (reference_build.build_reference),
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

Without --direction the airflow measured on the recording sets the direction when it is
confident (down: scene.downdraft_rotation, up: the other way; docs/airflow.md), else it
stays unknown; the summary's airflow keys and direction_source (given, airflow or none)
say which. A --direction that a confident airflow contradicts is stored, with a warning
that has the figures.

examples:
  bladesonar reference --config cfg.yaml --out ref.npz reference.wav
  bladesonar reference --config cfg.yaml --direction ccw --out ref.npz reference.wav
  bladesonar reference --live --seconds 20 --direction ccw --config /etc/bladesonar/bladesonar.yaml

With --live the recording is made through the daemon's own audio path (audio.backend) and
the reference is stored atomically where the daemon looks for it (daemon.state_dir /
daemon.reference) unless --out says otherwise; a running daemon picks it up within a few
seconds or at once on SIGHUP (systemctl reload bladesonar).
"""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("reference", help="make a reference (angular fingerprint) from a "
                       "recording of the fan turning steadily",
                       description="Estimate the blade period of a recording of the turning "
                       "fan, fold all its periods into an angular table and store it.",
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", metavar="CFG", help="YAML config (default: built-in defaults)")
    p.add_argument("--direction", choices=("cw", "ccw", "unknown"),
                   help="the fan's rotation during this recording, seen from the sensor "
                   "(below); default: from the airflow measured on the recording when it "
                   "is confident (scene.downdraft_rotation), else unknown")
    p.add_argument("--out", metavar="REF", help="reference file to write (.npz); default with "
                   "--live: the daemon's daemon.state_dir/daemon.reference")
    p.add_argument("--live", action="store_true", help="record through the configured audio "
                   "device (or the sim backend) instead of reading a WAV file")
    p.add_argument("--seconds", type=float, default=20.0, metavar="S", help="with --live: how "
                   "long to record, seconds (default 20, at most 2^20 samples: 23.8 s at 44.1 kHz; "
                   "at least analysis.min_periods blade periods must fit)")
    p.add_argument("--save-wav", metavar="WAV", help="with --live: also keep the recording")
    p.add_argument("wav", metavar="IN.wav", nargs="?", help="mono WAV recording (not with --live)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import logging

    from ..airflow_recording import reference_airflow
    from ..errors import InputError
    from ..io.config_file import load_config
    from ..io.reference import save_reference
    from ..io.wav import read_wav
    from ..reference_build import build_reference

    cfg = load_config(args.config)
    if args.live:
        if args.wav:
            raise InputError(f"give either --live or a recording ({args.wav}), not both")
        from ..io.wav import REFERENCE_SAMPLES

        # a reference uses at most what a recording file would give it (memory: building
        # one costs about 5 MiB per second of audio)
        longest = REFERENCE_SAMPLES / cfg.audio.sample_rate
        if not 0.5 <= args.seconds <= longest:
            raise InputError(f"--seconds {args.seconds:g}: record between 0.5 and "
                             f"{longest:.1f} s (20 s is plenty for a fan above 0.2 Hz)")
        from ..service.recorder import record

        x = record(cfg, args.seconds)
        if args.save_wav:
            from ..io.wav import WavWriter

            with WavWriter(args.save_wav, cfg.audio.sample_rate) as w:
                w.write(x)
        out_path = args.out or str(cfg.reference_path)
    else:
        if not args.wav or not args.out:
            raise InputError("give a recording and --out REF (or --live to record one)")
        from ..io.wav import REFERENCE_SAMPLES

        x, _ = read_wav(args.wav, expect_rate=cfg.audio.sample_rate,
                        max_samples=REFERENCE_SAMPLES, cut=True)
        out_path = args.out
    chosen = reference_airflow(x, cfg, args.direction)
    ref = build_reference(x, cfg, chosen.direction)
    if chosen.warnings:
        ref.meta["warnings"] = [*ref.meta.get("warnings", []), *chosen.warnings]
        for text in chosen.warnings:
            logging.getLogger(__name__).warning("%s", text)
    _remove_stale_temps(out_path)
    save_reference(ref, out_path)
    out = ref.summary()
    out.update(chosen.keys)
    out["out"] = str(out_path)
    print(json.dumps(out))
    return 0


def _remove_stale_temps(path: str) -> None:
    """Temporary files a killed write of ``path`` left behind (older than
    ``io.files.STALE_TEMP_S``) go before this write."""
    import logging

    from ..io.files import STALE_TEMP_S, remove_stale_temps

    for q in remove_stale_temps(path, older_than_s=STALE_TEMP_S):
        logging.getLogger(__name__).info("removed %s, left by an interrupted write", q)
