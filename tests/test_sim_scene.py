"""Scene validation (errors name the key) and the rate schedule's exact angle integral."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bladesonar import config
from bladesonar.errors import ConfigError
from bladesonar.io.scene_file import load_scene
from bladesonar.sim import Scene
from bladesonar.sim.schedule import Schedule, direction_of, parse

ROOT = Path(__file__).resolve().parents[1]


def base(**over):
    d = dict(room=dict(vertices=[[0, 0], [5, 0], [5, 4], [0, 4]], reflection=0.5),
             sensor=[0.5, 0.5], fan=dict(centre=[3, 2], blade_length_m=0.58))
    for k, v in over.items():
        d[k] = v
    return d


def test_shipped_scenes_load():
    s = load_scene(ROOT / "config/scenes/paper-room.yaml")
    assert s.K == 4 and s.blade_length_m == 0.58
    assert 2.1 < s.sensor_fan_distance_m < 2.3
    assert s.wall_reflection == (0.5,) * 4
    c = load_scene(ROOT / "config/scenes/corner-sensor.yaml")
    assert c.blades is None and c.with_config(config.Config()).K == 4
    assert len(c.vertices) == 6


@pytest.mark.parametrize("over,key", [
    (dict(sensor=[6, 1]), "sensor"),
    (dict(sensor=[5, 1]), "sensor"),                       # on the wall
    (dict(sensor="here"), "sensor"),
    (dict(fan=dict(centre=[9, 2])), "fan.centre"),
    (dict(fan=dict(centre=[3, 2], blade_length_m=3)), "fan.blade_length_m"),
    (dict(fan=dict(centre=[3, 2], blade_length_m=0)), "fan.blade_length_m"),
    (dict(fan=dict(centre=[3, 2], blades=0)), "fan.blades"),
    (dict(fan=dict(centre=[3, 2], blade_lenght_m=1)), "fan.blade_lenght_m"),
    (dict(room=dict(vertices=[[0, 0], [1, 1]])), "room.vertices"),
    (dict(room=dict(vertices=[[0, 0], [5, 4], [5, 0], [0, 4]])), "room.vertices"),
    (dict(room=dict(vertices=[[0, 0], [5, 0], [5, 4], [0, 4]], reflection=[0.5, 2])),
     "room.reflection"),
    (dict(schedule="ccw:0.5"), "schedule"),
    (dict(colour="red"), "colour"),
])
def test_bad_scenes_name_the_key(over, key):
    with pytest.raises(ConfigError) as e:
        Scene.from_mapping(base(**over))
    assert e.value.key == key


def test_sensor_outside_the_room_is_refused_with_the_fix():
    with pytest.raises(ConfigError, match="not inside the room"):
        Scene.from_mapping(base(sensor=[-1, 2]))


def test_blade_count_must_agree_with_the_config():
    s = Scene.from_mapping(base(fan=dict(centre=[3, 2], blades=3)))
    with pytest.raises(ConfigError) as e:
        s.with_config(config.Config())
    assert e.value.key == "fan.blades"
    cfg3 = config.replace(config.Config(), scene={"blades": 3})
    assert s.with_config(cfg3).K == 3


def test_scene_file_errors_carry_file_and_line(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text("room:\n  vertices: [[0,0],[5,0],[5,4],[0,4]]\nsensor: [7, 1]\n"
                 "fan:\n  centre: [3, 2]\n")
    with pytest.raises(ConfigError, match=r"s\.yaml:3: sensor"):
        load_scene(p)
    with pytest.raises(ConfigError, match="cannot be read"):
        load_scene(tmp_path / "missing.yaml")


def test_schedule_angle_is_the_exact_integral_of_the_rate():
    s = parse("ccw:0.5:3,stop:0:2,cw:0.4:5")
    t = np.array([0, 1.5, 3, 4, 5, 6, 10, 20])
    turns = np.array([0, 0.75, 1.5, 1.5, 1.5, 1.1, -0.5, -4.5])
    assert np.allclose(s.turns_at(t), turns)
    assert np.allclose(s.angle_at(t, 0.2), 0.2 + 2 * np.pi * turns)
    assert list(s.rate_at(np.array([0, 2.999, 3, 5, 30]))) == [0.5, 0.5, 0, -0.4, -0.4]
    assert list(direction_of(s.rate_at(np.array([1, 4, 6])))) == ["ccw", "stopped", "cw"]
    assert s.to_string() == "ccw:0.5:3,stop:0:2,cw:0.4:5"


def test_schedule_forms_and_errors():
    a = parse([{"direction": "cw", "rate_hz": 1, "seconds": 2}, "stop:0:1"])
    assert a.to_string() == "cw:1:2,stop:0:1"
    assert Schedule.constant(0.0, "cw").to_string() == "stop:0:1"
    assert Schedule.constant(2.0, "cw").rate_at(np.array([100.0]))[0] == -2.0
    for bad in ("", "ccw:-1:2", "spin:1:1", "stop:1:2", "ccw:1:0", "ccw:1:inf", 7, "ccw:a:1"):
        with pytest.raises(ConfigError):
            parse(bad, key="--schedule")
    assert math.isclose(parse("ccw:3:1").max_abs_hz, 3.0)


def test_scene_numbers_are_checked_by_the_config_schema_with_file_line_value_and_fix(tmp_path):
    """One schema helper (bladesonar.schema) checks config and scene files alike: the
    refusal names the file and line, the key, the value as written and the range or fix."""
    p = tmp_path / "s.yaml"
    p.write_text("room:\n  vertices: [[0,0],[5,0],[5,4],[0,4]]\nsensor: [1, 1]\n"
                 "fan:\n  centre: [3, 2]\n  blades: 0\n  reflectivity: 2\n"
                 "nuisances:\n  rt60_s: 9\n")
    with pytest.raises(ConfigError) as e:
        load_scene(p)
    assert str(e.value) == (f"{p}:6: fan.blades = 0: must be an integer from 1 to 16 (or "
                            "left out to use the config's scene.blades)")
    p.write_text(p.read_text().replace("blades: 0", "blades: 4"))
    with pytest.raises(ConfigError) as e:
        load_scene(p)
    assert str(e.value) == f"{p}:7: fan.reflectivity = 2: must be a number from 0 to 1"
    p.write_text(p.read_text().replace("reflectivity: 2", "reflectivity: 1"))
    with pytest.raises(ConfigError) as e:
        load_scene(p)
    assert str(e.value) == (f"{p}:9: nuisances.rt60_s = 9: must be a number from 0 to 3 (late "
                            "reverberation: 60 dB decay time, s (0: none))")
    p.write_text(p.read_text().replace("rt60_s: 9", "rt60_s: 0.5"))
    nz = load_scene(p).nuisances
    assert nz is not None and nz.rt60_s == 0.5
