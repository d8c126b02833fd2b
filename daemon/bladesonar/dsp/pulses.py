"""Cutting a contiguous recording into aligned, gated pulses.

The direct coupling (speaker straight into microphone) is the strongest feature of every
pulse and sits at delay 0. Its position is tracked pulse by pulse to sub-sample precision
with a windowed-sinc interpolant, so a capture clock that runs up to a few hundred ppm off
the playback clock (0.26 sample per pulse at 200 ppm) still yields pulses on one grid.
Fractional shifts are applied only to the gated window (never to the whole recording).

A direct coupling louder than full scale is clipped at the converter (normal on a phone or
a board whose speaker sits centimetres from the microphone): its top is a plateau, and the
band-limited peak fit cannot time it (the plateau's centre jumps between the lobes of a
ringing speaker as the sub-sample position drifts). Such an edge is timed by matching the
whole clipped coupling (:data:`TEMPLATE_BEFORE` to :data:`TEMPLATE_AFTER` samples around
it, clipped samples, plateau edges and the unclipped ringing alike) against the first
pulse's: the lag of the best match. The sub-sample part comes from the ringing past the
plateaus, which is the unclipped response itself: the first pulse's ringing, shifted
through the band-limited interpolant that times unclipped edges, against this one's
(:func:`_tail_offset`; 3e-5 to 6e-5 sample rms on a quiet synthetic coupling 4-8 times
full scale). A coupling with too short a ringing is timed from its plateaus' edges, a
coarse measurement whose error is a function of the sub-sample position (0.05-0.19
sample rms on the same couplings). The edges then follow the transmit
schedule: one clock drives playback and capture, so the edges lie on a line, and a slow
alpha-beta loop on the measurements follows that line (:data:`CLIP_ALPHA`): with a shared
clock exactly (the error is then the same on every pulse: a constant range offset of a
fraction of a sample), under clock drift to a few ten-thousandths of a sample from the
ringing (a few hundredths from the plateaus' edges). Clipped samples
of the coupling itself are counted, not held against the pulse; clipping anywhere else in
the gate still is.

A capture drop-out shows up as a direct pulse that is missing or not where the clock says
it should be: the aligner reports the pulse, re-acquires the edge and goes on, rather than
misaligning everything after it.

Streaming: :class:`PulseAligner` is fed chunks of any size and returns the pulses that are
complete, keeping its leftover buffer; :func:`align` is the one-shot form and gives the
same result (tested).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..errors import InputError
from ..waveform import HALF_TAPS, kernel
from .gate import Gate
from .stats import median

#: Half width (taps) of the windowed-sinc fractional-delay kernel: the simulator's
#: (waveform.kernel), which reads a pulse the way it was rendered.
KERNEL_HALF = HALF_TAPS
#: Fine grid step used to find the sub-sample peak of the direct coupling, samples.
_EDGE_GRID = 1.0 / 32.0
#: Least gains of the schedule loop that times a clipped coupling: the edge moves by
#: alpha and the PRI by beta of the measurement's distance from the prediction. The loop
#: starts as a least-squares line through the measurements so far (alpha 2(2n-1)/(n(n+1)),
#: beta 6/(n(n+1)) at the n-th: the PRI is learned within a few pulses) and settles at
#: this critically damped pair (BETA = ALPHA^2 / (2 - ALPHA)), a memory of some hundred
#: pulses. Why so long: the coarse timing from a plateau's edges is off by a function of
#: the sub-sample position (up to 0.15 sample on the simulator's small speaker clipped 1.3
#: times), which clock drift sweeps through with a period of 1 / (drift x PRI) pulses
#: (33 at 20 ppm). A loop that follows it moves the whole gate with it, and the strong
#: static echoes then change from pulse to pulse as a turning fan's would: on a random
#: scene's small speaker at 20 ppm the settled edges were off by 0.11 sample rms with a
#: memory of 6 pulses, and are off by 0.005 with this one.
CLIP_ALPHA = 0.01
CLIP_BETA = CLIP_ALPHA ** 2 / (2.0 - CLIP_ALPHA)
#: A clipped edge this far from its prediction (samples) twice in a row has jumped
#: (samples lost, the latency changed): the loop moves to it at once and then averages
#: the measurements since (alpha 1/m at the m-th), its PRI kept (one clock still).
CLIP_JUMP = 0.5
#: Measurements after which the loop's line has settled enough to tell a jump (alpha 0.1).
CLIP_SETTLED = 40
#: The coarse timing's error as a function of the sub-sample position, learned and taken
#: out (:class:`_FractionBias`). The line starts once the schedule loop has BIAS_START
#: measurements, on the loop's PRI (started on the nominal PRI it ran off by a sample
#: within 40 pulses at 10 ppm); its memory is BIAS_LINE_MEMORY pulses, and its residuals
#: are kept from BIAS_SETTLE measurements on, in BIAS_BINS sub-sample positions, each
#: position's mean over at most BIAS_MEMORY of them, used once that position has
#: BIAS_LEAST (some positions may never be timed coarsely: the ringing times them).
BIAS_START = 200
BIAS_LINE_MEMORY = 1000.0
BIAS_LAMBDA = 1.0 - 1.0 / BIAS_LINE_MEMORY
BIAS_SETTLE = 1000
BIAS_BINS = 32
BIAS_MEMORY = 64
BIAS_LEAST = 8
#: Samples past a clipped coupling's last clipped sample that still belong to it: the
#: fractional-shift kernel spreads the plateau's corners this far.
COUPLING_GUARD = 16
#: Samples before and after the coarse edge that a clipped coupling is matched over.
TEMPLATE_BEFORE = 16
TEMPLATE_AFTER = 112
#: Correlation coefficient below which a clipped coupling does not match the first one (a
#: full-band coupling half a sample off the first one's grid correlates only about 0.6).
TEMPLATE_MIN_CORR = 0.4
#: Fewest samples of a clipped coupling's clean tail (its ringing, KERNEL_HALF + 5 samples
#: or more from any clipped one) that time it (:func:`_tail_shifts`); with fewer, the
#: plateaus' edges do.
TAIL_MIN = 24
#: Least correlation of this coupling's tail with the first one's, shifted, for the tail
#: to time it: a ringing tail gave 0.97 or more at 0 dB (simulated small speaker), 0.99
#: on a synthetic one; one with no ringing (an ideal speaker), noise and near echoes
#: only, -0.06 to 0.5, and is timed from the plateaus' edges.
TAIL_MIN_CORR = 0.9


class _FractionBias:
    """The error of a clipped coupling timed from its plateaus' edges, as a function of
    the sub-sample position, learned on the stream and taken out of each measurement.

    Why: that timing reads a position within a sample as nearly its nearest sample (a
    sawtooth of +-0.3 sample against the sub-sample position on a random scene's ideal
    speaker 3.2 times full scale). Drift sweeps the position once every 1 / (drift x PRI)
    pulses, and where that is slower than the schedule loop's memory (385 pulses at
    2 ppm) the loop follows the error: the gate moved 0.1-0.2 sample rms, and a resting
    fan in a reverberant room read 2.7 on the short meter against 1.15. The error is the
    coupling's own, the same at every pass: the residuals of the measurements from a
    line fitted to them with a long memory (least squares, weights falling by
    1 / BIAS_LINE_MEMORY a pulse: no overshoot), each kept at its sub-sample position,
    give it, less their mean (a constant offset is only a range offset, and the line's
    lag under a changing drift is one). No drift, no sweep: one position is learned, and
    nothing but a constant is taken out."""

    def __init__(self) -> None:
        self.table = np.zeros(BIAS_BINS)
        self.n = np.zeros(BIAS_BINS, dtype=np.int64)
        self._restart()

    def _restart(self) -> None:
        self._ref: tuple[int, float, float] | None = None   # (pulse, edge, PRI)
        self._k = 0
        # weighted sums over the kept measurements by age a: 1, a, a^2, y, a y
        self._w = self._a = self._aa = self._y = self._ay = 0.0
        self._age = 0
        self._far = 0

    def correct(self, k: int, m: float, pred: float, period: float) -> float:
        """Pulse ``k``'s measured edge ``m`` with the learned error taken out (the
        schedule loop's prediction ``pred`` and PRI give the line its reference)."""
        k = int(k)
        if self._ref is None:
            self._ref, self._k = (k, float(pred), float(period)), k
        d = k - self._k
        if d:
            lam = BIAS_LAMBDA ** d
            self._aa = lam * (self._aa + 2.0 * d * self._a + d * d * self._w)
            self._a = lam * (self._a + d * self._w)
            self._w *= lam
            self._ay = lam * (self._ay + d * self._y)
            self._y *= lam
            self._k = k
        k0, e0, p0 = self._ref
        base = e0 + p0 * (k - k0)
        y = m - base
        det = self._w * self._aa - self._a * self._a
        c = 0.0
        if self._w > 2.0 and det > 1e-9 * self._w * self._w:
            line = (self._aa * self._y - self._a * self._ay) / det
            r = y - line
            b = int(((base + line) % 1.0) * BIAS_BINS) % BIAS_BINS
            filled = self.n >= BIAS_LEAST
            left = r - (self.table[b] - self.table[filled].mean() if filled[b] else 0.0)
            # a jump is told once the line spans its memory, by the error the correction
            # leaves: a younger line leans along the error itself (over less than a turn
            # of the position, 353 pulses at 1.8 ppm), its residual passed 0.5 a turn
            # after each start, and it restarted every turn and never learned
            far = self._age > BIAS_SETTLE and abs(left) > CLIP_JUMP
            self._far = self._far + 1 if far else 0
            if self._far >= 2:
                self._restart()          # samples lost: the line starts again here
                return m
            self._age += 1
            if self._age > BIAS_SETTLE:
                self.n[b] = min(int(self.n[b]) + 1, BIAS_MEMORY)
                self.table[b] += (r - self.table[b]) / float(self.n[b])
            filled = self.n >= BIAS_LEAST
            if filled[b]:
                c = float(self.table[b] - self.table[filled].mean())
        self._w += 1.0
        self._y += y - c
        return m - c


# Pulse status codes ------------------------------------------------------------------
OK = 0
DROPOUT = 1     # the next direct pulse was shifted: samples were lost within this pulse
MISSING = 2     # no direct pulse where one was due (zeros, drop-out, overload)
NAN = 3         # NaN or inf inside the gated window
CLIPPED = 4     # samples at full scale inside the gated window
SILENT = 5      # digital silence over the whole gated window
WARMUP = 6      # first pulses of a stream: no predecessor, so the reverberation that the
                # previous pulse leaves in every later window (range ambiguity) is missing
BURST = 7       # swamped by a burst of interference (speech, clatter): skipped, counted apart


#: A PRI of capture holds a pulse's direct coupling when its peak stands this far above
#: the PRI's median level (a noise peak of a PRI is some 5 times the median).
PEAK_OVER_MEDIAN = 8.0


def coupling_peak(a: np.ndarray) -> int | None:
    """Where the direct coupling peaks in one PRI of capture magnitudes ``a`` (not
    empty), or None if no peak stands PEAK_OVER_MEDIAN over their median: a coarse test
    of whether a pulse came back (the latency follower's, the recorder's first pulse);
    the aligner times edges on its own."""
    i = int(np.argmax(a))
    return None if a[i] <= PEAK_OVER_MEDIAN * max(float(median(a)), 1e-9) else i


def fractional_taps(frac: np.ndarray) -> np.ndarray:
    """Interpolation taps for reading ``x[i + frac]`` as ``sum_m x[i + m] taps[m]``.

    Parameters
    ----------
    frac : ndarray, shape (n,)
        Fractional positions in [0, 1).

    Returns
    -------
    ndarray, shape (n, 2 * KERNEL_HALF)
        Taps for ``m = -KERNEL_HALF + 1 .. KERNEL_HALF``.
    """
    m = np.arange(-KERNEL_HALF + 1, KERNEL_HALF + 1, dtype=np.float64)
    return kernel(m[None, :] - np.asarray(frac, dtype=np.float64)[:, None])


#: Band (fraction of the Nyquist frequency) of the interpolant that times the direct
#: coupling. A full-band one reads a full-band coupling's peak 0.023 sample rms off the
#: schedule's line at any SNR, a function of the sub-sample position: its sum over the
#: sample grid aliases at the band edge. Under clock drift that position turns every
#: 1 / (drift * PRI) pulses, and the error, times the strong static echoes, is a change
#: that repeats like a turning fan's, so a fan at rest would look as if it turned.
#: Below 0.7 of Nyquist (simulated, 10-100 ppm): 2e-6 sample rms at 80 dB, 0.0013 at
#: 10 dB, 0.004 at 0 dB (tests/test_dsp_pulses.py).
EDGE_BAND = 0.7
_GRID = np.arange(-1.0, 1.0 + _EDGE_GRID / 2, _EDGE_GRID)
#: offsets of the samples an edge or a tail sample is read from, about its nearest one
_TAPS = np.arange(-KERNEL_HALF, KERNEL_HALF + 1)
_GRID_W = kernel(_GRID[:, None] - _TAPS[None, :], EDGE_BAND)


#: How far before the strongest arrival of the first PRIs the direct coupling is looked for,
#: samples (1 m one-way at 44.1 kHz), and how strong an earlier arrival must be to be it.
#: The coupling is the first arrival, but not always the strongest sample: a full-band one
#: half a sample off the grid peaks at 0.64 of its height, while a wall close behind a
#: sensor whose coupling is weak can return nearly as much on the grid (0.79 of it from
#: 0.46 m in a random scene), and cutting the pulses at that echo puts every one late.
FIRST_ARRIVAL_LOOKBACK = 257
FIRST_ARRIVAL_SHARE = 0.5


def _first_arrival(fold: np.ndarray, p: int) -> int:
    """The earliest local maximum of ``fold`` (folded |x| over the first PRIs) within
    FIRST_ARRIVAL_LOOKBACK samples before its strongest sample ``p`` (circularly) that
    reaches FIRST_ARRIVAL_SHARE of it; ``p`` itself if none does."""
    n = len(fold)
    back = min(FIRST_ARRIVAL_LOOKBACK, n // 4)
    idx = (p - back + np.arange(back + 1)) % n
    v = fold[idx]
    peak = np.zeros(len(v), bool)
    peak[1:-1] = (v[1:-1] >= v[:-2]) & (v[1:-1] >= v[2:])
    peak[-1] = True
    strong = np.nonzero(peak & (v >= FIRST_ARRIVAL_SHARE * fold[p]))[0]
    return int(idx[strong[0]])


def _crossings(x: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Steep zero crossings of a clipped waveform: (sample before each, sub-sample
    position by linear interpolation). Steep: the two samples differ by over the level."""
    a, b = x[:-1], x[1:]
    j = np.nonzero((a * b < 0) & (np.abs(a - b) > level))[0]
    return j, j + a[j] / (a[j] - b[j])


def _crossing_offset(template: np.ndarray, seg: np.ndarray, level: float) -> float | None:
    """Sub-sample offset of ``seg`` against ``template`` (already matched to the sample)
    from the clipped plateaus' edges: the mean shift of the steep zero crossings they
    share (within a sample); None when fewer than two are shared."""
    jt, ct = _crossings(template, level)
    js, cs = _crossings(seg, level)
    if len(jt) < 2 or len(js) < 2:
        return None
    k = np.searchsorted(js, jt)
    shifts = []
    for m, kk in enumerate(k):
        for q in (kk - 1, kk):
            if 0 <= q < len(js) and abs(int(js[q]) - int(jt[m])) <= 1 and \
                    np.sign(template[jt[m]]) == np.sign(seg[js[q]]):
                shifts.append(cs[q] - ct[m])
                break
    if len(shifts) < 2:
        return None
    return float(np.clip(np.mean(shifts), -1.0, 1.0))


_TAIL_W0 = kernel(-_TAPS.astype(np.float64), EDGE_BAND)


def _tail_shifts(template: np.ndarray, level: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The clean tail of a clipped coupling shifted by every step of the edge grid:
    (indices of the tail in the template, matrix (grid steps, tail) of the template read
    ``_GRID[g]`` samples later through the band-limited interpolant, the norm of each
    row), or None when the tail is too short. A coupling's ringing past its clipped
    plateaus is the unclipped response itself, so it times the coupling as a band-limited
    peak is timed (without the bias of the plateaus' edges, a function of the sub-sample
    position: 0.11 sample rms under clock drift)."""
    clipped = np.abs(template) >= level
    # the kernel, the grid's one-sample shift, and a later coupling that clips a sample
    # or two further than this one
    reach = KERNEL_HALF + 4
    near = np.convolve(clipped.astype(np.int64), np.ones(2 * reach + 1, dtype=np.int64),
                       mode="same") > 0
    idx = np.nonzero(~near)[0]
    idx = idx[(idx >= reach) & (idx < len(template) - reach)]
    if len(idx) < TAIL_MIN:
        return None
    m = _TAPS
    # row g: template(j - d_g) = sum_m template[j + m] k(-m - d_g)
    w = kernel(-m[None, :] - _GRID[:, None], EDGE_BAND)        # (grid, taps)
    shifted = w @ template[idx[:, None] + m[None, :]].T          # (grid, tail)
    return idx, shifted, np.sqrt(np.einsum("gj,gj->g", shifted, shifted))


def _tail_offset(shifts: tuple[np.ndarray, np.ndarray, np.ndarray], seg: np.ndarray,
                 level: float) -> float | None:
    """Sub-sample delay of ``seg`` against the template (matched to the sample) from the
    clean tail (:func:`_tail_shifts`): the grid step whose shifted tail correlates best,
    refined by a parabola; None when the tail is clipped here, does not resemble the
    first one's (:data:`TAIL_MIN_CORR`) or fits best at the grid's end."""
    idx, rows, norms = shifts
    near = seg[idx[:, None] + _TAPS[None, :]]                    # (tail, taps)
    clean = np.all(np.isfinite(near) & (np.abs(near) < level), axis=1)
    if int(np.count_nonzero(clean)) < TAIL_MIN:
        return None
    if not clean.all():
        # this coupling clipped a sample or two further than the first one
        near, rows = near[clean], rows[:, clean]
        norms = np.sqrt(np.einsum("gj,gj->g", rows, rows))
    # the segment through the same interpolant unshifted: both band-limited alike (a
    # full-band tail against a band-limited one keeps a third of the bias)
    y = near @ _TAIL_W0
    r = rows @ y / norms
    g = int(np.argmax(r))
    if not 0 < g < len(r) - 1 or not r[g] >= TAIL_MIN_CORR * float(np.sqrt(y @ y)):
        return None
    return _grid_vertex(r, g)[0]


def _grid_vertex(v: np.ndarray, g: int) -> tuple[float, float]:
    """(position, value) of the parabola through ``v`` at grid steps g - 1, g, g + 1: the
    sub-step refinement of a maximum on the edge grid (``_GRID``)."""
    a, b, c = v[g - 1], v[g], v[g + 1]
    den = a - 2.0 * b + c
    d = 0.5 * (a - c) / den if den < 0 else 0.0
    d = min(max(d, -1.0), 1.0)
    return float(_GRID[g] + d * _EDGE_GRID), float(b - 0.25 * (a - c) * d)


def refine_peak(seg: np.ndarray) -> tuple[float, float]:
    """Sub-sample position and height of the band-limited peak near the centre of ``seg``.

    Parameters
    ----------
    seg : ndarray, shape (2 * KERNEL_HALF + 1,)
        Samples centred on the integer peak, already multiplied by the pulse polarity.

    Returns
    -------
    offset : float
        Peak position relative to the centre sample, in (-1, 1) samples.
    height : float
        Interpolated peak value.
    """
    v = _GRID_W @ seg
    return _grid_vertex(v, min(max(int(np.argmax(v)), 1), len(v) - 2))


@dataclass
class AlignedPulses:
    """Aligned, gated pulses and what is known about each.

    Attributes
    ----------
    pulses : ndarray, shape (n, gate.length), float64
        Gated samples; row k starts ``gate.start`` samples after pulse k's direct-coupling
        edge. Rows of pulses that are not OK are zero.
    edges : ndarray, shape (n,), float64
        Sub-sample position of each direct-coupling edge, in samples from the start of the
        stream (as delivered, drop-outs included).
    index : ndarray, shape (n,), int64
        Pulse number counted from the first acquired pulse.
    status : ndarray, shape (n,), int8
        OK, DROPOUT, MISSING, NAN, CLIPPED or SILENT.
    """

    pulses: np.ndarray
    edges: np.ndarray
    index: np.ndarray
    status: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask of usable pulses, shape (n,)."""
        mask: np.ndarray = self.status == OK
        return mask

    def __len__(self) -> int:
        return len(self.index)

    @staticmethod
    def empty(length: int) -> AlignedPulses:
        return AlignedPulses(np.zeros((0, length)), np.zeros(0), np.zeros(0, np.int64),
                             np.zeros(0, np.int8))

    @staticmethod
    def concat(parts: list[AlignedPulses], length: int) -> AlignedPulses:
        parts = [p for p in parts if len(p)]
        if not parts:
            return AlignedPulses.empty(length)
        return AlignedPulses(np.concatenate([p.pulses for p in parts]),
                             np.concatenate([p.edges for p in parts]),
                             np.concatenate([p.index for p in parts]),
                             np.concatenate([p.status for p in parts]))


@dataclass
class _Edge:
    edge: float
    status: int
    index: int


@dataclass
class PulseAligner:
    """Streaming aligner: chunks of samples in, aligned gated pulses out.

    Parameters
    ----------
    pri : int
        Nominal pulse repetition interval, samples.
    gate : Gate
        Delay window to cut, samples after the direct-coupling edge.
    search : int
        Half width (samples) of the window where the next edge is looked for.
    shift_tol : float
        An edge further than this from its prediction (samples) means samples were lost.
    clip_level : float
        Absolute sample value counted as clipped.
    max_drift_ppm : float
        Largest clock mismatch followed; the PRI estimate is held within it.
    warmup : int
        First pulses marked WARMUP (not used): a recording that starts with the pulse
        train lacks the previous pulse's late echoes in its first window.
    max_lead_in : int
        PRIs without a direct pulse tolerated at the start of a stream (capture runs
        before the first played pulse returns); beyond them the stream is refused.

    Notes
    -----
    A pulse is emitted once the next pulse's edge has been measured, because a drop-out
    inside pulse k only becomes visible as a shifted edge k+1. Processing decisions depend
    only on samples, never on chunk boundaries, so chunked and one-shot runs agree.
    """

    pri: int
    gate: Gate
    search: int = 3
    shift_tol: float = 1.0
    clip_level: float = 32767.0 / 32768.0
    max_drift_ppm: float = 500.0
    warmup: int = 1
    _buf: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    _offset: int = 0                 # stream position of _buf[0]
    _next: float | None = None       # predicted stream position of the next edge
    _period: float = 0.0             # tracked PRI, samples
    _polarity: float = 1.0
    _amp: float = 0.0                # direct-coupling height of an OK pulse
    _count: int = 0
    _pending: _Edge | None = None
    _ended: bool = False
    _acq_pris: int = 3
    max_lead_in: int = 64
    _lead_in: int = 0                # PRIs skipped before the first direct pulse
    coupling_clipped: int = 0
    """Pulses whose direct coupling was clipped (timed by the schedule loop)."""
    edges_measured: int = 0
    """Direct-coupling edges measured (clipped or not)."""
    _clip_span: int = 0              # delay of the latest clipped coupling sample seen
    _clip_n: int = 1                 # the schedule loop's measurements so far
    _clip_far: int = 0               # its measurements in a row beyond CLIP_JUMP
    _clip_m: int = 0                 # its measurements since a jump (0: none)
    _template: np.ndarray | None = field(default=None, repr=False)  # first clipped coupling
    _on_line: bool = False           # edges follow the schedule loop (a coupling clipped)
    _tail: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    _coarse: bool = False            # the last clipped edge was timed by its plateaus
    _bias: _FractionBias = field(default_factory=_FractionBias, repr=False)
    coarse_log: list[tuple[int, float]] | None = field(default=None, repr=False)
    """When a list: (pulse, edge) of every clipped coupling timed from its plateaus'
    edges, as measured (:func:`align_recording` learns their error from it)."""

    def __post_init__(self) -> None:
        if self.pri < 64:
            raise ValueError(f"pri must be at least 64 samples, got {self.pri!r}")
        if self.gate.stop > self.pri or self.gate.start < 0:
            raise ValueError(f"gate must lie within one PRI (0..{self.pri}), got "
                             f"{self.gate.start}..{self.gate.stop}")
        self._period = float(self.pri)

    # -- public -----------------------------------------------------------------------
    @property
    def acquired(self) -> bool:
        """Whether the first direct-coupling edge has been found."""
        return self._next is not None

    @property
    def coupling_zone(self) -> int:
        """Delays (samples after the edge) that belong to a clipped coupling: clipping
        there is counted, not held against the pulse. 0 while no coupling was clipped."""
        return self._clip_span + COUPLING_GUARD if self._template is not None else 0

    @property
    def period(self) -> float:
        """Current PRI estimate in capture samples (differs from ``pri`` by clock drift)."""
        return self._period

    def hand_on_at(self, k: int) -> int | None:
        """Stream position the samples must reach before pulse ``k`` (or the next one to
        be handed on, if that is later) is handed on: its successor's edge measured, the
        edges predicted at the current PRI. None before the first edge. The daemon cuts
        its analysis blocks there, on the pulses' grid, not on the capture's."""
        p = self._pending
        if p is None or self._ended:
            return None
        reach = TEMPLATE_AFTER if self._template is not None else KERNEL_HALF + 2
        pred = p.edge + (max(k, p.index) - p.index + 1) * self._period
        return int(math.floor(pred)) + self.pri // 2 + reach

    def push(self, chunk: np.ndarray) -> AlignedPulses:
        """Add samples; return the pulses completed by them (possibly none)."""
        if self._ended:
            raise ValueError("push after flush")
        chunk = np.asarray(chunk, dtype=np.float64).ravel()
        self._buf = np.concatenate([self._buf, chunk]) if len(self._buf) else chunk.copy()
        return self._run(final=False)

    def flush(self) -> AlignedPulses:
        """End of stream: return what is left that still fits in the samples given."""
        out = self._run(final=True)
        self._ended = True
        return out

    # -- internals --------------------------------------------------------------------
    @property
    def _end(self) -> int:
        return self._offset + len(self._buf)

    def _seg(self, a: int, b: int) -> np.ndarray:
        """Stream samples [a, b) with zeros outside what is buffered; NaN read as 0."""
        lo, hi = max(a, self._offset), min(b, self._end)
        if lo == a and hi == b:
            out = self._buf[lo - self._offset:hi - self._offset].copy()
        else:
            out = np.zeros(b - a)
            if hi > lo:
                out[lo - a:hi - a] = self._buf[lo - self._offset:hi - self._offset]
        if not np.isfinite(out).all():       # rare: checking is cheaper than cleaning
            np.nan_to_num(out, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        return out

    def _acquire(self, final: bool) -> bool:
        need = self._acq_pris * self.pri + KERNEL_HALF + 1
        if len(self._buf) < need and not final:
            return False
        n = max(1, min(self._acq_pris, (len(self._buf) - KERNEL_HALF - 1) // self.pri))
        if len(self._buf) < self.pri:
            if final and self._lead_in:
                raise InputError(
                    f"no direct-coupling pulse found in {self._lead_in + 1} PRIs: check that "
                    "the speaker plays the pulse train, the microphone hears it, and "
                    f"waveform.pri_samples ({self.pri}) matches the recording")
            return False
        fold = np.zeros(self.pri)
        for k in range(n):
            fold += np.abs(np.nan_to_num(self._buf[k * self.pri:(k + 1) * self.pri]))
        p = int(np.argmax(fold))
        typical = float(median(fold)) + 1e-300
        p = _first_arrival(fold, p)
        if fold[p] < 8.0 * typical:
            if not final and self._lead_in < self.max_lead_in:
                # capture usually starts before the first played pulse comes back (device
                # latency, a pre-roll of silence): skip one PRI and look again
                self._buf = self._buf[self.pri:]
                self._offset += self.pri
                self._lead_in += 1
                return self._acquire(final)
            raise InputError(
                "no direct-coupling pulse found: the strongest sample of the first PRIs is only "
                f"{fold[p] / typical:.1f}x the typical level (need 8x). Check that the speaker "
                "plays the pulse train, the microphone hears it, and waveform.pri_samples "
                f"({self.pri}) matches the recording")
        # begin with the first folded PRI that holds the pulse (after a lead-in of silence
        # or noise the earlier ones do not)
        heights = np.abs(np.nan_to_num(self._buf[p:n * self.pri:self.pri]))
        p += self.pri * int(np.argmax(heights >= 0.5 * heights.max()))
        if p < KERNEL_HALF + self.search:
            p += self.pri  # too close to the start to interpolate: begin with pulse 2
        x = self._buf
        self._polarity = 1.0 if x[p] >= 0 else -1.0
        at = self._offset + p                 # stream position (_seg counts in those)
        if abs(x[p]) >= self.clip_level:
            # clipped: the first clipped sample of this pulse is the time reference
            near = np.abs(self._seg(at - KERNEL_HALF, at + 1)) >= self.clip_level
            at -= KERNEL_HALF - int(np.argmax(near))
            self._template = self._seg(at - TEMPLATE_BEFORE, at + TEMPLATE_AFTER)
            self._tail = _tail_shifts(self._template, self.clip_level)
            self._note_clip_span(self._template, 0.0)
            self._amp = self.clip_level
            self._on_line = True
            self._next = float(at)
            if self.coarse_log is not None:
                # the template itself: timed against itself, on the others' terms
                self.coarse_log.append((self._count, float(at)))
            return True
        seg = self._polarity * self._seg(at - KERNEL_HALF, at + KERNEL_HALF + 1)
        off, height = refine_peak(seg)
        self._amp = height
        self._next = self._offset + p + off
        return True

    def _line_from_here(self) -> None:
        """A coupling acquired unclipped has clipped: from here on its edges follow the
        schedule's line too, each still timed by the peak fit.

        Why: a coupling whose peak passes full scale only at some sub-sample positions is
        acquired unclipped where it does not, and clock drift then sweeps its peak across
        the sample grid, clipping it every 1 / (drift x PRI) pulses. The peak fit reads a
        clipped top off by a function of that position (+-0.04 sample, 0.028 rms, on a
        random scene's ideal speaker 1.3 times full scale at 40 ppm), the gate moves
        with it, and the strong static echoes read as a turning fan's: a resting fan's
        short meter read 1.5-2.2 against a threshold of 1.15. The loop averages that
        error over its memory of some hundred pulses. (Timing such a coupling against a
        clipped template instead was worse, 0.17 sample rms: most of its pulses do not
        clip, and their plateau edges are not there to time.) The loop starts afresh,
        a line through the measurements from here on (started on the PRI so far, with
        the gains of a settled loop, it lost the line: 0.16 sample rms)."""
        self._on_line = True
        self._clip_n, self._clip_far, self._clip_m = 1, 0, 0

    def _note_clip_span(self, seg: np.ndarray, off: float) -> None:
        """Widen the coupling zone to the last clipped sample of a coupling segment that
        starts TEMPLATE_BEFORE samples before an edge ``off`` samples past its start."""
        at = np.nonzero(np.abs(seg) >= self.clip_level)[0]
        if len(at):
            self._clip_span = max(self._clip_span,
                                  int(math.ceil(at[-1] - TEMPLATE_BEFORE - off)))

    def _match_template(self, pred: float, half: int) -> tuple[float, float, bool] | None:
        """A clipped edge near ``pred``: the lag (within ``half``) where the coupling best
        matches the first one, refined by a parabola; None if nothing there resembles it."""
        T = self._template
        assert T is not None
        c = int(round(pred))
        seg = self._seg(c - half - TEMPLATE_BEFORE, c + half + TEMPLATE_AFTER)
        win = sliding_window_view(seg, len(T))
        r = win @ T
        i = int(np.argmax(r))
        ew, et = float(win[i] @ win[i]), float(T @ T)
        # a coupling like the first one: about as loud and of its shape. Within a factor
        # of 4 in energy: an AGC moves it by a few dB, and a clipped full-band click
        # that does not ring (the simulator's ideal speaker 12 dB over full scale) by up
        # to about 4 with its sub-sample position, which clock drift sweeps through
        if not (et > 0 and 0.25 * et <= ew <= 4.0 * et) or \
                r[i] < TEMPLATE_MIN_CORR * math.sqrt(ew * et):
            return None
        d = None if self._tail is None else _tail_offset(self._tail, win[i], self.clip_level)
        self._coarse = d is None
        if d is None:
            d = _crossing_offset(T, win[i], self.clip_level)
        if d is None:
            d = 0.0
            if 0 < i < len(r) - 1:
                den = r[i - 1] - 2.0 * r[i] + r[i + 1]
                d = min(max(0.5 * (r[i - 1] - r[i + 1]) / den, -0.5), 0.5) if den < 0 \
                    else 0.0
        self._note_clip_span(win[i], 0.0)
        return c - half + i + d, self.clip_level, bool(
            np.abs(win[i]).max() >= self.clip_level)

    def _premeasure(self, first: float) -> dict[int, tuple[float, float, bool]]:
        """The edges near the next pulses' predictions that the buffer holds, measured
        together as :meth:`_measure` measures one (a search of ``search`` samples about
        the prediction's nearest sample, then :func:`refine_peak`): {that sample:
        (position, height, clipped)}. The predictions step by the current PRI from
        ``first``; the loop's own, corrected pulse by pulse, falls on the same sample but
        rarely, and then measures it alone. Measured one pulse at a time, the edges cost
        a sixth of the daemon's CPU."""
        n = int((self._end - KERNEL_HALF - self.search - 2 - first) // self._period)
        if n < 2 or self._template is not None:
            return {}
        c = np.rint(first + self._period * np.arange(n)).astype(np.int64)
        s, kh, buf = self.search, KERNEL_HALF, self._buf
        lo = c - s - kh - self._offset
        c = c[lo >= 0]                   # (the end was checked with n)
        if not len(c):
            return {}
        win = buf[(c - s - self._offset)[:, None] + np.arange(2 * s + 1)]
        win = np.where(np.isfinite(win), win, 0.0) * self._polarity
        p = c - s + np.argmax(win, axis=1)
        seg = buf[(p - kh - self._offset)[:, None] + np.arange(2 * kh + 1)]
        seg = np.where(np.isfinite(seg), seg, 0.0) * self._polarity
        v = seg @ _GRID_W.T
        g = np.clip(np.argmax(v, axis=1), 1, v.shape[1] - 2)
        r = np.arange(len(v))
        a, b, cc = v[r, g - 1], v[r, g], v[r, g + 1]
        den = a - 2.0 * b + cc
        d = np.divide(0.5 * (a - cc), den, out=np.zeros_like(den), where=den < 0)
        d = np.clip(d, -1.0, 1.0)
        pos = p + (_GRID[g] + d * _EDGE_GRID)
        height = b - 0.25 * (a - cc) * d
        clipped: list[bool] = (np.abs(seg).max(axis=1) >= self.clip_level).tolist()
        return dict(zip(c.tolist(), zip(pos.tolist(), height.tolist(), clipped,
                                        strict=True), strict=True))

    def _measure(self, pred: float, half: int,
                 done: dict[int, tuple[float, float, bool]] | None = None
                 ) -> tuple[float, float, bool] | None:
        """Edge near ``pred`` (within ``half`` samples): (position, height, clipped) or
        None; ``done``: edges measured ahead (:meth:`_premeasure`), taken when there."""
        if self._template is not None:
            return self._match_template(pred, half)
        if done:
            got = done.get(int(round(pred)))
            if got is not None:
                pos, height, clipped = got
                if not 0.7 * self._amp <= height <= 1.4 * self._amp:
                    return None
                return pos, height, clipped
        c = int(round(pred))
        w = self._polarity * self._seg(c - half, c + half + 1)
        p = c - half + int(np.argmax(w))
        seg = self._polarity * self._seg(p - KERNEL_HALF, p + KERNEL_HALF + 1)
        off, height = refine_peak(seg)
        if not 0.7 * self._amp <= height <= 1.4 * self._amp:
            return None
        return p + off, height, bool((np.abs(seg) >= self.clip_level).any())

    def _reacquire(self, pred: float) -> tuple[float, float, bool] | None:
        """After a lost edge: the strongest plausible direct pulse within half a PRI."""
        half = self.pri // 2
        if self._template is not None:
            return self._match_template(pred, half)
        c = int(round(pred))
        w = self._polarity * self._seg(c - half, c + half + 1)
        for p in np.argsort(w)[::-1][:4]:
            got = self._measure(c - half + int(p), 0)
            if got is not None:
                return got
        return None

    def _run(self, final: bool) -> AlignedPulses:  # noqa: C901  the per-pulse loop, kept whole
        if self._next is None and not self._acquire(final):
            return AlignedPulses.empty(self.gate.length)
        done: list[_Edge] = []
        half = self.pri // 2
        ahead = self._premeasure(self._next) \
            if self._pending is not None and self._next is not None else {}
        while True:
            pred = self._next
            assert pred is not None   # set by _acquire, only ever advanced since
            if self._pending is None:
                # the first pulse: its edge was measured during acquisition
                self._pending = _Edge(pred, OK, self._count)
                self._count += 1
                self._next = pred + self._period
                continue
            # samples a measurement reads past the prediction: the kernel, or a clipped
            # coupling's whole template
            reach = TEMPLATE_AFTER if self._template is not None else KERNEL_HALF + 2
            need = int(math.floor(pred)) + half + reach
            if need > self._end:
                if not final or int(math.floor(pred)) + self.search + reach > self._end:
                    break
            got = self._measure(pred, self.search, ahead)
            # a clipped edge's coarse measurement is off by up to half a sample: more slack
            tol = self.shift_tol + (0.5 if self._template is not None else 0.0)
            if got is not None and abs(got[0] - pred) <= tol:
                lim = self.pri * self.max_drift_ppm * 1e-6
                m = got[0]
                if self._template is not None and self._coarse:
                    if self.coarse_log is not None:
                        self.coarse_log.append((self._count, m))
                    if self._clip_n >= BIAS_START:
                        m = self._bias.correct(self._count, m, pred, self._period)
                err = m - pred
                if self._template is None and got[2] and not self._on_line:
                    self._line_from_here()
                if self._template is None:
                    self._amp += 0.05 * (got[1] - self._amp)
                if self._on_line:
                    # clipped: the edge follows the schedule's line (alpha-beta loop)
                    self.coupling_clipped += int(got[2])
                    # (a jump is told from the line's own scatter once it has settled)
                    far = abs(err) > CLIP_JUMP and self._clip_n >= CLIP_SETTLED
                    self._clip_far = self._clip_far + 1 if far else 0
                    self._clip_n += 1
                    n = self._clip_n
                    alpha = max(2.0 * (2 * n - 1) / (n * (n + 1)), CLIP_ALPHA)
                    beta = max(6.0 / (n * (n + 1)), CLIP_BETA)
                    if self._clip_far >= 2:
                        self._clip_m, self._clip_far, beta = 0, 0, 0.0
                    if self._clip_m or beta == 0.0:
                        self._clip_m += 1
                        alpha = max(alpha, 1.0 / self._clip_m)
                        if alpha <= CLIP_ALPHA:
                            self._clip_m = 0
                    e = pred + alpha * err
                    step = beta * err
                else:
                    # alpha-beta tracking of the PRI (clock drift); bounded
                    e = got[0]
                    step = 0.1 * err
                self._period = min(max(self._period + step, self.pri - lim), self.pri + lim)
                status = OK
            else:
                got = self._reacquire(pred) if need <= self._end else None
                if got is not None and abs(got[0] - pred) > self.shift_tol:
                    if self._pending.status == OK:
                        self._pending.status = DROPOUT
                    e, status = got[0], OK
                elif got is not None:
                    e, status = got[0], OK
                else:
                    e, status = pred, MISSING
                    if self._pending.status == OK:
                        # whatever silenced this direct pulse may have begun in the last
                        self._pending.status = DROPOUT
                if got is not None and self._template is not None:
                    self.coupling_clipped += int(got[2])
            if got is not None:
                self.edges_measured += 1
            done.append(self._pending)
            self._pending = _Edge(e, status, self._count)
            self._count += 1
            self._next = e + self._period
        if final and self._pending is not None:
            # the last pulse: emitted if its gate fits in the samples given
            if int(math.floor(self._pending.edge)) + self.gate.stop + KERNEL_HALF <= self._end:
                done.append(self._pending)
            self._pending = None
        out = self._cut(done)
        self._trim()
        return out

    def recut(self, x: np.ndarray, edges: np.ndarray, index: np.ndarray,
              status: np.ndarray) -> AlignedPulses:
        """The pulses of the whole stream ``x`` (as pushed) cut again at ``edges``;
        pulses not OK keep their status, OK ones are checked again."""
        buf, off = self._buf, self._offset
        self._buf, self._offset = x, 0
        try:
            return self._cut_arrays(np.asarray(edges, dtype=np.float64),
                                    np.array(status, dtype=np.int8),
                                    np.asarray(index, dtype=np.int64))
        finally:
            self._buf, self._offset = buf, off

    def _cut(self, edges: list[_Edge]) -> AlignedPulses:
        if not edges:
            return AlignedPulses.empty(self.gate.length)
        return self._cut_arrays(np.array([d.edge for d in edges]),
                                np.array([d.status for d in edges], dtype=np.int8),
                                np.array([d.index for d in edges], dtype=np.int64))

    def _cut_arrays(self, e: np.ndarray, status: np.ndarray, index: np.ndarray
                    ) -> AlignedPulses:
        g = self.gate
        n, L = len(e), g.length
        base = np.floor(e).astype(np.int64)
        frac = e - base
        width = L + 2 * KERNEL_HALF - 1
        starts = base + (g.start - KERNEL_HALF + 1 - self._offset)
        if n and int(starts.min()) >= 0 and int(starts.max()) + width <= len(self._buf):
            # every window within the buffer (the usual case): one gather of them all
            raw = sliding_window_view(self._buf, width)[starts]
        else:
            raw = np.empty((n, width))
            for k in range(n):
                a = int(starts[k])
                if a >= 0 and a + width <= len(self._buf):
                    raw[k] = self._buf[a:a + width]
                else:
                    raw[k] = self._seg(a + self._offset, a + self._offset + width)
        core = raw[:, KERNEL_HALF - 1:KERNEL_HALF - 1 + L]
        finite = np.isfinite(raw).all(axis=1)
        status[(status == OK) & ~finite] = NAN
        # (NaNs read as 0 below; a block with none, the usual case, is read as it is:
        # the same flags without three masked copies of it)
        clean = bool(finite.all())
        # a clipped coupling is handled (timed by the schedule): only clipping past it
        # counts; nor, with none clipped at the start, within the guard of the edge: a
        # coupling acquired unclipped can clip later (drift moves its peak across the
        # sample grid, and at some sub-sample positions the peak passes full scale), and
        # no echo comes from so near
        past = core[:, max(max(self.coupling_zone, COUPLING_GUARD) - g.start, 0):]
        if not clean:
            past = np.where(np.isfinite(past), past, 0.0)
        clipped = (np.abs(past) >= self.clip_level).any(axis=1)
        status[(status == OK) & clipped] = CLIPPED
        silent = ~(np.abs(core if clean else np.where(np.isfinite(core), core, 0.0))
                   > 0.0).any(axis=1)
        status[(status == OK) & silent] = SILENT
        status[(status == OK) & (index < self.warmup)] = WARMUP
        taps = fractional_taps(frac)
        if not clean:
            raw = np.where(np.isfinite(raw), raw, 0.0)
        # out[k, i] = sum_m taps[k, m] raw[k, i + m]: one contraction over strided windows
        out = np.einsum("kim,km->ki", sliding_window_view(raw, 2 * KERNEL_HALF, axis=1)[:, :L],
                        taps)
        out[status != OK] = 0.0
        return AlignedPulses(out, e, index, status)

    def _trim(self) -> None:
        keep_from = self._end
        if self._next is not None:
            keep_from = int(math.floor(self._next)) - self.pri // 2 - KERNEL_HALF - 2
        if self._pending is not None:
            keep_from = min(keep_from, int(math.floor(self._pending.edge)) + min(
                self.gate.start, 0) - 2 * KERNEL_HALF - 2)
        drop = keep_from - self._offset
        if drop > 0:
            self._buf = self._buf[drop:]
            self._offset += drop


def end_of_stream(status: np.ndarray) -> int:
    """How many pulses at the end of a *finished* stream belong to its end, not to a drop-out.

    When the pulse train stops before the capture does, the aligner finds no direct pulse
    where the next one is due: the trailing pulses are MISSING, and the pulse before them
    is marked DROPOUT only because its successor is missing (when that successor's own
    window is cut by the end of the recording it is not emitted at all, and the DROPOUT
    pulse is the last one). None of them is usable, but none is a capture drop-out
    either: they are neither counted nor warned about.

    Parameters
    ----------
    status : ndarray, shape (n,)
        Status of every pulse of the stream, in order.
    """
    s = np.asarray(status)
    n = 0
    while n < len(s) and s[len(s) - 1 - n] == MISSING:
        n += 1
    if n < len(s) and s[len(s) - 1 - n] == DROPOUT:
        n += 1
    return n


def count_dropped(status: np.ndarray, *, ended: bool = False) -> int:
    """Pulses dropped or corrupt (not OK, not warm-up, not a burst: those are counted
    apart); with ``ended`` the end of a finished stream (:func:`end_of_stream`) is not
    counted."""
    s = np.asarray(status)
    if ended:
        s = s[:len(s) - end_of_stream(s)]
    return int(np.count_nonzero((s != OK) & (s != WARMUP) & (s != BURST)))


def count_clipped(status: np.ndarray) -> int:
    """Pulses left out because the echo window clipped (told apart from drop-outs so a
    refusal can name the volume rather than the audio path)."""
    return int(np.count_nonzero(np.asarray(status) == CLIPPED))


def align(x: np.ndarray, pri: int, gate: Gate, **kwargs: Any) -> AlignedPulses:
    """One-shot alignment of a whole recording (same result as feeding it in chunks).

    Parameters
    ----------
    x : ndarray, shape (n_samples,)
        Mono recording, float.
    pri : int
        Pulse repetition interval, samples.
    gate : Gate
        Delay window to cut.
    **kwargs
        Passed to :class:`PulseAligner`.
    """
    a = PulseAligner(pri, gate, **kwargs)
    return AlignedPulses.concat([a.push(x), a.flush()], gate.length)


#: The whole-recording fit of the plateau timing's error (:func:`fit_fraction_bias`): a
#: step between consecutive coarse edges this far (samples) past the PRI's starts a new
#: line (samples were lost; the aligner itself takes 1.5 for a clipped edge); the fit is
#: made only where the sub-sample position turns FIT_TURNS times or more over the edges
#: (with less, the error is nearly one constant: a range offset), over FIT_ROUNDS rounds
#: of line and table; a table that does not stand FIT_SIGNIFICANCE times over its own
#: noise is not taken.
FIT_JUMP = 1.5
FIT_TURNS = 2.0
FIT_ROUNDS = 6
FIT_SIGNIFICANCE = 3.0
#: Share of the measured edges that must be plateau-timed for the recording to be cut
#: again at the fitted line (edges timed by the ringing are right as they are, and a
#: mixed stream's two timings need not share one constant).
FIT_COARSE_SHARE = 0.9


@dataclass(frozen=True)
class FractionFit:
    """The plateau timing's error and the edges' line, fitted over a whole recording
    (:func:`fit_fraction_bias`)."""

    table: np.ndarray
    """The error at each of BIAS_BINS sub-sample positions (NaN where no edge fell)."""
    slope: float
    """Samples per pulse: the PRI in capture samples (one clock, one slope)."""
    first: np.ndarray
    """Each stretch's first and last plateau-timed pulse (between lost samples), and its
    edge at pulse 0 of the stream: the line is ``start + slope * k``."""
    last: np.ndarray
    start: np.ndarray

    def edges(self, index: np.ndarray, measured: np.ndarray) -> np.ndarray:
        """The edges of pulses ``index`` (as ``measured`` by the stream) on the line: the
        stretch's they fall in, or before or after, whichever passes within FIT_JUMP of
        the measured edge (a pulse timed otherwise at a stretch's end: the one after
        samples were lost, timed when the edge was found again); elsewhere as measured."""
        index = np.asarray(index)
        measured = np.asarray(measured, dtype=np.float64)
        top = len(self.last) - 1
        out = measured.copy()
        after = np.minimum(np.searchsorted(self.last, index), top)
        for s in (np.maximum(after - 1, 0), after):   # the later one wins
            line = self.start[s] + self.slope * index
            near = np.abs(line - measured) <= FIT_JUMP
            out = np.where(near, line, out)
        return out


def fit_fraction_bias(k: np.ndarray, m: np.ndarray) -> FractionFit | None:
    """The error of plateau-timed edges ``m`` (pulses ``k``, in order) as a function of
    the sub-sample position, and the line the edges lie on, fitted over a whole
    recording; None when the record cannot tell the error.

    Why: the streaming learner (:class:`_FractionBias`) needs a thousand pulses to trust
    its line, longer than the 20 s a reference is learned from; until then the edges
    follow the error. Under clock drift the sub-sample position turns, the gate moves
    with the error, and the strong static echoes change as a turning fan's would: a
    held-out room's reference (a coupling 7.4 times full scale, -13.6 ppm) was learned
    at that turn, 0.0176 blade period per pulse, for a fan at 0.039. The whole record
    holds the line and the error at once: a line per stretch between lost samples (one
    clock: one slope) and the error's mean at each position, fitted in turn."""
    k = np.asarray(k, dtype=np.float64)
    m = np.asarray(m, dtype=np.float64)
    if len(k) < 4 * BIAS_BINS:
        return None
    pri = float(median(np.diff(m) / np.maximum(np.diff(k), 1.0)))
    seg = np.concatenate([[0], np.cumsum(np.abs(np.diff(m) - pri * np.diff(k)) > FIT_JUMP)])
    n_seg = int(seg[-1]) + 1
    cnt = np.bincount(seg, minlength=n_seg).astype(np.float64)
    table = np.zeros(BIAS_BINS)
    b = np.zeros(len(k), dtype=np.int64)
    filled = np.zeros(BIAS_BINS, dtype=bool)
    slope, my, mk, r = pri, np.zeros(n_seg), np.zeros(n_seg), np.zeros(len(k))
    for _ in range(FIT_ROUNDS):
        y = m - table[b]
        mk = np.bincount(seg, k, n_seg) / cnt
        my = np.bincount(seg, y, n_seg) / cnt
        kc = k - mk[seg]
        den = float(kc @ kc)
        if not den > 0.0:
            return None
        slope = float(kc @ (y - my[seg])) / den
        line = my[seg] + slope * kc
        b = (np.floor((line % 1.0) * BIAS_BINS).astype(np.int64)) % BIAS_BINS
        r = m - line
        n = np.bincount(b, minlength=BIAS_BINS)
        filled = n >= BIAS_LEAST
        table = np.where(filled, np.bincount(b, r, BIAS_BINS) / np.maximum(n, 1), 0.0)
        table[filled] -= table[filled].mean()
    cyc = slope % 1.0
    turns = min(cyc, 1.0 - cyc) * float(k[-1] - k[0])
    n = np.bincount(b, minlength=BIAS_BINS)
    noise = float(np.sqrt(np.mean((r - table[b]) ** 2) / max(float(n[filled].mean()), 1.0)))
    size = float(np.sqrt(np.mean(table[filled] ** 2)))
    if turns < FIT_TURNS or not size > FIT_SIGNIFICANCE * noise:
        return None
    ends = np.nonzero(np.diff(seg))[0]
    first = k[np.concatenate([[0], ends + 1])].astype(np.int64)
    last = k[np.concatenate([ends, [len(k) - 1]])].astype(np.int64)
    return FractionFit(np.where(filled, table, np.nan), slope, first, last, my - slope * mk)


def align_recording(x: np.ndarray, pri: int, gate: Gate, **kwargs: Any
                    ) -> tuple[AlignedPulses, PulseAligner]:
    """A whole recording aligned (:func:`align`), and the aligner that did it. Where the
    coupling was clipped and nearly every edge timed from its plateaus, the pulses are
    cut again at the line fitted through those edges with their error taken out
    (:func:`fit_fraction_bias`): one clock, so over a recording of some seconds the
    line is the schedule itself."""
    log: list[tuple[int, float]] = []
    a = PulseAligner(pri, gate, coarse_log=log, **kwargs)
    out = AlignedPulses.concat([a.push(x), a.flush()], gate.length)
    if len(log) < FIT_COARSE_SHARE * max(a.edges_measured, 1):
        return out, a
    k, m = np.array(log).T
    fit = fit_fraction_bias(k, m)
    if fit is None:
        return out, a
    edges = fit.edges(out.index, out.edges)
    return a.recut(np.asarray(x, dtype=np.float64), edges, out.index, out.status), a


def min_recording_s(pri: int, sample_rate: float, min_pulses: int) -> float:
    """Shortest recording that yields ``min_pulses`` usable pulses, seconds, rounded up to
    0.1 s: the first pulse is warm-up and the last one's window may be cut by the end.

    Used in refusals, so that a user reads how long to record rather than a pulse count.
    """
    if not sample_rate > 0:
        return float("nan")
    return math.ceil((int(min_pulses) + 2) * int(pri) / float(sample_rate) * 10.0 - 1e-9) / 10.0


def too_few_pulses(usable: int, total: int, n_samples: int, *, pri: int, sample_rate: float,
                   min_pulses: int, dropped: int = 0, clipped: int = 0) -> InputError:
    """The refusal for a recording with fewer than ``min_pulses`` usable pulses: names
    the counts, its length and how long to record (or the drop-outs, when there were);
    where most of the pulses left out clip inside the range window (``clipped`` of the
    ``dropped``: a strong echo close to the device), the volume is the fix, and the
    words are those of the reference's clipping warning."""
    secs = min_recording_s(pri, sample_rate, min_pulses)
    dur = n_samples / sample_rate if sample_rate > 0 else float("nan")
    fix = f"record at least {secs:.1f} s"
    if clipped and 2 * clipped > dropped:
        fix = (f"{clipped} pulses have samples at full scale inside the range window (an "
               "echo close to the device clips): lower the playback volume or the capture "
               "gain")
    elif dropped:
        fix += f" or fix the drop-outs ({dropped} pulses dropped)"
    return InputError(f"only {usable} usable pulses (of {total}) in {dur:.2f} s; at least "
                      f"{min_pulses} are needed: {fix}")


#: Half width (samples) of the stretch of a PRI where clipped samples count as the direct
#: coupling's (they recur at one place every PRI; the window allows for clock drift).
COUPLING_CLIP_HALF = 128


class RecordingCheck:
    """:func:`check_recording` over a recording read in blocks (memory independent of its
    length): feed each block to :meth:`update` (NaN/inf raise at once, with the sample
    number), then :meth:`finish` gives the verdict on the whole.

    Clipped samples that recur at one place of every PRI are the direct coupling's (a
    speaker centimetres from the microphone): they are counted apart
    (:attr:`coupling_clipped`) and do not make the recording overloaded; the aligner
    times such edges without their peak. Clipping anywhere else does.
    """

    def __init__(self, *, pri: int, min_pulses: int, clip_level: float = 32767.0 / 32768.0,
                 max_clip_fraction: float = 0.01, sample_rate: float | None = None) -> None:
        self.pri, self.min_pulses = int(pri), int(min_pulses)
        self.clip_level, self.max_clip_fraction = float(clip_level), float(max_clip_fraction)
        self.sample_rate = sample_rate
        self.n = 0
        self.peak = 0.0
        self.clipped = 0
        self.bad = 0
        self.first_bad: int | None = None
        self._clip_at = np.zeros(self.pri, dtype=np.int64)   # clipped samples by PRI position

    def update(self, x: np.ndarray) -> None:
        """One block; raises on NaN/inf samples."""
        x = np.asarray(x)
        finite = np.isfinite(x)
        if not finite.all():
            bad = ~finite
            self.bad += int(bad.sum())
            i = self.n + int(np.argmax(bad))
            raise InputError(f"the recording holds NaN/inf samples (first at sample {i}); the "
                             "file is corrupt: record it again or cut that part")
        if len(x):
            ax = np.abs(x)
            self.peak = max(self.peak, float(ax.max()))
            at = np.nonzero(ax >= self.clip_level)[0]
            if len(at):
                self.clipped += len(at)
                self._clip_at += np.bincount((self.n + at) % self.pri, minlength=self.pri)
        self.n += len(x)

    @property
    def silent(self) -> bool:
        return self.peak < 1e-6

    @property
    def coupling_clipped(self) -> int:
        """Clipped samples in the stretch of the PRI where most of them recur (the direct
        coupling's), when they recur there in at least half the PRIs and hold at least
        half of all clipped samples; else 0."""
        if not self.clipped:
            return 0
        w = 2 * COUPLING_CLIP_HALF + 1
        h = self._clip_at
        c = np.concatenate([h, h[:w - 1]]).cumsum()
        win = c[w - 1:] - np.concatenate([[0], c[:-w]])
        best = int(win.max())
        recurs = 2 * best >= self.n // self.pri
        return best if recurs and 2 * best >= self.clipped else 0

    @property
    def overload_clipped(self) -> int:
        """Clipped samples that are not the direct coupling's."""
        return self.clipped - self.coupling_clipped

    def explain(self) -> None:
        """When the analysis of a stream fails part-way: raise the recording's own fault
        if what was fed so far shows one (silent, overloaded), else return."""
        if self.silent or (self.n and self.overload_clipped / self.n > self.max_clip_fraction):
            self.finish()

    def finish(self) -> list[str]:
        """The verdict on everything fed: raises for a silent, too short or overloaded
        recording; warnings for a doubtful one."""
        warnings: list[str] = []
        if self.silent:
            raise InputError("the recording is silent (peak level below -120 dBFS): check "
                             "that the microphone is not muted and the right capture device "
                             "is used")
        n_pulses = self.n // self.pri
        if n_pulses < self.min_pulses:
            sr = self.sample_rate
            if sr is not None and sr > 0:
                secs = min_recording_s(self.pri, sr, self.min_pulses)
                raise InputError(f"the recording holds {n_pulses} pulses "
                                 f"({self.n / sr:.2f} s at {self.pri} samples per pulse) but "
                                 f"at least {self.min_pulses} usable pulses are needed: "
                                 f"record at least {secs:.1f} s")
            raise InputError(f"the recording holds {n_pulses} pulses ({self.n} samples at "
                             f"{self.pri} samples per pulse) but at least {self.min_pulses} "
                             "are needed; record longer")
        over = self.overload_clipped
        if over:
            frac = over / self.n
            msg = (f"{over} samples ({100 * frac:.2f}%) are clipped at full scale; "
                   "lower the playback volume or the capture gain")
            if frac > self.max_clip_fraction:
                raise InputError("the recording is overloaded: " + msg)
            warnings.append(msg)
        return warnings


def check_recording(x: np.ndarray, *, pri: int, min_pulses: int, clip_level: float =
                    32767.0 / 32768.0, max_clip_fraction: float = 0.01,
                    sample_rate: float | None = None) -> list[str]:
    """Refuse recordings that cannot be analysed; return warnings for doubtful ones.

    Parameters
    ----------
    x : ndarray, shape (n_samples,)
        Mono recording in [-1, 1].
    pri : int
        Pulse repetition interval, samples.
    min_pulses : int
        Fewest whole pulses the caller needs.
    max_clip_fraction : float
        Above this fraction of clipped samples the recording is refused.
    sample_rate : float, optional
        Samples per second; when given, a too-short recording is refused with its length
        and the shortest length that would do, in seconds.

    Raises
    ------
    InputError
        NaN/inf samples, silence, heavy clipping, or fewer pulses than needed; the message
        names the problem and the fix.
    """
    chk = RecordingCheck(pri=pri, min_pulses=min_pulses, clip_level=clip_level,
                         max_clip_fraction=max_clip_fraction, sample_rate=sample_rate)
    chk.update(x)
    return chk.finish()
