"""A capture starts before the first played pulse comes back (device latency, the
loopback room's pre-roll): the aligner skips the lead-in instead of refusing the stream."""

from __future__ import annotations

import numpy as np
import pytest

from bladesonar.dsp.gate import make_gate
from bladesonar.dsp.pulses import OK, PulseAligner, align
from bladesonar.errors import InputError
from synth_pulses import pulse_train

PRI = 1297


def _gate():
    return make_gate(0.3, None, c=343.0, fs=44100.0, pri=PRI)


@pytest.mark.parametrize("lead_s, noise", [(4.3, 0.0), (4.3, 1e-3), (40.7, 1e-3)])
def test_the_first_pulse_after_a_lead_in_is_found_at_its_true_edge(lead_s, noise):
    x, edges, _ = pulse_train(60, PRI, rate=0.05, first_edge=100.25, noise=noise, seed=2)
    lead = int(lead_s * PRI)
    rng = np.random.default_rng(5)
    y = np.concatenate([noise * rng.standard_normal(lead), x])
    got = align(y, PRI, _gate())
    ok = got.status == OK
    assert ok.sum() >= 55
    # every OK pulse's edge is a true edge shifted by the lead-in, to a small fraction of
    # a sample (the position is not reset by the skipped PRIs)
    true = edges + lead
    nearest = np.abs(got.edges[ok][:, None] - true[None, :]).min(axis=1)
    assert nearest.max() < 0.05


def test_chunked_lead_in_equals_one_shot():
    x, _, _ = pulse_train(40, PRI, rate=0.05, first_edge=300.0, noise=1e-3)
    y = np.concatenate([np.zeros(5 * PRI + 321), x])
    one = align(y, PRI, _gate())
    a = PulseAligner(PRI, _gate())
    parts = [a.push(y[i:i + PRI]) for i in range(0, len(y), PRI)] + [a.flush()]
    edges = np.concatenate([p.edges for p in parts])
    assert np.array_equal(edges, one.edges)


def test_a_lead_in_longer_than_the_limit_is_refused():
    x, _, _ = pulse_train(20, PRI, rate=0.05, noise=1e-3)
    y = np.concatenate([1e-3 * np.random.default_rng(1).standard_normal(80 * PRI), x])
    with pytest.raises(InputError, match="no direct-coupling pulse"):
        align(y, PRI, _gate(), max_lead_in=64)
