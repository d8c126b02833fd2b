"""``bladesonar check-config``: validate a config file and exit, like a CI lint step."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("check-config", help="validate a YAML config and print the result",
                       description="Validate a YAML config file: unknown keys, types and "
                                   "ranges, with file and line. Exit 0 if valid, 2 if not.")
    p.add_argument("--config", required=True, metavar="CFG", help="YAML config file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..io.config_file import load_config

    cfg = load_config(args.config)
    print(f"{args.config}: ok (device_id={cfg.device_id}, backend={cfg.audio.backend}, "
          f"PRF {cfg.prf_hz:.4f} Hz, max range {cfg.max_range_m:.2f} m)")
    return 0
