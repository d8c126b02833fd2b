"""The magnitude of the analytic signal, on numpy.fft (pure numpy, float64).

numpy's FFT is the same pocketfft as scipy.fft's; the daemon uses it to leave scipy
out of its imports (scipy.fft with scipy.special cost it 18 MiB of resident memory).
"""

from __future__ import annotations

import functools

import numpy as np


@functools.lru_cache(maxsize=64)
def fast_len(n: int) -> int:
    """The smallest length >= ``n`` with no prime factor above 11: the FFT length
    scipy.fft.next_fast_len chooses for complex transforms."""
    m = max(int(n), 1)
    while True:
        r = m
        for p in (2, 3, 5, 7, 11):
            while r % p == 0:
                r //= p
        if r == 1:
            return m
        m += 1


#: Samples at each end of a row tapered (raised cosine) before a band limit: the top of
#: the band holds the aligner's interpolation error, a function of the sub-sample position
#: that turns once every 1 / (drift x PRI) pulses; cut off square at the gate's ends it
#: leaked into the low band, where, on strong static echoes (30 dB over the noise) with
#: 40 ppm of drift, it lifted a resting fan's motion figure from 1.02 to 1.07 (1.02 with
#: the taper; 32 or 64 samples did no better).
BAND_TAPER = 8


@functools.lru_cache(maxsize=16)
def edge_taper(L: int) -> np.ndarray:
    """Ones, with BAND_TAPER samples of raised cosine at each end (read-only, cached)."""
    w = np.ones(L)
    n = min(BAND_TAPER, L // 2)
    if n > 0:
        r = 0.5 - 0.5 * np.cos(np.pi * (np.arange(n) + 0.5) / n)
        w[:n] = r
        w[L - n:] = r[::-1]
    w.flags.writeable = False
    return w


def analytic_magnitude(y: np.ndarray, band: float = 1.0,
                       out: np.ndarray | None = None) -> np.ndarray:
    """|analytic signal| of each row of ``y`` (along the last axis), zero-padded by 32
    samples or more; ``band`` < 1 keeps only that fraction of the band up to Nyquist
    (the rows' ends tapered first: ``BAND_TAPER``). ``out``: where to write it (the
    shape of ``y``), else a new array."""
    y = np.asarray(y, dtype=np.float64)
    L = y.shape[-1]
    if band < 1.0:
        y = y * edge_taper(L)
    nfft = fast_len(L + 32)
    spec = np.fft.rfft(y, n=nfft, axis=-1)
    # positive frequencies doubled, negative ones zero
    spec[..., 1:(nfft + 1) // 2] *= 2.0
    if band < 1.0:
        spec[..., max(int(band * (nfft // 2)), 1):] = 0.0
    # ifft's n pads the half spectrum with the zeros of the negative frequencies
    got: np.ndarray = np.abs(np.fft.ifft(spec, n=nfft, axis=-1)[..., :L], out=out)
    return got
