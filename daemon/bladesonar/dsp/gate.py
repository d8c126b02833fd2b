"""The one-way range gate: metres <-> sample delays after the direct-coupling edge.

Convention (DESIGN.md): ``range = c * delay / 2`` with ``delay`` counted from the
direct-coupling leading edge. Samples outside the gate are never processed, so the gate is
also what keeps per-pulse work small.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import overload

import numpy as np

from .stats import median

#: Samples kept free at the end of a PRI: the next pulse's direct coupling and the
#: fractional-delay interpolation kernel must not leak into the gate.
END_GUARD_SAMPLES = 24


@dataclass(frozen=True)
class Gate:
    """A range gate as delay samples ``[start, stop)`` after the direct-coupling edge.

    Attributes
    ----------
    start, stop : int
        Half-open delay window in samples (0 = the direct-coupling edge).
    fs : float
        Sample rate, Hz.
    c : float
        Speed of sound, m/s.
    """

    start: int
    stop: int
    fs: float
    c: float

    @property
    def length(self) -> int:
        """Gated samples per pulse."""
        return self.stop - self.start

    @property
    def start_m(self) -> float:
        """One-way range of the first gated sample, m."""
        return delay_to_range(self.start, self.c, self.fs)

    @property
    def stop_m(self) -> float:
        """One-way range just past the last gated sample, m."""
        return delay_to_range(self.stop, self.c, self.fs)

    def ranges_m(self) -> np.ndarray:
        """One-way range of every gated sample, shape (length,), m."""
        return delay_to_range(np.arange(self.start, self.stop, dtype=np.float64), self.c,
                              self.fs)


@overload
def range_to_delay(range_m: float, c: float, fs: float) -> float: ...
@overload
def range_to_delay(range_m: np.ndarray, c: float, fs: float) -> np.ndarray: ...
def range_to_delay(range_m: float | np.ndarray, c: float, fs: float) -> float | np.ndarray:
    """Two-way delay in samples of a one-way range: ``2 r / c * fs``."""
    return 2.0 * np.asarray(range_m, dtype=np.float64) / c * fs if isinstance(
        range_m, np.ndarray) else 2.0 * float(range_m) / c * fs


@overload
def delay_to_range(delay: float, c: float, fs: float) -> float: ...
@overload
def delay_to_range(delay: np.ndarray, c: float, fs: float) -> np.ndarray: ...
def delay_to_range(delay: float | np.ndarray, c: float, fs: float) -> float | np.ndarray:
    """One-way range in metres of a delay in samples: ``c * delay / fs / 2``."""
    return c * np.asarray(delay, dtype=np.float64) / fs / 2.0 if isinstance(
        delay, np.ndarray) else c * float(delay) / fs / 2.0


def max_gate_stop(pri: int) -> int:
    """Largest usable delay (exclusive): one PRI less the guard for the next pulse."""
    return int(pri) - END_GUARD_SAMPLES


def make_gate(start_m: float, stop_m: float | None, *, c: float, fs: float, pri: int) -> Gate:
    """Gate from one-way ranges; ``stop_m=None`` means the last unambiguous range.

    Parameters
    ----------
    start_m, stop_m : float
        One-way ranges in metres; the gate holds every sample whose range is in
        ``[start_m, stop_m]`` (rounded outward to whole samples).
    c, fs, pri : float, float, int
        Speed of sound (m/s), sample rate (Hz), pulse repetition interval (samples).

    Raises
    ------
    ValueError
        If the window is empty or lies beyond the unambiguous range.
    """
    if not (c > 0 and fs > 0 and pri > END_GUARD_SAMPLES):
        raise ValueError(f"c, fs must be positive and pri larger than the guard "
                         f"({END_GUARD_SAMPLES}), got c={c!r}, fs={fs!r}, pri={pri!r}")
    start = max(0, int(math.floor(range_to_delay(max(start_m, 0.0), c, fs) + 1e-9)))
    hi = max_gate_stop(pri)
    stop = hi if stop_m is None else min(hi, int(math.ceil(range_to_delay(stop_m, c, fs)
                                                           - 1e-9)) + 1)
    if stop - start < 8:
        raise ValueError(f"range gate {start_m:g}..{stop_m if stop_m is not None else 'max'} m "
                         f"holds {max(stop - start, 0)} samples; it must lie between 0 and "
                         f"{delay_to_range(hi, c, fs):.2f} m (one PRI) and hold at least 8")
    return Gate(start, stop, float(fs), float(c))


def find_target_range(rd_power: np.ndarray, fs: float, c: float, *, dc_bins: int = 2,
                      skip_m: float = 0.3, smooth: int = 9, fraction: float = 0.3) -> float:
    """Range of the target: the first range where moving (non-zero doppler) energy rises.

    The paper keeps everything from the target's range on: what comes earlier is the
    waveform's range and doppler sidelobes. The target (direct fan echo) is the earliest
    strong moving echo; multipath can be stronger, so the first crossing of ``fraction``
    of the peak is taken rather than the peak itself.

    Parameters
    ----------
    rd_power : ndarray, shape (n_doppler, n_delay)
        Range-doppler power, zero doppler at index ``n_doppler // 2`` (fftshifted),
        delays counted from the direct-coupling edge.
    fs, c : float
        Sample rate (Hz) and speed of sound (m/s).
    dc_bins : int
        Doppler bins either side of zero excluded (static echoes, drift residue).
    skip_m : float
        First metres ignored (the direct coupling itself).

    Returns
    -------
    float
        One-way range in metres.
    """
    n_dop, n_del = rd_power.shape
    mid = n_dop // 2
    keep = np.ones(n_dop, dtype=bool)
    keep[max(mid - dc_bins, 0):mid + dc_bins + 1] = False
    moving = rd_power[keep].sum(axis=0)
    k = max(int(smooth), 1)
    moving = np.convolve(moving, np.ones(k) / k, mode="same")
    first = int(math.ceil(range_to_delay(skip_m, c, fs)))
    if first >= n_del:
        raise ValueError(f"skip_m={skip_m!r} is beyond the delays given ({n_del} delays)")
    seg = moving[first:]
    floor = float(median(seg))
    peak = float(seg.max())
    if not peak > floor:
        return delay_to_range(first, c, fs)
    above = np.nonzero(seg - floor >= fraction * (peak - floor))[0]
    return delay_to_range(first + int(above[0]), c, fs)
