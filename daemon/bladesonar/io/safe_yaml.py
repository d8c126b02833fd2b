"""The one YAML reader of config and scene files, with its limits decided before parsing.

- at most :data:`MAX_BYTES` read (``/dev/zero`` or a huge file is refused, not read);
- UTF-8 only, a bad byte named by line and column;
- no aliases (``*name``): they are what makes a 4 kB "billion laughs" expand to gigabytes,
  and a config never needs them; refused while scanning, before anything is built;
- nesting at most :data:`MAX_DEPTH` deep, checked on the event stream before the
  (recursive) composer runs, so no RecursionError;
- YAML errors reduced to one line (problem, line, column), user values in messages cut
  to 80 characters (errors.ConfigError).

Returns the parsed data and the line of every mapping key (dotted), for error messages.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..text import human_bytes, one_line
from .files import NotAFile, TooLarge, read_capped

#: Largest config or scene file, bytes. The commented example with every key is 7 kB;
#: parsing 256 KiB takes about a second with libyaml (several without).
MAX_BYTES = 256 << 10
#: Deepest nesting of mappings and lists (a config is 2 deep, a scene 4).
MAX_DEPTH = 16


def _loader() -> type:
    import yaml

    return getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _one_line(exc: Exception) -> tuple[str, int | None]:
    """A YAML exception as one line and the 1-based line it points at."""
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    problem = getattr(exc, "problem", None) or getattr(exc, "context", None) or str(exc)
    if mark is not None:
        return f"{one_line(problem)} (column {mark.column + 1})", mark.line + 1
    return one_line(problem), None


def _check_events(text: str, loader: type, key: str, source: str) -> None:
    """Refuse aliases and deep nesting from the event stream (cheap, non-recursive)."""
    import yaml

    depth = 0
    for ev in yaml.parse(text, Loader=loader):
        if isinstance(ev, yaml.AliasEvent):
            line = ev.start_mark.line + 1 if ev.start_mark else None
            raise ConfigError("<yaml>", source, f"uses a YAML alias "
                              f"(*{one_line(ev.anchor, 40)}); aliases are not accepted in "
                              "bladesonar files: write the value out", source=source,
                              line=line)
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_DEPTH:
                line = ev.start_mark.line + 1 if ev.start_mark else None
                raise ConfigError("<yaml>", source, f"nests deeper than {MAX_DEPTH} levels; "
                                  f"{key} files are a few levels deep: check the "
                                  "indentation and brackets", source=source, line=line)
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1


def parse_yaml(text: str, *, source: str, key: str = "--config") -> tuple[Any, dict[str, int]]:
    """Parse YAML text with the limits above (pure): data and the line of every key."""
    import yaml

    if len(text) > MAX_BYTES:
        raise ConfigError(key, source, f"is larger than {human_bytes(MAX_BYTES)}; "
                          f"a bladesonar {key.lstrip('-')} file is a few kB")
    loader_cls = _loader()
    try:
        _check_events(text, loader_cls, key.lstrip("-"), source)
        loader = loader_cls(text)
        try:
            node = loader.get_single_node()
            data = loader.construct_document(node) if node is not None else None
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        problem, line = _one_line(exc)
        raise ConfigError("<yaml>", source, f"is not valid YAML: {problem}", source=source,
                          line=line) from None
    except (ValueError, OverflowError, RecursionError, TypeError) as exc:
        # e.g. an integer of more than 4300 digits, or a key that cannot be hashed
        why = ("a number of more than 4300 digits" if "digits" in str(exc)
               else one_line(str(exc), 100))
        raise ConfigError("<yaml>", source, f"holds a value bladesonar cannot read ({why})",
                          source=source) from None
    lines: dict[str, int] = {}

    def walk(n: Any, prefix: str, depth: int) -> None:
        if isinstance(n, yaml.MappingNode) and depth < MAX_DEPTH:
            for k, v in n.value:
                if isinstance(k, yaml.ScalarNode):
                    name = f"{prefix}{k.value}"
                    lines[name] = k.start_mark.line + 1
                    walk(v, name + ".", depth + 1)

    walk(node, "", 0)
    return data, lines


def decode(raw: bytes, *, source: str, key: str = "--config") -> str:
    """UTF-8 text, a bad byte named by its line and column."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        col = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ConfigError(key, source, f"is not UTF-8 text (byte {raw[exc.start]:#04x} at "
                          f"column {col}); save it as UTF-8", source=source,
                          line=line) from None


def load_yaml_file(path: str | Path, *, key: str = "--config",
                   example: str = "config/bladesonar.example.yaml") -> tuple[Any, dict[str, int]]:
    """Read (at most MAX_BYTES), decode and parse a YAML file."""
    p = Path(path)
    try:
        raw = read_capped(p, MAX_BYTES)
    except TooLarge:
        raise ConfigError(key, str(path), f"is larger than {human_bytes(MAX_BYTES)} (a "
                          f"bladesonar {key.lstrip('-')} file is a few kB); give a YAML "
                          f"file such as {example}") from None
    except NotAFile as exc:
        raise ConfigError(key, str(path), f"{exc}; give the path of a YAML file such as "
                          f"{example}") from None
    except OSError as exc:
        raise ConfigError(key, str(path), f"cannot be read ({exc.strerror or exc}); give the "
                          f"path of a YAML file such as {example}") from None
    return parse_yaml(decode(raw, source=str(p), key=key), source=str(p), key=key)
