"""`bladesonar plot KIND`: valid PNG/SVG files from simulated recordings, clear refusals,
and matplotlib kept out of the analysis and the daemon."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from bladesonar.cli import main
from bladesonar.errors import BladesonarError

pytestmark = pytest.mark.slow   # renders PNGs (matplotlib): outside the fast tier

SCENE = "config/scenes/paper-room.yaml"


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG file"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


@pytest.fixture(scope="module")
def recs(tmp_path_factory, repo_root):
    d = tmp_path_factory.mktemp("plots")
    scene = str(repo_root / SCENE)
    for name, extra in (("ref", ["--rate", "0.47", "--direction", "ccw", "--seconds", "8"]),
                        ("probe", ["--rate", "0.6", "--direction", "cw", "--seconds", "6"]),
                        ("rev", ["--schedule", "ccw:0.47:5,cw:0.5:5", "--seconds", "10"])):
        assert main(["simulate", "--scene", scene, "--snr-db", "20", "--seed", "3", "--quiet",
                     "--out", str(d / f"{name}.wav"), *extra]) == 0
    assert main(["reference", "--direction", "ccw", "--out", str(d / "ref.npz"),
                 str(d / "ref.wav")]) == 0
    return d


def _rows(d, capsys):
    capsys.readouterr()
    assert main(["analyze", "--reference", str(d / "ref.npz"), "--track",
                 str(d / "rev.wav")]) == 0
    out = capsys.readouterr().out
    (d / "rev.jsonl").write_text(out)
    return d / "rev.jsonl"


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_every_kind_writes_a_valid_picture(recs, repo_root, capsys, suffix):
    d = recs
    rows = _rows(d, capsys)
    scene = str(repo_root / SCENE)
    cmds = {
        "rd": ["rd", str(d / "ref.wav")],
        "isar": ["isar", "--scene", scene, "--reference", str(d / "ref.npz"), "--pixels", "128",
                 str(d / "ref.wav")],
        "matrix": ["matrix", "--reference", str(d / "ref.npz"), str(d / "ref.wav"),
                   str(d / "probe.wav")],
        "track": ["track", "--truth", str(d / "rev.truth.json"), str(rows)],
        "sim": ["sim", "--scene", scene, "--direct"],
    }
    for kind, args in cmds.items():
        out = d / f"{kind}{suffix}"
        assert main(["plot", *args[:1], "--out", str(out), *args[1:]]) == 0, kind
        assert capsys.readouterr().out.strip() == str(out)
        if suffix == ".png":
            w, h = _png_size(out)
            assert 600 <= w <= 900 and 450 <= h <= 650, (kind, w, h)
            assert out.stat().st_size < 300_000
        else:
            root = ET.parse(out).getroot()
            assert root.tag.endswith("svg")


def test_axes_carry_units_and_the_range_convention(recs, tmp_path):
    """The SVG text holds the labels (matplotlib writes text as paths unless told not to,
    so check the drawing code's labels through an SVG with svg.fonttype none)."""
    import matplotlib

    matplotlib.rcParams["svg.fonttype"] = "none"
    try:
        out = tmp_path / "rd.svg"
        assert main(["plot", "rd", "--out", str(out), str(recs / "ref.wav")]) == 0
        text = out.read_text()
    finally:
        matplotlib.rcParams["svg.fonttype"] = "path"
    assert "doppler (Hz)" in text
    assert "one-way range (m) = c·delay/2 from the direct-coupling edge" in text
    assert "analysis gate" in text


def test_bad_suffix_and_missing_inputs_are_one_line_errors(recs, tmp_path, capsys):
    assert main(["plot", "rd", "--out", str(tmp_path / "x.jpg"), str(recs / "ref.wav")]) == 2
    err = capsys.readouterr().err
    assert "use .png or .svg" in err and err.count("\n") == 1
    assert not (tmp_path / "x.jpg").exists()
    assert main(["plot", "isar", "--rate", "0.5", "--out", str(tmp_path / "i.png"),
                 str(recs / "ref.wav")]) == 2
    assert "--sensor" in capsys.readouterr().err
    bad = tmp_path / "rows.jsonl"
    bad.write_text("{not json\n")
    assert main(["plot", "track", "--out", str(tmp_path / "t.png"), str(bad)]) == 2
    assert "analyze --track" in capsys.readouterr().err
    # bounded inputs: a 1 MB row, and /dev/zero as the truth file, are refused in one line
    huge = tmp_path / "huge.jsonl"
    huge.write_text("{" + " " * 1_000_000 + "}\n")
    assert main(["plot", "track", "--out", str(tmp_path / "t.png"), str(huge)]) == 2
    err = capsys.readouterr().err
    assert "characters" in err and err.count("\n") == 1
    assert main(["plot", "track", "--truth", "/dev/zero", "--out", str(tmp_path / "t.png"),
                 str(_rows(recs, capsys))]) == 2
    err = capsys.readouterr().err
    assert "not a simulator truth file" in err and err.count("\n") == 1


def test_missing_matplotlib_names_the_extra(repo_root, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert main(["plot", "sim", "--scene", str(repo_root / SCENE), "--out",
                 str(tmp_path / "s.png")]) == 2
    err = capsys.readouterr().err
    assert "bladesonar[plots]" in err


def test_analysis_and_daemon_never_import_matplotlib(repo_root):
    code = ("import sys, bladesonar.offline, bladesonar.imaging, bladesonar.runtime_report, "
            "bladesonar.cli, bladesonar.commands.plot, bladesonar.commands.report; "
            "bladesonar.cli.build_parser(); "
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('matplotlib'))))")
    out = subprocess.run([sys.executable, "-c", "import json; " + code], capture_output=True,
                         text=True, check=True, cwd=repo_root).stdout
    assert json.loads(out) == []


@pytest.mark.parametrize("schedule, airflow", [("cw:0.6:8", "up"), ("ccw:0.6:8", "down")])
def test_the_airflow_picture_shows_streaks_whose_slope_is_the_airflow(
        repo_root, tmp_path, schedule, airflow):
    """The living-room 3-D fan (+12 degrees pitch) turning cw blows up: its glints
    recede (a rising slope); turning ccw, down (falling). The picture's axes are the
    pulses' times and the gate's ranges; the SVG names the airflow and the slope."""
    import matplotlib

    from bladesonar import config
    from bladesonar.airflow_recording import range_time
    from bladesonar.io.wav import read_wav

    wav = tmp_path / "fan.wav"
    assert main(["simulate", "--scene", str(repo_root / "config/scenes/living-room-3d.yaml"),
                 "--seconds", "8", "--schedule", schedule, "--snr-db", "12", "--seed", "5",
                 "--drift-ppm", "60", "--no-paths", "--quiet", "--out", str(wav)]) == 0
    cfg = config.from_mapping({})
    x, _ = read_wav(str(wav), expect_rate=cfg.audio.sample_rate)
    rt = range_time(x, cfg, start_s=1.0, seconds=3.0)
    assert rt.airflow.airflow == airflow
    assert (rt.slope_m_s > 0) == (airflow == "up") and abs(rt.slope_m_s) > 0.05
    assert rt.time_s[0] >= 1.0 and rt.time_s[-1] < 4.0
    assert len(rt.time_s) == pytest.approx(3.0 * cfg.prf_hz, abs=1)
    assert rt.range_m[0] == pytest.approx(0.3, abs=343.0 / 44100)
    assert np.allclose(np.diff(rt.range_m), 343.0 / (2 * 44100))
    assert rt.image.shape == (len(rt.time_s), len(rt.range_m)) and rt.image.min() >= 0
    with pytest.raises(BladesonarError, match="no pulses from 30 s"):
        range_time(x, cfg, start_s=30.0, seconds=1.0)
    matplotlib.rcParams["svg.fonttype"] = "none"
    try:
        out = tmp_path / "a.svg"
        assert main(["plot", "airflow", "--seconds", "3", "--max-range", "3", "--out",
                     str(out), str(wav)]) == 0
        text = out.read_text()
    finally:
        matplotlib.rcParams["svg.fonttype"] = "path"
    assert f"airflow {airflow}" in text and "measured glint slope" in text
    assert "time (s)" in text and "from the direct-coupling edge" in text
    png = tmp_path / "a.png"
    assert main(["plot", "airflow", "--out", str(png), str(wav)]) == 0
    w, h = _png_size(png)
    assert 600 <= w <= 900 and 450 <= h <= 650
