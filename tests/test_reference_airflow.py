"""A reference sets its direction from the airflow measured on its own recording (truth:
simulated 3-D scenes whose pitch and rotation give the airflow), a given direction wins
and a contradiction is a warning with the figures; the rule itself in closed form."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bladesonar import cli, config
from bladesonar.airflow_recording import reference_direction, rotation_of, window_figures
from bladesonar.dsp.airflow import Airflow
from bladesonar.io.wav import read_wav
from bladesonar.service import learner

ROOT = Path(__file__).resolve().parents[1]
SCENE3D = ROOT / "config/scenes/living-room-3d.yaml"


def _a(word: str, t: float) -> Airflow:
    return Airflow(word, 0.9 if word != "unknown" else 0.3, t, t / 10, 400, "test", 3)


def test_the_direction_rule():
    cfg = config.from_mapping({})
    cw_cfg = config.from_mapping({"scene": {"downdraft_rotation": "cw"}})
    assert rotation_of("down", "ccw") == "ccw" and rotation_of("up", "ccw") == "cw"
    assert rotation_of("down", "cw") == "cw" and rotation_of("unknown", "ccw") is None
    assert reference_direction(None, _a("down", -8), cfg) == ("ccw", "airflow", [])
    assert reference_direction(None, _a("up", 8), cfg) == ("cw", "airflow", [])
    assert reference_direction(None, _a("up", 8), cw_cfg) == ("ccw", "airflow", [])
    assert reference_direction(None, _a("unknown", 1), cfg) == ("unknown", "none", [])
    assert reference_direction("cw", _a("up", 8), cfg) == ("cw", "given", [])
    assert reference_direction("unknown", _a("up", 8), cfg) == ("unknown", "given", [])
    d, src, w = reference_direction("ccw", _a("up", 8.0), cfg)
    assert (d, src) == ("ccw", "given") and len(w) == 1
    assert "contradicts" in w[0] and "up" in w[0] and "+8.0" in w[0] and "means cw" in w[0]
    # what the estimates against the old reference reported (the direction a person set
    # on it, or the one the daemon already showed) is kept over the airflow: a Learn
    # press must not turn the user's frame round; a contradiction is a warning
    assert reference_direction(None, _a("unknown", 1), cfg, "ccw") == ("ccw", "carried", [])
    assert reference_direction(None, _a("down", -8), cfg, "ccw") == ("ccw", "carried", [])
    d, src, w = reference_direction(None, _a("up", 8.0), cfg, "ccw")
    assert (d, src) == ("ccw", "carried") and len(w) == 1
    assert "carried" in w[0] and "means cw" in w[0] and "+8.0" in w[0]
    # a direction a person chose for the new reference wins over the carried one
    assert reference_direction("cw", _a("unknown", 1), cfg, "ccw") == ("cw", "given", [])
    assert reference_direction("unknown", _a("up", 8), cfg, "ccw") == ("unknown", "given", [])
    # nothing carried: the airflow, else unknown
    for nothing in (None, "unknown"):
        assert reference_direction(None, _a("up", 8), cfg, nothing) == ("cw", "airflow", [])
        assert reference_direction(None, _a("unknown", 1), cfg, nothing) == \
            ("unknown", "none", [])


@pytest.fixture(scope="module")
def up_wav(tmp_path_factory):
    """The living-room 3-D scene (+12 degrees pitch) turning cw seen from below: an
    up-draft, 10 s at 0.6 Hz."""
    out = tmp_path_factory.mktemp("ref3d") / "fan.wav"
    rc = cli.main(["simulate", "--scene", str(SCENE3D), "--seconds", "10", "--schedule",
                   "cw:0.6:10", "--snr-db", "12", "--drift-ppm", "60", "--seed", "5",
                   "--no-paths", "--out", str(out), "--quiet"])
    assert rc == 0
    return out


@pytest.mark.slow
def test_reference_takes_its_direction_from_the_airflow(up_wav, tmp_path, capsys):
    capsys.readouterr()
    out = tmp_path / "r.npz"
    assert cli.main(["reference", "--out", str(out), str(up_wav)]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["airflow"] == "up" and s["airflow_rotation"] == "cw"
    assert s["direction"] == "cw" and s["direction_source"] == "airflow"
    assert not any("contradicts" in w for w in s.get("warnings", []))
    # a given direction wins; one the airflow contradicts is stored with a warning
    assert cli.main(["reference", "--direction", "cw", "--out", str(out), str(up_wav)]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["direction"] == "cw" and s["direction_source"] == "given"
    assert cli.main(["reference", "--direction", "ccw", "--out", str(out), str(up_wav)]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["direction"] == "ccw" and s["direction_source"] == "given"
    assert any("contradicts" in w and "means cw" in w for w in s["warnings"])
    # the scene's fan built the other way (blows down turning cw): the same echoes
    # give the other rotation
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("scene:\n  downdraft_rotation: cw\n")
    assert cli.main(["reference", "--config", str(cfg), "--out", str(out), str(up_wav)]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["direction"] == "ccw" and s["direction_source"] == "airflow"


@pytest.mark.slow
def test_a_flat_fan_leaves_the_direction_unknown(tmp_path, capsys):
    # the 2-D paper room's blades have no pitch: no airflow to be had
    wav = tmp_path / "flat.wav"
    assert cli.main(["simulate", "--scene", str(ROOT / "config/scenes/paper-room.yaml"),
                     "--seconds", "8", "--schedule", "ccw:0.45:8", "--seed", "2",
                     "--no-paths", "--out", str(wav), "--quiet"]) == 0
    capsys.readouterr()
    out = tmp_path / "r.npz"
    assert cli.main(["reference", "--out", str(out), str(wav)]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["airflow"] == "unknown" and s["direction"] == "unknown"
    assert s["direction_source"] == "none"


@pytest.mark.slow
def test_the_daemons_learner_sets_the_direction_from_the_airflow(up_wav, tmp_path):
    cfg = config.from_mapping({})
    x, _ = read_wav(str(up_wav), expect_rate=cfg.audio.sample_rate)
    path = tmp_path / "ref.npz"
    got = learner.learn(x, cfg, "unknown", path)
    assert got["direction"] == "cw" and got["direction_source"] == "airflow"
    assert got["airflow"] == "up"
    assert got["direction_carried"] == "unknown" and got["direction_estimates"] == {}
    # what the estimates against the old reference said throughout is kept (the user's
    # frame), the airflow that contradicts it a warning; the figures that decided it out
    got = learner.learn(x, cfg, "unknown", path, "ccw", {"ccw": 40, "other": 2})
    assert got["direction"] == "ccw" and got["direction_source"] == "carried"
    assert got["airflow"] == "up" and any("contradicts" in w for w in got["warnings"])
    assert got["direction_carried"] == "ccw"
    assert got["direction_estimates"] == {"ccw": 40, "other": 2}
    # a person's choice wins, with the contradiction in the warnings
    got = learner.learn(x, cfg, "ccw", path)
    assert got["direction"] == "ccw" and got["direction_source"] == "given"
    assert any("contradicts" in w for w in got["warnings"])


@pytest.mark.slow
def test_the_window_figures_give_airflow_and_the_rate_with_no_reference(up_wav):
    cfg = config.from_mapping({})
    x, _ = read_wav(str(up_wav), expect_rate=cfg.audio.sample_rate)
    f = window_figures(x, cfg, rate=True)
    assert f.airflow.airflow == "up" and f.rotation == "cw"
    assert f.rate_hz is not None and abs(f.rate_hz - 0.6) < 0.01 * 0.6, f
    assert window_figures(x, cfg).rate_hz is None
    # a flat (2-D) room turning: no airflow, the rate all the same
