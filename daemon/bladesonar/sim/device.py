"""The device's own nuisances: speaker response, interference at the microphone, AGC, the
converter (pure).

Each is a closed form of the sample index or of the run's seed, so a chunked render and a
one-shot render give the same samples (as the rest of the simulator).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .nuisances import Nuisances

#: Longest speaker impulse response kept, samples (the rest is below -80 dB).
MAX_SPEAKER_TAPS = 512
#: Full scale of the converter (the largest 16-bit code).
FULL_SCALE = 32767.0 / 32768.0


def _biquad_ir(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Direct-form I biquad over a short signal (a plain loop: the speaker's response is
    computed once per run, and scipy.signal would cost the daemon's sim backend 75 MiB)."""
    y = np.zeros_like(x)
    x1 = x2 = y1 = y2 = 0.0
    for n, xn in enumerate(x):
        yn = (b[0] * xn + b[1] * x1 + b[2] * x2 - a[1] * y1 - a[2] * y2) / a[0]
        x2, x1, y2, y1 = x1, xn, y1, yn
        y[n] = yn
    return y


def speaker_response(nz: Nuisances, fs: float) -> np.ndarray:
    """Impulse response of a small speaker: a 2nd-order Butterworth high-pass at
    ``speaker_highpass_hz`` and a peaking resonance at ``speaker_resonance_hz`` (RBJ
    biquads), truncated where its energy is spent; ``[1.0]`` for an ideal speaker."""
    h = np.zeros(MAX_SPEAKER_TAPS)
    h[0] = 1.0
    if not nz.speaker:
        return h[:1]
    if nz.speaker_highpass_hz > 0:
        w = 2 * math.pi * min(nz.speaker_highpass_hz, 0.45 * fs) / fs
        al = math.sin(w) / (2 * (1 / math.sqrt(2)))
        cw = math.cos(w)
        b = np.array([(1 + cw) / 2, -(1 + cw), (1 + cw) / 2])
        a = np.array([1 + al, -2 * cw, 1 - al])
        h = _biquad_ir(b, a, h)
    if nz.speaker_resonance_hz > 0:
        w = 2 * math.pi * min(nz.speaker_resonance_hz, 0.45 * fs) / fs
        A = 10 ** (nz.speaker_resonance_db / 40)
        al = math.sin(w) / (2 * nz.speaker_q)
        cw = math.cos(w)
        b = np.array([1 + al * A, -2 * cw, 1 - al * A])
        a = np.array([1 + al / A, -2 * cw, 1 - al / A])
        h = _biquad_ir(b, a, h)
    e = np.cumsum(h * h)
    n = int(np.searchsorted(e, e[-1] * (1 - 1e-8))) + 1
    h = h[:max(n, 1)]
    # unit peak, like the pulse shapes: the coupling's height stays amplitude x gain
    unit: np.ndarray = h / np.abs(h).max()
    return unit


def agc_gain(nz: Nuisances, seed: int, n0: int, n: int, fs: float) -> np.ndarray:
    """Microphone gain (linear) at capture samples [n0, n0 + n): ``capture_gain_db`` plus
    an AGC's slow wander of at most ``agc_db`` (two incommensurate sines, seeded phases)."""
    g_db = np.full(n, nz.capture_gain_db)
    if nz.agc_db > 0:
        ph = np.random.default_rng([seed, 4]).uniform(0, 2 * math.pi, 2)
        t = (n0 + np.arange(n, dtype=np.float64)) / fs
        w = 2 * math.pi / nz.agc_period_s
        g_db += nz.agc_db * (0.7 * np.sin(w * t + ph[0]) + 0.3 * np.sin(2.7 * w * t + ph[1]))
    return 10 ** (g_db / 20)


@dataclass(frozen=True)
class Burst:
    capture_index: int
    """First capture sample of the burst."""
    samples: int


def place_bursts(nz: Nuisances, seed: int, n_capture: int, fs: float) -> list[Burst]:
    """Non-overlapping bursts covering ``burst_fraction`` of the capture, seeded."""
    if nz.burst_fraction <= 0:
        return []
    L = max(int(round(nz.burst_s * fs)), 1)
    n = int(round(nz.burst_fraction * n_capture / L))
    room = n_capture - n * L
    if n <= 0 or room <= 0:
        return []
    rng = np.random.default_rng([seed, 3])
    starts = np.sort(rng.integers(0, room, size=n)) + L * np.arange(n)
    return [Burst(int(a), L) for a in starts]


def burst_samples(bursts: list[Burst], i: int, rms: float, seed: int, fs: float
                  ) -> np.ndarray:
    """Burst ``i``: white noise under a Hann envelope, chopped at a syllable rate (speech
    and clatter alike come in short loud pieces), scaled to ``rms`` over its length."""
    b = bursts[i]
    z = np.random.default_rng([seed, 5, i]).standard_normal(b.samples)
    t = np.arange(b.samples) / fs
    env = np.sin(np.pi * (np.arange(b.samples) + 0.5) / b.samples) ** 2
    env *= 0.3 + 0.7 * np.abs(np.sin(2 * math.pi * 4.0 * t))
    z *= env
    p = float(np.mean(z * z))
    return z * (rms / math.sqrt(p)) if p > 0 else z


def convert(x: np.ndarray, bits: int) -> tuple[np.ndarray, int]:
    """The converter: clip at full scale, quantise to ``bits`` (0: none); returns the
    samples and how many were clipped."""
    over = int(np.count_nonzero(np.abs(x) > FULL_SCALE))
    np.clip(x, -FULL_SCALE, FULL_SCALE, out=x)
    if bits:
        q = float(2 ** (int(bits) - 1))
        x = np.round(x * q) / q
    return x, over
