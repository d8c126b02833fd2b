"""From a track and the motion evidence to an answer: direction, rate, confidence.

Two independent pieces of evidence:

* Motion (:class:`MotionMeter`): does anything in the gate change between pulses beyond
  the noise? With D_m the mean half squared difference of pulses m apart and V the
  temporal variance over a window, a target that does not move gives ``V / min_m D_m``
  close to 1 (every difference is noise), while a moving one gives more: its echo pattern
  varies over the window, but at some lag m <= max_lag it nearly repeats. "Stopped" is
  decided from this, never from a small, noisy rate.
* The track (:mod:`tracking`): phase rate w (reference cycles per pulse) and its standard
  deviation. The sign is trusted by ``p = Phi(|w| / sd)``, the probability that the sign
  is right under the filter's own uncertainty; confidence is ``2 p - 1`` times the
  quality-weighted share of recent matches the filter accepted, read against the share
  this device's settled tracks accept (:class:`AcceptFloor`), and scaled down further
  when matches are on average barely better than chance.

``unknown`` when the evidence is too weak: no lock, low confidence, or a scene that cannot
be seen at all (only noise in the gate: neither stopped nor moving can be told).
"""

from __future__ import annotations

import bisect
import functools
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..answer import (
    Decision as Decision,  # (transitions.py's import, until it takes it from answer)
)
from ..answer import Direction, RateState
from .fingerprint import envelope_features

#: New pulses whose lag energies one matrix product gives (MotionMeter.preview): each
#: product also spans the max_lag pulses before them, so a few dozen at a time does
#: little more than the least work (a whole window at a time did three times it).
PREVIEW_ROWS = 32

def _prefix_sums(parts: list[np.ndarray], points: np.ndarray) -> np.ndarray:
    """Sums of the first p rows of the arrays ``parts`` one after the other, for each p
    of ``points`` (ascending; no copy of them joined): a slice's sum per point (numpy's
    cumsum down the rows of a C-ordered block took three times as long)."""
    width = parts[-1].shape[1]
    out = np.empty((len(points), width))
    acc = np.zeros(width)
    part, base, prev = 0, 0, 0               # the part row ``prev`` is in, its first row
    for i, p in enumerate(points.tolist()):
        while prev < p:
            while prev - base >= len(parts[part]):
                base += len(parts[part])
                part += 1
            take = min(p, base + len(parts[part]))
            acc = acc + parts[part][prev - base:take - base].sum(axis=0)
            prev = take
        out[i] = acc
    return out


@dataclass(frozen=True)
class MeterBlock:
    """A block of pulses previewed by :meth:`MotionMeter.preview`: the pulses, their lag
    energies and squared norms (for :meth:`MotionMeter.commit`), and the statistic after
    each prefix of them (``motion``, ``scene``: n + 1 values, the first for none)."""

    xs: np.ndarray
    rows: np.ndarray
    e: np.ndarray
    motion: np.ndarray
    scene: np.ndarray


class MotionMeter:
    """Streaming motion statistic over the last ``window`` pulses.

    Parameters
    ----------
    length : int
        Samples per (gated) pulse.
    window : int
        Pulses in the sliding window.
    max_lag : int
        Largest lag m tried for D_m: any rate has a lag m <= max_lag at which the blade
        phase is within 1/(max_lag+1) cycle of where it was.

    Notes
    -----
    Per pulse the cost is ``max_lag`` vector differences; sums are kept per pulse in ring
    buffers so that a pulse leaving the window is subtracted exactly.
    """

    def __init__(self, length: int, window: int, max_lag: int = 16) -> None:
        if window < max_lag + 2:
            raise ValueError(f"window must exceed max_lag + 1 pulses, got window={window!r}, "
                             f"max_lag={max_lag!r}")
        self.window, self.max_lag = int(window), int(max_lag)
        self._d = np.zeros((self.window, self.max_lag))   # lag energies per pulse, ring
        self._e = np.zeros(self.window)                   # |x|^2 per pulse, ring
        self._s = np.zeros((self.window, length))         # the pulses themselves, ring
        # (the lags' history, the last max_lag pulses, is the newest end of this ring:
        # window > max_lag + 1)
        self._sum = np.zeros(length)                      # sum of the ring's pulses
        self._n = 0
        # index arrays that depend only on the shapes (made once: each call made them anew)
        self._lags = np.arange(1, self.max_lag + 1)
        self._upper = np.triu(np.ones((self.max_lag, self.max_lag), dtype=bool))
        self._indices: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}

    def _index(self, h: int, n: int) -> tuple[np.ndarray, ...]:
        """(each new pulse's predecessor at each lag, which exist, column of each new
        pulse) for ``h`` history pulses and ``n`` new ones."""
        got = self._indices.get((h, n))
        if got is None:
            pos = h + np.arange(n)                       # index of each new pulse in ext
            src = pos[:, None] - self._lags[None, :]     # its predecessor at each lag
            ok = src >= 0
            got = (np.where(ok, src, 0), ~ok, np.arange(n)[:, None])
            self._indices[(h, n)] = got
        return got

    def update(self, x: np.ndarray) -> None:
        """Add one pulse, shape (length,). Lost pulses are not fed (a lag then spans the
        gap, which only blurs the statistic slightly)."""
        self.update_block(np.asarray(x, dtype=np.float64)[None, :])

    def update_block(self, xs: np.ndarray) -> None:
        """Add consecutive pulses, shape (n, length): one matrix product for all lags, and
        no loop over the pulses (it was a sixth of the daemon's analysis time)."""
        xs = np.asarray(xs, dtype=np.float64)
        n = len(xs)
        if n == 0:
            return
        if n > self.window:                              # the ring holds one window
            for i in range(0, n, self.window):
                self.update_block(xs[i:i + self.window])
            return
        self._store(xs, *self._rows(xs))

    def _rows(self, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lag energies, |x|^2) of new pulses ``xs`` (n <= window) after the ring's."""
        n = len(xs)
        M = self.max_lag
        h = min(self._n, M)                              # history pulses available
        # products of the new pulses with the last h ones and with each other, the
        # history read in place from the ring (one or two contiguous runs: a gathered
        # copy of it was most of the cost with 85 lags of 780 samples)
        start = (self._n - h) % self.window
        runs = [(start, min(start + h, self.window))]
        if start + h > self.window:
            runs.append((0, start + h - self.window))
        e_new = np.einsum("ij,ij->i", xs, xs)
        e_ext = np.concatenate([self._e[a:b] for a, b in runs] + [e_new])
        gram = np.vstack([self._s[a:b] @ xs.T for a, b in runs] + [xs @ xs.T])   # (h + n, n)
        src, missing, cols = self._index(h, n)
        rows = 0.5 * (e_new[:, None] + e_ext[src] - 2.0 * gram[src, cols])
        rows[missing] = 0.0
        return rows, e_new

    def _store(self, xs: np.ndarray, rows: np.ndarray, e_new: np.ndarray) -> None:
        """Write new pulses (n <= window) and their lag energies into the rings."""
        n = len(xs)
        j0 = self._n % self.window
        j: slice | np.ndarray
        if j0 + n <= self.window and self._n >= self.window:
            j = slice(j0, j0 + n)                        # the usual case: no wrap, all full
            self._sum -= self._s[j].sum(axis=0)
        else:
            count = self._n + np.arange(n)               # pulses fed before each new one
            j = count % self.window
            full = count >= self.window                  # slots whose old pulse leaves
            if full.any():
                self._sum -= self._s[j[full]].sum(axis=0)
        self._sum += xs.sum(axis=0)
        self._d[j] = rows
        self._e[j] = e_new
        self._s[j] = xs
        self._n += n
        if self._n % self.window < n:
            # once a window, the running sum is taken afresh: what rounding left in it
            # does not build up over hours
            self._sum = self._s[:self.count].sum(axis=0)

    def preview(self, xs: np.ndarray, at: np.ndarray | None = None) -> MeterBlock:
        """The statistic after prefixes of consecutive new pulses ``xs`` (n, length),
        without adding them: ``motion[i]`` and ``scene[i]`` are :meth:`statistic`'s after
        the first ``at[i]`` of them (``at``: ascending, in 0..n; default every prefix,
        0..n), to rounding. :meth:`commit` then adds them.

        Why: a decision every few pulses asked the meter for its statistic, and the meter
        did a matrix product and its sums for those few pulses each time; a block of
        pulses (analyze's 256 PRIs) is done in a few products, and the window sums at
        its decisions come from running sums."""
        xs = np.asarray(xs, dtype=np.float64)
        n, M, W = len(xs), self.max_lag, self.window
        at = np.arange(n + 1) if at is None else np.asarray(at, dtype=np.int64)
        h0 = self.count
        order = (self._n - h0 + np.arange(h0)) % W      # the ring's pulses, oldest first
        # the lag energies, PREVIEW_ROWS new pulses at a time, each against the M pulses
        # before it (the ring's last h, then the block's own)
        h = min(h0, M)
        hist = self._s[order[h0 - h:]]
        e_new = np.einsum("ij,ij->i", xs, xs)
        e_ext = np.concatenate([self._e[order[h0 - h:]], e_new])
        rows = np.empty((n, M))
        for a in range(0, n, PREVIEW_ROWS):
            b = min(a + PREVIEW_ROWS, n)
            lo = max(h + a - M, 0)
            new = xs[a:b].T
            gram = xs[lo - h:b] @ new if lo >= h else \
                np.vstack([hist[lo:] @ new, xs[:b] @ new])    # (h + b - lo, b - a)
            src, missing, cols = self._index(h + a - lo, b - a)
            r = 0.5 * (e_new[a:b, None] + e_ext[lo + src] - 2.0 * gram[src, cols])
            r[missing] = 0.0
            rows[a:b] = r
        # the window after j new pulses: its count, and where it starts and ends among
        # the ring's pulses (oldest first) followed by the new ones ("ext")
        counts = np.minimum(self._n + at, W)
        ends = h0 + at
        starts = ends - counts
        # D_m over the window: the lag-m energies of its pulses whose predecessor at lag m
        # is in it too, from running sums over ext (a pulse's energies are 0 at lags
        # beyond the first pulse fed)
        d_ext = np.concatenate([self._d[order], rows])
        c = np.zeros((h0 + n + 1, M))
        np.cumsum(d_ext, axis=0, out=c[1:])
        lags = self._lags
        inner = np.minimum(starts[:, None] + lags[None, :], ends[:, None])
        dsum = c[ends] - c[inner, lags - 1]
        e_c = np.concatenate([[0.0], np.cumsum(np.concatenate([self._e[order], e_new]))])
        esum = e_c[ends] - e_c[starts]
        # the window's sum of pulses: the ring's running sum, plus the new ones, minus
        # those that left (the oldest of ext)
        first = (self._n - h0) % W                       # the ring's oldest pulse, in place
        ring = [self._s[first:min(first + h0, W)], self._s[:max(first + h0 - W, 0)]]
        total = self._sum + _prefix_sums([xs], at) - _prefix_sums(ring + [xs], starts)
        with np.errstate(divide="ignore", invalid="ignore"):
            nn = np.maximum(counts, 1).astype(np.float64)
            dm = dsum / np.maximum(nn[:, None] - lags[None, :], 1.0)
            noise = dm.min(axis=1) if len(at) else np.zeros(0)
            mean = total / nn[:, None]
            mm = np.einsum("ij,ij->i", mean, mean)
            var = esum / nn - mm
            ok = noise > 0
            motion = np.where(ok, var / np.where(ok, noise, 1.0),
                              np.where(var <= 0, 1.0, np.inf))
            scene = np.where(ok, mm / np.where(ok, noise, 1.0), np.inf)
        few = counts < M + 2
        motion[few] = scene[few] = np.nan
        return MeterBlock(xs, rows, e_new, motion, scene)

    def commit(self, block: MeterBlock, j: int | None = None) -> None:
        """Add the first ``j`` (default: all) pulses of a :meth:`preview`."""
        j = len(block.xs) if j is None else int(j)
        for a in range(0, j, self.window):
            b = min(a + self.window, j)
            self._store(block.xs[a:b], block.rows[a:b], block.e[a:b])

    @property
    def count(self) -> int:
        """Pulses in the window now."""
        return min(self._n, self.window)

    def statistic(self) -> tuple[float, float]:
        """(motion ratio V / min_m D_m, scene ratio |mean|^2 / noise); NaN if too few.

        The scene ratio is the static echo energy over the noise energy per pulse: near
        0 when the gate holds only noise.
        """
        n = self.count
        if n < self.max_lag + 2:
            return float("nan"), float("nan")
        # D_m: the mean over the pulses that had m predecessors in the window. Each ring
        # row holds a pulse's lag energies from its arrival; of the oldest M pulses
        # (time order), the one at position p < m has lost its lag-m predecessor
        oldest = (self._n - n + self._lags - 1) % self.window
        # rows p, lags m = c + 1 > p (np.triu, with its mask made once)
        lost = np.where(self._upper, self._d[oldest], 0.0).sum(axis=0)
        dm = (self._d[:n].sum(axis=0) - lost) / (n - self._lags)
        noise = float(dm.min())
        mean = self._sum / n          # a running sum: the ring is not re-averaged per call
        var = float(self._e[:n].mean() - mean @ mean)
        if not noise > 0:
            return (1.0 if var <= 0 else float("inf")), float("inf")
        return var / noise, float(mean @ mean) / noise


#: Quantile of the noise-alone statistic a meter's rest threshold sits on, and the trials
#: it is measured with (:func:`noise_threshold`).
NOISE_QUANTILE = 0.98
NOISE_TRIALS = 64
#: Longest gate (samples) the noise-alone statistic is simulated on (noise_threshold).
NOISE_MAX_LENGTH = 2048


def noise_threshold(length: int, window: int, max_lag: int, band: float, smooth: int,
                    quantile: float = NOISE_QUANTILE, trials: int = NOISE_TRIALS) -> float:
    """The motion statistic that white noise alone stays under with probability
    ``quantile``, through the same envelope features (``band``, ``smooth``) on a gate of
    ``length`` samples, for a meter of ``window`` pulses and lags up to ``max_lag``
    (:func:`_noise_readings`)."""
    # numpy's linear quantile, from a sort (np.quantile imports numpy.ma: dsp/stats.py)
    v = _noise_readings(length, window, max_lag, band, smooth, trials)
    pos = quantile * (len(v) - 1)
    lo = int(math.floor(pos))
    hi = min(lo + 1, len(v) - 1)
    return float(v[lo] + (pos - lo) * (v[hi] - v[lo]))


@functools.lru_cache(maxsize=32)
def _noise_readings(length: int, window: int, max_lag: int, band: float, smooth: int,
                    trials: int) -> np.ndarray:
    """What white noise alone reads through a meter (see :func:`noise_threshold`),
    ``trials`` readings, sorted.

    Why: ``min_m D_m`` is the least of ``max_lag`` noisy estimates, so even noise reads
    above 1, and the more so the fewer independent samples a pulse holds: a gate of 100
    samples (a fan 4.7 m away) reads 1.09 at the median and 1.20 at the 99th
    percentile, one of 800 samples 1.013 and 1.04. A fixed threshold of 1.15 therefore
    called a far fan's rest only now and then. Monte Carlo with a fixed seed (the same
    number every time), in batches of 16 trials (0.1-0.4 s here); cached per shape."""
    rng = np.random.default_rng(20261126)
    n, M = int(window), int(max_lag)
    # a longer gate reads closer to 1 still: its threshold is at most this one's (and the
    # floor, 1.15, is far above it), so the work and memory stay bounded for any gate
    length = max(min(int(length), NOISE_MAX_LENGTH), 1)
    out = np.empty(trials)
    lags = np.arange(1, M + 1)
    for a in range(0, trials, 16):
        b = min(a + 16, trials)
        noise = rng.standard_normal(((b - a) * n, int(length)))
        # the envelopes 128 rows at a time (the same values): all at once, their complex
        # analytic signal was the offline command's peak memory, 10 MiB over its budget
        f = np.concatenate([envelope_features(noise[r:r + 128], np.zeros(int(length)),
                                              band=band, smooth=smooth)
                            for r in range(0, len(noise), 128)])
        del noise
        f = f.reshape(b - a, n, -1)
        g = f @ np.swapaxes(f, 1, 2)                     # (t, n, n) Gram matrices
        e = np.diagonal(g, axis1=1, axis2=2)             # (t, n)
        mean = f.mean(axis=1)
        var = e.mean(axis=1) - (mean * mean).sum(axis=1)
        dm = np.empty((b - a, M))
        for j, m in enumerate(lags):
            cross = np.diagonal(g, offset=-m, axis1=1, axis2=2)   # x_i . x_{i-m}
            dm[:, j] = 0.5 * (e[:, m:] + e[:, :-m] - 2.0 * cross).mean(axis=1)
        low = dm.min(axis=1)
        out[a:b] = np.where(low > 0, var / np.where(low > 0, low, 1.0), 1.0)
    v = np.sort(out)
    v.flags.writeable = False           # (cached: shared by every caller)
    return v


class _Recent:
    """The last ``keep`` values, for their median and quantiles: the values in arrival
    order (which leaves first) and kept sorted beside it (an insertion and a removal by
    bisection), so that a reading is an index rather than a partition of up to ``keep``
    values on the analysis's per-decision path (the numpy partition was most of
    :class:`AcceptFloor`'s time). The same values as numpy's median and partition: the
    middle one, or the two middle ones' sum halved; NaN while the values hold one."""

    def __init__(self, keep: int) -> None:
        self._keep = int(keep)
        self._order: deque[float] = deque()
        self._sorted: list[float] = []
        self._nans = 0                   # NaNs among the values (not in _sorted)

    def add(self, x: float) -> None:
        x = float(x)
        if len(self._order) >= self._keep:
            old = self._order.popleft()
            if old != old:
                self._nans -= 1
            else:
                del self._sorted[bisect.bisect_left(self._sorted, old)]
        self._order.append(x)
        if x != x:
            self._nans += 1
        else:
            bisect.insort(self._sorted, x)

    def __len__(self) -> int:
        return len(self._order)

    def median(self) -> float:
        v, n = self._sorted, len(self._order)
        if self._nans or not n:
            return math.nan
        h = n // 2
        return v[h] if n % 2 else (v[h - 1] + v[h]) / 2.0

    def quantile(self, q: float) -> float:
        """The value with a share ``q`` of them under it (the nearest rank; NaNs rank
        last, as numpy's partition puts them)."""
        n = len(self._order)
        j = min(max(int(q * (n - 1) + 0.5), 0), n - 1)
        return self._sorted[j] if j < len(self._sorted) else math.nan


class RestFloor:
    """The short meter's rest threshold, calibrated on what this device reads at rest.

    Why: white noise (:func:`noise_threshold`) is not all a resting fan shows the meter.
    A strong reverberant tail under clock drift adds a slow wander of its own: in a
    random scene (held-out 700005, RT60 0.38 s, 44 ppm) the meter read 1.16 at the
    median at rest against a threshold of 1.15, so most stops were never called; with
    the drift or the tail taken out of the same scene it read 1.01-1.02, as noise does.
    So the readings of the moments the fan is seen at rest by the tracker (no lock, or a
    rate under the floor) and that lie within ``max_shift`` of the base threshold are
    kept, and the threshold rises by their median's excess over noise's median, at most
    ``max_shift`` (a turning fan reads well above: 1.43 at the 1st percentile in that
    scene, 1.67 at the 5th in the tuned room).
    """

    def __init__(self, base: float, noise_median: float, max_shift: float,
                 keep: int, least: int) -> None:
        self.base, self.noise_median = float(base), float(noise_median)
        self.max_shift = float(max_shift)
        self.least = int(least)
        self._seen = _Recent(keep)
        self.threshold = self.base
        #: the median of the readings at rest, once there are ``least`` of them
        self.rest_median: float | None = None

    def note(self, still: float, at_rest: bool) -> float:
        """Add one decision's short-meter reading (``at_rest``: the tracker sees no
        motion); return the threshold to use now."""
        if at_rest and math.isfinite(still) and still < self.base + self.max_shift:
            self._seen.add(float(still))
            if len(self._seen) >= self.least:
                med = self._seen.median()
                self.rest_median = med
                shift = min(max(med - self.noise_median, 0.0), self.max_shift)
                self.threshold = self.base + shift
        return self.threshold


class TurningFloor:
    """The short meter's readings while the fan is seen turning, and how far they let
    the rest threshold come down towards what noise alone reads.

    Why: a far fan's echoes change little from pulse to pulse in the meter's low band.
    In spent held-out 4000008 (3 blades 3.54 m away) a steady turn at 0.37 Hz read
    1.08-1.43, half of it under the rest threshold (the configured floor, 1.15), while
    the fan at rest read 1.01, noise's median; a moment without a track then let a quiet
    reading call a stop, and three false stop-start pairs followed in 8 h. So the
    readings of decisions where a turning state is published (at ``turning_hz`` or
    more, the static estimate not held) are kept, and while their ``quantile`` lies
    under the threshold, the threshold comes down to it; never under what noise alone
    stays under (``noise_high``: :func:`noise_threshold` plus its margin), nor under
    this device's readings at rest by less than noise's own spread above its median.
    """

    def __init__(self, noise_high: float, noise_median: float, quantile: float,
                 keep: int, least: int) -> None:
        self.noise_high, self.noise_median = float(noise_high), float(noise_median)
        self.quantile, self.least = float(quantile), int(least)
        self._seen = _Recent(keep)
        self._low = math.inf

    def note(self, still: float, turning: bool) -> None:
        """Add one decision's short-meter reading (``turning``: a turning state is
        published and the static estimate adapts)."""
        if turning and math.isfinite(still):
            self._seen.add(float(still))
            if len(self._seen) >= self.least:
                self._low = self._seen.quantile(self.quantile)

    def cap(self, threshold: float, rest_median: float | None) -> float:
        """The rest threshold to use, from the one calibrated at rest."""
        if not self._low < threshold:
            return threshold
        least = self.noise_high
        if rest_median is not None:
            least = max(least, rest_median + (self.noise_high - self.noise_median))
        return min(threshold, max(self._low, least))


class AcceptFloor:
    """The share of its matches a settled track accepts on this device, against which a
    window's share is read (:func:`decide`'s ``accepted``).

    Why: at low SNR the matches scatter beyond the track's gate even when the track is
    the fan's, so a settled, right track accepts only part of them (0.6-0.7 at 6.6 dB,
    6 blades, against 0.9 and more in clear rooms), and a dip after a reversal's lock
    left a right, tight track under the confidence that claims a direction for
    seconds. The shares of tracks older than the window, clear of zero by
    ``clear_sd`` standard deviations, are kept, and a window's share is divided by their
    median (never by less than ``least_share``, never scaled up before ``least``
    readings): a spurious lock accepts less than the device's settled tracks do, however
    good or bad the room.
    """

    def __init__(self, least_share: float, keep: int, least: int) -> None:
        self.least_share = float(least_share)
        self.least = int(least)
        self._seen = _Recent(keep)
        self.typical = 1.0

    def note(self, accepted: float, settled: bool) -> float:
        """Add one window's share (``settled``: its track is old and clear of zero);
        return the share read against the device's typical one, in [0, 1]."""
        if settled and math.isfinite(accepted):
            self._seen.add(accepted)
            if len(self._seen) >= self.least:
                med = self._seen.median()
                self.typical = min(max(med, self.least_share), 1.0)
        return min(max(accepted, 0.0) / self.typical, 1.0) if math.isfinite(accepted) \
            else accepted


class NoiseFloor:
    """One pulse's noise energy in the raw gate, for the scene test (``decide``'s
    ``scene``): half the energy of the difference between consecutive pulses, which is
    pure noise while nothing changes between them.

    Why it follows a fall within ``fall`` pulses and a rise only over ``rise``: while a
    fan turns, its echo's change between pulses is in the difference too (10-100 times
    the noise for a fast fan), and an estimate that forgot that over the analysis window
    alone kept a fan that had come to rest reading "nothing but noise" for 7-10 s after
    its stop (held-out scene 1600019: 1.1-1.5 Hz, the static echo in the gate 0.9 of one
    pulse's noise). Noise alone varies little between pulses (chi-square with the gate's
    hundreds of samples), so following its falls fast biases the estimate low only a
    little: 8 % for a gate of 400 samples, 16 % for 100 (tests). A rise of the true noise
    (a louder room) takes the window.
    """

    def __init__(self, fall: float, rise: float) -> None:
        self.fall, self.rise = float(fall), float(rise)
        self.energy = math.nan

    def update(self, diff_energy: float) -> float:
        """Add one lag-1 difference energy (``|x_k - x_{k-1}|^2``); return the estimate."""
        e = 0.5 * diff_energy
        if not math.isfinite(self.energy):
            self.energy = e
        else:
            self.energy += (e - self.energy) / (self.fall if e < self.energy else self.rise)
        return self.energy


def motion_statistic(pulses: np.ndarray, max_lag: int = 16) -> tuple[float, float]:
    """One-shot form of :class:`MotionMeter` over all rows of ``pulses`` (n, L)."""
    m = MotionMeter(pulses.shape[1], len(pulses), max_lag)
    for p in pulses:
        m.update(p)
    return m.statistic()


@dataclass(frozen=True)
class DecideSettings:
    """Thresholds of :func:`decide` (config ``tracking``)."""

    motion_threshold: float = 1.15
    #: the short meter's rest threshold (PulseAnalyzer: motion_threshold, or the noise-alone
    #: statistic of its gate if that is higher: :func:`noise_threshold`); NaN: the same
    still_threshold: float = math.nan
    #: static echo energy (the running mean pulse) over the noise energy of one pulse
    #: below which the gate holds nothing but noise. Noise alone gives about the mean's
    #: noise share, 1 / (effective pulses averaged), 0.005-0.01 with the 3 s static
    #: window; a fan at rest at 10 dB about 0.4 (docs/dynamics.md, "Why each rule is
    #: there")
    scene_threshold: float = 0.1
    min_confidence: float = 0.5
    slew_limit: float = 4.0
    good_quality: float = 0.02
    alias_margin: float = 0.1
    rate_floor_hz: float = 0.05
    changing_hz_s: float = 0.02


#: A short meter under this many times ``motion_threshold`` reads as rest when the matches
#: show the blade standing still in view (``seen_still``). At 30 dB with 40 ppm of clock
#: drift the aligner's residual error kept a fan at rest in view at 1.01-1.14 at the
#: median (up to 1.5 when the rest began), around the threshold of 1.15, and one rest of
#: 6 s was never called stopped; a turning fan read 1.67 or more at the 5th percentile,
#: a slow reversal 1.5 s at 0.02 Hz in view 7.7 (the report's transitions sweep).
SEEN_STILL_FACTOR = 1.3


#: A pattern turning at a rate that comes back within this share of a blade period at
#: one of the short meter's lags (having turned at least once) is seen by the meter: at
#: that lag its pulses differ by noise alone, and the window's spread holds the turning.
RECUR_SHARE = 0.02


def recurs(rate: float, lags: int, share: float = RECUR_SHARE) -> bool:
    """Whether a pattern turning ``rate`` blade periods per pulse comes back within
    ``share`` of a period at some lag 1..``lags`` after turning a whole period or more."""
    if not math.isfinite(rate):
        return False
    for m in range(1, max(int(lags), 0) + 1):
        x = rate * m
        n = round(x)
        if n != 0 and abs(x - n) <= share:
            return True
    return False


def _normal_cdf(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


def decide(*, rate: float, rate_std: float, locked: bool, accepted: float, quality: float,
           motion: float, scene: float, ref_cycles_per_pulse: float, ref_rate_hz: float,
           ref_direction: str = "unknown", alias_gap: float = math.inf,
           alias_note: str = "", direction_note: str = "", awaiting_check: bool = False,
           still: float = math.nan, accel: float = 0.0,
           changing_odds: float = 0.0, at_rest: bool = False, seen_still: bool = False,
           still_lags: int = 0,
           settings: DecideSettings = DecideSettings()) -> Decision:
    """Direction and rate of one window.

    Parameters
    ----------
    rate, rate_std : float
        Tracked phase rate and its standard deviation, reference cycles per pulse.
    locked : bool
        Whether the tracker holds a track.
    accepted : float
        Share of recent matches (weighted by quality squared, as the filter weighs them)
        the tracker accepted, in [0, 1], read against the device's settled tracks'
        (:class:`AcceptFloor`; the analysis does that).
    quality : float
        Mean match contrast of recent pulses, in [0, 1]; below ``good_quality`` it scales
        the confidence down (a scene hardly visible).
    motion, scene : float
        From :class:`MotionMeter` over the window (NaN if not yet known).
    still : float
        The motion ratio of a short window (the last second or two; NaN if not known):
        below ``motion_threshold`` nothing has changed lately, so a fan that has just come
        to rest is called stopped without waiting for the long window to forget it.
    ref_cycles_per_pulse, ref_rate_hz : float
        Reference blade phase per pulse and its rotation rate, Hz (> 0).
    ref_direction : {"cw", "ccw", "unknown"}
        The reference's own direction, for the absolute answer.
    alias_gap, alias_note : float, str
        From the alias check (:mod:`aliasing`) when the rate is near p/q cycles per pulse:
        the relative cost gap between the best phase line and the next, and what it found.
        Below ``alias_margin`` the rate is ambiguous (*unknown*, the note is the reason,
        the confidence scaled below ``min_confidence``); a note on a trusted rate becomes
        a warning (the track was moved off an alias).
    direction_note : str
        Why the track's direction is in doubt, from the mirror check
        (:attr:`aliasing.AliasWatch.mirror_note`; empty: it is not): its mirror image
        fits as well, at the same speed. The answer is *unknown* with this reason, its
        speed known all the same (``Decision.direction_doubt``); it outranks
        ``alias_note``.
    awaiting_check : bool
        The doubt is a new track's in a room where directions have been in doubt, waiting
        for its own check (:attr:`aliasing.AliasWatch.awaiting_check`): a clear track then
        says the fan turns even at rest, so that the rest's held estimate is let go and
        the check can run.
    accel : float
        Tracked change of the rate per second (reference cycles per pulse, per second).
    changing_odds : float
        Probability (0..1) that the rate is changing, i.e. the weight of the changing-rate
        model over the constant-rate one on the recent matches (:class:`tracking.Tracker`):
        above 1/2, with a change of at least ``changing_hz_s``, the rate is 'changing'.
    at_rest : bool
        The fan was seen to come to rest: the static estimate is held (the analysis's
        ``StaticRemover.frozen``) or the rest was confirmed (the state machine's known
        state is stopped): a quiet meter then outweighs any track.
    seen_still : bool
        The matches show the blade standing still in view (the analysis's
        ``_seen_still``): a short meter under ``SEEN_STILL_FACTOR`` times the threshold
        then reads as rest (high SNR with clock drift leaves a resting fan's meter about
        the threshold), and the answer says it was seen still.
    still_lags : int
        The short meter's largest lag: a quiet short meter outweighs a clear track whose
        rate recurs at one of its lags (:func:`recurs`); 0: never.

    Notes
    -----
    No direction is claimed below ``rate_floor_hz``: a fan that slow is stopped (when the
    short window saw no change) or unknown. A stop is never read from a small rate alone.
    """
    s = settings
    warnings: list[str] = []
    # nothing but noise: a weak static echo and no meter that saw change (a meter without
    # a verdict yet saw none either: early in a run the long one has too few pulses)
    still_thr = s.still_threshold if math.isfinite(s.still_threshold) else s.motion_threshold
    if scene < s.scene_threshold and not (motion >= s.motion_threshold) \
            and not (still >= still_thr):
        return Decision(Direction.UNKNOWN, None, None, None, None, 0.0,
                        "nothing but noise in the range gate", tuple(warnings))
    turning = locked and math.isfinite(rate) and ref_cycles_per_pulse > 0
    conf = 0.0
    rel = rel_std = rate_hz = math.nan
    if turning:
        rel = rate / ref_cycles_per_pulse
        rel_std = rate_std / ref_cycles_per_pulse
        p_sign = _normal_cdf(abs(rate) / rate_std) if rate_std > 0 else 1.0
        conf = (2.0 * p_sign - 1.0) * min(max(accepted, 0.0), 1.0)
        if quality < s.good_quality:
            # matches barely better than chance on average: the scene is hardly visible
            conf *= max(quality, 0.0) / s.good_quality
        rate_hz = abs(rel) * ref_rate_hz
    # a confident track above the floor outweighs a motion meter that saw little change
    # (a fan at a rate whose pattern recurs at none of the meter's lags)
    # (only a clear one: twice the floor, four standard deviations from zero)
    # Not for a fan seen at rest (``at_rest``): a track then is the static room's doing
    # (with clock drift the aligner's residual error recurs every 1 / (drift * PRI)
    # pulses, and a held static estimate turns it into a line near 1/20 blade period per
    # pulse: 0.43 Hz 'reversed' from a fan at rest), and a fan that starts again moves
    # its echoes for the meter to see.
    clear = turning and conf >= s.min_confidence and rate_hz >= 2.0 * s.rate_floor_hz \
        and abs(rate) >= 4.0 * rate_std
    m, thr = (still, still_thr) if math.isfinite(still) else (motion, s.motion_threshold)
    quiet = math.isfinite(m) and m < thr
    # ...but not a track at a rate the short meter sees recur (``recurs``): a fan turning
    # there would have read far above its threshold, so the track is an alias of a
    # pattern that does not move (a fan at rest whose pulses all fit a line at 1/9
    # blade period per pulse was published 0.62 Hz 'reversed' for 3.3 s: spent 3500007)
    seen_by_meter = quiet and math.isfinite(still) and recurs(rate, still_lags)
    moving = clear and not at_rest and not seen_by_meter
    if quiet and not moving:
        c = min(max((thr - m) / (thr - 1.0), 0.0), 1.0)
        return Decision(Direction.STOPPED, None, 0.0, 0.0, 0.0, c,
                        f"no change between pulses beyond noise (motion {m:.3f} < "
                        f"{thr:.3g})", tuple(warnings), seen_still=seen_still)
    limit = SEEN_STILL_FACTOR * still_thr
    if seen_still and math.isfinite(still) and still < limit and not moving:
        c = min(max((limit - still) / (limit - 1.0), 0.0), 1.0)
        return Decision(Direction.STOPPED, None, 0.0, 0.0, 0.0, c,
                        f"the blade stands still in view, little change between pulses "
                        f"(motion {still:.3f} < {limit:.3g})", tuple(warnings), seen_still=True)
    if not turning:
        return Decision(Direction.UNKNOWN, None, None, None, None, 0.0,
                        "no consistent match against the reference", tuple(warnings))
    if abs(rel) > s.slew_limit:
        warnings.append(f"|relative rate| {abs(rel):.2f} exceeds the slew limit "
                        f"{s.slew_limit:g}: re-record the reference nearer this speed")
        conf *= 0.5
    if not math.isfinite(motion):
        conf *= 0.5
    # the mirror image fitting as well leaves no direction: a gap of 0
    note = direction_note or alias_note
    gap = 0.0 if direction_note else alias_gap
    if s.alias_margin > 0 and gap < s.alias_margin:
        # several alias rates (or a line and its mirror) fit about equally: the sign or
        # the rate could be either
        conf = min(conf, s.min_confidence) * max(gap, 0.0) / s.alias_margin
        # a start in a room where directions have been in doubt turns all the same: the
        # rest's held estimate is let go and the track's mirror check runs (the meter
        # saw the change, or a quiet one would have answered above)
        return Decision(Direction.UNKNOWN, None, rel, rate_hz, rate_hz * 60.0, conf, note,
                        tuple(warnings), turning=moving or (clear and awaiting_check),
                        direction_doubt=bool(direction_note))
    if note:
        warnings.append(note)
    if conf < s.min_confidence:
        return Decision(Direction.UNKNOWN, None, rel, rate_hz, rate_hz * 60.0, conf,
                        f"weak evidence (confidence {conf:.2f} < {s.min_confidence:g}; "
                        f"relative rate {rel:+.3f} +- {rel_std:.3f})", tuple(warnings))
    if rate_hz < s.rate_floor_hz:
        return Decision(Direction.UNKNOWN, None, rel, rate_hz, rate_hz * 60.0, conf,
                        f"turning slower than the floor ({rate_hz:.3f} Hz < "
                        f"{s.rate_floor_hz:g} Hz): no direction is claimed", tuple(warnings))
    # the rate's change in Hz/s (sign: + when the fan speeds up)
    hz_per = ref_rate_hz / ref_cycles_per_pulse           # Hz per (cycle per pulse)
    change = accel * hz_per * (1.0 if rate >= 0 else -1.0)
    rate_state = RateState.CHANGING if (abs(change) >= s.changing_hz_s and
                                        changing_odds > 0.5) else RateState.SETTLED
    same = rel > 0
    direction = Direction.SAME if same else Direction.REVERSED
    rotation = None
    if ref_direction in ("cw", "ccw"):
        rotation = ref_direction if same else ("ccw" if ref_direction == "cw" else "cw")
    return Decision(direction, rotation, rel, rate_hz, rate_hz * 60.0, conf,
                    f"relative rate {rel:+.4f} +- {rel_std:.4f}", tuple(warnings),
                    rate_state=rate_state, rate_change_hz_s=change, turning=True)
