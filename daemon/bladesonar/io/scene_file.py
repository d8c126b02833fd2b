"""Read a scene YAML file into a validated ``Scene`` (the only file access of the simulator
besides the WAV and truth writers). Errors carry the file and line of the bad key."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..sim.scene import Scene
from ..sim.scene3d import Scene3D, is_3d_document


def _read(path: str | Path) -> tuple[Any, Any, Path]:
    from .safe_yaml import load_yaml_file

    p = Path(path)
    data, lines = load_yaml_file(p, key="--scene", example="config/scenes/paper-room.yaml")
    return data, lines, p


def load_scene(path: str | Path) -> Scene:
    """Parse and validate a 2-D scene file (see config/scenes/paper-room.yaml), with the
    limits of every bladesonar YAML file (io/safe_yaml.py)."""
    data, lines, p = _read(path)
    if is_3d_document(data):
        raise ConfigError("room.size", data["room"]["size"], "makes this a 3-D scene, which "
                          "only `bladesonar simulate` takes; give a 2-D floor plan (room."
                          "vertices, see config/scenes/paper-room.yaml)", source=str(p),
                          line=lines.get("room.size"))
    return Scene.from_mapping(data, source=str(p), lines=lines)


def load_any_scene(path: str | Path) -> Scene | Scene3D:
    """A 2-D floor plan, or a 3-D box room when ``room`` has ``size``
    (config/scenes/living-room-3d.yaml)."""
    data, lines, p = _read(path)
    if is_3d_document(data):
        return Scene3D.from_mapping(data, source=str(p), lines=lines)
    return Scene.from_mapping(data, source=str(p), lines=lines)
