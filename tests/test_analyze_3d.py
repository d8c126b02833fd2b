"""The independent 3-D sample, and the command-line contract (outputs and refusals)."""

from __future__ import annotations

import json
import shutil
import wave

import numpy as np
import pytest

from bladesonar import cli
from synth_pulses import pulse_train

pytestmark = pytest.mark.slow   # whole analyses of the 3-D sample and WAV files

SAMPLE = "fan-3d-sample"


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    from conftest import SHARED_DATA
    d = SHARED_DATA / SAMPLE
    if not (d / "reference.wav").is_file():
        pytest.skip(f"shared sample {d} not present")
    return d


@pytest.fixture(scope="module")
def ref_file(sample, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "ref.npz"
    rc = cli.main(["reference", "--config", str(sample / "config.yaml"), "--direction", "ccw",
                   "--out", str(out), str(sample / "reference.wav")])
    assert rc == 0
    return out


def _run(capsys, argv):
    rc = cli.main(argv)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_3d_sample_reference_summary(sample, capsys, tmp_path):
    out = tmp_path / "r.npz"
    rc, so, _ = _run(capsys, ["reference", "--config", str(sample / "config.yaml"),
                              "--direction", "ccw", "--out", str(out),
                              str(sample / "reference.wav")])
    assert rc == 0
    s = json.loads(so)
    truth = json.loads((sample / "truth.json").read_text())
    assert abs(s["rate_hz"] - truth["reference"]["rate_hz"]) < 0.01 * truth["reference"]["rate_hz"]
    for key in ("blade_rate_hz", "rate_hz", "rpm", "periods_folded", "quality", "gate_m",
                "pulses", "direction"):
        assert key in s
    assert s["gate_m"][0] <= 1.0 and s["gate_m"][1] >= 4.5 and s["direction"] == "ccw"


def test_3d_sample_probe_is_reversed_at_the_true_rate(sample, ref_file, capsys):
    truth = json.loads((sample / "truth.json").read_text())["probe"]
    rc, so, _ = _run(capsys, ["analyze", "--config", str(sample / "config.yaml"),
                              "--reference", str(ref_file), str(sample / "probe.wav")])
    assert rc == 0
    s = json.loads(so)
    assert s["direction"] == truth["expected_direction"] == "reversed"
    assert s["rotation"] == truth["rotation"] == "cw"
    rel = truth["expected_relative_rate"]
    assert abs(s["relative_rate"] - rel) < 0.03 * abs(rel)
    assert s["confidence"] >= 0.5
    for key in ("rate_hz", "rpm", "pulses"):
        assert key in s


def test_track_prints_one_json_line_per_pulse(sample, ref_file, capsys):
    rc, so, _ = _run(capsys, ["analyze", "--config", str(sample / "config.yaml"),
                              "--reference", str(ref_file), "--track",
                              str(sample / "probe.wav")])
    assert rc == 0
    rows = [json.loads(line) for line in so.splitlines()]
    assert len(rows) > 250
    for key in ("t_s", "phase", "direction", "relative_rate", "confidence"):
        assert key in rows[-1]
    assert rows[-1]["direction"] == "reversed"


# ---- refusals: one clear line, exit code 2, no traceback ------------------------------

def _write_wav(path, x, rate=44100, channels=1):
    q = np.clip(np.round(np.asarray(x) * 32767), -32768, 32767).astype("<i2")
    with wave.open(str(path), "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(q.tobytes())


def _float_wav(path, x):
    from scipy.io import wavfile
    wavfile.write(path, 44100, np.asarray(x, dtype=np.float32))


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    x, _, _ = pulse_train(120, 1297, rate=0.05, noise=1e-3)
    return x


@pytest.mark.parametrize("case, expect", [
    ("rate", "sample rate"), ("stereo", "channels"), ("silence", "silent"),
    ("clipping", "overloaded"), ("nan", "NaN"), ("short", "pulses"),
])
def test_bad_recordings_are_refused(sample, ref_file, good, tmp_path, capsys, case, expect):
    p = tmp_path / f"{case}.wav"
    if case == "rate":
        _write_wav(p, good, rate=48000)
    elif case == "stereo":
        _write_wav(p, np.repeat(good, 2), channels=2)
    elif case == "silence":
        _write_wav(p, good * 0)
    elif case == "clipping":
        _write_wav(p, np.clip(good * 1000, -1, 1))
    elif case == "nan":
        y = good.copy()
        y[777] = np.nan
        _float_wav(p, y)
    elif case == "short":
        _write_wav(p, good[:1297 * 20])
    rc, _, err = _run(capsys, ["analyze", "--config", str(sample / "config.yaml"),
                               "--reference", str(ref_file), str(p)])
    assert rc == 2
    assert expect in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_reference_made_with_other_config_values_is_refused(sample, ref_file, tmp_path,
                                                            capsys):
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text((sample / "config.yaml").read_text().replace("blades: 4", "blades: 5"))
    rc, _, err = _run(capsys, ["analyze", "--config", str(cfg), "--reference", str(ref_file),
                               str(sample / "probe.wav")])
    assert rc == 2 and "scene.blades" in err and "4" in err and "5" in err


def test_missing_or_corrupt_reference_is_refused(sample, tmp_path, capsys):
    rc, _, err = _run(capsys, ["analyze", "--config", str(sample / "config.yaml"),
                               "--reference", str(tmp_path / "none.npz"),
                               str(sample / "probe.wav")])
    assert rc == 2 and "no such reference file" in err
    bad = tmp_path / "bad.npz"
    shutil.copy(sample / "config.yaml", bad)
    rc, _, err = _run(capsys, ["analyze", "--config", str(sample / "config.yaml"),
                               "--reference", str(bad), str(sample / "probe.wav")])
    assert rc == 2 and "not a bladesonar reference" in err


def test_stationary_reference_is_refused(tmp_path, capsys):
    x, _, _ = pulse_train(200, 1297, rate=0.0, noise=1e-3)
    p = tmp_path / "still.wav"
    _write_wav(p, x)
    rc, _, err = _run(capsys, ["reference", "--direction", "ccw", "--out",
                               str(tmp_path / "r.npz"), str(p)])
    assert rc == 2 and "stationary" in err
