"""Angular table and matching."""

from __future__ import annotations

import numpy as np

from bladesonar.dsp import fingerprint as fp
from synth_pulses import fan_pulse

L = 1000
R_REF = 0.0437          # reference blade phase per pulse (non-integer period 22.9 pulses)


def _reference(n=500, noise=0.003, kind="envelope", seed=0):
    rng = np.random.default_rng(seed)
    ph = fp.fold_phases(np.arange(n), R_REF)
    x = np.array([fan_pulse(p, L) for p in ph]) + noise * rng.standard_normal((n, L))
    mean = x.mean(axis=0)
    f = fp.envelope_features(x, mean, kind=kind)
    bins = fp.auto_bins(R_REF)
    table, _ = fp.build_table(f, ph, bins)
    return table, mean


def _probe(phases, noise=0.003, jitter=0.0, seed=1):
    rng = np.random.default_rng(seed)
    j = jitter * rng.uniform(-1, 1, len(phases))
    return np.array([fan_pulse(p, L, jitter=jj) for p, jj in zip(phases, j, strict=True)]) + \
        noise * rng.standard_normal((len(phases), L))


def _circ_err(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + 0.5) % 1.0 - 0.5)


def test_matches_recover_the_true_phase_between_reference_pulses():
    """Folding 20+ periods of a non-integer period fills in angles between pulses."""
    table, mean = _reference()
    truth = np.random.default_rng(3).uniform(0, 1, 200)
    f = fp.envelope_features(_probe(truth), mean)
    m = fp.match(f, table)
    assert np.median(_circ_err(m.phase, truth)) < 0.01
    assert np.percentile(_circ_err(m.phase, truth), 95) < 0.03
    assert np.median(m.quality) > 0.3


def test_a_pattern_that_changes_within_a_pulse_step_is_matched_between_its_bins():
    """A fast reference (0.1237 blade periods per pulse: 8.1 pulses a period) of the
    synthetic fan: at two bins per pulse step (16) its neighbouring bins correlate 0.56
    and the matched phase of pulses at random angles is off by 0.0049 (median) and
    0.0137 (p95) blade periods; the default table must stay within 0.003 and 0.008
    (measured: four per step, 32 bins, 0.0019 and 0.0056)."""
    r = 0.1237
    rng = np.random.default_rng(0)
    n = 500
    ph = fp.fold_phases(np.arange(n), r)
    x = np.array([fan_pulse(p, L) for p in ph]) + 0.003 * rng.standard_normal((n, L))
    mean = x.mean(axis=0)
    bins = fp.auto_bins(r)
    table, _ = fp.build_table(fp.envelope_features(x, mean), ph, bins)
    truth = np.random.default_rng(3).uniform(0, 1, 300)
    m = fp.match(fp.envelope_features(_probe(truth), mean), table)
    err = _circ_err(m.phase, truth)
    assert np.median(err) < 0.003
    assert np.percentile(err, 95) < 0.008


def test_order_of_input_pulses_does_not_change_matches():
    table, mean = _reference()
    truth = np.random.default_rng(4).uniform(0, 1, 64)
    f = fp.envelope_features(_probe(truth), mean)
    perm = np.random.default_rng(5).permutation(len(f))
    a, b = fp.match(f, table), fp.match(f[perm], table)
    np.testing.assert_array_equal(a.phase[perm], b.phase)
    np.testing.assert_array_equal(a.quality[perm], b.quality)


def test_noise_gets_low_quality():
    table, mean = _reference()
    noise = 0.01 * np.random.default_rng(6).standard_normal((100, L))
    m = fp.match(fp.envelope_features(noise + mean, mean), table)
    assert np.median(m.quality) < 0.15


def test_envelope_beats_raw_under_jitter():
    """Why envelopes: with up to 1.5 samples of echo jitter (residual misalignment,
    clock drift inside a pulse, blade vibration) raw matching jumps to wrong angles for
    a fifth of the pulses; envelope matching keeps every one within 5 % of a period."""
    truth = np.random.default_rng(7).uniform(0, 1, 150)
    probe = _probe(truth, jitter=1.5)
    gross, med = {}, {}
    for kind in ("envelope", "raw"):
        table, mean = _reference(kind=kind)
        m = fp.match(fp.envelope_features(probe, mean, kind=kind), table)
        err = _circ_err(m.phase, truth)
        gross[kind], med[kind] = np.mean(err > 0.05), np.median(err)
    assert gross["envelope"] < 0.02 and med["envelope"] < 0.01
    assert gross["raw"] > 0.1


def test_table_fills_bins_nothing_fell_into():
    f = np.array([[0.0, 0.0], [4.0, 8.0]])
    table, w = fp.build_table(f, np.array([0.0, 0.5]), 4)
    assert w[1] == 0 and w[3] == 0
    np.testing.assert_allclose(table[1], [2.0, 4.0])
    np.testing.assert_allclose(table[3], [2.0, 4.0])


def test_distance_floor_of_orthogonal_rows_is_a_share_of_their_distance():
    """Rows a * e_b of the identity are all 2 a^2 apart (closed form)."""
    a = 0.3
    table = a * np.eye(32)
    assert np.isclose(fp.distance_floor(table), fp.FLAT_SHARE * 2 * a * a, rtol=1e-12)
    assert fp.distance_floor(table[:1]) == 0.0      # one bin: no alternative at all


def test_a_pulse_on_a_flat_part_of_the_table_has_no_quality():
    """Half the table alike (no blade in view), half distinct. A noiseless pulse close to
    one flat bin, closer by a hair than to the others, had a contrast of 1 - d0 / d_far
    well above any clear match's threshold; on the table's own scale those bins are one
    and the same, and with the floor the match says next to nothing. A pulse on a
    distinct bin keeps its contrast exactly."""
    rng = np.random.default_rng(11)
    bins, n = 32, 64
    table = np.zeros((bins, n))
    table[:16] = rng.standard_normal((16, n))             # distinct angles
    table[16:] = 1e-3 * rng.standard_normal((16, n))      # flat: all but alike
    floor = fp.distance_floor(table)
    flat = table[24] + 1e-4 * rng.standard_normal(n)      # nearest bin 24 by a hair
    plain, floored = fp.match(flat, table), fp.match(flat, table, floor=floor)
    assert int(round(float(plain.phase[0]) * bins)) % bins >= 16
    assert plain.quality[0] > 0.2                         # a "clear" match without the floor
    assert floored.quality[0] < 1e-3
    distinct = table[5] + 0.05 * rng.standard_normal(n)
    a, b = fp.match(distinct, table), fp.match(distinct, table, floor=floor)
    assert a.quality[0] > 0.5 and b.quality[0] == a.quality[0]


def test_moving_average_is_the_running_sum_s_and_exact_on_a_ramp():
    """The envelope's smoothing summed shift by shift (short windows) or from a running
    sum (long ones): both the centred mean of the edge-padded row. A ramp's interior is
    its own moving average (closed form); against the running-sum form it used before,
    the same values to rounding."""
    rng = np.random.default_rng(5)
    env = np.abs(rng.standard_normal((6, 90)))
    for s in (2, 3, 5, 8, fp.DIRECT_SMOOTH, fp.DIRECT_SMOOTH + 3):
        lo, hi = s // 2 + 1, s - s // 2 - 1
        c = np.cumsum(np.concatenate([np.repeat(env[:, :1], lo, axis=1), env,
                                      np.repeat(env[:, -1:], hi, axis=1)], axis=1), axis=1)
        before = (c[:, s:] - c[:, :-s]) / s
        got = fp._moving_average(env, s)
        assert got.shape == env.shape
        np.testing.assert_allclose(got, before, rtol=1e-13, atol=1e-14)
        ramp = np.tile(np.arange(90, dtype=np.float64), (2, 1))
        m = fp._moving_average(ramp, s)
        a, b = s // 2, 90 - (s - s // 2 - 1)
        np.testing.assert_allclose(m[:, a:b], ramp[:, a:b] + (0.0 if s % 2 else -0.5),
                                   rtol=0, atol=1e-12)
