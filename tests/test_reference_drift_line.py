"""A reference learned from the clock drift's pattern says so: where the fan's echoes are
too weak, the alignment's interpolation error on strong static echoes, which turns with
the pulses' sub-sample position under clock drift, is the strongest repeating pattern,
and a reference built on it has a rate that is no fan's (truth: the simulator's scene).
A warning, not a refusal: a fan may turn on that cycle's harmonic by chance."""

from __future__ import annotations

import pytest

from bladesonar import config
from bladesonar.reference_build import build_reference
from bladesonar.sim import random_scene
from bladesonar.sim.render import simulate

pytestmark = pytest.mark.slow   # two 20 s renders of 3-D rooms, about 10 s of CPU


def _reference_recording(seed: int, seconds: float = random_scene.REFERENCE_S):
    c0 = config.Config()
    dr = random_scene.draw_day_3d(seed, c0.prf_hz)
    cfg = config.replace(c0, scene={"blades": dr.blades})
    x, _ = simulate(dr.scene, cfg, seconds,
                    schedule=f"{dr.ref_direction}:{dr.ref_rate_hz:.4f}:60", seed=seed,
                    snr_db=dr.snr_db, drift_ppm=dr.drift_ppm, nuisances=dr.nuisances,
                    include_paths=False)
    return x, cfg, dr


def test_a_fan_hidden_under_the_walls_echoes_gives_a_reference_that_says_so():
    """3-D tuning scene 7: a 3-blade fan at 0.219 Hz 3.2 m away whose echoes are 30-45 dB
    under the walls' (no glint reaches the sensor), +24.7 ppm. The reference comes out at
    0.726 Hz (twice the sub-sample cycle, 0.032 per pulse), and every event of its day
    was missed; it used to carry no warning, now one names the drift and what to do."""
    x, cfg, dr = _reference_recording(7)
    assert dr.ref_rate_hz == pytest.approx(0.219, abs=0.001)
    ref = build_reference(x, cfg, dr.ref_direction)
    assert ref.meta["rate_hz"] == pytest.approx(0.726, abs=0.01)
    said = [w for w in ref.meta["warnings"] if "sub-sample position" in w]
    assert len(said) == 1 and "+25 ppm" in said[0] and "place the device" in said[0]


def test_a_visible_fan_under_drift_is_learned_at_its_rate():
    """3-D tuning scene 1: a 5-blade fan at 0.606 Hz seen 1.4 m away, +49.9 ppm (the
    sub-sample cycle 0.065 per pulse, the blade rate 0.089): learned at the true rate,
    with no word of the drift."""
    x, cfg, dr = _reference_recording(1)
    ref = build_reference(x, cfg, dr.ref_direction)
    assert ref.meta["rate_hz"] == pytest.approx(dr.ref_rate_hz, rel=0.01)
    assert not [w for w in ref.meta["warnings"] if "sub-sample position" in w]
