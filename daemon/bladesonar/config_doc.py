"""The commented example config, written from the schema itself so docs never drift.

``python -m bladesonar.config_doc > config/bladesonar.example.yaml`` regenerates it; a test
checks the committed file against the schema (every key, every default).
"""

from __future__ import annotations

import dataclasses
import json
from typing import TYPE_CHECKING, Any

from . import config
from .schema import number_text

if TYPE_CHECKING:
    from collections.abc import Mapping


def _domain(md: Mapping[str, Any]) -> str:
    parts = []
    if md.get("choices"):
        parts.append("one of " + ", ".join(map(str, md["choices"])))
    lo, hi = md.get("lo"), md.get("hi")
    if lo is not None and hi is not None:
        parts.append(f"{'>' if md.get('lo_open') else ''}{number_text(lo)}..{number_text(hi)}")
    if md.get("unit"):
        parts.append(md["unit"])
    if md.get("nullable"):
        parts.append("or null")
    return f" [{'; '.join(parts)}]" if parts else ""


def _yaml_value(v: object) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(v)


def example_yaml() -> str:
    """Every key with its default and a one-line doc, grouped by section."""
    lines = ["# bladesonar configuration: every key, its default and its allowed values.",
             "# Generated from daemon/bladesonar/config.py by `python -m bladesonar.config_doc`.",
             "# Keep only the keys you change; unknown keys are an error (with a suggestion).",
             ""]
    section = None
    for key, f in config.iter_fields():
        sec, _, name = key.rpartition(".")
        if sec != section:
            if sec:
                cls = type(getattr(config.Config(), sec))
                doc = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
                lines += ["", f"{sec}:" + (f"  # {doc}" if doc and "dataclass" not in doc
                                              and not doc.startswith(cls.__name__) else "")]
            section = sec
        indent = "  " if sec else ""
        default = f.default if f.default is not dataclasses.MISSING else None
        lines.append(f"{indent}# {f.metadata['doc']}{_domain(f.metadata)}")
        lines.append(f"{indent}{name}: {_yaml_value(default)}")
    return "\n".join(lines) + "\n"


def markdown_table() -> str:
    """The configuration reference as a Markdown table (for the README)."""
    rows = ["| key | default | allowed | meaning |", "|---|---|---|---|"]
    for key, f in config.iter_fields():
        default = f.default if f.default is not dataclasses.MISSING else None
        dom = _domain(f.metadata).strip(" []")
        rows.append(f"| `{key}` | `{_yaml_value(default)}` | {dom} | {f.metadata['doc']} |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(markdown_table() if "--markdown" in sys.argv else example_yaml(), end="")
