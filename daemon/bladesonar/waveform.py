"""Transmit pulses and the band-limited fractional-delay kernel (pure numpy, no I/O).

Two users: the daemon's playback thread (``pulse_train_chunk``: the PRF-locked transmit
signal addressed by a global sample counter, so any chunking gives the same samples) and
the scene simulator (``fractional_delay_taps``: an echo at a non-integer delay rendered
as a windowed sinc, never rounded to whole samples).

Time reference of a pulse: its first sample. For the paper's narrow impulse that is the
only sample; a Hann pulse of N samples peaks (N - 1) / 2 samples later.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .config import Config

#: Taps on each side of the fractional-delay kernel (2 * HALF_TAPS taps in all).
HALF_TAPS = 16
#: Kaiser window shape; with 32 taps the peak of a rendered echo lands well within
#: 0.05 sample of its true delay (tests/test_waveform.py checks against random delays).
KAISER_BETA = 8.0

#: 1 / (k!)^2: the power series of I0 in (x/2)^2, to the term below double precision
#: for |x| <= KAISER_BETA ((x/2)^2 <= 16: the 24th term is 1e-20 of the sum)
_I0_SERIES = np.array([1.0 / math.factorial(k) ** 2 for k in range(24)])


def i0(x: np.ndarray | float) -> np.ndarray:
    """The modified Bessel function I0 for |x| <= KAISER_BETA, the Kaiser window's
    arguments. scipy.special.i0 would bring scipy into the daemon (18 MiB) and numpy's
    np.i0 is a piecewise Chebyshev evaluation about 4 times slower on these arrays;
    this power series agrees with both to about 1e-15 (tests/test_waveform.py)."""
    y = 0.25 * np.square(np.asarray(x, dtype=np.float64))
    out = np.full_like(y, _I0_SERIES[-1])
    for c in _I0_SERIES[-2::-1]:
        out *= y
        out += c
    return out


_I0_BETA = float(i0(KAISER_BETA))


def pulse_shape(kind: str, n_samples: int = 1) -> np.ndarray:
    """Transmit pulse with unit peak, float64.

    ``impulse``: ``[1.0]`` (n_samples ignored). ``hann``: ``sin(pi*(n+1)/(N+1))**2`` for
    n = 0..N-1, i.e. a Hann window without its zero end points, scaled to peak 1.
    """
    if kind == "impulse":
        return np.ones(1)
    if kind == "hann":
        n = int(n_samples)
        if n < 1:
            raise ValueError(f"n_samples must be >= 1 for a hann pulse, got {n_samples!r}")
        p = np.sin(np.pi * np.arange(1, n + 1) / (n + 1)) ** 2
        pulse: np.ndarray = p / p.max()
        return pulse
    raise ValueError(f"pulse kind must be 'impulse' or 'hann', got {kind!r}")


def cfg_pulse(cfg: Config) -> np.ndarray:
    """The configured pulse shape (unit peak); amplitude is applied by the caller."""
    return pulse_shape(cfg.waveform.pulse, cfg.waveform.pulse_samples)


def kernel(x: np.ndarray, band: float = 1.0) -> np.ndarray:
    """Kaiser-windowed sinc at offsets ``x`` (samples); zero for |x| >= HALF_TAPS.

    Full band (``band`` 1, the default): at integer delays it is an exact unit impulse
    (sinc zeros), so the direct coupling of a pulse on the sample grid stays one sample
    wide, as the paper's narrow impulse. ``band`` < 1 cuts off at that fraction of the
    Nyquist frequency (unit gain below it): an interpolant that leaves out the band edge.
    """
    x = np.asarray(x, dtype=np.float64)
    r = x / HALF_TAPS
    inside = np.abs(r) < 1.0
    w = np.where(inside, i0(KAISER_BETA * np.sqrt(np.clip(1.0 - r * r, 0.0, None))), 0.0)
    return band * np.sinc(band * x) * w / _I0_BETA


def fractional_delay_taps(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample indices and weights that render unit impulses at fractional positions.

    Parameters
    ----------
    pos : (A,) float64, positions in samples (any real value).

    Returns
    -------
    idx : (A, 2*HALF_TAPS) int64, the samples touched (may be negative or past the end).
    w : (A, 2*HALF_TAPS) float64, weights; ``sum_j w[a, j] * delta[idx[a, j]]`` is the
        band-limited impulse at ``pos[a]``.
    """
    pos = np.asarray(pos, dtype=np.float64)
    base = np.floor(pos)
    frac = pos - base
    offs = np.arange(-HALF_TAPS + 1, HALF_TAPS + 1, dtype=np.float64)
    w = kernel(offs[None, :] - frac[:, None])
    idx = base.astype(np.int64)[:, None] + offs.astype(np.int64)[None, :]
    return idx, w


def shaped_taps(pos: np.ndarray, amp: np.ndarray, shape: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Like ``fractional_delay_taps`` but each impulse convolved with ``shape`` and scaled by
    ``amp``; each arrival's taps are computed from its own position only, so a chunked
    renderer and a one-shot renderer add identical numbers."""
    idx, w = fractional_delay_taps(pos)
    w = w * np.asarray(amp, dtype=np.float64)[:, None]
    n = len(shape)
    if n == 1:
        return idx, w * shape[0]
    out = np.zeros((w.shape[0], w.shape[1] + n - 1))
    for k in range(n):
        out[:, k:k + w.shape[1]] += shape[k] * w
    idx = idx[:, :1] + np.arange(out.shape[1], dtype=np.int64)[None, :]
    return idx, out


def render(idx: np.ndarray, w: np.ndarray, start: int, n: int) -> np.ndarray:
    """Add weighted taps into samples [start, start + n); taps outside are dropped."""
    i = idx.ravel() - int(start)
    v = w.ravel()
    keep = (i >= 0) & (i < n)
    return np.bincount(i[keep], weights=v[keep], minlength=n).astype(np.float64)


def pulse_train_chunk(start_sample: int, n: int, cfg: Config) -> np.ndarray:
    """Transmit samples [start_sample, start_sample + n): pulse k starts at k * pri_samples.

    Stateless: the daemon's playback thread asks for consecutive chunks and gets the same
    signal as one long call. Amplitude is ``cfg.waveform.amplitude`` at the pulse peak.
    """
    start, n = int(start_sample), int(n)
    if n < 0 or start < 0:
        raise ValueError(f"start_sample and n must be >= 0, got {start_sample!r}, {n!r}")
    pri = int(cfg.waveform.pri_samples)
    p = cfg_pulse(cfg) * float(cfg.waveform.amplitude)
    out = np.zeros(n)
    if n == 0:
        return out
    k0 = max(0, (start - len(p) + 1) // pri)
    k1 = (start + n - 1) // pri
    for k in range(k0, k1 + 1):
        a = k * pri - start
        lo, hi = max(a, 0), min(a + len(p), n)
        if lo < hi:
            out[lo:hi] += p[lo - a:hi - a]
    return out


def pulse_train(n_samples: int, cfg: Config) -> np.ndarray:
    """The first ``n_samples`` of the transmit signal (pulse 0 at sample 0)."""
    return pulse_train_chunk(0, n_samples, cfg)
