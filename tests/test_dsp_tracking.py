"""Circular Kalman filter: convergence, wrap-aware innovation, stiff SPD, outliers."""

from __future__ import annotations

import numpy as np
import pytest

from bladesonar.dsp.tracking import Tracker, TrackerSettings, circular_rate_search, \
    innovation, kalman_step, kalman_update, wrap


def _matches(rate, n, sigma=0.02, outliers=0.1, seed=0, phase0=0.3):
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    z = np.mod(phase0 + rate * k + sigma * rng.standard_normal(n), 1.0)
    bad = rng.uniform(size=n) < outliers
    z[bad] = rng.uniform(size=bad.sum())
    q = np.where(bad, 0.3, 0.9)
    return k, z, q


@pytest.mark.parametrize("rate", [0.047, -0.061, 0.2, -0.33])
def test_constant_rate_track_converges(rate):
    st = TrackerSettings(max_rate=0.45, q_rate=1e-10)
    tr = Tracker(st)
    k, z, q = _matches(rate, 400)
    states = [tr.update(int(a), float(b), float(c)) for a, b, c in zip(k, z, q)]
    last = states[-1]
    assert last.locked
    assert abs(last.rate - rate) < 3e-4
    assert last.rate_std < 3e-4
    assert abs(wrap(last.phase - (0.3 + rate * k[-1]))) < 0.02
    assert tr.outliers > 10           # the uniform outliers were gated, not followed


def test_wrap_aware_innovation_across_zero():
    x = np.array([0.98, 0.0])
    P = np.eye(2) * 0.01
    nu, s = innovation(x, P, 0.02, 0.001)
    assert nu == pytest.approx(0.04)
    xn, _ = kalman_update(x, P, 0.02, 0.001)
    assert 0.98 < xn[0] + (1 if xn[0] < 0.5 else 0) < 1.02   # moved forward through 0
    assert wrap(0.75) == pytest.approx(-0.25) and wrap(-0.6) == pytest.approx(0.4)


def test_stiff_case_keeps_covariance_symmetric_positive_definite():
    """Process noise 1e-12, measurement noise 1e6, a million steps (Joseph form)."""
    x, P = np.array([0.1, 0.01]), np.diag([1.0, 1e-2])
    rng = np.random.default_rng(0)
    zs = rng.uniform(size=1_000_000)
    for z in zs:
        x, P = kalman_step(x, P, float(z), q=1e-12, r=1e6)
    assert P[0, 1] == P[1, 0]
    ev = np.linalg.eigvalsh(P)
    assert ev.min() > 0 and np.all(np.isfinite(P))


def test_circular_regression_finds_the_sign_through_wraps():
    k, z, q = _matches(-0.21, 24, outliers=0.2, seed=2)
    rate, phase, coh = circular_rate_search(k, z, q, 0.45)
    assert abs(rate + 0.21) < 0.01 and coh > 0.6


def test_random_matches_do_not_lock():
    rng = np.random.default_rng(9)
    tr = Tracker(TrackerSettings(max_rate=0.3))
    locked = [tr.update(i, float(rng.uniform()), 0.5).locked for i in range(300)]
    assert sum(locked) < 15


def test_reversal_is_reacquired():
    tr = Tracker(TrackerSettings(max_rate=0.3))
    k1, z1, q1 = _matches(0.05, 200, outliers=0.0, seed=3)
    for a, b, c in zip(k1, z1, q1):
        tr.update(int(a), float(b), float(c))
    end = 0.3 + 0.05 * 199
    k2 = np.arange(200, 320)
    z2 = np.mod(end - 0.05 * (k2 - 199) + 0.02 * np.random.default_rng(4).standard_normal(120), 1)
    rates = [tr.update(int(a), float(b), 0.9).rate for a, b in zip(k2, z2)]
    # within init_pulses + reacquire_after pulses (about 1 s at 34 Hz) the sign flips
    flip = next(i for i, r in enumerate(rates) if r < 0)
    assert flip <= TrackerSettings(max_rate=0.3).init_pulses + 8
    assert abs(rates[-1] + 0.05) < 2e-3
