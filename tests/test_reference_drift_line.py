"""A reference is not learned from the clock drift's pattern: under drift the pulses are
read at a sub-sample position that turns once every 1 / (drift x PRI) pulses, and the
alignment's interpolation error on strong static echoes repeats with it. Where the
fan's echoes are far weaker, that is the strongest line; it lives at the top of the
band, a fan's echoes across it, so the band below decides (truth: the simulator's
scene; the coincidence is built by choosing the drift)."""

from __future__ import annotations

import pytest

from bladesonar import config
from bladesonar.reference_build import build_reference
from bladesonar.sim import random_scene
from bladesonar.sim.render import simulate

pytestmark = pytest.mark.slow   # three 20 s renders, 3-D and 2-D, about 15 s of CPU


def _reference(seed: int, dims: int = 3, drift_ppm: float | None = None):
    c0 = config.Config()
    dr = random_scene.draw_day_3d(seed, c0.prf_hz) if dims == 3 \
        else random_scene.draw(seed, c0.prf_hz)
    cfg = config.replace(c0, scene={"blades": dr.blades})
    drift = dr.drift_ppm if drift_ppm is None else drift_ppm
    x, _ = simulate(dr.scene, cfg, random_scene.REFERENCE_S,
                    schedule=f"{dr.ref_direction}:{dr.ref_rate_hz:.4f}:60", seed=seed,
                    snr_db=dr.snr_db, drift_ppm=drift, nuisances=dr.nuisances,
                    include_paths=False)
    return build_reference(x, cfg, dr.ref_direction), dr, cfg


def _drift_words(ref):
    return [w for w in ref.meta["warnings"] if "sub-sample position" in w]


def test_a_fan_hidden_under_the_drifts_pattern_is_learned_from_the_band_below():
    """3-D tuning scene 7: a 3-blade fan at 0.219 Hz 3.2 m away whose echoes are 30-45 dB
    under the walls' (no glint reaches the sensor), +24.7 ppm. Over the whole band the
    strongest line is twice the sub-sample cycle (0.032 per pulse): a reference at 0.726
    Hz, every event of its day missed. Below 0.7 of Nyquist the fan's own line is the
    strongest: learned at its rate, and the reference says why."""
    ref, dr, _ = _reference(7)
    assert dr.ref_rate_hz == pytest.approx(0.219, abs=0.001)
    assert ref.meta["rate_hz"] == pytest.approx(dr.ref_rate_hz, rel=0.01)
    said = _drift_words(ref)
    assert len(said) == 1 and "0.726 Hz" in said[0] and "+25 ppm" in said[0]


def test_a_visible_fan_under_drift_is_learned_at_its_rate_without_a_word():
    """3-D tuning scene 1: a 5-blade fan at 0.606 Hz seen 1.4 m away, +49.9 ppm (the
    sub-sample cycle 0.065 per pulse, the blade rate 0.089): its rate, no warning."""
    ref, dr, _ = _reference(1)
    assert ref.meta["rate_hz"] == pytest.approx(dr.ref_rate_hz, rel=0.01)
    assert not _drift_words(ref)


def _on_twice_the_cycle(seed: int, ppm: float):
    """2-D tuning scene ``seed``'s reference learned with the drift chosen so that its
    blade rate is exactly twice the sub-sample cycle (``ppm``, checked to 0.1)."""
    c0 = config.Config()
    dr = random_scene.draw(seed, c0.prf_hz)
    blade_rate = dr.ref_rate_hz * dr.blades / c0.prf_hz
    drift = blade_rate / 2.0 / c0.waveform.pri_samples * 1e6
    assert drift == pytest.approx(ppm, abs=0.1)
    ref, dr, _ = _reference(seed, dims=2, drift_ppm=drift)
    return ref, dr


def test_a_fan_that_turns_on_the_drifts_cycle_by_chance_is_learned_without_a_word():
    """2-D tuning scene 1 (a 5-blade fan at 0.228 Hz) with the drift chosen so that its
    blade rate, 0.0335 per pulse, is exactly twice the sub-sample cycle (12.9 ppm on a
    1297-sample PRI): the fan's line is in the band below too, so it is the fan's, and
    nothing is said (refusing such references refused a room whose fan was plain to see)."""
    ref, dr = _on_twice_the_cycle(1, ppm=12.9)
    assert ref.meta["rate_hz"] == pytest.approx(dr.ref_rate_hz, rel=0.01)
    assert not _drift_words(ref)


def test_a_fan_on_twice_the_drifts_cycle_is_learned_at_its_rate():
    """2-D tuning scene 26 (a 4-blade fan at 0.938 Hz) with the drift chosen so that its
    blade rate is exactly twice the sub-sample cycle (42.5 ppm): every line of the fan
    and of the drift's pattern is a harmonic of the cycle (found by building the
    coincidence in tuning scenes 2-48 at harmonic 1 and 1-30 at harmonic 2: the only one
    of 77 not learned at its rate). It was learned at the cycle itself, 0.469 Hz, while
    its coupling, acquired unclipped, clipped at the sub-sample positions the drift
    brings round once a cycle, and those pulses were left out as clipped; clipping at
    the coupling's edge is the coupling's now (PulseAligner._cut), and with every pulse
    kept it is learned at its rate."""
    ref, dr = _on_twice_the_cycle(26, ppm=42.5)
    assert ref.meta["rate_hz"] == pytest.approx(dr.ref_rate_hz, rel=0.01)
