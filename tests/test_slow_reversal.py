"""A slow reversal through zero (0.06 Hz/s) of a 6-blade fan at 10 dB under 148 ppm of
clock drift in a reverberant room, the scene of spent held-out seed 1400008: the reversal
must be confirmed in time, the way the fan went, and nothing else fire.

A fan that slows through zero lingers within a few degrees of one angle for a second or
two, and the running static estimate (a 3 s mean) took in part of its echo there. When
the fan sped up the other way that part stayed in every residual as a ghost at the
angle where it lingered, the matches kept pointing at it, the track stood still while
the fan moved, and the reversal was confirmed 3.2-3.5 s after the fan passed 0.15 Hz
in that scene's day (here 4.9 s, on this noise draw); the estimate now stops adapting
while the fan is read under 0.15 Hz (docs/dynamics.md, "The room while the fan rests").
Truth from the simulator's schedule; a closed form for when it crosses.
"""

from __future__ import annotations

import pytest

from bladesonar import config
from bladesonar.live import LiveAnalyzer
from bladesonar.sim import random_scene
from bladesonar.sim.schedule import parse
from bladesonar.sim.score import true_time
from live_feed import pulses
from scene_runs import learned, streamed

pytestmark = pytest.mark.slow

SEED = 1400008       # spent held-out: 6 blades 1.9 m away, RT60 0.36 s (docs/dynamics.md)
NOISE_SEED = SEED + 2    # the noise draw of the day (one of two tried: 4.9 s late before)
STEADY_S = 12.0      # the reference's way at FROM_HZ, then a ramp of RAMP_S to TO_HZ the
FROM_HZ, TO_HZ, RAMP_S = 0.5, 0.4, 15.0      # other way (as the traced day's reversals)
HOLD_S = 10.0        # the other way at TO_HZ after the ramp's end


def test_a_slow_reversal_is_confirmed_in_time():
    dr = random_scene.draw(SEED)
    cfg = config.replace(config.Config(), scene={"blades": dr.blades})
    ref = learned(dr, cfg, SEED)
    other = "cw" if dr.ref_direction == "ccw" else "ccw"
    sch = parse(f"{dr.ref_direction}:{FROM_HZ}:{STEADY_S},"
                f"{other}:{TO_HZ}:{RAMP_S + HOLD_S}~{RAMP_S}")
    sim = streamed(dr, cfg, sch, NOISE_SEED)
    live = LiveAnalyzer(cfg, ref)
    events = []
    for _, _, fired in pulses(sim, live, STEADY_S + RAMP_S + HOLD_S):
        events += [(e.kind.value, e.direction.value, true_time(e.t_s, drift_ppm=dr.drift_ppm))
                   for e in fired]
    # the ramp passes zero, and 0.15 Hz the other way, where FROM_HZ - slope * t is 0
    # and -0.15 (the scoring's event time; a reversal answered from 0.1 Hz on may come a
    # little before it)
    slope = (FROM_HZ + TO_HZ) / RAMP_S
    zero, crossed = STEADY_S + FROM_HZ / slope, STEADY_S + (FROM_HZ + 0.15) / slope
    assert [(k, d) for k, d, _ in events] == [("reversed", "reversed")], events
    late = events[0][2] - crossed
    # after the fan passed zero; the bound for `reversed` is 2 s at the 95th
    # percentile (4.9 s before)
    assert zero < events[0][2] and late <= 2.0, (late, events)
