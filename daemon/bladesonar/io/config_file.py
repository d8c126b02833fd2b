"""Read a YAML config file into the validated ``Config`` (config.py builds and checks it;
this edge reads the file). Errors carry the file and line of the bad key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..config import Config, from_mapping
from .safe_yaml import load_yaml_file


def load_config(path: str | Path | None) -> Config:
    """Read and validate a YAML config file; None gives the defaults. The file is read
    and parsed with hard limits (size, UTF-8, no aliases, depth): io/safe_yaml.py.
    Relative paths in it are taken from the file's folder (``Config.base_dir``)."""
    if path is None:
        return Config()
    p = Path(path)
    data, lines = load_yaml_file(p, key="--config")
    cfg = from_mapping(data, source=str(p), lines=lines)
    return dataclasses.replace(cfg, base_dir=str(p.resolve().parent))
