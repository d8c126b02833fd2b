"""tools/bench_analyze's paper-literal baseline (plain numpy, the method as the paper
states it) finds the direction and the rate of a steady fan against the simulator's truth:
the figure it puts beside ``analyze`` is that of a pipeline that works, not of one that
skips the work."""

from __future__ import annotations

import importlib.machinery
import importlib.util

import pytest

from bladesonar import config
from bladesonar.io.scene_file import load_scene
from bladesonar.reference_build import build_reference
from bladesonar.sim.render import simulate

pytestmark = pytest.mark.slow   # simulated recordings: outside the fast tier


@pytest.fixture(scope="module")
def bench(repo_root):
    loader = importlib.machinery.SourceFileLoader("bench_analyze",
                                                  str(repo_root / "tools/bench_analyze"))
    spec = importlib.util.spec_from_loader("bench_analyze", loader)
    assert spec is not None
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("schedule, direction, relative", [
    ("ccw:0.45:30", "same", 1.0),
    ("cw:0.4:30", "reversed", -0.4 / 0.45),
])
def test_the_paper_literal_baseline_finds_a_steady_fan(repo_root, bench, schedule,
                                                       direction, relative):
    cfg = config.Config()
    scene = load_scene(repo_root / "config/scenes/paper-room.yaml")
    xr, _ = simulate(scene, cfg, 12.0, schedule="ccw:0.45:12", seed=1, snr_db=20.0)
    ref = build_reference(xr, cfg, "ccw")
    x, _ = simulate(scene, cfg, 30.0, schedule=schedule, seed=2, snr_db=20.0,
                    drift_ppm=50.0)
    got = bench.paper_literal(x, cfg, ref)
    assert got["direction"] == direction, got
    # a rough answer (no tracker: the mismatches of the blind half-period pull it towards
    # rest by a few per cent), but the rate of this fan, not of another line
    assert abs(got["relative_rate"] - relative) < 0.06 * abs(relative), got
