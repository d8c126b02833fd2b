"""``bladesonar run``: the device daemon (a systemd service, or in a terminal for the demo)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..config import Config
    from ..reference_build import Reference

EPILOG = """\
The daemon plays the pulse train and records through ALSA (audio.backend: alsa) or runs
against the in-process scene simulator (audio.backend: sim), tracks the fan against the
reference in daemon.state_dir, and publishes on MQTT (mqtt.host) or, with no broker
configured, prints the same messages as JSON lines on stdout.

Exit status: 0 after a stop, 78 for an invalid config file (systemd does not restart
it: RestartPreventExitStatus=78), 2 for other errors (retried by systemd).

Signals: SIGTERM/SIGINT stop gracefully (availability offline, devices closed); SIGHUP
re-reads the config (a bad new config is logged and the old one keeps running) and the
reference. A missing or invalid reference is never an exit: the daemon publishes the
status (reference_missing, reference_invalid with the reason) and waits for a valid one;
a replaced or deleted reference file is noticed within a few seconds without SIGHUP.

examples:
  bladesonar run --config /etc/bladesonar/bladesonar.yaml
  bladesonar run --config config/demo.yaml --seconds 60
"""


#: Exit status of ``run`` for an invalid config file (sysexits EX_CONFIG).
EXIT_CONFIG = 78


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("run", help="the device daemon: play, record, track, publish",
                       description="Run the sonar daemon.", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", required=True, metavar="CFG", help="YAML config file")
    p.add_argument("--seconds", type=float, metavar="S",
                   help="stop by itself after S seconds (demo, tests); default: run until "
                        "stopped")
    p.set_defaults(func=run)


def load_reference_for(cfg: Config) -> Reference:
    """The daemon's reference, validated, checked against the running config, with the
    id of the bytes it was read from."""
    from ..io.reference import read_reference
    from ..reference_build import check_compatible

    ref, digest = read_reference(cfg.reference_path)
    check_compatible(ref, cfg)
    ref.meta["id"] = digest[:12]
    return ref


def run(args: argparse.Namespace) -> int:
    # Before anything slow (imports of numpy, the config, the broker): a SIGHUP's default
    # action is to terminate, so one sent early (systemctl reload during start) would kill
    # the daemon. Remember it and reload once the service runs.
    import signal

    early_hup = {"seen": False}     # a plain store: a handler must take no lock

    def on_early_hup(*_: object) -> None:
        early_hup["seen"] = True

    signal.signal(signal.SIGHUP, on_early_hup)

    # before the MQTT client is imported: what it imports but seldom uses is loaded only
    # when used (6.7 MiB of resident memory: service/deferred_imports.py)
    from ..service.deferred_imports import defer
    defer()

    import logging

    from ..errors import ConfigError, InputError
    from ..io.config_file import load_config
    from ..live import LiveAnalyzer
    from ..service.backends import open_audio
    from ..service.logs import setup_logging
    from ..service.notify import make_notifier
    from ..service.publish import make_publisher
    from ..service.runner import Service

    setup_logging(getattr(args, "debug", False))
    if args.seconds is not None and args.seconds <= 0:
        raise InputError(f"--seconds {args.seconds:g}: give a positive duration")
    try:
        cfg = load_config(args.config)
    except ConfigError as exc:
        # EX_CONFIG: the unit's RestartPreventExitStatus stops a restart loop on a bad file
        exc.exit_code = EXIT_CONFIG
        raise
    from ..io.files import STALE_TEMP_S, remove_stale_temps

    # a kill -9 during a reference write leaves a hidden temporary file; younger ones may
    # belong to a 'bladesonar reference --live' writing now
    for q in remove_stale_temps(cfg.reference_path, older_than_s=STALE_TEMP_S):
        logging.getLogger(__name__).info("removed %s, left by an interrupted write", q)
    svc = Service(cfg, config_path=args.config, audio_factory=open_audio,
                  publisher_factory=make_publisher,
                  analyzer_factory=lambda c, r: LiveAnalyzer(
                      c, r, reference_id=r.meta.get("id"),
                      block_pulses=c.daemon.block_pulses),
                  reference_loader=load_reference_for, notifier=make_notifier(),
                  max_seconds=args.seconds)
    svc.install_signal_handlers()
    if early_hup["seen"]:
        svc.request_reload()
    return svc.run()
