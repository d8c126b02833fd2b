"""The few exceptions bladesonar raises on purpose, each carrying what a user needs to fix it.

The command line turns any of these into one clear line on stderr and exit code 2;
anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

from .text import short_repr


class BladesonarError(Exception):
    """Base class: a problem with the user's input, configuration or environment."""

    exit_code = 2


class ConfigError(BladesonarError):
    """A configuration value is missing, malformed or out of range."""

    def __init__(self, key: str, value: object, allowed: str, *, source: str | None = None,
                 line: int | None = None) -> None:
        key = _printable(str(key), 80)
        self.key, self.value, self.allowed = key, value, allowed
        self.source, self.line = source, line
        where = ""
        if source:
            source = _printable(str(source), 4096)
            where = f"{source}:{line}: " if line else f"{source}: "
        # a value's repr is bounded (it may be huge); a file named by --config, --scene,
        # --out or <yaml> is shown whole (up to PATH_MAX)
        limit = 4096 if key in ("--config", "--scene", "--out", "<yaml>") else 80
        super().__init__(f"{where}{key} = {short_repr(value, limit)}: {allowed}")


def _printable(s: str, limit: int) -> str:
    """``s`` on one line (control characters escaped), cut to ``limit`` characters."""
    if not s.isprintable():
        s = s.encode("unicode_escape").decode("ascii")
    return s if len(s) <= limit else s[:limit - 3] + "..."


class InputError(BladesonarError):
    """A recording (WAV file or audio stream) cannot be analysed as it is."""


class ReferenceFileError(BladesonarError):
    """A reference file is missing, corrupt, or was made with other config values."""


class ReferenceMissingError(ReferenceFileError):
    """There is no reference file (yet): the daemon waits for one, it is not invalid."""


class EstimationError(BladesonarError):
    """The data do not determine the answer (stationary target, aliasing, too few periods)."""


class AudioDeviceError(BladesonarError):
    """An audio device could not be opened or configured."""
