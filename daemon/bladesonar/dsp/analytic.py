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


def analytic_magnitude(y: np.ndarray, band: float = 1.0) -> np.ndarray:
    """|analytic signal| of each row of ``y`` (along the last axis), zero-padded by 32
    samples or more; ``band`` < 1 keeps only that fraction of the band up to Nyquist."""
    y = np.asarray(y, dtype=np.float64)
    L = y.shape[-1]
    nfft = fast_len(L + 32)
    spec = np.fft.rfft(y, n=nfft, axis=-1)
    # positive frequencies doubled, negative ones zero
    spec[..., 1:(nfft + 1) // 2] *= 2.0
    if band < 1.0:
        spec[..., max(int(band * (nfft // 2)), 1):] = 0.0
    full = np.zeros(y.shape[:-1] + (nfft,), dtype=complex)
    full[..., :spec.shape[-1]] = spec
    out: np.ndarray = np.abs(np.fft.ifft(full, axis=-1)[..., :L])
    return out
