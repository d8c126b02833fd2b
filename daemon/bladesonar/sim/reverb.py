"""Late reverberation as a statistical tail, part of it moving with the fan (pure).

The image-source paths of sim/geometry.py stop at one wall bounce. A real room keeps
ringing: each pulse's echoes, the fan's included, decay over ``rt60_s`` and so carry over
into many later PRIs (17-30 at RT60 0.5-0.9 s and the default PRF). The tail here is a
dense set of arrivals with random signs, their amplitude under an exponential decay of
60 dB per ``rt60_s``, rising over the first few milliseconds (density of higher-order
reflections), starting after the first-order echoes. Two parts:

- static: the same for every pulse (the room);
- fan: ``reverb_fan_share`` of the energy, its arrivals' gains a smooth function of the
  blade phase (three harmonics of it), so the late echoes of the fan move with the fan.

Rendering: the tail's waveforms are band-limited (same kernel and pulse shape as the
paths) and precomputed (lazily, float64) at 35 fractional start positions (-1/32, 0, ..,
33/32); a pulse's tail is interpolated between the four about its edge's fraction (cubic
Lagrange: 2e-5 of the tail below half the band under clock drift, as little as a static
path changes there, and a smooth function of the fraction). A pulse k adds
``static + sum_h cos(2 pi h phi_k) A_h + sin(...) B_h``.
"""

from __future__ import annotations

import math

import numpy as np

from .. import waveform

#: Fractional positions the tail is precomputed at.
FRACTIONS = 32
#: Harmonics of the blade phase in the fan's part of the tail.
HARMONICS = 3
#: Arrivals per second of tail (static part; the fan part has a quarter of them).
DENSITY_PER_S = 4000.0
#: The tail is rendered down to -70 dB.
DEPTH_DB = 70.0
#: Rise time of the tail's envelope, s.
RISE_S = 0.004


class Tail:
    """The late tail of one pulse as waveforms over delay, see the module docstring.

    Parameters
    ----------
    rt60_s : decay time, s.
    start : first delay of the tail, samples after the coupling edge.
    level : rms amplitude of the tail at its start (full envelope), per unit transmit.
    fan_share : share of the energy in the fan's part.
    shape : the transmit pulse shape (speaker response included).
    fs : sample rate, Hz.
    seed : the room's seed (the same room rings the same way in every run).
    time_scale : the arrivals' delays are paths through the room: a room where sound is
        faster by a factor f has them at 1 / f (``343 / c``; 1 at 343 m/s).
    """

    def __init__(self, rt60_s: float, start: float, level: float, fan_share: float,
                 shape: np.ndarray, fs: float, seed: int, time_scale: float = 1.0) -> None:
        self.start = int(math.floor(start))
        self.fs = float(fs)
        T = rt60_s * DEPTH_DB / 60.0
        self.length = int(math.ceil(T * fs)) + 2 * waveform.HALF_TAPS + len(shape)
        rng = np.random.default_rng([seed, 6])
        n_s = max(int(DENSITY_PER_S * T), 8)
        n_f = max(n_s // 4, 8)

        def arrivals(n: int) -> tuple[np.ndarray, np.ndarray]:
            t = np.sort(rng.uniform(0.0, T, n))
            env = 10 ** (-3.0 * t / rt60_s) * np.minimum(1.0, t / RISE_S)
            # mean square per sample = level^2 * env^2
            g = rng.standard_normal(n) * env * math.sqrt(T * fs / n)
            return waveform.HALF_TAPS + t * fs * time_scale, g

        ts, gs = arrivals(n_s)
        tf, gf = arrivals(n_f)
        s_static = level * math.sqrt(max(1.0 - fan_share, 0.0))
        s_fan = level * math.sqrt(max(fan_share, 0.0))
        # each fan arrival's gain: sum_h c_h cos(2 pi h phi + psi_h), mean square 1
        c = rng.standard_normal((n_f, HARMONICS))
        c /= np.sqrt((c * c).sum(axis=1, keepdims=True) / 2.0)
        psi = rng.uniform(0, 2 * math.pi, (n_f, HARMONICS))
        self._parts = [(ts, s_static * gs)]
        for h in range(HARMONICS):
            self._parts.append((tf, s_fan * gf * c[:, h] * np.cos(psi[:, h])))
            self._parts.append((tf, -s_fan * gf * c[:, h] * np.sin(psi[:, h])))
        self._shape = shape
        # every sub-sample position's waveforms in one array, filled as they are first
        # needed (float32: the tail is tens of dB under the echoes, and half the memory
        # traffic of the four positions read per pulse)
        self._wave = np.zeros((FRACTIONS + 3, 1 + 2 * HARMONICS, self.length), np.float32)
        self._filled = np.zeros(FRACTIONS + 3, bool)

    def waveforms(self, frac_bin: int) -> np.ndarray:
        """(1 + 2 HARMONICS, length) waveforms starting at ``start - HALF_TAPS +
        frac_bin / FRACTIONS`` samples after the edge (``frac_bin`` -1..FRACTIONS + 1)."""
        i = frac_bin + 1
        if not self._filled[i]:
            f = frac_bin / FRACTIONS
            self._wave[i] = np.stack([waveform.render(*waveform.shaped_taps(t + f, g,
                                                                            self._shape),
                                                      0, self.length)
                                      for t, g in self._parts])
            self._filled[i] = True
        wave: np.ndarray = self._wave[i]
        return wave

    def add(self, out: np.ndarray, n0: int, edges: np.ndarray, phases: np.ndarray) -> None:
        """Add the tails of pulses with coupling edges ``edges`` (capture samples) and blade
        phases ``phases`` into ``out`` (capture samples [n0, n0 + len(out)))."""
        n = len(out)
        for e, ph in zip(edges, phases, strict=True):
            pos = float(e) + self.start - waveform.HALF_TAPS
            base = math.floor(pos)
            # between the four nearest precomputed positions (cubic Lagrange): the nearest
            # alone jumped by 1/32 sample every few pulses under clock drift, and two
            # (linearly) left 1e-3 of the tail below half the band, a change of a room
            # at rest that a strong tail made look like a turning fan
            u = (pos - base) * FRACTIONS
            fb = min(int(math.floor(u)), FRACTIONS - 1)
            u -= fb
            a, b = base - n0, base - n0 + self.length
            lo, hi = max(a, 0), min(b, n)
            if lo >= hi:
                continue
            coef = [1.0]
            for h in range(1, HARMONICS + 1):
                coef += [math.cos(2 * math.pi * h * ph), math.sin(2 * math.pi * h * ph)]
            lag = (-u * (u - 1.0) * (u - 2.0) / 6.0, (u + 1.0) * (u - 1.0) * (u - 2.0) / 2.0,
                   -(u + 1.0) * u * (u - 2.0) / 2.0, (u + 1.0) * u * (u - 1.0) / 6.0)
            c = np.asarray(coef, dtype=np.float32)
            acc = (lag[0] * c) @ self.waveforms(fb - 1)[:, lo - a:hi - a]
            for j in range(1, 4):
                acc += (lag[j] * c) @ self.waveforms(fb - 1 + j)[:, lo - a:hi - a]
            out[lo:hi] += acc
