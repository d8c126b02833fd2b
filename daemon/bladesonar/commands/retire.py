"""``bladesonar retire``: take the device out of Home Assistant and off the broker."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("retire", help="remove the device from Home Assistant and its "
                                      "retained MQTT topics",
                       description="Publish an empty retained payload on the device's "
                                   "Home Assistant discovery config (Home Assistant then "
                                   "deletes the device and all its entities), on any "
                                   "per-entity config of an earlier version, and on the "
                                   "retained state, status, stats and availability topics. "
                                   "Stop the daemon first: it announces itself again when "
                                   "it (re)connects.")
    p.add_argument("--config", required=True, metavar="CFG", help="YAML config file")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for the broker (default 10)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from ..io.config_file import load_config
    from ..service.publish import retire

    cfg = load_config(args.config)
    cleared = retire(cfg, timeout=args.timeout)
    print(json.dumps({"device_id": cfg.device_id, "cleared": cleared}))
    return 0
