"""A 64-bit float WAV far past full scale: its samples are limited to float32's range
when read, so ``analyze`` ends in its one error line (overloaded) with no numpy
overflow warnings before it (at 1e300 it printed 8 lines of them)."""

from __future__ import annotations

import os
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from bladesonar import config
from bladesonar.io.reference import save_reference
from bladesonar.io.scene_file import load_scene
from bladesonar.io.wav import MAX_FLOAT_SAMPLE, read_wav
from bladesonar.reference_build import build_reference
from bladesonar.sim.render import simulate
from bladesonar.sim.schedule import Schedule
from loopback import ROOT, SCENE, bladesonar_cmd


def _float64_wav(path: Path, x: np.ndarray, rate: int = 44100) -> None:
    y = np.asarray(x, dtype="<f8")
    body = (b"fmt " + struct.pack("<IHHIIHH", 16, 3, 1, rate, rate * 8, 8, 64)
            + b"data" + struct.pack("<I", y.nbytes) + y.tobytes())
    path.write_bytes(b"RIFF" + struct.pack("<I", len(body) + 4) + b"WAVE" + body)


def test_float64_samples_beyond_float32_are_limited_and_the_rest_kept_exactly(tmp_path):
    x = np.array([0.25, -1e300, 1e300, 3e38, -0.5, np.inf, -np.inf, np.nan, 1.0 + 2**-40,
                  np.finfo(np.float64).max])
    _float64_wav(tmp_path / "x.wav", x)
    got, _ = read_wav(tmp_path / "x.wav")
    want = [0.25, -MAX_FLOAT_SAMPLE, MAX_FLOAT_SAMPLE, 3e38, -0.5, np.inf, -np.inf, np.nan,
            1.0 + 2**-40, MAX_FLOAT_SAMPLE]
    np.testing.assert_array_equal(got, want)   # NaN == NaN here; bit-exact elsewhere
    assert MAX_FLOAT_SAMPLE == float(np.finfo(np.float32).max)


@pytest.fixture(scope="module")
def recording_and_reference(tmp_path_factory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("huge")
    cfg = config.Config()
    x, _ = simulate(load_scene(SCENE), cfg, 8.0, schedule=Schedule.constant(0.45, "ccw"),
                    snr_db=20.0, seed=5)
    save_reference(build_reference(x, cfg, "ccw"), out / "ref.npz")
    _float64_wav(out / "huge.wav", x[:4 * 44100] * 1e300)
    return out / "huge.wav", out / "ref.npz"


def test_analyze_on_a_float64_wav_scaled_by_1e300_prints_one_error_line(
        recording_and_reference):
    wav, ref = recording_and_reference
    env = dict(os.environ, PYTHONWARNINGS="default")
    r = subprocess.run(bladesonar_cmd("analyze", "--reference", str(ref), str(wav)),
                       capture_output=True, text=True, timeout=120, cwd=ROOT, env=env)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("bladesonar analyze: error: the recording is overloaded")
