"""The one schema helper of bladesonar's YAML documents (config and scene files; pure).

A document section is a frozen dataclass whose fields are declared with :func:`opt`:
default, a one-line doc (with unit) and the allowed domain. :func:`build` walks those
declarations: a section must be a mapping, an unknown key is refused with the keys known
there (and the closest one), each value is checked against its type and domain, nested
sections are built the same way. Every refusal is one :class:`ConfigError` naming the
file and line (from ``lines``, the dotted key -> line map of io/safe_yaml.py), the key,
the bad value and what is allowed. Checks that span several values (a gate's two ends,
a room's walls) stay with the document that has them.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable, Mapping
from dataclasses import field
from typing import Any

from .errors import ConfigError

#: Longest text value (names, paths, schedules), characters: a topic, a file name or a
#: PCM name is far shorter; a longer one is a mistake, not a setting.
MAX_TEXT = 1024


def opt(default: Any, doc: str, *, lo: float | None = None, hi: float | None = None,
        choices: tuple[Any, ...] | None = None, unit: str | None = None,
        nullable: bool = False, pattern: str | None = None, lo_open: bool = False,
        note: str | None = None, max_len: int = MAX_TEXT) -> Any:
    """Declare a document field: default, one-line doc, and its allowed domain (``note``:
    said in brackets after a refusal: what the value means or what to do instead;
    ``max_len``: longest text value, characters)."""
    return field(default=default, metadata=dict(
        doc=doc, lo=lo, hi=hi, choices=choices, unit=unit, nullable=nullable,
        pattern=pattern, lo_open=lo_open, note=note, max_len=max_len))


def number_text(x: float) -> str:
    """A range end as written: 4 not 4.0, 0.5, 1e+06."""
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


def allowed_text(md: Mapping[str, Any], what: str) -> str:
    """'must be a number from 0 to 1 m' from a field's metadata."""
    lo, hi, unit = md.get("lo"), md.get("hi"), md.get("unit")
    u = f" {unit}" if unit else ""
    if lo is not None and hi is not None:
        lo_word = "above" if md.get("lo_open") else "from"
        return f"must be {what} {lo_word} {number_text(lo)} to {number_text(hi)}{u}"
    return f"must be {what}"


def base_type(f: dataclasses.Field[Any]) -> type | None:
    """bool, int, float or str from a field's annotation (``int | None`` is int); None:
    any value (checked by the document itself)."""
    s = str(f.type)
    for name, tp in (("bool", bool), ("int", int), ("float", float), ("str", str)):
        if s.startswith(name):
            return tp
    return None


def check_value(key: str, f: dataclasses.Field[Any], value: Any,  # noqa: C901  one case a type
                lines: Mapping[str, int],
                source: str | None) -> Any:
    """``value`` of the field ``f`` at dotted ``key`` checked against its declaration;
    returns it as its type (an integral float as an int, an int as a float)."""
    md = f.metadata
    note = f" ({md['note']})" if md.get("note") else ""
    given = value   # named in a refusal as written

    def fail(allowed: str) -> None:
        raise ConfigError(key, given, allowed + note, source=source, line=lines.get(key))

    if value is None:
        if md.get("nullable"):
            return None
        fail(f"must not be empty ({md['doc']})")
    tp = base_type(f)
    if tp is bool:
        if not isinstance(value, bool):
            fail("must be true or false")
    elif tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                fail(allowed_text(md, "an integer"))
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            fail(allowed_text(md, "a number"))
        value = float(value)
        if value != value or value in (float("inf"), float("-inf")):
            fail(allowed_text(md, "a finite number"))
    elif tp is str:
        if not isinstance(value, str) or not value:
            fail(allowed_text(md, "a non-empty string"))
        longest = md.get("max_len", MAX_TEXT)
        if len(value) > longest:
            fail(f"must be at most {longest} characters long (this one has {len(value)})")
    if md.get("choices") is not None and value not in md["choices"]:
        import difflib  # only for an invalid config: kept out of the daemon's memory

        close = difflib.get_close_matches(str(value), [str(c) for c in md["choices"]], 1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        fail(f"must be one of {', '.join(map(str, md['choices']))}{hint}")
    lo, hi = md.get("lo"), md.get("hi")
    if tp in (int, float):
        if (lo is not None and (value < lo or (md.get("lo_open") and value == lo))) or (
                hi is not None and value > hi):
            fail(allowed_text(md, "an integer" if tp is int else "a number"))
    if md.get("pattern") and not re.fullmatch(md["pattern"], value):
        fail(f"must match {md['pattern']}")
    return value


def check_keys(data: Mapping[Any, Any], known: Iterable[str], prefix: str,
               lines: Mapping[str, int], source: str | None, *,
               what: str = "unknown key") -> None:
    """Refuse a key of ``data`` that is not in ``known``, naming the keys known there
    and the closest one (``prefix``: the section's dotted path with its dot)."""
    known = list(known)
    for k in data:
        if k not in known:
            import difflib

            close = difflib.get_close_matches(str(k), known, 1)
            hint = f"; did you mean {prefix}{close[0]}?" if close else ""
            raise ConfigError(f"{prefix}{k}", data[k],
                              f"{what} (known here: {', '.join(known)}){hint}",
                              source=source, line=lines.get(f"{prefix}{k}"))


def fields_of(cls: type) -> dict[str, dataclasses.Field[Any]]:
    """A section's declared fields by name (not the ``internal`` ones a file never sets)."""
    return {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}


def section_type(f: dataclasses.Field[Any]) -> type | None:
    """The dataclass of a nested section (a field whose default_factory is one), else
    None."""
    fac = f.default_factory
    if fac is not dataclasses.MISSING and isinstance(fac, type) and dataclasses.is_dataclass(fac):
        return fac
    return None


def build(cls: type, data: Any, prefix: str, lines: Mapping[str, int],
          source: str | None) -> Any:
    """The section ``cls`` from ``data`` (None: all defaults), every key and value
    checked; ``prefix`` is the section's dotted path with its dot ('' at the top)."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(prefix.rstrip(".") or "<top>", data, "must be a mapping of keys",
                          source=source, line=lines.get(prefix.rstrip(".")))
    fields = fields_of(cls)
    check_keys(data, fields, prefix, lines, source)
    kwargs = {}
    for name, f in fields.items():
        key = f"{prefix}{name}"
        section = section_type(f)
        if section is not None:
            kwargs[name] = build(section, data.get(name), key + ".", lines, source)
        elif name in data:
            kwargs[name] = check_value(key, f, data[name], lines, source)
    return cls(**kwargs)
