"""Transmit pulses and the fractional-delay kernel, checked against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from bladesonar import config, waveform


def band_limited_peak(x: np.ndarray, up: int = 64) -> float:
    """Peak position of the band-limited reconstruction of x (zero-padded FFT upsampling,
    then a parabola on the fine grid): independent of the kernel under test."""
    n = len(x)
    X = np.fft.rfft(x)
    Y = np.zeros(n * up // 2 + 1, complex)
    Y[:len(X)] = X
    y = np.fft.irfft(Y, n * up)
    i = int(np.argmax(y))
    a, b, c = y[i - 1], y[i], y[i + 1]
    return (i + 0.5 * (a - c) / (a - 2 * b + c)) / up


def test_fractional_delay_peak_lands_within_005_sample():
    rng = np.random.default_rng(7)
    for t in rng.uniform(80.0, 176.0, 300):
        idx, w = waveform.fractional_delay_taps(np.array([t]))
        x = waveform.render(idx, w, 0, 256)
        assert abs(band_limited_peak(x) - t) < 0.05


def test_integer_delay_is_a_unit_impulse():
    idx, w = waveform.fractional_delay_taps(np.array([40.0]))
    x = waveform.render(idx, w, 0, 100)
    expect = np.zeros(100)
    expect[40] = 1.0
    assert np.allclose(x, expect, atol=1e-15)


def test_kernel_passes_dc_and_is_symmetric():
    for f in (0.1, 0.37, 0.5, 0.93):
        _, w = waveform.fractional_delay_taps(np.array([10.0 + f]))
        assert abs(w.sum() - 1.0) < 1e-3
    x = np.linspace(-15.5, 15.5, 101)
    assert np.allclose(waveform.kernel(x), waveform.kernel(-x))
    assert np.all(waveform.kernel(np.array([16.0, -16.0, 20.0])) == 0)


def test_hann_pulse_shape():
    p = waveform.pulse_shape("hann", 5)
    assert np.allclose(p, np.sin(np.pi * np.arange(1, 6) / 6) ** 2 / 1.0)
    assert p.max() == 1.0 and np.argmax(p) == 2
    assert np.array_equal(waveform.pulse_shape("impulse", 9), [1.0])
    with pytest.raises(ValueError, match="pulse kind"):
        waveform.pulse_shape("chirp")
    with pytest.raises(ValueError, match="n_samples"):
        waveform.pulse_shape("hann", 0)


def test_pulse_train_places_pulse_k_at_k_times_pri():
    cfg = config.Config()
    x = waveform.pulse_train(5 * 1297 + 3, cfg)
    nz = np.nonzero(x)[0]
    assert list(nz) == [0, 1297, 2594, 3891, 5188, 6485]
    assert np.all(x[nz] == cfg.waveform.amplitude)


@pytest.mark.parametrize("pulse,n", [("impulse", 1), ("hann", 31)])
def test_pulse_train_chunked_equals_one_shot(pulse, n):
    cfg = config.replace(config.Config(), waveform={"pulse": pulse, "pulse_samples": n,
                                                    "pri_samples": 100})
    whole = waveform.pulse_train(1000, cfg)
    parts, start = [], 0
    for size in (1, 7, 99, 100, 250, 13, 530):
        parts.append(waveform.pulse_train_chunk(start, size, cfg))
        start += size
    assert np.array_equal(np.concatenate(parts), whole)
    if pulse == "hann":
        assert np.allclose(whole[200:231], cfg.waveform.amplitude
                           * waveform.pulse_shape("hann", 31))


def test_pulse_train_rejects_negative_arguments():
    with pytest.raises(ValueError, match="start_sample"):
        waveform.pulse_train_chunk(-1, 10, config.Config())


def test_i0_agrees_with_scipy_over_the_kaiser_arguments():
    """The daemon's own I0 (a power series: scipy stays out of the daemon) against
    scipy.special.i0, the reference implementation, over 0..KAISER_BETA and at the
    closed forms I0(0) = 1 and I0 even."""
    from scipy.special import i0 as scipy_i0

    from bladesonar.waveform import KAISER_BETA, i0
    x = np.linspace(0.0, KAISER_BETA, 20001)
    np.testing.assert_allclose(i0(x), scipy_i0(x), rtol=4e-15, atol=0.0)
    assert i0(0.0) == 1.0
    np.testing.assert_array_equal(i0(-x), i0(x))
