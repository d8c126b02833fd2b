"""The blade-pass frequency: found on the doppler spectrum, refined well below one bin.

With K blades the echo pattern repeats every 1/K turn, so the pulse-to-pulse sequence at
every range is periodic with ``r = K f / PRF`` cycles per pulse and its doppler spectrum
holds lines at ``h r`` (h = 1, 2, ..., folded into [0, 1/2] by the PRF). The strongest line
is often a harmonic, not the fundamental; and one FFT bin (1/N cycles per pulse, 6.5 % at
3 Hz in the paper's 175 pulses) is too coarse for folding many periods.

Method
------
1. Incoherent, range-summed doppler spectrum of the mean-removed pulses (zero-padded).
2. Refuse if no line stands above the noise floor (stationary target).
3. Candidates ``r = (n +- nu) / m`` from the strongest lines ``nu`` (a line may be any
   harmonic m of r, aliased by n PRFs). Each candidate is scored by the fraction of the
   spectrum's line energy that sits on its harmonics. A harmonic of the true rate misses the
   other harmonics' energy, so candidates explaining much less than the best are dropped;
   a sub-harmonic (r/2, or an alias like (1 - r)/2) explains as much as the true rate, so
   among the rest the one with the least folding dispersion is kept: sorted by phase under
   the true r, neighbouring pulses are alike because the echo pattern is a continuous
   function of the angle.
4. Refine by maximising the coherent harmonic power
   ``J(r) = sum_h sum_d |sum_k z_kd exp(-2 pi i h r k)|^2`` on a fine grid and then a
   parabola, where ``z`` are the leading principal components of the pulses (this keeps the
   search cheap). This is the maximum-likelihood frequency of a periodic signal in white
   noise; its error falls as N^-1.5 and with the harmonic number.
5. Refuse aliased rates (``r`` near 1/2) and records holding too few periods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import EstimationError
from .aliasing import folded_angles, near_fraction
from .stats import median


@dataclass(frozen=True)
class PeriodEstimate:
    """The blade-pass rate of a reference recording.

    Attributes
    ----------
    cycles_per_pulse : float
        r: blade-pass cycles (1/K turn) per pulse, in (0, 1/2).
    coarse : float
        The candidate r before refinement (bin accuracy).
    line_snr : float
        Strongest doppler line over the noise floor (power ratio).
    explained : float
        Fraction of line energy on the harmonics of r, in [0, 1].
    harmonics : tuple of int
        Harmonic numbers used for refinement.
    periods : float
        Blade periods spanned by the pulses used.
    strongest_line : float
        Cycles per pulse (0 .. 1/2) of the strongest doppler line, whose aliases and
        harmonics the candidate rates are: a rate is chosen because it explains that
        line, which can be a pattern other than the fan's (:func:`drift_harmonic`).
    """

    cycles_per_pulse: float
    coarse: float
    line_snr: float
    explained: float
    harmonics: tuple[int, ...]
    periods: float
    strongest_line: float = float("nan")


#: Roughness (PhaseFolds.roughness) above which a fold's angles are in no order: about 1
#: for a random order, 0.09-0.46 for the true rate of 48 random rooms (sim/random_scene.py).
RANDOM_ORDER = 0.9
#: Largest q of the p/q whose multiples m/q are weighed against each other when the
#: tightest fold is in no order (_fundamental).
FAMILY_MAX_Q = 64

#: Highest harmonic that refines a candidate before its order is read: enough to place it
#: within a few hundredths of a cycle over the record (a coarser place smears the angles
#: and makes a wrong order look smooth), at a quarter of the cost of all 16.
ORDER_HARMONICS = 8

#: Columns (samples or features) per FFT in :func:`doppler_spectrum` (memory, not speed).
_SPECTRUM_COLUMNS = 64


def _fold(nu: np.ndarray | float) -> np.ndarray:
    """Fold frequencies in cycles/pulse into [0, 1/2] (real signals alias symmetrically)."""
    f = np.mod(np.asarray(nu, dtype=np.float64), 1.0)
    return np.minimum(f, 1.0 - f)


def doppler_spectrum(y: np.ndarray, pad: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Range-summed incoherent doppler power of mean-removed pulses.

    Parameters
    ----------
    y : ndarray, shape (n_pulses, n_samples)
        Pulses with the static (mean) part removed; missing pulses as zero rows.
    pad : int
        Zero-padding factor along pulses.

    Returns
    -------
    nu : ndarray, shape (n_bins,)
        Frequency in cycles per pulse, 0 .. 1/2.
    s : ndarray, shape (n_bins,)
        Power summed over samples.
    """
    n = y.shape[0]
    w = np.hanning(n)[:, None]
    # a block of columns at a time: the padded spectrum of a whole reference recording
    # (24 s, 780 features) is 38 MiB of complex values, and its squares as much again
    s = np.zeros(pad * n // 2 + 1)
    for c in range(0, y.shape[1], _SPECTRUM_COLUMNS):
        spec = np.fft.rfft(y[:, c:c + _SPECTRUM_COLUMNS] * w, n=pad * n, axis=0)
        s += (spec.real ** 2 + spec.imag ** 2).sum(axis=1)
    return np.fft.rfftfreq(pad * n), s


def principal_series(y: np.ndarray, d: int = 16) -> np.ndarray:
    """Leading principal-component time series of the pulses, shape (n_pulses, <= d).

    Periodicity in the pulses is periodicity in these few series, so searches over the
    rate cost N*d per candidate instead of N*L.
    """
    u, s, _ = np.linalg.svd(y, full_matrices=False)
    d = int(min(d, len(s)))
    coords: np.ndarray = u[:, :d] * s[:d]
    return coords


def harmonic_power(z: np.ndarray, k: np.ndarray, rates: np.ndarray,
                   harmonics: np.ndarray) -> np.ndarray:
    """Coherent power on the harmonics of each candidate rate.

    Parameters
    ----------
    z : ndarray, shape (n, d)
        Series (e.g. principal components) at pulse numbers ``k``.
    k : ndarray, shape (n,)
        Pulse numbers (gaps allowed).
    rates : ndarray, shape (m,)
        Candidate rates, cycles per pulse.
    harmonics : ndarray, shape (h,)
        Harmonic numbers.

    Returns
    -------
    ndarray, shape (m,)
        ``sum_h sum_d |sum_k z_kd exp(-2 pi i h r k)|^2 / n``.
    """
    out = np.empty(len(rates))
    kk = k.astype(np.float64) - k.mean()
    for i, r in enumerate(rates):
        e = np.exp(-2j * np.pi * np.outer(harmonics * r, kk))
        c = e @ z
        out[i] = float((c.real ** 2 + c.imag ** 2).sum()) / len(kk)
    return out


def estimate_period(y: np.ndarray, k: np.ndarray | None = None, *,
                    features: np.ndarray | None = None, min_periods: float = 3.0,
                    max_cycles_per_pulse: float = 0.4, line_snr_min: float = 8.0,
                    explain_tol: float = 0.8, max_harmonic: int = 8,
                    pad: int = 8) -> PeriodEstimate:
    """Estimate the blade-pass rate r (cycles per pulse) of mean-removed pulses.

    Parameters
    ----------
    y : ndarray, shape (n_pulses, n_samples)
        Gated pulses minus their mean; rows of missing pulses are zero.
    k : ndarray, shape (n_pulses,), optional
        Pulse numbers of the rows (default 0..n-1); only rows with nonzero data are used in
        the refinement.
    features : ndarray, shape (n_pulses, m), optional
        Vectors in which the echo pattern is a smooth function of angle (mean-removed
        envelopes, see fingerprint.py); when given, every step runs on them instead of
        ``y``. Rows of missing pulses are zero.
    min_periods : float
        Fewest blade periods the record must span.
    max_cycles_per_pulse : float
        Largest r accepted; near 1/2 a rate and its reverse alias onto each other.
    line_snr_min : float
        Strongest line over the median spectrum needed to call the target moving.
    explain_tol : float
        A candidate explaining at least this fraction of the best candidate's line energy
        counts as explaining the data (picks the fundamental over its harmonics).

    Raises
    ------
    EstimationError
        Stationary target, aliased rate, or too few periods.
    """
    if features is not None:
        # everything runs on the features: a raw echo that moves by several samples per
        # blade period spreads its energy over many aliased harmonics (a high floor),
        # its envelope gives a few clean lines
        y = features
    y = np.asarray(y, dtype=np.float64)
    n = y.shape[0]
    if k is None:
        k = np.arange(n)
    if n < 16:
        raise EstimationError(f"only {n} pulses: the blade period cannot be estimated; "
                              "record a longer reference")
    lines = DopplerLines.of(y, pad)
    if lines.line_snr < line_snr_min:
        raise EstimationError(
            f"no doppler line above the noise (strongest is {lines.line_snr:.1f}x the floor, "
            f"need {line_snr_min:g}x): the target seems stationary. Record the reference "
            "while the fan turns")
    candidates = lines.candidate_rates(max(min_periods / n, 1.0 / n), max_harmonic)
    if not len(candidates):
        raise EstimationError(
            f"the strongest doppler line, at {lines.nu[lines.strongest]:.3f} cycles per "
            "pulse, is no peak a turning fan makes (the spectrum only falls from zero "
            "doppler or rises to half the PRF): the echoes changed during the recording "
            "instead of turning (a moved sensor, a gain step, or data whose format or "
            "sample rate changes part-way). Record the reference again, the fan turning "
            "steadily and nothing else changing")
    rows = np.any(y != 0.0, axis=1)
    folds = PhaseFolds(principal_series(y[rows]), np.asarray(k)[rows],
                       span=float(np.max(k) - np.min(k) + 1))
    r0 = _fundamental(candidates, lines, folds, explain_tol, max_harmonic,
                      max_cycles_per_pulse)
    span = float(k.max() - k.min() + 1)
    _refuse_unusable(r0, span, max_cycles_per_pulse, min_periods)
    use = lines.harmonics_with_energy(r0)
    r = _refine(folds.z, folds.k, r0, np.array(use, dtype=np.float64), span)
    return PeriodEstimate(cycles_per_pulse=r, coarse=r0, line_snr=lines.line_snr,
                          explained=float(lines.explained(r0)), harmonics=tuple(use),
                          periods=r * span, strongest_line=float(lines.nu[lines.strongest]))


#: Harmonics of the aligner's sub-sample cycle that a found blade rate is checked against.
DRIFT_HARMONICS = (1, 2, 3)


def sub_sample_cycle(period: float) -> float:
    """Cycles per pulse of the sub-sample position at which pulses ``period`` capture
    samples apart are read (0 .. 1/2): under clock drift it turns once every
    1 / (drift x PRI) pulses, and with it the interpolation error on strong static
    echoes, a pattern that repeats like a fan's."""
    frac = float(period) % 1.0
    return min(frac, 1.0 - frac)


def drift_harmonic(r: float, period: float, span: float) -> int | None:
    """The harmonic h (of :data:`DRIFT_HARMONICS`) of the sub-sample cycle that the blade
    rate ``r`` (cycles per pulse) lies within one spectral bin (1 / ``span`` pulses) of,
    or None. A fan 3.2 m away whose echoes were 30-45 dB under the walls' gave a
    reference at 1.99 times the cycle (0.726 Hz for a fan at 0.219 Hz), another at 2.007
    times (3.54 Hz for 0.264 Hz). A cycle that turns fewer than 2 times over the record
    is no line at all and is not checked."""
    cyc = sub_sample_cycle(period)
    if not span > 0 or cyc * span < 2.0:
        return None
    for h in DRIFT_HARMONICS:
        f = (h * cyc) % 1.0
        if abs(min(f, 1.0 - f) - float(r)) <= 1.0 / span:
            return h
    return None


@dataclass(frozen=True)
class DopplerLines:
    """The range-summed doppler spectrum of a record (:func:`doppler_spectrum`), its noise
    floor and the line energy above it: where the candidate rates come from and how much
    of the lines each explains."""

    nu: np.ndarray
    """Frequency of each bin, cycles per pulse, 0 .. 1/2."""
    power: np.ndarray
    """Power summed over samples, per bin."""
    pad: int
    """Zero-padding factor (padded bins per FFT bin)."""
    dc: np.ndarray
    """Bins of zero doppler and its window mainlobe."""
    floor: float
    """Median power outside zero doppler (the noise floor)."""
    excess: np.ndarray
    """Power above the floor, 0 at zero doppler."""
    line_energy: float
    """All the excess (the denominator of :meth:`explained`)."""
    strongest: int
    """Bin of the strongest line."""

    @classmethod
    def of(cls, y: np.ndarray, pad: int) -> DopplerLines:
        n = y.shape[0]
        nu, s = doppler_spectrum(y, pad)
        dc = nu < 2.0 / n
        floor = float(median(s[~dc])) + 1e-300
        excess = np.where(dc, 0.0, np.maximum(s - floor, 0.0))
        return cls(nu=nu, power=s, pad=pad, dc=dc, floor=floor, excess=excess,
                   line_energy=float(excess.sum()) + 1e-300,
                   strongest=int(np.argmax(np.where(dc, 0.0, s))))

    @property
    def line_snr(self) -> float:
        """Strongest line over the noise floor (power ratio)."""
        return float(self.power[self.strongest] / self.floor)

    @property
    def bin_width(self) -> float:
        """Cycles per pulse between padded bins."""
        return float(self.nu[1] - self.nu[0])

    def peaks(self) -> np.ndarray:
        """The strongest local maxima (at most 3, each at least 1/4 of the strongest)."""
        s = self.power
        peaks = np.nonzero((s[1:-1] > s[:-2]) & (s[1:-1] >= s[2:]) & ~self.dc[1:-1])[0] + 1
        peaks = peaks[np.argsort(s[peaks])[::-1][:3]]
        strong: np.ndarray = peaks[s[peaks] >= 0.25 * s[self.strongest]]
        return strong

    def candidate_rates(self, r_lo: float, max_harmonic: int) -> np.ndarray:
        """Every rate ``(n +- nu) / m`` in [r_lo/2, 1/2) of which a peak ``nu`` may be
        harmonic m aliased by n PRFs, sorted."""
        cands: set[float] = set()
        for p in self.peaks():
            for m in range(1, max_harmonic + 1):
                for nn in range(0, m + 1):
                    for sign in (1.0, -1.0):
                        r = (nn + sign * self.nu[p]) / m
                        if r_lo * 0.5 <= r < 0.5:
                            cands.add(round(r, 12))
        return np.array(sorted(cands))

    def explained(self, r: float) -> float:
        """Fraction of the line energy on the first 16 harmonics of ``r``."""
        # the line of harmonic h sits within +-h/2 padded bins of h*r (r is known to about
        # half a padded bin) plus its own mainlobe; take the strongest bin of each and the
        # line's central FFT bin either side of it (pad padded bins; the Hann window's line
        # is 2 bins wide each way). Half a bin each way counted only the peak of a line,
        # and a multiple of r whose harmonics fell on the lines' flanks as well as on their
        # peaks then explained more than r itself (docs/analysis.md)
        pad, excess, n_bins = self.pad, self.excess, len(self.nu)
        hs = np.arange(1, 17)
        centre = np.rint(_fold(hs * r) / self.bin_width).astype(int)
        got: set[int] = set()
        for h, b in zip(hs, centre, strict=True):
            w = pad // 2 + int(h) // 2
            lo, hi = max(b - w, 0), min(b + w + 1, n_bins)
            i = lo + int(np.argmax(excess[lo:hi]))
            got.update(range(max(i - pad, 0), min(i + pad + 1, n_bins)))
        return float(excess[list(got)].sum()) / self.line_energy

    def harmonics_with_energy(self, r: float) -> list[int]:
        """Harmonics of ``r`` (up to 16) whose line stands 4x over the floor; [1] if
        none: the ones the coherent refinement uses."""
        use = []
        for h in range(1, 17):
            b = round(float(_fold(h * r)) / self.bin_width)
            lo, hi = max(b - self.pad // 2, 0), min(b + self.pad // 2 + 1, len(self.power))
            if float(self.power[lo:hi].max()) > 4.0 * self.floor:
                use.append(h)
        return use or [1]


class PhaseFolds:
    """A record folded at trial rates: the principal series ``z`` at pulse numbers ``k``
    sorted into phase bins, and the measures that tell the true rate from its harmonics,
    sub-harmonics and aliases."""

    def __init__(self, z: np.ndarray, k: np.ndarray, span: float) -> None:
        self.z = z
        self.k = k
        self.span = span
        """Pulses spanned by the record (first to last pulse number)."""
        self.total_var = float((z * z).sum()) + 1e-300

    def fold(self, r: float, bins: int) -> tuple[np.ndarray, np.ndarray, float]:
        """Bin means (filled bins only, in phase order), all counts, within-bin energy."""
        z = self.z
        b = np.floor(np.mod(self.k * r, 1.0) * bins).astype(np.int64) % bins
        cnt = np.bincount(b, minlength=bins)
        sums = np.zeros((bins, z.shape[1]))
        np.add.at(sums, b, z)
        full = cnt > 0
        means = np.zeros_like(sums)
        means[full] = sums[full] / cnt[full, None]
        within = float(((z - means[b]) ** 2).sum())
        return means, cnt, within

    def dispersion(self, r: float) -> float:
        """Folding dispersion: energy left within the phase bins over the total. A
        harmonic of the true rate puts different angles into one bin and leaves much
        more."""
        # the minimum over a few nearby rates, as a coarse candidate is only known to
        # about 1/(16 N) and its fold would smear otherwise
        offs = np.array([-1.0, -0.5, 0.0, 0.5, 1.0]) / (16.0 * self.span)
        return min(self.fold(r + o, 32)[2] for o in offs) / self.total_var

    def roughness(self, r: float, bins: int = 64) -> float:
        """Neighbouring bins compared, relative to the spread of the bins (1 for a random
        order). The echo pattern is a continuous function of the angle, so only the true
        rate makes neighbours alike; an exactly periodic record (r = j/P, every j alike in
        the spectrum and in dispersion) is ordered right only by its true j."""
        means, cnt, _ = self.fold(r, bins)
        t = means[cnt > 0]
        if len(t) < 3:
            return np.inf
        d = _step_energy(t)
        e = float(((t - t.mean(axis=0)) ** 2).sum())
        return d / (2.0 * e) if e > 0 else np.inf

    def order_spread(self, r: float, bins: int = 64) -> float:
        """The standard deviation of :meth:`roughness` over random orders of the same
        filled bins (a fixed draw: the same record gives the same answer)."""
        means, cnt, _ = self.fold(r, bins)
        t = means[cnt > 0]
        if len(t) < 3:
            return math.inf
        rng = np.random.default_rng(0)
        e = float(((t - t.mean(axis=0)) ** 2).sum())
        if not e > 0:
            return math.inf
        got = np.empty(ORDER_NULL_TRIALS)
        for i in range(ORDER_NULL_TRIALS):
            got[i] = _step_energy(t[rng.permutation(len(t))]) / (2.0 * e)
        return float(got.std())

    def repeats_within(self, r: float, m: int, per: int = 16) -> bool:
        """Is the fold at ``r`` made of ``m`` copies (``r`` is a sub-harmonic: r/m, or an
        alias such as (1 - r)/2)? The table compared with itself shifted by 1/m period."""
        means, cnt, _ = self.fold(r, m * per)
        both = (cnt > 0) & (np.roll(cnt, -per) > 0)
        if both.sum() < per:
            return False
        t = means[both]
        sh = np.roll(means, -per, axis=0)[both]
        d = float(((sh - t) ** 2).sum())
        e = float(((t - t.mean(axis=0)) ** 2).sum())
        return e > 0 and d / (2.0 * e) < 0.2


def _step_energy(t: np.ndarray) -> float:
    """Summed squared change between neighbouring rows of ``t`` (the last to the first):
    :meth:`PhaseFolds.roughness`'s numerator, for a fold's bins in any order."""
    return float(((np.roll(t, -1, axis=0) - t) ** 2).sum())


def _fundamental(candidates: np.ndarray, lines: DopplerLines, folds: PhaseFolds,
                 explain_tol: float, max_harmonic: int, limit: float = math.inf) -> float:
    """The candidate that is the blade-pass rate: explains the lines (not a harmonic),
    folds tightest and smoothest (not a sub-harmonic or an alias), climbed to r*m while
    the fold at r repeats m times. A choice over ``limit`` (which the analysis refuses)
    is made again among the candidates under it, where one explains the lines as well:
    a record whose period is nearly a whole number P of pulses folds every m r (m prime
    to P) about as tightly as r, with the same lines (spent held-out 3800008: 20 r, 0.465
    blade period per pulse, for a fan at 0.0233 with P = 43, and the reference was
    refused as too fast)."""
    scores = np.array([lines.explained(r) for r in candidates])
    best = float(scores.max())
    ok = np.array(sorted(set(np.round(candidates[scores >= explain_tol * best], 5).tolist())),
                  dtype=np.float64)   # np.unique's values, without its import of numpy.ma
    r0 = _choose(ok, lines, folds, max_harmonic)
    if r0 > limit and (ok <= limit).any():
        r0 = _choose(ok[ok <= limit], lines, folds, max_harmonic)
    return r0


def _choose(ok: np.ndarray, lines: DopplerLines, folds: PhaseFolds, max_harmonic: int
            ) -> float:
    """:func:`_fundamental`'s choice among the candidates ``ok`` that explain the lines."""
    disp = np.array([folds.dispersion(r) for r in ok])
    tight = ok[disp <= 1.2 * disp.min() + 0.02]
    rough = np.array([folds.roughness(r) for r in tight])
    r0 = float(tight[int(np.argmin(rough))])
    lines_of = _apart(tight, 2.0 / folds.span)
    if len(lines_of) > 1:
        # tight folds of different lines (the rate and a multiple m r that folds nearly
        # as tightly): each line's order read at its refined rate, since a coarse
        # candidate a little off m r spreads each angle over a band of neighbouring bins
        # that are alike, and looks ordered (a 3-blade fan's 11 r read 0.24 against its
        # rate's 0.31; refined, 0.70 against 0.33)
        def refined(group: np.ndarray) -> float:
            r = float(group[0])
            hs = np.array([h for h in lines.harmonics_with_energy(r) if h <= ORDER_HARMONICS]
                          or [1], dtype=np.float64)
            return _refine(folds.z, folds.k, r, hs, folds.span, finer=1)
        rates = [refined(g) for g in lines_of]
        orders = [folds.roughness(r) for r in rates]
        if min(orders) <= RANDOM_ORDER:
            # (where no line orders its angles, a record at p/q showing only q of them,
            # the order tells nothing: the family of m/q below decides, or the reference
            # is warned about)
            line = lines_of[_slower_harmonic(int(np.argmin(orders)), rates, orders, folds)]
            r0 = float(line[int(np.argmin([folds.roughness(float(r)) for r in line]))])
    frac = near_fraction(r0, span=int(folds.span), max_q=FAMILY_MAX_Q, min_q=2, zero=False)
    if frac is not None:
        # a record at p/q shows only q angles, every m/q folds them alike, and one of them
        # was tightest by chance: the order of the angles decides among the m/q that
        # explain the lines. Where the tightest puts them in no order at all (a 4-blade
        # fan at 2/33 blade period per pulse: 13/33 by 0.04 against 0.11, its neighbours
        # no more alike than random, 1.07, where 2/33 read 0.27), the most ordered; else
        # one clearly more ordered than the tightest (spent held-out 6300006: a 6-blade
        # fan at 4/37, 0.29, folded at 5/37, 0.73, by 0.06 against 0.16; every rate
        # published 5/4 of the fan's)
        q = frac.denominator
        family = ok[np.abs(ok * q - np.round(ok * q)) * folds.span < 0.5]
        if float(rough.min()) > RANDOM_ORDER:
            rough_all = np.array([folds.roughness(r) for r in family])
            r0 = float(family[int(np.argmin(rough_all))])
        else:
            r0 = _more_ordered(r0, family, folds)
    climbed = True
    while climbed:
        climbed = False
        for m in range(2, max_harmonic + 1):
            rm = float(_fold(m * r0))
            if rm > r0 and folds.repeats_within(r0, m):
                r0, climbed = rm, True
                break
    return r0


#: Largest m for which a line at 1/m of the chosen one has its order read at the chosen
#: line's angular step (:func:`_slower_harmonic`).
ORDER_SUBHARMONIC_M = 4


def _slower_harmonic(best: int, rates: list[float], orders: list[float],
                     folds: PhaseFolds) -> int:
    """The line to take instead of line ``best`` (refined ``rates``, their ``orders``
    over 64 bins): a line at 1/m of its rate (m <= ``ORDER_SUBHARMONIC_M``) whose order
    over m times the bins, the same step in the fan's angle, is the better. A line at
    m r bins the angles m times closer than r over the same bins, so it reads smoother
    wherever the pattern is smooth, though its fold mixes m stretches of the period
    (spent held-out 6100007: a 6-blade fan's reference took 2 r, its order 0.131 against
    r's 0.311, where r over 128 bins reads 0.108; every rate published was doubled). A
    true sub-harmonic (its fold m copies of the pattern) reads alike either way and is
    climbed back by :func:`_choose`."""
    rb = rates[best]
    pick, low = best, orders[best]
    for i, r in enumerate(rates):
        if i == best or not r > 0:
            continue
        m = rb / r
        mi = round(m)
        if 2 <= mi <= ORDER_SUBHARMONIC_M and abs(m - mi) <= 2e-3 * mi:
            o = folds.roughness(r, bins=64 * mi)
            if o < low:
                pick, low = i, o
    return pick


#: Random orders of a fold's angles that give the spread of its roughness under no order
#: (:func:`_more_ordered`), and how many of those spreads a better order must stand out by.
ORDER_NULL_TRIALS = 200
ORDER_NULL_SD = 3.0


def _more_ordered(r0: float, family: np.ndarray, folds: PhaseFolds) -> float:
    """Among the rates ``family`` (the m/q of a record at p/q), one whose angles lie in
    clearly better order than ``r0``'s, or ``r0``. Each m/q folds the same q angles (over
    the same 64 bins: more bins would split their clusters into alike neighbours), the
    true rate in the order of the fan's angle and another at a larger angular step, which
    a slowly changing pattern or noise may read as nearly as ordered (a 5-blade fan at
    1/34 read 0.68 against 11/34's 0.60): clearly is by ``ORDER_NULL_SD`` times the spread
    of the roughness of ``r0``'s fold in random orders (1.5 there; 5.9 for 6300006's 4/37
    against the tightest 5/37). A line at m times ``r0`` (m <= ``ORDER_SUBHARMONIC_M``,
    folded) is left out: its fold mixes m stretches of the period and may read the
    smoother (:func:`_slower_harmonic`)."""
    gap = 2.0 / folds.span
    own = folds.roughness(r0)
    pick, low = r0, own
    for r in family:
        r = float(r)
        if abs(r - r0) < gap or not r > 0 or any(
                abs(float(_fold(m * r0)) - r) < gap
                for m in range(2, ORDER_SUBHARMONIC_M + 1)):
            continue
        o = folds.roughness(r)
        if o < low:
            pick, low = r, o
    if pick == r0 or not low < own - ORDER_NULL_SD * folds.order_spread(r0):
        return r0
    return pick


def _apart(rates: np.ndarray, gap: float) -> list[np.ndarray]:
    """Sorted ``rates`` split where neighbours are more than ``gap`` apart."""
    r = np.sort(rates)
    return np.split(r, np.flatnonzero(np.diff(r) > gap) + 1)


def _refuse_unusable(r0: float, span: float, max_cycles_per_pulse: float,
                     min_periods: float) -> None:
    """Refuse a rate too near 1/2 cycle per pulse (aliased) or a record holding too few
    periods of it."""
    if r0 > max_cycles_per_pulse:
        frac = folded_angles(r0, int(span))
        also = (f" Or, if the fan turned slower: {r0:.3f} is {frac} cycle per pulse, and a "
                f"record at a rate near p/q sees only q={frac.denominator} angles, so its "
                "period may be any m/q; record the reference at a slightly different fan "
                "speed" if frac is not None else "")
        raise EstimationError(
            f"the blade phase advances {r0:.2f} cycles per pulse (limit "
            f"{max_cycles_per_pulse:g}): near 1/2 the rate is aliased and the direction "
            "ambiguous. The fan must turn slower than PRF/(2K), or raise the PRF "
            f"(smaller waveform.pri_samples).{also}")
    if r0 * span < min_periods:
        raise EstimationError(
            f"the reference spans {r0 * span:.1f} blade periods but at least {min_periods:g} "
            "are needed (analysis.min_periods); record a longer reference")


def _refine(z: np.ndarray, k: np.ndarray, r0: float, hs: np.ndarray, span: float,
            finer: int = 2) -> float:
    """The maximum of the coherent harmonic power (:func:`harmonic_power` on harmonics
    ``hs``) near the coarse rate ``r0``: a grid, ``finer`` finer grids, then a parabola."""
    # coarse candidates are good to about a padded bin divided by the harmonic number
    width = 1.5 / span
    step = 1.0 / (8.0 * span * hs.max())
    grid = r0 + np.arange(-width, width + step / 2, step)
    grid = grid[grid > 0]
    j = harmonic_power(z, k, grid, hs)
    g = int(np.argmax(j))
    for _ in range(finer):
        step /= 8.0
        grid = grid[g] + np.arange(-8, 9) * step
        j = harmonic_power(z, k, grid, hs)
        g = int(np.argmax(j))
    r = float(grid[g])
    if 0 < g < len(grid) - 1:
        a, b, c = j[g - 1], j[g], j[g + 1]
        den = a - 2 * b + c
        if den < 0:
            r += float(0.5 * (a - c) / den) * step
    return r
