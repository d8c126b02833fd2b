"""Command-line entry point: parse, dispatch, and turn user errors into one clear line."""

from __future__ import annotations

import argparse
import logging
import sys

from . import __version__
from .blas import single_threaded_blas
from .commands import (
    analyze,
    check_config,
    plot,
    reference,
    report,
    retire,
    room,
    run,
    simulate,
)
from .errors import BladesonarError

#: The subcommands, in the order ``bladesonar --help`` lists them.
COMMANDS = (simulate, reference, analyze, plot, report, run, room, check_config, retire)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bladesonar",
        description="Rotation direction and rate of a fan from a pulsed sonar's multipath "
                    "echoes (M. Robinson's angular fingerprinting).")
    parser.add_argument("--version", action="version", version=f"bladesonar {__version__}")
    parser.add_argument("--debug", action="store_true", help="verbose logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.register(sub)
    return parser


#: Longest error message printed, characters: the last guard of "one line", whatever a
#: message embeds (paths are at most 4096).
MAX_ERROR_CHARS = 5000


def _one_line(msg: str) -> str:
    msg = " ".join(msg.split()) if "\n" in msg or "\r" in msg else msg
    return msg if len(msg) <= MAX_ERROR_CHARS else msg[:MAX_ERROR_CHARS - 3] + "..."


def main(argv: list[str] | None = None) -> int:
    single_threaded_blas()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not logging.getLogger().handlers:
        logging.basicConfig(level=logging.DEBUG if args.debug else logging.INFO,
                            format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    try:
        return int(args.func(args) or 0)
    except BladesonarError as exc:
        print(f"bladesonar {args.command}: error: {_one_line(str(exc))}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
