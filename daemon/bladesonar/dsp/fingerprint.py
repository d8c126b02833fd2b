"""Angular fingerprint: a table of echo patterns by blade phase, and matching against it.

Features: envelopes, not raw samples
------------------------------------
A pulse is matched by its *envelope* (magnitude of the analytic signal of the pulse minus
the reference's mean pulse, lightly smoothed along range, with its own mean removed).

* Raw samples oscillate at the pulse's carrier: a blade moving a few millimetres between
  pulses, or a residual alignment error of a tenth of a sample, turns a raw echo into a
  different vector, while its envelope barely moves. Folding many periods averages pulses
  taken at slightly different angles; raw echoes with wandering delays cancel in that
  average, envelopes add up.
* The echo pattern as a function of angle is therefore continuous in the envelope domain
  (neighbouring table bins alike), which the period search and the tracker rely on. In the
  raw domain it is not, at the angular steps a pulse train samples (test:
  tests/test_dsp_fingerprint.py::test_envelope_beats_raw_under_jitter).
* The price is angular resolution: what the envelope smooths away is the fine detail
  that would separate very close angles. The tracker integrates many pulses, so a few
  percent of a blade period per match is plenty.

The static room (mean pulse of the reference) is removed before the envelope, so the
table describes the moving target only; the per-vector mean is removed after it, so a
different noise level (Rayleigh floor of the envelope) does not bias the match.

Matching is the energy norm, vectorised over pulses and phase bins:
``D = |x|^2 - 2 x T^T + |T|^2`` (one matrix product), best bin refined by a parabola.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .analytic import analytic_magnitude
from .stats import median

#: Share of the table's median distance between distinct angles (more than 1/8 period
#: apart) under which a match's best alternative counts as no alternative at all
#: (:func:`distance_floor`). In the paper room the table is flat over the blind half of
#: the blade period (no blade in view: every bin alike, 0.000-0.001 of that median apart);
#: a pulse there matched one of those bins at a quality of 0.13-0.23 at 30 dB, from
#: differences far below anything the reference resolves, and that standing line pulled
#: tracks to rest and through zero (false reversals). Its best alternative lay 0.004-0.02
#: of the median away (median to 90th percentile, 10-30 dB); a blade in view's 0.41-0.42
#: at the 10th percentile, 0.15 at the 1st.
FLAT_SHARE = 0.1

#: Rows whose envelopes are taken at once (envelope_features): a block of 256 pulses'
#: complex spectra (4 MiB and more) leave the CPU's cache, 64 rows' stay in it.
FEATURE_ROWS = 64

#: A clear match, for :func:`twin_bins`: the quality the tracker needs of the best match
#: in its window before it locks (``TrackerSettings.min_info``).
TWIN_CLEAR = 0.2
#: Share of a bin's clear matches that must come from one other angle for that angle to
#: be its twin, and the least number of them: a fifth, a sign of look-alikes rather than
#: of noise (in three simulated glint scenes one other angle gave a median 24-36 % of a
#: bin's clear matches, at most 39-57 %; in four scenes whose tracks hold, none in nine
#: bins of ten).
TWIN_SHARE = 0.2
TWIN_LEAST = 3


def envelope_features(pulses: np.ndarray, mean_pulse: np.ndarray | None, *,
                      kind: str = "envelope", smooth: int = 5, band: float = 1.0
                      ) -> np.ndarray:
    """The vectors that are matched: one row per pulse.

    Parameters
    ----------
    pulses : ndarray, shape (n, L)
        Aligned gated pulses.
    mean_pulse : ndarray, shape (L,), or None
        Static part (the reference's mean pulse), removed first; None: nothing removed
        (residuals already: the same values as a mean of zeros, without the copy).
    kind : {"envelope", "raw"}
        Envelope features (default, see module notes) or the raw mean-removed samples.
    smooth : int
        Length of the moving average applied to the envelope along range, samples.
    band : float
        Fraction of the band up to Nyquist kept before the envelope (envelope kind only).
        Below 1 it drops the top of the band, where the aligner's fractional shift is
        least exact: with clock drift, the strong static echoes there change a little
        from pulse to pulse although nothing in the room moves.

    Returns
    -------
    ndarray, shape (n, L), float64
    """
    y = np.asarray(pulses, dtype=np.float64)
    if mean_pulse is not None:
        y = y - np.asarray(mean_pulse, dtype=np.float64)
    if kind == "raw":
        return y if mean_pulse is not None else y.copy()
    if kind != "envelope":
        raise ValueError(f"kind must be 'envelope' or 'raw', not {kind!r}")
    if y.ndim == 2 and len(y) > FEATURE_ROWS:
        # a few dozen rows at a time: the same values (each row's transforms are its
        # own), at half the time of a block of 256 whose complex spectra leave the cache
        out = np.empty_like(y)
        for i in range(0, len(y), FEATURE_ROWS):
            _envelope(y[i:i + FEATURE_ROWS], smooth, band, out[i:i + FEATURE_ROWS])
        return out
    return _envelope(y, smooth, band)


def _envelope(y: np.ndarray, smooth: int, band: float, out: np.ndarray | None = None
              ) -> np.ndarray:
    """envelope_features' envelope kind on mean-removed rows (2-D: into ``out`` if
    given, whole rows of a C-ordered array)."""
    env: np.ndarray
    if y.ndim == 2 and 1 < smooth <= DIRECT_SMOOTH:
        # the magnitude written straight into the moving average's padded rows, the
        # average straight into ``out``: _moving_average's and the mean's operations on
        # the same numbers, without three copies of the block
        n, L = y.shape
        lo = smooth // 2
        padded = np.empty((n, L + smooth - 1))
        analytic_magnitude(y, band, out=padded[:, lo:lo + L])
        _pad_edges(padded, lo, L)
        env = np.empty((n, L)) if out is None else out
        _shifted_mean(padded, smooth, env)
    else:
        env = analytic_magnitude(y, band)
        if smooth > 1:
            env = _moving_average(env, smooth)
        if out is not None:
            out[...] = env
            env = out
    env -= env.mean(axis=1, keepdims=True)
    return env


#: Longest moving average summed shift by shift (_moving_average); a longer one is taken
#: from a running sum.
DIRECT_SMOOTH = 16


def _moving_average(env: np.ndarray, smooth: int) -> np.ndarray:
    """The centred moving average of ``smooth`` samples along each row, the rows' end
    values repeated beyond their ends. A short one (the default 5) as the sum of
    ``smooth`` shifted copies: whole-row vector additions, where a running sum
    (``cumsum``) is one long chain of dependent additions, and most of the envelope's
    cost beside its FFTs. The two differ in the last bits only (the shifted sum has no
    running sum's cancellation)."""
    n, L = env.shape
    lo = smooth // 2        # (and smooth - lo - 1 after the row)
    padded = np.empty((n, L + smooth - 1))
    padded[:, lo:lo + L] = env
    _pad_edges(padded, lo, L)
    out: np.ndarray = np.empty((n, L))
    if smooth > DIRECT_SMOOTH:
        c = np.cumsum(padded, axis=1)
        out[:, 0] = c[:, smooth - 1]
        np.subtract(c[:, smooth:], c[:, :-smooth], out=out[:, 1:])
        out /= smooth
    else:
        _shifted_mean(padded, smooth, out)
    return out


def _pad_edges(padded: np.ndarray, lo: int, L: int) -> None:
    """Repeat each row's end values, at ``lo:lo + L`` of ``padded``, into the columns
    before and after them (np.pad(mode="edge") written out: it cost a tenth of the
    daemon's analysis on small blocks)."""
    padded[:, :lo] = padded[:, lo:lo + 1]
    padded[:, lo + L:] = padded[:, lo + L - 1:lo + L]


def _shifted_mean(padded: np.ndarray, smooth: int, out: np.ndarray) -> None:
    """The mean of ``smooth`` shifted copies of the edge-padded rows into ``out``
    (n, L): the first two added, then each next one, then the division."""
    L = out.shape[1]
    if smooth > 1:
        np.add(padded[:, :L], padded[:, 1:1 + L], out=out)
    else:
        out[...] = padded[:, :L]
    for m in range(2, smooth):
        out += padded[:, m:m + L]
    out /= smooth


#: Table bins per reference pulse step (:func:`auto_bins`)
BINS_PER_STEP = 4.0


def fold_phases(k: np.ndarray, cycles_per_pulse: float, k0: float = 0.0) -> np.ndarray:
    """Blade phase of pulse numbers ``k`` under a constant rate, in [0, 1) cycles."""
    return np.mod(cycles_per_pulse * (np.asarray(k, dtype=np.float64) - k0), 1.0)


def largest_gap(phases: np.ndarray) -> float:
    """The widest stretch of blade phase (cycles, circular) that no pulse fell in: there
    the table is interpolated between the angles on either side, not measured."""
    ph = np.sort(np.mod(np.asarray(phases, dtype=np.float64), 1.0))
    if len(ph) < 2:
        return 1.0
    return float(max(np.diff(ph).max(initial=0.0), ph[0] + 1.0 - ph[-1]))


def auto_bins(cycles_per_pulse: float, requested: int = 0, angles: int | None = None
              ) -> int:
    """Phase bins of the table: ``requested``, or four per reference pulse step (16..256),
    and no more than two per blade angle the reference saw (``angles``: a reference near
    p/q blade period per pulse sees only q; finer bins would be blends of those).

    Folding many periods whose length is not a whole number of pulses fills in the angles
    between pulses, so the table can be finer than one bin per pulse. It must be: the
    echoes of a far or many-bladed fan change so much within a pulse step that
    neighbouring bins at two per step correlate 0.2-0.5 in random scenes, and the
    parabolic sub-bin step between such bins is poor. Four per step halve the phase
    error of a table that coarse and leave a smooth one as it was (docs/analysis.md).
    """
    if requested > 0:
        return int(requested)
    r = max(float(cycles_per_pulse), 1e-9)
    bins = round(BINS_PER_STEP / r)
    if angles is not None and angles > 0:
        bins = min(bins, 2 * int(angles))
    return int(min(256, max(16, bins)))


def build_table(features: np.ndarray, phases: np.ndarray, bins: int) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """Fold feature vectors into an angular table by linear binning over phase.

    Parameters
    ----------
    features : ndarray, shape (n, L)
        One vector per pulse.
    phases : ndarray, shape (n,)
        Blade phase of each, cycles in [0, 1).
    bins : int
        Phase bins B; bin b is centred on phase b / B.

    Returns
    -------
    table : ndarray, shape (B, L)
        Weighted mean of the vectors near each bin; bins nothing fell near are filled by
        circular interpolation between their filled neighbours.
    weight : ndarray, shape (B,)
        Total weight per bin (about the number of pulses averaged).
    """
    f = np.asarray(features, dtype=np.float64)
    pos = np.mod(np.asarray(phases, dtype=np.float64), 1.0) * bins
    b0 = np.floor(pos).astype(np.int64) % bins
    w1 = pos - np.floor(pos)
    b1 = (b0 + 1) % bins
    wmat = np.zeros((bins, len(f)))
    idx = np.arange(len(f))
    np.add.at(wmat, (b0, idx), 1.0 - w1)
    np.add.at(wmat, (b1, idx), w1)
    weight = wmat.sum(axis=1)
    table = np.zeros((bins, f.shape[1]))
    full = weight > 1e-6
    table[full] = (wmat[full] @ f) / weight[full, None]
    if not full.all() and full.any():
        filled = np.nonzero(full)[0]
        for b in np.nonzero(~full)[0]:
            j = np.searchsorted(filled, b)
            lo, hi = filled[j - 1], filled[j % len(filled)]
            gap = (hi - lo) % bins or bins
            t = ((b - lo) % bins) / gap
            table[b] = (1 - t) * table[lo] + t * table[hi]
    return table, weight


@dataclass(frozen=True)
class Matches:
    """Nearest reference phase of each pulse.

    Attributes
    ----------
    phase : ndarray, shape (n,)
        Matched blade phase, cycles in [0, 1) (sub-bin by a parabola).
    quality : ndarray, shape (n,)
        Contrast ``1 - d_best / d_far`` in [0, 1], where ``d_far`` is the best distance
        among bins more than 1/8 period away from the best one: near 0 for noise and for
        an ambiguous match (several distant angles fit as well, e.g. while no blade echo
        is visible), towards 1 for a clear, unique match.
    distance : ndarray, shape (n,)
        Best squared distance (energy norm).

    The contrast is scaled down by ``d_far / floor`` where ``d_far`` is below the table's
    :func:`distance_floor`: alternatives that close are alike on the table's own scale.
    """

    phase: np.ndarray
    quality: np.ndarray
    distance: np.ndarray


def distance_floor(table: np.ndarray, share: float = FLAT_SHARE) -> float:
    """``share`` of the median squared distance between table rows more than 1/8 period
    apart: the scale under which :func:`match` counts two alternatives as alike (0 for a
    table of one bin, or all alike)."""
    t = np.asarray(table, dtype=np.float64)
    bins = t.shape[0]
    excl = max(1, bins // 8)
    off = (np.arange(bins)[None, :] - np.arange(bins)[:, None] + bins // 2) % bins - bins // 2
    far = np.abs(off) > excl
    if not far.any():
        return 0.0
    n = (t * t).sum(axis=1)
    d = np.maximum(n[:, None] + n[None, :] - 2.0 * (t @ t.T), 0.0)
    return float(share * median(d[far]))


def match(features: np.ndarray, table: np.ndarray, table_sq: np.ndarray | None = None,
          floor: float = 0.0) -> Matches:
    """Nearest table phase of every row of ``features`` (energy norm), vectorised.

    Parameters
    ----------
    features : ndarray, shape (n, L)
        Vectors to match (same transform as the table).
    table : ndarray, shape (B, L)
        Angular table.
    table_sq : ndarray, shape (B,), optional
        Precomputed ``|T_b|^2`` (the daemon keeps it).
    floor : float
        The table's :func:`distance_floor` (0: none). A pulse whose best alternative is
        closer than that, as a pulse is to every bin of a flat part of the table (no
        blade in view), gets its contrast scaled by that distance over the floor.

    Returns
    -------
    Matches
        Each row is matched independently: reordering the input reorders the output.
    """
    x = np.atleast_2d(np.asarray(features, dtype=np.float64))
    t = np.asarray(table, dtype=np.float64)
    bins = t.shape[0]
    tsq = (t * t).sum(axis=1) if table_sq is None else table_sq
    xsq = (x * x).sum(axis=1)
    d = xsq[:, None] - 2.0 * (x @ t.T) + tsq[None, :]
    d = np.maximum(d, 0.0)
    rows = np.arange(len(x))
    b = np.argmin(d, axis=1)
    dm, d0, dp = d[rows, (b - 1) % bins], d[rows, b], d[rows, (b + 1) % bins]
    den = dm - 2.0 * d0 + dp
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(den > 0, 0.5 * (dm - dp) / den, 0.0)
    delta = np.clip(delta, -0.5, 0.5)
    excl = max(1, bins // 8)
    off = (np.arange(bins)[None, :] - b[:, None] + bins // 2) % bins - bins // 2
    far = np.where(np.abs(off) > excl, d, np.inf).min(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(np.isfinite(far) & (far > 0), (far - d0) / np.maximum(far, floor), 0.0)
    return Matches(phase=np.mod((b + delta) / bins, 1.0), quality=np.clip(q, 0.0, 1.0),
                   distance=d0)


def nearest_bin(phases: np.ndarray, bins: int) -> np.ndarray:
    """The table bin (bin b centred on phase b / ``bins``) nearest each phase."""
    return np.round(np.mod(np.asarray(phases, dtype=np.float64), 1.0) * bins) \
        .astype(np.int64) % bins


def cross_tables(features: np.ndarray, phases: np.ndarray, bins: int
                 ) -> list[tuple[slice, np.ndarray]]:
    """Each half of a reference's pulses with a table folded from the other half: (the
    half's rows, that table), twice. What a reference measures of its own pulses is
    measured this way, since a table folded from the same pulses would favour them."""
    n = len(features)
    half = n // 2
    return [(test, build_table(features[train], phases[train], bins)[0])
            for test, train in ((slice(half, n), slice(0, half)),
                                (slice(0, half), slice(half, n)))]


def cross_matches(features: np.ndarray, phases: np.ndarray, bins: int,
                  halves: list[tuple[slice, np.ndarray]] | None = None
                  ) -> list[tuple[slice, Matches]]:
    """Each half of a reference's pulses matched against a table folded from the other
    half (:func:`cross_tables`, or ``halves`` if made), with the table's
    :func:`distance_floor`: (the half's rows, their matches), twice. What
    :func:`twin_bins` and :func:`self_matches` read."""
    f = np.asarray(features, dtype=np.float64)
    return [(test, match(f[test], table, None, distance_floor(table)))
            for test, table in (halves if halves is not None
                                else cross_tables(f, np.mod(phases, 1.0), bins))]


def twin_bins(features: np.ndarray, phases: np.ndarray, bins: int,
              crossed: list[tuple[slice, Matches]] | None = None) -> np.ndarray:
    """For each bin of the table, the other angle whose pulses often match it clearly
    (its *twin*), or -1: shape (bins,), learned from a reference's own pulses.

    Why: where the echo is mostly glints (a blade's specular flash on each path, lasting
    a pulse or two), two angles of a blade period can look alike: in a simulated
    six-bladed fan the flashes of two stretches of the period were mirror images of each
    other, and a pulse at one matched the other as clearly as its own, nearly as often
    (37-47 % of the clear matches in such scenes, where other scenes' are 0-2 %). A
    tracker that counts those as outliers gives its line up every second. Which bins
    are confused with which is a property of the room and fan, so it is measured where
    the truth is known: each half of the reference's pulses is matched against a table
    folded from the other half (:func:`cross_matches`, or ``crossed`` if made), and a bin
    whose clear matches (quality ``TWIN_CLEAR`` or more) came from one other angle, more
    than 1/8 period away, at least ``TWIN_SHARE`` of the time (and ``TWIN_LEAST`` times)
    has that angle as its twin. A match at a bin with a twin could be either angle;
    the tracker takes whichever its line expects (:meth:`tracking.Tracker.update`),
    and the direction between a line and its mirror is left to the mirror check, which
    weighs whole windows.
    """
    f = np.asarray(features, dtype=np.float64)
    p = np.mod(np.asarray(phases, dtype=np.float64), 1.0)
    twins = np.full(bins, -1, dtype=np.int64)
    if len(f) // 2 < 2 or bins < 8:
        return twins
    true_bin, got_bin = [], []
    for test, m in (crossed if crossed is not None else cross_matches(f, p, bins)):
        clear = m.quality >= TWIN_CLEAR
        true_bin.append(nearest_bin(p[test][clear], bins))
        got_bin.append(nearest_bin(m.phase[clear], bins))
    tb, gb = np.concatenate(true_bin), np.concatenate(got_bin)
    excl = max(1, bins // 8)
    for b in range(bins):
        came = tb[gb == b]
        if len(came) < TWIN_LEAST:
            continue
        off = (came - b + bins // 2) % bins - bins // 2
        other = np.bincount(came[np.abs(off) > excl], minlength=bins)
        j = int(np.argmax(other))
        if other[j] >= max(TWIN_LEAST, TWIN_SHARE * len(came)):
            twins[b] = j
    return twins


@dataclass(frozen=True)
class SelfMatches:
    """How a reference's own pulses match a table of the other half (:func:`self_matches`):
    the shares of its pulses matched clearly within 1/8 period of their own angle
    (``own``) and further (``astray``); NaN for too few pulses."""

    own: float
    astray: float

    @property
    def astray_of_clear(self) -> float:
        """Share of the clear matches that land at another angle (NaN: none clear)."""
        clear = self.own + self.astray
        return self.astray / clear if clear > 0 else math.nan


def self_matches(features: np.ndarray, phases: np.ndarray, bins: int,
                 crossed: list[tuple[slice, Matches]] | None = None) -> SelfMatches:
    """Each half of a reference's pulses matched against a table folded from the other
    half (:func:`cross_matches`, or ``crossed`` if made): the shares of its pulses matched
    clearly (quality ``TWIN_CLEAR`` or more) at their own angle and elsewhere.

    Why: the live track lives on clear matches at the fan's own angle, and clear ones
    elsewhere (look-alike glints, often mirror images) pull it off its line or onto its
    mirror. The table's own fit (``quality``, its explained energy) stays near 1 where
    the fan is seen only in short glints, or where two stretches of the blade period
    look alike; there a track is lost every blade period or two. Measured on pulses
    the table did not see, the shares tell those places apart (docs/dynamics.md, "How
    much of the fan a place shows")."""
    f = np.asarray(features, dtype=np.float64)
    p = np.mod(np.asarray(phases, dtype=np.float64), 1.0)
    if len(f) // 2 < 2:
        return SelfMatches(math.nan, math.nan)
    own = astray = 0
    for test, m in (crossed if crossed is not None else cross_matches(f, p, bins)):
        near = np.abs((m.phase - p[test] + 0.5) % 1.0 - 0.5) <= 0.125
        clear = m.quality >= TWIN_CLEAR
        own += int((clear & near).sum())
        astray += int((clear & ~near).sum())
    return SelfMatches(own / len(f), astray / len(f))


def twin_phases(phases: np.ndarray, twins: np.ndarray) -> np.ndarray:
    """The twin angle (:func:`twin_bins`, bin centre) of each matched phase, NaN where
    its bin has none."""
    bins = len(twins)
    t = twins[nearest_bin(phases, bins)]
    return np.where(t >= 0, t / bins, np.nan)


def table_lookup(table: np.ndarray, phases: np.ndarray) -> np.ndarray:
    """Table rows at arbitrary phases by circular linear interpolation, shape (n, L)."""
    bins = table.shape[0]
    pos = np.mod(np.asarray(phases, dtype=np.float64), 1.0) * bins
    b0 = np.floor(pos).astype(np.int64) % bins
    w = (pos - np.floor(pos))[:, None]
    rows: np.ndarray = (1.0 - w) * table[b0] + w * table[(b0 + 1) % bins]
    return rows


def explained_fraction(features: np.ndarray, table: np.ndarray, phases: np.ndarray) -> float:
    """Share of the features' energy the table explains at the given phases, in [0, 1].

    A quality figure for a reference: near 1 when folding at the estimated period makes
    every pulse look like its table row, near 0 when the table is noise.
    """
    f = np.asarray(features, dtype=np.float64)
    total = float((f * f).sum())
    if total <= 0:
        return 0.0
    res = f - table_lookup(table, phases)
    return float(np.clip(1.0 - (res * res).sum() / total, 0.0, 1.0))
