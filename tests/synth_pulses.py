"""Synthetic pulse trains with exactly known geometry, for the dsp unit tests.

Independent of the code under test: a band-limited impulse is a Hann-windowed sinc
written out here; echoes of a "fan" move in delay and amplitude with the blade phase as
smooth, asymmetric functions (so direction is visible), like multipath echoes do.
"""

from __future__ import annotations

import numpy as np

HALF = 24


def bl_impulse(t: np.ndarray) -> np.ndarray:
    """Band-limited unit impulse at offsets t (samples): Hann-windowed sinc."""
    w = np.where(np.abs(t) < HALF, 0.5 + 0.5 * np.cos(np.pi * t / HALF), 0.0)
    return np.sinc(t) * w


def add_pulse(x: np.ndarray, at: float, amp: float) -> None:
    """Add ``amp * bl_impulse(n - at)`` into x in place."""
    i0 = int(np.floor(at)) - HALF
    n = np.arange(max(i0, 0), min(i0 + 2 * HALF + 2, len(x)))
    x[n] += amp * bl_impulse(n - at)


#: echoes of the moving target: (mean delay, delay swing, phase offset, amplitude, amp
#: swing, harmonic of the swing) -- delays in samples after the direct coupling
ECHOES = [(330.0, 9.0, 0.0, 0.05, 0.5, 1), (420.0, 14.0, 0.3, 0.04, 0.6, 1),
          (610.0, 6.0, 0.55, 0.03, 0.4, 2), (760.0, 11.0, 0.8, 0.035, 0.5, 1),
          (905.0, 8.0, 0.15, 0.025, 0.7, 2)]
STATIC = [(120.0, 0.2), (500.0, -0.1), (850.0, 0.08)]


def fan_pulse(phase: float, length: int, jitter: float = 0.0) -> np.ndarray:
    """One pulse window (delay 0 .. length) of the moving echoes at a blade phase."""
    x = np.zeros(length)
    for d0, dd, off, a, da, h in ECHOES:
        ang = 2 * np.pi * (phase + off)
        d = d0 + dd * (np.sin(ang) + 0.3 * np.sin(2 * ang + 1.0)) + jitter
        amp = a * (1.0 + da * np.cos(h * ang + 0.4))
        add_pulse(x, d, amp)
    return x


def pulse_train(n_pulses: int, pri: int, *, rate: float, phase0: float = 0.0,
                first_edge: float = 100.0, drift_ppm: float = 0.0, noise: float = 0.0,
                seed: int = 0, direct: float = 0.8, static: bool = True,
                phases: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A recording: direct coupling + static echoes + moving echoes, per pulse.

    Returns (x, edges, phases): the samples, the true direct-coupling positions and the
    true blade phase of each pulse. With drift the whole capture time axis is scaled.
    """
    scale = 1.0 + drift_ppm * 1e-6
    n = int((first_edge + (n_pulses + 1) * pri) * scale) + 4 * HALF
    x = np.zeros(n)
    if phases is None:
        phases = np.mod(phase0 + rate * np.arange(n_pulses), 1.0)
    edges = (first_edge + pri * np.arange(n_pulses)) * scale
    for k in range(n_pulses):
        e = edges[k]
        add_pulse(x, e, direct)
        if static:
            for d, a in STATIC:
                add_pulse(x, e + d * scale, a)
        win = fan_pulse(phases[k], pri - 2 * HALF)
        # place the moving echoes exactly: re-render at scaled delays
        for d0, dd, off, a, da, h in ECHOES:
            ang = 2 * np.pi * (phases[k] + off)
            d = d0 + dd * (np.sin(ang) + 0.3 * np.sin(2 * ang + 1.0))
            amp = a * (1.0 + da * np.cos(h * ang + 0.4))
            add_pulse(x, e + d * scale, amp)
        del win
    if noise:
        x += noise * np.random.default_rng(seed).standard_normal(len(x))
    return x, edges, phases
