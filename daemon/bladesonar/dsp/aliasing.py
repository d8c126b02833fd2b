"""Rate aliases when the blade phase per pulse is (close to) a fraction p/q.

Why: at a rate of p/q blade periods per pulse the fan is back where it was every q pulses,
so the pulses see only q distinct angles. Matched phases then repeat with period q and
every rate m/q draws a line through them: circular regression and the tracker can lock on
such an alias with full confidence (e.g. 4 blades at 1.7 Hz with PRF 34 Hz: 1/5 period per
pulse, tracked as -1/5, i.e. reversed). The paper-room fan is seen only over a narrow range
of angles, so often only one or two of the q angles carry information.

The check: keep the aliases of the tracked rate, ``w + j/q`` (the tracked offset from p/q
kept), and fit each as a phase line against the reference table with *all* the features of
the window: cost = mean over pulses of ``|f_k - T(phi0 + w k)|^2``, minimised over the
phase ``phi0``. Per-pulse nearest matches throw away how well the other angles fit; the
line fit does not, and it singles out the true rate where the matches cannot. When the
best line is not ahead of the next by ``margin`` (relative cost), the rate is ambiguous;
when another alias wins by that margin, the track is on an alias and is moved to it.

A reference recorded at such a rate folds onto q angles only (its table interpolates the
rest) and its period search cannot order them reliably either: :func:`folded_angles`
finds the fraction, for a warning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .fingerprint import table_lookup

#: Largest denominator q checked (simulated paper-room probes locked on aliases up to
#: q = 24, the largest tried; 17 angles, 0.5 Hz, were mostly fine without the check).
MAX_Q = 24
#: Relative cost gap between the best alias line and the next one needed to trust it.
MARGIN = 0.1
#: Phase steps of the line fit per table bin.
FIT_STEPS_PER_BIN = 4


def near_fractions(rate: float, *, span: int, rate_std: float = 0.0, max_q: int = MAX_Q,
                   min_q: int = 2, zero: bool = True, accel: float = 0.0) -> list[Fraction]:
    """The fractions p/q (``min_q <= q <= max_q``, smallest q first) that ``rate`` (cycles
    per pulse) is commensurate with over ``span`` pulses.

    Commensurate: over the span the visited angles drift by less than half the gap 1/q
    between them (``|rate - p/q| * span < 1/(2q)``), widened by twice the rate's standard
    deviation because the tracked rate is only known that well (so several may qualify),
    but by no more than that tolerance again: on a short window the standard deviation
    spans many p/q, and checking ordinary rates in a weakly asymmetric room (simulated
    narrow hall, 10 dB) turned right answers into unknown or mirror-wrong ones.
    With ``zero``, a rate that close to 0 gives 0/1 first: a track that stands still on a
    moving fan may be the alias of any p/q (the pulses that show no blade all match one
    phase).

    ``accel`` (cycles per pulse per pulse) is how fast the rate changes: a fan on a ramp
    passes p/q instead of staying there, and the angles it visits spread by about
    ``|accel| span^2 / 8`` about a line; once that exceeds half the gap 1/q they are not
    q angles any more, and p/q is not near (a ramp through 1/19 gave 1.5 s of 'rate
    ambiguous' otherwise).
    """
    if not math.isfinite(rate):
        return []
    n = max(int(span), 1)
    spread = abs(accel) * n * n / 8.0 if math.isfinite(accel) else 0.0
    sd = max(float(rate_std), 0.0) if math.isfinite(rate_std) else 0.0
    out = []
    if zero and abs(rate) <= 0.5 / n + 2.0 * sd:
        out.append(Fraction(0, 1))
    for q in range(max(min_q, 1), max_q + 1):
        p = round(rate * q)
        f = Fraction(p, q)
        tol = 0.5 / (q * n)
        if p != 0 and f.denominator == q and abs(rate - p / q) <= tol + min(2.0 * sd, tol) \
                and spread < 0.5 / q:
            out.append(f)
    return out


def near_fraction(rate: float, **kwargs) -> Fraction | None:
    """The first of :func:`near_fractions` (smallest q), or None."""
    got = near_fractions(rate, **kwargs)
    return got[0] if got else None


def folded_angles(cycles_per_pulse: float, pulses: int, *, max_q: int = MAX_Q
                  ) -> Fraction | None:
    """For a reference: the fraction p/q (q <= ``max_q``) its rate is commensurate with
    over its ``pulses``, or None. Folding then fills only q phases of the table, and the
    period search cannot tell p/q from another m/q when few of the q angles show the
    blade (simulated paper room: 1/9 estimated as 2/9, 1/18 as 5/18, 2/17 as 1/17)."""
    return near_fraction(cycles_per_pulse, span=pulses, max_q=max_q, min_q=1, zero=False)


@lru_cache(maxsize=64)
def _shifts(q0: int, max_q: int) -> np.ndarray:
    """Nonzero shifts j/q in (-1, 1) for q the multiples of ``q0`` up to ``max_q``."""
    out = {Fraction(j, c * q0) for c in range(1, max(max_q // q0, 1) + 1)
           for j in range(-c * q0 + 1, c * q0)} - {Fraction(0)}
    return np.array(sorted(float(f) for f in out), dtype=np.float64)


def alias_rates(rate: float, fracs: list[Fraction], *, max_rate: float, min_rate: float,
                max_q: int = MAX_Q) -> np.ndarray:
    """Candidate rates: ``rate + j / q`` for the denominators q of ``fracs`` and their
    multiples (the true period may be a multiple of the one tracked), within
    ``min_rate <= |w| <= max_rate``; the tracked rate is first."""
    sh = np.unique(np.concatenate([_shifts(f.denominator, max_q) for f in fracs]))
    w = float(rate) + sh
    w = w[(np.abs(w) >= min_rate) & (np.abs(w) <= max_rate)]
    return np.concatenate([[float(rate)], w])


def fine_table(table: np.ndarray, steps_per_bin: int = FIT_STEPS_PER_BIN
               ) -> tuple[np.ndarray, np.ndarray]:
    """The table at ``steps_per_bin`` phases per bin (linear interpolation) and its row
    energies: what :func:`line_costs` fits against (computed once per reference)."""
    M = max(int(table.shape[0]) * int(steps_per_bin), 16)
    t = table_lookup(table, np.arange(M) / M)
    return t, (t * t).sum(axis=1)


def distances(features: np.ndarray, fine: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Squared distance of each feature vector (n, L) to each fine-table phase: (n, M).
    A pulse's row never changes, so a streaming caller computes it once per pulse and
    keeps it (the product dominates a check otherwise)."""
    f = np.asarray(features, dtype=np.float64)
    t, tsq = fine
    return (f * f).sum(axis=1)[:, None] - 2.0 * (f @ t.T) + tsq[None, :]


def line_costs(features: np.ndarray | None, k: np.ndarray, fine: tuple[np.ndarray, np.ndarray],
               rates: np.ndarray, *, dist: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Best fit of phase lines ``phi0 + w k`` against the table, for each rate ``w``.

    Parameters
    ----------
    features : ndarray, shape (n, L)
        The window's feature vectors (same transform as the table).
    k : ndarray, shape (n,)
        Their pulse numbers.
    fine : (ndarray (M, L), ndarray (M,))
        :func:`fine_table` of the reference table.
    rates : ndarray, shape (m,)
        Cycles per pulse.
    dist : ndarray, shape (n, M), optional
        :func:`distances` of the features, if already known (``features`` is then unused).

    Returns
    -------
    cost : ndarray, shape (m,)
        Mean squared distance per pulse along the best line of each rate.
    phase : ndarray, shape (m,)
        That line's phase at the last pulse ``k[-1]``, cycles.
    """
    d = distances(features, fine) if dist is None else np.asarray(dist, dtype=np.float64)
    kk = np.asarray(k, dtype=np.float64) - float(k[-1])
    M = len(fine[0])
    # row k of the line at rate w is d[k] rotated by s_k = round(w k M): a contiguous window
    # of the doubled row, so each rate gathers n slices instead of n * M single elements
    win = sliding_window_view(np.concatenate([d, d], axis=1), M, axis=1)   # (n, M + 1, M)
    rows = np.arange(len(d))
    n = max(len(d), 1)
    rates = np.asarray(rates, dtype=np.float64)
    shifts = np.mod(np.round(rates[:, None] * kk[None, :] * M).astype(np.int64), M)
    cost = np.empty(len(rates))
    phase = np.empty(len(rates))
    for i in range(len(rates)):
        c = win[rows, shifts[i]].sum(axis=0)
        j = int(np.argmin(c))
        cost[i] = c[j] / n
        phase[i] = j / M
    return cost, phase


@dataclass(frozen=True)
class AliasVerdict:
    """Outcome of :func:`check_aliases`.

    Attributes
    ----------
    status : {"clear", "ambiguous", "resolved"}
        clear: the tracked rate fits best by ``margin``; ambiguous: the best two lines are
        closer than that; resolved: another alias fits best by ``margin``.
    frac : Fraction
        The fraction p/q (smallest q) the tracked rate is near.
    rate : float
        The tracked rate checked, cycles per pulse.
    best_rate, best_phase : float
        The best line (phase at the last pulse).
    runner_rate : float
        The next best line's rate.
    gap : float
        Relative cost gap between them, ``(c2 - c1) / c1``.
    """

    status: str
    frac: Fraction
    rate: float
    best_rate: float
    best_phase: float
    runner_rate: float
    gap: float


def check_aliases(features: np.ndarray | None, k: np.ndarray,
                  fine: tuple[np.ndarray, np.ndarray], rate: float, rate_std: float, *,
                  max_rate: float, min_rate: float, max_q: int = MAX_Q,
                  margin: float = MARGIN, fracs: list[Fraction] | None = None,
                  dist: np.ndarray | None = None) -> AliasVerdict | None:
    """Check a tracked rate against its aliases (``fine``: :func:`fine_table`); None when
    it is not near a p/q (q <= ``max_q``; ``fracs`` from :func:`near_fractions` if already
    known) or the window is too short to tell (fewer pulses than the fewest angles, or
    than 16)."""
    if len(k) < 2:
        return None
    if fracs is None:
        fracs = near_fractions(rate, span=int(k[-1] - k[0]) + 1, rate_std=rate_std,
                               max_q=max_q)
    if not fracs or len(k) < max(fracs[0].denominator, 16):
        return None
    frac = fracs[0]
    rates = alias_rates(rate, fracs, max_rate=max_rate, min_rate=min_rate, max_q=max_q)
    if len(rates) < 2:
        return None
    cost, phase = line_costs(features, k, fine, rates, dist=dist)
    order = np.argsort(cost, kind="stable")
    b, r = int(order[0]), int(order[1])
    c1, c2 = float(cost[b]), float(cost[r])
    gap = (c2 - c1) / c1 if c1 > 0 else (math.inf if c2 > 0 else 0.0)
    if gap < margin:
        status = "ambiguous"
    else:
        status = "clear" if b == 0 else "resolved"
    return AliasVerdict(status, frac, float(rate), float(rates[b]), float(phase[b]),
                        float(rates[r]), float(gap))
