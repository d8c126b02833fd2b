"""A fan at rest in a room whose static echoes stand 30 dB over the fan's, under clock
drift: it changes nothing between pulses, so the short motion meter must read what noise
alone reads through the same features (a Monte Carlo of white noise, the physics here),
and the stop must be called in time.

Under drift the sub-sample position of every pulse turns once every 1 / (drift x PRI)
pulses, and with it the aligner's interpolation error at the top of the band; strong
static echoes carry it. Three things let it pass for motion (1.07-1.46 where noise reads
1.02): the simulator's late tail, once rendered at the nearest of 32 sub-sample
positions; the gate's square ends, which leaked that error into the band the meter
uses (dsp/analytic.py BAND_TAPER), and a direct coupling that clips at some
sub-sample positions only, whose edges the peak fit read off the clocks' line.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bladesonar import config
from bladesonar.dsp.decide import MotionMeter
from bladesonar.dsp.fingerprint import envelope_features
from bladesonar.live import LiveAnalyzer
from bladesonar.reference_build import build_reference
from bladesonar.sim import random_scene
from bladesonar.sim.render import Simulator, simulate
from bladesonar.sim.schedule import parse
from bladesonar.sim.score import true_time
from bladesonar.tuning import STILL_BAND
from live_feed import pulses

pytestmark = pytest.mark.slow

SEED = 3            # a 3-blade fan 1.75 m away in a 4 x 4.6 m room, reverberant, phone speaker
SNR_DB = 12.0
REST_FROM = 38.0    # the spin-down ends here (true time)


def _strong_static_scene():
    dr = random_scene.draw(SEED)
    # bare walls and blades that return 30 dB less than the ideal reflector: at 12 dB of
    # fan SNR the static room stands some 40 dB over the noise
    scene = dataclasses.replace(dr.scene, wall_reflection=(0.9,) * len(dr.scene.vertices),
                                blade_reflectivity=0.03)
    return dr, scene


def _noise_null(length: int, window: int, max_lag: int, trials: int = 60) -> np.ndarray:
    """The short meter's statistic on white noise through the same features."""
    rng = np.random.default_rng(0)
    out = []
    for _ in range(trials):
        f = envelope_features(rng.standard_normal((window, length)), np.zeros(length),
                              band=STILL_BAND)
        m = MotionMeter(length, window, max_lag)
        m.update_block(f)
        out.append(m.statistic()[0])
    return np.array(out)


@pytest.mark.parametrize("drift_ppm, coupling, snr_db", [
    (0.0, None, SNR_DB), (40.0, None, SNR_DB), (150.0, None, SNR_DB), (40.0, 2.1, 30.0)])
def test_a_resting_fan_among_strong_static_echoes_reads_as_noise(drift_ppm, coupling, snr_db):
    # coupling 2.1, 30 dB: through an ideal speaker, a full-band direct coupling that
    # clips where its peak falls near a sample and not where it falls between two, as
    # drift sweeps it; acquired unclipped, its edges were read off the clocks' line by
    # the peak fit, and the resting room read 1.06 at the median (noise 1.02), as in a
    # held-out room whose stops were never called (dsp/pulses.PulseAligner._line_from_here)
    dr, scene = _strong_static_scene()
    nz = dr.nuisances
    if coupling is not None:
        scene = dataclasses.replace(scene, coupling_gain=coupling)
        nz = dataclasses.replace(nz, speaker_highpass_hz=0.0, speaker_resonance_hz=0.0)
    cfg = config.replace(config.Config(), scene={"blades": dr.blades})
    x, _ = simulate(scene, cfg, 20.0, schedule=f"{dr.ref_direction}:{dr.ref_rate_hz:.4f}:60",
                    seed=SEED, snr_db=snr_db, drift_ppm=drift_ppm, nuisances=nz,
                    include_paths=False)
    ref = build_reference(x, cfg, dr.ref_direction)
    sch = parse(f"{dr.ref_direction}:{dr.ref_rate_hz:.4f}:30,stop:0:40~8")
    sim = Simulator(scene, cfg, sch, snr_db=snr_db, seed=SEED + 1, drift_ppm=drift_ppm,
                    nuisances=nz, include_paths=False)
    live = LiveAnalyzer(cfg, ref)
    fs = cfg.audio.sample_rate
    rest_stats, states, events = [], [], []
    for pos, est, fired in pulses(sim, live, 70.0):
        an = live.analyzer
        t = true_time(pos / fs, drift_ppm)
        events += [(e.kind, true_time(e.t_s, drift_ppm)) for e in fired]
        if est is None or an is None or an._since != 0:
            continue
        states.append((t, est.direction.value, est.rotating))
        if t > REST_FROM + 2.0:      # the short window holds only the resting fan
            rest_stats.append(an.still.statistic()[0])
    an = live.analyzer
    assert an is not None
    null = _noise_null(an.still._s.shape[1], an.still.window, an.still.max_lag)
    rest = np.array(rest_stats)
    assert np.median(rest) <= np.median(null) + 0.02, (np.median(rest), np.median(null))
    assert np.percentile(rest, 95) <= np.percentile(null, 95) + 0.03
    # the stop is called within 3 s of rest and holds, and an event marks it where the
    # fan was known to turn. With the fan's echoes 30 dB down the wall echoes that tell
    # its direction are weak, and under drift the direction can stay in doubt all the
    # while it turns (docs/dynamics.md, the mirror check): the fan is then known to turn
    # with its direction in doubt, and its stop waits, as a known direction's does, for
    # a reversal through zero that would show; a doubt that lasts to the end of the
    # spin-down (the direction never seen) is given until 4.5 s (measured 4.05 s at 40
    # ppm; the worst case is 4 s: docs/dynamics.md, open)
    known = any(d in ("same", "reversed") for t, d, _ in states if t < REST_FROM)
    bound = REST_FROM + (3.0 if known else 4.5)
    called = [t for t, d, _ in states if d == "stopped" and t > REST_FROM - 1.0]
    assert called and REST_FROM <= called[0] <= bound, (called[:3], events)
    after = [d for t, d, _ in states if t >= called[0]]
    assert all(d == "stopped" for d in after)
    turned = any(d in ("same", "reversed") or rot for t, d, rot in states if t < REST_FROM)
    stops = [t for k, t in events if k == "stopped"]
    assert len(stops) == (1 if turned else 0), events
    assert all(REST_FROM <= t <= bound for t in stops), events
