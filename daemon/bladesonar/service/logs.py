"""Logging set-up for the daemon: the systemd journal when run as a service, stderr otherwise.

``setup_logging(debug)`` is called once by ``bladesonar run`` (the entry point owns
logging configuration; modules only ``getLogger(__name__)``). It picks one handler:

- ``journal``: ``systemd.journal.JournalHandler`` with ``SYSLOG_IDENTIFIER=bladesonar``,
  when stderr is the journal stream systemd connected (``JOURNAL_STREAM`` names stderr's
  device and inode, as systemd.exec(5) documents for exactly this choice) and
  systemd-python is installed. Records then carry their priority, logger name
  (``LOGGER=``) and source location as journal fields; the journal adds the timestamps.
- ``stderr``: a StreamHandler with ``"%(asctime)s %(levelname)s %(name)s: %(message)s"``;
  the time stamp is left out when stderr is the journal stream anyway (no systemd-python).

``INVOCATION_ID`` alone is not taken as a sign of the journal: systemd sets it for every
unit, also when stderr goes to a file or a terminal (StandardError=), where the user looks
for the log. ``BLADESONAR_LOG=stderr|journal`` overrides the choice (``auto`` or unset:
as above).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Mapping
from typing import TextIO

#: Journal identifier (``journalctl -t bladesonar``; the unit name works too).
SYSLOG_IDENTIFIER = "bladesonar"
STDERR_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
JOURNAL_FORMAT = "%(levelname)s %(name)s: %(message)s"
#: Marks the handlers this module installed (so a second call replaces, not adds).
_MARK = "_bladesonar_handler"


def stderr_is_journal(env: Mapping[str, str], stream: TextIO) -> bool:
    """True if ``stream`` is the journal stream systemd connected (``JOURNAL_STREAM``)."""
    value = env.get("JOURNAL_STREAM", "")
    try:
        dev, ino = (int(v) for v in value.split(":"))
        st = os.fstat(stream.fileno())
    except (ValueError, OSError, AttributeError):
        # no or malformed JOURNAL_STREAM, or a stream without a file descriptor (pytest)
        return False
    return (st.st_dev, st.st_ino) == (dev, ino)


def _journal_handler() -> logging.Handler | None:
    try:
        from systemd.journal import JournalHandler
    except ImportError:
        return None
    handler: logging.Handler = JournalHandler(SYSLOG_IDENTIFIER=SYSLOG_IDENTIFIER)
    return handler


def choose_target(env: Mapping[str, str], stream: TextIO) -> str:
    """``"journal"`` or ``"stderr"``, from ``BLADESONAR_LOG`` and ``JOURNAL_STREAM``."""
    forced = env.get("BLADESONAR_LOG", "auto").strip().lower() or "auto"
    if forced in ("stderr", "journal"):
        return forced
    if forced != "auto":
        # logging is not set up yet; this one line goes straight to stderr
        print(f"bladesonar: BLADESONAR_LOG={forced!r} is not stderr, journal or auto; "
              "using auto", file=sys.stderr)
    return "journal" if stderr_is_journal(env, stream) else "stderr"


def _is_plain_stderr_handler(h: logging.Handler) -> bool:
    """A handler logging.basicConfig() made on stderr (the CLI's fallback set-up)."""
    return (type(h) is logging.StreamHandler
            and getattr(h, "stream", None) in (sys.stderr, sys.__stderr__))


def setup_logging(debug: bool = False, *, env: Mapping[str, str] | None = None,
                  stream: TextIO | None = None) -> logging.Handler:
    """Configure the root logger for the daemon and return the handler installed.

    Parameters
    ----------
    debug
        DEBUG level instead of INFO.
    env
        Environment to read (default ``os.environ``).
    stream
        The stderr stream to log to and to compare with ``JOURNAL_STREAM``
        (default ``sys.stderr``).

    Idempotent: the handler a previous call installed, and a plain stderr handler from
    ``logging.basicConfig`` (the CLI installs one before dispatching), are replaced, so
    no line is printed twice. Other handlers (pytest's capture, a user's) are kept.
    """
    env = os.environ if env is None else env
    stream = sys.stderr if stream is None else stream
    root = logging.getLogger()
    for h in list(root.handlers):
        if getattr(h, _MARK, False) or _is_plain_stderr_handler(h):
            root.removeHandler(h)
            if getattr(h, _MARK, False):
                h.close()

    target = choose_target(env, stream)
    handler: logging.Handler | None = None
    if target == "journal":
        handler = _journal_handler()
        if handler is not None:
            handler.setFormatter(logging.Formatter(JOURNAL_FORMAT))
    if handler is None:
        # stderr, or the journal asked for without systemd-python (stderr is still
        # captured by the journal under systemd, just without the fields)
        handler = logging.StreamHandler(stream)
        fmt = JOURNAL_FORMAT if stderr_is_journal(env, stream) else STDERR_FORMAT
        handler.setFormatter(logging.Formatter(fmt))
    setattr(handler, _MARK, True)
    root.addHandler(handler)
    root.setLevel(logging.DEBUG if debug else logging.INFO)
    if target == "journal" and type(handler) is logging.StreamHandler:
        logging.getLogger(__name__).warning(
            "journal logging needs systemd-python (pip install 'bladesonar[systemd]'); "
            "logging to stderr")
    return handler
