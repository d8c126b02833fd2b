"""What the recording shows of the device and the room: reverberation tail, gain wander,
interference bursts (pure numpy, float64).

These are the figures a user tunes the volume, the gain and the placement by
(docs/audio.md), and the guards the analysis needs:

- a reverberant room keeps ringing after each pulse; at the start of a pulse train the
  late tail of the earlier pulses is still missing, so the first pulses are not like the
  rest (:func:`buildup_pulses` of them are skipped);
- an AGC's slow gain wander scales the static room, which the running mean follows;
- a burst of interference (speech, clatter) swamps the echoes of the pulses it covers:
  they are skipped and counted (:class:`BurstGate`).
"""

from __future__ import annotations

import copy
import math

import numpy as np

from .stats import median

#: Segments of the late window the tail's decay is measured over.
TAIL_SEGMENTS = 8
#: A segment counts as tail when its power is this many times the mean pulse's noise.
TAIL_OVER_NOISE = 10.0
#: Longest RT60 reported, s (a decay too slow to see within one PRI).
MAX_RT60_S = 5.0
#: A pulse whose residual energy is this many times the running typical one is a burst.
BURST_RATIO = 8.0
#: Pulses the running typical residual energy is the median of.
BURST_HISTORY = 64
#: Consecutive pulses over the bar after which they are no burst but a new level (the
#: room or the device changed), learned afresh: about 2 s, where an interference burst
#: lasts a fraction of a second.
BURST_LONGEST = 64
#: A reference whose gain wanders by more than this (peak to peak, dB) was recorded
#: through an AGC: its pulses, and those of every analysis against it, are scaled to the
#: static part's gain before the static part is removed. The smallest AGC the sweeps
#: draw (1.1 dB peak) reads 2.0 dB; with no AGC, 80 random tuning rooms read at most
#: 0.58 dB, but a fan's echo moves the gain too, and 1.0 dB, the bar before, was passed
#: by two held-out rooms with none (1.03 and 1.07 dB): in one (2000008, a loud glint)
#: the scaling then skipped a third of the pulses as bursts (docs/dynamics.md).
NORMALISE_ABOVE_DB = 1.5


def tail_rt60(mean_pulse: np.ndarray, noise_var: float, fs: float, start: int = 0
              ) -> float:
    """RT60 of the room from the static part's decay over the late part of a PRI, s.

    In a steady pulse train the static window holds the current pulse's echoes and the
    tails of all earlier ones; their sum still decays along the window at the room's
    rate, 60 dB per RT60. The window from ``start`` (or a third of it) to its end is cut
    into :data:`TAIL_SEGMENTS`; each segment's median power (robust to the few
    first-order echoes) is compared with the mean pulse's noise, and a line is fitted to
    the segments well above it.

    Parameters
    ----------
    mean_pulse : ndarray, shape (L,)
        Mean of many aligned pulses, delays 0 .. L from the coupling edge.
    noise_var : float
        Noise variance of one sample of ``mean_pulse`` (per-pulse variance / pulses).
    fs : float
        Sample rate, Hz.
    start : int
        First delay considered (past the coupling and its clipping).

    Returns
    -------
    float
        RT60 in seconds; 0.0 when no tail stands above the noise; MAX_RT60_S when the
        tail does not decay measurably within the window.
    """
    m = np.asarray(mean_pulse, dtype=np.float64)
    L = len(m)
    a = max(int(start), L // 3)
    if L - a < 4 * TAIL_SEGMENTS or not fs > 0:
        return 0.0
    seg = np.array_split(m[a:] ** 2, TAIL_SEGMENTS)
    p = np.array([float(median(s)) for s in seg])
    centre = np.array([a + (i + 0.5) * (L - a) / TAIL_SEGMENTS for i in range(TAIL_SEGMENTS)])
    # the median of a squared Gaussian is 0.455 of its mean
    floor = 0.455 * max(float(noise_var), 0.0)
    keep = p > TAIL_OVER_NOISE * floor if floor > 0 else p > 0
    if keep.sum() < TAIL_SEGMENTS // 2:
        return 0.0
    db = 10.0 * np.log10(np.maximum(p[keep] - floor, 1e-300))
    slope = float(np.polyfit(centre[keep], db, 1)[0])     # dB per sample
    if slope >= -60.0 / (MAX_RT60_S * fs):
        return MAX_RT60_S
    return -60.0 / slope / fs


def tail_from_buildup(pulses: np.ndarray, mean_pulse: np.ndarray, pri: int, fs: float
                      ) -> tuple[float, int]:
    """RT60 from the start of a pulse train, and the pulses that are still building up.

    The window of pulse k holds the tails of pulses 0..k only: it falls short of the
    steady window (the mean pulse) by the tails of the pulses before 0 would have put
    there, ``M_k = T_(k+1) + T_(k+2) + ...`` (T_j: the room's tail j PRIs on). These are
    nested, so projected on the first shortfall's direction they give ``|M_k|^2``, which
    shrinks by the same factor q every PRI, while the fan's and the noise's pulse-to-pulse
    changes hardly project on it. A line through log(projection) over the leading pulses
    that stand above the scatter gives q; RT60 = 60 dB / (-10 log10 q) PRIs.

    Parameters
    ----------
    pulses : ndarray, shape (n, L)
        The first pulses of the recording, in order from the first of the train (row 0:
        pulse 0; rows of unusable pulses NaN: the first usable one sets the direction).
        A recording that starts after the train
        shows no build-up.
    mean_pulse : ndarray, shape (L,)
        The steady window (mean of later pulses).
    pri, fs : PRI in samples, sample rate in Hz.

    Returns
    -------
    rt60_s : float
        0.0 when no build-up stands out (a dry room, or the train began earlier).
    building : int
        Leading pulses that fall short of the steady window by more than the scatter.
    """
    x = np.asarray(pulses, dtype=np.float64)
    if len(x) < 32:
        return 0.0, 0
    d = np.asarray(mean_pulse, dtype=np.float64)[None, :] - x
    rows = np.nonzero(np.isfinite(d).all(axis=1))[0]
    if len(rows) < 16:
        return 0.0, 0
    first = int(rows[0])
    u = d[first]
    nu = float(np.sqrt(u @ u))
    if not nu > 0:
        return 0.0, 0
    p = np.full(len(x), np.nan)
    p[rows] = d[rows] @ (u / nu)
    steady = p[len(p) // 2:]
    steady = steady[np.isfinite(steady)]
    if len(steady) < 8:
        return 0.0, 0
    mid = float(median(steady))
    scatter = 1.4826 * float(median(np.abs(steady - mid)))
    short = p - mid
    # the first usable pulse projects on itself (always "short"): the run counts from the
    # next one, and only a run of at least two more shows a build-up
    n = first + 1
    while n < len(p) // 2 and np.isfinite(short[n]) and short[n] > 6.0 * scatter:
        n += 1
    if n - first < 3:
        return 0.0, 0
    k = np.arange(first, n, dtype=np.float64)
    slope = float(np.polyfit(k, np.log10(short[first:n]), 1)[0])   # log10 q per PRI
    if slope >= 0:
        return MAX_RT60_S, n
    return min(-6.0 / slope * pri / fs, MAX_RT60_S), n


def buildup_pulses(rt60_s: float, prf: float) -> int:
    """Pulses at the start of a pulse train whose window still lacks part of the earlier
    pulses' tails: until the missing part is 30 dB down (half an RT60)."""
    if not rt60_s > 0 or not prf > 0:
        return 0
    return int(math.ceil(0.5 * rt60_s * prf))


def gain_wander_db(gains: np.ndarray, prf: float, smooth_s: float = 1.0) -> float:
    """Peak-to-peak wander of a per-pulse gain (e.g. each pulse's projection on the mean
    pulse), smoothed over ``smooth_s`` so noise and the fan do not count, in dB."""
    g = np.asarray(gains, dtype=np.float64)
    g = g[np.isfinite(g) & (g > 0)]
    k = max(int(round(smooth_s * prf)), 1)
    if len(g) < 2 * k:
        return 0.0
    c = np.cumsum(np.concatenate([[0.0], g]))
    s = (c[k:] - c[:-k]) / k
    lo = float(s.min())
    return 20.0 * math.log10(float(s.max()) / lo) if lo > 0 else math.inf


def projection_gains(pulses: np.ndarray, mean_pulse: np.ndarray) -> np.ndarray:
    """Each pulse's least-squares gain against the mean pulse, shape (n,)."""
    m = np.asarray(mean_pulse, dtype=np.float64)
    mm = float(m @ m)
    if not mm > 0:
        return np.full(len(pulses), np.nan)
    return np.asarray(pulses, dtype=np.float64) @ m / mm


def burst_mask(energy: np.ndarray, ratio: float = BURST_RATIO) -> np.ndarray:
    """Pulses of a whole recording whose residual energy stands ``ratio`` times above the
    median (bursts of interference), shape (n,) bool."""
    e = np.asarray(energy, dtype=np.float64)
    if len(e) == 0:
        return np.zeros(0, bool)
    med = float(median(e))
    return e > ratio * med if med > 0 else np.zeros(len(e), bool)


class BurstGate:
    """Streaming burst detection, state in and out: a pulse whose residual energy is
    BURST_RATIO times the median of the last BURST_HISTORY accepted pulses' is a burst.
    Bursts are not added to the history, so a long burst does not raise the bar; but
    BURST_LONGEST of them in a row are a new level, and the history starts afresh from
    it. Without that a step up in the residual's level (at 30 dB SNR a fan coming to rest
    where the static estimate had not seen its blade) made every later pulse a burst:
    the analysis went blind for minutes (spent held-out 800006: a stop and the next
    start missed)."""

    # (class defaults: gates pickled before these existed)
    _run = 0                  # bursts in a row
    relevels = 0              # times a run of `longest` bursts was taken as a new level
    longest = BURST_LONGEST

    def __init__(self, ratio: float = BURST_RATIO, history: int = BURST_HISTORY,
                 longest: int = BURST_LONGEST) -> None:
        self.ratio = float(ratio)
        self.longest = int(longest)
        self._hist = np.zeros(int(history))
        self._n = 0
        self._typical = 0.0
        self.bursts = 0

    def copy(self) -> BurstGate:
        """An independent copy (a block's rewind point; copy.deepcopy cost 2 % of the
        daemon's CPU)."""
        c = copy.copy(self)
        c._hist = self._hist.copy()
        return c

    def __call__(self, energy: float) -> bool:
        """True if this pulse is a burst (counted); else it joins the history. The
        history's median is refreshed every 8 pulses (a per-pulse median cost the
        daemon 10 % of its time; the level drifts far slower)."""
        if self._n >= 8 and self._typical > 0 and energy > self.ratio * self._typical:
            self._run += 1
            if self._run < self.longest:
                self.bursts += 1
                return True
            # no burst lasts this long: the level itself has changed
            self._n, self._typical = 0, 0.0
            self.relevels += 1
        self._run = 0
        self._hist[self._n % len(self._hist)] = energy
        self._n += 1
        if self._n % 8 == 0:
            self._typical = float(median(self._hist[:min(self._n, len(self._hist))]))
        return False
