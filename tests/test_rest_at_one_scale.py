"""A loud fan near the device comes to rest (truth: the simulator's schedule). Spent
held-out room 3700008 (docs/dynamics.md, "The room while the fan rests"): a 5-blade
fan 1.7 m from the device at 29.5 dB, under 5 ppm of clock drift. Its echo moves the
pulses' gain by more than 1.5 dB, so the reference asks for each pulse to be scaled to
the static estimate (``normalise``). That scale followed the estimate: after a slow
spin-down the estimate, held while the fan was slow, was let go and moved over seconds
to the resting room, whose resting blade glints, and the scale of every resting pulse
moved with it (by 2.3 times); the projection also follows the sub-sample position
under drift. The short meter, which calls rest when the pulses stop changing, read
both as motion: in a day there, stops came 8.4 and 4.8 s late.

Since 0c4b3d9 that reference reads 0.28 dB of gain wander: the 1.5 dB and more it read
came from its clipped coupling's timing, off by a sawtooth of the sub-sample position
that the 5 ppm of drift turned, which the whole-recording fit now takes out
(dsp/pulses.align_recording). So the room is run both ways: as its reference now
leaves it (no scaling), and with the reference's figure set over the threshold, as it
read before, so that the scaled path stays covered.
"""

from __future__ import annotations

import pytest

from bladesonar import config
from bladesonar.dsp import device as dev
from bladesonar.live import LiveAnalyzer
from bladesonar.sim import random_scene
from live_feed import pulses
from scene_runs import learned, streamed

pytestmark = pytest.mark.slow   # a 20 s reference and three 84 s runs, about 30 s of CPU

SEED = 3700008
#: at rest first: the aligner learns the coupling's timing error over its first 30 s
LEAD_S, TURN_S = 40.0, 20.0


@pytest.mark.parametrize("ramp_s, scaled", [(8.0, True), (10.0, True), (10.0, False)])
def test_a_loud_fans_rest_is_called_once_its_echoes_have_died_away(ramp_s, scaled):
    c0 = config.Config()
    dr = random_scene.draw(SEED, c0.prf_hz)
    cfg = config.replace(c0, scene={"blades": dr.blades})
    ref = learned(dr, cfg, SEED)
    device = ref.meta["device"]
    assert device is not None and device["gain_wander_db"] < dev.NORMALISE_ABOVE_DB
    if scaled:
        # the case as it was: the reference's figure over the threshold, pulses scaled
        device["gain_wander_db"] = 2.0 * dev.NORMALISE_ABOVE_DB
    rest_at = LEAD_S + TURN_S + ramp_s
    # a slow spin-down (0.04-0.05 Hz/s), slow long enough for the estimate to be held
    sim = streamed(dr, cfg, f"stop:0:{LEAD_S},{dr.ref_direction}:{dr.ref_rate_hz:.4f}:"
                   f"{TURN_S}~3,stop:0:14~{ramp_s}", SEED + 1)
    live = LiveAnalyzer(cfg, ref)
    fs = cfg.audio.sample_rate
    stops = [pos / fs for pos, _, events in pulses(sim, live, rest_at + 14.0)
             for e in events if e.kind == "stopped" and pos / fs > LEAD_S]
    assert stops, "no stop called"
    # at rest the pulses are the same but for noise; what keeps changing after the
    # fan's last echoes have rung out (RT60 0.71 s) is the meter's own 1.5 s window,
    # and the bound for the worst stop is 4 s: here it must come within 3 s
    assert rest_at - 1.0 <= stops[0] <= rest_at + 3.0, (stops, rest_at)
