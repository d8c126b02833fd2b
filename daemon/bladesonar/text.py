"""Text for one-line error messages: user values and library messages cut to a bounded
length without ever building them whole (a value may be huge or deeply nested). It
imports nothing of ours, so errors.py can use it.
"""

from __future__ import annotations

import reprlib

#: Longest repr of a user value inside an error message, characters.
MAX_REPR = 80

_repr = reprlib.Repr()
_repr.maxlevel = 2
_repr.maxstring = MAX_REPR
_repr.maxother = MAX_REPR
_repr.maxlong = 40
for _name in ("maxlist", "maxtuple", "maxdict", "maxset", "maxfrozenset", "maxdeque",
              "maxarray"):
    setattr(_repr, _name, 4)


def short_repr(value: object, limit: int = MAX_REPR) -> str:
    """repr() of a user value cut to ``limit`` characters, without ever building the full
    repr (a nested or huge value costs no more than a short one)."""
    try:
        s = repr(value[:limit]) if isinstance(value, str) else _repr.repr(value)
    except Exception:  # noqa: BLE001 - a repr that fails must not mask the real error
        s = f"<{type(value).__name__}>"
    s = s.replace("\n", "\\n")
    return s if len(s) <= limit else s[:limit - 3] + "..."


def one_line(text: object, limit: int = 120) -> str:
    """``text`` on one line, cut to ``limit`` characters (a library's message in ours)."""
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[:limit - 3] + "..."


def human_bytes(n: int) -> str:
    """1048576 -> '1 MiB' (for limits in messages)."""
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            v = n / size
            return f"{v:.0f} {unit}" if v == int(v) else f"{v:.1f} {unit}"
    return f"{n} bytes"
