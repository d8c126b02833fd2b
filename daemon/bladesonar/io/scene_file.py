"""Read a scene YAML file into a validated ``Scene`` (the only file access of the simulator
besides the WAV and truth writers). Errors carry the file and line of the bad key."""

from __future__ import annotations

from pathlib import Path

from ..sim.scene import Scene


def load_scene(path: str | Path) -> Scene:
    """Parse and validate a scene file (see config/scenes/paper-room.yaml), with the
    limits of every bladesonar YAML file (io/safe_yaml.py)."""
    from .safe_yaml import load_yaml_file

    p = Path(path)
    data, lines = load_yaml_file(p, key="--scene", example="config/scenes/paper-room.yaml")
    return Scene.from_mapping(data, source=str(p), lines=lines)
