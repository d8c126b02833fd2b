"""The offline path runs its stages on the same blocks whether the recording comes as one
array or as a stream of blocks of any size (a WAV is read in 64 Ki samples): the answers
are the same, bit for bit (the range scale is re-estimated at a block's start, so other
blocks once gave the command line another range_scale than the API)."""

from __future__ import annotations

import numpy as np
import pytest

from bladesonar import config
from bladesonar.io.scene_file import load_scene
from bladesonar.offline import _blocks, _regrouped, analyze
from bladesonar.reference_build import build_reference
from bladesonar.sim.nuisances import Nuisances
from bladesonar.sim.render import simulate

pytestmark = pytest.mark.slow   # whole simulated recordings: outside the fast tier


def test_a_stream_is_cut_into_the_arrays_blocks():
    x = np.arange(1_000_003, dtype=np.float64)
    want = list(_blocks(x, 332_032))
    for size in (1, 77_777, 65_536, 332_032, 400_000, 2_000_000):
        got = list(_regrouped(_blocks(x, size), 332_032))
        assert [len(b) for b in got] == [len(b) for b in want], size
        assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True)), size
    assert list(_regrouped(iter([]), 10)) == []


def test_a_streamed_recording_gives_the_arrays_answer(repo_root):
    cfg = config.Config()
    scene = load_scene(repo_root / "config/scenes/paper-room.yaml")
    xr, _ = simulate(scene, cfg, 12.0, schedule="ccw:0.45:12", seed=1, snr_db=20.0)
    ref = build_reference(xr, cfg, "ccw")
    # a warmer room than the reference's: the range scale is followed (rescaled features)
    x, _ = simulate(scene, cfg, 20.0, schedule="cw:0.4:20", seed=2, snr_db=15.0,
                    drift_ppm=30.0, nuisances=Nuisances(speed_of_sound=346.0),
                    include_paths=False)
    whole, rows = analyze(x, cfg, ref, track=True)
    assert whole["direction"] == "reversed", whole
    for size in (65_536, 77_777):
        s, r = analyze((x[i:i + size] for i in range(0, len(x), size)), cfg, ref,
                       track=True)
        assert s == whole, size
        assert r == rows, size
