"""Settings changed from Home Assistant, kept across restarts beside the reference.

A user tunes ``reference.auto_learn``, ``learn_seconds`` and ``stale_fit`` from Home
Assistant's config entities (messages.SETTINGS). Each value is checked like the YAML
(config.replace: type, range, cross checks) and stored in ``<daemon.state_dir>/
settings.json`` with the YAML's value at that time. The YAML's value is the default:
a stored value applies only while the YAML still says what it said when the value was
set, so an edit of the config file wins over an older choice made in Home Assistant.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from .. import config as config_mod
from ..errors import ConfigError
from ..io.files import NotAFile, TooLarge, atomic_writer, read_capped
from .messages import SETTINGS

log = logging.getLogger(__name__)

FILE_NAME = "settings.json"
#: Largest settings file read, bytes (it holds three numbers).
MAX_BYTES = 16 << 10


def path_for(cfg: config_mod.Config) -> Path:
    return cfg.path(cfg.daemon.state_dir) / FILE_NAME


def current(cfg: config_mod.Config) -> dict[str, Any]:
    """The settings in force, as the status message shows them."""
    return {k: getattr(cfg.reference, k) for k in SETTINGS}


def load(path: Path) -> dict[str, dict[str, Any]]:
    """{key: {"value": v, "yaml": the YAML's value then}}; {} when absent or unreadable
    (logged: a damaged file must not stop the daemon; the YAML applies)."""
    try:
        data = json.loads(read_capped(path, MAX_BYTES).decode("utf-8"))
    except FileNotFoundError:
        return {}
    except (OSError, TooLarge, NotAFile, UnicodeDecodeError, ValueError) as exc:
        log.warning("settings from Home Assistant in %s cannot be read (%s); using the "
                    "config file's values", path, exc)
        return {}
    if not isinstance(data, dict):
        return {}
    return {k: v for k, v in data.items()
            if k in SETTINGS and isinstance(v, dict) and "value" in v and "yaml" in v}


def apply(yaml_cfg: config_mod.Config, stored: dict[str, dict[str, Any]]
          ) -> tuple[config_mod.Config, dict[str, dict[str, Any]]]:
    """``yaml_cfg`` with the stored values whose YAML value is unchanged; (config, the
    stored entries still in force). An entry that no longer validates is dropped."""
    keep: dict[str, dict[str, Any]] = {}
    for key, entry in stored.items():
        if getattr(yaml_cfg.reference, key) != entry["yaml"]:
            log.info("reference.%s: the config file now says %r; the value %r set from "
                     "Home Assistant is dropped", key, getattr(yaml_cfg.reference, key),
                     entry["value"])
            continue
        keep[key] = entry
    if not keep:
        return yaml_cfg, {}
    try:
        cfg = config_mod.replace(yaml_cfg, reference={k: e["value"] for k, e in keep.items()})
    except ConfigError as exc:
        log.warning("settings from Home Assistant dropped: %s", exc)
        return yaml_cfg, {}
    return cfg, keep


def change(cfg: config_mod.Config, yaml_cfg: config_mod.Config,
           stored: dict[str, dict[str, Any]], key: str, value: Any
           ) -> tuple[config_mod.Config, dict[str, dict[str, Any]]]:
    """The config with ``reference.<key>`` = ``value``, checked like the YAML, and the
    stored entries to write. Raises ConfigError (naming the key, value and range)."""
    if key not in SETTINGS:
        raise ConfigError(f"reference.{key}", value,
                          f"is not a setting Home Assistant can change; one of "
                          f"{', '.join(SETTINGS)}")
    if key == "learn_seconds" or key == "stale_fit":
        value = float(value)
    new = config_mod.replace(cfg, reference={key: value})
    out = dict(stored)
    out[key] = {"value": getattr(new.reference, key), "yaml": getattr(yaml_cfg.reference, key)}
    return new, out


def save(path: Path, stored: dict[str, dict[str, Any]]) -> None:
    """Write atomically (a power cut leaves the old file or the new one)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_writer(path) as f:
        f.write(json.dumps(stored, indent=1, sort_keys=True).encode("utf-8"))
