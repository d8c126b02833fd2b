"""Config validation: every rejected value names the key, the value and the allowed range."""

from __future__ import annotations

import subprocess
import sys

import pytest

from bladesonar import config
from bladesonar.errors import ConfigError
from bladesonar.io.config_file import load_config


@pytest.mark.parametrize("data, key, words", [
    ({"scene": {"blades": 0}}, "scene.blades", "from 1 to 16"),
    ({"scene": {"blade": 3}}, "scene.blade", "did you mean scene.blades"),
    ({"audio": {"backend": "pulse"}}, "audio.backend", "one of alsa, pipewire, auto, sim"),
    ({"audio": {"sample_rate": 44100.5}}, "audio.sample_rate", "integer"),
    ({"waveform": {"pri_samples": "1297"}}, "waveform.pri_samples", "integer"),
    ({"waveform": {"amplitude": 0}}, "waveform.amplitude", "above 0"),
    ({"scene": {"speed_of_sound": float("nan")}}, "scene.speed_of_sound", "finite"),
    ({"mqtt": {"port": 70000}}, "mqtt.port", "from 1 to 65535"),
    ({"device_id": "living room"}, "device_id", "must match"),
    ({"scene": {"gate_start_m": 3.0, "gate_stop_m": 2.0}}, "scene.gate_stop_m", "greater"),
    ({"scene": "four"}, "scene", "mapping"),
])
def test_bad_values_name_key_value_and_range(data, key, words):
    with pytest.raises(ConfigError) as ei:
        config.from_mapping(data)
    assert ei.value.key == key
    assert words in str(ei.value)


def test_text_values_are_capped_and_a_schedule_may_be_a_simulated_day():
    day = ",".join(["ccw:0.45:60", "stop:0:30~8", "cw:0.312:75.5~4.2"] * 400)  # 20 h
    assert 1024 < len(day) < config.MAX_SCHEDULE
    assert config.from_mapping({"sim": {"schedule": day}}).sim.schedule == day
    with pytest.raises(ConfigError, match="at most 1024 characters long") as ei:
        config.from_mapping({"sim": {"scene": "x" * 1025}})
    assert ei.value.key == "sim.scene"
    with pytest.raises(ConfigError, match=f"at most {config.MAX_SCHEDULE} characters") as ei:
        config.from_mapping({"sim": {"schedule": "ccw:0.45:60," * 6000}})
    assert ei.value.key == "sim.schedule"


def test_gate_beyond_one_pri_is_refused_with_the_physical_limit():
    # c * pri / fs / 2 = 343 * 1297 / 44100 / 2 = 5.0439 m
    with pytest.raises(ConfigError, match=r"at most 5\.044 m"):
        config.from_mapping({"scene": {"gate_stop_m": 5.1}})
    cfg = config.from_mapping({"scene": {"gate_stop_m": 5.0}})
    assert cfg.max_range_m == pytest.approx(343 * 1297 / 44100 / 2)
    assert cfg.prf_hz == pytest.approx(34.0016, abs=1e-4)


def test_file_errors_carry_the_line_number(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("audio:\n  sample_rate: 44100\nscene:\n  blades: 40\n")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    assert ei.value.line == 4
    assert str(ei.value).startswith(f"{p}:4: scene.blades = 40")


def test_shared_sample_config_loads():
    from conftest import require_shared_sample

    cfg = load_config(require_shared_sample() / "config.yaml")
    assert (cfg.scene.gate_start_m, cfg.scene.gate_stop_m, cfg.scene.blades) == (1.0, 4.5, 4)


def test_check_config_command_exit_codes(tmp_path):
    good = tmp_path / "good.yaml"
    good.write_text("scene:\n  blades: 3\n")
    bad = tmp_path / "bad.yaml"
    bad.write_text("scene:\n  blades: [3\n")
    ok = subprocess.run([sys.executable, "-m", "bladesonar", "check-config", "--config",
                         str(good)], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    ko = subprocess.run([sys.executable, "-m", "bladesonar", "check-config", "--config",
                         str(bad)], capture_output=True, text=True)
    assert ko.returncode == 2
    assert "not valid YAML" in ko.stderr and "Traceback" not in ko.stderr


def test_example_config_documents_every_key_with_its_default(repo_root):
    """The shipped example must load to exactly the defaults and name every key.

    If this fails after adding a setting, regenerate the file:
    ``.venv/bin/python -m bladesonar.config_doc > config/bladesonar.example.yaml``.
    """
    import yaml

    path = repo_root / "config" / "bladesonar.example.yaml"
    loaded = load_config(path)
    assert config.to_mapping(loaded) == config.to_mapping(config.Config())
    data = yaml.safe_load(path.read_text())
    for key, _ in config.iter_fields():
        node = data
        for part in key.split("."):
            assert part in node, f"{key} missing from {path.name}"
            node = node[part]
    text = path.read_text()
    for key, f in config.iter_fields():
        assert f.metadata["doc"] in text, f"doc of {key} missing"


def test_readme_configuration_table_is_current(repo_root):
    """The README's table must be the schema's; regenerate with tools/gen-docs."""
    from bladesonar.config_doc import markdown_table

    assert markdown_table() in (repo_root / "README.md").read_text()
