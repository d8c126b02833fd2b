"""Airflow (down-draft or up-draft) from the echoes alone, with no reference (pure).

Why it can be told: a pitched blade is brightest when its face turns towards the sensor.
For a down-draft the leading edge is high, so the face turns towards the sensor while the
blade approaches and the glint's echo moves to shorter range from pulse to pulse; for an
up-draft it comes while the blade recedes (docs/airflow.md). The sign of the
energy-weighted range motion of the moving echoes is therefore the airflow, whatever the
room and wherever the sensor stands.

The stage, on drift-aligned gated pulses (dsp/pulses.py):

1. the static room removed by a **two-sided** running mean (forward and backward
   exponential averages of the pulses, interference bursts left out: a pulse whose
   median square stands out, never one with a bright glint in a few samples): the causal running
   mean of the fingerprint leaves a fading copy of *earlier* echoes behind a moving one,
   a ghost on one side only that biased the sign; then each pulse's least-squares fit by
   the local static mean and its derivative along range is removed (a sub-sample timing
   error of the coupling edge or an AGC step moves or scales every static echo at once:
   under clock drift that residue of the strong static echoes moved by itself and
   outweighed the fan 10 to 20 times);
2. the envelope of what is left (top of the band dropped, where the fractional shift is
   least exact), each range weighted down where the static room is strong against the
   moving echoes, and its own two-sided mean removed;
3. the cross-correlation of each pulse's envelope with the next one's, summed over blocks:
   its peak is the shift of the strongest moving echoes (sub-sample, by a parabola);
   longer lags, while lag times that shift stays under ``SPAN`` samples, are searched
   near lag times it and fitted by a line through zero (slow fans move a fraction of a
   sample per pulse but several samples over ten pulses); a call needs two lags;
4. the shift's standard error from random halves of the blocks, t = shift / error;
   ``|t| >= CALL_T`` calls the airflow, lags that disagree in sign give unknown;
5. where the plain peak makes no call (it stays at zero shift under an echo that keeps
   its range and only changes strength: a reverberant tail, the blades' diffuse echoes
   far off the axis), steps 3-4 again on the correlations' mirror excess c(s) - c(-s),
   which such echoes leave empty; its call also needs its largest values at lags 1 and
   2 on the side of the call. Two readings that call opposite ways give unknown;
6. a call whose correlation peak at some lag lies at the end of the shifts looked at is
   unknown (no shift is located there: the reverberant tail's fan-moving arrivals).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import device as dev
from .analytic import analytic_magnitude
from .fingerprint import envelope_features
from .rangedoppler import band_limited
from .stats import median

#: Lags (pulses) of the correlation: at least MIN_LAGS for a call, at most MAX_LAG. A
#: slow fan's glint lasts many pulses and moves a fraction of a sample per pulse, so its
#: longer lags carry the shift; a fast fan's is gone after a pulse or two, and 24 fixed
#: lags met the next blade's glint there (a 5-blade fan at 1.4 Hz repeats every 5
#: pulses), which turned the sign on 1 of 80 tuning scenes.
MIN_LAGS = 2
MAX_LAG = 16
#: The longest lag's expected shift, samples: lags 1 .. SPAN / (lag-1 shift), and 2 at
#: least while twice the lag-1 shift stays under FIT_SHIFT. A call needs the motion seen
#: at two lags: on the tuning set's fans at rest the only calls (2 of 100, t 3.8 and 4.4)
#: were single-lag peaks of noise 36-37 samples out, faster than any glint (21 samples
#: per pulse at most); a lag-2 peak is searched near twice the lag-1 shift, within the
#: window.
SPAN = 8.0
FIT_SHIFT = 46.0
#: Largest shift between two pulses' envelopes looked at, samples: a blade tip 0.9 m out
#: at 1.6 Hz pitched 18 degrees moves its glint 21 samples (two-way) per pulse at 34 Hz,
#: 42 at lag 2.
MAX_SHIFT = 48
#: Pulses per block of the noise estimate (about 0.5 s).
BLOCK = 16
#: Pulses whose spectra and envelopes are held at once (memory: 800 pulses at once took
#: 100 MiB). Every step is row by row or adds rows in their order, so the figures are
#: the same bits whatever the blocks (tests/test_airflow.py).
ROWS = 8 * BLOCK
#: Fewest blocks (of valid pulse pairs) that are called at all: about 4 s at 34 Hz.
MIN_BLOCKS = 8
#: Random halves of the blocks the standard error comes from (fixed seed: the same
#: recording gives the same answer).
HALVES = 32
#: |t| at and above which the airflow is called. The peak's position is not a smooth
#: statistic and its t from random halves is not a calibrated one where nothing moves:
#: on the tuning set's fans at rest, noise and drift alone (no other nuisance) gave a
#: pair of peaks 20 and 40 samples out at lags 1 and 2 with t 3.5. The one right call
#: of the tuning set under 4 (t 3.9) is made by the mirror excess instead (t 27).
CALL_T = 4.0
#: The mirror excess's call needs its largest values at lags 1 and 2 on its side; where
#: they are not, this is the reason. At rest in reverberant rooms with small speakers
#: (tuning seeds 3, 97, 121 of 200 at rest) the excess called with t 12 to 59 otherwise.
SIDES = "the mirror excess's peaks at lags 1 and 2 lie on opposite sides"
#: A plain call whose lag-1 peak lies within this many samples of zero shift, in a
#: recording whose mirror excess has ``SIDES``, is unknown: on tuning seed 340 (2.6 m off
#: the axis, 0.69 Hz) such a call was wrong with t 31; on seeds 1-400 the rule silenced
#: one right call besides (seed 34). (Seed 340's wrong call came from glints taken for
#: bursts; with the median-square burst mask it calls right, t -309.)
NEAR_ZERO = 2.0
#: A call whose correlation peak at some lag lies at the end of the shifts looked at is
#: unknown: the correlation still rises past it, so there is no located peak. On tuning
#: seeds with a long RT60 forced (``tools/bench_airflow --reverb``), read over parts of
#: the range gate, this removed 2 of 23 wrong readings (the tail's fan-moving arrivals)
#: and none of 331 right whole-gate ones.
EDGE = f"a correlation peak at the end of the shifts looked at ({MAX_SHIFT} samples)"
#: Time constants of the two-sided means: the static room and the envelope's slow part, s.
STATIC_S = 3.0
ENVELOPE_S = 1.0
#: Fraction of the band kept before the envelope.
BAND = 0.7
#: A range's weight is 1 / (1 + (static / (STATIC_WEIGHT * moving))^2): the static room's
#: envelope there against the moving echoes' typical (median) level.
STATIC_WEIGHT = 30.0


@dataclass(frozen=True)
class Airflow:
    """The answer and its figures."""

    airflow: str
    """'down', 'up' or 'unknown'."""
    confidence: float
    """erf(|t| / (CALL_T * sqrt(2))): 0.68 at the calling threshold, 0.997 at 3 times it."""
    t: float
    """The shift over its standard error; + means receding echoes (up)."""
    shift: float
    """The strongest moving echoes' range shift, samples (two-way delay) per pulse;
    + = receding (up)."""
    pulses: int
    """Valid pulses used."""
    reason: str
    lags: int = 0
    """Lags of the correlation used (1 .. lags)."""

    def as_dict(self) -> dict[str, object]:
        return dict(airflow=self.airflow, airflow_confidence=round(self.confidence, 4),
                    airflow_t=round(self.t, 2), airflow_shift=round(self.shift, 4),
                    airflow_lags=self.lags, airflow_reason=self.reason)


def _row_blocks(n: int) -> list[tuple[int, int]]:
    """Row ranges of ``ROWS`` pulses covering ``n`` rows."""
    return [(a, min(n, a + ROWS)) for a in range(0, n, ROWS)]


def two_sided_mean(x: np.ndarray, keep: np.ndarray, alpha: float) -> np.ndarray:
    """The mean of forward and backward exponential averages (weight ``alpha`` per row)
    of the rows of ``x`` where ``keep``; rows not kept do not enter the averages. Each
    row's value leans on past and future alike, so a moving echo leaves no one-sided
    trace. Shape of ``x``."""
    x = np.asarray(x, dtype=np.float64)
    if not 0.0 < alpha <= 1.0:
        raise ValueError(f"alpha must be in (0, 1], got {alpha!r}")
    out = np.zeros_like(x)
    idx = np.nonzero(keep)[0]
    if len(idx) == 0:
        return out
    for order in (idx, idx[::-1]):
        m = x[order[: max(1, min(len(order), int(round(1.0 / alpha))))]].mean(axis=0)
        for i in order:
            m += alpha * (x[i] - m)
            out[i] += 0.5 * m
    # rows not kept take the nearest kept row's value
    near = idx[np.clip(np.searchsorted(idx, np.arange(len(x))), 0, len(idx) - 1)]
    out[~keep] = out[near[~keep]]
    return out


def moving_part(pulses: np.ndarray, valid: np.ndarray, prf: float, *,
                overwrite: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 1: the pulses less the static room (two-sided), less each pulse's fit by the
    static mean and its derivative. Returns (residuals, usable, the static room's mean
    pulse) with bursts not usable. Row by row work runs in blocks of ``ROWS`` pulses and
    the residuals overwrite the band-limited copy (with ``overwrite``, ``pulses`` itself
    when it is a float64 array: its caller's copy is then spent)."""
    pulses = np.asarray(pulses, dtype=np.float64)
    n, L = pulses.shape
    x = pulses if overwrite and pulses.flags.writeable else np.empty((n, L))
    for a, b in _row_blocks(n):
        x[a:b] = band_limited(pulses[a:b], BAND)
    ok = np.asarray(valid, bool).copy()
    alpha = min(1.0, 1.0 / (STATIC_S * prf))
    static = two_sided_mean(x, ok, alpha)
    # each pulse's level as the median of its squares (as reference_build and the
    # analyzer take it): interference covers the window, a glint a few samples; the mean
    # square took a flat fan's brightest glints for bursts and left some passes' approach
    # or recede glints out, and the rest called an airflow it has not (t up to 38)
    energy = np.zeros(n)
    for a, b in _row_blocks(n):
        r = x[a:b] - static[a:b]
        energy[a:b] = np.where(ok[a:b], median(r * r, axis=1), 0.0)
    burst = np.zeros(n, bool)
    burst[ok] = dev.burst_mask(energy[ok])
    if burst.any():            # again without the bursts in the static estimate
        ok &= ~burst
        static = two_sided_mean(x, ok, alpha)
    res = x                    # x is not needed past here
    res -= static
    for a, b in _row_blocks(n):
        d_static = np.gradient(static[a:b], axis=1)
        for i in np.nonzero(ok[a:b])[0]:
            basis = np.stack([static[a + i], d_static[i]], axis=1)
            coef, *_ = np.linalg.lstsq(basis, res[a + i], rcond=None)
            res[a + i] -= basis @ coef
    res[~ok] = 0.0
    return res, ok, _row_mean(static, ok)


def _row_mean(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``x[rows].mean(axis=0)`` (the same bits: rows added in order) with no copy of the
    rows; zeros when there are none."""
    acc = np.zeros(x.shape[1])
    idx = np.nonzero(rows)[0]
    for i in idx:
        acc += x[i]
    if len(idx):
        acc /= len(idx)
    return acc


def envelope_image(res: np.ndarray, ok: np.ndarray, static: np.ndarray, prf: float, *,
                   overwrite: bool = False) -> np.ndarray:
    """Step 2: the residuals' envelopes, weighted down where the static room is strong,
    less their own two-sided mean; rows not usable are zero. The envelopes (complex
    analytic signals) are taken ``ROWS`` pulses at a time, over ``res`` itself with
    ``overwrite``."""
    n, L = res.shape
    env = res if overwrite else np.empty((n, L))
    zero = np.zeros(L)
    for a, b in _row_blocks(n):
        env[a:b] = envelope_features(res[a:b], zero)
    env[~ok] = 0.0
    if ok.any():
        sq = np.zeros(L)
        for i in np.nonzero(ok)[0]:      # np.mean(env[ok] ** 2, axis=0), no copies
            sq += env[i] * env[i]
        # (stats.median: np.median's values without importing numpy.ma)
        moving = float(median(np.sqrt(sq / np.count_nonzero(ok))))
        s_env = np.convolve(analytic_magnitude(static[None, :])[0], np.ones(5) / 5.0,
                            mode="same")
        if moving > 0:
            env *= 1.0 / (1.0 + (s_env / (STATIC_WEIGHT * moving)) ** 2)[None, :]
    alpha = min(1.0, 1.0 / (ENVELOPE_S * prf))
    d = two_sided_mean(env, ok, alpha)
    np.subtract(env, d, out=d)
    d[~ok] = 0.0
    return d


def block_correlations(d: np.ndarray, ok: np.ndarray, lag: int) -> np.ndarray:
    """The cross-correlation of each usable pulse's envelope with the one ``lag`` pulses
    later, shifts -MAX_SHIFT..MAX_SHIFT, summed over blocks of ``BLOCK`` pulses:
    (blocks, 2 MAX_SHIFT + 1); shift s > 0 means the later pulse's echoes lie further
    out."""
    return lag_correlations(d, ok, [lag])[0]


def lag_correlations(d: np.ndarray, ok: np.ndarray, lags: list[int]) -> list[np.ndarray]:
    """:func:`block_correlations` at each of ``lags``, the spectra shared by the lags and
    taken ``ROWS`` pulses at a time (whole, the spectra and products of 800 pulses took
    100 MiB)."""
    n, L = d.shape
    nb = max(1, -(-n // BLOCK))
    outs = [np.zeros((nb, 2 * MAX_SHIFT + 1)) for _ in lags]
    todo = [(out, lag) for out, lag in zip(outs, lags, strict=True) if lag < n]
    if not todo:
        return outs
    longest = max(lag for _, lag in todo)
    nfft = 1 << int(math.ceil(math.log2(2 * L)))
    for a, b in _row_blocks(n):
        F = np.fft.rfft(d[a:min(n, b + longest)], n=nfft, axis=1)
        for out, lag in todo:
            # pairs (i, i + lag) with both usable, i in [a, b)
            k = a + np.nonzero(ok[a:min(b, n - lag)] & ok[a + lag:min(b + lag, n)])[0]
            if len(k) == 0:
                continue
            cc = np.fft.irfft(np.conj(F[k - a]) * F[k - a + lag], n=nfft, axis=1)
            cc = np.concatenate([cc[:, -MAX_SHIFT:], cc[:, :MAX_SHIFT + 1]], axis=1)
            np.add.at(out, k // BLOCK, cc)
    return outs


def peak_shift(c: np.ndarray, near: float | None = None, half: float = 0.0) -> float:
    """Sub-sample position of the largest value of ``c`` (shifts -MAX_SHIFT..MAX_SHIFT),
    by a parabola through it and its neighbours; with ``near``, the largest within
    ``half`` samples of that shift."""
    s = np.arange(-MAX_SHIFT, MAX_SHIFT + 1)
    look = np.asarray(c, dtype=np.float64)
    if near is not None:
        look = np.where(np.abs(s - near) <= half, look, -np.inf)
    i = int(np.argmax(look))
    if 0 < i < len(c) - 1:
        a, b, e = float(c[i - 1]), float(c[i]), float(c[i + 1])
        den = a - 2.0 * b + e
        frac = 0.5 * (a - e) / den if den < 0 else 0.0
        return i - MAX_SHIFT + max(-0.5, min(0.5, frac))
    return float(i - MAX_SHIFT)


def mirror_excess(c: np.ndarray) -> np.ndarray:
    """``c`` less its mirror image, c(s) - c(-s): what moves one way more than the other.
    An echo that stays at its range while its strength changes (a reverberant tail, a
    blade's diffuse echo) is one fixed shape times a strength from pulse to pulse, and
    its correlation c(s) = (sum a_i a_i+lag) R(s) is even in s: it leaves nothing here,
    however strong, where it peaks the plain correlation at zero shift."""
    c = np.asarray(c, dtype=np.float64)
    out: np.ndarray = c - c[::-1]
    return out


def lag_peaks(per_lag: list[np.ndarray], keep: np.ndarray | None = None,
              mirror: bool = False) -> list[float]:
    """The correlation peak at each lag (blocks ``keep`` only): at lag 1 the largest
    over all shifts, at lag n the largest within half of n times that shift (3 samples
    at least) of n times it, where the same echoes should be. With ``mirror``, the peaks
    of :func:`mirror_excess` of the correlations."""
    peaks: list[float] = []
    for lag, blocks in enumerate(per_lag, start=1):
        c = blocks.sum(axis=0) if keep is None else blocks[keep].sum(axis=0)
        if mirror:
            c = mirror_excess(c)
        if lag == 1:
            peaks.append(peak_shift(c))
        else:
            guess = lag * peaks[0]
            peaks.append(peak_shift(c, guess, max(3.0, 0.5 * abs(guess))))
    return peaks


def glint_speed(per_lag: list[np.ndarray], keep: np.ndarray | None = None,
                mirror: bool = False) -> float:
    """Samples per pulse of the strongest moving echoes: the correlation peaks at lags
    1..len(per_lag) (:func:`lag_peaks`) fitted by speed * lag through zero."""
    peaks = lag_peaks(per_lag, keep, mirror)
    num = sum(lag * p for lag, p in enumerate(peaks, start=1))
    return num / sum(lag * lag for lag in range(1, len(peaks) + 1))


def decide(per_lag: list[np.ndarray], used: int, mirror: bool = False) -> Airflow:
    """Step 4: the glint speed, its standard error from ``HALVES`` random halves of the
    blocks (their scatter; a half holds half the data, so its estimates scatter as the
    whole's would with twice the noise, and the delete-half jackknife takes their spread
    as the whole's standard error), the call."""
    live = np.nonzero(per_lag[0].any(axis=1))[0]
    nb = len(live)
    lags = len(per_lag)
    if nb < MIN_BLOCKS:
        return Airflow("unknown", 0.0, 0.0, 0.0, used,
                       f"too short: {nb} blocks of {BLOCK} usable pulse pairs, "
                       f"{MIN_BLOCKS} needed", lags)
    v = glint_speed(per_lag, mirror=mirror)
    peaks = lag_peaks(per_lag, mirror=mirror)
    if any(p * v < 0 and abs(p) > 1.0 for p in peaks):
        return Airflow("unknown", 0.0, 0.0, v, used,
                       "the lags disagree: correlation peaks at "
                       + ", ".join(f"{p:+.1f}" for p in peaks) + " samples", lags)
    # half-samples of the blocks (the delete-half jackknife: a peak's position is not a
    # smooth statistic, and leaving one block out left a noise peak where it was, so the
    # delete-one jackknife called white noise with t of 30)
    rng = np.random.default_rng(0)
    half = np.array([glint_speed(per_lag, rng.permutation(live)[: nb // 2], mirror)
                     for _ in range(HALVES)])
    se = float(np.std(half))
    ts = v / se if se > 0 else 0.0
    conf = math.erf(abs(ts) / (CALL_T * math.sqrt(2.0)))
    if abs(ts) < CALL_T:
        return Airflow("unknown", conf, ts, v, used,
                       f"glint shift {v:+.3f} samples per pulse is {abs(ts):.1f} standard "
                       f"errors from zero, {CALL_T:g} needed (fan at rest, too slow, or "
                       "the sensor near its axis)", lags)
    word = "up" if ts > 0 else "down"
    return Airflow(word, conf, ts, v, used,
                   f"glints {'recede' if ts > 0 else 'approach'} by {abs(v):.3f} samples "
                   f"per pulse, {abs(ts):.1f} standard errors", lags)


def measure(pulses: np.ndarray, valid: np.ndarray, prf: float, *,
            overwrite: bool = False) -> Airflow:
    """Airflow of aligned gated pulses (rows; ``valid`` marks usable ones) at ``prf`` Hz;
    with ``overwrite`` a float64 ``pulses`` is used as working memory (its contents are
    lost: one (n, L) array less)."""
    x = np.asarray(pulses, dtype=np.float64)
    if x.ndim != 2 or len(valid) != len(x):
        raise ValueError(f"pulses must be (n, L) with one valid flag per row, got "
                         f"{x.shape} and {len(valid)} flags")
    if not (prf > 0 and math.isfinite(prf)):
        raise ValueError(f"prf must be a positive number of Hz, got {prf!r}")
    ok = np.asarray(valid, bool)
    if np.count_nonzero(ok) < 2:
        return Airflow("unknown", 0.0, 0.0, 0.0, int(np.count_nonzero(ok)),
                       "too short: fewer than 2 usable pulses")
    res, ok, static = moving_part(x, ok, prf, overwrite=overwrite)
    d = envelope_image(res, ok, static, prf, overwrite=True)     # res is this call's
    del res
    first = block_correlations(d, ok, 1)
    used = int(np.count_nonzero(ok))
    c1 = first.sum(axis=0)
    speeds = [abs(peak_shift(c1)), abs(peak_shift(mirror_excess(c1)))]
    lags = [_lags_for(v) for v in speeds]
    # the lags both readings need, their spectra taken once
    per_lag = [first] + lag_correlations(d, ok, list(range(2, max(lags) + 1)))
    plain, mirrored = (_decide_at_lags(per_lag[:n], used, v, mirror=m)
                       for n, v, m in zip(lags, speeds, (False, True), strict=True))
    if plain.reason.startswith("too short"):
        return plain
    return combine(plain, mirrored, speeds[0])


def _lags_for(speed: float) -> int:
    """Lags 1..n for a lag-1 shift of ``speed`` samples (1: none confirmable)."""
    lags = int(min(MAX_LAG, max(1, SPAN // max(speed, 0.5))))
    if lags < MIN_LAGS and MIN_LAGS * speed <= FIT_SHIFT:
        lags = MIN_LAGS
    return lags


def _decide_at_lags(per_lag: list[np.ndarray], used: int, speed: float, *,
                    mirror: bool) -> Airflow:
    """Steps 3-4 on the correlations at lags 1..len(per_lag), plain or their mirror
    excess; ``speed`` is the lag-1 peak's shift that chose the lags."""
    lags = len(per_lag)
    if lags < MIN_LAGS:
        return Airflow("unknown", 0.0, 0.0, speed, used,
                       f"the strongest moving echoes shift {speed:.1f} samples per pulse, "
                       "too fast to be confirmed at a second lag", 1)
    a = decide(per_lag, used, mirror)
    if mirror and a.airflow != "unknown":
        # the mirror excess's largest value at lags 1 and 2, over all shifts, on the
        # side of the call: at rest, a strong echo whose shape wavers from pulse to
        # pulse left small lopsided excesses that flip side from lag to lag
        signs = [np.sign(peak_shift(mirror_excess(b.sum(axis=0))))
                 for b in per_lag[:2]]
        if any(sg != np.sign(a.t) for sg in signs):
            return Airflow("unknown", a.confidence, a.t, a.shift, used, SIDES, lags)
    if a.airflow != "unknown":
        why = lag_structure(lag_peaks(per_lag, mirror=mirror))
        if why:
            return Airflow("unknown", a.confidence, a.t, a.shift, used, why, lags)
    return a


def lag_structure(peaks: list[float]) -> str | None:
    """Why the correlation peaks at lags 1, 2, .. are no motion, or None: a peak at the
    end of the shifts looked at is not located (on a reverberant tuning case, 18 samples
    at lag 1 and the end at lag 2 were called wrong with t 657, read over part of the
    gate: the tail's fan-moving arrivals, not a glint)."""
    if any(abs(p) >= MAX_SHIFT for p in peaks):
        return EDGE
    return None


def combine(plain: Airflow, mirrored: Airflow, lag1_shift: float = math.inf) -> Airflow:
    """The plain correlation's call; where it has none, the mirror excess's. Two calls
    that contradict each other are unknown (never a guess), and so is a plain call whose
    lag-1 peak lies within ``NEAR_ZERO`` samples of zero shift where the mirror excess
    is lopsided one way at lag 1 and the other at lag 2 (``SIDES``)."""
    if plain.airflow != "unknown":
        if mirrored.airflow not in ("unknown", plain.airflow):
            return Airflow("unknown", 0.0, plain.t, plain.shift, plain.pulses,
                           f"the correlation's peak says {plain.airflow} (t {plain.t:+.1f}) "
                           f"and its mirror excess {mirrored.airflow} (t {mirrored.t:+.1f})",
                           plain.lags)
        if abs(lag1_shift) < NEAR_ZERO and mirrored.reason == SIDES:
            return Airflow("unknown", 0.0, plain.t, plain.shift, plain.pulses,
                           f"the correlation's peak ({plain.airflow}, t {plain.t:+.1f}) "
                           f"lies {abs(lag1_shift):.1f} samples from zero shift, where "
                           "echoes that keep their range pull it, and " + SIDES, plain.lags)
        return plain
    if mirrored.airflow != "unknown":
        return Airflow(mirrored.airflow, mirrored.confidence, mirrored.t, mirrored.shift,
                       mirrored.pulses, mirrored.reason + " (read on the mirror excess: "
                       "the plain peak made no call)", mirrored.lags)
    return Airflow(plain.airflow, plain.confidence, plain.t, plain.shift, plain.pulses,
                   f"{plain.reason}; mirror excess: {mirrored.reason}", plain.lags)
