"""settings_store.py: settings changed from Home Assistant, checked like the YAML, kept
across restarts, and the YAML's value as the default."""

from __future__ import annotations

import dataclasses
import json
import logging

import pytest

from bladesonar import config
from bladesonar.errors import ConfigError
from bladesonar.service import settings_store as S
from bladesonar.service.notify import NullNotifier
from bladesonar.service.runner import Service


def cfg_for(tmp_path, **reference):
    cfg = config.from_mapping({"daemon": {"state_dir": str(tmp_path / "state")},
                               "reference": reference})
    return dataclasses.replace(cfg, base_dir=str(tmp_path))


def test_a_value_is_checked_like_the_yaml(tmp_path):
    cfg = cfg_for(tmp_path)
    with pytest.raises(ConfigError, match="reference.learn_seconds = 100.0: must be a "
                                          "number from 3 to 60 s"):
        S.change(cfg, cfg, {}, "learn_seconds", 100.0)
    # the cross check of the file: at most 2^20 samples at 44.1 kHz
    with pytest.raises(ConfigError, match="at most 23.8 s"):
        S.change(cfg, cfg, {}, "learn_seconds", 30.0)
    with pytest.raises(ConfigError, match="reference.stale_fit"):
        S.change(cfg, cfg, {}, "stale_fit", 1.5)
    with pytest.raises(ConfigError, match="not a setting"):
        S.change(cfg, cfg, {}, "min_quality", 0.1)
    new, stored = S.change(cfg, cfg, {}, "auto_learn", False)
    assert new.reference.auto_learn is False and cfg.reference.auto_learn is True
    assert stored == {"auto_learn": {"value": False, "yaml": True}}


def test_stored_values_survive_a_restart_until_the_yaml_changes(tmp_path, caplog):
    cfg = cfg_for(tmp_path, learn_seconds=20)
    _, stored = S.change(cfg, cfg, {}, "learn_seconds", 12.0)
    path = S.path_for(cfg)
    S.save(path, stored)
    assert json.loads(path.read_text()) == {"learn_seconds": {"value": 12.0, "yaml": 20.0}}
    again, kept = S.apply(cfg_for(tmp_path, learn_seconds=20), S.load(path))
    assert again.reference.learn_seconds == 12.0 and kept == stored
    # someone edited the file since: the file wins, the older choice is dropped
    caplog.set_level(logging.INFO)
    edited, kept = S.apply(cfg_for(tmp_path, learn_seconds=15), S.load(path))
    assert edited.reference.learn_seconds == 15.0 and kept == {}
    assert "now says 15.0" in caplog.text


def test_a_damaged_file_leaves_the_yaml_in_force(tmp_path, caplog):
    cfg = cfg_for(tmp_path)
    path = S.path_for(cfg)
    path.parent.mkdir(parents=True)
    for text in ("{not json", "[1, 2]", json.dumps({"learn_seconds": {"value": "x",
                                                                      "yaml": 20.0}})):
        path.write_text(text)
        got, kept = S.apply(cfg, S.load(path))
        assert got == cfg and kept == {}
    assert "cannot be read" in caplog.text


def test_the_daemon_starts_with_the_stored_settings(tmp_path):
    cfg = cfg_for(tmp_path, stale_fit=0.6)
    _, stored = S.change(cfg, cfg, {}, "stale_fit", 0.45)
    S.save(S.path_for(cfg), stored)

    def unused(*_a):
        raise AssertionError("not started in this test")

    svc = Service(cfg, config_path=None, audio_factory=unused, publisher_factory=unused,
                  analyzer_factory=unused, reference_loader=unused, notifier=NullNotifier())
    assert svc.cfg.reference.stale_fit == 0.45
    assert S.current(svc.cfg) == {"auto_learn": True, "learn_seconds": 20.0,
                                  "stale_fit": 0.45}
