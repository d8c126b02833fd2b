"""Blade-pass rate: sub-bin accuracy, harmonic-vs-fundamental, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from bladesonar.dsp.fingerprint import envelope_features
from bladesonar.dsp.period import drift_harmonic, estimate_period, sub_sample_cycle
from bladesonar.errors import EstimationError
from synth_pulses import fan_pulse

pytestmark = pytest.mark.slow   # period estimation on simulated recordings: outside the fast tier

L = 1000


def _pulses(rate, n, noise=0.004, seed=0, pattern=fan_pulse):
    rng = np.random.default_rng(seed)
    ph = np.mod(0.13 + rate * np.arange(n), 1.0)
    x = np.array([pattern(p, L) for p in ph]) + noise * rng.standard_normal((n, L))
    y = x - x.mean(axis=0)
    f = envelope_features(x, x.mean(axis=0))
    return y, f - f.mean(axis=0)


@pytest.mark.parametrize("rate", [0.0617, 0.1333, 0.2871])
def test_refined_rate_error_is_far_below_one_bin(rate):
    """Non-integer period (e.g. 16.2 pulses): error << one FFT bin (1/N cycles/pulse)."""
    n = 300
    y, f = _pulses(rate, n)
    est = estimate_period(y, features=f)
    assert abs(est.cycles_per_pulse - rate) < 0.02 / n


def test_fundamental_is_found_when_a_harmonic_is_the_strongest_line():
    """Echo amplitudes whose 2nd harmonic in angle dominates: the fundamental must win."""
    from synth_pulses import add_pulse

    def pattern(phase, length):
        x = np.zeros(length)
        for j, d in enumerate((310.0, 455.0, 620.0, 800.0)):
            a = 0.04 * (1.2 + 0.35 * np.cos(2 * np.pi * (phase + 0.2 * j))
                        + np.cos(2 * np.pi * (2 * phase + 0.37 * j)))
            add_pulse(x, d + 2.0 * np.sin(2 * np.pi * (phase + 0.1 * j)), a)
        return x
    rate = 0.043
    y, f = _pulses(rate, 400, pattern=pattern)
    from bladesonar.dsp.period import doppler_spectrum
    nu, s = doppler_spectrum(f)
    strongest = nu[np.argmax(np.where(nu > 0.01, s, 0))]
    assert abs(strongest - rate) > 0.01                 # the strongest line is a harmonic
    est = estimate_period(y, features=f)
    assert abs(est.cycles_per_pulse - rate) < 0.02 / 400


def test_stationary_target_is_refused():
    y, f = _pulses(0.0, 300)
    with pytest.raises(EstimationError, match="stationary"):
        estimate_period(y, features=f)


def test_aliased_rate_is_refused():
    y, f = _pulses(0.46, 300)
    with pytest.raises(EstimationError, match="aliased"):
        estimate_period(y, features=f)


def test_too_few_periods_are_refused():
    y, f = _pulses(0.05, 100)                   # 5 periods
    with pytest.raises(EstimationError, match="5.0 blade periods"):
        estimate_period(y, features=f, min_periods=6)


def _step_or_alternation(n: int, kind: str) -> np.ndarray:
    """Pulses whose echo pattern is one of two: switching once at pulse 220 (a WAV whose
    data change sample rate there, as a fuzzed file did at sample 286231 = 220.7 PRIs),
    or every other pulse; mean removed, a little noise."""
    rng = np.random.default_rng(3)
    a, b = rng.standard_normal(40), rng.standard_normal(40)
    second = np.arange(n) >= 220 if kind == "step" else np.arange(n) % 2 == 1
    y = np.where(second[:, None], b, a) + 0.01 * rng.standard_normal((n, 40))
    return y - y.mean(axis=0)


@pytest.mark.parametrize("kind", ["step", "alternation"])
def test_echoes_that_change_instead_of_turning_are_refused(kind):
    """A step's spectrum only falls from zero doppler and an alternation's sits at half
    the PRF: neither has a peak a fan makes, so no rate is a candidate. That is a clear
    EstimationError (it was numpy's "zero-size array to reduction operation maximum")."""
    y = _step_or_alternation(808, kind)
    with pytest.raises(EstimationError, match="changed during the recording"):
        estimate_period(y)


def test_range_doppler_puts_a_modulated_sample_at_its_doppler_and_delay():
    from bladesonar.dsp.rangedoppler import range_doppler
    prf, n = 34.0, 256
    x = np.zeros((n, 100))
    x[:, 40] = np.cos(2 * np.pi * 3.0 * np.arange(n) / prf) + 5.0   # 3 Hz at delay 40
    f, p = range_doppler(x, prf)
    i, j = np.unravel_index(np.argmax(p), p.shape)
    assert j == 40 and abs(abs(f[i]) - 3.0) <= prf / n
    assert f[len(f) // 2] == 0.0 and p[len(f) // 2, 40] < 1e-6 * p.max()  # static removed



def test_commensurate_reference_is_right_or_refused_naming_the_fraction(tmp_path):
    # 0.5 Hz, 4 blades, PRF 34.0: exactly 1/17 blade period per pulse, 8 s through the
    # daemon's sim backend. The pulses see only 17 angles and every m/17 fits them; with
    # this seed the search says 7/17 = 0.41, beyond the aliasing guard. The refusal must
    # then name the fraction and the fix, not only the aliasing limit; a success (should
    # the search improve) must have the true rate.
    import json
    import subprocess

    from loopback import bladesonar_cmd, write_config
    cfg = write_config(tmp_path / "c.yaml", tmp_path, audio={"backend": "sim"},
                       sim={"schedule": "ccw:0.5:20", "realtime": False})
    r = subprocess.run(bladesonar_cmd("reference", "--live", "--seconds", "8", "--direction",
                                      "ccw", "--config", str(cfg)),
                       capture_output=True, text=True, timeout=120)
    if r.returncode == 0:
        assert json.loads(r.stdout)["rate_hz"] == pytest.approx(0.5, rel=0.01)
    else:
        assert r.returncode == 2 and "Traceback" not in r.stderr
        assert "/17 cycle per pulse" in r.stderr and "different fan speed" in r.stderr


def test_a_reference_at_2_33_blade_period_per_pulse_is_not_folded_at_13_33():
    """A 4-blade fan at 0.5151 Hz is 2/33 blade period per pulse within 1e-5: twenty
    seconds show the same 33 angles again and again, every m/33 folds them as tightly, and
    the search took 13/33 (3.35 Hz, a fold whose angles were in no order). Among folds in
    no order the order of the angles decides (random tuning scene 45)."""
    from bladesonar import config
    from bladesonar.reference_build import build_reference
    from bladesonar.sim.nuisances import Nuisances
    from bladesonar.sim.render import simulate
    from bladesonar.sim.scene import Scene
    w, d = 6.437514676614429, 3.807731469506611
    sc = Scene.from_mapping({
        "room": {"vertices": [[0, 0], [w, 0], [w, d], [0, d]],
                 "reflection": [0.527, 0.862, 0.422, 0.437]},
        "sensor": [6.04052082014192, 1.8165420589064094], "coupling_gain": 1.0163684436891622,
        "fan": {"centre": [4.000505761134571, 1.3770283454499717], "blades": 4,
                "blade_length_m": 0.5875387960157299, "hub_radius_m": 0.07672756734798229,
                "start_angle_deg": float(np.degrees(3.7450468830768413))}})
    cfg = config.Config()
    nz = Nuisances(speaker_highpass_hz=391.0, speaker_resonance_hz=1663.0, rt60_s=0.2,
                   reverb_db=-11.4)
    x, _ = simulate(sc, cfg, 20.0, schedule="cw:0.5151:60", seed=45,
                    snr_db=24.74495076394045, drift_ppm=132.46336829143542, nuisances=nz,
                    include_paths=False)
    ref = build_reference(x, cfg, "cw")
    assert ref.meta["rate_hz"] == pytest.approx(0.5151, rel=1e-3)


def test_a_rate_on_the_drifting_sub_sample_cycle_is_named_by_its_harmonic():
    """Closed form: pulses 1297.0320 samples apart (+24.7 ppm on a 1297-sample PRI) are
    read at a sub-sample position that turns 0.0320 cycles per pulse; over 680 pulses a
    bin is 1/680 = 0.00147. 0.0640 (1.99 x, the 3-D scene whose reference came out at
    3.3 times the fan's rate) is the second harmonic, 0.0320 and 0.0960 the first and
    third, 0.050 none. With the drift the other way (1296.8443: 0.1557 per pulse) 0.3125
    is the second; a harmonic past 1/2 folds (0.3 per pulse: the second is 0.4)."""
    assert sub_sample_cycle(1297.0320) == pytest.approx(0.0320, abs=1e-9)
    assert sub_sample_cycle(1296.8443) == pytest.approx(0.1557, abs=1e-9)
    assert drift_harmonic(0.0640, 1297.0320, 680) == 2
    assert drift_harmonic(0.06407, 1297.0320, 680) == 2
    assert drift_harmonic(0.0320, 1297.0320, 680) == 1
    assert drift_harmonic(0.0960, 1297.0320, 680) == 3
    assert drift_harmonic(0.0500, 1297.0320, 680) is None
    assert drift_harmonic(0.0640 + 2.0 / 680, 1297.0320, 680) is None
    assert drift_harmonic(0.3125, 1296.8443, 680) == 2
    assert drift_harmonic(0.4, 1297.3, 680) == 2


def test_a_sub_sample_cycle_that_hardly_turns_over_the_record_is_no_line():
    """Closed form: at +0.8 ppm (1297.001 samples) the position turns 0.68 times over
    680 pulses: no line to mistake a fan for, whatever the rate (so a slow fan at
    0.001 cycles per pulse is not refused)."""
    assert drift_harmonic(0.001, 1297.001, 680) is None
    assert drift_harmonic(0.002, 1297.001, 680) is None
    assert drift_harmonic(0.001, 1297.001, 3000) == 1


def test_the_strongest_line_is_reported_beside_the_rate_that_explains_it():
    """A pattern with one line only, at 0.31512 cycles per pulse (twice the sub-sample
    cycle of pulses 1296.8424 samples apart, -121.5 ppm on 1297): whichever rate the
    estimator takes to explain it (the line itself, or a rate whose aliased harmonic it
    is, as in held-out 7100013: 0.342, whose second harmonic folds onto it), the line it
    explains is reported, within a bin (1/680), and named as the drift's second
    harmonic."""
    from synth_pulses import add_pulse

    def pattern(phase, length):
        x = np.zeros(length)
        add_pulse(x, 420.0, 0.04 * (1.2 + np.cos(2 * np.pi * phase)))
        return x
    nu0 = 2 * (1297.0 - 1296.8424)
    y, _ = _pulses(nu0, 680, pattern=pattern)
    est = estimate_period(y)            # (the raw pulses: linear in the echo's amplitude)
    assert abs(est.strongest_line - nu0) <= 1.0 / 680
    assert drift_harmonic(est.strongest_line, 1296.8424, 680) == 2
