"""Range-doppler map: the discrete Fourier transform along pulses, centred at zero doppler.

As in the paper, no weighting beyond an optional window: it is used to find the target's
range and the blade-pass frequency at reference time, and for pictures. It is never run
per live pulse.
"""

from __future__ import annotations

import numpy as np

from .analytic import edge_taper, fast_len


def band_limited(pulses: np.ndarray, band: float) -> np.ndarray:
    """Each pulse (row) with only the lower ``band`` of its band up to Nyquist, its ends
    tapered first (a square cut leaks the top of the band into the rest)."""
    x = np.asarray(pulses, dtype=np.float64)
    L = x.shape[-1]
    n = fast_len(L + 32)
    spec = np.fft.rfft(x * edge_taper(L), n=n, axis=-1)
    spec[..., max(int(band * (n // 2)), 1):] = 0.0
    out: np.ndarray = np.fft.irfft(spec, n=n, axis=-1)[..., :L]
    return out


def without_shift_and_gain(pulses: np.ndarray) -> np.ndarray:
    """The pulses less what a sub-sample shift or a gain change of their mean explains:
    each row minus its least-squares fit by the mean pulse and the mean's derivative
    along range (a pulse cut a few hundredths of a sample off, or heard a little louder,
    leaves exactly those on every static echo; the fan's echoes, shaped otherwise, stay)."""
    x = np.asarray(pulses, dtype=np.float64)
    mean = x.mean(axis=0)
    basis = np.stack([mean, np.gradient(mean)], axis=1)          # (L, 2)
    coef, *_ = np.linalg.lstsq(basis, (x - mean).T, rcond=None)    # (2, n)
    out: np.ndarray = x - (basis @ coef).T
    return out


def range_doppler(pulses: np.ndarray, prf: float, *, window: str | None = "hann",
                  remove_mean: bool = True, pad: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Doppler spectrum of every delay sample.

    Parameters
    ----------
    pulses : ndarray, shape (n_pulses, n_samples)
        Aligned pulses (rows), float.
    prf : float
        Pulse repetition frequency, Hz.
    window : {"hann", None}
        Taper along pulses (lowers the sidelobes of strong lines).
    remove_mean : bool
        Subtract the mean pulse first (the static room response, all at zero doppler).
    pad : int
        Zero-padding factor along pulses (finer bin spacing, same resolution).

    Returns
    -------
    freqs : ndarray, shape (n_fft,)
        Doppler frequency of each row, Hz, ascending with zero at ``n_fft // 2``.
    power : ndarray, shape (n_fft, n_samples)
        Power ``|X|^2`` per doppler bin and delay sample.
    """
    x = np.asarray(pulses, dtype=np.float64)
    if x.ndim != 2 or x.shape[0] < 2:
        raise ValueError(f"pulses must be a 2-D array with at least 2 rows, got shape "
                         f"{x.shape}")
    if remove_mean:
        x = x - x.mean(axis=0, keepdims=True)
    if window == "hann":
        x = x * np.hanning(x.shape[0])[:, None]
    elif window is not None:
        raise ValueError(f"window must be 'hann' or None, not {window!r}")
    n_fft = int(max(1, pad)) * x.shape[0]
    spec = np.fft.fftshift(np.fft.fft(x, n=n_fft, axis=0), axes=0)
    freqs = np.fft.fftshift(np.fft.fftfreq(n_fft, d=1.0 / prf))
    return freqs, np.abs(spec) ** 2
