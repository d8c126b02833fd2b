"""Read a scene YAML file into a validated ``Scene`` (the only file access of the simulator
besides the WAV and truth writers). Errors carry the file and line of the bad key."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..sim.scene import Scene


def _yaml_lines(text: str) -> tuple[Any, dict[str, int]]:
    import yaml

    node = yaml.compose(text, Loader=yaml.SafeLoader)
    lines: dict[str, int] = {}

    def walk(n: Any, prefix: str) -> None:
        if isinstance(n, yaml.MappingNode):
            for k, v in n.value:
                key = f"{prefix}{k.value}"
                lines[key] = k.start_mark.line + 1
                walk(v, key + ".")

    if node is not None:
        walk(node, "")
    return yaml.safe_load(text), lines


def load_scene(path: str | Path) -> Scene:
    """Parse and validate a scene file (see config/scenes/paper-room.yaml)."""
    import yaml

    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError("--scene", str(path), f"cannot be read ({exc.strerror}); give a "
                          "scene YAML file such as config/scenes/paper-room.yaml") from exc
    try:
        data, lines = _yaml_lines(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise ConfigError("<yaml>", str(path), f"is not valid YAML: {exc}", source=str(p),
                          line=(mark.line + 1) if mark else None) from exc
    return Scene.from_mapping(data, source=str(p), lines=lines)
