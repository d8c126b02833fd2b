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

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from fractions import Fraction
from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .fingerprint import table_lookup
from .stats import t_as_z
from .tracking import Tracker, TrackId, wrap

#: Largest denominator q checked (simulated paper-room probes locked on aliases up to
#: q = 24, the largest tried; 17 angles, 0.5 Hz, were mostly fine without the check).
MAX_Q = 24
#: Relative cost gap between the best alias line and the next one needed to trust it.
MARGIN = 0.1
#: Times the window since a lock must have seen each of the q blade angles before its
#: winner moves the track: over fewer the lines' costs swing from one check to the next
#: (a start at 1/12 blade period per pulse: the true line clear by 0.13 over 32 pulses,
#: its mirror by 0.16 over 41, which moved the track there and fired a false reversal;
#: kept on, the true line won by 0.31 and more from 50 pulses on)
SEEN_EACH = 4
#: Pulses (about a second) of a ramp that verify a track (AliasWatch.verified).
RAMP_PULSES = 34
#: Largest denominator q of the lines ``rate + j/q`` that a track near no p/q must fit
#: no better than its own to be verified, and once verified (AliasWatch._check_shifts):
#: halves, thirds and quarters of a blade period per pulse, the aliases a ramp through a
#: small-q fraction can leave a track on.
SHIFT_Q = 4
#: Phase steps of the line fit per table bin.
FIT_STEPS_PER_BIN = 4
#: Evidence (:attr:`MirrorEvidence.z`: the t statistic of :func:`mirror_evidence` read as
#: the normal z of the same tail) that a track's line fits the table better than its
#: mirror line, below which its direction is in doubt: a significance, not a room's
#: figure. A window of 5 s holds about six batch means (a blade period each), and a t
#: from six is heavy-tailed: t 3 is z 2.17 (one window in 70 on noise, not one in 740),
#: and t 5.6 is z 3. (As t, random tuning scenes whose direction held gave 3.0-22 at the
#: 5th percentile of 5 s windows, those that flipped -2.9 to 1.7.)
MIRROR_Z = 3.0
#: Evidence under which a whole window of steady turning leaves the direction in doubt
#: (between the two, neither: a hysteresis, so that a strong room's windows through a
#: ramp do not count as doubt).
MIRROR_DOUBT_Z = 2.0
#: Share of a path's sweep going against its main direction above which the window holds
#: a reversal: a path through a reversal and its mirror differ little; no verdict.
MIRROR_TURN_SHARE = 0.1
#: Least pulses of a track the mirror check looks at (about a second at PRF 34 Hz).
MIRROR_MIN_PULSES = 34
#: Least batches of the mirror statistic's batch means.
MIRROR_BATCHES = 6
#: Least phase the track's line moves over the pulses checked (blade cycles): below it a
#: line and its mirror are nearly the same line.
MIRROR_MIN_SWEEP = 0.25
#: Least ratio of the slowest quarter's sweep to the briskest's in a window that may
#: leave the direction in doubt (a steady rate; not a ramp from or to rest).
MIRROR_STEADY = 0.6
#: The share of doubtful checks (``AliasWatch.mirror_doubt``, forgetting a fifth per half
#: window) from which a new track's direction waits for its own evidence: one doubtful
#: half window in the last two or so.
MIRROR_DOUBTFUL = 0.1
#: Why a new track's direction waits, in a room where directions have been in doubt.
TO_BE_CONFIRMED = ("direction to be confirmed: in this room the echoes of the fan turned "
                   "either way have been about as alike as the pulses' noise allows")
#: A path's step under this share of its brisk steps (90th percentile) stands still.
MIRROR_STILL_STEP = 0.25


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


def near_fraction(rate: float, **kwargs: Any) -> Fraction | None:
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


@lru_cache(maxsize=1)
def _few_angle_shifts() -> np.ndarray:
    """0, then the shifts j/q (q <= ``SHIFT_Q``) of :meth:`AliasWatch._check_shifts`."""
    sh = {float(f) for q in range(2, SHIFT_Q + 1) for f in
          (Fraction(j, q) for j in range(-q + 1, q)) if f != 0}
    return np.array([0.0] + sorted(sh), dtype=np.float64)


def alias_rates(rate: float, fracs: list[Fraction], *, max_rate: float, min_rate: float,
                max_q: int = MAX_Q) -> np.ndarray:
    """Candidate rates: ``rate + j / q`` for the denominators q of ``fracs`` and their
    multiples (the true period may be a multiple of the one tracked), within
    ``min_rate <= |w| <= max_rate``; the tracked rate is first."""
    # sorted and unique as np.unique gives them, which imports numpy.ma (1.9 MiB resident
    # in the daemon) for its check of a masked array
    sh = np.array(sorted({float(s) for f in fracs for s in _shifts(f.denominator, max_q)}),
                  dtype=np.float64)
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
    d: np.ndarray = (f * f).sum(axis=1)[:, None] - 2.0 * (f @ t.T) + tsq[None, :]
    return d


def _doubled_rows(d: np.ndarray) -> np.ndarray:
    """Row k of ``d`` rotated by any shift s is a contiguous window of the doubled row:
    (n, M + 1, M) views, so a path gathers n slices instead of n * M single elements."""
    return sliding_window_view(np.concatenate([d, d], axis=1), d.shape[1], axis=1)


def _best_offset(win: np.ndarray, shifts: np.ndarray) -> tuple[int, float]:
    """The offset j (fine-table steps) that fits a path best, and its summed distance:
    the path puts pulse k at fine phase ``shifts[k] + j`` (``win``: :func:`_doubled_rows`)."""
    c = win[np.arange(len(shifts)), shifts].sum(axis=0)
    j = int(np.argmin(c))
    return j, float(c[j])


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
    if dist is None:
        assert features is not None   # the callers give one of the two
        d = distances(features, fine)
    else:
        d = np.asarray(dist, dtype=np.float64)
    kk = np.asarray(k, dtype=np.float64) - float(k[-1])
    M = len(fine[0])
    # row k of the line at rate w is d[k] rotated by s_k = round(w k M)
    win = _doubled_rows(d)
    n = max(len(d), 1)
    rates = np.asarray(rates, dtype=np.float64)
    shifts = np.mod(np.round(rates[:, None] * kk[None, :] * M).astype(np.int64), M)
    cost = np.empty(len(rates))
    phase = np.empty(len(rates))
    for i in range(len(rates)):
        j, c = _best_offset(win, shifts[i])
        cost[i] = c / n
        phase[i] = j / M
    return cost, phase


def shifted_path_costs(dist: np.ndarray, path: np.ndarray, k: np.ndarray,
                       fine: tuple[np.ndarray, np.ndarray], shifts: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Best fit of the paths ``path_k + s (k - k_last)`` against the table, one per shift
    ``s`` (cycles per pulse): :func:`line_costs` for a track's own path, ramps and all,
    and the paths its rate's aliases ``rate + s`` would have drawn through the same
    pulses. Returns each path's mean squared distance per pulse and its phase at the last
    pulse (cycles)."""
    d = np.asarray(dist, dtype=np.float64)
    p = np.asarray(path, dtype=np.float64)
    kk = np.asarray(k, dtype=np.float64) - float(k[-1])
    M = len(fine[0])
    sh = np.asarray(shifts, dtype=np.float64)
    win = _doubled_rows(d)
    n = max(len(d), 1)
    # (pulse k of path i at fine phase s[i, k] + j, the offset j fitted as line_costs does)
    s = np.mod(np.round((p[None, :] + sh[:, None] * kk[None, :]) * M).astype(np.int64), M)
    cost = np.empty(len(sh))
    phase = np.empty(len(sh))
    for i in range(len(sh)):
        j, c = _best_offset(win, s[i])
        cost[i] = c / n
        phase[i] = (float(p[-1]) + j / M) % 1.0
    return cost, phase


class MirrorEvidence(NamedTuple):
    """What :func:`mirror_evidence` found."""

    t: float            # how much better the path fits than its mirror (a t statistic)
    sweep: float        # blade cycles the path moved over
    offset: float       # the mirror image's best offset c (cycles): it is ``c - p_k``
    dof: int = 0        # the t's degrees of freedom (batch means less one; 0: no t)

    @property
    def z(self) -> float:
        """``t`` as the normal z of the same tail (:func:`stats.t_as_z`): the scale
        ``MIRROR_Z`` and ``MIRROR_DOUBT_Z`` are set on."""
        return t_as_z(self.t, self.dof) if self.dof > 0 else self.t


def mirror_evidence(dist: np.ndarray, path: np.ndarray, fine: tuple[np.ndarray, np.ndarray]
                    ) -> MirrorEvidence:
    """How much better the track's path of phases fits the table than its mirror image.

    Why: the direct echo of a flat fan is the same turned either way (the angle pattern is
    symmetric about the blade pointing at the sensor); only the wall bounces tell the
    directions apart. Where they are weak the reversed path fits almost as well, and the
    per-pulse matches fall on either, so a track can lock on the mirror and flip. The path
    ``p_k`` (the tracked phase of each pulse, ramps and all) and its mirror ``c - p_k`` are
    each fitted with their best offset; their per-pulse distances are compared. Pulses of
    one blade period see the same blade, so the differences are averaged per blade period
    (batch means, at least ``MIRROR_BATCHES`` of them) before their mean is set against
    its standard error.
    """
    d = np.asarray(dist, dtype=np.float64)
    p = np.asarray(path, dtype=np.float64)
    n, M = len(d), len(fine[0])
    steps = np.abs(wrap(np.diff(p))) if n > 1 else np.zeros(0)
    sweep = float(steps.sum())
    if n < 2 or not sweep > 0:
        return MirrorEvidence(0.0, sweep, 0.0)
    win = _doubled_rows(d)
    rows = np.arange(n)
    per, offset = [], 0.0
    for sign in (1.0, -1.0):
        s = np.mod(np.round(sign * p * M).astype(np.int64), M)
        j, _ = _best_offset(win, s)
        per.append(d[rows, (s + j) % M])
        offset = j / M                  # (kept from the mirror's fit, the second)
    delta = per[1] - per[0]
    size = max(1, min(math.ceil(n / sweep), n // MIRROR_BATCHES))
    nb = n // size
    if nb < 2:
        return MirrorEvidence(0.0, sweep, offset)
    bm = delta[n - nb * size:].reshape(nb, size).mean(axis=1)
    mean, sd = float(bm.mean()), float(bm.std(ddof=1))
    if not sd > 0:
        return MirrorEvidence(math.copysign(math.inf, mean) if mean != 0 else 0.0, sweep,
                              offset, nb - 1)
    return MirrorEvidence(mean / (sd / math.sqrt(nb)), sweep, offset, nb - 1)


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


@dataclass
class AliasWatch:
    """The alias check run on a live track, pulse by pulse (the daemon and analyze).

    Keeps the last ``window`` pulses' distances to the fine table; every quarter window
    (every 8 pulses soon after a lock), or when the track jumps to another rate, asks
    whether the tracked rate is near p/q cycles per pulse and, if so, which of its aliases
    fits the reference table best. A clear winner other than the track, found twice in a
    row, moves the track; no clear winner leaves a verdict that makes the answer unknown,
    with ``note`` as the reason.
    """

    fine: tuple[np.ndarray, np.ndarray]
    window: int
    ref_cycles_per_pulse: float
    min_rate: float
    verdict: AliasVerdict | None = None
    note: str = ""
    moves: int = 0                                  # times the track was moved off an alias
    last_move: tuple[float, float, int] | None = None   # (from, to relative rate, pulse)
    count: int = 0                                  # pulses pushed
    _dist: np.ndarray = field(init=False, repr=False)
    _phase: np.ndarray = field(init=False, repr=False)
    _pulse: np.ndarray = field(init=False, repr=False)
    _at: int = -(10 ** 9)
    _rate: float = float("nan")
    _move_to: float = float("nan")                  # a move seen once, awaiting confirmation
    _shift_to: float = float("nan")                 # the same for _check_shifts
    _line_of: TrackId | None = None                 # the track (line) last seen by check
    _line_from: int = -(10 ** 9)                    # its pulses are those after this one
    _shift_due: int = 0                             # count due for the next _check_shifts
    #: the least rate change (cycles per pulse^2) that makes a ramp
    ramp_accel: float = math.inf
    #: the track (Tracker.identity) whose line has been shown to be the true one: it
    #: followed a ramp (its matches favoured a changing rate of at least ``ramp_accel``
    #: for ``RAMP_PULSES``: a line whose matches keep fitting while the rate changes is
    #: no alias, the alias of a changing rate fits none of them), or its steady rate was
    #: near no p/q over half a window (the matches single out one line)
    verified: TrackId | None = None
    _ramp_track: TrackId | None = None
    _ramp_pulses: int = 0
    #: why the track's direction is in doubt (its mirror line fits about as well); empty
    #: when it is not (:meth:`_check_mirror`)
    mirror_note: str = ""
    #: share of the recent full-window mirror checks that found the direction in doubt
    #: (forgetting): in a room where it has been, a new track's direction waits for its
    #: own check
    mirror_doubt: float = 0.0
    mirror_moves: int = 0                           # tracks moved to their mirror line
    _mirror_track: TrackId | None = None
    _mirror_ok: TrackId | None = None               # the track whose line beat its mirror
    _mirror_seen: TrackId | None = None             # the track whose mirror won one check
    _mirror_at: int = -(10 ** 9)
    #: the steady run whose mirror evidence is pooled: (track, turning the positive way)
    _pool_key: tuple[TrackId, bool] | None = None
    _pool_sum: float = 0.0
    _pool_n: int = 0
    _pool_end: int = -1                             # the last pulse of its last window

    def __post_init__(self) -> None:
        self._dist = np.zeros((self.window, len(self.fine[0])))
        self._pulse = np.zeros(self.window, dtype=np.int64)
        self._phase = np.full(self.window, math.nan)
        self._every = max(self.window // 4, 8)

    def mirror_checked(self, tr: Tracker) -> bool:
        """Whether track ``tr``'s line has fitted the table clearly better than its
        mirror line (``MIRROR_Z``)."""
        return tr.locked and self._mirror_ok is not None and self._mirror_ok == tr.identity

    @property
    def awaiting_check(self) -> bool:
        """Whether the track's direction waits for its own check, being new in a room
        where directions have been in doubt (``mirror_note`` is ``TO_BE_CONFIRMED``)."""
        return self.mirror_note == TO_BE_CONFIRMED

    @property
    def standing(self) -> bool:
        """Whether the last check found the track standing still (near 0/q blade period
        per pulse) with another line fitting as well or better: the fan moves, and the
        track's slow rate says nothing of a fan near zero (Decision.standing_alias)."""
        v = self.verdict
        return v is not None and v.frac == 0 and v.status != "clear"

    @property
    def doubtful(self) -> bool:
        """Whether directions have lately been in doubt here (``MIRROR_DOUBTFUL``)."""
        return self.mirror_doubt >= MIRROR_DOUBTFUL

    def push(self, k: int, dist: np.ndarray, phase: float = math.nan) -> None:
        """Pulse ``k``'s distances to the fine table (:func:`distances`) and the track's
        phase at it (NaN: none)."""
        j = self.count % self.window
        self._dist[j] = dist
        self._pulse[j] = int(k)
        self._phase[j] = float(phase)
        self.count += 1

    def check(self, tr: Tracker, *, accel: float | Callable[[], float],
              moving: Callable[[], bool], resting: bool = False) -> None:
        """Look at track ``tr`` if due (``accel``: its clear acceleration, cycles per
        pulse^2, or a function giving it, asked only when a check is due: on every
        pulse's path; ``moving()``: whether the fan is seen to move, asked only for a
        track standing still); may move the track."""
        if not tr.locked:
            self.verdict, self.note = None, ""
            self._rate = float("nan")
            self.mirror_note = ""
            return
        self._note_ramp(tr)
        if tr.identity != self._line_of:
            self._line_of, self._line_from = tr.identity, int(tr.last_k or 0)
        if resting:
            # a fan at rest has no direction to doubt; but in a doubtful room the track a
            # start brings waits for its own check like any new track: its first answers
            # come while the rest's static estimate is still held, when the check is not
            # run, and unchecked they were answered the wrong way (docs/dynamics.md)
            self.mirror_note = TO_BE_CONFIRMED \
                if self.doubtful and tr.identity != self._mirror_ok else ""
        elif self._check_mirror(tr):
            return
        if tr.identity == self.verified and not self._stands_while_moving(tr, moving):
            # a track that followed the phase continuously from a stretch where its line
            # was shown to be the true one cannot have jumped to an alias (a jump of 1/q
            # in rate): a ramp through p/q keeps its answer (a ramp through 1/18 was
            # 'ambiguous' between the rate and its mirror for 1.2 s); only lines a few
            # angles away are looked at again, every half window
            self.verdict, self.note = None, ""
            if self.count >= self._shift_due:
                self._check_shifts(tr)
            return
        rate, var = tr.track_rate       # (locked)
        jumped = not abs(rate - self._rate) <= 0.25 / MAX_Q
        # soon after a lock the window since it is short and its verdict young: look again
        # every 8 pulses until it spans half the window
        young = tr.last_k is not None and tr.start_k is not None and \
            tr.last_k - tr.start_k < self.window // 2
        every = 8 if young else self._every
        if not jumped and self.count - self._at < every:
            return
        self._at = self.count
        self._rate = rate
        self.verdict, self.note = None, ""
        idx, k = self._window_of(tr)
        if len(k) < 2:
            return
        sd = math.sqrt(max(var, 0.0))
        span = int(k[-1] - k[0]) + 1
        fracs = near_fractions(rate, span=span, rate_std=sd,
                               accel=accel() if callable(accel) else accel)
        if not fracs:
            if span >= self.window // 2 and not near_fractions(rate, span=span, rate_std=sd):
                # near no p/q over half a window even as a steady rate: the matches single
                # out this line (with the ramp's exemption a track on a wrong line, its
                # rate change noisy, passed at exactly 1/16 and stayed on a mirror alias),
                # unless a line a few angles away fits the table better
                if self._check_shifts(tr) is True:
                    self.verified = tr.identity
            return
        # a track standing still: check it against every p/q only while the fan moves
        # (the check then has the most candidates)
        if fracs[0] == 0 and not moving():
            return
        v = check_aliases(None, k, self.fine, rate, sd, max_rate=tr.max_rate,
                          min_rate=self.min_rate, fracs=fracs, dist=self._dist[idx])
        self.verdict = v
        if v is not None:
            self._act(tr, v, int(k[-1]), span < SEEN_EACH * v.frac.denominator)

    def _check_shifts(self, tr: Tracker) -> bool | None:
        """Whether the track's path fits the table no worse than the paths its rate's
        lines ``j/q`` (q <= ``SHIFT_Q``) blade period per pulse away would have drawn
        (:func:`shifted_path_costs`); one that fits clearly better (``MARGIN``) at two
        checks in a row moves the track there.

        Why: a track verified by a ramp, or by a steady rate near no p/q, was never
        checked against its aliases again, and a ramp through p/q can leave it on the
        alias line ``rate + j/q``: where the blade pattern nearly repeats within a blade
        period (a few bright angles) that line keeps enough matches to stay locked away
        from every p/q (spent held-out 5900018: a ramp through 1/4 blade period per
        pulse left the track on ``rate - 1/2``, reversed, verified by the ramp's last
        second; the true line fitted the table 20-50 % better for the next 10 s, and the
        wrong way was published for 10 s). So a verified track is looked at every half
        window, and a steady one before it is verified. A close call withholds nothing:
        the answer stands. None: too few pulses since the line last moved to tell."""
        self._shift_due = self.count + 2 * self._every
        idx, k = self._window_of(tr)
        path = self._phase[idx]
        # (the path since the track's line last moved: before it, the old line's)
        keep = np.isfinite(path) & (k > self._line_from)
        idx, k, path = idx[keep], k[keep], path[keep]
        if len(k) < max(self.window // 2, 16):
            self._look_again_soon()
            return None
        rate, _ = tr.track_rate         # (locked)
        sh = _few_angle_shifts()
        w = rate + sh
        ok = (np.abs(w) >= self.min_rate) & (np.abs(w) <= tr.max_rate)
        ok[0] = True
        sh = sh[ok]
        if len(sh) < 2:
            return True
        cost, phase = shifted_path_costs(self._dist[idx], path, k, self.fine, sh)
        b = int(np.argmin(cost))
        c0 = float(cost[0])
        gap = (c0 - float(cost[b])) / float(cost[b]) if cost[b] > 0 else 0.0
        if b == 0 or gap < MARGIN:
            self._shift_to = math.nan
            return True
        to = rate + float(sh[b])
        if not abs(to - self._shift_to) <= 0.25 / MAX_Q:
            self._shift_to = to             # one check alone never moves the track
            self._look_again_soon()
            return False
        self._shift_to = math.nan
        r0 = self.ref_cycles_per_pulse
        self._move(tr, rate, to, float(phase[b]), int(k[-1]))
        self.note = (f"the track was on the alias {rate / r0:+.3f} (relative rate) of a "
                     f"line {float(sh[b]):+.3g} blade period per pulse away and was moved "
                     f"to {to / r0:+.3f}, whose path fits the reference table better (cost "
                     f"gap {gap:.2f})")
        return False

    def _move(self, tr: Tracker, rate: float, to: float, phase: float, k_last: int
              ) -> None:
        """Relock the track from ``rate`` onto the line ``to`` (phase at ``k_last``), and
        count the move."""
        r0 = self.ref_cycles_per_pulse
        tr.relock(to, phase, k_last)
        self._rate = to
        self.moves += 1
        self.last_move = (rate / r0, to / r0, k_last)

    def _look_again_soon(self) -> None:
        """The next check in 8 pulses, verified track or not."""
        self._at = self.count - self._every + 8
        self._shift_due = self.count + 8

    def _stands_while_moving(self, tr: Tracker, moving: Callable[[], bool]) -> bool:
        """Whether the track stands (:meth:`_stands`) while the long meter sees the fan
        move: a ramp does not vouch for
        such a track. Where the table is clear at one angle only, the clear matches come
        once a blade period, and a fan turning near q pulses a period strobes them into a
        line near zero that follows the fan's ramp as an alias does (spent held-out
        5500017: a start to 0.68 Hz at 7.3 pulses a period was tracked standing for
        165 s, verified by the ramp, never checked against its aliases)."""
        return self._stands(tr.track_rate[0]) and moving()

    def _stands(self, rate: float) -> bool:
        """Whether a line at ``rate`` (cycles per pulse) sweeps less than
        ``MIRROR_MIN_SWEEP`` over half a window: near zero a line and its mirror, or its
        aliases, are nearly the same line."""
        return abs(rate) * (self.window // 2) < MIRROR_MIN_SWEEP

    def _window_of(self, tr: Tracker) -> tuple[np.ndarray, np.ndarray]:
        """Ring indices and pulse numbers of the window's pulses since the track began."""
        n = min(self.count, self.window)
        idx = (self.count - n + np.arange(n)) % self.window
        k = self._pulse[idx]
        keep = k >= (tr.start_k if tr.start_k is not None else k[0])
        return idx[keep], k[keep]

    def _check_mirror(self, tr: Tracker) -> bool:  # noqa: C901  one check's life in order
        """Ask whether the track's path fits the table clearly better than its mirror
        image (:func:`mirror_evidence`): every 8 pulses until it has, then every quarter
        window. Clearly worse twice: the track is moved to the mirror line. Neither over
        a whole window of steady turning: the direction is in doubt (``mirror_note``),
        and in a room where that happens a new track's direction waits for its own clear
        check. True when the track was moved (the alias check then waits for the next
        pulse)."""
        ident = tr.identity
        if ident != self._mirror_track:
            self._mirror_track, self._mirror_at = ident, self.count
            waits = ident != self._mirror_ok and self.mirror_doubt >= MIRROR_DOUBTFUL
            self.mirror_note = TO_BE_CONFIRMED if waits else ""
        confirmed = self._mirror_ok == ident
        new = self.count - self._mirror_at
        if new < (self._every if confirmed else 8):
            return False
        w, _ = tr.track_rate            # (locked)
        if self._stands(w):
            return self._no_verdict()     # the track stands (near zero): nothing to tell
        idx, k = self._window_of(tr)
        path = self._phase[idx]
        keep = np.isfinite(path)
        idx, k, path = idx[keep], k[keep], path[keep]
        if len(k) > 1:
            # pulses where the path stands (a fan at rest before it started, the turn of a
            # reversal) fit a path and its mirror alike: only those where it moves
            step = np.abs(wrap(np.diff(path, prepend=path[0])))
            step[0] = step[1] if len(step) > 1 else 0.0
            # (sorted by hand: np.percentile imports numpy.ma, 1.9 MiB in the daemon)
            brisk = float(np.sort(step)[int(0.9 * (len(step) - 1))])
            moves = step >= MIRROR_STILL_STEP * brisk
            idx, k, path = idx[moves], k[moves], path[moves]
        if len(k) < MIRROR_MIN_PULSES:
            return self._no_verdict()
        signed = wrap(np.diff(path))
        back = min(float(signed[signed > 0].sum()), float(-signed[signed < 0].sum()))
        if back > MIRROR_TURN_SHARE * float(np.abs(signed).sum()):
            # a path through a turn: only its part since the last step against the way
            # it goes now can be told from its mirror (a track taken up just before a
            # reversal waited a whole window, 5 s, for its turn to leave it)
            against = np.flatnonzero(signed * (1.0 if w >= 0 else -1.0) < 0)
            if len(against):
                j = int(against[-1]) + 1
                idx, k, path = idx[j:], k[j:], path[j:]
                if len(k) < MIRROR_MIN_PULSES:
                    return self._no_verdict()
                signed = wrap(np.diff(path))
                back = min(float(signed[signed > 0].sum()),
                           float(-signed[signed < 0].sum()))
        ev = mirror_evidence(self._dist[idx], path, self.fine)
        z, sweep, mirror_offset = ev.z, ev.sweep, ev.offset
        if sweep < MIRROR_MIN_SWEEP or back > MIRROR_TURN_SHARE * sweep:
            return self._no_verdict()   # a path and its mirror are nearly the same
        self._mirror_at = self.count
        # doubt is read only from a whole window of steady turning: on a ramp from or to
        # rest the slow end of the path tells little, and a strong room's reversals read
        # 1.8-2 there; so did its half windows of a fan at a third of the reference's
        # speed, whose whole windows read 2.6 (tuned room)
        quarters = [float(np.abs(q).sum()) for q in np.array_split(signed, 4)]
        full = len(k) >= self.window - 1 and min(quarters) >= MIRROR_STEADY * max(quarters)
        # the doubt forgets at a fifth per half window of new pulses
        forget = 0.2 * min(new / max(self.window // 2, 1), 1.0)
        pooled = self._pooled(ident, w, idx, k, path) if full else self._pool_of(ident, w)
        # a run's pooled evidence confirms a track as one clear window would, and keeps
        # it while it stays above doubt, unless a window clearly favours the mirror
        pool_ok = z > -MIRROR_Z and pooled >= (MIRROR_DOUBT_Z if self._mirror_ok == ident
                                                else MIRROR_Z)
        doubt = full and z < MIRROR_DOUBT_Z
        if z >= MIRROR_Z or pool_ok:
            self._mirror_ok, self._mirror_seen, self.mirror_note = ident, None, ""
            if full and z >= MIRROR_Z:
                self.mirror_doubt *= 1.0 - forget
            elif doubt:                 # the room's windows stay in doubt: new tracks wait
                self.mirror_doubt += forget * (1.0 - self.mirror_doubt)
            return False
        # the run's pooled evidence against the track counts as a window's would: the
        # track's path follows its own matches and leans toward its own line, so a
        # track on the mirror line read -0.7 to -2.9 on its path for 12 s of steady
        # turning while its fitted line pooled -6.3 (held-out 1800002, then spent)
        worst = min(z, pooled)
        if worst <= -MIRROR_Z or doubt:
            self.mirror_doubt += forget * (1.0 - self.mirror_doubt)
        if worst <= -MIRROR_Z:
            if self._mirror_seen == ident:
                # the mirror image of the line at the last pulse, rate reversed
                tr.relock(-w, mirror_offset - float(path[-1]), int(k[-1]))
                self._mirror_ok = self._mirror_track = tr.identity
                self._mirror_seen, self.mirror_note = None, ""
                self.mirror_moves += 1
                self._rate = -w
                return True
            self._mirror_seen = ident
            r0 = self.ref_cycles_per_pulse
            self.mirror_note = (f"direction in doubt: the reversed path (relative rate "
                                f"{-w / r0:+.3f}) fits the reference table better than the "
                                f"track's {w / r0:+.3f} (z {worst:.1f}), to be confirmed")
        elif doubt:
            self._mirror_ok = None
            self.mirror_note = (f"direction in doubt: the fan's echoes turned either way fit "
                                f"the reference table about equally (z {z:.1f} < "
                                f"{MIRROR_DOUBT_Z:g}); from where the device stands the "
                                "wall echoes that tell the directions apart are weak: a "
                                "place nearer a wall, off the fan's axis, makes them "
                                "stronger")
        return False

    def _pool_of(self, ident: TrackId, w: float) -> float:
        """The pooled evidence of the steady run of track ``ident`` turning the way of
        ``w`` (0 when none has been pooled for it)."""
        if self._pool_key != (ident, w > 0) or not self._pool_n:
            return 0.0
        return self._pool_sum / math.sqrt(self._pool_n)

    def _pooled(self, ident: TrackId, w: float, idx: np.ndarray, k: np.ndarray,
                path: np.ndarray) -> float:
        """Pool the mirror evidence of whole windows of steady turning that share no
        pulse (Stouffer: the sum of their t over the root of their count).

        Why: where the wall echoes are weak (a sensor near the fan's axis or far from
        the walls) one 5 s window's evidence sits near its noise on the track's true
        line too (t 0.9-2.6 on average in such rooms), and the direction stayed in
        doubt for a minute of steady turning. Windows of one run add up. The track's
        path follows its own matches and so leans toward its own line (a wrong track
        read +0.4 on average in such a room); the straight line fitted through the path
        does not (-0.2 on wrong tracks, +0.9 and +3.5 on right ones in two rooms), so
        that line is what is pooled.
        """
        key = (ident, w > 0)
        if key != self._pool_key:
            self._pool_key, self._pool_sum, self._pool_n, self._pool_end = key, 0.0, 0, -1
        if int(k[0]) > self._pool_end:
            u = np.concatenate(([0.0], np.cumsum(wrap(np.diff(path))))) + float(path[0])
            x = (k - k[0]).astype(np.float64)
            xm, um = float(x.mean()), float(u.mean())
            sxx = float(((x - xm) ** 2).sum())
            slope = float(((x - xm) * (u - um)).sum()) / sxx if sxx > 0 else 0.0
            line = np.mod(um + slope * (x - xm), 1.0)
            t1 = mirror_evidence(self._dist[idx], line, self.fine).z
            if math.isfinite(t1):
                self._pool_sum += t1
                self._pool_n += 1
                self._pool_end = int(k[-1])
        return self._pool_of(ident, w)

    def _no_verdict(self) -> bool:
        """No check possible now: a doubt found on earlier pulses does not carry over
        (they may have been a reversal's turn); in a doubtful room the track waits."""
        if self.mirror_note.startswith("direction in doubt"):
            self.mirror_note = "" if self.mirror_doubt < MIRROR_DOUBTFUL else TO_BE_CONFIRMED
        return False

    def _note_ramp(self, tr: Tracker) -> None:
        """Count the pulses of this track on which its matches favour a changing rate
        (the follower's model, :attr:`Tracker.follower_weight`) at a ramp of at least
        ``ramp_accel``; after ``RAMP_PULSES`` of them the track is verified."""
        ident = tr.identity
        if ident != self._ramp_track:
            self._ramp_track, self._ramp_pulses = ident, 0
        a, _ = tr.accel
        # (the ramp first: the weight, an exponential, is asked only of a ramp)
        if abs(a) >= self.ramp_accel and tr.follower_weight > 0.5:
            self._ramp_pulses += 1
            if self._ramp_pulses >= RAMP_PULSES:
                self.verified = ident

    def _act(self, tr: Tracker, v: AliasVerdict, k_last: int, young: bool = False
             ) -> None:
        """Move the track on a confirmed clear winner, never while the window since the
        lock is ``young`` (``SEEN_EACH``); say why the answer is unknown."""
        r0 = self.ref_cycles_per_pulse
        if v.frac == 0:
            seen = ("the track stands still while the fan moves: it may be the alias of a "
                    "rate near p/q blade period per pulse, where the pulses see only q "
                    "blade angles")
        else:
            seen = (f"rate near {v.frac.numerator}/{v.frac.denominator} blade period per "
                    f"pulse: the pulses see only {v.frac.denominator} blade angles")
        if v.status == "resolved" and (young
                                       or not abs(v.best_rate - self._move_to) <= 0.25 / MAX_Q):
            # one check alone never moves the track (a mirror line can win one window of
            # a weakly asymmetric room): until the next check agrees, the answer is unknown
            self._move_to = v.best_rate
            self.verdict = dataclasses.replace(v, status="ambiguous", gap=0.0)
            self._at = self.count - self._every + 8        # look again soon
            self.note = (f"rate ambiguous: {seen}; relative rate {v.best_rate / r0:+.3f} "
                         f"fits the reference table better than the track's "
                         f"{v.rate / r0:+.3f} (cost gap {v.gap:.2f}), to be confirmed")
            return
        self._move_to = float("nan")
        if v.status == "resolved":
            self._move(tr, v.rate, v.best_rate, v.best_phase, k_last)
            self.note = (f"{seen}; the track was on the alias {v.rate / r0:+.3f} "
                         f"(relative rate) and was moved to {v.best_rate / r0:+.3f}, which "
                         f"fits the reference table better (cost gap {v.gap:.2f})")
        elif v.status == "ambiguous":
            self.note = (f"rate ambiguous: {seen}, and relative rates "
                         f"{v.best_rate / r0:+.3f} and {v.runner_rate / r0:+.3f} fit the "
                         f"reference table about equally (cost gap {v.gap:.2f} < "
                         f"{MARGIN:g}); another fan speed, or another waveform.pri_samples "
                         "with a new reference, avoids it")
