"""The 3-D scene: file validation, the plate's glint against closed forms, flat blades
without airflow asymmetry, the mirror-image symmetry, random 3-D scenes and the CLI."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bladesonar import cli, config
from bladesonar.errors import ConfigError
from bladesonar.io.scene_file import load_any_scene, load_scene
from bladesonar.sim import geometry3d, random_scene
from bladesonar.sim.render import simulate
from bladesonar.sim.scene3d import Scene3D

ROOT = Path(__file__).resolve().parents[1]
CFG1 = config.from_mapping({"scene": {"blades": 1}})


def doc(**over):
    d: dict[str, Any] = dict(room=dict(size=[6.0, 6.0, 3.0], reflection=0.5),
                             sensor=[3.45, 3.0, 1.0],
                             fan=dict(centre=[3.0, 3.0, 2.5], blades=1, blade_length_m=0.6,
                                      hub_radius_m=0.1, chord_m=0.3, pitch_deg=12.0,
                                      droop_deg=0.0))
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(d.get(k), dict):
            d[k] = {**d[k], **v}
        else:
            d[k] = v
    return d


def plate(**over) -> Scene3D:
    return Scene3D.from_mapping(doc(**over)).with_config(CFG1)


def test_shipped_3d_scene_loads_and_2d_loader_refuses_it():
    s = load_any_scene(ROOT / "config/scenes/living-room-3d.yaml")
    assert isinstance(s, Scene3D) and s.K == 4 and s.surface_reflection[4:] == (0.3, 0.7)
    assert 1.5 < s.axis_offset_m < 1.7
    with pytest.raises(ConfigError, match="3-D scene"):
        load_scene(ROOT / "config/scenes/living-room-3d.yaml")


@pytest.mark.parametrize("over,key", [
    (dict(room=dict(size=[6.0, 6.0])), "room.size"),
    (dict(room=dict(reflection=[0.5] * 4)), "room.reflection"),
    (dict(room=dict(reflection=dict(walls=0.5, roof=0.2))), "room.reflection"),
    (dict(sensor=[7.0, 3.0, 1.0]), "sensor"),
    (dict(sensor=[3.2, 3.0, 2.5]), "sensor"),                # among the blades
    (dict(fan=dict(centre=[0.5, 3.0, 2.5])), "fan.blade_length_m"),
    (dict(fan=dict(centre=[3.0, 3.0, 2.99], pitch_deg=40)), "fan.centre"),
    (dict(fan=dict(pitch_deg=60)), "fan.pitch_deg"),
    (dict(fan=dict(spin=3)), "fan.spin"),
    (dict(nuisances=dict(walker_speed_m_s=1.0)), "nuisances.walker_speed_m_s"),
])
def test_bad_3d_scenes_name_the_key(over, key):
    with pytest.raises(ConfigError) as e:
        Scene3D.from_mapping(doc(**over))
    assert e.value.key == key


def _glint(s: Scene3D) -> tuple[float, float, float, float]:
    """Closed form for one plate pitched by beta about its radial axis, no droop, the
    sensor H below the blade plane and D off the axis: the face points at the sensor
    where the sensor is r* = sqrt(D^2 - (H tan beta)^2) out along the blade and
    H tan beta ahead of it; the range is H / cos beta and falls at r* sin beta per radian
    of (ccw from below) rotation. Returns (angle, range, d range / d angle, r*)."""
    S, C = np.asarray(s.sensor), np.asarray(s.fan_centre)
    D = math.hypot(*(S - C)[:2])
    H = C[2] - S[2]
    b = math.radians(s.pitch_deg)
    h = H * math.tan(b)
    r = math.sqrt(D * D - h * h)
    # ccw from below turns +x towards -y: the sensor's angle seen from below
    ang = math.atan2(-(S - C)[1], (S - C)[0]) - math.atan2(h, r)
    return ang, H / math.cos(b), -r * math.sin(b), r


def test_a_tilted_plate_glints_at_the_closed_form_delay_and_slope():
    s = plate()
    ang, rng, slope, r = _glint(s)
    assert s.hub_radius_m < r < s.tip_radius_m
    eps = 1e-5
    tab = geometry3d.path_table(s, np.array([ang - eps, ang, ang + eps]))
    j = int(np.nonzero(tab.kind == "blade")[0][0])
    assert tab.valid[:, j].all()
    one_way = tab.length_m[:, j] / 2
    assert one_way[1] == pytest.approx(rng, abs=1e-9)
    assert (one_way[2] - one_way[0]) / (2 * eps) == pytest.approx(slope, rel=1e-5)
    # the lobe is 1 inside the plate: the gain is the small plate's peak area / (lambda d^2)
    area = s.blade_length_m * s.chord_m
    assert tab.gain[1, j] == pytest.approx(area / (s.lobe_wavelength_m * rng * rng), rel=1e-9)
    # and the glint is the strongest the plate gets over a turn
    th = np.linspace(-math.pi, math.pi, 7201)
    g = geometry3d.path_table(s, th, wall_bounces=False).gain[:, j]
    assert g.max() <= tab.gain[1, j] * (1 + 1e-6) * (rng / (rng - 0.2)) ** 2
    # delay in samples and range slope per pulse at 0.5 Hz, as the renderer places them
    fs, c, prf = 44100.0, 343.0, 44100.0 / 1297
    x, truth = simulate(s, CFG1, 0.2, "ccw:0.5:1", snr_db=None, seed=1,
                        start_offset=0.0)
    assert truth["meta"]["scene"]["pitch_deg"] == 12.0
    p = geometry3d.paths(s, ang)
    d = p.delay_samples(c, fs)[p.kind == "blade"][0]
    assert d == pytest.approx(2 * rng / c * fs, rel=1e-12)
    per_pulse = slope * 2 * math.pi * 0.5 / prf
    assert per_pulse < 0                   # pitched +, turning ccw: approaching (down)


def test_the_glint_leads_the_blade_on_the_side_it_approaches_from():
    s = plate()
    ang, _, _, _ = _glint(s)
    flip = plate(fan=dict(pitch_deg=-12.0))
    ang_f, _, slope_f, _ = _glint(flip)
    # the mirror pitch glints as far behind the sensor's bearing as + pitch glints ahead
    bearing = math.atan2(0.0, 0.45)
    assert ang - bearing == pytest.approx(-(ang_f - bearing), abs=1e-12)
    assert slope_f > 0


def _energy_weighted_slope(s: Scene3D, kinds=geometry3d.FAN_KINDS) -> float:
    th = np.linspace(0.0, 2 * math.pi, 14401)[:-1]
    tab = geometry3d.path_table(s, th)
    num = den = 0.0
    for kind in kinds:
        m = tab.kind == kind
        L = np.where(tab.valid[:, m], tab.length_m[:, m], 0.0)
        dL = (np.roll(L, -1, axis=0) - np.roll(L, 1, axis=0)) / (2 * (th[1] - th[0]))
        ok = tab.valid[:, m] & np.roll(tab.valid[:, m], 1, 0) & np.roll(tab.valid[:, m], -1, 0)
        w = np.where(ok, tab.gain[:, m] ** 2, 0.0)
        num += float(np.sum(w * dL))
        den += float(np.sum(w))
    return num / den


def test_flat_blades_give_no_airflow_asymmetry_and_pitched_ones_do():
    s = Scene3D.from_mapping(doc(sensor=[4.4, 2.1, 0.9],
                                 fan=dict(blades=4, pitch_deg=0.0, chord_m=0.12))
                             ).with_config(config.Config())
    flat = _energy_weighted_slope(s)
    down = _energy_weighted_slope(dataclasses.replace(s, pitch_deg=12.0))
    up = _energy_weighted_slope(dataclasses.replace(s, pitch_deg=-12.0))
    assert abs(flat) < 1e-3 * abs(down)
    assert down < 0 < up                 # + pitch turning ccw: echoes approach at the glint


def test_reversing_pitch_and_rotation_together_leaves_the_echoes_unchanged():
    # the room is symmetric about the vertical plane through the axis and the sensor, so
    # the mirror scene is the same room with the fan's pitch and rotation both reversed
    s = Scene3D.from_mapping(doc(room=dict(size=[6.0, 6.0, 3.0], reflection=[0.3, 0.6, 0.5,
                                                                           0.5, 0.2, 0.8]),
                                 sensor=[4.6, 3.0, 0.9],
                                 fan=dict(blades=3, pitch_deg=14.0, chord_m=0.12,
                                          start_angle_deg=17.0, droop_deg=3.0))
                             ).with_config(config.from_mapping({"scene": {"blades": 3}}))
    m = dataclasses.replace(s, pitch_deg=-14.0, start_angle_rad=-s.start_angle_rad)
    cfg = config.from_mapping({"scene": {"blades": 3}})
    kw = dict(snr_db=None, seed=4, start_offset=100.0)
    x1, t1 = simulate(s, cfg, 1.0, "ccw:0.7:1", **kw)
    x2, t2 = simulate(m, cfg, 1.0, "cw:0.7:1", **kw)
    assert np.max(np.abs(x1 - x2)) < 1e-9 * np.max(np.abs(x1))
    assert {p["airflow"] for p in t1["pulses"]} == {p["airflow"] for p in t2["pulses"]} \
        == {"down"}
    assert t1["pulses"][3]["direction"] == "ccw" and t2["pulses"][3]["direction"] == "cw"


def test_truth_carries_pitch_rotation_and_airflow():
    s = load_any_scene(ROOT / "config/scenes/living-room-3d.yaml")
    x, t = simulate(s, config.Config(), 2.0, "stop:0:0.5,cw:0.5:1.5~0.5", snr_db=20, seed=2)
    air = [p["airflow"] for p in t["pulses"]]
    assert air[0] == "none" and air[-1] == "up"
    assert t["pulses"][-1]["direction"] == "cw"
    assert "below" in t["meta"]["conventions"]["angle"]
    assert t["meta"]["scene"]["pitch_deg"] == 12.0
    kinds = {q["kind"] for p in t["pulses"] for q in p["paths"]}
    assert {"coupling", "wall", "wall2", "blade_diffuse", "wall_blade"} <= kinds


def test_random_3d_scenes_stay_in_their_ranges_and_repeat_by_seed():
    for seed in range(1, 41):
        d = random_scene.draw_3d(seed)
        s = d.scene
        assert 3.0 <= s.size[0] <= 7.0 and 3.0 <= s.size[1] <= 7.0
        assert 2.4 <= s.size[2] <= 3.2
        assert 0.5 <= s.axis_offset_m <= 3.0
        assert 6.0 <= abs(s.pitch_deg) <= 18.0
        assert 0.15 <= abs(d.rate_hz) <= 1.6 and 3 <= d.blades <= 5
        assert 4.0 <= d.snr_db <= 20.0 and abs(d.drift_ppm) <= 150.0
        assert d.airflow in ("down", "up")
    assert random_scene.draw_3d(7).describe() == random_scene.draw_3d(7).describe()
    signs = {random_scene.draw_3d(s).airflow for s in range(1, 41)}
    assert signs == {"down", "up"}


def test_simulate_cli_renders_a_3d_scene(tmp_path, capsys):
    out = tmp_path / "f.wav"
    rc = cli.main(["simulate", "--scene", str(ROOT / "config/scenes/living-room-3d.yaml"),
                   "--seconds", "1", "--rate", "0.4", "--direction", "cw", "--out", str(out),
                   "--quiet", "--nuisance", "rt60_s=0.3"])
    assert rc == 0
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    assert truth["pulses"][-1]["airflow"] == "up"
    capsys.readouterr()
    rc = cli.main(["simulate", "--scene", str(ROOT / "config/scenes/living-room-3d.yaml"),
                   "--seconds", "1", "--out", str(out), "--quiet",
                   "--nuisance", "walker_speed_m_s=1"])
    assert rc == 2
    assert "walker_speed_m_s" in capsys.readouterr().err
